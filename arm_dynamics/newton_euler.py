"""Recursive Newton-Euler inverse dynamics of a planar n-link revolute chain.

The lecture's "Newton's method": kinematics, accelerations of the CGs, free-body diagrams,
force and moment balance. It never forms ``D(q)`` or ``C(q, q')``, which makes it an
independent check of the Lagrange route.

Convention (the contract's): ``q1`` from the +x axis, ``q_i`` relative to link ``i-1``,
gravity along -y. Link ``i`` has length ``l_i``, CG at ``lc_i`` from its joint axis along the
link, mass ``m_i``, inertia ``I_i`` about its CG normal to the plane, viscous joint damping
``b_i``. All vectors are expressed in the base frame.

Forward pass (base to tip), with ``phi_i = q_1 + ... + q_i``, ``e_i = (cos phi_i, sin
phi_i)``, ``n_i = (-sin phi_i, cos phi_i)`` and gravity entered as a base acceleration of
``+g0`` along +y (so the gravity force never appears explicitly)::

    w_i = w_{i-1} + q_i'          alpha_i = alpha_{i-1} + q_i''
    a_ci = a_{p,i-1} + alpha_i lc_i n_i - w_i^2 lc_i e_i
    a_{p,i} = a_{p,i-1} + alpha_i l_i n_i - w_i^2 l_i e_i,      a_{p,0} = (0, g0)

Backward pass (tip to base), ``f_i`` the force and ``mu_i`` the moment link ``i-1`` exerts
on link ``i`` at joint ``i``, ``f_{n+1} = 0``, ``mu_{n+1} = 0``::

    f_i  = f_{i+1} + m_i a_ci
    mu_i = mu_{i+1} + I_i alpha_i + (lc_i e_i) x (m_i a_ci) + (l_i e_i) x f_{i+1}
    tau_i = mu_i + b_i q_i'

References: Siciliano et al., *Robotics: Modelling, Planning and Control* (2009), §7.5;
Featherstone, *Rigid Body Dynamics Algorithms* (2008), §5.3; Craig, *Introduction to
Robotics* (3rd ed., 2005), §6.5 (iterative Newton-Euler).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from arm_dynamics._validate import finite_scalar, finite_tuple, state_array


def _cross(ax, ay, bx, by):
    """z-component of (ax, ay, 0) x (bx, by, 0)."""
    return ax * by - ay * bx


@dataclass(frozen=True)
class NewtonEulerChain:
    """Planar n-link revolute chain for recursive Newton-Euler inverse dynamics.

    Parameters
    ----------
    link_lengths : (n,) m, each > 0
    com_distances : (n,) m, each >= 0
    link_masses : (n,) kg, each >= 0
    link_inertias : (n,) kg m^2, each >= 0
    gravity : m/s^2, >= 0 (acting along -y)
    joint_damping : (n,) N m s/rad, each >= 0 (default zeros)
    """

    # Any sequences on the way in; tuples of floats once validated.
    link_lengths: Sequence[float]
    com_distances: Sequence[float]
    link_masses: Sequence[float]
    link_inertias: Sequence[float]
    gravity: float = 9.81
    joint_damping: Sequence[float] | None = None

    def __post_init__(self) -> None:
        lengths = self.link_lengths
        if isinstance(lengths, (str, bytes)) or not isinstance(
                lengths, (Sequence, np.ndarray)) or len(lengths) < 1:
            raise ValueError(f'link_lengths must be a non-empty sequence, got {lengths!r}')
        n = len(lengths)
        damping = (0.0,) * n if self.joint_damping is None else self.joint_damping
        values = {
            'link_lengths': finite_tuple('link_lengths', lengths, n, minimum=0.0, strict=True),
            'com_distances': finite_tuple('com_distances', self.com_distances, n, minimum=0.0),
            'link_masses': finite_tuple('link_masses', self.link_masses, n, minimum=0.0),
            'link_inertias': finite_tuple('link_inertias', self.link_inertias, n, minimum=0.0),
            'gravity': finite_scalar('gravity', self.gravity, minimum=0.0),
            'joint_damping': finite_tuple('joint_damping', damping, n, minimum=0.0),
        }
        for name, value in values.items():
            object.__setattr__(self, name, value)

    @property
    def n_dof(self) -> int:
        """Number of joints n."""
        return len(self.link_lengths)

    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        """Joint torques tau [N m] for q [rad], qd [rad/s], qdd [rad/s^2].

        Each argument has shape (n,) or (..., n) (leading shapes broadcast); the result has
        the broadcast shape. Damping ``b_i qd_i`` is included.
        """
        n = self.n_dof
        q = state_array('q', q, n)
        qd = state_array('qd', qd, n)
        qdd = state_array('qdd', qdd, n)
        return self.unchecked(q, qd, qdd)

    def unchecked(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """:meth:`inverse_dynamics` on arrays already validated; complex ``q`` is carried
        through (for complex-step derivatives)."""
        n = self.n_dof
        q, qd, qdd = np.broadcast_arrays(q, qd, qdd)
        zero = np.zeros(q.shape[:-1])

        # Forward pass: link angular rates and the accelerations of CGs and joints.
        phi, w, alpha = zero, zero, zero
        apx, apy = zero, zero + self.gravity          # base acceleration (0, +g0)
        links = []
        for i in range(n):
            phi = phi + q[..., i]
            w = w + qd[..., i]
            alpha = alpha + qdd[..., i]
            cx, sx = np.cos(phi), np.sin(phi)
            w2 = w * w
            lc, li = self.com_distances[i], self.link_lengths[i]
            acx = apx - alpha * lc * sx - w2 * lc * cx
            acy = apy + alpha * lc * cx - w2 * lc * sx
            links.append((cx, sx, alpha, acx, acy))
            apx = apx - alpha * li * sx - w2 * li * cx
            apy = apy + alpha * li * cx - w2 * li * sx

        # Backward pass: force and moment each link receives at its own joint.
        fx, fy, mu = zero, zero, zero                 # from link i+1 (none beyond the tip)
        tau = [zero] * n
        damping = self.joint_damping
        assert damping is not None  # __post_init__ replaced None by zeros
        for i in reversed(range(n)):
            cx, sx, alpha, acx, acy = links[i]
            m, lc, li = self.link_masses[i], self.com_distances[i], self.link_lengths[i]
            max_, may = m * acx, m * acy
            mu = (mu + self.link_inertias[i] * alpha + _cross(lc * cx, lc * sx, max_, may)
                  + _cross(li * cx, li * sx, fx, fy))
            fx, fy = fx + max_, fy + may
            tau[i] = mu + damping[i] * qd[..., i]
        return np.stack(tau, -1)


def rnea(q, qd, qdd, *, link_lengths: Sequence[float], com_distances: Sequence[float],
         link_masses: Sequence[float], link_inertias: Sequence[float], gravity: float = 9.81,
         joint_damping: Sequence[float] | None = None) -> np.ndarray:
    """Recursive Newton-Euler inverse dynamics of a planar n-link revolute chain.

    Parameters
    ----------
    q, qd, qdd : (n,) or (..., n) -- rad, rad/s, rad/s^2
    link_lengths, com_distances : (n,) m
    link_masses : (n,) kg
    link_inertias : (n,) kg m^2 about each CG, normal to the plane
    gravity : m/s^2, along -y
    joint_damping : (n,) N m s/rad, default zeros

    Returns
    -------
    tau : (n,) or (..., n) N m, damping included.
    """
    chain = NewtonEulerChain(link_lengths=link_lengths, com_distances=com_distances,
                             link_masses=link_masses, link_inertias=link_inertias,
                             gravity=gravity, joint_damping=joint_damping)
    return chain.inverse_dynamics(q, qd, qdd)
