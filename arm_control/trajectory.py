"""Joint trajectories as joint_trajectory_controller understands them (no rclpy).

* :func:`validate_trajectory` checks a received trajectory the way ros2_controllers does
  (plus what it misses) and raises :class:`TrajectoryError` with the reason.
* :class:`Trajectory` samples desired ``q, qd, qdd`` at any time from the start:
  quintic between points that carry positions, velocities and accelerations, cubic with
  positions and velocities, linear with positions only. Before the first point's
  ``time_from_start`` the trajectory starts from the state it was given at ``t = 0``;
  after the last point the last position is held with zero velocity.

References: cubic and quintic interpolating polynomials, Siciliano et al., *Robotics:
Modelling, Planning and Control* (2009), §4.2.1-4.2.2; ros2_controllers'
joint_trajectory_controller (splines and validation).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


class TrajectoryError(ValueError):
    """A trajectory that must not replace the current reference; the message says why."""


class JointNamesError(TrajectoryError):
    """A trajectory whose ``joint_names`` are not this controller's joints (unknown, missing
    or repeated names)."""


class StaleTrajectoryError(TrajectoryError):
    """A trajectory that ends before the current simulated time (planned from a state the
    simulation has since left behind: planning it again from the latest state helps)."""


@dataclass(frozen=True)
class TrajectoryPoint:
    """One waypoint as received: ``time_from_start`` [s] and per-joint arrays in the
    message's joint order (empty sequences where the message had none)."""

    time_from_start: float
    positions: Sequence[float]
    velocities: Sequence[float] = ()
    accelerations: Sequence[float] = ()


def _finite(name: str, values: np.ndarray) -> None:
    if not np.isfinite(values).all():
        raise TrajectoryError(f'{name} has non-finite values: {values.tolist()}')


def validate_trajectory(joint_names: Sequence[str], points: Sequence[TrajectoryPoint],
                        expected: Sequence[str]) -> tuple[np.ndarray, np.ndarray,
                                                          np.ndarray | None,
                                                          np.ndarray | None]:
    """Check a trajectory and return it in ``expected`` joint order.

    Returns
    -------
    times : (K,) s, strictly increasing, >= 0
    positions : (K, n) rad
    velocities : (K, n) rad/s or None (no point had velocities)
    accelerations : (K, n) rad/s^2 or None

    Raises
    ------
    TrajectoryError
        Unknown, missing or repeated joint names (:class:`JointNamesError`); no points;
        times negative or not strictly increasing; array lengths that do not match the
        joints; velocities or accelerations given for some points only; accelerations
        without velocities; non-finite values.
    """
    names = list(joint_names)
    unknown = sorted(set(names) - set(expected))
    if unknown:
        raise JointNamesError(f'unknown joint names {unknown}; this controller has '
                              f'{list(expected)}')
    missing = [j for j in expected if j not in names]
    if missing:
        raise JointNamesError(f'joints {missing} missing from joint_names {names}')
    if len(set(names)) != len(names):
        raise JointNamesError(f'joint_names has repeats: {names}')
    if not points:
        raise TrajectoryError('trajectory has no points')
    order = [names.index(j) for j in expected]
    n = len(names)
    times = np.array([p.time_from_start for p in points], dtype=float)
    _finite('time_from_start', times)
    if times[0] < 0 or (np.diff(times) <= 0).any():
        raise TrajectoryError(f'time_from_start must be >= 0 and strictly increasing, got '
                              f'{times.tolist()}')
    fields: dict[str, np.ndarray | None] = {}
    for field in ('positions', 'velocities', 'accelerations'):
        sizes = [len(getattr(p, field)) for p in points]
        if field == 'positions' and any(s != n for s in sizes):
            bad = next(i for i, s in enumerate(sizes) if s != n)
            raise TrajectoryError(f'point {bad} has {sizes[bad]} positions for {n} joints')
        if all(s == 0 for s in sizes):
            fields[field] = None
            continue
        if any(s != n for s in sizes):
            bad = next(i for i, s in enumerate(sizes) if s != n)
            raise TrajectoryError(f'point {bad} has {sizes[bad]} {field} for {n} joints '
                                  f'(give {field} for every point or for none)')
        values = np.array([getattr(p, field) for p in points], dtype=float)[:, order]
        _finite(field, values)
        fields[field] = values
    if fields['accelerations'] is not None and fields['velocities'] is None:
        raise TrajectoryError('accelerations given without velocities')
    positions = fields['positions']
    assert positions is not None  # every point has n positions (checked above)
    return times, positions, fields['velocities'], fields['accelerations']


class Trajectory:
    """Desired joint motion over time, from a start state and validated waypoints.

    Parameters
    ----------
    q0, qd0 : (n,) rad, rad/s -- the state at ``t = 0`` (the measured state when the
        trajectory was accepted); used only if the first point's time is > 0.
    times, positions, velocities, accelerations : as returned by
        :func:`validate_trajectory`.
    """

    def __init__(self, q0, qd0, times: np.ndarray, positions: np.ndarray,
                 velocities: np.ndarray | None = None,
                 accelerations: np.ndarray | None = None) -> None:
        q0, qd0 = np.asarray(q0, dtype=float), np.asarray(qd0, dtype=float)
        n = positions.shape[1]
        vel = velocities if velocities is not None else np.zeros_like(positions)
        acc = accelerations if accelerations is not None else np.zeros_like(positions)
        self.order = 5 if accelerations is not None else 3 if velocities is not None else 1
        if times[0] > 0.0:
            times = np.concatenate([[0.0], times])
            positions = np.vstack([q0, positions])
            start_vel = qd0 if self.order > 1 else np.zeros(n)
            vel = np.vstack([start_vel, vel])
            acc = np.vstack([np.zeros(n), acc])
        self.times, self.positions, self.velocities, self.accelerations = (
            times, positions, vel, acc)
        self.duration = float(times[-1])
        self.set_point = len(times) == 1

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Desired (q [rad], qd [rad/s], qdd [rad/s^2]) at ``t`` s after the start."""
        q, qd, qdd = self.sample_many(np.array([t], dtype=float))
        return q[0], qd[0], qdd[0]

    def sample_many(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vectorised :meth:`sample`: ``t`` (M,) s -> three (M, n) arrays."""
        t = np.asarray(t, dtype=float)
        times, p, v, a = self.times, self.positions, self.velocities, self.accelerations
        m, n = len(t), p.shape[1]
        q = np.empty((m, n))
        qd = np.zeros((m, n))
        qdd = np.zeros((m, n))
        before = t <= times[0]
        after = t >= times[-1]
        q[before] = p[0]
        q[after] = p[-1]
        if self.set_point:
            return q, qd, qdd
        qd[before], qdd[before] = v[0], a[0]
        inside = ~(before | after)
        if inside.any():
            ti = t[inside]
            k = np.searchsorted(times, ti, side='right') - 1
            h = (times[k + 1] - times[k])[:, None]
            s = ((ti - times[k])[:, None]) / h
            q[inside], qd[inside], qdd[inside] = _segment(
                self.order, s, h, p[k], v[k], a[k], p[k + 1], v[k + 1], a[k + 1])
        return q, qd, qdd


def _segment(order: int, s: np.ndarray, h: np.ndarray, p0, v0, a0, p1, v1, a1):
    """Polynomial between two waypoints at normalised time ``s`` in [0, 1] of a segment of
    length ``h`` [s]; returns (q, qd, qdd)."""
    if order == 1:
        slope = (p1 - p0) / h
        return p0 + s * (p1 - p0), slope, np.zeros_like(slope)
    # Work in normalised time: derivatives scale by h.
    v0n, v1n = v0 * h, v1 * h
    d = p1 - p0
    if order == 3:
        c2 = 3.0 * d - 2.0 * v0n - v1n
        c3 = -2.0 * d + v0n + v1n
        q = p0 + s * (v0n + s * (c2 + s * c3))
        dq = v0n + s * (2.0 * c2 + 3.0 * s * c3)
        ddq = 2.0 * c2 + 6.0 * s * c3
        return q, dq / h, ddq / h**2
    a0n, a1n = a0 * h * h, a1 * h * h
    c3 = 10.0 * d - 6.0 * v0n - 4.0 * v1n - 1.5 * a0n + 0.5 * a1n
    c4 = -15.0 * d + 8.0 * v0n + 7.0 * v1n + 1.5 * a0n - a1n
    c5 = 6.0 * d - 3.0 * v0n - 3.0 * v1n - 0.5 * a0n + 0.5 * a1n
    c2 = 0.5 * a0n
    q = p0 + s * (v0n + s * (c2 + s * (c3 + s * (c4 + s * c5))))
    dq = v0n + s * (2.0 * c2 + s * (3.0 * c3 + s * (4.0 * c4 + 5.0 * s * c5)))
    ddq = 2.0 * c2 + s * (6.0 * c3 + s * (12.0 * c4 + 20.0 * s * c5))
    return q, dq / h, ddq / h**2

