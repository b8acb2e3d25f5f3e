"""The controller's state machine, free of ROS: what the ``controller`` node calls.

:class:`ControllerCore` keeps the active reference (a :class:`~arm_control.trajectory.
Trajectory` and its start time in simulated seconds), holds the first measured position
until a trajectory arrives, replaces the reference when a valid trajectory comes (an
invalid one is refused and the current reference kept) and evaluates the control law.

Time jumps: when the measured state's simulated time goes backwards (a restarted simulator,
a bag replayed), leaps forward by more than ``jump_threshold``, or the state moves further
in one step than its velocities allow (a reset), the reference is dropped and the measured
position held; :attr:`Step.jump` says why. A repeated stamp (a re-sent state) is not a jump.

A new trajectory takes over from the first state *after* its start time: the state at the
start time itself (and any earlier one) is still answered with the previous reference, as
joint_trajectory_controller executes the old trajectory until a new one's start. So the
command answering a state never depends on whether that state or the trajectory reached
the controller first: a trajectory planned from a held state (stamped with it) gives the
same motion however the messages raced.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from arm_control.laws import Command, ControlLaw
from arm_control.trajectory import (
    StaleTrajectoryError,
    Trajectory,
    TrajectoryError,
    TrajectoryPoint,
    validate_trajectory,
)
from arm_dynamics.limits import JointLimits


@dataclass(frozen=True)
class Step:
    """One control tick's outcome: the command and the reference it tracked."""

    command: Command
    q_des: np.ndarray
    qd_des: np.ndarray
    qdd_des: np.ndarray
    jump: str | None = None  # why the reference was dropped at this step, else None


class ControllerCore:
    """Reference handling plus a control law.

    Parameters
    ----------
    joint_names : the controller's joints, in command order.
    law : the :class:`ControlLaw` to evaluate (replaceable at run time).
    jump_threshold : s > 0 -- a forward step of simulated time longer than this between two
        states is a time jump.
    state_jump_tolerance : rad >= 0 -- a joint moving further between two states than
        ``dt * max(|qd|)`` plus this is a state jump (e.g. a simulator reset).
    """

    def __init__(self, joint_names: Sequence[str], law: ControlLaw, *,
                 jump_threshold: float = 1.0, state_jump_tolerance: float = 0.1,
                 limits: JointLimits | None = None) -> None:
        if not jump_threshold > 0:
            raise ValueError(f'jump_threshold must be > 0 s, got {jump_threshold}')
        if not state_jump_tolerance >= 0:
            raise ValueError(f'state_jump_tolerance must be >= 0 rad, got '
                             f'{state_jump_tolerance}')
        self.joint_names = tuple(joint_names)
        self.law = law
        self.jump_threshold = jump_threshold
        self.state_jump_tolerance = state_jump_tolerance
        self.limits = limits
        self.trajectory: Trajectory | None = None
        self.start = 0.0
        self.next: tuple[Trajectory, float] | None = None  # accepted, from a later state on
        self.last: tuple[float, np.ndarray, np.ndarray] | None = None  # (t, q, qd)
        self.trajectories_accepted = 0
        self.jumps = 0

    @property
    def last_time(self) -> float | None:
        """Simulated time [s] of the last state evaluated."""
        return None if self.last is None else self.last[0]

    @property
    def holding_start(self) -> bool:
        """True until the first trajectory arrives (the first measured position is held)."""
        return self.trajectories_accepted == 0

    def set_trajectory(self, joint_names: Sequence[str], points: Sequence[TrajectoryPoint],
                       start: float, q: np.ndarray, qd: np.ndarray,
                       now: float | None = None) -> Trajectory:
        """Validate and make a trajectory the reference from ``start`` [s, sim time] on,
        starting from the measured state (q, qd) at simulated time ``now`` [s] (default
        ``start``). Raises TrajectoryError (reference kept), also for a trajectory that
        ends before ``now`` (as joint_trajectory_controller refuses one) and for points
        outside the joint limits (position, or the velocity given)."""
        times, pos, vel, acc = self.check_trajectory(joint_names, points)
        now = start if now is None else now
        if start + times[-1] < now:
            raise StaleTrajectoryError(
                f'trajectory ends in the past: it starts at t={start:.3f} s and ends at '
                f't={start + times[-1]:.3f} s, but the state is at t={now:.3f} s')
        traj = Trajectory(q, qd, times, pos, vel, acc)
        if self.trajectory is None:
            self.trajectory, self.start = traj, start
        else:
            self.next = (traj, start)  # takes over at the first state after ``start``
        self.trajectories_accepted += 1
        return traj

    def check_trajectory(self, joint_names: Sequence[str],
                         points: Sequence[TrajectoryPoint]) -> tuple[
                             np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Everything about a trajectory that needs no measured state: its joint names,
        points and the joint limits. Returns :func:`validate_trajectory`'s arrays in this
        controller's joint order; raises TrajectoryError (:class:`JointNamesError` for the
        names) naming the bad value."""
        times, pos, vel, acc = validate_trajectory(joint_names, points, self.joint_names)
        if self.limits is not None:
            outside = (self.limits.position_violation(pos)
                       or (vel is not None and self.limits.velocity_violation(vel)))
            if outside:
                raise TrajectoryError(f'trajectory leaves the joint limits: {outside}')
        return times, pos, vel, acc

    def hold(self, t: float, q: np.ndarray, qd: np.ndarray) -> None:
        """Drop the reference (and one waiting to take over) and hold position ``q`` from
        ``t`` [s] on."""
        self.trajectory = Trajectory(q, qd, np.zeros(1), np.array([q], dtype=float))
        self.start = t
        self.next = None

    def jump_reason(self, t: float, q: np.ndarray, qd: np.ndarray) -> str | None:
        """Why the state at ``t`` [s] does not continue the last one, or None."""
        if self.last is None:
            return None
        t0, q0, qd0 = self.last
        if t < t0:
            return f'simulated time went back from {t0:.3f} s to {t:.3f} s'
        dt = t - t0
        if dt > self.jump_threshold:
            return (f'simulated time jumped from {t0:.3f} s to {t:.3f} s (more than '
                    f'{self.jump_threshold:g} s)')
        moved = np.abs(q - q0)
        reach = dt * np.maximum(np.abs(qd0), np.abs(qd)) + self.state_jump_tolerance
        if (moved > reach).any():
            return (f'the state jumped at t={t:.3f} s: joints moved {moved.round(4).tolist()}'
                    f' rad in {dt:.3f} s, more than their velocities allow')
        return None

    def update(self, t: float, q: np.ndarray, qd: np.ndarray) -> Step:
        """The command for state (q, qd) measured at simulated time ``t`` [s]."""
        jump = self.jump_reason(t, q, qd)
        if self.trajectory is None:  # first state: hold where the arm is
            self.hold(t, q, qd)
        elif jump:
            self.jumps += 1
            self.hold(t, q, qd)
            self.law.reset()
        elif self.next is not None and t > self.next[1]:
            (self.trajectory, self.start), self.next = self.next, None
        dt = 0.0 if self.last is None or jump else max(t - self.last[0], 0.0)
        self.last = (t, np.array(q, dtype=float), np.array(qd, dtype=float))
        assert self.trajectory is not None  # hold() set one if there was none
        q_des, qd_des, qdd_des = self.trajectory.sample(t - self.start)
        return Step(self.law(q, qd, q_des, qd_des, qdd_des, dt), q_des, qd_des, qdd_des,
                    jump)
