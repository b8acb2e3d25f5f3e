"""Performance metrics of an arm run: the one table of them, and pure functions over numpy
arrays.

:data:`METRICS` is the single source of every per-segment metric: its name (the JSON field
of ``arm-sim analyze --json``, the attribute of :class:`~arm_bag.analysis.Segment`, the
sweep's column, ``<name>_<j>`` per joint), unit, whether it is per joint, its format and
meaning. :func:`segment_metrics` computes them for one segment, for ``analyze`` and for
the sweeps alike. To add a metric: add a :class:`Metric` row and its computation in
:func:`segment_metrics` -- this file only (docs/architecture.md, "Add a metric").

:data:`DISTURBANCE_METRICS` is the same for the figures of a real arm that only some bags
have: the energy Coulomb friction took (a robot record with ``coulomb_friction``) and the
response to each push (a bag with ``simulator/events``); they are not sweep columns, and
a report leaves them out where they do not apply (so reports of other bags are unchanged).

Shapes: ``N`` samples, ``J`` joints. Times in s, angles in rad, torques in N m,
positions in m. Errors are actual minus desired.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Metric:
    """One per-segment metric: ``name``, report ``label``, ``unit``, per joint or not, the
    report's number ``fmt`` (a format spec, or ``pct`` for a fraction shown in percent),
    when it is defined (``all``, ``regulation``, ``straight_line``; in
    :data:`DISTURBANCE_METRICS`: ``friction``, a robot with a non-zero
    ``coulomb_friction``, or ``push``, each push of the run) and its ``meaning``."""

    name: str
    label: str
    unit: str
    per_joint: bool
    fmt: str
    when: str
    meaning: str


#: Every per-segment metric, in report order.
METRICS: tuple[Metric, ...] = (
    Metric('tracking_rms', 'tracking RMS', 'rad', True, '.4g', 'all',
           'RMS of the joint position minus the reference'),
    Metric('tracking_max', 'tracking max', 'rad', True, '.4g', 'all',
           'largest |joint position minus the reference|'),
    Metric('final_error', 'final error', 'rad', True, '.3g', 'all',
           'joint position minus the reference at the last sample (signed)'),
    Metric('settling_time', 'settling time', 's', True, '.3f', 'regulation',
           'from the segment start until the joint stays within 2% of its step of the set '
           'point (none if it never does)'),
    Metric('settling_time_overall', 'settling overall', 's', False, '.3f', 'regulation',
           'the largest settling time of the joints that move'),
    Metric('overshoot', 'overshoot', '%', True, '.2f', 'regulation',
           'largest excursion past the set point, in percent of the step'),
    Metric('deviation_max', 'off segment max', 'm', False, '.3g', 'straight_line',
           "largest distance of the tip from the commanded segment"),
    Metric('deviation_rms', 'off segment RMS', 'm', False, '.3g', 'straight_line',
           'RMS distance of the tip from the commanded segment'),
    Metric('line_overshoot_end', 'past line end', 'm', False, '.3g', 'straight_line',
           'how far the tip went beyond the end of the segment, along it'),
    Metric('line_overshoot_start', 'before line start', 'm', False, '.3g', 'straight_line',
           'how far the tip went back before the start of the segment, along it'),
    Metric('torque_peak', 'torque peak', 'N m', True, '.2f', 'all',
           'largest |applied torque|'),
    Metric('torque_rms', 'torque RMS', 'N m', True, '.2f', 'all', 'RMS applied torque'),
    Metric('saturated_fraction', 'saturated', '%', True, 'pct', 'all',
           'fraction of the samples at the effort limit'),
    Metric('energy', 'energy', 'J', False, '.3f', 'all',
           'work of the held torques, sum of tau_k . (q_k - q_(k-1)) over the periods '
           'they were held (exact: change in mechanical energy plus the damping loss)'),
)
#: The metrics' names, in order.
METRIC_NAMES = tuple(m.name for m in METRICS)
#: The per-joint ones.
PER_JOINT_METRICS = tuple(m.name for m in METRICS if m.per_joint)

#: After a push the tip counts as back once within max(floor [m], fraction x its peak
#: deviation) of where it should be (:func:`push_response`).
RECOVERY_BAND_FLOOR = 1e-3
RECOVERY_BAND_FRACTION = 0.05

#: The figures of a real arm's friction and of its response to pushes, in report order:
#: ``friction_loss`` per segment (and ``run.friction_loss``) when the robot record has a
#: non-zero ``coulomb_friction``; the others per push (``Report.pushes``).
DISTURBANCE_METRICS: tuple[Metric, ...] = (
    Metric('friction_loss', 'friction loss', 'J', False, '.4g', 'friction',
           'energy the Coulomb friction took: sum over the joints of coulomb_friction_i '
           'times the path length sum_k |q_i,k - q_i,(k-1)| of the (true) positions, per '
           'segment and for the run; exact except in a sample period in which a joint '
           'reverses, which it then undercounts (Coulomb work is c |dq| while the joint '
           'slips one way and zero while it sticks, and such a period counts only its net '
           '|dq|)'),
    Metric('peak_deviation', 'peak deviation', 'm', False, '.3g', 'push',
           "largest distance of the tip from where it should be (the reference's tip at "
           'the same stamp, else the tip at the push) from the push until the next push or '
           'the end of the run'),
    Metric('recovery_time', 'recovery time', 's', False, '.3f', 'push',
           'from the push until the tip is back within max('
           f'{RECOVERY_BAND_FLOOR * 1e3:g} mm, {RECOVERY_BAND_FRACTION * 100:g}% of '
           'peak_deviation) of where it should be and stays there to the end of the '
           'window (none if it is outside at its end)'),
    Metric('peak_joint_deviation', 'peak joint deviation', 'rad', True, '.3g', 'push',
           'largest |joint position minus where it should be| over the same window'),
)
#: Their names, in order.
DISTURBANCE_METRIC_NAMES = tuple(m.name for m in DISTURBANCE_METRICS)
#: The ones a segment (and the run) has: ``friction_loss``.
SEGMENT_DISTURBANCE_METRICS = tuple(m.name for m in DISTURBANCE_METRICS if m.when != 'push')
#: The ones each push has.
PUSH_METRICS = tuple(m for m in DISTURBANCE_METRICS if m.when == 'push')


def _markdown(table: tuple[Metric, ...]) -> str:
    rows = ['| metric | unit | per joint | defined for | meaning |', '|---|---|---|---|---|']
    rows += [f"| `{m.name}` | {m.unit} | {'yes' if m.per_joint else ''} | {m.when} | "
             f'{m.meaning} |' for m in table]
    return '\n'.join(rows) + '\n'


def metrics_markdown() -> str:
    """The docs' table of the metrics (docs/bags.md holds it verbatim; a test checks)."""
    return _markdown(METRICS)


def disturbance_metrics_markdown() -> str:
    """The same table of :data:`DISTURBANCE_METRICS`."""
    return _markdown(DISTURBANCE_METRICS)


def finite_rows(*arrays: np.ndarray) -> np.ndarray:
    """(N,) bool: the rows finite in every (N, J) array (column by column: faster than
    ``isfinite(a).all(axis=1)`` on a few columns, the same result)."""
    ok = np.ones(len(arrays[0]), bool)
    for a in arrays:
        for j in range(a.shape[1]):
            ok &= np.isfinite(a[:, j])
    return ok


def segment_metrics(t=None, q=None, *, desired=None, set_point=None, line=None, xy=None,
                    effort=None, effort_limits=None, work=None, friction=None,
                    series: dict | None = None) -> dict[str, Any]:
    """Every metric of :data:`METRICS` the inputs define, by name, for one segment (and
    ``friction_loss`` of :data:`DISTURBANCE_METRICS` with ``friction``).

    Parameters
    ----------
    t : (N,) s from the segment's start; q : (N, J) rad, the joint positions (both needed
        with ``desired`` or ``set_point`` only).
    desired : (N, J) rad or None -- the reference at each sample (tracking metrics, over
        the rows finite in both).
    set_point : (J,) rad or None -- a regulation's goal (settling time and overshoot).
    line : ((2,), (2,)) m or None, with ``xy`` (M, 2) m the tip positions measured against
        it -- a straight line's ends (deviation and overshoot along the line).
    effort : (N, J) N m, with ``effort_limits`` (J,) N m -- the applied torque (peak, RMS,
        saturated fraction).
    work : ((K, J) N m, (K, J) rad) or None -- the held torques and the positions over
        the periods they were held, for the energy (:func:`energy_delivered`).
    friction : ((J,) N m, (K, J) rad) or None -- the joints' Coulomb friction and their
        positions over the same periods, for ``friction_loss`` (:func:`friction_loss`).
    series : a dict to receive the arrays behind the figures, for plots (``deviation``:
        (M,) m), or None.

    Returns
    -------
    dict of name -> value: per-joint metrics as (J,) arrays (a None item: undefined),
    the others as floats or None.
    """
    out: dict[str, Any] = {}
    if desired is not None or set_point is not None:
        q = np.asarray(q, dtype=np.float64)
    if desired is not None:
        ok = finite_rows(desired, q)
        if ok.any():
            err = tracking_errors(q - desired if ok.all() else q[ok] - desired[ok])
            out.update(tracking_rms=err['rms'], tracking_max=err['max'],
                       final_error=err['final'])
    if set_point is not None:
        q0, joints = q[0], range(q.shape[1])
        st = [settling_time(t, q[:, j], q0[j], set_point[j]) for j in joints]
        moving = [st[j] for j in joints if q0[j] != set_point[j]]
        out['settling_time'] = st
        out['settling_time_overall'] = (None if not moving or any(x is None for x in moving)
                                        else max(x for x in moving if x is not None))
        out['overshoot'] = [overshoot(q[:, j], q0[j], set_point[j]) for j in joints]
    if line is not None and xy is not None:
        a, b = line
        dev = segment_deviation(xy, a, b)
        if series is not None:
            series['deviation'] = dev
        if len(dev):
            before, past = overshoot_along_line(xy, a, b)
            out.update(deviation_max=float(dev.max()),
                       deviation_rms=float(np.sqrt(np.mean(dev * dev))),
                       line_overshoot_end=float(past.max()),
                       line_overshoot_start=float(before.max()))
    if effort is not None:
        stats = torque_stats(effort, effort_limits)
        out.update(torque_peak=stats['peak'], torque_rms=stats['rms'],
                   saturated_fraction=stats['saturated_fraction'])
    if work is not None:
        out['energy'] = energy_delivered(*work)
    if friction is not None:
        out['friction_loss'] = friction_loss(*friction)
    return out


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


def friction_loss(coulomb, position) -> float:
    """Energy [J] Coulomb friction took: ``sum_j c_j sum_k |q_kj - q_(k-1)j|``, k = 1 .. N-1.

    ``coulomb`` (J,) N m, the joints' Coulomb (sliding) friction ``c_j >= 0``; ``position``
    (N, J) rad, sampled. A slipping joint loses ``c_j |dq|`` and a stuck one nothing, so
    this is exact unless a joint reverses within a sample period: that period counts only
    its net displacement, an undercount (of ``2 c_j`` times the shorter way, for one
    reversal). Periods with a non-finite position are left out (as in
    :func:`energy_delivered`)."""
    q = _as2d('position', position)
    c = np.asarray(coulomb, np.float64).reshape(-1)
    if c.shape != (q.shape[1],):
        raise ValueError(f'coulomb must have {q.shape[1]} values, got {c.shape}')
    if len(q) < 2:
        return 0.0
    step = np.abs(np.diff(q, axis=0))
    ok = finite_rows(step)
    path = step.sum(axis=0) if ok.all() else step[ok].sum(axis=0)  # (J,) rad
    return float(np.sum(c * path))


def recovery_band(peak: float) -> float:
    """The band [m] a tip must be back within after a push of ``peak`` deviation [m]:
    max(:data:`RECOVERY_BAND_FLOOR`, :data:`RECOVERY_BAND_FRACTION` x peak)."""
    return max(RECOVERY_BAND_FLOOR, RECOVERY_BAND_FRACTION * peak)


def push_response(t, distance, t_push: float) -> tuple[float | None, float | None]:
    """Peak deviation [m] and recovery time [s] of one push.

    Parameters
    ----------
    t : (N,) s, the samples from the push on (to the next push or the end of the run).
    distance : (N,) m, how far the tip is from where it should be at each.
    t_push : s, when the push started (on the clock of ``t``).

    Returns
    -------
    (peak, recovery): ``peak`` the largest distance; ``recovery`` the time from
    ``t_push`` to the first sample from which the distance stays within
    :func:`recovery_band` (peak) to the last one (0.0 if it never left it, None if it is
    outside at the last sample); (None, None) without samples.
    """
    t = np.asarray(t, np.float64)
    d = np.asarray(distance, np.float64)
    if t.shape != d.shape or t.ndim != 1:
        raise ValueError(f't and distance must be equal-length 1-D arrays, got {t.shape} '
                         f'and {d.shape}')
    if len(d) == 0:
        return None, None
    peak = float(d.max())
    outside = np.flatnonzero(d > recovery_band(peak))
    if len(outside) == 0:
        return peak, 0.0
    last = int(outside[-1])
    if last == len(d) - 1:
        return peak, None
    return peak, float(t[last + 1] - t_push)
