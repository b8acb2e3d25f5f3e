"""The lecture's general Lagrange route, as a second, independent implementation.

Give a :class:`LagrangianSystem` the two things the lecture says are enough -- the mass
matrix ``D(q)`` (``KE = q'^T D(q) q' / 2``) and the potential energy ``PE(q)`` -- and it
derives the rest of the equations of motion::

    D(q) q'' + C(q, q') q' + g(q) + B q' = tau

* ``dD/dq_k`` and ``dPE/dq_k`` by complex-step differentiation: with ``h = 1e-30``,
  ``df/dq_k = Im f(q + i h e_k) / h`` to machine precision (no subtraction, so no
  cancellation error). The callables must therefore be *complex-analytic*: built from
  numpy arithmetic and analytic functions (``np.sin``, ``np.cos``, ``np.exp``, powers, ...)
  that accept complex arrays, with no ``abs``, ``np.conj``, ``np.real``, ``float()``,
  comparisons or ``dtype=float`` casts on anything that depends on ``q``. A callable that
  returns a real array for complex input is taken to be constant in ``q``.
* Christoffel symbols ``c_ijk = 1/2 (dd_kj/dq_i + dd_ki/dq_j - dd_ij/dq_k)``, and
  ``C_kj = sum_i c_ijk q_i'`` (so ``D' - 2C`` is skew-symmetric);
* ``g = grad PE``; ``B = diag(joint_damping)`` (viscous joint friction).

Builders for the systems the project and the lecture use:

* :func:`planar_chain` -- a planar n-link serial revolute arm (any ``n >= 1``), written with
  plain loops over the links from the link Jacobians, not from the 2-link closed form;
* :func:`spring_mass` -- the lecture's check ``m x'' + k x = F``;
* :func:`geared_link_lagrangian` -- the single link behind an ``n:1`` gear box, on the
  motor side: ``J th'' + B th' + C sin(th/n) = u``.

Everything is pure numpy; a system also provides ``n_dof`` and ``step`` so that
:func:`arm_dynamics.integrate.simulate` can run it.

References: Siciliano et al., *Robotics: Modelling, Planning and Control* (2009), §7.1
(Christoffel symbols); complex-step derivatives: Martins, Sturdza,
Alonso, "The complex-step derivative approximation", ACM TOMS 29(3), 2003.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from arm_dynamics._validate import finite_scalar, finite_tuple
from arm_dynamics.integrate import rk4_step

#: Complex-step size. Any tiny value works: no difference is ever taken.
COMPLEX_STEP = 1e-30

MassMatrixFn = Callable[[np.ndarray], np.ndarray]
PotentialFn = Callable[[np.ndarray], float]


class LagrangianSystem:
    """Equations of motion derived from ``D(q)`` and ``PE(q)`` alone.

    Parameters
    ----------
    mass_matrix : callable ``q (n,) -> D (n, n)``, kg m^2 (or kg for a sliding joint)
        Must be complex-analytic (see the module docstring) and symmetric positive definite
        for real ``q``.
    potential : callable ``q (n,) -> PE``, J
        Must be complex-analytic.
    n_dof : int, >= 1
        Number of generalized coordinates ``n``.
    joint_damping : (n,) N m s/rad, each >= 0, optional
        Viscous friction: generalized force ``-b_k q_k'``. Default zero.

    Notes
    -----
    The state-taking methods accept one state: every argument has shape ``(n,)``. Bad
    arguments raise ``ValueError`` naming the argument.
    """

    __slots__ = ('_d_fn', '_pe_fn', 'joint_damping', 'n_dof')

    def __init__(self, mass_matrix: MassMatrixFn, potential: PotentialFn, *, n_dof: int,
                 joint_damping: Sequence[float] | np.ndarray | None = None) -> None:
        # ValueError (not TypeError): the contract's one exception type for bad arguments.
        if not callable(mass_matrix):
            raise ValueError(f'mass_matrix must be callable, got {mass_matrix!r}')
        if not callable(potential):
            raise ValueError(f'potential must be callable, got {potential!r}')
        if isinstance(n_dof, bool) or not isinstance(n_dof, (int, np.integer)) or n_dof < 1:
            raise ValueError(f'n_dof must be an integer >= 1, got {n_dof!r}')
        n = int(n_dof)
        damping = (0.0,) * n if joint_damping is None else finite_tuple(
            'joint_damping', joint_damping, n, minimum=0.0)
        self._d_fn = mass_matrix
        self._pe_fn = potential
        self.n_dof = n
        self.joint_damping = np.array(damping)
        self.joint_damping.setflags(write=False)

    def __setattr__(self, name: str, value: object) -> None:
        if hasattr(self, name):
            raise AttributeError(f'LagrangianSystem is immutable: cannot set {name}')
        object.__setattr__(self, name, value)

    def __repr__(self) -> str:
        return (f'LagrangianSystem(n_dof={self.n_dof}, '
                f'joint_damping={tuple(self.joint_damping.tolist())})')

    # ------------------------------------------------------------------ checks
    def _vec(self, name: str, value: object) -> np.ndarray:
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f'{name} must be numeric, got {value!r}') from None
        if arr.shape != (self.n_dof,):
            raise ValueError(f'{name} must have shape ({self.n_dof},), got shape {arr.shape}')
        if not np.isfinite(arr).all():
            raise ValueError(f'{name} must be finite, got {value!r}')
        return arr

    def _call_d(self, q: np.ndarray) -> np.ndarray:
        n = self.n_dof
        d = np.asarray(self._d_fn(q))
        if d.shape != (n, n):
            raise ValueError(f'mass_matrix must return shape ({n}, {n}), got shape {d.shape}')
        if not np.isfinite(d).all():
            raise ValueError(f'mass_matrix returned non-finite values at q={q!r}')
        return d

    def _call_pe(self, q: np.ndarray) -> Any:
        pe = np.asarray(self._pe_fn(q))
        if pe.size != 1:
            raise ValueError(f'potential must return a scalar, got shape {pe.shape}')
        pe = pe.reshape(())[()]
        if not np.isfinite(pe):
            raise ValueError(f'potential returned a non-finite value at q={q!r}')
        return pe

    def _perturbed(self, q: np.ndarray, k: int) -> np.ndarray:
        qc = q.astype(complex)
        qc[k] += 1j * COMPLEX_STEP
        return qc

    # ------------------------------------------------------------------ derived terms
    def mass_matrix(self, q) -> np.ndarray:
        """D(q), shape (n, n), kg m^2: the user's callable evaluated at a real ``q``."""
        return np.real(self._call_d(self._vec('q', q))).astype(float)

    def potential_energy(self, q) -> float:
        """PE(q) [J]."""
        return float(np.real(self._call_pe(self._vec('q', q))))

    def mass_matrix_derivatives(self, q) -> np.ndarray:
        """dD/dq by complex step: shape (n, n, n), ``out[k, i, j] = d d_ij / dq_k``."""
        q = self._vec('q', q)
        return np.stack([np.imag(self._call_d(self._perturbed(q, k))) / COMPLEX_STEP
                         for k in range(self.n_dof)])

    def christoffel_symbols(self, q) -> np.ndarray:
        """c_ijk = 1/2 (dd_kj/dq_i + dd_ki/dq_j - dd_ij/dq_k): shape (n, n, n), [i, j, k]."""
        dd = self.mass_matrix_derivatives(q)   # dd[m, a, b] = d d_ab / dq_m
        return 0.5 * (np.einsum('ikj->ijk', dd) + np.einsum('jki->ijk', dd)
                      - np.einsum('kij->ijk', dd))

    def coriolis_matrix(self, q, qd) -> np.ndarray:
        """C(q, qd) with ``C_kj = sum_i c_ijk qd_i``: shape (n, n), N m s/rad."""
        qd = self._vec('qd', qd)
        return np.einsum('ijk,i->kj', self.christoffel_symbols(q), qd)

    def gravity_vector(self, q) -> np.ndarray:
        """g(q) = dPE/dq by complex step: shape (n,), N m."""
        q = self._vec('q', q)
        return np.array([np.imag(self._call_pe(self._perturbed(q, k))) / COMPLEX_STEP
                         for k in range(self.n_dof)])

    def damping_torque(self, qd) -> np.ndarray:
        """B qd, shape (n,), N m."""
        return self.joint_damping * self._vec('qd', qd)

    def forward_dynamics(self, q, qd, tau) -> np.ndarray:
        """qdd (n,) [rad/s^2] from q, qd, tau (each (n,)); one ``np.linalg.solve``."""
        q, qd, tau = self._vec('q', q), self._vec('qd', qd), self._vec('tau', tau)
        rhs = (tau - self.coriolis_matrix(q, qd) @ qd - self.gravity_vector(q)
               - self.joint_damping * qd)
        return np.linalg.solve(self.mass_matrix(q), rhs)

    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        """tau (n,) [N m] = D qdd + C qd + g + B qd for q, qd, qdd of shape (n,)."""
        q, qd, qdd = self._vec('q', q), self._vec('qd', qd), self._vec('qdd', qdd)
        return (self.mass_matrix(q) @ qdd + self.coriolis_matrix(q, qd) @ qd
                + self.gravity_vector(q) + self.joint_damping * qd)

    def energy(self, q, qd) -> tuple[float, float]:
        """(kinetic, potential) energy [J]: ``(qd^T D qd / 2, PE(q))``."""
        qd = self._vec('qd', qd)
        return 0.5 * float(qd @ self.mass_matrix(q) @ qd), self.potential_energy(q)

    def step(self, q, qd, tau, dt: float, n_steps: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Advance ``n_steps`` RK4 steps of ``dt`` [s] holding ``tau``; returns (q, qd)."""
        dt = finite_scalar('dt', dt, minimum=0.0, strict=True)
        if isinstance(n_steps, bool) or not isinstance(n_steps, (int, np.integer)) \
                or n_steps < 0:
            raise ValueError(f'n_steps must be an integer >= 0, got {n_steps!r}')
        q, qd, tau = self._vec('q', q), self._vec('qd', qd), self._vec('tau', tau)
        for _ in range(n_steps):
            q, qd = rk4_step(self.forward_dynamics, q, qd, tau, dt)
        return q, qd


# ---------------------------------------------------------------------- builders
def _chain_kinematics(q: np.ndarray, lengths: np.ndarray, com: np.ndarray
                      ) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Joint positions p_0..p_{n-1} and CG positions c_1..c_n of a planar chain.

    ``q`` may be complex (complex step). Link ``i`` (0-based) starts at joint ``i``, at
    ``joints[i]``, and points along the absolute angle ``phi_i = q_0 + ... + q_i``.
    """
    zero = np.zeros(2, dtype=q.dtype)
    joints: list[np.ndarray] = []
    cgs: list[np.ndarray] = []
    phi = q.dtype.type(0)
    origin = zero
    for i in range(q.shape[0]):
        phi = phi + q[i]
        direction = np.array([np.cos(phi), np.sin(phi)])
        joints.append(origin)
        cgs.append(origin + com[i] * direction)
        origin = origin + lengths[i] * direction
    return joints, cgs, origin


def planar_chain(link_lengths: Sequence[float], com_distances: Sequence[float],
                 link_masses: Sequence[float], link_inertias: Sequence[float],
                 gravity: float = 9.81,
                 joint_damping: Sequence[float] | None = None) -> LagrangianSystem:
    """A planar n-link serial revolute arm as a :class:`LagrangianSystem` (any n >= 1).

    Convention: ``q1`` from the +x axis, ``q_i`` relative to link ``i-1``, gravity along -y,
    PE zero at the base height. Link ``i`` has length ``l_i``, CG at ``lc_i`` from its joint
    axis along the link, mass ``m_i`` and inertia ``I_i`` about its CG normal to the plane.

    ``D(q) = sum_i (m_i J_vci^T J_vci + I_i J_wi^T J_wi)`` with the CG Jacobian column
    ``j <= i`` equal to ``z x (c_i - p_j)`` (``p_j`` the position of joint ``j``) and
    ``J_wi = [1 .. 1 (i ones), 0 .. 0]``; ``PE = sum_i m_i g y_ci``.

    Parameters
    ----------
    link_lengths : (n,) m, each > 0
    com_distances : (n,) m, each >= 0
    link_masses : (n,) kg, each > 0
    link_inertias : (n,) kg m^2, each >= 0
    gravity : m/s^2, >= 0
    joint_damping : (n,) N m s/rad, each >= 0, default zeros

    Raises
    ------
    ValueError
        Naming the bad argument; also if ``D(q)`` is singular (smallest eigenvalue below
        1e-12 of the largest) at a stretched/folded configuration (``q_i`` in {0, pi} for
        i >= 2, all combinations up to n = 9, the first 256 beyond), where the
        translational parts lose rank. ``q_1`` does not enter ``D``.
    """
    if isinstance(link_lengths, (str, bytes)) or not isinstance(
            link_lengths, (Sequence, np.ndarray)) or len(link_lengths) < 1:
        raise ValueError(f'link_lengths must be a non-empty sequence, got {link_lengths!r}')
    n = len(link_lengths)
    lengths = np.array(finite_tuple('link_lengths', link_lengths, n, minimum=0.0, strict=True))
    com = np.array(finite_tuple('com_distances', com_distances, n, minimum=0.0))
    masses = np.array(finite_tuple('link_masses', link_masses, n, minimum=0.0, strict=True))
    inertias = np.array(finite_tuple('link_inertias', link_inertias, n, minimum=0.0))
    g0 = finite_scalar('gravity', gravity, minimum=0.0)
    damping = None if joint_damping is None else finite_tuple(
        'joint_damping', joint_damping, n, minimum=0.0)

    def mass_matrix(q: np.ndarray) -> np.ndarray:
        joints, cgs, _ = _chain_kinematics(q, lengths, com)
        d = np.zeros((n, n), dtype=q.dtype)
        for i in range(n):
            jv = np.zeros((2, n), dtype=q.dtype)
            for j in range(i + 1):
                r = cgs[i] - joints[j]
                jv[0, j] = -r[1]          # z x r = (-r_y, r_x)
                jv[1, j] = r[0]
            jw = np.zeros(n)
            jw[:i + 1] = 1.0
            d = d + masses[i] * (jv.T @ jv) + inertias[i] * np.outer(jw, jw)
        return d

    def potential(q: np.ndarray):
        _, cgs, _ = _chain_kinematics(q, lengths, com)
        pe = q.dtype.type(0)
        for i in range(n):
            pe = pe + masses[i] * g0 * cgs[i][1]
        return pe

    # Singularity check where the point-mass parts are degenerate (links aligned).
    grid = [np.zeros(n)]
    if n > 1:
        count = min(2 ** (n - 1), 256)
        for code in range(1, count):
            q = np.zeros(n)
            q[1:] = [np.pi * ((code >> b) & 1) for b in range(n - 1)]
            grid.append(q)
    for q in grid:
        eig = np.linalg.eigvalsh(mass_matrix(q))
        if not eig[0] > 1e-12 * eig[-1]:
            raise ValueError(
                'link_inertias/com_distances: the mass matrix D(q) is singular at '
                f'q={q.tolist()}; give the outer links a positive inertia or CG distance')
    return LagrangianSystem(mass_matrix, potential, n_dof=n, joint_damping=damping)


def spring_mass(mass: float, stiffness: float, damping: float = 0.0) -> LagrangianSystem:
    """The lecture's check: ``KE = m x'^2/2``, ``PE = k x^2/2`` (x in m, F in N).

    Lagrange then gives ``m x'' + c x' + k x = F`` (``c`` = ``damping``, N s/m).

    Parameters
    ----------
    mass : kg, > 0
    stiffness : N/m, >= 0
    damping : N s/m, >= 0
    """
    m = finite_scalar('mass', mass, minimum=0.0, strict=True)
    k = finite_scalar('stiffness', stiffness, minimum=0.0)
    c = finite_scalar('damping', damping, minimum=0.0)
    return LagrangianSystem(lambda x: np.array([[m]]), lambda x: 0.5 * k * x[0] ** 2,
                            n_dof=1, joint_damping=(c,))


def geared_link_lagrangian(motor_inertia: float = 0.005, load_inertia: float = 1.0,
                           motor_damping: float = 0.01, load_damping: float = 0.5,
                           gear_ratio: float = 50.0, mass: float = 2.0, length: float = 0.5,
                           gravity: float = 9.81) -> LagrangianSystem:
    """The single link behind an n:1 gear box, generalized coordinate ``theta_m`` [rad].

    Same parameters (names, units, defaults) as
    :class:`arm_dynamics.geared_link.SingleLinkGeared`. Built from energies, not from the
    closed form: the motor turns at ``theta_m'`` and the load at ``theta_m'/n``, so
    ``KE = (Jm 1^2 + Jl (1/n)^2) theta_m'^2 / 2``, the Rayleigh dissipation gives the
    damping ``Bm 1^2 + Bl (1/n)^2``, and ``PE = M g l (1 - cos(theta_m / n))`` (zero hanging
    straight down).
    """
    jm = finite_scalar('motor_inertia', motor_inertia, minimum=0.0, strict=True)
    n = finite_scalar('gear_ratio', gear_ratio, minimum=0.0, strict=True)
    jl, bm, bl, m, ll, g0 = (finite_scalar(name, v, minimum=0.0) for name, v in (
        ('load_inertia', load_inertia), ('motor_damping', motor_damping),
        ('load_damping', load_damping), ('mass', mass), ('length', length),
        ('gravity', gravity)))
    speed_ratios = np.array([1.0, 1.0 / n])      # d(theta_motor, theta_load)/d theta_m
    inertias = np.array([jm, jl])
    dampings = np.array([bm, bl])
    reflected_inertia = float(inertias @ speed_ratios**2)
    reflected_damping = float(dampings @ speed_ratios**2)
    return LagrangianSystem(
        lambda th: np.array([[reflected_inertia]]),
        lambda th: m * g0 * ll * (1.0 - np.cos(th[0] / n)),
        n_dof=1, joint_damping=(reflected_damping,))
