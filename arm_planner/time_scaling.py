"""Time scalings ``s(t)``: progress 0 -> 1 along a path over a duration (no rclpy).

A :class:`TimeScaling` is a fixed normalised shape ``sigma(tau)``, ``tau = t / T`` in
[0, 1], stretched over the duration ``T``: ``s(t) = sigma(t / T)``, ``s' = sigma' / T``,
``s'' = sigma'' / T^2``. Stretching a plan therefore means changing ``T`` only; the
shape (and so the geometric path and the sampling in ``tau``) stays the same.

* ``quintic``: ``sigma = 10 tau^3 - 15 tau^4 + 6 tau^5``; zero speed and acceleration at
  both ends; peak ``sigma' = 15/8`` at ``tau = 1/2``, peak ``|sigma''| = 10/sqrt(3)`` at
  ``tau = 1/2 -+ sqrt(3)/6``.
* ``trapezoidal``: constant acceleration for a fraction ``blend`` of the duration, cruise,
  constant deceleration for the last ``blend`` (``blend = 1/2``: triangular); zero speed
  at both ends; the acceleration jumps at ``tau = blend`` and ``1 - blend``
  (:attr:`TimeScaling.breaks`). Peak ``sigma' = 1 / (1 - blend)``, ``|sigma''| =
  1 / (blend (1 - blend))``.

References: Lynch and Park, *Modern Robotics* (2017), §9.2.2 (polynomial and trapezoidal
time scalings); Siciliano et al., *Robotics: Modelling, Planning and Control* (2009),
§4.2.1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

KINDS = ('quintic', 'trapezoidal')
QUINTIC_PEAK_SPEED = 15.0 / 8.0
QUINTIC_PEAK_ACCEL = 10.0 / math.sqrt(3.0)
DEFAULT_BLEND = 1.0 / 3.0  # trapezoid with a given duration: thirds


@dataclass(frozen=True)
class TimeScaling:
    """``s(t)`` over ``[0, duration]``.

    Parameters
    ----------
    kind : 'quintic' or 'trapezoidal'
    duration : s, > 0
    blend : -, in (0, 1/2] -- trapezoidal only: acceleration phase / duration.
    """

    kind: str
    duration: float
    blend: float = DEFAULT_BLEND

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"time scaling must be one of {', '.join(KINDS)}, got "
                             f'{self.kind!r}')
        if not (math.isfinite(self.duration) and self.duration > 0.0):
            raise ValueError(f'duration must be > 0 s, got {self.duration!r}')
        if not 0.0 < self.blend <= 0.5:
            raise ValueError(f'blend must be in (0, 0.5], got {self.blend!r}')

    def with_duration(self, duration: float) -> TimeScaling:
        """The same shape over another duration [s]."""
        return TimeScaling(self.kind, duration, self.blend)

    @property
    def breaks(self) -> tuple[float, ...]:
        """Normalised times ``tau`` where ``s''`` jumps (empty for quintic)."""
        if self.kind == 'quintic':
            return ()
        return (self.blend,) if self.blend == 0.5 else (self.blend, 1.0 - self.blend)

    @property
    def peak_speed(self) -> float:
        """Peak ``s'`` [1/s]."""
        unit = QUINTIC_PEAK_SPEED if self.kind == 'quintic' else 1.0 / (1.0 - self.blend)
        return unit / self.duration

    @property
    def peak_acceleration(self) -> float:
        """Peak ``|s''|`` [1/s^2]."""
        unit = (QUINTIC_PEAK_ACCEL if self.kind == 'quintic'
                else 1.0 / (self.blend * (1.0 - self.blend)))
        return unit / self.duration**2

    def normalised(self, tau) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(sigma, dsigma/dtau, d2sigma/dtau2)`` at ``tau`` (any shape, clipped to [0, 1]).

        At a break the value on the left is returned (the acceleration of the phase that
        ends there).
        """
        tau = np.clip(np.asarray(tau, dtype=float), 0.0, 1.0)
        if self.kind == 'quintic':
            t2 = tau * tau
            s = t2 * tau * (10.0 + tau * (-15.0 + 6.0 * tau))
            ds = 30.0 * t2 * (1.0 - tau) ** 2
            dds = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau)
            return s, ds, dds
        b = self.blend
        a = 1.0 / (b * (1.0 - b))  # acceleration
        v = a * b                  # cruise speed = 1 / (1 - b)
        rest = 1.0 - tau
        accel = tau <= b
        decel = tau > 1.0 - b
        s = np.where(accel, 0.5 * a * tau * tau,
                     np.where(decel, 1.0 - 0.5 * a * rest * rest, v * (tau - 0.5 * b)))
        ds = np.where(accel, a * tau, np.where(decel, a * rest, v))
        dds = np.where(accel, a, np.where(decel, -a, 0.0))
        return s, ds, dds

    def evaluate(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(s [-], s' [1/s], s'' [1/s^2])`` at times ``t`` [s] (any shape)."""
        s, ds, dds = self.normalised(np.asarray(t, dtype=float) / self.duration)
        return s, ds / self.duration, dds / self.duration**2


def from_limits(kind: str, speed_time: float, accel_time: float) -> TimeScaling:
    """The fastest scaling of a path whose speed and acceleration are bounded.

    Parameters
    ----------
    kind : 'quintic' or 'trapezoidal'
    speed_time : s, > 0 -- ``L / v_max``: the time the path takes at the peak speed.
    accel_time : s^2, > 0 -- ``L / a_max``.

    With these, ``|s'| L <= v_max`` and ``|s''| L <= a_max``. Quintic: ``T =
    max(15/8 V, sqrt(10/sqrt(3) A))``. Trapezoidal: cruise at ``v_max`` if ``V^2 >= A``
    (``T = V + A / V``, ``blend = (A / V) / T``), else triangular (``T = 2 sqrt(A)``).
    """
    v, a = float(speed_time), float(accel_time)
    if not (v > 0.0 and a > 0.0 and math.isfinite(v) and math.isfinite(a)):
        raise ValueError(f'speed_time and accel_time must be > 0, got {v!r}, {a!r}')
    if kind == 'quintic':
        return TimeScaling(kind, max(QUINTIC_PEAK_SPEED * v, math.sqrt(QUINTIC_PEAK_ACCEL * a)))
    if kind == 'trapezoidal':
        if v * v >= a:
            t = v + a / v
            return TimeScaling(kind, t, min(0.5, (a / v) / t))
        return TimeScaling(kind, 2.0 * math.sqrt(a), 0.5)
    raise ValueError(f"time scaling must be one of {', '.join(KINDS)}, got {kind!r}")
