"""Planning a sweep's scenario: the plan the controller would track, or why there is none.

Pure: no rclpy. The planner's :func:`~arm_planner.planner.plan_goal` on the robot (its
motors included) without payload or model errors, as the planner node plans it; knot
times rounded to whole ns, as the controller receives them.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from arm_control.trajectory import Trajectory
from arm_dynamics.limits import JointLimits
from arm_planner.kinematics import PlanningError
from arm_planner.planner import PlannerSettings, plan_goal
from arm_sim.sweep.spec import ROBOT, Scenario, robot_with_motors

FASTEST_REQUEST = 1e-3    # s: asked of the planner for 'fastest' (stretched to fit)
IGNORE_LIMITS = (1e9, 1e9)  # N m: the planner's limits under feasibility 'ignore'


@dataclass(frozen=True)
class Planned:
    """A scenario's plan as the controller tracks it, or why there is none."""

    trajectory: Trajectory | None
    q_start: np.ndarray
    set_point: np.ndarray | None = None   # (2,) rad, the plan's last point
    line: tuple[np.ndarray, np.ndarray] | None = None  # path's first and last pose, m
    duration: float = 0.0
    peak_torque: np.ndarray | None = None
    refused: str | None = None


@functools.lru_cache(maxsize=4096)
def _plan(task: str, start: tuple[float, float], goal: tuple[float, float], elbow: str,
          duration: float | str, time_scaling: str, profile: str, feasibility: str,
          limits: tuple[float, float], motors: tuple = ()) -> Planned:
    q_start = ROBOT.inverse_kinematics(np.array(start), elbow)
    bad = ROBOT.workspace_violation(np.array(start), 0.01, 0.0, 'start')
    if bad:
        return Planned(None, q_start, refused=bad)
    settings = PlannerSettings(
        mode=task, elbow='keep', time_scaling=time_scaling,
        duration=FASTEST_REQUEST if duration == 'fastest' else float(duration),
        regulation_profile=profile,
        feasibility='stretch' if feasibility in ('ignore', 'stretch') else 'refuse')
    try:
        arm = robot_with_motors(*motors) if motors else ROBOT
        plan = plan_goal(arm, IGNORE_LIMITS if feasibility == 'ignore' else limits,
                         q_start, goal, settings, JointLimits())
    except PlanningError as exc:
        return Planned(None, q_start, refused=str(exc))
    # The controller receives knot times as whole ns (builtin_interfaces/Duration).
    ns = np.round(plan.times * 1e9).astype(np.int64)
    sec, nsec = np.divmod(ns, 1_000_000_000)
    times = sec + nsec * 1e-9
    traj = Trajectory(q_start, np.zeros(2), times, plan.q, plan.qd, plan.qdd)
    path = plan.display_path
    line = (path[0], path[-1]) if task == 'straight_line' and len(path) >= 3 else None
    return Planned(traj, q_start, plan.q[-1].copy(), line, float(times[-1]),
                   np.asarray(plan.peak_torque, dtype=float))


def plan_scenario(s: Scenario) -> Planned:
    """The scenario's plan (cached per process: scenarios differing only in control
    settings share it). The planner uses the robot without payload or model errors."""
    return _plan(s.task, s.start, s.goal, s.elbow, s.duration, s.time_scaling,
                 s.regulation_profile, s.feasibility, s.effort_limits)
