"""FollowJointTrajectory goals as joint_trajectory_controller executes them (no rclpy).

What the ``controller`` node's ``arm_controller/follow_joint_trajectory`` action server
decides, free of ROS: the node converts the messages and calls this module.

* :func:`accept_goal` checks a goal and makes its trajectory the controller's reference
  (:meth:`arm_control.core.ControllerCore.set_trajectory`), or raises :class:`GoalError`
  with the ``control_msgs`` result code and the reason: ``INVALID_JOINTS`` (unknown,
  missing or repeated joint names), ``OLD_HEADER_TIMESTAMP`` (a non-zero header stamp with
  which the trajectory ends before the current state), ``INVALID_GOAL`` (anything else:
  no points, sizes, times, non-finite values, joint limits, bad tolerances).
* :func:`default_tolerances` builds the tolerances from the ``constraints.*`` parameters;
  :func:`goal_tolerances` lays a goal's own over them (joint_trajectory_controller's rule
  for each value: > 0 replaces the default, 0 keeps it, -1 erases it, other negatives are
  refused).
* :class:`GoalMonitor` checks each state the controller answers: the path tolerance while
  the trajectory runs (``PATH_TOLERANCE_VIOLATED``), then the goal tolerance from its end
  on: inside it the goal succeeds (``SUCCESSFUL``); still outside ``goal_time`` s after the
  end it aborts (``GOAL_TOLERANCE_VIOLATED``; ``goal_time`` 0 = wait without limit).

Errors are desired - actual, as joint_trajectory_controller computes them. A tolerance of
0 is not checked. Accelerations are not measured (``joint_states`` carry none), so
acceleration tolerances are accepted and not checked.

Reference: ros2_controllers' joint_trajectory_controller (``tolerances.hpp``,
``validate_trajectory_msg``, the action callbacks), control_msgs' FollowJointTrajectory.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from arm_control.core import ControllerCore
from arm_control.trajectory import (
    JointNamesError,
    StaleTrajectoryError,
    Trajectory,
    TrajectoryError,
    TrajectoryPoint,
)

# control_msgs/action/FollowJointTrajectory result codes (test_follow_joint_trajectory
# checks them against the message's constants).
SUCCESSFUL = 0
INVALID_GOAL = -1
INVALID_JOINTS = -2
OLD_HEADER_TIMESTAMP = -3
PATH_TOLERANCE_VIOLATED = -4
GOAL_TOLERANCE_VIOLATED = -5

CODE_NAMES = {SUCCESSFUL: 'SUCCESSFUL', INVALID_GOAL: 'INVALID_GOAL',
              INVALID_JOINTS: 'INVALID_JOINTS', OLD_HEADER_TIMESTAMP: 'OLD_HEADER_TIMESTAMP',
              PATH_TOLERANCE_VIOLATED: 'PATH_TOLERANCE_VIOLATED',
              GOAL_TOLERANCE_VIOLATED: 'GOAL_TOLERANCE_VIOLATED'}

ERASE = -1.0  # a goal's tolerance value that removes the default (no check)


class GoalError(ValueError):
    """A goal refused: ``code`` is its result code, the message the error string."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class JointTolerance:
    """One entry of a goal's ``path_tolerance`` or ``goal_tolerance`` (as the message:
    rad, rad/s, rad/s^2; 0 = the default, -1 = no check)."""

    name: str
    position: float = 0.0
    velocity: float = 0.0
    acceleration: float = 0.0


@dataclass(frozen=True)
class StateTolerance:
    """Per-joint bounds on |desired - actual|, in the controller's joint order: position
    [rad], velocity [rad/s], acceleration [rad/s^2]; 0 = not checked."""

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray

    @classmethod
    def none(cls, n: int) -> StateTolerance:
        return cls(np.zeros(n), np.zeros(n), np.zeros(n))


@dataclass(frozen=True)
class Tolerances:
    """What a goal is held to: ``path`` while its trajectory runs, ``goal`` from its end
    on, reached within ``goal_time`` [s] after the end (0 = no limit)."""

    path: StateTolerance
    goal: StateTolerance
    goal_time: float


def default_tolerances(trajectory: Sequence[float], goal: Sequence[float],
                       goal_time: float, stopped_velocity: float) -> Tolerances:
    """The tolerances of a goal that gives none, from the ``constraints.*`` parameters:
    ``trajectory`` and ``goal`` per joint [rad], ``goal_time`` [s] and
    ``stopped_velocity`` [rad/s] (the goal velocity tolerance of every joint), as
    joint_trajectory_controller's ``constraints.<joint>.trajectory``, ``.goal``,
    ``constraints.goal_time`` and ``constraints.stopped_velocity_tolerance``."""
    path = np.array(trajectory, dtype=float)
    end = np.array(goal, dtype=float)
    if path.shape != end.shape:
        raise ValueError(f'constraints.trajectory has {len(path)} values but '
                         f'constraints.goal has {len(end)}')
    n = len(path)
    return Tolerances(StateTolerance(path, np.zeros(n), np.zeros(n)),
                      StateTolerance(end, np.full(n, float(stopped_velocity)), np.zeros(n)),
                      float(goal_time))


def _resolve(default: float, given: float, what: str) -> float:
    """joint_trajectory_controller's ``resolve_tolerance_source``: > 0 given, 0 the
    default, -1 erased (0: no check); other negatives refused."""
    if not np.isfinite(given):
        raise GoalError(INVALID_GOAL, f'{what} must be finite, got {given!r}')
    if given > 0:
        return float(given)
    if given == 0:
        return default
    if given == ERASE:
        return 0.0
    raise GoalError(INVALID_GOAL, f'{what} must be > 0, 0 (the default) or -1 (no check), '
                                  f'got {given!r}')


def _lay_over(base: StateTolerance, given: Sequence[JointTolerance],
              joint_names: Sequence[str], field: str) -> StateTolerance:
    pos, vel, acc = base.position.copy(), base.velocity.copy(), base.acceleration.copy()
    for tol in given:
        if tol.name not in joint_names:
            raise GoalError(INVALID_GOAL, f'{field} names joint {tol.name!r}, which this '
                                          f'controller does not have ({list(joint_names)})')
        j = list(joint_names).index(tol.name)
        pos[j] = _resolve(pos[j], tol.position, f'{field} position of {tol.name} [rad]')
        vel[j] = _resolve(vel[j], tol.velocity, f'{field} velocity of {tol.name} [rad/s]')
        acc[j] = _resolve(acc[j], tol.acceleration,
                          f'{field} acceleration of {tol.name} [rad/s^2]')
    return StateTolerance(pos, vel, acc)


def goal_tolerances(defaults: Tolerances, joint_names: Sequence[str],
                    path: Sequence[JointTolerance] = (), goal: Sequence[JointTolerance] = (),
                    goal_time: float = 0.0) -> Tolerances:
    """A goal's tolerances (``path_tolerance``, ``goal_tolerance``, ``goal_time_tolerance``
    [s]) laid over ``defaults``; ``joint_names`` are the controller's. Raises GoalError
    (INVALID_GOAL) for a joint the controller does not have or an illegal value (where
    joint_trajectory_controller logs it and keeps every default: a goal should not run
    held to tolerances other than those it asked for)."""
    return Tolerances(_lay_over(defaults.path, path, joint_names, 'path_tolerance'),
                      _lay_over(defaults.goal, goal, joint_names, 'goal_tolerance'),
                      _resolve(defaults.goal_time, goal_time, 'goal_time_tolerance [s]'))


def error_code(exc: TrajectoryError) -> int:
    """The result code for a trajectory :meth:`ControllerCore.set_trajectory` refused."""
    if isinstance(exc, JointNamesError):
        return INVALID_JOINTS
    if isinstance(exc, StaleTrajectoryError):
        return OLD_HEADER_TIMESTAMP
    return INVALID_GOAL


def check_goal(core: ControllerCore, joint_names: Sequence[str],
               points: Sequence[TrajectoryPoint], defaults: Tolerances, *,
               path: Sequence[JointTolerance] = (), goal: Sequence[JointTolerance] = (),
               goal_time: float = 0.0, multi_dof_joints: Sequence[str] = ()) -> Tolerances:
    """Everything about a goal that needs no measured state (so a goal that comes before
    the first joint state gets the same answer as one after it): multi-DOF joints, the
    tolerances, the joint names (INVALID_JOINTS), the points and the joint limits
    (INVALID_GOAL). Returns the goal's tolerances; raises GoalError with the result code
    and the bad value. Only the start time needs the state (:func:`accept_goal`)."""
    if multi_dof_joints:
        raise GoalError(INVALID_GOAL, f'multi_dof_trajectory names joints '
                                      f'{list(multi_dof_joints)}; this controller has only '
                                      f'single-DOF joints {list(core.joint_names)}')
    tolerances = goal_tolerances(defaults, core.joint_names, path, goal, goal_time)
    try:
        core.check_trajectory(joint_names, points)
    except TrajectoryError as exc:
        raise GoalError(error_code(exc), str(exc)) from None
    return tolerances


@dataclass(frozen=True)
class Accepted:
    """A goal made the reference: its trajectory, start [s, sim time] and tolerances."""

    trajectory: Trajectory
    start: float
    tolerances: Tolerances


def accept_goal(core: ControllerCore, joint_names: Sequence[str],
                points: Sequence[TrajectoryPoint], stamp: float, now: float,
                q: np.ndarray, qd: np.ndarray, defaults: Tolerances, *,
                path: Sequence[JointTolerance] = (), goal: Sequence[JointTolerance] = (),
                goal_time: float = 0.0, multi_dof_joints: Sequence[str] = ()) -> Accepted:
    """Check a goal and make its trajectory ``core``'s reference, starting at ``stamp`` [s,
    sim time; 0 = now] from the measured state (q, qd) at simulated time ``now`` [s].
    Raises GoalError (the reference kept) with the result code and the reason."""
    tolerances = check_goal(core, joint_names, points, defaults, path=path, goal=goal,
                            goal_time=goal_time, multi_dof_joints=multi_dof_joints)
    start = stamp or now
    try:
        traj = core.set_trajectory(joint_names, points, start, q, qd, now=now)
    except TrajectoryError as exc:
        raise GoalError(error_code(exc), str(exc)) from None
    return Accepted(traj, start, tolerances)


@dataclass(frozen=True)
class Outcome:
    """How a goal ended: its result code and error string; ``succeeded`` for SUCCESSFUL."""

    code: int
    text: str

    @property
    def succeeded(self) -> bool:
        return self.code == SUCCESSFUL


def _violations(tol: StateTolerance, joint_names: Sequence[str], e_q: np.ndarray,
                e_qd: np.ndarray) -> list[str]:
    found = []
    for j, name in enumerate(joint_names):
        for what, err, bound, unit in (('position', e_q[j], tol.position[j], 'rad'),
                                       ('velocity', e_qd[j], tol.velocity[j], 'rad/s')):
            if bound > 0 and abs(err) > bound:
                found.append(f'{name} {what} error {err:.6g} {unit} (tolerance '
                             f'{bound:g} {unit})')
    return found


class GoalMonitor:
    """Decides, state by state, whether a goal goes on, succeeded or failed.

    Parameters
    ----------
    joint_names : the controller's joints, in its order.
    tolerances : the goal's (:func:`goal_tolerances`).
    start : s, simulated -- the trajectory's start time.
    duration : s -- its last point's ``time_from_start``.
    """

    def __init__(self, joint_names: Sequence[str], tolerances: Tolerances, start: float,
                 duration: float) -> None:
        self.joint_names = tuple(joint_names)
        self.tolerances = tolerances
        self.start = start
        self.end = start + duration

    def check(self, t: float, q: np.ndarray, qd: np.ndarray, q_des: np.ndarray,
              qd_des: np.ndarray) -> Outcome | None:
        """The goal's outcome at the state (q, qd) measured at ``t`` [s], tracked against
        the reference (q_des, qd_des) the controller used for it; None: it goes on. Call it
        only for states the goal's trajectory was the reference of (after its start)."""
        e_q = np.asarray(q_des, dtype=float) - np.asarray(q, dtype=float)
        e_qd = np.asarray(qd_des, dtype=float) - np.asarray(qd, dtype=float)
        tol = self.tolerances
        if t < self.end:
            bad = _violations(tol.path, self.joint_names, e_q, e_qd)
            if bad:
                return Outcome(PATH_TOLERANCE_VIOLATED,
                               f'path tolerance violated at t={t:.3f} s ('
                               f'{t - self.start:.3f} s into the trajectory): '
                               + '; '.join(bad))
            return None
        bad = _violations(tol.goal, self.joint_names, e_q, e_qd)
        late = t - self.end
        if not bad:
            return Outcome(SUCCESSFUL, f'goal reached at t={t:.3f} s ({late:.3f} s after '
                                       f'the trajectory ended), position errors '
                                       f'{np.round(e_q, 6).tolist()} rad')
        if tol.goal_time > 0 and late > tol.goal_time:
            return Outcome(GOAL_TOLERANCE_VIOLATED,
                           f'goal tolerance still violated at t={t:.3f} s, {late:.3f} s '
                           f'after the trajectory ended (goal_time_tolerance '
                           f'{tol.goal_time:g} s): ' + '; '.join(bad))
        return None
