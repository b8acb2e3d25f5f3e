"""Integration of the arm models, with no middleware.

* :func:`rk4_step` -- one classic Runge-Kutta 4 step of ``qdd = fd(q, qd, tau)`` with the
  torque held over the step (what the simulator node does every physics step).
* :class:`TipLoaded` -- a model with a constant tip force (base frame) in its right-hand
  side: the force's joint torque ``J(q)^T F`` evaluated at every RK4 stage.
* :func:`simulate` -- run a model under any torque law over time and return arrays; the
  ``'solve_ivp'`` method is the accuracy reference (scipy's DOP853 at tight tolerances).

References: classic RK4 and DOP853: Hairer, Norsett, Wanner, *Solving Ordinary
Differential Equations I* (2nd ed., 1993), Ch. II.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from arm_dynamics._validate import finite_scalar, state_array


class Model(Protocol):
    """What :func:`simulate` and the simulator node need from a model."""

    @property
    def n_dof(self) -> int: ...

    def forward_dynamics(self, q, qd, tau) -> np.ndarray: ...

    def step(self, q, qd, tau, dt: float, n_steps: int = 1
             ) -> tuple[np.ndarray, np.ndarray]: ...


TorqueLaw = Callable[[float, np.ndarray, np.ndarray], np.ndarray]


def rk4_step(fd: Callable, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, dt: float
             ) -> tuple[np.ndarray, np.ndarray]:
    """One RK4 step of ``dt`` [s] for ``qdd = fd(q, qd, tau)``; arrays of any shape."""
    h2 = 0.5 * dt
    a1 = fd(q, qd, tau)
    v2 = qd + h2 * a1
    a2 = fd(q + h2 * qd, v2, tau)
    v3 = qd + h2 * a2
    a3 = fd(q + h2 * v2, v3, tau)
    v4 = qd + dt * a3
    a4 = fd(q + dt * v3, v4, tau)
    return (q + dt / 6.0 * (qd + 2.0 * (v2 + v3) + v4),
            qd + dt / 6.0 * (a1 + 2.0 * (a2 + a3) + a4))


class TipLoaded:
    """``model`` with a constant tip force ``force`` (2,) [N, base frame] in its dynamics.

    The force's joint torque ``J(q)^T F`` is evaluated wherever the dynamics are: every
    RK4 stage of :meth:`step`, every stage and event re-integration of
    :func:`~arm_dynamics.friction.friction_step` (which asks :meth:`step` and
    :meth:`inverse_dynamics`), so a push follows the arm within a physics step to the
    integrator's order (held at the step's start it would be first order). Like gravity,
    the load is part of the bias torque: :meth:`inverse_dynamics` subtracts it,
    :meth:`forward_dynamics` adds it to ``tau``; the mass matrix and the Jacobian are the
    arm's. Single states (n,) only.
    """

    def __init__(self, model: Any, force) -> None:
        self.model = model
        self.force = np.asarray(force, dtype=float).reshape(2)

    @property
    def n_dof(self) -> int:
        return self.model.n_dof

    def load(self, q) -> np.ndarray:
        """``J(q)^T F`` [N m], (n,)."""
        return np.asarray(self.model.jacobian(q), dtype=float).T @ self.force

    def jacobian(self, q) -> np.ndarray:
        """The arm's tip Jacobian [m/rad], (2, n)."""
        return self.model.jacobian(q)

    def mass_matrix(self, q) -> np.ndarray:
        """The arm's D(q) [kg m^2], (n, n)."""
        return self.model.mass_matrix(q)

    def forward_dynamics(self, q, qd, tau) -> np.ndarray:
        """qdd [rad/s^2] under ``tau`` [N m] plus the tip force's ``J(q)^T F``."""
        return np.asarray(self.model.forward_dynamics(
            q, qd, np.asarray(tau, dtype=float) + self.load(q)), dtype=float)

    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        """The torque [N m] the joints must add to the tip force for ``qdd``."""
        return np.asarray(self.model.inverse_dynamics(q, qd, qdd), dtype=float) - self.load(q)

    def step(self, q, qd, tau, dt: float, n_steps: int = 1
             ) -> tuple[np.ndarray, np.ndarray]:
        """``n_steps`` RK4 steps of ``dt`` [s], ``tau`` [N m] held, ``J(q)^T F`` per
        stage; (q [rad], qd [rad/s]). Raises ValueError on a non-finite state (the arm's
        own checks)."""
        q, qd = np.asarray(q, dtype=float), np.asarray(qd, dtype=float)
        tau = np.asarray(tau, dtype=float)
        for _ in range(n_steps):
            q, qd = rk4_step(self.forward_dynamics, q, qd, tau, dt)
        return q, qd


@dataclass(frozen=True)
class SimResult:
    """A simulated run, sampled every ``dt``.

    Attributes
    ----------
    t : (N + 1,) s
    q : (N + 1, n) rad
    qd : (N + 1, n) rad/s
    tau : (N + 1, n) N m -- torque applied from ``t[k]`` on (after saturation); the last
        row is what the law commands at the final state.
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    tau: np.ndarray


def simulate(*, model: Model, q0, qd0, torque: TorqueLaw | np.ndarray | list | tuple,
             duration: float, dt: float = 1e-3, control_period: float | None = None,
             effort_limits=None, method: str = 'rk4', rtol: float = 1e-12,
             atol: float = 1e-12) -> SimResult:
    """Simulate ``model`` from ``(q0, qd0)`` for ``duration`` seconds.

    Parameters
    ----------
    model : TwoLinkArm, SingleLinkGeared or anything with ``n_dof``, ``forward_dynamics``
        and ``step``.
    q0, qd0 : (n,) rad, rad/s
    torque : callable ``(t, q, qd) -> tau`` [N m], or a constant (n,) torque. The law is
        sampled every ``control_period`` and held in between (zero-order hold).
    duration : s, > 0
    dt : s, > 0 -- output sample spacing and RK4 step.
    control_period : s, a whole multiple of ``dt`` (default ``dt``).
    effort_limits : (n,) N m or None -- applied torque is clipped to +-limits.
    method : ``'rk4'`` (fixed step, as the simulator node) or ``'solve_ivp'`` (DOP853 with
        ``rtol``/``atol``, the reference).
    """
    n = model.n_dof
    q = state_array('q0', q0, n)
    qd = state_array('qd0', qd0, n)
    duration = finite_scalar('duration', duration, minimum=0.0, strict=True)
    dt = finite_scalar('dt', dt, minimum=0.0, strict=True)
    period = dt if control_period is None else finite_scalar(
        'control_period', control_period, minimum=0.0, strict=True)
    hold = round(period / dt)
    if hold < 1 or abs(hold * dt - period) > 1e-9 * period:
        raise ValueError(f'control_period must be a whole multiple of dt={dt}, got {period}')
    steps = round(duration / dt)
    if steps < 1:
        raise ValueError(f'duration must be at least dt={dt}, got {duration}')
    if method not in ('rk4', 'solve_ivp'):
        raise ValueError(f"method must be 'rk4' or 'solve_ivp', got {method!r}")
    limits = None if effort_limits is None else state_array('effort_limits', effort_limits, n)
    if limits is not None and (limits < 0).any():
        raise ValueError(f'effort_limits must be >= 0, got {limits.tolist()}')
    if callable(torque):
        law = torque
    else:
        constant = state_array('torque', torque, n)

        def law(t, q, qd):
            return constant

    def applied(t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        tau = np.asarray(law(t, q, qd), dtype=float)
        return tau if limits is None else np.clip(tau, -limits, limits)

    t = np.arange(steps + 1) * dt
    qs, qds, taus = np.empty((steps + 1, n)), np.empty((steps + 1, n)), np.empty((steps + 1, n))
    qs[0], qds[0] = q, qd
    tau = np.zeros(n)
    for k in range(steps):
        if k % hold == 0:
            tau = applied(t[k], q, qd)
        taus[k] = tau
        if method == 'rk4':
            q, qd = model.step(q, qd, tau, dt)
        else:
            q, qd = _reference_interval(model, q, qd, tau, dt, rtol, atol)
        qs[k + 1], qds[k + 1] = q, qd
    taus[steps] = applied(t[steps], q, qd)
    return SimResult(t=t, q=qs, qd=qds, tau=taus)


def _reference_interval(model: Model, q: np.ndarray, qd: np.ndarray, tau: np.ndarray,
                        dt: float, rtol: float, atol: float) -> tuple[np.ndarray, np.ndarray]:
    n = model.n_dof

    def rhs(_t, x):
        return np.concatenate([x[n:], model.forward_dynamics(x[:n], x[n:], tau)])

    # scipy is imported here, not with the module: it costs ~0.5 s and ~50 MB, and only
    # this reference method needs it (``arm-sim analyze`` imports arm_dynamics too).
    from scipy.integrate import solve_ivp

    sol = solve_ivp(rhs, (0.0, dt), np.concatenate([q, qd]), method='DOP853', rtol=rtol,
                    atol=atol)
    if not sol.success:
        raise RuntimeError(f'solve_ivp failed: {sol.message}')
    return sol.y[:n, -1], sol.y[n:, -1]
