"""Closed-form dynamics of the planar two-link revolute (2-R) arm.

Convention (the contract's): ``q1`` is measured from the +x axis, ``q2`` relative to link 1,
gravity acts along -y, and the potential energy is zero at the base height. The equations
of motion are ``D(q) qdd + C(q, qd) qd + g(q) + B qd = tau`` with ``B = diag(joint_damping
+ n^2 Bm)``.

Geared motors: joint ``i`` is driven through a gear of ratio ``n_i`` (``gear_ratios``, motor
turns per joint turn) by a motor of rotor inertia ``Jm_i`` (``motor_inertias``) and viscous
friction ``Bm_i`` (``motor_damping``), both on the motor side. Torques stay joint-side
(``tau_i`` = ``n_i`` times the motor torque). The rotor turns at ``n_i qd_i``, so it adds
``n_i^2 Jm_i qd_i^2 / 2`` to the kinetic energy and ``n_i^2 Bm_i qd_i`` to the joint's
friction: the *reflected* inertia ``A_i = n_i^2 Jm_i`` (MuJoCo's joint ``armature``,
Pinocchio's ``model.armature``) sits on the diagonal of ``D`` and ``n_i^2 Bm_i`` adds to
``joint_damping`` (rotor gyroscopic terms neglected, as usual for high ratios). Defaults
``n = 1``, ``Jm = Bm = 0``: no motors. Spong, Hutchinson, Vidyasagar, *Robot Modeling and
Control*, Dynamics chapter (the actuator's reflected inertia in ``D(q)``) and Independent
Joint Control chapter (actuator dynamics, ``J = Jm + Jl / n^2`` seen from the motor).

With ``a = m1 lc1^2 + m2 (l1^2 + lc2^2) + I1 + I2 + A1``, ``b = m2 l1 lc2``,
``d = m2 lc2^2 + I2`` and ``e = d + A2``::

    D = [[a + 2 b cos q2, d + b cos q2],
         [d + b cos q2,   e          ]]
    C = b sin q2 [[-qd2, -(qd1 + qd2)],      (Christoffel form: D' - 2C is skew)
                  [ qd1,  0          ]]
    g = [(m1 lc1 + m2 l1) g0 cos q1 + m2 lc2 g0 cos(q1 + q2), m2 lc2 g0 cos(q1 + q2)]

(without motors ``e = d``: ``D22`` is the constant part of ``D12``; with them it is not.)

Every state-taking method accepts one state, shape ``(2,)``, or a batch, shape ``(N, 2)``
(any leading shape broadcasts). Single states of (2,) arrays take a pure-float hot path,
validated once at the call (a forward-dynamics call costs about what ``pinocchio.aba`` does
from Python, ~1 us); :func:`_make_step` is the unchecked RK4 behind ``step``, for cores that
validated their state once.

Kinematics (the one place their formulas live; planner, analysis and tests call these):
forward kinematics ``p = (l1 cos q1 + l2 cos(q1 + q2), l1 sin q1 + l2 sin(q1 + q2))``, the
Jacobian ``J = dp/dq``, ``J' q'`` (so ``p'' = J q'' + J' q'``), closed-form inverse
kinematics with an elbow choice, and the workspace check that refuses a point with the
numbers. Angles are counter-clockwise positive, y up.

Elbow branches: every reachable point off the workspace boundary has two solutions, mirror
images about the line from the base to the point.

* ``'down'``: ``q2 > 0`` (``sin q2 > 0``). The elbow lies clockwise of the base-to-tip
  line, i.e. *below* it when the arm reaches towards +x.
* ``'up'``: ``q2 < 0`` (``sin q2 < 0``). The elbow lies counter-clockwise of that line,
  *above* it when reaching towards +x.

(With ``q2 > 0`` link 2 turns counter-clockwise from link 1, so link 1 must point below the
target direction: ``q1 = atan2(y, x) - atan2(l2 sin q2, l1 + l2 cos q2)``.) A
configuration with ``sin q2 = 0`` (arm stretched or folded) is singular (``det J = l1 l2
sin q2``) and counts as ``'down'`` where a branch must be named. ``cos q2 = (r^2 - l1^2 -
l2^2) / (2 l1 l2)`` depends on the tip's distance ``r`` from the base only, so ``|sin q2|``
is smallest at the ends of the reachable annulus ``|l1 - l2| <= r <= l1 + l2``.

References: Siciliano et al., *Robotics: Modelling, Planning and Control* (2009), §7.1
(Lagrange formulation), §7.2 (skew-symmetry of D' - 2C), §7.3.2 (this arm); Spong,
Hutchinson, Vidyasagar, *Robot Modeling and Control*, the planar elbow manipulator
(Dynamics chapter, "some common configurations"); forward kinematics and the Jacobian:
Siciliano et al. §2.9, §3.1.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from arm_dynamics._validate import finite_scalar, finite_tuple, state_array, step_count

Pair = tuple[float, float]
_isfinite, _cos, _sin = math.isfinite, math.cos, math.sin
_array, _empty = np.array, np.empty


def _pair(name: str, x: object) -> Pair | None:
    """Fast path: ``x`` as two finite floats, or None if ``x`` is not a single 2-vector."""
    if type(x) is np.ndarray:
        if x.shape != (2,):
            return None
        a, b = x.tolist()  # 3x cheaper than unpacking numpy scalars
    else:
        try:
            a, b = x  # type: ignore[misc]
        except (TypeError, ValueError):
            return None
    try:
        a = float(a)
        b = float(b)
    except (TypeError, ValueError):
        return None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise ValueError(f'{name} must be finite, got {x!r}')
    return a, b


def _make_accel(k: tuple[float, ...], cos: Callable, sin: Callable) -> Callable:
    """qdd(q1, q2, qd1, qd2, t1, t2) for one parameter set ``k``; with ``math`` functions it
    takes floats, with ``numpy`` ones arrays: the single formula both paths use. Solves
    ``D qdd = tau - C qd - g - B qd`` (2x2, closed form).

    ``k = (a, b, d, e, g1, g2, b1, b2)``: the lumped constants of the module docstring
    (``D11 = a + 2 b cos q2``, ``D12 = d + b cos q2``, ``D22 = e``, both armatures
    included), ``g1 = (m1 lc1 + m2 l1) g0``, ``g2 = m2 lc2 g0`` [N m] and the joints' total
    viscous damping ``b_i = joint_damping_i + n_i^2 Bm_i`` [N m s/rad]."""
    a, b, d, e, g1, g2, b1, b2 = k

    def accel(q1, q2, qd1, qd2, t1, t2):
        c2 = cos(q2)
        bs2 = b * sin(q2)
        gc12 = g2 * cos(q1 + q2)
        d11 = a + 2.0 * b * c2
        d12 = d + b * c2
        r1 = t1 + bs2 * qd2 * (2.0 * qd1 + qd2) - g1 * cos(q1) - gc12 - b1 * qd1
        r2 = t2 - bs2 * qd1 * qd1 - gc12 - b2 * qd2
        det = d11 * e - d12 * d12
        return (e * r1 - d12 * r2) / det, (d11 * r2 - d12 * r1) / det

    return accel


def _make_inverse(k: tuple[float, ...], cos: Callable, sin: Callable) -> Callable:
    """tau(q1, q2, qd1, qd2, qdd1, qdd2) = D qdd + C qd + g + B qd for one parameter set
    ``k``, term for term the left-hand side of :func:`_make_accel`'s equation."""
    a, b, d, e, g1, g2, b1, b2 = k

    def inverse(q1, q2, qd1, qd2, a1, a2):
        c2 = cos(q2)
        bs2 = b * sin(q2)
        gc12 = g2 * cos(q1 + q2)
        d12 = d + b * c2
        t1 = ((a + 2.0 * b * c2) * a1 + d12 * a2 - bs2 * qd2 * (2.0 * qd1 + qd2)
              + g1 * cos(q1) + gc12 + b1 * qd1)
        t2 = d12 * a1 + e * a2 + bs2 * qd1 * qd1 + gc12 + b2 * qd2
        return t1, t2

    return inverse


def _make_step(k: tuple[float, ...]) -> Callable[..., tuple[float, float, float, float]]:
    """The unchecked single-state RK4 for one parameter set ``k``: ``step(q1, q2, qd1, qd2,
    t1, t2, dt, n_steps) -> (q1, q2, qd1, qd2)`` on floats [rad, rad/s, N m, s].

    :func:`_rk4` around :func:`_make_accel`'s formula with ``math`` functions, written out
    (the four accelerations inlined, no call per stage): the same operations in the same
    order, so the results are bit-identical to ``_rk4(_make_accel(k, math.cos, math.sin),
    ...)``, about twice as fast. No validation: callers pass finite floats, ``dt > 0`` and
    an int ``n_steps >= 1`` (:meth:`TwoLinkArm.step` checks them once at its boundary).
    """
    a, b, d, e, g1, g2, b1, b2 = k
    cos, sin = math.cos, math.sin
    b2x = 2.0 * b

    def step(q1: float, q2: float, qd1: float, qd2: float, t1: float, t2: float,
             dt: float, n_steps: int) -> tuple[float, float, float, float]:
        h2 = 0.5 * dt
        h6 = dt / 6.0
        for _ in range(n_steps):
            # stage 1 at (q, qd)
            c2 = cos(q2)
            bs2 = b * sin(q2)
            gc12 = g2 * cos(q1 + q2)
            d11 = a + b2x * c2
            d12 = d + b * c2
            r1 = t1 + bs2 * qd2 * (2.0 * qd1 + qd2) - g1 * cos(q1) - gc12 - b1 * qd1
            r2 = t2 - bs2 * qd1 * qd1 - gc12 - b2 * qd2
            det = d11 * e - d12 * d12
            a1, e1 = (e * r1 - d12 * r2) / det, (d11 * r2 - d12 * r1) / det
            p1, p2, v1, v2 = q1 + h2 * qd1, q2 + h2 * qd2, qd1 + h2 * a1, qd2 + h2 * e1
            # stage 2 at (p, v)
            c2 = cos(p2)
            bs2 = b * sin(p2)
            gc12 = g2 * cos(p1 + p2)
            d11 = a + b2x * c2
            d12 = d + b * c2
            r1 = t1 + bs2 * v2 * (2.0 * v1 + v2) - g1 * cos(p1) - gc12 - b1 * v1
            r2 = t2 - bs2 * v1 * v1 - gc12 - b2 * v2
            det = d11 * e - d12 * d12
            a2, e2 = (e * r1 - d12 * r2) / det, (d11 * r2 - d12 * r1) / det
            p1, p2, w1, w2 = q1 + h2 * v1, q2 + h2 * v2, qd1 + h2 * a2, qd2 + h2 * e2
            # stage 3 at (p, w)
            c2 = cos(p2)
            bs2 = b * sin(p2)
            gc12 = g2 * cos(p1 + p2)
            d11 = a + b2x * c2
            d12 = d + b * c2
            r1 = t1 + bs2 * w2 * (2.0 * w1 + w2) - g1 * cos(p1) - gc12 - b1 * w1
            r2 = t2 - bs2 * w1 * w1 - gc12 - b2 * w2
            det = d11 * e - d12 * d12
            a3, e3 = (e * r1 - d12 * r2) / det, (d11 * r2 - d12 * r1) / det
            p1, p2, u1, u2 = q1 + dt * w1, q2 + dt * w2, qd1 + dt * a3, qd2 + dt * e3
            # stage 4 at (p, u)
            c2 = cos(p2)
            bs2 = b * sin(p2)
            gc12 = g2 * cos(p1 + p2)
            d11 = a + b2x * c2
            d12 = d + b * c2
            r1 = t1 + bs2 * u2 * (2.0 * u1 + u2) - g1 * cos(p1) - gc12 - b1 * u1
            r2 = t2 - bs2 * u1 * u1 - gc12 - b2 * u2
            det = d11 * e - d12 * d12
            a4, e4 = (e * r1 - d12 * r2) / det, (d11 * r2 - d12 * r1) / det
            q1 = q1 + h6 * (qd1 + 2.0 * (v1 + w1) + u1)
            q2 = q2 + h6 * (qd2 + 2.0 * (v2 + w2) + u2)
            qd1 = qd1 + h6 * (a1 + 2.0 * (a2 + a3) + a4)
            qd2 = qd2 + h6 * (e1 + 2.0 * (e2 + e3) + e4)
        return q1, q2, qd1, qd2

    return step


def _make_forward_dynamics(k: tuple[float, ...], checked: Callable[..., np.ndarray]
                           ) -> Callable[..., np.ndarray]:
    """The single-state hot path of :meth:`TwoLinkArm.forward_dynamics` for one parameter
    set ``k``: ``fd(q, qd, tau) -> qdd``, three (2,) float arrays in, a new (2,) array out.

    Built once per arm, so the constants are closure cells (no attribute look-up or tuple
    unpacking per call), and installed as the instance's ``forward_dynamics``. The inputs are
    unpacked with ``tolist`` and :func:`_make_accel`'s formula runs inline, term for term
    (bit-identical). It is checked once, on the result: a non-finite input gives a
    non-finite result or raises (``math.cos(inf)``), and either, like any argument that is
    not a (2,) array, goes to ``checked`` (the validating path), which names the bad
    argument or, for finite inputs that overflow, returns the same values.
    """
    a, b, d, e, g1, g2, b1, b2 = k
    b2x = 2.0 * b
    cos, sin, isfinite, empty = math.cos, math.sin, math.isfinite, np.empty

    def forward_dynamics(q, qd, tau):
        try:
            q1, q2 = q.tolist()
            qd1, qd2 = qd.tolist()
            t1, t2 = tau.tolist()
            c2 = cos(q2)
            bs2 = b * sin(q2)
            gc12 = g2 * cos(q1 + q2)
            d11 = a + b2x * c2
            d12 = d + b * c2
            r1 = t1 + bs2 * qd2 * (2.0 * qd1 + qd2) - g1 * cos(q1) - gc12 - b1 * qd1
            r2 = t2 - bs2 * qd1 * qd1 - gc12 - b2 * qd2
            det = d11 * e - d12 * d12
            x1 = (e * r1 - d12 * r2) / det
            x2 = (d11 * r2 - d12 * r1) / det
            if isfinite(x1 + x2):
                out = empty(2)  # 30% cheaper than np.array((x1, x2))
                out[0] = x1
                out[1] = x2
                return out
        except (AttributeError, TypeError, ValueError, OverflowError, ZeroDivisionError):
            pass
        return checked(q, qd, tau)

    return forward_dynamics


def _make_inverse_dynamics(tau_float: Callable[..., tuple[float, float]],
                           checked: Callable[..., np.ndarray]) -> Callable[..., np.ndarray]:
    """The single-state hot path of :meth:`TwoLinkArm.inverse_dynamics`, installed like
    :func:`_make_forward_dynamics`: three finite (2,) arrays go through ``tau_float``
    (:func:`_make_inverse`'s float formula; checked on the inputs, as the formula has no
    division to expose them), anything else to ``checked``."""
    isfinite, empty = math.isfinite, np.empty

    def inverse_dynamics(q, qd, qdd):
        try:
            q1, q2 = q.tolist()
            qd1, qd2 = qd.tolist()
            a1, a2 = qdd.tolist()
            ok = isfinite(q1 + q2 + qd1 + qd2 + a1 + a2)
        except (AttributeError, TypeError, ValueError):
            ok = False
        if not ok:
            return checked(q, qd, qdd)
        out = empty(2)
        out[0], out[1] = tau_float(q1, q2, qd1, qd2, a1, a2)
        return out

    return inverse_dynamics


def _fast_floats(q: object, qd: object, tau: object) -> list[float] | None:
    """The hot path: three finite (2,) float arrays as six floats, else None (the caller
    then takes the validating path, which names any bad argument)."""
    if (type(q) is np.ndarray and type(qd) is np.ndarray and type(tau) is np.ndarray
            and q.shape == qd.shape == tau.shape == (2,)):
        x = q.tolist() + qd.tolist() + tau.tolist()
        if math.isfinite(sum(x)):
            return x
    return None


def _rk4(acc: Callable, x: Sequence[Any], dt: float, n_steps: int
         ) -> tuple[Any, Any, Any, Any]:
    """Classic RK4 with the torque held over each step; ``x`` = (q1, q2, qd1, qd2, t1, t2),
    floats or arrays (``acc`` as built by :func:`_make_accel`). Returns (q1, q2, qd1, qd2)."""
    q1, q2, qd1, qd2, t1, t2 = x
    h2 = 0.5 * dt
    h6 = dt / 6.0
    for _ in range(n_steps):
        a1, b1 = acc(q1, q2, qd1, qd2, t1, t2)
        p1, p2, v1, v2 = q1 + h2 * qd1, q2 + h2 * qd2, qd1 + h2 * a1, qd2 + h2 * b1
        a2, b2 = acc(p1, p2, v1, v2, t1, t2)
        r1, r2, w1, w2 = q1 + h2 * v1, q2 + h2 * v2, qd1 + h2 * a2, qd2 + h2 * b2
        a3, b3 = acc(r1, r2, w1, w2, t1, t2)
        s1, s2, u1, u2 = q1 + dt * w1, q2 + dt * w2, qd1 + dt * a3, qd2 + dt * b3
        a4, b4 = acc(s1, s2, u1, u2, t1, t2)
        q1 = q1 + h6 * (qd1 + 2.0 * (v1 + w1) + u1)
        q2 = q2 + h6 * (qd2 + 2.0 * (v2 + w2) + u2)
        qd1 = qd1 + h6 * (a1 + 2.0 * (a2 + a3) + a4)
        qd2 = qd2 + h6 * (b1 + 2.0 * (b2 + b3) + b4)
    return q1, q2, qd1, qd2


@dataclass(frozen=True)
class TwoLinkArm:
    """Planar 2-R arm with point-mass-plus-inertia links and viscous joint damping.

    Parameters
    ----------
    link_lengths : (l1, l2), m, each > 0
        Joint axis to joint axis (link 1) and elbow axis to end effector (link 2).
    com_distances : (lc1, lc2), m, each >= 0
        Joint axis to the link's centre of gravity.
    link_masses : (m1, m2), kg, each > 0
    link_inertias : (I1, I2), kg m^2, each >= 0
        About the centre of gravity, normal to the plane. ``D(q)`` must stay positive
        definite for every ``q``; a parameter set for which it does not is refused.
    gravity : m/s^2, >= 0
        Magnitude of gravity, acting along -y.
    joint_damping : (b1, b2), N m s/rad, each >= 0
        Viscous friction torque ``-b_i qd_i`` at each joint (link side).
    gear_ratios : (n1, n2), [-], each > 0 (default 1)
        Gear reduction of each joint's drive: motor turns per joint turn.
    motor_inertias : (Jm1, Jm2), kg m^2, each >= 0 (default 0)
        Rotor inertia of each joint's motor, motor side. The joint sees the reflected
        inertia ``n_i^2 Jm_i`` (:attr:`armature`) on the diagonal of ``D(q)``.
    motor_damping : (Bm1, Bm2), N m s/rad, each >= 0 (default 0)
        Viscous friction of each motor, motor side. The joint sees ``n_i^2 Bm_i`` added to
        ``joint_damping`` (:attr:`total_damping`).

    Commands (``tau``) and every state are joint-side (link-side): ``tau_i`` is ``n_i``
    times motor ``i``'s torque, ``qd_i`` its speed over ``n_i``. Spong, Hutchinson,
    Vidyasagar, *Robot Modeling and Control*, Dynamics chapter (reflected rotor inertia in
    ``D(q)``) and Independent Joint Control chapter (actuator dynamics).
    """

    link_lengths: Pair = (1.0, 0.8)
    com_distances: Pair = (0.5, 0.4)
    link_masses: Pair = (2.0, 1.5)
    link_inertias: Pair = (0.1, 0.08)
    gravity: float = 9.81
    joint_damping: Pair = (0.0, 0.0)
    gear_ratios: Pair = (1.0, 1.0)
    motor_inertias: Pair = (0.0, 0.0)
    motor_damping: Pair = (0.0, 0.0)
    n_dof: int = field(default=2, init=False)
    # Derived in __post_init__, not arguments: the lumped constants (a, b, d, e, g1, g2, b1,
    # b2; see _make_accel) and the formulas built from them (float and array versions).
    _k: tuple[float, ...] = field(init=False, repr=False, compare=False)
    _acc_float: Callable[..., Any] = field(init=False, repr=False, compare=False)
    _acc_array: Callable[..., Any] = field(init=False, repr=False, compare=False)
    _tau_float: Callable[..., Any] = field(init=False, repr=False, compare=False)
    _step_float: Callable[..., Any] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        checks: dict[str, dict[str, Any]] = {
            'link_lengths': dict(minimum=0.0, strict=True),
            'com_distances': dict(minimum=0.0),
            'link_masses': dict(minimum=0.0, strict=True),
            'link_inertias': dict(minimum=0.0),
            'joint_damping': dict(minimum=0.0),
            'gear_ratios': dict(minimum=0.0, strict=True),
            'motor_inertias': dict(minimum=0.0),
            'motor_damping': dict(minimum=0.0),
        }
        for name, kw in checks.items():
            object.__setattr__(self, name, finite_tuple(name, getattr(self, name), 2, **kw))
        object.__setattr__(self, 'gravity', finite_scalar('gravity', self.gravity, minimum=0.0))
        (l1, _), (lc1, lc2) = self.link_lengths, self.com_distances
        (m1, m2), (i1, i2) = self.link_masses, self.link_inertias
        (arm1, arm2), (bt1, bt2) = self.armature, self.total_damping
        a = m1 * lc1**2 + m2 * (l1**2 + lc2**2) + i1 + i2 + arm1
        b = m2 * l1 * lc2
        d = m2 * lc2**2 + i2
        e = d + arm2
        # det D(q) = a e - d^2 + 2 b (e - d) cos q2 - b^2 cos^2 q2, concave in cos q2, is
        # smallest at cos q2 = -1 (e >= d, b >= 0); without motors a d - d^2 - b^2.
        if not (e > 0.0 and a * e - d * d - b * b - 2.0 * b * (e - d) > 1e-12 * a * e):
            raise ValueError(
                'link_inertias/com_distances: the mass matrix D(q) is singular for some q '
                f'(link_inertias={self.link_inertias}, com_distances={self.com_distances}, '
                f'motor_inertias={self.motor_inertias}); give link 2 a positive inertia or a '
                'non-zero com distance')
        k = (a, b, d, e, (m1 * lc1 + m2 * l1) * self.gravity, m2 * lc2 * self.gravity,
             bt1, bt2)
        object.__setattr__(self, '_k', k)
        object.__setattr__(self, '_acc_float', _make_accel(k, math.cos, math.sin))
        object.__setattr__(self, '_acc_array', _make_accel(k, np.cos, np.sin))
        object.__setattr__(self, '_tau_float', _make_inverse(k, math.cos, math.sin))
        object.__setattr__(self, '_step_float', _make_step(k))
        # The single-state hot paths, as instance attributes: they shadow the methods, which
        # stay the documented, validating fall-backs.
        object.__setattr__(self, 'forward_dynamics', _make_forward_dynamics(
            k, TwoLinkArm.forward_dynamics.__get__(self)))
        object.__setattr__(self, 'inverse_dynamics', _make_inverse_dynamics(
            self._tau_float, TwoLinkArm.inverse_dynamics.__get__(self)))
        for name in ('forward_dynamics', 'inverse_dynamics'):
            getattr(self, name).__doc__ = getattr(TwoLinkArm, name).__doc__

    def __reduce__(self) -> tuple[type, tuple[Any, ...]]:
        """Pickle as the constructor arguments (the derived formulas are rebuilt)."""
        return type(self), tuple(getattr(self, name) for name in self.PARAMETERS)

    #: The constructor arguments, which are also the robot parameters' names.
    PARAMETERS = ('link_lengths', 'com_distances', 'link_masses', 'link_inertias', 'gravity',
                  'joint_damping', 'gear_ratios', 'motor_inertias', 'motor_damping')

    @property
    def armature(self) -> Pair:
        """``(n1^2 Jm1, n2^2 Jm2)`` [kg m^2]: each rotor's inertia reflected to its joint,
        added to the diagonal of ``D(q)`` (MuJoCo's joint ``armature``)."""
        (n1, n2), (j1, j2) = self.gear_ratios, self.motor_inertias
        return n1 * n1 * j1, n2 * n2 * j2

    @property
    def total_damping(self) -> Pair:
        """``joint_damping + n^2 Bm`` [N m s/rad] per joint: the viscous friction the
        joint sees, link side plus the motor's reflected through the gear (``B``)."""
        (b1, b2), (n1, n2), (f1, f2) = self.joint_damping, self.gear_ratios, self.motor_damping
        return b1 + n1 * n1 * f1, b2 + n2 * n2 * f2

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> TwoLinkArm:
        """The arm from robot parameters by name (missing ones take the defaults, other
        keys are ignored): one construction for simulator, controller and planner."""
        return cls(**{k: params[k] for k in cls.PARAMETERS if k in params})

    # ------------------------------------------------------------------ public API
    def mass_matrix(self, q) -> np.ndarray:
        """D(q), kg m^2: shape (2, 2), or (..., 2, 2) for a batch of q (..., 2) [rad]; the
        reflected rotor inertias (:attr:`armature`) included on the diagonal."""
        q = state_array('q', q, 2)
        a, b, d, e = self._k[:4]
        c2 = np.cos(q[..., 1])
        d12 = d + b * c2
        return np.stack([np.stack([a + 2.0 * b * c2, d12], -1),
                         np.stack([d12, np.full_like(c2, e)], -1)], -2)

    def coriolis_matrix(self, q, qd) -> np.ndarray:
        """C(q, qd), N m s/rad, Christoffel form: shape (2, 2) or (..., 2, 2)."""
        q = state_array('q', q, 2)
        qd = state_array('qd', qd, 2)
        bs2 = self._k[1] * np.sin(q[..., 1])
        qd1, qd2 = np.broadcast_arrays(qd[..., 0], qd[..., 1])
        bs2, qd1, qd2 = np.broadcast_arrays(bs2, qd1, qd2)
        return np.stack([np.stack([-bs2 * qd2, -bs2 * (qd1 + qd2)], -1),
                         np.stack([bs2 * qd1, np.zeros_like(bs2)], -1)], -2)

    def gravity_vector(self, q) -> np.ndarray:
        """g(q) = dPE/dq, N m: shape (2,) or (..., 2)."""
        q = state_array('q', q, 2)
        g1, g2 = self._k[4:6]
        gc12 = g2 * np.cos(q[..., 0] + q[..., 1])
        return np.stack([g1 * np.cos(q[..., 0]) + gc12, gc12], -1)

    def damping_torque(self, qd) -> np.ndarray:
        """B qd, N m (the viscous friction the joints resist with): ``B = diag(joint_damping
        + n^2 Bm)`` (:attr:`total_damping`), shape (2,) or (..., 2)."""
        qd = state_array('qd', qd, 2)
        return qd * np.asarray(self._k[6:8])

    def forward_dynamics(self, q, qd, tau) -> np.ndarray:
        """qdd [rad/s^2] from q [rad], qd [rad/s], tau [N m]; damping included.

        One 2x2 solve of ``D qdd = tau - C qd - g - B qd``. Shapes (2,) or (..., 2).

        On an instance this name is the hot path :func:`_make_forward_dynamics` built for
        its parameters: three finite (2,) arrays are unpacked as floats and the closed form
        evaluated inline, checked once on the result. Anything else (a batch, tuples, a
        non-finite or malformed argument) comes here, to the validating path, which names
        the bad argument; for finite inputs both give the same bits.
        """
        sq, sqd, stau = _pair('q', q), _pair('qd', qd), _pair('tau', tau)
        if sq is not None and sqd is not None and stau is not None:
            return np.array(self._acc_float(*sq, *sqd, *stau))
        q, qd, tau = (state_array(n, v, 2) for n, v in (('q', q), ('qd', qd), ('tau', tau)))
        out = self._acc_array(q[..., 0], q[..., 1], qd[..., 0], qd[..., 1],
                              tau[..., 0], tau[..., 1])
        return np.stack(np.broadcast_arrays(*out), -1)

    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        """tau [N m] = D qdd + C qd + g + B qd for q, qd, qdd of shape (2,) or (..., 2).

        On an instance this name is the single-state hot path
        :func:`_make_inverse_dynamics` (what the computed-torque controller calls every
        tick); anything else comes here: one state of other types takes the float formula,
        a batch the array path below."""
        sq, sqd, sqdd = _pair('q', q), _pair('qd', qd), _pair('qdd', qdd)
        if sq is not None and sqd is not None and sqdd is not None:
            return np.array(self._tau_float(*sq, *sqd, *sqdd))
        qdd = state_array('qdd', qdd, 2)
        return (np.einsum('...ij,...j->...i', self.mass_matrix(q), qdd)
                + np.einsum('...ij,...j->...i', self.coriolis_matrix(q, qd), qd)
                + self.gravity_vector(q) + self.damping_torque(qd))

    def inverse_dynamics_complex(self, q, qd, qdd) -> np.ndarray:
        """:meth:`inverse_dynamics` of one state (2,) carrying complex ``q`` and ``qd``
        through (the same closed form), for complex-step derivatives; unchecked."""
        q, qd, qdd = (np.asarray(v) for v in (q, qd, qdd))
        return np.array(_make_inverse(self._k, np.cos, np.sin)(q[0], q[1], qd[0], qd[1],
                                                              qdd[0], qdd[1]))

    def linearize(self, q, qd, tau, period: float | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        """``(A, B)`` about ``(q, qd, tau)``, state ``(q, qd)``: continuous, or with
        ``period`` [s] the zero-order-hold pair of the control period
        (:mod:`arm_dynamics.linearize`)."""
        from arm_dynamics.linearize import linearized
        return linearized(self, q, qd, tau, period)

    def step(self, q, qd, tau, dt: float, n_steps: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Advance ``n_steps`` RK4 steps of ``dt`` [s] holding ``tau`` [N m]; returns (q, qd).

        Works on one state (2,) or a batch (..., 2); the batch form runs many arms at once.
        One state of three (2,) arrays, a float ``dt`` and an int ``n_steps`` takes the hot
        path: checked once here, then the unchecked inlined RK4 (:func:`_make_step`).
        """
        if type(dt) is float and 0.0 < dt < math.inf and type(n_steps) is int and n_steps > 0:
            try:
                q1, q2 = q.tolist()
                qd1, qd2 = qd.tolist()
                t1, t2 = tau.tolist()
                ok = _isfinite(q1 + q2 + qd1 + qd2 + t1 + t2)
            except (AttributeError, TypeError, ValueError):
                ok = False
            if ok:
                try:
                    q1, q2, qd1, qd2 = self._step_float(q1, q2, qd1, qd2, t1, t2, dt, n_steps)
                except (ValueError, OverflowError):  # math.cos(inf): diverged, as numpy would
                    q1 = q2 = qd1 = qd2 = math.nan
                q, qd = _empty(2), _empty(2)  # 30% cheaper than np.array((q1, q2))
                q[0], q[1], qd[0], qd[1] = q1, q2, qd1, qd2
                return q, qd
        dt = finite_scalar('dt', dt, minimum=0.0, strict=True)
        n_steps = step_count('n_steps', n_steps)
        x = _fast_floats(q, qd, tau)
        if x is None:
            sq, sqd, stau = _pair('q', q), _pair('qd', qd), _pair('tau', tau)
            if sq is not None and sqd is not None and stau is not None:
                x = [*sq, *sqd, *stau]
        if x is not None:
            try:
                q1, q2, qd1, qd2 = self._step_float(*x, dt, n_steps)
            except (ValueError, OverflowError):  # math.cos(inf): diverged, as numpy would
                q1 = q2 = qd1 = qd2 = math.nan
            return np.array((q1, q2)), np.array((qd1, qd2))
        q, qd, tau = (state_array(n, v, 2) for n, v in (('q', q), ('qd', qd), ('tau', tau)))
        q1, q2, qd1, qd2 = _rk4(self._acc_array, (q[..., 0], q[..., 1], qd[..., 0],
                                     qd[..., 1], tau[..., 0], tau[..., 1]), dt, n_steps)
        q1, q2, qd1, qd2 = np.broadcast_arrays(q1, q2, qd1, qd2)
        return np.stack((q1, q2), -1), np.stack((qd1, qd2), -1)

    def step_floats(self, q1: float, q2: float, qd1: float, qd2: float, tau1: float,
                    tau2: float, dt: float, n_steps: int = 1
                    ) -> tuple[float, float, float, float]:
        """:meth:`step` for one state given as plain floats, for hot loops that keep their
        state as floats: returns ``(q1, q2, qd1, qd2)`` [rad, rad/s] after ``n_steps`` RK4
        steps of ``dt`` [s] holding ``(tau1, tau2)`` [N m].

        Validated here, once per call (finite state and torque, ``dt`` a float > 0,
        ``n_steps`` an int >= 1; a bad argument raises ValueError naming it), then the
        unchecked inlined RK4 (:func:`_make_step`) runs its four stages per step: the same
        operations as :meth:`step`, so the same bits. A state that diverges within the call
        comes back as NaNs, as in :meth:`step`. In a PD loop this is about 3x faster than
        :meth:`step` with numpy arrays (``bench/bench_dynamics.py``).
        """
        try:
            ok = (_isfinite(q1 + q2 + qd1 + qd2 + tau1 + tau2) and type(dt) is float
                  and 0.0 < dt < math.inf and type(n_steps) is int and n_steps > 0)
        except TypeError:
            ok = False
        if not ok:
            q1, q2, qd1, qd2, tau1, tau2 = (
                finite_scalar(name, value) for name, value in (
                    ('q1', q1), ('q2', q2), ('qd1', qd1), ('qd2', qd2), ('tau1', tau1),
                    ('tau2', tau2)))
            dt = finite_scalar('dt', dt, minimum=0.0, strict=True)
            n_steps = step_count('n_steps', n_steps)
        try:
            return self._step_float(q1, q2, qd1, qd2, tau1, tau2, dt, n_steps)
        except (ValueError, OverflowError):  # math.cos(inf): diverged, as in step
            return math.nan, math.nan, math.nan, math.nan

    def energy(self, q, qd) -> tuple[np.ndarray, np.ndarray]:
        """(kinetic, potential) energy [J]; potential is zero at the base height. Kinetic
        ``qd^T D(q) qd / 2``, the rotors' ``n^2 Jm qd^2 / 2`` included; shapes () or (...)
        for q, qd (2,) or (..., 2) [rad, rad/s]."""
        qd = state_array('qd', qd, 2)
        kinetic = 0.5 * np.einsum('...i,...ij,...j->...', qd, self.mass_matrix(q), qd)
        q = state_array('q', q, 2)
        (_, _), (lc1, lc2) = self.link_lengths, self.com_distances
        m1, m2 = self.link_masses
        l1 = self.link_lengths[0]
        y1 = lc1 * np.sin(q[..., 0])
        y2 = l1 * np.sin(q[..., 0]) + lc2 * np.sin(q[..., 0] + q[..., 1])
        return kinetic, self.gravity * (m1 * y1 + m2 * y2)

    # ------------------------------------------------------------------ kinematics
    #: Elbow branches of :meth:`inverse_kinematics` (see the module docstring).
    ELBOWS = ('up', 'down')

    def forward_kinematics(self, q) -> np.ndarray:
        """End-effector position ``p = (x, y)`` in the base frame.

        Parameters
        ----------
        q : (2,) or (..., 2), rad

        Returns
        -------
        p : (2,) or (..., 2), m
            ``(l1 cos q1 + l2 cos(q1 + q2), l1 sin q1 + l2 sin(q1 + q2))``.
        """
        q = state_array('q', q, 2)
        l1, l2 = self.link_lengths
        q12 = q[..., 0] + q[..., 1]
        return np.stack([l1 * np.cos(q[..., 0]) + l2 * np.cos(q12),
                         l1 * np.sin(q[..., 0]) + l2 * np.sin(q12)], -1)

    def joint_points(self, q) -> np.ndarray:
        """Base, elbow and tip [m] at ``q`` (2,) or (..., 2) [rad]: (3, 2) or (..., 3, 2),
        for drawing (the elbow ``(l1 cos q1, l1 sin q1)``, the tip
        :meth:`forward_kinematics`)."""
        q = state_array('q', q, 2)
        l1 = self.link_lengths[0]
        elbow = np.stack([l1 * np.cos(q[..., 0]), l1 * np.sin(q[..., 0])], -1)
        tip = self.forward_kinematics(q)
        return np.stack([np.zeros_like(tip), elbow, tip], -2)

    def jacobian(self, q) -> np.ndarray:
        """``J(q) = dp/dq``, so that the tip velocity is ``p' = J q'``.

        Parameters
        ----------
        q : (2,) or (..., 2), rad

        Returns
        -------
        J : (2, 2) or (..., 2, 2), m/rad
            Rows x, y; columns q1, q2. ``det J = l1 l2 sin q2``.
        """
        q = state_array('q', q, 2)
        l1, l2 = self.link_lengths
        q12 = q[..., 0] + q[..., 1]
        s12, c12 = l2 * np.sin(q12), l2 * np.cos(q12)
        return np.stack([np.stack([-l1 * np.sin(q[..., 0]) - s12, -s12], -1),
                         np.stack([l1 * np.cos(q[..., 0]) + c12, c12], -1)], -2)

    def jdot_qd(self, q, qd) -> np.ndarray:
        """``J'(q, q') q'``: the tip acceleration at zero joint acceleration, so that
        ``p'' = J q'' + J' q'``.

        Parameters
        ----------
        q : (2,) or (..., 2), rad
        qd : (2,) or (..., 2), rad/s (any time unit: the result is in m per that unit^2)

        Returns
        -------
        (2,) or (..., 2), m/s^2
            ``-(l1 cos q1 q1'^2 + l2 cos(q1 + q2) (q1' + q2')^2,
            l1 sin q1 q1'^2 + l2 sin(q1 + q2) (q1' + q2')^2)`` (centripetal only: ``J`` is
            linear in the cosines and sines of the link angles).
        """
        q = state_array('q', q, 2)
        qd = state_array('qd', qd, 2)
        l1, l2 = self.link_lengths
        w1, w12 = qd[..., 0], qd[..., 0] + qd[..., 1]
        q12 = q[..., 0] + q[..., 1]
        return -np.stack(np.broadcast_arrays(
            l1 * np.cos(q[..., 0]) * w1**2 + l2 * np.cos(q12) * w12**2,
            l1 * np.sin(q[..., 0]) * w1**2 + l2 * np.sin(q12) * w12**2), -1)

    def elbow_of(self, q) -> str | np.ndarray:
        """The elbow branch of configuration(s) ``q`` (2,) or (..., 2) [rad]: ``'down'``
        where ``sin q2 >= 0`` (the singular ``sin q2 = 0`` counts as down), else ``'up'``;
        a str for one configuration, an array of str for a batch."""
        q = state_array('q', q, 2)
        down = np.sin(q[..., 1]) >= 0.0
        return ('down' if down else 'up') if q.ndim == 1 else np.where(down, 'down', 'up')

    def cos_q2(self, r) -> np.ndarray:
        """``cos q2`` [-] of the configurations whose tip is at distance ``r`` [m] (any
        shape) from the base: ``(r^2 - l1^2 - l2^2) / (2 l1 l2)``. Not clipped: values
        outside [-1, 1] mean ``r`` is out of reach."""
        l1, l2 = self.link_lengths
        r = np.asarray(r, dtype=float)
        return (r * r - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)

    def abs_sin_q2(self, r) -> np.ndarray:
        """``|sin q2|`` [-] at tip distance ``r`` [m] (any shape) from the base; 0 where out
        of reach. ``|det J| = l1 l2 |sin q2|`` depends on ``r`` only and is smallest at the
        ends of the reachable annulus."""
        c2 = self.cos_q2(r)
        return np.sqrt(np.clip((1.0 - c2) * (1.0 + c2), 0.0, None))

    def inverse_kinematics(self, p, elbow: str) -> np.ndarray:
        """Joint angles putting the tip at ``p``, closed form, on the chosen elbow branch.

        Parameters
        ----------
        p : (2,) or (..., 2), m
            Tip position(s) in the base frame. Points outside the reachable annulus are
            clipped to its boundary; refuse them first with :meth:`workspace_violation`.
        elbow : 'up' or 'down'
            ``'down'`` gives ``q2 in [0, pi]``, ``'up'`` gives ``q2 in [-pi, 0]``.

        Returns
        -------
        q : (2,) or (..., 2), rad
            ``q1`` in (-pi, pi] (``atan2`` range), ``q2`` as above; ``forward_kinematics(q)
            == p`` to rounding for reachable ``p``.
        """
        if elbow not in self.ELBOWS:
            raise ValueError(f"elbow must be 'up' or 'down', got {elbow!r}")
        p = state_array('p', p, 2)
        l1, l2 = self.link_lengths
        x, y = p[..., 0], p[..., 1]
        c2 = np.clip(self.cos_q2(np.hypot(x, y)), -1.0, 1.0)
        s2 = np.sqrt((1.0 - c2) * (1.0 + c2))  # accurate near c2 = +-1
        if elbow == 'up':
            s2 = -s2
        q2 = np.arctan2(s2, c2)
        q1 = np.arctan2(y, x) - np.arctan2(l2 * s2, l1 + l2 * c2)
        q1 = np.arctan2(np.sin(q1), np.cos(q1))  # wrap to (-pi, pi]
        return np.stack([q1, q2], -1)

    def workspace_violation(self, p, reach_margin: float = 0.0,
                            singularity_margin: float = 0.0,
                            what: str = 'point') -> str | None:
        """Why tip position ``p`` must be refused (with the numbers), or None.

        Parameters
        ----------
        p : (2,), m
        reach_margin : m, >= 0
            Distance kept from both boundaries of the annulus: ``|l1 - l2| + reach_margin
            <= r <= l1 + l2 - reach_margin`` with ``r = |p|``.
        singularity_margin : [-], in [0, 1)
            Minimum ``|sin q2|`` (:meth:`abs_sin_q2`): it bounds the joint speeds a tip
            speed needs, ``|q'| <~ |p'| / (l_min |sin q2|)``.
        what : name of the point in the message.

        Returns
        -------
        str or None
            Non-finite or not two numbers, out of reach, too close to the base, or too
            near a singularity; None if ``p`` is fine.
        """
        l1, l2 = self.link_lengths
        p = np.asarray(p, dtype=float)
        if p.shape != (2,) or not np.isfinite(p).all():
            return f'{what} must be two finite numbers (x, y) in m, got {p.tolist()}'
        r = math.hypot(p[0], p[1])
        lo, hi = abs(l1 - l2) + reach_margin, l1 + l2 - reach_margin
        where = f'{what} ({p[0]:.4f}, {p[1]:.4f}) m'
        if r > hi:
            return (f'{where} is out of reach: r = {r:.4f} m > l1 + l2 - reach_margin = '
                    f'{l1 + l2:.4f} - {reach_margin:g} = {hi:.4f} m')
        if r < lo:
            return (f'{where} is too close to the base: r = {r:.4f} m < |l1 - l2| + '
                    f'reach_margin = {abs(l1 - l2):.4f} + {reach_margin:g} = {lo:.4f} m')
        s = float(self.abs_sin_q2(r))
        if s < singularity_margin:
            return (f'{where} is too near a singularity: |sin q2| = {s:.4f} < '
                    f'singularity_margin {singularity_margin:g} (r = {r:.4f} m; arm almost '
                    f"{'stretched' if self.cos_q2(r) > 0 else 'folded'})")
        return None

    # ------------------------------------------------------------------ model variants
    def with_payload(self, mass: float) -> TwoLinkArm:
        """This arm carrying a point mass at the tip of link 2 (e.g. an unmodelled payload).

        Parameters
        ----------
        mass : kg, finite, >= 0
            The point mass ``p``, at distance ``l2`` from the elbow on link 2's axis.

        Returns
        -------
        TwoLinkArm
            Link 2 becomes the rigid body of the link and the point mass, everything else
            unchanged: mass ``m2 + p``, centre of gravity
            ``lc2' = (m2 lc2 + p l2) / (m2 + p)``, inertia about it (parallel axis
            theorem) ``I2' = I2 + m2 (lc2' - lc2)^2 + p (l2 - lc2')^2``. Its dynamics are
            this arm's plus the point mass's (``D' = D + p J^T J``, ``g' = g + p g0
            dy_tip/dq``, ``J`` :meth:`jacobian`); gravity, damping and the motors are
            carried over. ``mass == 0`` returns this arm itself.
        """
        p = finite_scalar('mass', mass, minimum=0.0)
        if p == 0.0:
            return self
        (_, l2), (lc1, lc2) = self.link_lengths, self.com_distances
        (m1, m2), (i1, i2) = self.link_masses, self.link_inertias
        c = (m2 * lc2 + p * l2) / (m2 + p)
        return replace(self, com_distances=(lc1, c), link_masses=(m1, m2 + p),
                       link_inertias=(i1, i2 + m2 * (c - lc2) ** 2 + p * (l2 - c) ** 2))

    def with_errors(self, mass_error: float, length_error: float) -> TwoLinkArm:
        """This arm with relative parameter errors, e.g. a controller's imperfect model.

        Parameters
        ----------
        mass_error : [-], finite, > -1
            ``e_m``: link masses ``m_i (1 + e_m)``.
        length_error : [-], finite, > -1
            ``e_l``: link lengths ``l_i (1 + e_l)`` and centre of gravity distances
            ``lc_i (1 + e_l)``.

        Returns
        -------
        TwoLinkArm
            Inertias ``I_i (1 + e_m) (1 + e_l)^2`` (each link scaled as a body: mass times
            length squared), gravity, joint damping and the motors (gear ratios, rotor
            inertias and damping) unchanged; so the links' part of ``D(q)`` scales by
            ``(1 + e_m) (1 + e_l)^2`` (the :attr:`armature` stays) and ``g(q)`` by ``(1 +
            e_m) (1 + e_l)``. Where both factors are exactly 1 this arm itself.
        """
        m = 1.0 + finite_scalar('mass_error', mass_error, minimum=-1.0, strict=True)
        s = 1.0 + finite_scalar('length_error', length_error, minimum=-1.0, strict=True)
        if m == 1.0 and s == 1.0:
            return self
        (l1, l2), (c1, c2) = self.link_lengths, self.com_distances
        (m1, m2), (i1, i2) = self.link_masses, self.link_inertias
        return replace(self, link_lengths=(s * l1, s * l2), com_distances=(s * c1, s * c2),
                       link_masses=(m * m1, m * m2),
                       link_inertias=(m * s * s * i1, m * s * s * i2))


class TwoLinkBatch:
    """``B`` two-link arms, each with its own parameters, evaluated and stepped together.

    Row ``i`` of every state array belongs to ``arms[i]``. The formulas are the ones
    :class:`TwoLinkArm` uses for one state (:func:`_make_accel`, :func:`_make_inverse`,
    :func:`_rk4`), with each lumped constant an array of ``B`` values, so arm ``i`` gets
    what ``arms[i]`` gives for that state (to rounding: numpy's ``cos``/``sin`` against
    ``math``'s). What a parameter sweep steps: plants with different payloads, controllers
    with different model errors.

    Parameters
    ----------
    arms : sequence of B :class:`TwoLinkArm`, B >= 1
    """

    n_dof = 2

    def __init__(self, arms: Sequence[TwoLinkArm]) -> None:
        arms = tuple(arms)
        if not arms:
            raise ValueError('arms must hold at least one TwoLinkArm, got none')
        bad = [i for i, a in enumerate(arms) if not isinstance(a, TwoLinkArm)]
        if bad:
            raise ValueError(f'arms[{bad[0]}] must be a TwoLinkArm, got {arms[bad[0]]!r}')
        self.arms = arms
        k: tuple[Any, ...] = tuple(np.array([a._k[i] for a in arms])
                                   for i in range(len(arms[0]._k)))
        self._k = k
        self._acc = _make_accel(k, np.cos, np.sin)
        self._tau = _make_inverse(k, np.cos, np.sin)

    def __len__(self) -> int:
        return len(self.arms)

    def _states(self, **arrays: object) -> list[np.ndarray]:
        """The named arrays checked to be finite with shape (B, 2), as float arrays."""
        out = []
        for name, value in arrays.items():
            arr = state_array(name, value, 2)
            if arr.shape != (len(self.arms), 2):
                raise ValueError(f'{name} must have shape ({len(self.arms)}, 2) (one row per '
                                 f'arm), got {arr.shape}')
            out.append(arr)
        return out

    def forward_dynamics(self, q, qd, tau) -> np.ndarray:
        """qdd (B, 2) [rad/s^2] of each arm from q [rad], qd [rad/s], tau [N m], each (B, 2)."""
        q, qd, tau = self._states(q=q, qd=qd, tau=tau)
        return np.stack(self._acc(q[:, 0], q[:, 1], qd[:, 0], qd[:, 1], tau[:, 0],
                                  tau[:, 1]), -1)

    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        """tau (B, 2) [N m] = D qdd + C qd + g + B qd of each arm; q, qd, qdd (B, 2)."""
        q, qd, qdd = self._states(q=q, qd=qd, qdd=qdd)
        return np.stack(self._tau(q[:, 0], q[:, 1], qd[:, 0], qd[:, 1], qdd[:, 0],
                                  qdd[:, 1]), -1)

    def gravity_vector(self, q) -> np.ndarray:
        """g(q) (B, 2) [N m] of each arm at q (B, 2) [rad]."""
        (q,) = self._states(q=q)
        g1, g2 = self._k[4:6]
        gc12 = g2 * np.cos(q[:, 0] + q[:, 1])
        return np.stack([g1 * np.cos(q[:, 0]) + gc12, gc12], -1)

    def step(self, q, qd, tau, dt: float, n_steps: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Advance every arm ``n_steps`` RK4 steps of ``dt`` [s] holding its ``tau`` [N m];
        q, qd, tau (B, 2) [rad, rad/s, N m]. Returns (q, qd), (B, 2) each; a diverging arm
        gives non-finite rows (no error: the caller decides)."""
        dt = finite_scalar('dt', dt, minimum=0.0, strict=True)
        n_steps = step_count('n_steps', n_steps)
        q, qd, tau = self._states(q=q, qd=qd, tau=tau)
        with np.errstate(all='ignore'):
            q1, q2, qd1, qd2 = _rk4(self._acc, (q[:, 0], q[:, 1], qd[:, 0], qd[:, 1],
                                                tau[:, 0], tau[:, 1]), dt, n_steps)
        return np.stack((q1, q2), -1), np.stack((qd1, qd2), -1)
