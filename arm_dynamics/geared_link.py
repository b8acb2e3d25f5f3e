"""The lecture's single link driven through a gear box (ratio n:1).

Motor angle ``theta_m = n theta_l``. Kinetic energy ``(Jm + Jl/n^2) theta_m'^2 / 2``,
potential energy ``M g l (1 - cos theta_l)`` (theta_l = 0 hanging straight down), viscous
damping on both sides of the gear. Lagrange gives, on the motor side::

    J theta_m'' + B theta_m' + C sin(theta_m / n) = u
    J = Jm + Jl/n^2,   B = Bm + Bl/n^2,   C = M g l / n

References: Spong, Hutchinson, Vidyasagar, *Robot Modeling and Control*, Independent
Joint Control chapter (actuator dynamics with gear reduction); Siciliano et al.,
*Robotics: Modelling, Planning and Control* (2009), §5.1 (transmissions, reflected
inertia) and §8.3.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from arm_dynamics._validate import finite_scalar, step_count
from arm_dynamics.integrate import rk4_step


def _arr(name: str, x: object) -> np.ndarray:
    try:
        arr = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f'{name} must be numeric, got {x!r}') from None
    if not np.isfinite(arr).all():
        raise ValueError(f'{name} must be finite, got {x!r}')
    return arr


@dataclass(frozen=True)
class SingleLinkGeared:
    """One link behind an n:1 gear box, seen from the motor shaft.

    Parameters
    ----------
    motor_inertia : Jm, kg m^2, > 0
    load_inertia : Jl, kg m^2, >= 0 (the link about the joint axis)
    motor_damping : Bm, N m s/rad, >= 0
    load_damping : Bl, N m s/rad, >= 0
    gear_ratio : n, dimensionless, > 0 (motor turns per link turn)
    mass : M, kg, >= 0
    length : l, m, >= 0 (joint axis to the link's centre of gravity)
    gravity : g, m/s^2, >= 0
    """

    motor_inertia: float = 0.005
    load_inertia: float = 1.0
    motor_damping: float = 0.01
    load_damping: float = 0.5
    gear_ratio: float = 50.0
    mass: float = 2.0
    length: float = 0.5
    gravity: float = 9.81
    n_dof: int = field(default=1, init=False)

    def __post_init__(self) -> None:
        for name in ('motor_inertia', 'gear_ratio'):
            object.__setattr__(self, name, finite_scalar(name, getattr(self, name),
                                                         minimum=0.0, strict=True))
        for name in ('load_inertia', 'motor_damping', 'load_damping', 'mass', 'length',
                     'gravity'):
            object.__setattr__(self, name, finite_scalar(name, getattr(self, name),
                                                         minimum=0.0))

    @property
    def inertia(self) -> float:
        """J = Jm + Jl/n^2, kg m^2 (load inertia reflected to the motor)."""
        return self.motor_inertia + self.load_inertia / self.gear_ratio**2

    @property
    def damping(self) -> float:
        """B = Bm + Bl/n^2, N m s/rad."""
        return self.motor_damping + self.load_damping / self.gear_ratio**2

    @property
    def gravity_coefficient(self) -> float:
        """C = M g l / n, N m."""
        return self.mass * self.gravity * self.length / self.gear_ratio

    def forward_dynamics(self, theta_m, theta_m_dot, u) -> np.ndarray:
        """Motor acceleration [rad/s^2] from motor angle [rad], speed [rad/s], torque [N m]."""
        th, thd, u = _arr('theta_m', theta_m), _arr('theta_m_dot', theta_m_dot), _arr('u', u)
        return (u - self.damping * thd
                - self.gravity_coefficient * np.sin(th / self.gear_ratio)) / self.inertia

    def inverse_dynamics(self, theta_m, theta_m_dot, theta_m_ddot) -> np.ndarray:
        """Motor torque u [N m] producing the given motor acceleration [rad/s^2]."""
        th, thd = _arr('theta_m', theta_m), _arr('theta_m_dot', theta_m_dot)
        thdd = _arr('theta_m_ddot', theta_m_ddot)
        return (self.inertia * thdd + self.damping * thd
                + self.gravity_coefficient * np.sin(th / self.gear_ratio))

    def link_torque(self, theta_m, theta_m_dot, u) -> np.ndarray:
        """Torque the gear's output shaft applies to the link [N m] under motor torque ``u``.

        The motor shaft spends part of ``u`` on its own inertia and damping; the ideal gear
        multiplies the rest by ``n``::

            tau_l = n (u - Jm theta_m'' - Bm theta_m'),   theta_m'' = forward_dynamics(...)

        which is what the link's own equation needs, ``tau_l = Jl theta_l'' + Bl theta_l'
        + M g l sin(theta_l)`` with ``theta_l = theta_m / n``. It equals ``n u`` only when
        the motor shaft neither accelerates nor turns (at rest, or ``Jm = Bm = 0``):
        starting from rest hanging straight down, ``tau_l = n u (Jl / n^2) / J``; with the
        defaults (``Jl / n^2 = 4e-4``, ``J = 5.4e-3`` kg m^2) that is 7% of ``n u``.

        Parameters
        ----------
        theta_m : rad (motor angle); theta_m_dot : rad/s; u : N m (motor torque). Scalars
            or arrays of one shape (broadcast).

        Returns
        -------
        N m, the shape of the broadcast inputs.
        """
        thd = _arr('theta_m_dot', theta_m_dot)
        acc = self.forward_dynamics(theta_m, thd, u)
        return self.gear_ratio * (_arr('u', u) - self.motor_inertia * acc
                                  - self.motor_damping * thd)

    def joint_view(self, joint_names, q, qd, u) -> tuple[tuple[str, str], list[float],
                                                        list[float], list[float]]:
        """How the simulator publishes this model: ``<joint>_motor`` (motor angle [rad],
        speed [rad/s], applied motor torque u [N m]) and ``<joint>`` (link angle and speed =
        motor's / n; effort = :meth:`link_torque` at this state, ``n u`` only at rest), with
        ``<joint>`` the first of ``joint_names``; ``q``, ``qd``, ``u`` one-element lists."""
        n, j = self.gear_ratio, joint_names[0]
        link_tau = float(self.link_torque(q[0], qd[0], u[0]))
        return (f'{j}_motor', j), [q[0], q[0] / n], [qd[0], qd[0] / n], [u[0], link_tau]

    def energy(self, theta_m, theta_m_dot) -> tuple[np.ndarray, np.ndarray]:
        """(kinetic, potential) energy [J]; potential is zero hanging straight down."""
        th, thd = _arr('theta_m', theta_m), _arr('theta_m_dot', theta_m_dot)
        return (0.5 * self.inertia * thd**2,
                self.mass * self.gravity * self.length * (1.0 - np.cos(th / self.gear_ratio)))

    def small_oscillation_period(self) -> float:
        """Period [s] of small undamped swings about hanging down: 2 pi sqrt(J n / C)
        (infinite without gravity torque, C = 0)."""
        if self.gravity_coefficient == 0.0:
            return float('inf')
        return 2.0 * np.pi * np.sqrt(self.inertia * self.gear_ratio / self.gravity_coefficient)

    def step(self, q, qd, tau, dt: float, n_steps: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Advance ``n_steps`` RK4 steps of ``dt`` [s] holding the motor torque ``tau``."""
        dt = finite_scalar('dt', dt, minimum=0.0, strict=True)
        n_steps = step_count('n_steps', n_steps)
        q, qd, tau = _arr('q', q), _arr('qd', qd), _arr('tau', tau)
        if not q.shape == qd.shape == np.broadcast_shapes(q.shape, tau.shape):
            raise ValueError(f'q, qd and tau shapes differ: {q.shape}, {qd.shape}, {tau.shape}')
        for _ in range(n_steps):
            q, qd = rk4_step(self.forward_dynamics, q, qd, tau, dt)
        return q, qd
