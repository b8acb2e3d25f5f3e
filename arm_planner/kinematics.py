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


#: Numeric inverse kinematics: tip tolerance [m] and iteration cap.
IK_TOLERANCE = 1e-10
IK_ITERATIONS = 200


def solve_ik(arm, p, q_start, reach_margin: float = 0.0, what: str = 'goal') -> np.ndarray:
    """Joint angles putting the tip of any planar chain at ``p``, nearest ``q_start``.

    For models without closed-form inverse kinematics (``planar_chain``): damped least
    squares (Levenberg-Marquardt) on the tip position from ``q_start``, so a redundant arm
    takes a solution reached by the smallest joint motion the iteration finds. Refuses a
    point beyond the reach (the sum of the link lengths, less ``reach_margin``) and one the
    iteration cannot reach to ``IK_TOLERANCE`` (inside the inner hole of the workspace, or
    at a singularity), with the numbers.

    Parameters
    ----------
    arm : a :class:`~arm_dynamics.models.RobotModel` (``forward_kinematics``, ``jacobian``).
    p : (2,) m; q_start : (n,) rad.

    Returns
    -------
    (n,) rad, with ``|forward_kinematics(q) - p| <= IK_TOLERANCE``.

    References: Buss, *Introduction to Inverse Kinematics with Jacobian Transpose,
    Pseudoinverse and Damped Least Squares methods* (2004), §5; Siciliano et al. (2009),
    §3.7.
    """
    p = np.asarray(p, dtype=float)
    if p.shape != (2,) or not np.isfinite(p).all():
        raise PlanningError(f'{what} must be two finite numbers (x, y) in m, got '
                            f'{p.ravel().tolist()}')
    reach = float(np.sum(arm.link_lengths)) - reach_margin
    r = float(np.hypot(*p))
    where = f'{what} ({p[0]:.4f}, {p[1]:.4f}) m'
    if r > reach:
        raise PlanningError(f'{where} is out of reach: r = {r:.4f} m > the sum of the link '
                            f'lengths less reach_margin = {reach:.4f} m')
    q = np.asarray(q_start, dtype=float).copy()
    damping = 1e-3
    err = p - arm.forward_kinematics(q)
    for _ in range(IK_ITERATIONS):
        if np.hypot(*err) <= IK_TOLERANCE:
            return q
        jac = arm.jacobian(q)
        step = jac.T @ np.linalg.solve(jac @ jac.T + damping**2 * np.eye(2), err)
        trial = q + step
        trial_err = p - arm.forward_kinematics(trial)
        if np.hypot(*trial_err) < np.hypot(*err):
            q, err, damping = trial, trial_err, max(damping * 0.5, 1e-9)
        else:
            damping *= 4.0
    raise PlanningError(f'{where} cannot be reached: the nearest tip position found is '
                        f'{float(np.hypot(*err)):.3g} m away (inside the inner hole of the '
                        'workspace, or at a singularity)')

