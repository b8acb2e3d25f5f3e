"""The linearised sampled-data closed loop of a control law and its frequency response
(no rclpy).

The loop the simulator and controller form in lockstep: the controller answers the state
``x_k = (q_k, qd_k)`` measured at ``t_k = k T`` with the torque ``u_k`` of its law for the
reference ``r_k = (q_des, qd_des, qdd_des)(t_k)``; the simulator holds it (zero-order
hold) over ``[t_(k+d), t_(k+d+1)]`` -- ``d = 0`` in lockstep, ``d`` periods of extra delay
otherwise. About the law's equilibrium (the arm at rest at ``q_eq`` under the constant
reference ``q_des = centre``; for ``pd`` under gravity ``q_eq`` sags until ``Kp (centre -
q_eq) = g(q_eq)``) the plant is ``x_(k+1) = Ad x_k + Bd u_k`` (:func:`arm_dynamics.
linearize.linearize_discrete`, exact ZOH equivalent) and the law linearises to::

    u_k = -Kx x_k + Kr r_k (+ the pid integral state)

* ``pd``: ``Kx = [Kp, Kd]``, ``Kr = [Kp, Kd, 0]``
* ``pd_gravity``: ``Kx = [Kp - dg/dq, Kd]``, ``Kr = [Kp, Kd, 0]``
* ``computed_torque``: ``Kx = [D Kp - dID/dq, D Kd - dID/dqd]``, ``Kr = [D Kp, D Kd, D]``
  (``D``, ``dID`` of the controller's model at ``q_eq``, at rest)
* ``lqr``: ``Kx = K``, ``Kr = [K_q + dg/dq, K_qd, 0]`` (K designed about ``centre``)
* ``pid``: ``I_k = I_(k-1) + Ki T e_k``, ``u_k = Kp e_k + Kd e'_k + I_k`` (no clamp, no
  saturation: small signals)

The reference of a sinusoid ``q_des = e^(j w t)`` is ``r = (1, j w, -w^2) e^(j w t)``, so
the frequency response from ``q_des`` of joint ``i`` to ``q`` of joint ``j`` is
``H_ji(w) = [C (zI - Acl)^-1 Bcl R(w)]_ji`` at ``z = e^(j w T)``: :meth:`ClosedLoop.
response`. The loop broken at the plant input (all joints) is ``G(z) = Cx(z) z^-d P(z)``
with ``P = (zI - Ad)^-1 Bd`` and ``u = -Cx(z) x`` the law's feedback; the loop of joint
``j`` broken with the others closed is ``L_j = 1 / [(I + G)^-1]_jj - 1``
(:meth:`ClosedLoop.loop`), whose gain and phase margins :func:`margins` finds.

Units: frequencies Hz (``w = 2 pi f``), angles rad, torques N m; responses are complex
ratios (rad/rad for ``q``, N m/rad for the command).

References: Franklin, Powell, Workman, *Digital Control of Dynamic Systems* (3rd ed.,
1998), §4.3.3 (ZOH equivalent), §7.2 (frequency response of sampled systems, margins);
Skogestad and Postlethwaite, *Multivariable Feedback Control* (2nd ed., 2005), §4.9 and
§8.6 (loop broken at one input with the others closed); Siciliano et al. (2009), §8.5.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import fsolve

from arm_control.laws import LAW_TABLE, LAWS, Gains, law_torque, lqr_gain
from arm_dynamics.linearize import STEP, linearize_discrete

#: The laws whose linearisation :func:`closed_loop` knows.
LINEAR_LAWS = ('pd', 'pd_gravity', 'computed_torque', 'lqr', 'pid')


@dataclass(frozen=True)
class ClosedLoop:
    """The linearised sampled-data loop about ``q_eq`` (made by :func:`closed_loop`).

    Attributes
    ----------
    law : str; period : s; delay : periods (int >= 0)
    q_eq : (n,) rad -- where the arm rests under the constant reference ``centre``;
    tau_eq : (n,) N m -- the torque holding it there.
    ad, bd : (2n, 2n), (2n, n) -- the plant over one period, torque held.
    kx : (n, 2n) -- static state feedback (``u = -kx x + ...``); kr : (n, 3n) -- reference
        feedforward on ``(q_des, qd_des, qdd_des)``; ki : (n,) N m/(rad s) -- pid's
        integral gain (zeros for the other laws).
    """

    law: str
    period: float
    delay: int
    q_eq: np.ndarray
    tau_eq: np.ndarray
    ad: np.ndarray
    bd: np.ndarray
    kx: np.ndarray
    kr: np.ndarray
    ki: np.ndarray

    @property
    def n(self) -> int:
        return len(self.q_eq)

    @property
    def nyquist(self) -> float:
        """Hz."""
        return 0.5 / self.period

    def _z(self, freqs) -> np.ndarray:
        return np.exp(2j * np.pi * np.asarray(freqs, dtype=float) * self.period)

    def feedback(self, freqs) -> np.ndarray:
        """``Cx(z)`` (F, n, 2n): the command's response to the state, ``u = -Cx x`` (for
        pid the integral's ``Ki T z / (z - 1)`` on the position)."""
        z = self._z(freqs)
        c = np.broadcast_to(self.kx, (len(z),) + self.kx.shape).astype(complex)
        if self.ki.any():
            n = self.n
            c[:, :, :n] = c[:, :, :n] + (self.ki * self.period)[None, :, None] * np.eye(n) \
                * (z / (z - 1.0))[:, None, None]
        return c

    def reference_gain(self, freqs) -> np.ndarray:
        """(F, n, n): the command's direct response to ``q_des`` of each joint (its
        derivatives included): ``Kr R(w)``, plus pid's integral path."""
        w = 2.0 * np.pi * np.asarray(freqs, dtype=float)
        n = self.n
        eye = np.eye(n)
        r = np.concatenate([np.broadcast_to(eye, (len(w), n, n)),
                            (1j * w)[:, None, None] * eye,
                            (-w * w)[:, None, None] * eye], axis=1)   # (F, 3n, n)
        g = self.kr @ r
        if self.ki.any():
            z = self._z(freqs)
            g = g + (self.ki * self.period)[None, :, None] * eye * (z / (z - 1.0))[:, None,
                                                                                  None]
        return g

    def plant(self, freqs) -> np.ndarray:
        """``P(z) = (zI - Ad)^-1 Bd`` (F, 2n, n): state per held torque."""
        z = self._z(freqs)
        m = len(self.ad)
        return np.linalg.solve(z[:, None, None] * np.eye(m) - self.ad, self.bd)

    def responses(self, freqs) -> tuple[np.ndarray, np.ndarray]:
        """State and command responses to ``q_des`` of each joint: ``X`` (F, 2n, n),
        ``U`` (F, n, n) (``U`` the command as computed, before the delay)."""
        z = self._z(freqs)
        p = self.plant(freqs) * (z ** -self.delay)[:, None, None]   # x per command
        c = self.feedback(freqs)
        kr = self.reference_gain(freqs)
        n = self.n
        # u = kr - c x,  x = p u  =>  (I + c p) u = kr
        u = np.linalg.solve(np.eye(n) + c @ p, kr)
        return p @ u, u

    def response(self, freqs) -> np.ndarray:
        """Closed-loop frequency response ``H`` (F, n, n): ``H[f, j, i]`` is ``q_j`` per
        ``q_des`` of joint ``i`` (rad/rad) at ``freqs`` (F,) Hz."""
        x, _ = self.responses(freqs)
        return x[:, :self.n]

    def loop_matrix(self, freqs) -> np.ndarray:
        """``G(z) = Cx(z) z^-d P(z)`` (F, n, n): the loop broken at every plant input."""
        z = self._z(freqs)
        return self.feedback(freqs) @ self.plant(freqs) * (z ** -self.delay)[:, None, None]

    def loop(self, freqs) -> np.ndarray:
        """``L_j`` (F, n): joint ``j``'s loop broken at its plant input, the other joints'
        loops closed: ``1 / [(I + G)^-1]_jj - 1``."""
        g = self.loop_matrix(freqs)
        s = np.linalg.inv(np.eye(self.n) + g)
        return 1.0 / np.diagonal(s, axis1=1, axis2=2) - 1.0

    def eigenvalues(self) -> np.ndarray:
        """Closed-loop poles (z plane) of the whole loop (delay and pid states included):
        stable iff all inside the unit circle."""
        n, m, d = self.n, 2 * self.n, self.delay
        pid = bool(self.ki.any())
        size = m + d * n + (n if pid else 0)
        a = np.zeros((size, size))
        # state: x, then the commands computed 1..d periods ago, then the pid integral
        kx = self.kx.copy()
        ki_t = np.diag(self.ki * self.period)
        if pid:
            kx[:, :n] += ki_t
        u_now = np.zeros((n, size))
        u_now[:, :m] = -kx
        if pid:
            u_now[:, m + d * n:] = np.eye(n)
        applied = u_now if d == 0 else np.eye(n, size, m + (d - 1) * n)
        a[:m] = self.ad @ np.eye(m, size) + self.bd @ applied
        if d:
            a[m:m + n] = u_now
            for k in range(1, d):
                a[m + k * n:m + (k + 1) * n] = np.eye(n, size, m + (k - 1) * n)
        if pid:
            row = m + d * n
            a[row:] = -ki_t @ np.eye(n, size) + np.eye(n, size, row)
        return np.linalg.eigvals(a)


@dataclass(frozen=True)
class Margins:
    """Stability margins of one loop.

    ``gain_db`` [dB]: how much the loop gain may rise before the loop goes unstable, at
    the phase crossover ``phase_crossover`` [Hz] (inf, NaN: the phase never reaches -180
    deg with the gain below 1); ``lower_gain_db`` [dB, <= 0]: how much it may fall (an
    open-loop unstable plant, or an integrator, makes the loop conditionally stable: the
    -180 deg crossing where the gain is above 1), at ``lower_crossover`` [Hz] (-inf, NaN:
    none); ``phase_deg`` [deg]: the phase margin at the gain crossover ``gain_crossover``
    [Hz] (NaN: the gain never crosses 0 dB)."""

    gain_db: float
    phase_crossover: float
    phase_deg: float
    gain_crossover: float
    lower_gain_db: float = -np.inf
    lower_crossover: float = np.nan


def margins(freqs, loop) -> Margins:
    """Margins of one SISO loop ``loop`` (F,) complex, sampled at ascending ``freqs`` (F,)
    Hz (dense: crossings are interpolated linearly between samples). The smallest margins
    win: over all -180 deg (mod 360) crossings, the smallest rise and the smallest fall of
    the gain; over all 0 dB crossings, the smallest phase margin."""
    f = np.asarray(freqs, dtype=float)
    mag = 20.0 * np.log10(np.abs(loop))
    ph = np.degrees(np.unwrap(np.angle(loop)))
    up, f_up, down, f_down = np.inf, np.nan, -np.inf, np.nan
    shifted = (ph + 180.0) / 360.0
    k = np.floor(shifted)
    for i in np.flatnonzero(np.diff(k) != 0):
        level = max(k[i], k[i + 1])
        s = (level - shifted[i]) / (shifted[i + 1] - shifted[i])
        margin = -float(mag[i] + s * (mag[i + 1] - mag[i]))
        at = float(f[i] + s * (f[i + 1] - f[i]))
        if margin >= 0.0 and margin < up:
            up, f_up = margin, at
        elif margin < 0.0 and margin > down:
            down, f_down = margin, at
    pm, f_pm = np.nan, np.nan
    for i in np.flatnonzero(np.diff(np.sign(mag)) != 0):
        s = (0.0 - mag[i]) / (mag[i + 1] - mag[i])
        p = (ph[i] + s * (ph[i + 1] - ph[i]) + 180.0) % 360.0
        if p > 180.0:
            p -= 360.0
        if not abs(p) >= abs(pm):
            pm, f_pm = float(p), float(f[i] + s * (f[i + 1] - f[i]))
    return Margins(up, f_up, pm, f_pm, down, f_down)


def loop_margins(loop: ClosedLoop, f_min: float = 1e-3, points: int = 6000
                 ) -> list[Margins]:
    """:func:`margins` of each joint's loop :meth:`ClosedLoop.loop`, on ``points``
    log-spaced frequencies from ``f_min`` Hz to just below Nyquist."""
    f = np.geomspace(f_min, loop.nyquist * (1.0 - 1e-6), points)
    l_all = loop.loop(f)
    return [margins(f, l_all[:, j]) for j in range(loop.n)]


def law_equilibrium(law: str, gains: Gains, plant, model, centre, period: float = 0.01
                    ) -> np.ndarray:
    """Where the arm comes to rest under the constant reference ``centre`` (n,) rad:
    ``law torque(q, 0; centre) = g_plant(q)`` solved for ``q`` (pid: ``centre``, the
    integral takes the gravity). ``plant``, ``model``: the simulated arm and the
    controller's model (RobotModel); ``period`` [s]: what lqr designs for."""
    c = np.asarray(centre, dtype=float)
    if law == 'pid':
        return c.copy()
    n = len(c)
    z = np.zeros(n)
    kp, kd = np.asarray(gains.kp), np.asarray(gains.kd)
    weights = (gains.lqr_q, gains.lqr_qd, gains.lqr_r)

    def residual(q):
        tau, _ = law_torque(law, kp, kd, np.asarray(gains.ki), np.asarray(gains.i_clamp),
                            np.full(n, np.inf), model, z, q, z, c, z, z, period,
                            weights=weights, cache={})
        return tau - plant.gravity_vector(q)

    q, info, ok, msg = fsolve(residual, c, full_output=True, xtol=1e-13)
    if ok != 1 or np.abs(residual(q)).max() > 1e-8:
        raise ValueError(f'{law}: no rest position found about centre {c.tolist()} rad '
                         f'({msg.strip()})')
    return np.asarray(q, dtype=float)


def _did(model, q, qd, qdd) -> tuple[np.ndarray, np.ndarray]:
    """dID/dq and dID/dqd (n, n) of ``model``'s inverse dynamics, by complex step."""
    n = len(q)
    eye = np.eye(n)
    dq = np.stack([model.inverse_dynamics_complex(q + 1j * STEP * eye[k], qd + 0j, qdd
                                                  ).imag / STEP for k in range(n)], -1)
    dqd = np.stack([model.inverse_dynamics_complex(q + 0j, qd + 1j * STEP * eye[k], qdd
                                                   ).imag / STEP for k in range(n)], -1)
    return dq, dqd


def closed_loop(law: str, gains: Gains, plant, centre, period: float, *,
                model=None, delay: int = 0) -> ClosedLoop:
    """The linearised sampled-data closed loop of ``law`` about ``centre``.

    Parameters
    ----------
    law : one of :data:`LINEAR_LAWS`
    gains : :class:`~arm_control.laws.Gains` (n values each)
    plant : the simulated arm (:class:`~arm_dynamics.models.RobotModel`)
    centre : (n,) rad -- the constant reference the loop is linearised about
    period : s > 0 -- the control period (torque held over it)
    model : the controller's model (None: the plant, a perfect model)
    delay : whole control periods of extra delay between state and held torque (>= 0)

    Raises ValueError naming a bad law, delay or an equilibrium that cannot be found.
    """
    if law not in LAW_TABLE:
        raise ValueError(f"law must be one of {', '.join(LAWS)}; got {law!r}")
    if not (isinstance(delay, (int, np.integer)) and delay >= 0):
        raise ValueError(f'delay must be a whole number of periods >= 0, got {delay!r}')
    if not period > 0:
        raise ValueError(f'period must be > 0 s, got {period!r}')
    model = plant if model is None else model
    n = plant.n_dof
    kp, kd = np.diag(gains.kp), np.diag(gains.kd)
    q_eq = law_equilibrium(law, gains, plant, model, centre, period)
    z = np.zeros(n)
    tau_eq = np.asarray(plant.gravity_vector(q_eq), dtype=float)
    ad, bd = linearize_discrete(plant, q_eq, z, tau_eq, period)
    zero = np.zeros((n, n))
    ki = np.zeros(n)
    if law in ('pd', 'pid'):
        kx = np.hstack([kp, kd])
        kr = np.hstack([kp, kd, zero])
        if law == 'pid':
            ki = np.asarray(gains.ki, dtype=float)
    elif law == 'pd_gravity':
        dg, _ = _did(model, q_eq, z, z)  # at rest: dID/dq = dg/dq
        kx = np.hstack([kp - dg, kd])
        kr = np.hstack([kp, kd, zero])
    elif law == 'computed_torque':
        d = np.asarray(model.mass_matrix(q_eq), dtype=float)
        dq, dqd = _did(model, q_eq, z, z)
        kx = np.hstack([d @ kp - dq, d @ kd - dqd])
        kr = np.hstack([d @ kp, d @ kd, d])
    elif law == 'lqr':
        c = np.asarray(centre, dtype=float)
        k = lqr_gain(model, c, (gains.lqr_q, gains.lqr_qd, gains.lqr_r), period)
        dg, _ = _did(model, c, z, z)
        kx = k
        kr = np.hstack([k[:, :n] + dg, k[:, n:], zero])
    else:  # pragma: no cover - every law of the table is handled above
        raise ValueError(f'no linearisation for law {law!r}')
    return ClosedLoop(law, float(period), int(delay), q_eq, tau_eq, ad, bd, kx, kr, ki)
