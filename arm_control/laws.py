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

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from arm_dynamics._validate import finite_tuple
from arm_dynamics.models import RobotModel


@dataclass(frozen=True)
class GainSpec:
    """One per-joint gain: its name (``gains.<name>`` on the controller), the default for
    the 2-R arm's two joints (joints beyond take the last value), unit and meaning."""

    name: str
    default: tuple[float, ...]
    unit: str
    description: str
    positive: bool = False  # > 0 (else >= 0)


#: The gains, one source for the controller's parameters, the sweep and the docs.
#: PID's integral clamp must let the integral supply the whole gravity torque wherever the
#: arm stops: at most 30.4 N m (shoulder) and 5.9 N m (elbow), with the default arm
#: stretched horizontally. 40 / 10 N m cover that with a third to spare and stay below the
#: effort limits (60 / 20 N m). (20 N m, the old shoulder clamp, is below the 20.66 N m the
#: demo pose needs: PID then left 8.2e-3 rad there forever.)
GAINS: tuple[GainSpec, ...] = (
    GainSpec('kp', (100.0, 60.0), 'N m/rad; computed_torque: 1/s^2', 'proportional gain'),
    GainSpec('kd', (20.0, 12.0), 'N m s/rad; computed_torque: 1/s', 'derivative gain'),
    GainSpec('ki', (50.0, 30.0), 'N m/(rad s)', 'integral gain (pid)'),
    GainSpec('i_clamp', (40.0, 10.0), 'N m',
             'bound on the integral term (pid anti-windup); above the largest gravity '
             'torque so the integral can hold any pose'),
    GainSpec('lqr_q', (1e4, 1e4), '1/rad^2', 'lqr: weight of the position error in Q'),
    GainSpec('lqr_qd', (100.0, 100.0), 's^2/rad^2', 'lqr: weight of the velocity error in Q'),
    GainSpec('lqr_r', (1.0, 1.0), '1/(N m)^2', 'lqr: weight of the torque in R', True),
)
_DEFAULTS = {g.name: g.default for g in GAINS}


@dataclass(frozen=True)
class Gains:
    """Per-joint gains, one value per joint (every gain the same length n).

    Parameters
    ----------
    kp : (n,) N m/rad, >= 0 (for computed_torque: 1/s^2)
    kd : (n,) N m s/rad, >= 0 (for computed_torque: 1/s)
    ki : (n,) N m/(rad s), >= 0 (pid only)
    i_clamp : (n,) N m, >= 0 -- bound on the integral term's torque (pid only)
    lqr_q, lqr_qd : (n,) 1/rad^2, s^2/rad^2, >= 0; lqr_r : (n,) 1/(N m)^2, > 0 -- the
        diagonal weights of lqr's cost (None: each joint's default)

    Defaults: :data:`GAINS` (for two joints).
    """

    kp: tuple[float, ...] = _DEFAULTS['kp']
    kd: tuple[float, ...] = _DEFAULTS['kd']
    ki: tuple[float, ...] = _DEFAULTS['ki']
    i_clamp: tuple[float, ...] = _DEFAULTS['i_clamp']
    lqr_q: tuple[float, ...] | None = None
    lqr_qd: tuple[float, ...] | None = None
    lqr_r: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        n = len(self.kp) if hasattr(self.kp, '__len__') else 0
        for g in GAINS:
            value = getattr(self, g.name)
            if value is None:  # a gain given for two joints only: the last one repeated
                value = (g.default + (g.default[-1],) * n)[:n]
            object.__setattr__(self, g.name, finite_tuple(
                g.name, value, n, minimum=0.0, strict=g.positive))


#: torque(kp, kd, ki, i_clamp, limits, model, integral, e, ed, q, qd, qdd_des, dt, *,
#: q_des, weights, cache) -> (raw torque, new integral); see :func:`law_torque` for the
#: arguments (a law takes the keywords it needs and ignores the rest).
TorqueFn = Callable[..., tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Law:
    """One control law: ``name`` (the ``law`` parameter's value), its formula, the gains
    it reads, whether it needs the controller's model, and its torque function."""

    name: str
    formula: str
    note: str
    gains: tuple[str, ...]
    uses_model: bool
    torque: TorqueFn
    batch: bool = True   # works on a batch of arms (the sweeps' loop)


def _pd(kp, kd, ki, i_clamp, limits, model, integral, e, ed, q, qd, qdd_des, dt, **_):
    return kp * e + kd * ed, integral


def _pd_gravity(kp, kd, ki, i_clamp, limits, model, integral, e, ed, q, qd, qdd_des, dt, **_):
    return kp * e + kd * ed + model.gravity_vector(q), integral


def _computed_torque(kp, kd, ki, i_clamp, limits, model, integral, e, ed, q, qd, qdd_des,
                     dt, **_):
    return model.inverse_dynamics(q, qd, qdd_des + kd * ed + kp * e), integral


def lqr_gain(model: RobotModel, q_goal, weights, period: float) -> np.ndarray:
    """The discrete LQR gain K (n, 2n) [N m/rad, N m s/rad] about the goal at rest,
    ``q_goal`` [rad] with its gravity torque: ``(Ad, Bd)`` of the control ``period`` [s]
    (:mod:`arm_dynamics.linearize`), the discrete algebraic Riccati equation
    (``scipy.linalg.solve_discrete_are``) with ``Q = diag(lqr_q, lqr_qd)``, ``R =
    diag(lqr_r)``, and ``K = (R + Bd' P Bd)^-1 Bd' P Ad``: the closed loop ``Ad - Bd K``
    has the eigenvalues the design chose. ``weights`` = (lqr_q, lqr_qd, lqr_r).

    References: Franklin, Powell, Workman, *Digital Control of Dynamic Systems* (1998),
    §9.2; Lewis, Vrabie, Syrmos, *Optimal Control* (3rd ed., 2012), §2.4."""
    from scipy.linalg import solve_discrete_are
    q_goal = np.asarray(q_goal, dtype=float)
    n = len(q_goal)
    ad, bd = model.linearize(q_goal, np.zeros(n), model.gravity_vector(q_goal),
                             period=period)
    q_w, qd_w, r_w = (np.asarray(w, dtype=float) for w in weights)
    p = solve_discrete_are(ad, bd, np.diag(np.r_[q_w, qd_w]), np.diag(r_w))
    return np.linalg.solve(np.diag(r_w) + bd.T @ p @ bd, bd.T @ p @ ad)


#: The control period lqr designs for when the law has not been called before (s).
LQR_PERIOD = 0.01


def _lqr(kp, kd, ki, i_clamp, limits, model, integral, e, ed, q, qd, qdd_des, dt, *,
         q_des, weights, cache=None, **_):
    if np.ndim(q) != 1:
        raise ValueError('lqr designs one gain per arm about its goal: not for a batch')
    q_goal = np.asarray(q_des, dtype=float)
    period = dt if dt > 0.0 else LQR_PERIOD
    key = (tuple(q_goal), period)
    gain = None if cache is None else cache.get(key)
    if gain is None:
        gain = lqr_gain(model, q_goal, weights, period)
        if cache is not None:
            cache.clear()  # one goal at a time: a moving reference re-designs each tick
            cache[key] = gain
    return model.gravity_vector(q_goal) + gain @ np.r_[e, ed], integral


def _pid(kp, kd, ki, i_clamp, limits, model, integral, e, ed, q, qd, qdd_des, dt, **_):
    candidate = np.clip(integral + ki * e * dt, -i_clamp, i_clamp)
    raw = kp * e + kd * ed + candidate
    # Conditional integration: keep the old integral where the output saturates
    # and the error would push it further out.
    winding = (np.abs(raw) > limits) & (np.sign(raw) == np.sign(e))
    integral = np.where(winding, integral, candidate)
    return kp * e + kd * ed + integral, integral


#: The laws by name: the controller's ``law`` choices, its help, the docs' law table and
#: the sweep's ``law`` axis all come from here. To add a law, add an entry (and a test that
#: states its behaviour): docs/architecture.md, "Add a control law".
LAW_TABLE: dict[str, Law] = {law.name: law for law in (
    Law('pd', "Kp e + Kd e'", 'independent joint PD; leaves the steady-state error of '
        'Kp e = g(q)', ('kp', 'kd'), False, _pd),
    Law('pd_gravity', "Kp e + Kd e' + g(q)", "PD with gravity from the controller's model",
        ('kp', 'kd'), True, _pd_gravity),
    Law('computed_torque', "D(q) (qdd_des + Kd e' + Kp e) + C q' + g + B q'",
        "inverse dynamics: e'' + Kd e' + Kp e = 0 with an exact model", ('kp', 'kd'), True,
        _computed_torque),
    Law('pid', "Kp e + Ki int(e) + Kd e'", 'model-free; the integral clamped to i_clamp and '
        'frozen while the output saturates', ('kp', 'kd', 'ki', 'i_clamp'), False, _pid),
    Law('lqr', "g(q_goal) + K (e, e')", 'discrete LQR about the goal at rest (the sampled '
        'linearisation, Riccati), gravity feed-forward; not in batch sweeps',
        ('lqr_q', 'lqr_qd', 'lqr_r'), True, _lqr, batch=False),
)}
#: The laws a batch of arms can run (the sweeps' law axis).
BATCH_LAWS = tuple(name for name, law in LAW_TABLE.items() if law.batch)
LAWS = tuple(LAW_TABLE)


def laws_markdown() -> str:
    """The docs' table of the laws (docs/nodes.md holds it verbatim; a test checks)."""
    rows = ['| law | torque | what it is | gains |', '|---|---|---|---|']
    rows += [f"| `{law.name}` | `{law.formula}` | {law.note} | "
             f"{', '.join(f'`{g}`' for g in law.gains)} |" for law in LAW_TABLE.values()]
    return '\n'.join(rows) + '\n'


def gains_markdown() -> str:
    """The docs' table of the gains (docs/nodes.md holds it verbatim; a test checks)."""
    rows = ['| parameter | default (2-R) | unit | meaning |', '|---|---|---|---|']
    rows += [f"| `gains.{g.name}` | `{list(g.default)}` | {g.unit} | {g.description} |"
             for g in GAINS]
    return '\n'.join(rows) + '\n'


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
    model: RobotModel
    effort_limits: tuple[float, ...]
    integral: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        if self.law not in LAWS:
            raise ValueError(f"law must be one of {', '.join(LAWS)}; got {self.law!r}")
        n = self.model.n_dof
        self.effort_limits = finite_tuple('effort_limits', self.effort_limits, n,
                                          minimum=0.0, strict=True)
        if len(self.gains.kp) != n:
            raise ValueError(f'gains have {len(self.gains.kp)} values per gain but the '
                             f'model has {n} joints')
        self._limits = np.array(self.effort_limits)
        if np.shape(self.integral) != (n,):  # not given (or not for these joints): zero
            self.integral = np.zeros(n)
        self._designs: dict = {}  # lqr: the gain of the current goal

    def reset(self) -> None:
        """Forget the integral."""
        self.integral = np.zeros(len(self.effort_limits))

    def __call__(self, q: np.ndarray, qd: np.ndarray, q_des: np.ndarray,
                 qd_des: np.ndarray, qdd_des: np.ndarray, dt: float) -> Command:
        """Torque for state (q [rad], qd [rad/s]) and reference (q_des, qd_des,
        qdd_des [rad/s^2]); ``dt`` [s] is the time since the previous call (PID only)."""
        g = self.gains
        raw, self.integral = law_torque(
            self.law, np.asarray(g.kp), np.asarray(g.kd), np.asarray(g.ki),
            np.asarray(g.i_clamp), self._limits, self.model, self.integral, q, qd, q_des,
            qd_des, qdd_des, dt, weights=(g.lqr_q, g.lqr_qd, g.lqr_r),
            cache=self._designs)
        tau = np.clip(raw, -self._limits, self._limits)
        return Command(tau=tau, raw=raw, saturated=np.abs(raw) > self._limits)


def law_torque(law: str, kp: np.ndarray, kd: np.ndarray, ki: np.ndarray,
               i_clamp: np.ndarray, limits: np.ndarray, model, integral: np.ndarray,
               q: np.ndarray, qd: np.ndarray, q_des: np.ndarray, qd_des: np.ndarray,
               qdd_des: np.ndarray, dt: float,
               weights=None, cache: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The unsaturated torque of ``law`` and the PID integral after this call.

    The formulas of :class:`ControlLaw` (which calls this), for one state or a batch:
    every array is (n,) or (B, n) (gains and limits broadcast), ``model`` a
    :class:`~arm_dynamics.models.RobotModel` or, for a batch with one model per row, a
    :class:`~arm_dynamics.two_link.TwoLinkBatch`.

    Parameters
    ----------
    law : one of ``LAWS`` (:data:`LAW_TABLE`)
    kp, kd, ki, i_clamp : gains, units as in :class:`Gains`
    limits : N m, the effort limits (PID conditional integration)
    integral : N m, the PID integral term before this call (other laws: returned as is)
    q, qd : rad, rad/s -- measured state
    q_des, qd_des, qdd_des : rad, rad/s, rad/s^2 -- reference
    dt : s, time since the previous call (PID; lqr designs for it)
    weights : (lqr_q, lqr_qd, lqr_r), each (n,) -- lqr's cost weights (other laws: unused)
    cache : dict or None -- lqr keeps the gain of the current goal here between calls

    Returns
    -------
    raw : N m, before saturation
    integral : N m, the new PID integral
    """
    spec = LAW_TABLE.get(law)
    if spec is None:
        raise ValueError(f"law must be one of {', '.join(LAWS)}; got {law!r}")
    e, ed = q_des - q, qd_des - qd
    return spec.torque(kp, kd, ki, i_clamp, limits, model, integral, e, ed, q, qd, qdd_des,
                       dt, q_des=q_des, weights=weights, cache=cache)
