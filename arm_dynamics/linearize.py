"""Linearisation of any arm model about a state and torque, continuous and sampled (no ROS).

With the state ``x = (q, qd)`` (2n) and the input ``u = tau`` (n), the equations of motion
``qdd = f(q, qd, tau)`` linearise about ``(q0, qd0, tau0)`` to ``dx' = A dx + B du``::

    A = [[0,        I       ],      B = [[0     ],
         [df/dq,    df/dqd  ]]           [D^-1  ]]

The partial derivatives come from the model's own inverse dynamics, by complex step (no
subtraction, so exact to rounding): with ``qdd0 = f(q0, qd0, tau0)`` fixed, ``ID(q, qd,
qdd0) = tau`` gives ``df/dq = -D^-1 dID/dq`` and ``df/dqd = -D^-1 dID/dqd`` (implicit
function theorem), ``df/dtau = D^-1``. A model supplies ``inverse_dynamics_complex(q, qd,
qdd)``: its inverse dynamics carrying complex ``q`` and ``qd`` through.

The sampled pair for a control period ``T`` with the torque held over it (the simulator's
zero-order hold): ``Ad = e^(A T)``, ``Bd = int_0^T e^(A s) ds B``, both from one matrix
exponential of ``[[A, B], [0, 0]] T`` (Van Loan). At an equilibrium (at rest, ``tau =
g(q)``) that is the Jacobian of the sampled plant, to the integrator's error; about a
moving state it is the hold equivalent of the linearisation at the period's start.

References: Franklin, Powell, Workman, *Digital Control of Dynamic Systems* (3rd ed.,
1998), §4.3.3 (zero-order-hold equivalent); Martins, Sturdza, Alonso, "The complex-step
derivative approximation", ACM TOMS 29 (2003); Siciliano et al. (2009), §8.5.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.linalg import expm

#: Complex-step size: any tiny step is exact to rounding (no subtractive cancellation).
STEP = 1e-30


def linearize(model: Any, q, qd, tau) -> tuple[np.ndarray, np.ndarray]:
    """Continuous ``(A, B)`` of ``model`` about ``(q, qd, tau)``.

    Parameters
    ----------
    model : a :class:`~arm_dynamics.models.RobotModel` with ``inverse_dynamics_complex``.
    q : (n,) rad; qd : (n,) rad/s; tau : (n,) N m.

    Returns
    -------
    A : (2n, 2n) [1/s, 1/s^2 ...], B : (2n, n) [rad/(N m s^2)]: ``dx' = A dx + B dtau``.
    """
    n = model.n_dof
    q, qd, tau = (np.asarray(v, dtype=float).reshape(n) for v in (q, qd, tau))
    qdd = np.asarray(model.forward_dynamics(q, qd, tau), dtype=float)
    d_inv = np.linalg.inv(model.mass_matrix(q))
    eye = np.eye(n)
    did_dq = np.stack([model.inverse_dynamics_complex(q + 1j * STEP * eye[k], qd + 0j,
                                                      qdd).imag / STEP
                       for k in range(n)], -1)
    did_dqd = np.stack([model.inverse_dynamics_complex(q + 0j, qd + 1j * STEP * eye[k],
                                                       qdd).imag / STEP
                        for k in range(n)], -1)
    a = np.zeros((2 * n, 2 * n))
    a[:n, n:] = eye
    a[n:, :n] = -d_inv @ did_dq
    a[n:, n:] = -d_inv @ did_dqd
    b = np.zeros((2 * n, n))
    b[n:] = d_inv
    return a, b


def discretize(a: np.ndarray, b: np.ndarray, period: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold equivalent ``(Ad, Bd)`` of ``(A, B)`` over ``period`` [s] > 0."""
    if not period > 0.0:
        raise ValueError(f'period must be > 0 s, got {period!r}')
    n, m = b.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n], block[:n, n:] = a, b
    e = expm(block * period)
    return e[:n, :n], e[:n, n:]


def linearize_discrete(model: Any, q, qd, tau, period: float
                       ) -> tuple[np.ndarray, np.ndarray]:
    """The sampled ``(Ad, Bd)`` of ``model`` about ``(q, qd, tau)`` for a control period
    ``period`` [s] with the torque held (what the simulator does between commands)."""
    a, b = linearize(model, q, qd, tau)
    return discretize(a, b, period)


def linearized(model: Any, q, qd, tau, period: float | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """What every model's ``linearize`` returns: :func:`linearize`, or with ``period`` [s]
    :func:`linearize_discrete`."""
    if period is None:
        return linearize(model, q, qd, tau)
    return linearize_discrete(model, q, qd, tau, period)

