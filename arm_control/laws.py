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
        kp, kd = np.asarray(g.kp), np.asarray(g.kd)
        e, ed = q_des - q, qd_des - qd
        if self.law == 'pd':
            raw = kp * e + kd * ed
        elif self.law == 'pd_gravity':
            raw = kp * e + kd * ed + self.model.gravity_vector(q)
        elif self.law == 'computed_torque':
            raw = self.model.inverse_dynamics(q, qd, qdd_des + kd * ed + kp * e)
        else:
            clamp = np.asarray(g.i_clamp)
            ki = np.asarray(g.ki)
            integral = np.clip(self.integral + ki * e * dt, -clamp, clamp)
            raw = kp * e + kd * ed + integral
            # Conditional integration: keep the old integral where the output saturates
            # and the error would push it further out.
            winding = (np.abs(raw) > self._limits) & (np.sign(raw) == np.sign(e))
            self.integral = np.where(winding, self.integral, integral)
            raw = kp * e + kd * ed + self.integral
        tau = np.clip(raw, -self._limits, self._limits)
        return Command(tau=tau, raw=raw, saturated=np.abs(raw) > self._limits)
