#!/usr/bin/env python3
"""Cost of each sensor and actuator effect per simulator step, next to the ideal step.

One process, no ROS: :class:`arm_dynamics.simulation.SimulatorCore` stepped in lockstep
(the 2-R arm's defaults, RK4 1 ms physics steps, 10 ms control periods, the command of
each period a PD + gravity law computed from the published state, ``joint_view()`` read
every period as the node publishes it, ``true_view()`` too whenever the true state would be
published), once ideal and once per effect (:mod:`arm_dynamics.sensors`): Gaussian
position and velocity noise, encoder quantisation, a sensing delay, an actuation delay,
and all of them together. Each figure is the median over repeats of the wall time of one
control period [us], interleaved so that drifts of the machine hit every variant alike; the
ratio is to the ideal step. Run from the repo root::

    .venv/bin/python bench/bench_sensors.py           # ~15 s
    .venv/bin/python bench/bench_sensors.py --quick   # ~3 s
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import numpy as np

try:
    from arm_dynamics import TwoLinkArm
except ImportError:  # run as `python bench/bench_sensors.py` without PYTHONPATH
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from arm_dynamics import TwoLinkArm
from arm_dynamics.sensors import SensorModel
from arm_dynamics.simulation import SimulatorCore

ARM = TwoLinkArm()
GOAL = np.array([0.3, 0.6])
#: (label, SensorModel keywords, actuation_delay)
VARIANTS: tuple[tuple[str, dict, int], ...] = (
    ('ideal (defaults)', {}, 0),
    ('position + velocity noise', {'position_noise': [1e-3, 1e-3],
                                   'velocity_noise': [1e-2, 1e-2]}, 0),
    ('encoder 4096 counts/rev', {'encoder_resolution': [4096, 4096]}, 0),
    ('sensing delay 3 periods', {'sensing_delay': 3}, 0),
    ('actuation delay 3 periods', {}, 3),
    ('all of them', {'position_noise': [1e-3, 1e-3], 'velocity_noise': [1e-2, 1e-2],
                     'encoder_resolution': [4096, 4096], 'sensing_delay': 3}, 3),
)


def run(settings: dict, actuation_delay: int, periods: int) -> float:
    """Wall seconds per control period of a lockstep loop of ``periods`` periods."""
    core = SimulatorCore(ARM, q0=[-0.4, 1.2], qd0=[0.0, 0.0], effort_limits=[60.0, 20.0],
                         physics_step_ns=1_000_000, control_period_ns=10_000_000,
                         velocity_limit=1000.0, joint_names=['joint1', 'joint2'],
                         sensors=SensorModel(2, seed=1, **settings),
                         actuation_delay=actuation_delay)
    publish_true = core.sensors is not None or actuation_delay > 0
    start = time.perf_counter()
    for _ in range(periods):
        view = core.joint_view()
        if publish_true:
            core.true_view()
        q, qd = np.array(view.position), np.array(view.velocity)
        core.command = 100.0 * (GOAL - q) - 20.0 * qd + ARM.gravity_vector(q)
        core.advance()
    return (time.perf_counter() - start) / periods


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true', help='fewer, shorter repeats')
    args = parser.parse_args(argv)
    periods, repeats = (300, 5) if args.quick else (1000, 11)
    times: dict[str, list[float]] = {label: [] for label, _, _ in VARIANTS}
    for _label, settings, delay in VARIANTS:  # warm-up
        run(settings, delay, 50)
    for _ in range(repeats):
        for label, settings, delay in VARIANTS:
            times[label].append(run(settings, delay, periods))
    ideal = statistics.median(times[VARIANTS[0][0]])
    width = max(len(label) for label, _, _ in VARIANTS)
    print(f'SimulatorCore lockstep step (10 ms period = 10 RK4 steps + PD law), median of '
          f'{repeats} x {periods} periods')
    print(f"{'effect':<{width}}  {'us/step':>8}  {'extra us':>8}  {'x ideal':>7}")
    for label, _, _ in VARIANTS:
        t = statistics.median(times[label])
        print(f'{label:<{width}}  {t * 1e6:8.1f}  {(t - ideal) * 1e6:8.1f}  '
              f'{t / ideal:7.3f}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
