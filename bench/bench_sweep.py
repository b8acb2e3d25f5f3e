#!/usr/bin/env python3
"""Benchmark ``arm-sim sweep``: many closed-loop scenarios, vectorised and in parallel.

The workload: 10,000 scenarios of 2 s straight lines at 1 kHz control (physics step 1 ms,
so 2000 control periods and 2000 RK4 steps each): 10 lines from the demo's Ps (goals on a
circle of 0.4 m around Pf) x 4 laws with their gains x 25 payloads x 10 controller mass
errors. Measured in this one process:

1. the sweep as ``arm-sim sweep`` runs it (:func:`arm_sim.sweep.run_sweep`, 2 worker
   processes by default) -- wall time, scenario-steps per second; target <= 15 s;
2. the same sweep on a 2,000-scenario subset with one worker (the batch path per core);
3. the peer: one :func:`arm_dynamics.simulate` call per scenario with the controller core
   (:func:`arm_sim.sweep.run_single`, what the nodes compute one state at a time) for a
   few hundred of the scenarios, extrapolated to 10,000; the ratio of scenario-steps per
   second, target >= 20x.

4. the real arm (config/real_arm.yaml's values: motors, stick/slip friction, noise, 14-bit
   encoders, one period of sensing delay) against the ideal arm, in this one process (one
   worker, the same scenarios otherwise): the cost per scenario-step of each and their
   ratio, at 1 kHz (the workload above, 2 s lines) and at the demo's 100 Hz (10 physics
   steps per control period). The issue's target: < 1.5x (``--real-arm-only`` runs just
   this part).

No asserts: it prints the figures, the ratios and the machine's load average (the machine
may be shared). Run from the repo root::

    .venv/bin/python bench/bench_sweep.py             # ~1 minute
    .venv/bin/python bench/bench_sweep.py --quick     # 2,000 scenarios, 50 peers
    .venv/bin/python bench/bench_sweep.py --real-arm-only --repeats 3   # part 4, best of 3
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from typing import Any

import numpy as np

try:
    from arm_sim import sweep
except ImportError:  # run as `python bench/bench_sweep.py` without PYTHONPATH
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from arm_sim import sweep

TARGET_WALL = 15.0   # s for 10,000 scenarios
TARGET_RATIO = 20.0  # scenario-steps/s, sweep vs one simulate() per scenario
TARGET_REAL = 1.5    # real-arm cost per scenario-step / the ideal arm's (the issue's)
#: config/real_arm.yaml's values (test/test_sweep_real_arm.py uses the same).
REAL_ARM: dict[str, Any] = dict(gear_ratios=(100.0, 80.0), motor_inertias=(1.2e-5, 6e-6),
                motor_damping=(1e-5, 1e-5), coulomb_friction=(1.5, 0.5),
                static_friction=(1.95, 0.65), position_noise=(4e-4, 4e-4),
                velocity_noise=(0.01, 0.01), encoder_resolution=(16384.0, 16384.0),
                sensing_delay=1, noise_seed=1)
VARIANTS: tuple[dict[str, Any], ...] = (
            {'law': 'computed_torque', 'kp': (100.0, 60.0), 'kd': (20.0, 12.0)},
            {'law': 'pd_gravity', 'kp': (600.0, 300.0), 'kd': (60.0, 25.0)},
            {'law': 'pid', 'kp': (600.0, 300.0), 'kd': (60.0, 25.0), 'ki': (300.0, 150.0)},
            {'law': 'pd', 'kp': (600.0, 300.0), 'kd': (60.0, 25.0)})


def scenarios(count: int) -> list[sweep.Scenario]:
    """``count`` scenarios (a multiple of 400) of the workload above."""
    goals = [(sweep.PF[0] + 0.4 * math.cos(a), sweep.PF[1] + 0.4 * math.sin(a))
             for a in np.linspace(0.0, 2.0 * math.pi, 10, endpoint=False)]
    payloads = np.linspace(0.0, 1.0, max(1, count // 400))
    out = []
    for goal in goals:
        for v in VARIANTS:
            for p in payloads:
                for e in np.linspace(-0.2, 0.2, 10):
                    out.append(sweep.Scenario(
                        task='straight_line', start=(sweep.PS[0], sweep.PS[1]), goal=goal,
                        duration=2.0,
                        hold=0.0, control_rate=1000.0, physics_step=0.001,
                        feasibility='ignore', payload=float(p), mass_error=float(e), **v))
    return out


def real_arm_cost(count: int = 400, repeats: int = 1) -> None:
    """Print the cost per scenario-step of the real arm next to the ideal one (one process,
    :func:`arm_sim.sweep.run_sweep` with one worker; the same ``count`` scenarios of the
    workload, or of it at 100 Hz, with and without :data:`REAL_ARM`): the least of
    ``repeats`` runs of each, ideal and real alternating (a shared machine's load varies)."""
    from dataclasses import replace

    base = scenarios(400)[:: max(1, 400 // count)][:count]
    print(f'\nthe real arm vs the ideal arm ({len(base)} scenarios, 1 worker, best of '
          f'{repeats}; target < {TARGET_REAL:g}x; load average {os.getloadavg()[0]:.2f} on '
          f'{os.cpu_count()} cores):')
    for rate, label in ((1000.0, '1 kHz, 1 physics step per period'),
                        (100.0, '100 Hz, 10 physics steps per period')):
        cost: dict[str, float] = {}
        for _ in range(repeats):
            for name, extra in (('ideal', {}), ('real', REAL_ARM)):
                work = [replace(s, control_rate=rate, **extra) for s in base]
                started = time.perf_counter()
                rows = sweep.run_sweep(work, workers=1)
                took = (time.perf_counter() - started) / steps(rows)
                cost[name] = min(cost.get(name, math.inf), took)
        ratio = cost['real'] / cost['ideal']
        print(f'  {label}: ideal {cost["ideal"] * 1e6:.2f} us, real arm '
              f'{cost["real"] * 1e6:.2f} us per scenario-step: {ratio:.2f}x '
              f'({"met" if ratio < TARGET_REAL else "NOT met"})', flush=True)
    print(f'  load average at the end {os.getloadavg()[0]:.2f}')


def steps(rows) -> int:
    """Scenario-steps simulated: control periods of every scenario that ran."""
    return sum(int(r['samples']) - 1 for r in rows if r['status'] != 'refused')


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='2,000 scenarios, 50 peer runs')
    ap.add_argument('--workers', type=int, default=2, help='worker processes (default 2)')
    ap.add_argument('--real-arm-only', action='store_true',
                    help='only the real arm vs the ideal arm (part 4)')
    ap.add_argument('--peers', type=int, default=None,
                    help='scenarios run one by one through simulate() (default 300)')
    ap.add_argument('--repeats', type=int, default=1,
                    help='part 4: the best of this many runs of each (default 1)')
    args = ap.parse_args()
    if args.real_arm_only:
        real_arm_cost(200 if args.quick else 400, max(1, args.repeats))
        return 0
    count = 2000 if args.quick else 10_000
    peers = args.peers or (50 if args.quick else 300)
    work = scenarios(count)
    print(f'[bench] {len(work)} scenarios, 2 s lines at 1 kHz; load average '
          f'{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores', flush=True)

    started = time.perf_counter()
    bar = sweep.Progress(len(work))
    rows = sweep.run_sweep(work, workers=args.workers, progress=bar.add)
    wall = time.perf_counter() - started
    rate = steps(rows) / wall
    status = {k: sum(r['status'] == k for r in rows) for k in sweep.STATUSES}

    subset = work[:: max(1, len(work) // 2000)][:2000]
    started = time.perf_counter()
    one = sweep.run_sweep(subset, workers=1)
    one_rate = steps(one) / (time.perf_counter() - started)

    picks = work[:: max(1, len(work) // peers)][:peers]
    started = time.perf_counter()
    single = [sweep.run_single(i, s) for i, s in enumerate(picks)]
    single_wall = time.perf_counter() - started
    single_rate = steps(single) / single_wall
    extrapolated = single_wall * len(work) / len(picks)
    load = os.getloadavg()[0]

    print(f'\nsweep of {len(work)} scenarios ({status}):')
    print(f'  {args.workers} workers: {wall:.2f} s wall (target <= {TARGET_WALL:g} s for '
          f'10,000: {"met" if wall <= TARGET_WALL or count < 10_000 else "NOT met"}), '
          f'{rate / 1e6:.2f} M scenario-steps/s')
    print(f'  1 worker ({len(subset)} of them): {one_rate / 1e6:.2f} M scenario-steps/s')
    print(f'peer, one simulate() per scenario ({len(picks)} of them): {single_wall:.2f} s, '
          f'{single_rate / 1e3:.1f} k scenario-steps/s; {len(work)} would take '
          f'{extrapolated:.0f} s')
    print(f'ratios: sweep / peer {rate / single_rate:.0f}x (target >= {TARGET_RATIO:g}x: '
          f'{"met" if rate / single_rate >= TARGET_RATIO else "NOT met"}); per core '
          f'{one_rate / single_rate:.0f}x; parallel speed-up {rate / one_rate:.2f}x')
    real_arm_cost(200 if args.quick else 400, max(1, args.repeats))
    print(f'load average at the end {load:.2f}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
