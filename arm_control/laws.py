"""Joint-space control laws (no rclpy): each maps (state, reference, model) to torques.

With tracking error ``e = q_des - q`` and ``e' = qd_des - qd``:

* ``pd`` -- independent joint PD: ``tau = Kp e + Kd e'``. Under gravity it leaves the
  steady-state error that solves ``Kp e = g(q)``.
* ``pd_gravity`` -- PD plus gravity compensation from the controller's model:
  ``tau = Kp e + Kd e' + g(q)``; zero steady-state error when the model is right.
* ``computed_torque`` -- inverse dynamics / feedback linearisation:
  ``tau = D(q) (qdd_des + Kd e' + Kp e) + C(q, qd) qd + g(q) + B qd``; the error obeys
  ``e'' + Kd e' + Kp e = 0`` when the model is exact.
* ``pid`` -- independent joint PID, model-free: ``tau = Kp e + Ki int(e) + Kd e'``; the
  integral is clamped to ``+-i_clamp`` (anti-windup, as ros2_controllers'
  ``gains.<joint>.i_clamp_*``) and frozen while the output saturates.

The result is saturated at the controller's effort limits and the saturation reported.

References: Siciliano et al., *Robotics: Modelling, Planning and Control* (2009), §8.3
(independent joint control), §8.5.2 (PD with gravity compensation), §8.5.3 (inverse
dynamics control); Lynch and Park, *Modern Robotics* (2017), §11.4.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from arm_dynamics._validate import finite_tuple
from arm_dynamics.two_link import TwoLinkArm

LAWS = ('pd', 'pd_gravity', 'computed_torque', 'pid')


@dataclass(frozen=True)
class Gains:
    """Per-joint gains (n = 2).

    Parameters
    ----------
    kp : (n,) N m/rad, >= 0 (for computed_torque: 1/s^2)
    kd : (n,) N m s/rad, >= 0 (for computed_torque: 1/s)
    ki : (n,) N m/(rad s), >= 0 (pid only)
    i_clamp : (n,) N m, >= 0 -- bound on the integral term's torque (pid only)
    """

    kp: tuple[float, ...] = (100.0, 60.0)
    kd: tuple[float, ...] = (20.0, 12.0)
    ki: tuple[float, ...] = (50.0, 30.0)
    i_clamp: tuple[float, ...] = (20.0, 10.0)

    def __post_init__(self) -> None:
        for name in ('kp', 'kd', 'ki', 'i_clamp'):
            object.__setattr__(self, name, finite_tuple(name, getattr(self, name), 2,
                                                        minimum=0.0))


@dataclass(frozen=True)
class Command:
    """One control output: ``tau`` (n,) N m after saturation, ``raw`` before it, and which
    joints saturated."""

    tau: np.ndarray
    raw: np.ndarray
    saturated: np.ndarray


@dataclass
class ControlLaw:
    """A law with its gains, model and limits; holds the PID integral between calls.

    Parameters
    ----------
    law : one of ``LAWS``
    gains : :class:`Gains`
    model : the controller's model of the arm (may differ from the plant)
    effort_limits : (n,) N m, > 0
    """

    law: str
    gains: Gains
    model: TwoLinkArm
    effort_limits: tuple[float, ...]
    integral: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def __post_init__(self) -> None:
        if self.law not in LAWS:
            raise ValueError(f"law must be one of {', '.join(LAWS)}; got {self.law!r}")
        self.effort_limits = finite_tuple('effort_limits', self.effort_limits, 2,
                                          minimum=0.0, strict=True)
        self._limits = np.array(self.effort_limits)

    def reset(self) -> None:
        """Forget the integral."""
        self.integral = np.zeros(2)

    def __call__(self, q: np.ndarray, qd: np.ndarray, q_des: np.ndarray,
                 qd_des: np.ndarray, qdd_des: np.ndarray, dt: float) -> Command:
        """Torque for state (q [rad], qd [rad/s]) and reference (q_des, qd_des,
        qdd_des [rad/s^2]); ``dt`` [s] is the time since the previous call (PID only)."""
        g = self.gains
        raw, self.integral = law_torque(
            self.law, np.asarray(g.kp), np.asarray(g.kd), np.asarray(g.ki),
            np.asarray(g.i_clamp), self._limits, self.model, self.integral, q, qd, q_des,
            qd_des, qdd_des, dt)
        tau = np.clip(raw, -self._limits, self._limits)
        return Command(tau=tau, raw=raw, saturated=np.abs(raw) > self._limits)


def law_torque(law: str, kp: np.ndarray, kd: np.ndarray, ki: np.ndarray,
               i_clamp: np.ndarray, limits: np.ndarray, model, integral: np.ndarray,
               q: np.ndarray, qd: np.ndarray, q_des: np.ndarray, qd_des: np.ndarray,
               qdd_des: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The unsaturated torque of ``law`` and the PID integral after this call.

    The formulas of :class:`ControlLaw` (which calls this), for one state or a batch:
    every array is (2,) or (B, 2) (gains and limits broadcast), ``model`` a
    :class:`~arm_dynamics.two_link.TwoLinkArm` or, for a batch with one model per row, a
    :class:`~arm_dynamics.two_link.TwoLinkBatch`.

    Parameters
    ----------
    law : one of ``LAWS``
    kp, kd, ki, i_clamp : gains, units as in :class:`Gains`
    limits : N m, the effort limits (PID conditional integration)
    integral : N m, the PID integral term before this call (other laws: returned as is)
    q, qd : rad, rad/s -- measured state
    q_des, qd_des, qdd_des : rad, rad/s, rad/s^2 -- reference
    dt : s, time since the previous call (PID only)

    Returns
    -------
    raw : N m, before saturation
    integral : N m, the new PID integral
    """
    e, ed = q_des - q, qd_des - qd
    if law == 'pd':
        return kp * e + kd * ed, integral
    if law == 'pd_gravity':
        return kp * e + kd * ed + model.gravity_vector(q), integral
    if law == 'computed_torque':
        return model.inverse_dynamics(q, qd, qdd_des + kd * ed + kp * e), integral
    if law != 'pid':
        raise ValueError(f"law must be one of {', '.join(LAWS)}; got {law!r}")
    candidate = np.clip(integral + ki * e * dt, -i_clamp, i_clamp)
    raw = kp * e + kd * ed + candidate
    # Conditional integration: keep the old integral where the output saturates
    # and the error would push it further out.
    winding = (np.abs(raw) > limits) & (np.sign(raw) == np.sign(e))
    integral = np.where(winding, integral, candidate)
    return kp * e + kd * ed + integral, integral
