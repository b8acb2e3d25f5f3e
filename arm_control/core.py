"""The controller's state machine, free of ROS: what the ``controller`` node calls.

:class:`ControllerCore` keeps the active reference (a :class:`~arm_control.trajectory.
Trajectory` and its start time in simulated seconds), holds the first measured position
until a trajectory arrives, replaces the reference when a valid trajectory comes (an
invalid one is refused and the current reference kept) and evaluates the control law.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from arm_control.laws import Command, ControlLaw
from arm_control.trajectory import Trajectory, TrajectoryPoint, validate_trajectory


@dataclass(frozen=True)
class Step:
    """One control tick's outcome: the command and the reference it tracked."""

    command: Command
    q_des: np.ndarray
    qd_des: np.ndarray
    qdd_des: np.ndarray


class ControllerCore:
    """Reference handling plus a control law.

    Parameters
    ----------
    joint_names : the controller's joints, in command order.
    law : the :class:`ControlLaw` to evaluate (replaceable at run time).
    """

    def __init__(self, joint_names: Sequence[str], law: ControlLaw) -> None:
        self.joint_names = tuple(joint_names)
        self.law = law
        self.trajectory: Trajectory | None = None
        self.start = 0.0
        self.last_time: float | None = None
        self.trajectories_accepted = 0

    @property
    def holding_start(self) -> bool:
        """True until the first trajectory arrives (the first measured position is held)."""
        return self.trajectories_accepted == 0

    def set_trajectory(self, joint_names: Sequence[str], points: Sequence[TrajectoryPoint],
                       start: float, q: np.ndarray, qd: np.ndarray) -> Trajectory:
        """Validate and make a trajectory the reference from ``start`` [s, sim time] on,
        starting from the measured state (q, qd). Raises TrajectoryError (reference kept)."""
        times, pos, vel, acc = validate_trajectory(joint_names, points, self.joint_names)
        self.trajectory = Trajectory(q, qd, times, pos, vel, acc)
        self.start = start
        self.trajectories_accepted += 1
        return self.trajectory

    def update(self, t: float, q: np.ndarray, qd: np.ndarray) -> Step:
        """The command for state (q, qd) measured at simulated time ``t`` [s]."""
        if self.trajectory is None:  # first state: hold where the arm is
            self.trajectory = Trajectory(q, qd, np.zeros(1), np.array([q], dtype=float))
            self.start = t
        dt = 0.0 if self.last_time is None else max(t - self.last_time, 0.0)
        self.last_time = t
        q_des, qd_des, qdd_des = self.trajectory.sample(t - self.start)
        return Step(self.law(q, qd, q_des, qd_des, qdd_des, dt), q_des, qd_des, qdd_des)
