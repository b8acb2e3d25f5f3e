"""Performance metrics of a recorded arm run: pure functions over numpy arrays.

Shapes: ``N`` samples, ``J`` joints. Times in s, angles in rad, torques in N m,
positions in m. Errors are actual minus desired.
"""

from __future__ import annotations

import numpy as np


def _as2d(name: str, x, n: int | None = None) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2 or (n is not None and a.shape[0] != n):
        raise ValueError(f'{name} must have shape (N, J) with N = {n}, got {a.shape}')
    return a


def _column_max(a: np.ndarray) -> np.ndarray:
    """``a.max(axis=0)`` of an (N, J) array, N >= 1, one column at a time: the same values
    (a maximum does not depend on the order; NaN wins either way), 5-10x faster on the few
    columns of a joint array, where numpy's axis-0 reduction walks rows of J elements."""
    return np.array([a[:, j].max() for j in range(a.shape[1])], dtype=a.dtype)


def tracking_errors(error) -> dict[str, np.ndarray]:
    """RMS, max and final tracking error per joint.

    Parameters
    ----------
    error : (N, J) array, rad
        Actual minus desired joint positions, N >= 1.

    Returns
    -------
    dict with ``rms`` (J,), ``max`` (J,) (largest magnitude) and ``final`` (J,) (signed,
    the last sample), rad.
    """
    e = _as2d('error', error)
    if len(e) == 0:
        raise ValueError('error must have at least one sample, got 0')
    return {'rms': np.sqrt(np.mean(e * e, axis=0)), 'max': _column_max(np.abs(e)),
            'final': e[-1].copy()}


def settling_time(t, q, q_start: float, q_final: float, band: float = 0.02) -> float | None:
    """Time after ``t[0]`` from which ``q`` stays within ``band`` x step of ``q_final``.

    Parameters
    ----------
    t : (N,) array, s
    q : (N,) array, rad
    q_start, q_final : float, rad
        The step is ``|q_final - q_start|``; the band is ``band`` times it (2% default).

    Returns
    -------
    float (s) or None if ``q`` is outside the band at the last sample or the step is zero.
    """
    t = np.asarray(t, np.float64)
    q = np.asarray(q, np.float64)
    if t.shape != q.shape or t.ndim != 1 or len(t) == 0:
        raise ValueError(f't and q must be equal-length 1-D arrays, got {t.shape} and '
                         f'{q.shape}')
    step = abs(q_final - q_start)
    if step == 0.0:
        return None
    outside = np.flatnonzero(np.abs(q - q_final) > band * step)
    if len(outside) == 0:
        return 0.0
    last = outside[-1]
    if last == len(q) - 1:
        return None
    return float(t[last + 1] - t[0])


def overshoot(q, q_start: float, q_final: float) -> float | None:
    """Overshoot in percent of the step: how far ``q`` (N,) [rad] goes past ``q_final`` in
    the direction of motion (0 if never); None for a zero step."""
    q = np.asarray(q, np.float64)
    step = q_final - q_start
    if step == 0.0 or len(q) == 0:
        return None
    past = (q - q_final) * np.sign(step)
    return float(max(0.0, past.max()) / abs(step) * 100.0)


def _segment(xy, a, b) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Points ``xy`` as (N, 2), their offsets ``xy - a`` (N, 2), ``b - a`` (2,) and its
    length, all in m."""
    p = np.asarray(xy, np.float64).reshape(-1, 2)
    a = np.asarray(a, np.float64).reshape(2)
    d = np.asarray(b, np.float64).reshape(2) - a
    return p, p - a, d, float(np.hypot(d[0], d[1]))


def segment_deviation(xy, a, b) -> np.ndarray:
    """Distance of each point from the segment from ``a`` to ``b`` (not the infinite line).

    A point alongside the segment is measured perpendicular to it; a point beyond an end is
    measured to that end point.

    Parameters
    ----------
    xy : (N, 2) array, m
        Points, e.g. the tip positions of a run.
    a, b : (2,) arrays, m
        Start and end of the commanded segment; ``a == b`` is allowed (the distance from
        ``a``).

    Returns
    -------
    (N,) array, m, >= 0.
    """
    _, r, d, length = _segment(xy, a, b)
    if length == 0.0:
        return np.hypot(r[:, 0], r[:, 1])
    s = np.clip(r @ d / (length * length), 0.0, 1.0)
    off = r - s[:, None] * d
    return np.hypot(off[:, 0], off[:, 1])


def overshoot_along_line(xy, a, b) -> tuple[np.ndarray, np.ndarray]:
    """How far each point lies beyond the ends of the segment ``a``-``b``, along the line.

    The point is projected on the line through ``a`` and ``b``; the result is how far that
    projection lies before ``a`` and past ``b`` (0 when it lies between them). The distance
    across the line does not count here (:func:`segment_deviation` has it).

    Parameters
    ----------
    xy : (N, 2) array, m
        Points, e.g. the tip positions of a run.
    a, b : (2,) arrays, m
        Start and end of the commanded segment. A zero-length segment has no direction:
        both results are 0 (its whole distance is in :func:`segment_deviation`).

    Returns
    -------
    before_start, past_end : (N,) arrays, m, >= 0
        Distance along the line before ``a`` (opposite to the motion) and past ``b`` (in
        the direction of motion).
    """
    p, r, d, length = _segment(xy, a, b)
    if length == 0.0:
        zero = np.zeros(len(p))
        return zero, zero.copy()
    along = r @ d / length  # m from a towards b
    return np.maximum(0.0, -along), np.maximum(0.0, along - length)


def is_straight_line(points, tol: float = 1e-6) -> bool:
    """True if there are >= 3 ``points`` (P, 2) [m] and all lie within ``tol`` m of the
    segment from the first to the last."""
    p = np.asarray(points, np.float64).reshape(-1, 2)
    if len(p) < 3 or not np.isfinite(p).all():
        return False
    if (p[0] == p[-1]).all():
        return False
    return bool(segment_deviation(p, p[0], p[-1]).max() <= tol)


def torque_stats(effort, effort_limits) -> dict[str, np.ndarray]:
    """Peak |tau|, RMS tau and saturated fraction per joint.

    Parameters
    ----------
    effort : (N, J) array, N m
        Applied torque.
    effort_limits : (J,) array, N m
        A sample counts as saturated when ``|tau| >= limit - 1e-9``.

    Returns
    -------
    dict with ``peak`` (J,) N m, ``rms`` (J,) N m, ``saturated_fraction`` (J,) in [0, 1]
    (fraction of samples, i.e. of time at a uniform sampling rate).
    """
    tau = _as2d('effort', effort)
    lim = np.asarray(effort_limits, np.float64).reshape(-1)
    if lim.shape != (tau.shape[1],):
        raise ValueError(f'effort_limits must have {tau.shape[1]} values, got {lim.shape}')
    if len(tau) == 0:
        nan = np.full(tau.shape[1], np.nan)
        return {'peak': nan, 'rms': nan.copy(), 'saturated_fraction': nan.copy()}
    mag = np.abs(tau)
    saturated = mag >= lim - 1e-9
    return {'peak': _column_max(mag), 'rms': np.sqrt(np.mean(tau * tau, axis=0)),
            'saturated_fraction': np.array([np.count_nonzero(saturated[:, j])
                                            for j in range(saturated.shape[1])]) / len(tau)}


def energy_delivered(effort, position) -> float:
    """Mechanical energy [J] delivered by the joint torques, exactly: the work of each held
    torque, ``sum_k sum_j tau_kj (q_kj - q_(k-1)j)`` for k = 1 .. N-1.

    ``effort`` (N, J) N m: sample k is the torque applied (held) over the control period
    that ends at sample k, as the simulator publishes it; ``position`` (N, J) rad. The work
    of a constant torque over a period is exactly torque times displacement, so this equals
    the change in mechanical energy plus the damping loss up to the integrator's error
    (a trapezoid of ``tau . qd`` pairs each torque with the velocities at both ends of its
    period and was 0.2-3% too high on the demo's tasks). Periods with a non-finite value
    are left out."""
    tau = _as2d('effort', effort)
    q = _as2d('position', position, len(tau))
    if tau.shape != q.shape:
        raise ValueError(f'effort {tau.shape} and position {q.shape} must match')
    if len(tau) < 2:
        return 0.0
    work = np.sum(tau[1:] * np.diff(q, axis=0), axis=1)
    ok = np.isfinite(work)
    return float(np.sum(work if ok.all() else work[ok]))
