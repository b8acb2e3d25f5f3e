"""Identification of the 2-R arm's dynamic parameters from sampled states and held torques.

Pure numpy: no rclpy. What ``arm-sim identify`` runs (:mod:`arm_sim.identify_cli`).

**The parameters.** The dynamics ``D(q) q'' + C(q, q') q' + g(q) + B q' = tau`` of
:class:`~arm_dynamics.two_link.TwoLinkArm` are linear in the inertial parameters, ``tau =
Y(q, q', q'') pi``. With the geometry (``l1``) and gravity ``g0`` known, the inertial
parameters that the dynamics depend on (the *base parameters*: the minimal set, each a
grouping of masses, first moments and inertias) are four, plus the two viscous friction
coefficients (Khalil & Dombre, *Modeling, Identification and Control of Robots* (2002),
§9.3 "base inertial parameters" and §12.3-12.5; Gautier & Khalil, "Direct calculation of
minimum set of inertial parameters of serial robots", IEEE T-RA 6(3), 1990):

======  ===========================  =========  =======================================
name    grouping                     unit       where it appears
======  ===========================  =========  =======================================
ZZ1R    I1 + m1 lc1^2 + m2 l1^2      kg m^2     a = ZZ1R + ZZ2
MX1R    m1 lc1 + m2 l1               kg m       g1 = g0 MX1R
ZZ2     I2 + m2 lc2^2                kg m^2     d = ZZ2
MX2     m2 lc2                       kg m       b = l1 MX2, g2 = g0 MX2
FV1     b1                           N m s/rad  B = diag(FV1, FV2)
FV2     b2                           N m s/rad
======  ===========================  =========  =======================================

(``a, b, d, g1, g2`` are TwoLinkArm's lumped constants, see :mod:`arm_dynamics.two_link`.)
Masses, centre-of-gravity distances and inertias separately are not identifiable from
motion: only these groupings change the torques. A point payload ``p`` at the tip adds
``p (l1^2, l1, l2^2, l2, 0, 0)`` (link 2's mass grows by ``p`` and its first moment and
inertia about the elbow by ``p l2`` and ``p l2^2``), so its mass follows from the change
of the base parameters (:func:`payload_mass`). With ``g0 = 0``, MX1R does not enter the
dynamics: it is then held at its nominal value.

**Geared motors are refused.** A motor behind gear ``n_i`` with rotor inertia ``Jm_i`` and
damping ``Bm_i`` (``TwoLinkArm``'s ``motor_inertias``, ``motor_damping``) adds ``n_i^2
Jm_i q_i''`` and ``n_i^2 Bm_i q_i'`` to joint ``i``'s torque. Joint 1's rotor would hide in
ZZ1R and the motor damping in FV1/FV2, but joint 2's rotor inertia adds ``A2 q2''`` to the
second row alone, which no column above has: the fit would be biased, not exact. So
:func:`base_parameters` and :func:`identified_arm` refuse an arm with a non-zero motor
inertia or damping (:class:`IdentificationError` naming the values); gear ratios alone
change nothing and are carried over.

**The estimation form.** The data are what the simulator publishes (and the recorder
keeps): states ``(q_k, q'_k)`` at ``t_k`` and the effort ``tau_k`` applied, held, over the
control period ``[t_(k-1), t_k]`` (:meth:`~arm_dynamics.simulation.SimulatorCore.
joint_view`). No acceleration is measured, and ``q''`` jumps at every ``t_k`` (the torque
does), so finite differences of ``q'`` across a tick mix two periods. Instead the
equations of motion are integrated over each hold period, where the torque is constant
(the momentum, or "filtered", form: Gautier, "Dynamic identification of robots with power
model", ICRA 1997; Khalil & Dombre §12.4). With the generalized momentum ``p = D(q) q' =
Y_p(q, q') pi`` and ``p' = tau - n(q, q')``, ``n = Y_n(q, q') pi`` (the Christoffel
property ``D' = C + C^T`` gives ``n = g + B q' + (0, l1 MX2 sin q2 q1' (q1' + q2'))``)::

    tau_k = [Y_p(q_k, q'_k) - Y_p(q_(k-1), q'_(k-1))] pi / T + (1/T) int Y_n(q, q') dt pi

exactly. The integral is taken with 4-point Gauss-Legendre quadrature along the cubic
Hermite interpolant of the period's end states (positions and velocities at both ends:
the motion is smooth inside a period); its error is ``O(T^4)`` per period. On the
acceptance data of ``test/test_identify.py`` (a 20 s multi-sine up to 1.5 Hz at 100 Hz,
T = 10 ms, through the closed loop, 1 kg tip payload) the torque residual of the true
parameters is 8.5e-9 N m RMS and the payload error 6e-10 kg; central differences of
``q'`` (the inverse-dynamics form at ``t_k`` against the mean of the two torques around
it) leave 1.6e-3 N m and 2.3e-5 kg, the momentum form with trapezoidal quadrature
4.8e-4 N m and 7.9e-5 kg (on a 3 Hz excitation: 0.024 and 0.002 N m, this form 3e-7).
The energy form (the held torque's work ``tau_k . (q_k - q_(k-1))`` is exact) is exact
without damping but has one equation per period, not two, and its damping term needs the same
quadrature.

**Least squares.** Weighted (Gautier's IDIM-WLS): ordinary least squares first, then each
joint's rows weighted by the inverse of that joint's residual standard deviation, then
least squares again. Standard errors from ``sigma^2 (W^T W)^-1`` with ``W`` the weighted
regressor and ``sigma^2`` its residual variance (``rows - parameters`` degrees of
freedom). The condition number reported is that of ``W`` with its columns scaled to unit
norm (independent of units; an excitation below ~100 is good, this module refuses one above
:data:`MAX_CONDITION`).

Shapes: ``q``, ``qd``, ``qdd`` (..., 2) [rad, rad/s, rad/s^2]; regressors (..., 2, 6)
(rows joints, columns :data:`NAMES`) in N m per unit of each parameter.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from arm_dynamics.two_link import TwoLinkArm


@dataclass(frozen=True)
class BaseParameter:
    """One column of the regressor: ``name``, the grouping it stands for (``formula``),
    its ``unit`` and ``meaning``."""

    name: str
    formula: str
    unit: str
    meaning: str


#: The identified parameters, in the regressor's column order.
BASE_PARAMETERS: tuple[BaseParameter, ...] = (
    BaseParameter('ZZ1R', 'I1 + m1 lc1^2 + m2 l1^2', 'kg m^2',
                  'inertia of link 1 about joint 1, with link 2\'s mass at the elbow'),
    BaseParameter('MX1R', 'm1 lc1 + m2 l1', 'kg m',
                  'first moment of link 1 about joint 1, with link 2\'s mass at the elbow'),
    BaseParameter('ZZ2', 'I2 + m2 lc2^2', 'kg m^2', 'inertia of link 2 about the elbow'),
    BaseParameter('MX2', 'm2 lc2', 'kg m', 'first moment of link 2 about the elbow'),
    BaseParameter('FV1', 'b1', 'N m s/rad', 'viscous friction of joint 1'),
    BaseParameter('FV2', 'b2', 'N m s/rad', 'viscous friction of joint 2'),
)
NAMES = tuple(p.name for p in BASE_PARAMETERS)
ZZ1R, MX1R, ZZ2, MX2, FV1, FV2 = range(6)
INERTIAL = (ZZ1R, MX1R, ZZ2, MX2)
#: A regressor whose column-scaled condition number is above this does not determine the
#: parameters: the motion did not excite them.
MAX_CONDITION = 1e3
#: Gauss-Legendre nodes on [0, 1] and weights (summing to 1) of the period integral.
_GL_X, _GL_W = np.polynomial.legendre.leggauss(4)
_GL_U, _GL_W = 0.5 * (_GL_X + 1.0), 0.5 * _GL_W


class IdentificationError(ValueError):
    """The data cannot determine the parameters; the message (one line) says why."""


def _without_motors(arm: TwoLinkArm, what: str) -> None:
    """Raise :class:`IdentificationError` if ``arm`` (named ``what``) has a motor with
    inertia or damping: the regressor has no column for them (module docstring)."""
    if any(arm.motor_inertias) or any(arm.motor_damping):
        raise IdentificationError(
            f'{what} has geared motors (motor_inertias={list(arm.motor_inertias)} kg m^2, '
            f'motor_damping={list(arm.motor_damping)} N m s/rad, gear_ratios='
            f'{list(arm.gear_ratios)}): identification models the links only (no regressor '
            "column for joint 2's reflected rotor inertia), so it refuses them; give an arm "
            'with motor_inertias and motor_damping 0')


def base_parameters(arm: TwoLinkArm) -> np.ndarray:
    """The base parameters (6,) of ``arm`` in the order of :data:`NAMES` [kg m^2, kg m,
    kg m^2, kg m, N m s/rad, N m s/rad].

    Raises
    ------
    IdentificationError
        ``arm`` has a motor with inertia or damping (module docstring).
    """
    _without_motors(arm, 'the arm')
    (l1, _), (c1, c2) = arm.link_lengths, arm.com_distances
    (m1, m2), (i1, i2) = arm.link_masses, arm.link_inertias
    return np.array([i1 + m1 * c1 ** 2 + m2 * l1 ** 2, m1 * c1 + m2 * l1,
                     i2 + m2 * c2 ** 2, m2 * c2, *arm.joint_damping])


def payload_direction(arm: TwoLinkArm) -> np.ndarray:
    """d pi / d p (6,): the change of the base parameters per kg of point payload at the
    tip, ``(l1^2, l1, l2^2, l2, 0, 0)`` [m^2, m, m^2, m, 0, 0]."""
    l1, l2 = arm.link_lengths
    return np.array([l1 * l1, l1, l2 * l2, l2, 0.0, 0.0])


def _trig(q):
    q = np.asarray(q, dtype=float)
    return np.cos(q[..., 0]), np.cos(q[..., 1]), np.sin(q[..., 1]), np.cos(q[..., 0] + q[..., 1])


def regressor(q, qd, qdd, l1: float, g0: float) -> np.ndarray:
    """Y (..., 2, 6) [N m per parameter unit] with ``Y pi = D q'' + C q' + g + B q'``, the
    inverse dynamics (Khalil & Dombre §9.2: the dynamic model is linear in the inertial
    parameters). ``l1`` [m] link 1's length, ``g0`` [m/s^2] gravity (along -y)."""
    qd, qdd = np.asarray(qd, dtype=float), np.asarray(qdd, dtype=float)
    c1, c2, s2, c12 = _trig(q)
    w1, w2, a1, a2 = qd[..., 0], qd[..., 1], qdd[..., 0], qdd[..., 1]
    y = np.zeros(np.broadcast_shapes(c1.shape, w1.shape, a1.shape) + (2, 6))
    y[..., 0, ZZ1R] = a1
    y[..., 0, MX1R] = g0 * c1
    y[..., 0, ZZ2] = y[..., 1, ZZ2] = a1 + a2
    y[..., 0, MX2] = l1 * (c2 * (2.0 * a1 + a2) - s2 * w2 * (2.0 * w1 + w2)) + g0 * c12
    y[..., 1, MX2] = l1 * (c2 * a1 + s2 * w1 * w1) + g0 * c12
    y[..., 0, FV1] = w1
    y[..., 1, FV2] = w2
    return y


def momentum_regressor(q, qd, l1: float) -> np.ndarray:
    """Y_p (..., 2, 6) [N m s per parameter unit] with ``Y_p pi = D(q) q'``, the generalized
    momentum."""
    qd = np.asarray(qd, dtype=float)
    _, c2, _, _ = _trig(q)
    w1, w2 = qd[..., 0], qd[..., 1]
    y = np.zeros(np.broadcast_shapes(c2.shape, w1.shape) + (2, 6))
    y[..., 0, ZZ1R] = w1
    y[..., 0, ZZ2] = y[..., 1, ZZ2] = w1 + w2
    y[..., 0, MX2] = l1 * c2 * (2.0 * w1 + w2)
    y[..., 1, MX2] = l1 * c2 * w1
    return y


def rest_regressor(q, qd, l1: float, g0: float) -> np.ndarray:
    """Y_n (..., 2, 6) [N m per parameter unit] with ``Y_n pi = tau - d/dt (D q') = g + B q'
    + (C - D') q'``; for this arm ``(C - D') q' = -C^T q' = (0, b sin q2 q1' (q1' + q2'))``
    (Siciliano et al. §7.2: ``D' = C + C^T``)."""
    qd = np.asarray(qd, dtype=float)
    c1, _, s2, c12 = _trig(q)
    w1, w2 = qd[..., 0], qd[..., 1]
    y = np.zeros(np.broadcast_shapes(c1.shape, w1.shape) + (2, 6))
    y[..., 0, MX1R] = g0 * c1
    y[..., 0, MX2] = g0 * c12
    y[..., 1, MX2] = l1 * s2 * w1 * (w1 + w2) + g0 * c12
    y[..., 0, FV1] = w1
    y[..., 1, FV2] = w2
    return y


def energy_regressor(q, qd, l1: float, g0: float) -> np.ndarray:
    """Y_E (..., 6) [J per parameter unit] with ``Y_E pi`` the mechanical energy
    (kinetic + potential, zero at the base height; damping columns zero), for checks."""
    qd = np.asarray(qd, dtype=float)
    q = np.asarray(q, dtype=float)
    _, c2, _, _ = _trig(q)
    w1, w2 = qd[..., 0], qd[..., 1]
    y = np.zeros(np.broadcast_shapes(c2.shape, w1.shape) + (6,))
    y[..., ZZ1R] = 0.5 * w1 * w1
    y[..., MX1R] = g0 * np.sin(q[..., 0])
    y[..., ZZ2] = 0.5 * (w1 + w2) ** 2
    y[..., MX2] = l1 * c2 * w1 * (w1 + w2) + g0 * np.sin(q[..., 0] + q[..., 1])
    return y


@dataclass(frozen=True)
class HoldPeriods:
    """Control periods each with one torque held: the state at the start ``(q0, qd0)`` and
    at the end ``(q1, qd1)`` (M, 2) [rad, rad/s], the ``period`` (M,) [s], the held torque
    ``tau`` (M, 2) [N m] and the period's end ``end_ns`` (M,) [ns, the stamp]."""

    q0: np.ndarray
    qd0: np.ndarray
    q1: np.ndarray
    qd1: np.ndarray
    period: np.ndarray
    tau: np.ndarray
    end_ns: np.ndarray

    def __len__(self) -> int:
        return len(self.period)

    @staticmethod
    def concatenate(parts: Sequence[HoldPeriods]) -> HoldPeriods:
        """The periods of ``parts`` one after the other."""
        return HoldPeriods(*(np.concatenate([getattr(p, f) for p in parts]) for f in
                             ('q0', 'qd0', 'q1', 'qd1', 'period', 'tau', 'end_ns')))


def hold_periods(stamp_ns, position, velocity, effort) -> HoldPeriods:
    """The hold periods of a joint-state stream as the simulator publishes it: ``effort[k]``
    [N m] is the torque held over ``[t_(k-1), t_k]``.

    Parameters
    ----------
    stamp_ns : (N,) int, ns -- header stamps, in order; a state repeating the previous
        stamp (re-sent) is dropped.
    position, velocity, effort : (N, 2) rad, rad/s, N m.

    Returns
    -------
    HoldPeriods
        One per consecutive pair of states one control period apart (the most common
        stamp step): across a longer step (a lost message) more than one torque was held,
        so that pair is left out; so are pairs with a non-finite value.
    """
    stamp = np.asarray(stamp_ns, dtype=np.int64)
    q, qd, tau = (np.asarray(a, dtype=float) for a in (position, velocity, effort))
    if len(stamp) >= 2:
        keep = np.r_[True, np.diff(stamp) != 0]
        stamp, q, qd, tau = stamp[keep], q[keep], qd[keep], tau[keep]
    empty = HoldPeriods(*(np.zeros((0, 2)),) * 4, np.zeros(0), np.zeros((0, 2)),
                        np.zeros(0, np.int64))
    if len(stamp) < 2:
        return empty
    step = np.diff(stamp)
    values, counts = np.unique(step[step > 0], return_counts=True)
    if not len(values):
        return empty
    period = values[np.argmax(counts)]
    ok = (step == period) & np.isfinite(q[1:] + q[:-1] + qd[1:] + qd[:-1] + tau[1:]).all(1)
    i = np.flatnonzero(ok)
    return HoldPeriods(q[i], qd[i], q[i + 1], qd[i + 1], np.full(len(i), period * 1e-9),
                       tau[i + 1], stamp[i + 1])


def period_regressor(periods: HoldPeriods, l1: float, g0: float) -> np.ndarray:
    """Y (M, 2, 6) [N m per parameter unit] of the momentum form integrated over each hold
    period (module docstring): ``Y pi`` is the torque held over the period, to ``O(T^4)``.

    ``[Y_p(end) - Y_p(start)] / T`` plus the mean of :func:`rest_regressor` over the period
    by 4-point Gauss-Legendre along the cubic Hermite interpolant of ``(q, q')`` at both
    ends (Hairer, Norsett, Wanner, *Solving ODEs I*, §II.6 dense output).
    """
    t = periods.period[:, None]
    q0, q1 = periods.q0, periods.q1
    v0, v1 = periods.qd0 * t, periods.qd1 * t  # velocities in units of the period
    mean = np.zeros((len(t), 2, 6))
    for u, w in zip(_GL_U, _GL_W):
        h00, h10 = 2 * u ** 3 - 3 * u ** 2 + 1, u ** 3 - 2 * u ** 2 + u
        h01, h11 = -2 * u ** 3 + 3 * u ** 2, u ** 3 - u ** 2
        d00, d10 = 6 * u ** 2 - 6 * u, 3 * u ** 2 - 4 * u + 1
        d01, d11 = -6 * u ** 2 + 6 * u, 3 * u ** 2 - 2 * u
        q = h00 * q0 + h10 * v0 + h01 * q1 + h11 * v1
        qd = (d00 * q0 + d10 * v0 + d01 * q1 + d11 * v1) / t
        mean += w * rest_regressor(q, qd, l1, g0)
    dp = momentum_regressor(q1, periods.qd1, l1) - momentum_regressor(q0, periods.qd0, l1)
    return dp / t[:, :, None] + mean


@dataclass(frozen=True)
class Estimate:
    """A least-squares estimate of the base parameters.

    Attributes
    ----------
    values : (6,) -- in the order and units of :data:`NAMES`.
    std_errors : (6,) -- standard errors, same units (0 for a parameter held ``fixed``).
    covariance : (6, 6) -- of ``values`` (rows and columns of held parameters zero).
    fixed : tuple of int -- the parameters held at given values, not estimated.
    condition : float -- condition number of the weighted regressor, columns scaled to unit
        norm [-].
    residual_rms : (2,) N m -- the torque residual per joint.
    rows : int -- equations used (2 per period).
    """

    values: np.ndarray
    std_errors: np.ndarray
    covariance: np.ndarray
    fixed: tuple[int, ...]
    condition: float
    residual_rms: np.ndarray
    rows: int


def estimate(y: np.ndarray, tau: np.ndarray, fixed: dict[int, float] | None = None
             ) -> Estimate:
    """Weighted least squares of ``tau = y pi`` (module docstring).

    Parameters
    ----------
    y : (M, 2, 6) N m per parameter unit -- the regressor (e.g. :func:`period_regressor`).
    tau : (M, 2) N m -- the torques.
    fixed : {column: value} -- parameters held at known values (their columns times the
        value are taken off ``tau``), e.g. damping known, or MX1R without gravity.

    Raises
    ------
    IdentificationError
        Too few periods, or the motion does not excite the parameters (a column of zeros,
        or a condition number above :data:`MAX_CONDITION`), naming the parameters.
    """
    fixed = dict(fixed or {})
    free = [i for i in range(6) if i not in fixed]
    y = np.asarray(y, dtype=float)
    tau = np.asarray(tau, dtype=float)
    if len(tau) < len(free):
        raise IdentificationError(f'{len(tau)} hold periods: too few to identify '
                                  f'{len(free)} parameters (record a longer excitation)')
    target = tau - sum((y[:, :, i] * v for i, v in fixed.items()), np.zeros_like(tau))
    a = y[:, :, free]
    # First pass: ordinary least squares, for each joint's residual spread (the weights).
    theta, _ = _lstsq(a.reshape(-1, len(free)), target.reshape(-1), free)
    resid = target - a @ theta
    rms = np.sqrt(np.mean(resid ** 2, axis=0))
    scale = np.sqrt(np.mean(target ** 2, axis=0))
    weights = 1.0 / np.maximum(rms, 1e-12 * max(float(scale.max()), 1e-300))
    aw = (a * weights[None, :, None]).reshape(-1, len(free))
    bw = (target * weights).reshape(-1)
    theta, cond = _lstsq(aw, bw, free)
    resid = target - a @ theta
    rw = (resid * weights).reshape(-1)
    dof = max(len(bw) - len(free), 1)
    s2 = float(rw @ rw) / dof
    cov_free = s2 * np.linalg.inv(aw.T @ aw)
    values = np.zeros(6)
    cov = np.zeros((6, 6))
    values[free] = theta
    for i, v in fixed.items():
        values[i] = v
    cov[np.ix_(free, free)] = cov_free
    return Estimate(values, np.sqrt(np.clip(np.diag(cov), 0.0, None)), cov,
                    tuple(sorted(fixed)), cond,
                    np.sqrt(np.mean(resid ** 2, axis=0)), len(bw))


def _lstsq(a: np.ndarray, b: np.ndarray, free: list[int]) -> tuple[np.ndarray, float]:
    """Least squares of ``a x = b`` after the excitation check; (x, condition number of
    ``a`` with unit-norm columns)."""
    norms = np.linalg.norm(a, axis=0)
    dead = [NAMES[free[j]] for j in np.flatnonzero(~(norms > 0.0))]
    if dead:
        raise IdentificationError(f"the motion does not excite {', '.join(dead)} (its "
                                  'regressor column is zero): record an excitation with '
                                  'both joints moving (docs/identify.md)')
    scaled = a / norms
    sv = np.linalg.svd(scaled, compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float('inf')
    if not cond <= MAX_CONDITION:
        _, _, vt = np.linalg.svd(scaled)
        worst = vt[-1] / norms
        weak = [NAMES[free[j]] for j in np.argsort(-np.abs(vt[-1]))[:2]]
        raise IdentificationError(
            f'the motion does not excite the parameters: regressor condition number '
            f'{cond:.3g} > {MAX_CONDITION:g} (least determined: {" and ".join(weak)}, '
            f'direction {np.round(worst / np.abs(worst).max(), 3).tolist()}); record an '
            'excitation with both joints moving over a range of speeds (docs/identify.md)')
    x, *_ = np.linalg.lstsq(scaled, b, rcond=None)
    return x / norms, cond


def identify(periods: HoldPeriods, l1: float, g0: float,
             fixed: dict[int, float] | None = None) -> Estimate:
    """The base parameters from hold periods: :func:`estimate` on
    :func:`period_regressor`. With ``g0 == 0`` MX1R does not enter the dynamics: give its
    value in ``fixed`` (else it is held at 0)."""
    fixed = dict(fixed or {})
    if g0 == 0.0:
        fixed.setdefault(MX1R, 0.0)
    return estimate(period_regressor(periods, l1, g0), periods.tau, fixed)


def predict(values, periods: HoldPeriods, l1: float, g0: float) -> np.ndarray:
    """The torque (M, 2) [N m] each period's motion needs under base parameters ``values``
    (6,): the held torque, if the parameters are the arm's."""
    return period_regressor(periods, l1, g0) @ np.asarray(values, dtype=float)


def prediction_error(values, periods: HoldPeriods, l1: float, g0: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(RMS error [N m], the same as % of the RMS measured torque), each (2,), of the
    torques :func:`predict` gives against the held torques of ``periods``."""
    err = predict(values, periods, l1, g0) - periods.tau
    rms = np.sqrt(np.mean(err ** 2, axis=0))
    ref = np.sqrt(np.mean(periods.tau ** 2, axis=0))
    with np.errstate(divide='ignore', invalid='ignore'):
        pct = np.where(ref > 0, 100.0 * rms / ref, np.nan)
    return rms, pct


def payload_mass(est: Estimate, nominal: TwoLinkArm) -> tuple[float, float]:
    """The tip payload [kg] and its standard error [kg] that take ``nominal``'s base
    parameters to the estimated ones.

    Generalized least squares of the one number ``p`` in ``pi_hat - pi_nominal = p s``
    (``s`` = :func:`payload_direction`) over the inertial parameters, weighted by their
    covariance ``S``: ``p = s^T S^-1 dpi / (s^T S^-1 s)``, standard error
    ``(s^T S^-1 s)^-1/2`` (Kay, *Fundamentals of Statistical Signal Processing: Estimation
    Theory* (1993), §4.6 and §6.5: the BLUE). A held parameter (zero variance) is left out.
    """
    idx = [i for i in INERTIAL if i not in est.fixed]
    s = payload_direction(nominal)[idx]
    dpi = (est.values - base_parameters(nominal))[idx]
    cov = est.covariance[np.ix_(idx, idx)]
    # Normalise first: the variances may be tiny (noise-free data) or large.
    d = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    if not (d > 0).all():
        # An exact fit (no residual): plain least squares.
        return float(s @ dpi / (s @ s)), 0.0
    corr = cov / np.outer(d, d)
    sn, dn = s / d, dpi / d
    info = float(sn @ np.linalg.solve(corr, sn))
    return float(sn @ np.linalg.solve(corr, dn)) / info, 1.0 / np.sqrt(info)


def identified_arm(values, nominal: TwoLinkArm, payload: float = 0.0,
                   std_errors=None) -> TwoLinkArm:
    """An arm (robot parameter values) whose base parameters are ``values`` (6,), the
    geometry and gravity ``nominal``'s: what the controller's ``control_model.*`` takes.

    Only the groupings are identified, so one physical split is chosen: link 1's mass
    ``nominal``'s, link 2's ``nominal``'s plus ``payload`` [kg]; then ``lc2 = MX2 / m2``,
    ``I2 = ZZ2 - m2 lc2^2``, ``lc1 = (MX1R - m2 l1) / m1``, ``I1 = ZZ1R - m1 lc1^2 - m2
    l1^2``. Any split with these groupings has the same dynamics; when the change is a tip
    payload ``p`` exactly, this is ``nominal.with_payload(p)`` (to rounding).

    A value below zero by less than rounding (1e-6 of the largest inertial parameter) or,
    for the friction, than 3 ``std_errors`` (6,) is taken as 0.

    Raises
    ------
    IdentificationError
        No physical arm has these groupings with those masses (a negative inertia or
        centre-of-gravity distance, or friction below zero by more than that), naming
        the value; or ``nominal`` has a motor with inertia or damping (module docstring;
        its gear ratios alone are carried over).
    """
    _without_motors(nominal, 'the nominal arm')
    v = np.asarray(values, dtype=float)
    l1, _ = nominal.link_lengths
    m1, m2 = nominal.link_masses[0], nominal.link_masses[1] + payload
    if not m2 > 0.0:
        raise IdentificationError(f'link 2 mass {m2:g} kg (nominal plus payload {payload:g} '
                                  'kg) is not positive')
    lc2 = v[MX2] / m2
    i2 = v[ZZ2] - m2 * lc2 ** 2
    lc1 = (v[MX1R] - m2 * l1) / m1
    i1 = v[ZZ1R] - m1 * lc1 ** 2 - m2 * l1 ** 2
    tiny = 1e-6 * max(1.0, float(np.abs(v[:4]).max()))
    se = np.zeros(6) if std_errors is None else np.asarray(std_errors, dtype=float)
    named = {'com_distances[0]': (lc1, tiny), 'com_distances[1]': (lc2, tiny),
             'link_inertias[0]': (i1, tiny), 'link_inertias[1]': (i2, tiny),
             'joint_damping[0]': (v[FV1], max(tiny, 3 * se[FV1])),
             'joint_damping[1]': (v[FV2], max(tiny, 3 * se[FV2]))}
    for name, (x, tol) in named.items():
        if x < -tol:
            raise IdentificationError(
                f'the identified parameters need {name} = {x:.6g} < 0 (with link masses '
                f'{m1:g}, {m2:g} kg): no physical arm has them; check the nominal arm '
                '(--nominal) and the excitation')
    clip = [max(0.0, float(x)) for x in (lc1, lc2, i1, i2, v[FV1], v[FV2])]
    try:
        return TwoLinkArm(link_lengths=nominal.link_lengths, com_distances=(clip[0], clip[1]),
                          link_masses=(m1, m2), link_inertias=(clip[2], clip[3]),
                          gravity=nominal.gravity, joint_damping=(clip[4], clip[5]),
                          gear_ratios=nominal.gear_ratios)
    except ValueError as exc:
        raise IdentificationError(f'the identified arm is not a valid model: {exc}') from None
