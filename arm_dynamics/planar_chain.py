"""A planar chain of n revolute links, any n >= 1, from one generic routine.

The lecture ends on extending the 2-R dynamics "in general for the n-link manipulator";
this is that model, and the proof that the robot-model seam (:mod:`arm_dynamics.models`)
carries any robot. Every dynamic quantity comes from recursive Newton-Euler
(:class:`~arm_dynamics.newton_euler.NewtonEulerChain`), never from a hand-written formula:

* ``tau = ID(q, qd, qdd)`` is one RNEA pass (gravity and damping included) plus the
  rotors' ``A qdd``;
* ``D(q)`` column ``j`` is ``ID(q, 0, e_j)`` of the same chain without gravity and damping
  (all n columns in one broadcast pass), plus ``A`` on the diagonal;
* ``g(q) = ID(q, 0, 0)`` without damping; the bias ``h = C qd + g + B qd = ID(q, qd, 0)``;
* forward dynamics is one solve, ``qdd = D^-1 (tau - h)``;
* ``C(q, qd)`` (Christoffel form) from ``dD/dq`` by complex step (exact to rounding), for
  the analyses that want the matrix itself.

Geared motors (as :class:`~arm_dynamics.two_link.TwoLinkArm`): joint ``i`` driven through
a gear of ratio ``n_i`` by a rotor of inertia ``Jm_i`` and viscous friction ``Bm_i`` (motor
side) gets the reflected inertia ``A_i = n_i^2 Jm_i`` on the diagonal of ``D`` (``A =
diag(armature)``) and ``n_i^2 Bm_i`` added to its damping; torques and states stay
joint-side. Spong, Hutchinson, Vidyasagar, *Robot Modeling and Control*, Dynamics chapter
(reflected rotor inertia) and Independent Joint Control chapter (actuator dynamics).

Convention (the contract's): ``q1`` from the +x axis, ``q_i`` relative to link ``i-1``,
gravity along -y, potential energy zero at the base height. With n = 2 and the same
parameters it is the 2-R arm of :class:`~arm_dynamics.two_link.TwoLinkArm` (to rounding,
tested), which keeps its closed form for speed.

References: Featherstone, *Rigid Body Dynamics Algorithms* (2008), §5.3 (RNEA) and §6.1
(the mass matrix by unit accelerations); Siciliano et al., *Robotics: Modelling, Planning
and Control* (2009), §7.1 (Christoffel symbols) and §7.5.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from arm_dynamics._validate import finite_scalar, finite_tuple, state_array, step_count
from arm_dynamics.integrate import rk4_step
from arm_dynamics.newton_euler import NewtonEulerChain

#: Complex-step size for dD/dq (no subtraction, so any tiny step is exact to rounding).
_COMPLEX_STEP = 1e-30


@dataclass(frozen=True)
class PlanarChain:
    """Planar n-R arm (n = ``len(link_lengths)``) with point-mass-plus-inertia links.

    Parameters
    ----------
    link_lengths : (n,) m, each > 0
        Joint axis to next joint axis; the last one to the end effector.
    com_distances : (n,) m, each >= 0
        Joint axis to the link's centre of gravity, along the link.
    link_masses : (n,) kg, each > 0
    link_inertias : (n,) kg m^2, each >= 0
        About the centre of gravity, normal to the plane. ``D(q)`` must stay positive
        definite; a set for which it is singular with the links aligned is refused.
    gravity : m/s^2, >= 0, acting along -y.
    joint_damping : (n,) N m s/rad, each >= 0 (default zeros).
    gear_ratios : (n,) [-], each > 0 (default ones)
        Motor turns per joint turn.
    motor_inertias : (n,) kg m^2, each >= 0 (default zeros)
        Rotor inertias, motor side: ``n_i^2 Jm_i`` (:attr:`armature`) on ``D``'s diagonal.
    motor_damping : (n,) N m s/rad, each >= 0 (default zeros)
        Motor viscous friction, motor side: ``n_i^2 Bm_i`` added to ``joint_damping``
        (:attr:`total_damping`).

    Every state-taking method accepts one state (n,) or a batch (..., n); torques are
    joint-side.
    """

    link_lengths: Sequence[float] = (1.0, 0.8)
    com_distances: Sequence[float] = (0.5, 0.4)
    link_masses: Sequence[float] = (2.0, 1.5)
    link_inertias: Sequence[float] = (0.1, 0.08)
    gravity: float = 9.81
    joint_damping: Sequence[float] | None = None
    gear_ratios: Sequence[float] | None = None
    motor_inertias: Sequence[float] | None = None
    motor_damping: Sequence[float] | None = None
    _full: NewtonEulerChain = field(init=False, repr=False, compare=False)
    _inertial: NewtonEulerChain = field(init=False, repr=False, compare=False)
    _gravity: NewtonEulerChain = field(init=False, repr=False, compare=False)
    _armature: np.ndarray = field(init=False, repr=False, compare=False)

    #: The constructor arguments, which are also the robot parameters' names.
    PARAMETERS = ('link_lengths', 'com_distances', 'link_masses', 'link_inertias', 'gravity',
                  'joint_damping', 'gear_ratios', 'motor_inertias', 'motor_damping')

    def __post_init__(self) -> None:
        lengths = self.link_lengths
        if isinstance(lengths, (str, bytes)) or not isinstance(
                lengths, (Sequence, np.ndarray)) or len(lengths) < 1:
            raise ValueError(f'link_lengths must be a non-empty list, got {lengths!r}')
        n = len(lengths)

        def given(value: Any, default: float) -> Any:
            return (default,) * n if value is None else value

        values: dict[str, Any] = {
            'link_lengths': finite_tuple('link_lengths', lengths, n, minimum=0.0, strict=True),
            'com_distances': finite_tuple('com_distances', self.com_distances, n, minimum=0.0),
            'link_masses': finite_tuple('link_masses', self.link_masses, n, minimum=0.0,
                                        strict=True),
            'link_inertias': finite_tuple('link_inertias', self.link_inertias, n, minimum=0.0),
            'gravity': finite_scalar('gravity', self.gravity, minimum=0.0),
            'joint_damping': finite_tuple('joint_damping', given(self.joint_damping, 0.0), n,
                                          minimum=0.0),
            'gear_ratios': finite_tuple('gear_ratios', given(self.gear_ratios, 1.0), n,
                                        minimum=0.0, strict=True),
            'motor_inertias': finite_tuple('motor_inertias', given(self.motor_inertias, 0.0),
                                           n, minimum=0.0),
            'motor_damping': finite_tuple('motor_damping', given(self.motor_damping, 0.0), n,
                                          minimum=0.0),
        }
        for name, value in values.items():
            object.__setattr__(self, name, value)
        armature = np.array(self.armature)
        armature.setflags(write=False)
        object.__setattr__(self, '_armature', armature)
        geometry = {k: values[k] for k in ('link_lengths', 'com_distances', 'link_masses',
                                           'link_inertias')}
        object.__setattr__(self, '_full', NewtonEulerChain(
            **geometry, gravity=values['gravity'], joint_damping=self.total_damping))
        object.__setattr__(self, '_inertial', NewtonEulerChain(**geometry, gravity=0.0))
        object.__setattr__(self, '_gravity', NewtonEulerChain(**geometry,
                                                              gravity=values['gravity']))
        self._check_mass_matrix()

    def _check_mass_matrix(self) -> None:
        """Refuse parameters whose D(q) is singular with the links aligned (q_i in {0, pi}
        for i >= 2: where the point-mass parts lose rank; q_1 does not enter D)."""
        n = self.n_dof
        grid = np.zeros((min(2 ** (n - 1), 256), n))
        for code in range(1, grid.shape[0]):
            grid[code, 1:] = [np.pi * ((code >> b) & 1) for b in range(n - 1)]
        eig = np.linalg.eigvalsh(self.mass_matrix(grid))
        bad = np.flatnonzero(~(eig[:, 0] > 1e-12 * eig[:, -1]))
        if bad.size:
            raise ValueError(
                'link_inertias/com_distances: the mass matrix D(q) is singular at '
                f'q={grid[bad[0]].tolist()} (link_inertias={list(self.link_inertias)}, '
                f'com_distances={list(self.com_distances)}); give the outer links a positive '
                'inertia or a non-zero com distance')

    def __reduce__(self) -> tuple[type, tuple[Any, ...]]:
        """Pickle as the constructor arguments (the Newton-Euler chains are rebuilt)."""
        return type(self), tuple(getattr(self, name) for name in self.PARAMETERS)

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> PlanarChain:
        """The chain from robot parameters by name (missing ones take the defaults, other
        keys are ignored)."""
        return cls(**{k: params[k] for k in cls.PARAMETERS if k in params})

    @property
    def n_dof(self) -> int:
        """Number of joints n."""
        return len(self.link_lengths)

    @property
    def armature(self) -> tuple[float, ...]:
        """``n_i^2 Jm_i`` [kg m^2] per joint: the rotor inertias reflected to the joints, on
        the diagonal of ``D(q)`` (MuJoCo's joint ``armature``)."""
        assert self.gear_ratios is not None and self.motor_inertias is not None
        return tuple(r * r * j for r, j in zip(self.gear_ratios, self.motor_inertias))

    @property
    def total_damping(self) -> tuple[float, ...]:
        """``joint_damping_i + n_i^2 Bm_i`` [N m s/rad] per joint: the viscous friction the
        joint sees (``B``)."""
        assert (self.joint_damping is not None and self.gear_ratios is not None
                and self.motor_damping is not None)
        return tuple(b + r * r * f for b, r, f in zip(self.joint_damping, self.gear_ratios,
                                                      self.motor_damping))

    # ------------------------------------------------------------------ dynamics
    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        """tau [N m] = D qdd + C qd + g + B qd; shapes (n,) or (..., n): the links' RNEA
        pass (damping ``B`` total) plus the rotors' ``A qdd``."""
        n = self.n_dof
        q, qd, qdd = (state_array(name, v, n) for name, v in (('q', q), ('qd', qd),
                                                             ('qdd', qdd)))
        return self._full.unchecked(q, qd, qdd) + self._armature * qdd

    def inverse_dynamics_complex(self, q, qd, qdd) -> np.ndarray:
        """:meth:`inverse_dynamics` carrying complex ``q`` and ``qd`` through (the same
        Newton-Euler pass), for complex-step derivatives; unchecked."""
        qdd = np.asarray(qdd)
        return (self._full.unchecked(np.asarray(q), np.asarray(qd), qdd)
                + self._armature * qdd)

    def linearize(self, q, qd, tau, period: float | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        """``(A, B)`` about ``(q, qd, tau)``, state ``(q, qd)``: continuous, or with
        ``period`` [s] the zero-order-hold pair of the control period
        (:mod:`arm_dynamics.linearize`)."""
        from arm_dynamics.linearize import linearized
        return linearized(self, q, qd, tau, period)

    def mass_matrix(self, q) -> np.ndarray:
        """D(q), kg m^2: (n, n) or (..., n, n); column j is ID(q, 0, e_j) without gravity,
        plus the reflected rotor inertias (:attr:`armature`) on the diagonal."""
        return self._columns(state_array('q', q, self.n_dof))

    def _columns(self, q: np.ndarray) -> np.ndarray:
        n = self.n_dof
        eye = np.eye(n, dtype=q.dtype)
        cols = self._inertial.unchecked(q[..., None, :], np.zeros(n), eye)
        # row j of cols is column j of D; D is symmetric
        return np.swapaxes(cols, -1, -2) + np.diag(self._armature)

    def gravity_vector(self, q) -> np.ndarray:
        """g(q) = dPE/dq, N m: (n,) or (..., n)."""
        n = self.n_dof
        return self._gravity.inverse_dynamics(q, np.zeros(n), np.zeros(n))

    def damping_torque(self, qd) -> np.ndarray:
        """B qd, N m, ``B = diag(joint_damping + n^2 Bm)`` (:attr:`total_damping`)."""
        return state_array('qd', qd, self.n_dof) * np.asarray(self.total_damping)

    def bias(self, q, qd) -> np.ndarray:
        """h = C(q, qd) qd + g(q) + B qd [N m], one Newton-Euler pass."""
        n = self.n_dof
        return self._full.inverse_dynamics(q, qd, np.zeros(n))

    def coriolis_matrix(self, q, qd) -> np.ndarray:
        """C(q, qd) [N m s/rad] in Christoffel form (so D' - 2C is skew), (n, n) or
        (..., n, n): ``C_kj = sum_i c_ijk qd_i``, ``c_ijk = (dD_kj/dq_i + dD_ki/dq_j -
        dD_ij/dq_k) / 2``, with ``dD/dq_i`` by complex step."""
        n = self.n_dof
        q = state_array('q', q, n)
        qd = state_array('qd', qd, n)
        dd = np.stack([self._columns(q + 1j * _COMPLEX_STEP * np.eye(n)[i]).imag
                       / _COMPLEX_STEP for i in range(n)], -3)   # (..., i, k, j): dD_kj/dq_i
        christoffel = 0.5 * (dd + np.swapaxes(dd, -3, -1) - np.swapaxes(dd, -3, -2))
        # christoffel[..., i, k, j] = c_ijk as above
        return np.einsum('...ikj,...i->...kj', christoffel, qd)

    def forward_dynamics(self, q, qd, tau) -> np.ndarray:
        """qdd [rad/s^2] = D^-1 (tau - h): one solve; shapes (n,) or (..., n)."""
        n = self.n_dof
        q = state_array('q', q, n)
        qd = state_array('qd', qd, n)
        tau = state_array('tau', tau, n)
        q, qd, tau = np.broadcast_arrays(q, qd, tau)
        rhs = tau - self.bias(q, qd)
        return np.linalg.solve(self._columns(q), rhs[..., None])[..., 0]

    def step(self, q, qd, tau, dt: float, n_steps: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Advance ``n_steps`` RK4 steps of ``dt`` [s] holding ``tau`` [N m]; (q, qd)."""
        dt = finite_scalar('dt', dt, minimum=0.0, strict=True)
        n_steps = step_count('n_steps', n_steps)
        n = self.n_dof
        q, qd = state_array('q', q, n), state_array('qd', qd, n)
        tau = state_array('tau', tau, n)
        for _ in range(n_steps):
            q, qd = rk4_step(self.forward_dynamics, q, qd, tau, dt)
        return q, qd

    def energy(self, q, qd) -> tuple[np.ndarray, np.ndarray]:
        """(kinetic, potential) energy [J]; potential zero at the base height. Kinetic
        ``qd^T D(q) qd / 2``, the rotors' ``n^2 Jm qd^2 / 2`` included."""
        qd = state_array('qd', qd, self.n_dof)
        kinetic = 0.5 * np.einsum('...i,...ij,...j->...', qd, self.mass_matrix(q), qd)
        q = state_array('q', q, self.n_dof)
        phi = np.cumsum(q, -1)
        lengths = np.asarray(self.link_lengths)
        joint_y = np.cumsum(lengths * np.sin(phi), -1) - lengths * np.sin(phi)
        cg_y = joint_y + np.asarray(self.com_distances) * np.sin(phi)
        return kinetic, self.gravity * np.sum(np.asarray(self.link_masses) * cg_y, -1)

    # ------------------------------------------------------------------ kinematics
    def joint_points(self, q) -> np.ndarray:
        """Base, every joint after it and the tip [m]: (n + 1, 2) or (..., n + 1, 2)."""
        q = state_array('q', q, self.n_dof)
        phi = np.cumsum(q, -1)
        lengths = np.asarray(self.link_lengths)
        xy = np.stack([np.cumsum(lengths * np.cos(phi), -1),
                       np.cumsum(lengths * np.sin(phi), -1)], -1)
        base = np.zeros(xy.shape[:-2] + (1, 2))
        return np.concatenate([base, xy], -2)

    def forward_kinematics(self, q) -> np.ndarray:
        """End-effector position (x, y) [m]: (2,) or (..., 2)."""
        return self.joint_points(q)[..., -1, :]

    def jacobian(self, q) -> np.ndarray:
        """``J = dp/dq`` of the tip [m/rad]: (2, n) or (..., 2, n). Column j is
        ``z x (p_tip - p_j)``."""
        points = self.joint_points(q)
        r = points[..., -1:, :] - points[..., :-1, :]          # (..., n, 2)
        return np.stack([-r[..., 1], r[..., 0]], -2)

    def jdot_qd(self, q, qd) -> np.ndarray:
        """``J'(q, q') q'`` [m/s^2]: the tip acceleration at zero joint acceleration,
        ``-sum_i l_i w_i^2 (cos phi_i, sin phi_i)`` with the link angles ``phi_i = q_1 +
        ... + q_i`` and rates ``w_i``; (2,) or (..., 2)."""
        q = state_array('q', q, self.n_dof)
        qd = state_array('qd', qd, self.n_dof)
        phi, w = np.cumsum(q, -1), np.cumsum(qd, -1)
        lw2 = np.asarray(self.link_lengths) * w * w
        return -np.stack(np.broadcast_arrays(np.sum(lw2 * np.cos(phi), -1),
                                             np.sum(lw2 * np.sin(phi), -1)), -1)

