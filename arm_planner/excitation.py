"""Excitation signals about a joint configuration: chirps and multi-sines (pure numpy).

Each signal moves the chosen joints about ``centre`` and returns the reference the
controller tracks, sampled at given times with analytic derivatives::

    q(t) = centre + a * w(t) * s(t)        (a: amplitude per joint, 0 for joints at rest)

``s`` is the unit signal (a sine sweep, or a sum of sines) and ``w`` a smooth fade in and
out (a quintic smoothstep, so ``w``, ``w'`` and ``w''`` are 0 at both ends): the arm starts
and ends at rest at ``centre`` with zero acceleration, and ``q`` is twice continuously
differentiable everywhere (before 0 and after ``duration`` it stays at ``centre``).

* :func:`chirp` -- a linear (``sweep='linear'``: ``f(t) = f0 + (f1 - f0) t / T``) or
  logarithmic (``sweep='log'``: ``f(t) = f0 (f1 / f0)^(t / T)``: equal time per octave)
  sine sweep, phase ``phi(t) = 2 pi int_0^t f``.
* :func:`multisine` -- a sum of tones on the harmonics of ``1 / duration`` (log spaced in
  ``f0 .. f1``) with Schroeder phases (low crest factor), scaled so that its peak over the
  duration is the amplitude.

Shapes: ``times`` (M,) s; ``centre``, ``amplitude`` (n,) rad (a scalar amplitude: the
same for every moved joint); results ``q, qd, qdd`` (M, n) rad, rad/s, rad/s^2.
Every parameter is checked; a bad one raises :class:`ExcitationError` naming it and the
value (a band above the Nyquist rate of the control period, an amplitude that leaves the
joint limits, a duration too short for the lowest frequency, ...).

References: Pintelon and Schoukens, *System Identification: A Frequency Domain Approach*
(2nd ed., Wiley 2012), §5.2 (swept sines, multisines), §5.2.2 (Schroeder phases);
Schroeder, "Synthesis of low-peak-factor signals and binary sequences with low
autocorrelation", IEEE Trans. Inf. Theory 16 (1970).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

SWEEPS = ('linear', 'log')
#: Default fade in / out as a share of the duration (each end).
FADE_SHARE = 0.05


class ExcitationError(ValueError):
    """An excitation parameter that cannot make a valid signal; the message names it."""


def _fade(t: np.ndarray, duration: float, fade: float) -> tuple[np.ndarray, ...]:
    """Window ``w`` and its two derivatives: quintic smoothstep up over ``[0, fade]``, 1,
    down over ``[duration - fade, duration]``, 0 outside. ``t`` (M,) s."""
    w = np.zeros_like(t)
    wd = np.zeros_like(t)
    wdd = np.zeros_like(t)
    inside = (t > 0.0) & (t < duration)
    w[inside] = 1.0
    for up in (True, False):
        s = t / fade if up else (duration - t) / fade
        sel = inside & (s < 1.0)
        x = s[sel]
        sign = 1.0 if up else -1.0
        w[sel] = x**3 * (10.0 - 15.0 * x + 6.0 * x * x)
        wd[sel] = sign * 30.0 * x * x * (1.0 - x) ** 2 / fade
        wdd[sel] = 60.0 * x * (1.0 - x) * (1.0 - 2.0 * x) / fade**2
    return w, wd, wdd


def _amplitudes(centre, amplitude, joints, lower, upper) -> tuple[np.ndarray, np.ndarray]:
    c = np.asarray(centre, dtype=float).reshape(-1)
    n = len(c)
    if n == 0 or not np.isfinite(c).all():
        raise ExcitationError(f'centre must be finite joint angles [rad], got {c.tolist()}')
    a = np.asarray(amplitude, dtype=float).reshape(-1)
    if a.size == 1:
        a = np.full(n, float(a[0]))
    if a.size != n:
        raise ExcitationError(f'amplitude has {a.size} values for {n} joints')
    if not (np.isfinite(a).all() and (a > 0).all()):
        raise ExcitationError(f'amplitude must be > 0 rad per joint, got {a.tolist()}')
    moved = np.ones(n, dtype=bool) if joints is None else np.zeros(n, dtype=bool)
    if joints is not None:
        for j in joints:
            if not (isinstance(j, (int, np.integer)) and 0 <= int(j) < n):
                raise ExcitationError(f'joints must be joint indices 0..{n - 1}, got {j!r}')
            moved[int(j)] = True
        if not moved.any():
            raise ExcitationError('joints is empty: no joint to excite')
    a = np.where(moved, a, 0.0)
    for name, bound, sign in (('lower', lower, -1.0), ('upper', upper, 1.0)):
        if bound is None:
            continue
        b = np.asarray(bound, dtype=float).reshape(-1)
        reach = c + sign * a
        bad = np.flatnonzero(sign * (reach - b) > 0.0)
        if bad.size:
            j = int(bad[0])
            raise ExcitationError(
                f'amplitude {a[j]:g} rad about {c[j]:g} rad takes joint {j + 1} to '
                f'{reach[j]:g} rad, beyond its {name} position limit {b[j]:g} rad')
    return c, a


def _band(f0: float, f1: float, duration: float, fade: float | None,
          period: float | None) -> float:
    """Check the band and timing; return the fade [s]."""
    for name, v in (('f0', f0), ('f1', f1), ('duration', duration)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ExcitationError(f'{name} must be > 0, got {v!r}')
    if not f1 > f0:
        raise ExcitationError(f'f1 ({f1:g} Hz) must be above f0 ({f0:g} Hz)')
    if period is not None:
        nyquist = 0.5 / period
        if f1 >= nyquist:
            raise ExcitationError(
                f'f1 {f1:g} Hz is not below the Nyquist rate {nyquist:g} Hz of the control '
                f'period {period:g} s')
    if duration * f0 < 1.0:
        raise ExcitationError(f'duration {duration:g} s is shorter than one period of f0 '
                              f'({f0:g} Hz: {1.0 / f0:g} s)')
    fade = FADE_SHARE * duration if fade is None else fade
    if not (math.isfinite(fade) and 0.0 < fade <= 0.5 * duration):
        raise ExcitationError(f'fade must be > 0 and at most half the duration '
                              f'({0.5 * duration:g} s), got {fade!r}')
    return fade


def _compose(t, c, a, duration, fade, s, sd, sdd):
    w, wd, wdd = _fade(t, duration, fade)
    u = w * s
    ud = wd * s + w * sd
    udd = wdd * s + 2.0 * wd * sd + w * sdd
    return (c + u[:, None] * a, ud[:, None] * a, udd[:, None] * a)


def chirp(times, *, centre: Sequence[float], amplitude, f0: float, f1: float,
          duration: float, joints: Sequence[int] | None = None, sweep: str = 'log',
          fade: float | None = None, period: float | None = None,
          lower: Sequence[float] | None = None, upper: Sequence[float] | None = None
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A faded sine sweep about ``centre``: ``q = centre + a w(t) sin(phi(t))``.

    Parameters
    ----------
    times : (M,) s from the start of the excitation (any values; outside ``[0,
        duration]`` the joints rest at ``centre``).
    centre : (n,) rad.
    amplitude : scalar or (n,) rad, > 0 -- peak deviation of each moved joint.
    f0, f1 : Hz, 0 < f0 < f1 -- the band swept, from f0 at ``t = 0`` to f1 at ``duration``.
    duration : s, at least one period of f0.
    joints : indices of the joints that move (None: all); the others stay at ``centre``.
    sweep : ``'log'`` (equal time per octave; the default) or ``'linear'``.
    fade : s, the fade in and out at each end (None: 5% of the duration).
    period : s or None -- the control period; f1 must be below its Nyquist rate.
    lower, upper : (n,) rad or None -- joint limits ``centre +- amplitude`` must stay in.

    Returns
    -------
    q, qd, qdd : (M, n) rad, rad/s, rad/s^2 -- exact derivatives of one another.
    """
    if sweep not in SWEEPS:
        raise ExcitationError(f"sweep must be one of {', '.join(SWEEPS)}, got {sweep!r}")
    c, a = _amplitudes(centre, amplitude, joints, lower, upper)
    fade = _band(f0, f1, duration, fade, period)
    t = np.asarray(times, dtype=float).reshape(-1)
    tc = np.clip(t, 0.0, duration)
    if sweep == 'linear':
        rate = (f1 - f0) / duration
        phi = 2.0 * np.pi * (f0 * tc + 0.5 * rate * tc * tc)
        phid = 2.0 * np.pi * (f0 + rate * tc)
        phidd = np.full_like(tc, 2.0 * np.pi * rate)
    else:
        k = math.log(f1 / f0) / duration
        grow = np.exp(k * tc)
        phi = 2.0 * np.pi * f0 * (grow - 1.0) / k
        phid = 2.0 * np.pi * f0 * grow
        phidd = phid * k
    s = np.sin(phi)
    cs = np.cos(phi)
    return _compose(t, c, a, duration, fade, s, cs * phid, cs * phidd - s * phid * phid)


def instantaneous_frequency(times, *, f0: float, f1: float, duration: float,
                            sweep: str = 'log') -> np.ndarray:
    """The frequency [Hz] :func:`chirp` sweeps through at ``times`` (M,) s."""
    tc = np.clip(np.asarray(times, dtype=float), 0.0, duration)
    if sweep == 'linear':
        return f0 + (f1 - f0) * tc / duration
    return f0 * (f1 / f0) ** (tc / duration)


def multisine_tones(f0: float, f1: float, duration: float, tones: int = 40
                    ) -> np.ndarray:
    """The frequencies [Hz] :func:`multisine` uses: harmonics of ``1 / duration`` in
    ``[f0, f1]``, at most ``tones`` of them, log spaced (distinct, ascending)."""
    base = 1.0 / duration
    lo, hi = max(1, math.ceil(f0 / base - 1e-9)), math.floor(f1 / base + 1e-9)
    if hi < lo:
        raise ExcitationError(f'no harmonic of 1/duration ({base:g} Hz) lies in '
                              f'{f0:g} .. {f1:g} Hz: lengthen the duration')
    k = np.unique(np.round(np.geomspace(lo, hi, max(1, int(tones)))).astype(int))
    return k * base


def multisine(times, *, centre: Sequence[float], amplitude, f0: float, f1: float,
              duration: float, joints: Sequence[int] | None = None, tones: int = 40,
              fade: float | None = None, period: float | None = None,
              lower: Sequence[float] | None = None, upper: Sequence[float] | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A faded Schroeder-phased multisine about ``centre``.

    ``s(t) = sum_k cos(2 pi f_k t + phi_k) / P`` over the tones of :func:`multisine_tones`,
    ``phi_k = -pi k (k - 1) / K`` (Schroeder), ``P`` the peak of the sum over the duration
    (sampled every ``1 / (20 f1)`` s), so ``|q - centre| <= amplitude`` (to that sampling).
    Parameters and returns as :func:`chirp` (``tones``: at most this many).
    """
    c, a = _amplitudes(centre, amplitude, joints, lower, upper)
    fade = _band(f0, f1, duration, fade, period)
    f = multisine_tones(f0, f1, duration, tones)
    kk = np.arange(1, len(f) + 1)
    ph = -np.pi * kk * (kk - 1) / len(f)

    def parts(t):
        arg = 2.0 * np.pi * np.outer(t, f) + ph
        w = 2.0 * np.pi * f
        return (np.cos(arg).sum(1), (-np.sin(arg) * w).sum(1),
                (-np.cos(arg) * w * w).sum(1))

    grid = np.arange(0.0, duration, 1.0 / (20.0 * f1))
    peak = float(np.abs(parts(grid)[0]).max())
    t = np.asarray(times, dtype=float).reshape(-1)
    s, sd, sdd = (p / peak for p in parts(np.clip(t, 0.0, duration)))
    return _compose(t, c, a, duration, fade, s, sd, sdd)
