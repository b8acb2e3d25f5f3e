"""Planning's side of the arm's kinematics (no rclpy): the refusal error, the goal check and
the whole-turn choice.

The kinematics themselves -- forward kinematics, Jacobian, ``J' q'``, closed-form inverse
kinematics with the elbow choice and the workspace check that names the numbers -- are
methods of the model, :class:`arm_dynamics.two_link.TwoLinkArm` (its module docstring
gives the conventions and the elbow branches); nothing here repeats a formula.
"""

from __future__ import annotations

import numpy as np

from arm_dynamics.two_link import TwoLinkArm


class PlanningError(ValueError):
    """A goal or plan that is refused; the message gives the reason with the numbers."""


def check_point(arm: TwoLinkArm, p, reach_margin: float, singularity_margin: float,
                what: str = 'goal') -> None:
    """Refuse a non-finite, unreachable or near-singular point with the reason.

    Parameters
    ----------
    arm : the planner's model (its link lengths).
    p : (2,), m
    reach_margin : m, >= 0 -- distance kept from both boundaries of the annulus.
    singularity_margin : -, in [0, 1) -- minimum ``|sin q2|``.
    what : name of the point in the message.

    Raises
    ------
    PlanningError
        With :meth:`TwoLinkArm.workspace_violation`'s reason.
    """
    reason = arm.workspace_violation(p, reach_margin, singularity_margin, what)
    if reason is not None:
        raise PlanningError(reason)


def nearest_equivalent(q, reference) -> np.ndarray:
    """``q`` (..., 2) [rad] shifted by whole turns per joint to lie within pi of
    ``reference`` (2,) [rad]: the same pose, the shortest joint motion."""
    q = np.asarray(q, dtype=float)
    ref = np.asarray(reference, dtype=float)
    return q - 2.0 * np.pi * np.round((q - ref) / (2.0 * np.pi))
