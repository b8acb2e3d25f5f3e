"""Closed-form inverse kinematics of the planar 2-R arm, and the goal checks (no rclpy).

Convention (the contract's): ``q1`` is measured from the +x axis, ``q2`` relative to link
1, both counter-clockwise positive, y up. The end effector is at
``p = (l1 cos q1 + l2 cos(q1 + q2), l1 sin q1 + l2 sin(q1 + q2))``.

Elbow branches
--------------
Every reachable point off the workspace boundary has two solutions, mirror images about
the line from the base to the point:

* ``'down'``: ``q2 > 0`` (``sin q2 > 0``). The elbow lies clockwise of the base-to-tip
  line, i.e. *below* it when the arm reaches towards +x.
* ``'up'``: ``q2 < 0`` (``sin q2 < 0``). The elbow lies counter-clockwise of that line,
  *above* it when reaching towards +x.

(With ``q2 > 0`` link 2 turns counter-clockwise from link 1, so link 1 must point below the
target direction: ``q1 = atan2(y, x) - atan2(l2 sin q2, l1 + l2 cos q2)``.) A
configuration with ``sin q2 = 0`` (arm stretched or folded) is singular and counts as
``'down'`` where a branch must be named.

Goal checks
-----------
* Reachability: ``|l1 - l2| + reach_margin <= r <= l1 + l2 - reach_margin`` with ``r``
  the distance of the point from the base [m].
* Singularity: ``|sin q2| >= singularity_margin``; ``det J = l1 l2 sin q2``, so the
  margin bounds the joint speeds a Cartesian speed needs (``|q'| <~ |x'| / (l_min |sin q2|)``).
  ``sin^2 q2 = 1 - c2^2`` with ``c2 = (r^2 - l1^2 - l2^2) / (2 l1 l2)``: it depends on
  ``r`` only and is smallest at the ends of the reachable annulus.
"""

from __future__ import annotations

import math

import numpy as np

ELBOWS = ('up', 'down')


class PlanningError(ValueError):
    """A goal or plan that is refused; the message gives the reason with the numbers."""


def elbow_of(q) -> str:
    """The elbow branch of configuration ``q`` (2,) [rad]: ``'down'`` if ``sin q2 >= 0``."""
    return 'down' if math.sin(float(np.asarray(q, dtype=float)[1])) >= 0.0 else 'up'


def cos_q2(link_lengths, r) -> np.ndarray:
    """``cos q2`` [-] of the solutions reaching distance ``r`` [m] (any shape) from the base.

    Not clipped: values outside [-1, 1] mean ``r`` is out of reach.
    """
    l1, l2 = (float(v) for v in link_lengths)
    r = np.asarray(r, dtype=float)
    return (r * r - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)


def abs_sin_q2(link_lengths, r) -> np.ndarray:
    """``|sin q2|`` [-] at distance ``r`` [m] from the base (0 where out of reach)."""
    c2 = cos_q2(link_lengths, r)
    return np.sqrt(np.clip((1.0 - c2) * (1.0 + c2), 0.0, None))


def inverse_kinematics(link_lengths, p, elbow: str) -> np.ndarray:
    """Joint angles reaching end-effector position(s) ``p``.

    Parameters
    ----------
    link_lengths : (l1, l2), m
    p : (2,) or (..., 2), m
        End-effector position(s) in the base frame; must be reachable (see
        :func:`check_point`); points outside the annulus are clipped to its boundary.
    elbow : 'up' or 'down'
        Branch: ``'down'`` gives ``q2 in [0, pi]``, ``'up'`` gives ``q2 in [-pi, 0]``.

    Returns
    -------
    q : (2,) or (..., 2), rad
        ``q1`` in (-pi, pi] (``atan2`` range), ``q2`` as above.
    """
    if elbow not in ELBOWS:
        raise ValueError(f"elbow must be 'up' or 'down', got {elbow!r}")
    l1, l2 = (float(v) for v in link_lengths)
    p = np.asarray(p, dtype=float)
    if p.shape[-1:] != (2,):
        raise ValueError(f'p must have shape (..., 2), got {p.shape}')
    x, y = p[..., 0], p[..., 1]
    c2 = np.clip(cos_q2((l1, l2), np.hypot(x, y)), -1.0, 1.0)
    s2 = np.sqrt((1.0 - c2) * (1.0 + c2))  # accurate near c2 = +-1
    if elbow == 'up':
        s2 = -s2
    q2 = np.arctan2(s2, c2)
    q1 = np.arctan2(y, x) - np.arctan2(l2 * s2, l1 + l2 * c2)
    q1 = np.arctan2(np.sin(q1), np.cos(q1))  # wrap to (-pi, pi]
    return np.stack([q1, q2], -1)


def check_point(link_lengths, p, reach_margin: float, singularity_margin: float,
                what: str = 'goal') -> None:
    """Refuse a non-finite, unreachable or near-singular point with the reason.

    Parameters
    ----------
    link_lengths : (l1, l2), m
    p : (2,), m
    reach_margin : m, >= 0 -- distance kept from both boundaries of the annulus.
    singularity_margin : -, in [0, 1) -- minimum ``|sin q2|``.
    what : name of the point in the message.

    Raises
    ------
    PlanningError
    """
    l1, l2 = (float(v) for v in link_lengths)
    p = np.asarray(p, dtype=float)
    if p.shape != (2,) or not np.isfinite(p).all():
        raise PlanningError(f'{what} must be two finite numbers (x, y) in m, got '
                            f'{p.tolist()}')
    r = math.hypot(p[0], p[1])
    lo, hi = abs(l1 - l2) + reach_margin, l1 + l2 - reach_margin
    where = f'{what} ({p[0]:.4f}, {p[1]:.4f}) m'
    if r > hi:
        raise PlanningError(
            f'{where} is out of reach: r = {r:.4f} m > l1 + l2 - reach_margin = '
            f'{l1 + l2:.4f} - {reach_margin:g} = {hi:.4f} m')
    if r < lo:
        raise PlanningError(
            f'{where} is too close to the base: r = {r:.4f} m < |l1 - l2| + reach_margin = '
            f'{abs(l1 - l2):.4f} + {reach_margin:g} = {lo:.4f} m')
    s = float(abs_sin_q2((l1, l2), r))
    if s < singularity_margin:
        raise PlanningError(
            f'{where} is too near a singularity: |sin q2| = {s:.4f} < singularity_margin '
            f'{singularity_margin:g} (r = {r:.4f} m; arm almost '
            f"{'stretched' if cos_q2((l1, l2), r) > 0 else 'folded'})")


def nearest_equivalent(q, reference) -> np.ndarray:
    """``q`` (..., 2) [rad] shifted by whole turns per joint to lie within pi of
    ``reference`` (2,) [rad]: the same pose, the shortest joint motion."""
    q = np.asarray(q, dtype=float)
    ref = np.asarray(reference, dtype=float)
    return q - 2.0 * np.pi * np.round((q - ref) / (2.0 * np.pi))
