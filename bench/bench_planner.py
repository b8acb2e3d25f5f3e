"""Benchmark: the planner's worst cases against its everyday plan, in one process.

Every plan is bounded (``arm_planner.planner``: at most ``MAX_DURATION`` s, ``MAX_POINTS``
points, ``MAX_VERIFY_SAMPLES`` verification samples held ``VERIFY_CHUNK`` at a time). This
times each case (best of ``--repeats``) and measures the peak memory it allocates
(tracemalloc, numpy arrays included), printed with the ratio to the demo's everyday plan
(a 0.5 m/s straight line). Refused cases are timed up to their refusal. Run:
``python bench/bench_planner.py``.
"""

from __future__ import annotations

import argparse
import time
import tracemalloc

import numpy as np

from arm_dynamics.robot import ROBOT_DEFAULTS
from arm_planner import PlannerSettings, PlanningError, plan_goal
from arm_planner.planner import MAX_DURATION, make_arm

ROBOT = ROBOT_DEFAULTS
Q0 = np.array([-0.4, 1.2])
GOAL = np.array([0.5, 1.0])

CASES = [  # (label, settings); the first is the reference
    ('everyday: straight line at 0.5 m/s', PlannerSettings(mode='straight_line')),
    (f'straight line of {MAX_DURATION:g} s (the longest)',
     PlannerSettings(mode='straight_line', duration=MAX_DURATION)),
    (f'synchronized regulation of {MAX_DURATION:g} s',
     PlannerSettings(mode='regulation', regulation_profile='synchronized',
                     duration=MAX_DURATION)),
    ('straight line, tolerance 1e-9 m (finest sampling)',
     PlannerSettings(mode='straight_line', line_tolerance=1e-9)),
    ('max_speed 1e-6 m/s (refused)', PlannerSettings(mode='straight_line', max_speed=1e-6)),
    ('joint_max_acceleration 1e-300 rad/s^2 (refused)',
     PlannerSettings(mode='regulation', regulation_profile='synchronized',
                     joint_max_acceleration=1e-300)),
]


def run(settings: PlannerSettings) -> tuple[str, int]:
    arm = make_arm(ROBOT)
    try:
        plan = plan_goal(arm, np.array(ROBOT['effort_limits']), Q0, GOAL, settings)
    except PlanningError as exc:
        return f'refused: {str(exc)[:60]}...', 0
    return f'{plan.duration:.3f} s', len(plan.times)


def measure(settings: PlannerSettings, repeats: int) -> tuple[float, float, str, int]:
    best = float('inf')
    for _ in range(repeats):
        start = time.perf_counter()
        outcome, points = run(settings)
        best = min(best, time.perf_counter() - start)
    tracemalloc.start()
    run(settings)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return best, peak / 2**20, outcome, points


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=5, help='timed runs per case (best)')
    args = parser.parse_args()
    run(CASES[0][1])  # warm-up: imports and first-call costs
    rows = []
    for i, (label, settings) in enumerate(CASES, 1):
        print(f'[bench] {i}/{len(CASES)} {label}', flush=True)
        rows.append((label, *measure(settings, args.repeats)))
    ref_time, ref_mem = rows[0][1], rows[0][2]
    print(f"\n{'case':50} {'time':>9} {'x ref':>7} {'peak MiB':>9} {'x ref':>7} "
          f"{'points':>7}  outcome")
    for label, t, mem, outcome, points in rows:
        print(f'{label:50} {t * 1e3:7.1f}ms {t / ref_time:7.1f} {mem:9.1f} '
              f'{mem / ref_mem:7.1f} {points:7d}  {outcome}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
