#!/usr/bin/env python3
"""Cost of Coulomb + static joint friction per physics step, next to the ideal step.

One process, no ROS: lockstep control loops as the simulator core runs them (1 ms RK4
physics steps, 10 ms control periods, the command of each period computed from the state),
stepped once ideal and once through :func:`arm_dynamics.friction.friction_step`, for the
2-R arm's defaults (:class:`~arm_dynamics.two_link.TwoLinkArm`) and a 3-link
:class:`~arm_dynamics.planar_chain.PlanarChain`. The scenarios put the friction in each of
its modes:

* ``ramp``: PD + gravity tracking a ramp at constant speed: every joint slipping, no event
  (one ``model.step`` under ``tau - c sign(qd)`` and a sign check per step);
* ``track``: tracking a slow sinusoid: mostly slipping, with stick/slip events at the
  reversals (a real arm's everyday case);
* ``hold``: PD + gravity holding a pose it starts at: every joint stuck;
* ``mixed``: joint 1 held by a large static friction while joint 2 swings: a stuck joint
  among moving ones (the constrained RK4 step);
* ``off``: friction disabled through ``friction_step`` (the wrapper's cost over
  ``model.step``).

The peers, each the same law and scenario with ideal physics: ``model.step`` once per
physics step (what the core does with hard stops, the fair comparison: friction needs the
state after every step), and ``model.step(..., 10)`` once per period (what the core does
otherwise). Each figure is the median over interleaved repeats of the wall time per physics
step [us] (the law included, 1/10 of it per step); the ratios are to the peers; the mode
columns say what share of the steps had a stuck joint, how many events (stick, break-away,
reversal) the run saw. No asserts. Run from the repo root::

    .venv/bin/python bench/bench_friction.py           # ~30 s
    .venv/bin/python bench/bench_friction.py --quick   # ~5 s
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from collections.abc import Callable

import numpy as np

try:
    from arm_dynamics import TwoLinkArm
except ImportError:  # run as `python bench/bench_friction.py` without PYTHONPATH
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from arm_dynamics import TwoLinkArm
from arm_dynamics.friction import JointFriction, friction_step
from arm_dynamics.planar_chain import PlanarChain

DT, SUBSTEPS = 1e-3, 10
ARM = TwoLinkArm()
CHAIN = PlanarChain(link_lengths=(1.0, 0.8, 0.6), com_distances=(0.5, 0.4, 0.3),
                    link_masses=(2.0, 1.5, 1.0), link_inertias=(0.1, 0.08, 0.05))
Law = Callable[[float, np.ndarray, np.ndarray], np.ndarray]


def pd_law(model, target: Callable[[float], tuple[np.ndarray, np.ndarray]],
           kp: np.ndarray, kd: np.ndarray) -> Law:
    def law(t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        r, rd = target(t)
        return kp * (r - q) + kd * (rd - qd) + model.gravity_vector(q)
    return law


def scenarios(model) -> dict[str, tuple[JointFriction, np.ndarray, np.ndarray, Law]]:
    """name -> (friction, q0, qd0, law) for ``model`` (2 or 3 joints)."""
    n = model.n_dof
    q0 = np.array([-0.4, 1.2, -0.5][:n])
    real = JointFriction(coulomb=[2.0, 1.0, 0.5][:n], static=[3.0, 1.5, 0.8][:n])
    speed = np.array([0.4, -0.3, 0.2][:n])
    amp = np.array([0.3, 0.2, 0.1][:n])
    w = 2.0 * math.pi * 0.5
    kp, kd = np.array([100.0, 60.0, 30.0][:n]), np.array([20.0, 10.0, 5.0][:n])
    # joint 1 in a large static friction, the others free to swing under gravity alone
    strong = JointFriction(coulomb=[40.0] + [0.1] * (n - 1), static=[80.0] + [0.2] * (n - 1))
    g0 = model.gravity_vector(q0) * np.array([1.0] + [0.0] * (n - 1))
    rest = np.zeros(n)

    def sine(t: float) -> tuple[np.ndarray, np.ndarray]:
        return q0 + amp * math.sin(w * t), amp * w * math.cos(w * t)

    return {
        'ramp': (real, q0, speed, pd_law(model, lambda t: (q0 + speed * t, speed), kp, kd)),
        'track': (real, q0, rest, pd_law(model, sine, kp, kd)),
        'hold': (real, q0, rest, pd_law(model, lambda t: (q0, rest), kp, kd)),
        'mixed': (strong, q0, rest, lambda t, q, qd: g0),
        'off': (JointFriction.none(n), q0, rest, pd_law(model, sine, kp, kd)),
    }


def run(model, friction: JointFriction, q0: np.ndarray, qd0: np.ndarray, law: Law,
        periods: int, how: str) -> float:
    """Wall seconds per physics step of a lockstep loop: ``how`` is ``'ideal'``
    (``model.step`` per physics step), ``'ideal x10'`` (per period) or ``'friction'``."""
    n = model.n_dof
    q, qd = q0.copy(), qd0.copy()
    stuck = np.zeros(n, dtype=bool)
    start = time.perf_counter()
    if how == 'ideal':
        for k in range(periods):
            tau = law(k * SUBSTEPS * DT, q, qd)
            for _ in range(SUBSTEPS):
                q, qd = model.step(q, qd, tau, DT, 1)
    elif how == 'ideal x10':
        for k in range(periods):
            tau = law(k * SUBSTEPS * DT, q, qd)
            q, qd = model.step(q, qd, tau, DT, SUBSTEPS)
    else:
        for k in range(periods):
            tau = law(k * SUBSTEPS * DT, q, qd)
            for _ in range(SUBSTEPS):
                q, qd, stuck, _ = friction_step(model, q, qd, tau, DT, stuck, friction)
    return (time.perf_counter() - start) / (periods * SUBSTEPS)


def modes(model, friction: JointFriction, q0: np.ndarray, qd0: np.ndarray, law: Law,
          periods: int) -> tuple[int, int]:
    """The friction loop of :func:`run`, untimed: (steps ending with a joint stuck, events:
    stuck flags changing and velocity reversals)."""
    n = model.n_dof
    q, qd = q0.copy(), qd0.copy()
    stuck = np.zeros(n, dtype=bool)
    held = events = 0
    for k in range(periods):
        tau = law(k * SUBSTEPS * DT, q, qd)
        for _ in range(SUBSTEPS):
            before, sign = stuck, np.sign(qd)
            q, qd, stuck, _ = friction_step(model, q, qd, tau, DT, stuck, friction)
            held += bool(stuck.any())
            events += int((stuck != before).sum() + (np.sign(qd) * sign < 0).sum())
    return held, events


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true', help='fewer, shorter repeats')
    args = parser.parse_args(argv)
    periods, repeats = (100, 3) if args.quick else (300, 7)
    for model, name, scale in ((ARM, 'TwoLinkArm (defaults)', 1), (CHAIN, 'PlanarChain, 3 links',
                                                                  10)):
        cases = scenarios(model)
        p = max(10, periods // scale)
        times: dict[tuple[str, str], list[float]] = {}
        seen = {label: modes(model, *case, p) for label, case in cases.items()}
        for fr, q0, qd0, law in cases.values():   # warm-up
            for how in ('ideal', 'ideal x10', 'friction'):
                run(model, fr, q0, qd0, law, 5, how)
        for _ in range(repeats):
            for label, (fr, q0, qd0, law) in cases.items():
                for how in ('ideal', 'ideal x10', 'friction'):
                    times.setdefault((label, how), []).append(
                        run(model, fr, q0, qd0, law, p, how))
        print(f'{name}: lockstep loop, {p} periods x {SUBSTEPS} RK4 steps of 1 ms, median '
              f'of {repeats} (us per physics step, law included)')
        print(f"{'scenario':<8} {'ideal':>8} {'ideal x10':>9} {'friction':>9} "
              f"{'x ideal':>7} {'x ideal x10':>11} {'stuck %':>7} {'events':>6}")
        for label in cases:
            ideal, ideal10, fric = (statistics.median(times[(label, how)])
                                    for how in ('ideal', 'ideal x10', 'friction'))
            held, events = seen[label]
            print(f'{label:<8} {ideal * 1e6:8.1f} {ideal10 * 1e6:9.1f} {fric * 1e6:9.1f} '
                  f'{fric / ideal:7.2f} {fric / ideal10:11.2f} '
                  f'{100.0 * held / (p * SUBSTEPS):7.1f} {events:6d}')
        print()
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
