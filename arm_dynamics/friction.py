"""Coulomb and static (stick/slip) joint friction, with event-located switching.

Each joint ``i`` has, on the link side, a Coulomb (sliding) friction ``c_i >= 0`` and a
static (break-away) friction ``s_i >= c_i`` [N m] (:class:`JointFriction`). The arm obeys
``D(q) qdd + C(q, qd) qd + g(q) + B qd = tau + tau_f`` (:class:`~arm_dynamics.models.
RobotModel`) with the friction torque ``tau_f``:

* a **slipping** joint (``qd_i != 0``, or just broken away) feels ``-c_i sigma_i``, with
  ``sigma_i`` the sign of its velocity (right after break-away: the direction of the net
  torque). Over one interval between events ``sigma`` is fixed, so with no joint stuck the
  dynamics are the model's own under the torque ``tau - c sigma``, held: one
  ``model.step``;
* a **stuck** joint has ``qd_i = 0`` and ``qdd_i = 0`` exactly: its friction torque is the
  constraint torque that holds it. With the stuck set ``S`` and the free set ``F``, the
  free joints move by the reduced system ``D_FF qdd_F = r_F`` (``r = tau - c sigma - h``,
  ``h = C qd + g + B qd``) and the holding torque is ``lambda_S = D_SF qdd_F - r_S``. The
  joint stays stuck while ``|lambda_i| <= s_i``; beyond, it breaks away and slips in the
  direction of the net torque ``-lambda_i``, ``c_i`` opposing (Karnopp's stick/slip
  switch, here with the zero velocity located exactly instead of a small velocity band);
* a **locked** joint (a brake: the "stuck joint" fault) is held like a stuck one whatever
  the torque and never breaks away.

Events are located inside the physics step (event-driven integration): a slipping joint's
velocity reaching zero, a stuck joint's holding torque leaving its band. The rest of the
step is integrated in the current mode by one classical RK4 step (the model's; constrained
joints held); if an event function changed sign over it, the earliest crossing is found by
the Illinois method (regula falsi with the stagnant end's value halved, bisection as a
safeguard) on re-integrations from the start of the interval to a fraction of it, to
:data:`EVENT_TOLERANCE` seconds. The state just past the crossing is taken (the velocities
that reached zero set to exactly 0.0), the mode decided again (:meth:`_Step.decide`: a joint
at zero velocity sticks if the holding torque it needs is within ``s_i``, else slips the way
the net torque pushes; several at once: the most overloaded is released first and the others
re-checked with it free, a greedy answer to the underlying complementarity problem), and the
rest of the step integrated. One event at a time, the earliest first; at most
:data:`MAX_EVENTS` per step (beyond, the step is finished in the last mode: a guard against
Zeno switching). A velocity that crosses zero and comes back within one RK4 interval is not
seen (at 1 ms steps that takes a torque reversing within the millisecond).

A stuck joint neither creeps nor chatters: its position is carried through unchanged, bit
for bit, and its velocity is exactly 0.0 for as long as the holding torque stays in band.
The mode is a function of the state: a joint with friction and ``qd_i == 0`` is decided
afresh at every step (the ``stuck`` flags are reported, and checked, but hold nothing the
velocities do not), so a reset or a vectorised sweep needs no extra state.

Cost, from cheapest: friction off and no brake is ``model.step`` itself; every joint with
friction at rest is one inverse-dynamics call (the holding torque ``g(q) - tau``) and
nothing moves; every joint slipping with no event is one ``model.step`` under ``tau - c
sign(qd)`` plus a sign check; a stuck joint among moving ones is a constrained RK4 step (the
free-free block of ``D`` from inverse-dynamics differences, ``1 + |F|`` calls per stage)
plus a holding-torque check at its end; an event adds the re-integrations of its location
(four or five). On the 2-R arm the slipping case calls its ``step_floats`` (``step``'s
operations on floats: the same bits, without the arrays), and the event-driven path runs on
floats too (:class:`_Step2`: the arm's float RK4 and inverse dynamics, the same bits).
:func:`friction_step_batch` steps ``B`` arms, the event-free rows in one batched
``model.step`` (:mod:`arm_dynamics.batch` batches every mode, for the sweep's plants).

References: H. Olsson, K. J. Åström, C. Canudas de Wit, M. Gäfvert, P. Lischinsky,
"Friction models and friction compensation", European Journal of Control 4 (1998) 176-195
(Coulomb friction and stiction, the static model used here); D. Karnopp, "Computer
simulation of stick-slip friction in mechanical dynamic systems", ASME J. Dyn. Syst. Meas.
Control 107 (1985) 100-103 (sticking decided on the torque needed to stay stuck);
R. I. Leine, H. Nijmeijer, *Dynamics and Bifurcations of Non-Smooth Mechanical Systems*
(Springer, 2004), ch. 2-3 (switch models, event-driven integration); the Illinois method:
M. Dowell, P. Jarratt, BIT 11 (1971) 168-174.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from arm_dynamics._validate import finite_scalar, finite_tuple
from arm_dynamics.integrate import rk4_step

#: Event instants are located to this [s] (the width of the final bracket).
EVENT_TOLERANCE = 1e-12
#: At most this many stick/slip events in one physics step (a guard against Zeno
#: switching); beyond it the rest of the step is integrated in the last mode.
MAX_EVENTS = 64
#: Unit acceleration [rad/s^2] of the inverse-dynamics differences that give columns of
#: D(q): a power of two (exact scaling), large so that the bias cancels with little loss.
_UNIT_ACCEL = 1024.0
#: Iterations of one event location before it settles for its bracket (never reached:
#: the safeguarded bisection halves the bracket at least every other iteration).
_MAX_ITERATIONS = 200

_Kind = tuple[int, int]   # (0, i): joint i's velocity reached zero; (1, i): i breaks away
_State = tuple[tuple[float, float], tuple[float, float]]   # ((q1, q2), (qd1, qd2)), 2-R


def _friction_values(name: str, value: object, n: int) -> tuple[float, ...]:
    return finite_tuple(name, value, n, minimum=0.0)


# ------------------------------------------------------------------- the parameter rules
# The rules of the robot parameters ``coulomb_friction`` / ``static_friction`` (the
# simulator's, the sweeps' scenario settings, the parameter validation): stated here once.

#: The ``static_friction`` rule in words, as the parameter descriptions state it.
STATIC_FRICTION_RULE = '0 = its coulomb_friction, else >= it'


def static_friction_used(static: Sequence[float],
                         coulomb: Sequence[float]) -> tuple[float, ...]:
    """The break-away friction [N m] of each joint that the ``static_friction`` parameter
    gives: its value, a 0 standing for the joint's ``coulomb_friction`` [N m] (Coulomb
    friction that sticks at zero velocity, no extra break-away torque)."""
    return tuple(float(c) if s == 0 else float(s) for s, c in zip(static, coulomb))


def static_friction_problem(static: Sequence[float], coulomb: Sequence[float], *,
                            zero_is_coulomb: bool = True) -> str | None:
    """Why ``static`` [N m] is below ``coulomb`` [N m] on a joint (the first such), or None:
    the break-away torque is at least the sliding one.

    ``zero_is_coulomb`` (default): the values as the parameters give them, a 0 being the
    joint's Coulomb value (:func:`static_friction_used`), numbers shown short (``:g``);
    else the values used themselves (a 0 is 0, as :class:`JointFriction` takes them),
    numbers shown exactly."""
    used = static_friction_used(static, coulomb) if zero_is_coulomb else tuple(static)
    for i, (s, c) in enumerate(zip(used, coulomb)):
        if s < c:
            shown = (f'{float(s):g}', f'{float(c):g}') if zero_is_coulomb else (
                repr(float(s)), repr(float(c)))
            return (f'static_friction[{i}] = {shown[0]} N m is below coulomb_friction[{i}] = '
                    f'{shown[1]} N m: the break-away torque is at least the sliding one'
                    + (' (0 = equal to it)' if zero_is_coulomb else ''))
    return None


def _empty(value: object) -> bool:
    return value is None or (hasattr(value, '__len__') and len(value) == 0)


@dataclass(frozen=True, eq=False)
class JointFriction:
    """Per-joint Coulomb and static friction, on the link side.

    Parameters
    ----------
    coulomb : (n,) N m, each finite and >= 0
        Sliding friction ``c_i``: a slipping joint feels ``-c_i sign(qd_i)``.
    static : (n,) N m, each finite and >= ``coulomb[i]``
        Break-away friction ``s_i``: a joint at rest stays at rest while the torque needed
        to hold it is within ``+-s_i``. ``s_i == c_i`` is plain Coulomb friction with
        sticking; ``s_i == 0`` (hence ``c_i == 0``) a frictionless joint, never stuck.

    Both are stored as read-only float arrays. Errors name the robot parameters
    (``coulomb_friction``, ``static_friction``), the joint and the bad value.
    """

    coulomb: np.ndarray
    static: np.ndarray
    _active: np.ndarray = field(init=False, repr=False)
    _enabled: bool = field(init=False, repr=False)
    _lists: tuple[list[float], list[float], tuple[int, ...]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        coulomb = self.coulomb
        if isinstance(coulomb, (str, bytes)) or not isinstance(coulomb, (Sequence, np.ndarray)):
            raise ValueError(f'coulomb_friction must be a sequence of numbers, got {coulomb!r}')
        n = len(coulomb)
        c = np.array(_friction_values('coulomb_friction', coulomb, n), dtype=float)
        s = np.array(_friction_values('static_friction', self.static, n), dtype=float)
        problem = static_friction_problem(s.tolist(), c.tolist(), zero_is_coulomb=False)
        if problem:
            raise ValueError(problem)
        active = s > 0.0
        for arr in (c, s, active):
            arr.setflags(write=False)
        object.__setattr__(self, 'coulomb', c)
        object.__setattr__(self, 'static', s)
        object.__setattr__(self, '_active', active)
        object.__setattr__(self, '_enabled', bool(active.any()))
        object.__setattr__(self, '_lists', (c.tolist(), s.tolist(),
                                            tuple(int(i) for i in np.flatnonzero(active))))

    @classmethod
    def from_params(cls, params: Mapping[str, Any], n: int) -> JointFriction:
        """The friction of an ``n``-joint arm from robot parameters by name.

        ``coulomb_friction`` (n,) N m: missing or empty -> zeros. ``static_friction`` (n,)
        N m: missing or empty -> equal to ``coulomb_friction``, and so is each 0
        (:func:`static_friction_used`: Coulomb friction that sticks at zero velocity, no
        extra break-away torque). A non-empty list must have exactly ``n`` values: a
        shorter one is refused, not padded (more likely a mistake than a wish). Other keys
        are ignored.
        """
        coulomb = params.get('coulomb_friction')
        c = _friction_values('coulomb_friction', (0.0,) * n if _empty(coulomb) else coulomb, n)
        static = params.get('static_friction')
        s = c if _empty(static) else _friction_values('static_friction', static, n)
        return cls(coulomb=np.array(c), static=np.array(static_friction_used(s, c)))

    @classmethod
    def none(cls, n: int) -> JointFriction:
        """No friction on any of ``n`` joints."""
        return cls(coulomb=np.zeros(n), static=np.zeros(n))

    @property
    def n(self) -> int:
        """Number of joints."""
        return len(self.coulomb)

    @property
    def enabled(self) -> bool:
        """Whether any joint has friction (any non-zero value)."""
        return self._enabled

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, JointFriction):
            return NotImplemented
        return (np.array_equal(self.coulomb, other.coulomb)
                and np.array_equal(self.static, other.static))

    def __hash__(self) -> int:
        return hash((tuple(self._lists[0]), tuple(self._lists[1])))

    def __repr__(self) -> str:
        return f'JointFriction(coulomb={self._lists[0]}, static={self._lists[1]})'

    def __reduce__(self) -> tuple[type, tuple[Any, ...]]:
        """Pickle as the two value lists (the derived fields are rebuilt)."""
        return type(self), (self._lists[0], self._lists[1])


# ---------------------------------------------------------------------------------- step
def friction_step(model: Any, q, qd, tau, dt: float, stuck, friction: JointFriction,
                  locked=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """One physics step of ``dt`` [s] with joint friction, the torque ``tau`` held.

    Parameters
    ----------
    model : a :class:`~arm_dynamics.models.RobotModel` (uses ``n_dof``, ``step``,
        ``inverse_dynamics``; ``mass_matrix`` only when a brake catches a moving joint)
    q, qd : (n,) rad, rad/s -- the state at the start of the step.
    tau : (n,) N m -- the applied torque (external torques included), held over the step.
    dt : s, > 0
    stuck : (n,) bool -- the flags the previous step returned (all False to start). A
        joint flagged stuck must have ``qd_i == 0.0`` exactly (else ValueError). Every
        joint with friction and ``qd_i == 0`` is decided afresh by the static rule,
        flagged or not: the flags hold nothing the velocities do not.
    friction : :class:`JointFriction` of ``n`` joints.
    locked : (n,) bool or None -- joints held by a brake whatever the torque (never break
        away). A locked joint still moving is caught at the start of the step: an
        inelastic impact, ``qd_L -> 0`` with the free joints' momentum ``(D qd)_F`` kept.

    Returns
    -------
    q, qd : (n,) rad, rad/s -- the state after the step (new arrays).
    stuck : (n,) bool -- the joints at rest and held at the end of the step: by static
        friction, or by the brake (a locked joint is always True).
    work : J, >= 0 -- the energy friction took in the step: ``sum c_i |dq_i|`` over the
        slipping intervals (a stuck joint takes nothing), plus the kinetic energy lost
        when a brake catches a moving joint. So over any run ``E(end) - E(start) = sum
        tau . dq - damping work - sum work``, to the integrator's error.

    With ``friction.enabled`` False and no joint locked this is ``model.step(q, qd, tau,
    dt, 1)``, bit for bit (``stuck`` all False, ``work`` 0.0). Raises ValueError naming a
    bad argument.
    """
    c, s, active = friction._lists
    n = len(c)
    if model.n_dof != n:
        raise ValueError(f'friction has {n} joints but the model has {model.n_dof}')
    if locked is None and not friction._enabled:
        q1, qd1 = model.step(q, qd, tau, dt, 1)
        return q1, qd1, _bools(n, dtype=bool), 0.0
    # Checks a hot loop can afford (model.step checks the values themselves); anything
    # unusual takes the validating conversions, which name a bad argument.
    if not (type(q) is _ndarray and type(qd) is _ndarray and type(tau) is _ndarray
            and type(stuck) is _ndarray and q.shape == qd.shape == tau.shape == stuck.shape
            == (n,) and q.dtype == qd.dtype == tau.dtype == _FLOAT and stuck.dtype == _BOOL
            and type(dt) is float and 0.0 < dt < math.inf):
        q, qd, tau = _vector('q', q, n), _vector('qd', qd, n), _vector('tau', tau, n)
        stuck = _flags('stuck', stuck, n)
        dt = finite_scalar('dt', dt, minimum=0.0, strict=True)
    v = qd.tolist()
    if True in stuck.tolist():
        for i, (flag, x) in enumerate(zip(stuck.tolist(), v)):
            if flag and x != 0.0:
                raise ValueError(f'stuck[{i}] is True but qd[{i}] = {x!r} rad/s: a stuck '
                                 'joint is at rest (qd exactly 0.0)')
    lock = None
    if locked is not None:
        lock = _flags('locked', locked, n)
        if True not in lock.tolist():
            lock = None
            if not friction._enabled:
                q1, qd1 = model.step(q, qd, tau, dt, 1)
                return q1, qd1, _bools(n, dtype=bool), 0.0
    if lock is None:
        # The common cases on plain floats, with the operations of _Step (the same bits).
        sign = [1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0) for x in v]
        rest = 0
        for i in active:
            if sign[i] == 0.0:
                rest += 1
        if not rest:
            # Every joint with friction slipping: one model.step under tau - c sign(qd),
            # kept unless a velocity stopped (or the state diverged).
            floats = getattr(model, 'step_floats', None) if n == 2 else None
            if floats is not None:
                # The 2-R arm's float RK4: model.step's operations, bits and all, without
                # its arrays.
                (x, y), (t1, t2) = q.tolist(), tau.tolist()
                v1 = list(floats(x, y, v[0], v[1], t1 - c[0] * sign[0], t2 - c[1] * sign[1],
                                 dt, 1))
                q1, qd1 = _array(v1[:2]), _array(v1[2:])
                v1 = v1[2:]
            else:
                taup = _array([t - ci * si for t, ci, si in zip(tau.tolist(), c, sign)])
                q1, qd1 = model.step(q, qd, taup, dt, 1)
                v1 = qd1.tolist()
            for i in active:
                if not sign[i] * v1[i] > 0.0:
                    break
            else:
                x0, x1 = q.tolist(), q1.tolist()
                work = 0.0
                for i in active:
                    dq = sign[i] * (x1[i] - x0[i])
                    if dq > 0.0:
                        work += c[i] * dq
                return q1, qd1, _bools(n, dtype=bool), work
        elif rest == n:
            # Every joint at rest: qdd = 0, holding torque -(tau - h), h = g(q) here.
            h = model.inverse_dynamics(q, qd, _zeros(n)).tolist()
            for t, hi, si in zip(tau.tolist(), h, s):
                if not abs(-(t - hi)) <= si:
                    break
            else:
                return q.copy(), qd.copy(), _ones(n, dtype=bool), 0.0
    step = _Step2 if n == 2 and getattr(model, '_tau_float', None) is not None else _Step
    return step(model, tau, friction, lock).run(q, qd, dt)


_ndarray, _array, _bools, _ones = np.ndarray, np.array, np.zeros, np.ones
_FLOAT, _BOOL = np.dtype(np.float64), np.dtype(bool)


def _vector(name: str, value: object, n: int) -> np.ndarray:
    arr = value if type(value) is np.ndarray else np.asarray(value, dtype=float)
    if arr.shape != (n,) or arr.dtype != np.float64:
        arr = np.asarray(value, dtype=float)
        if arr.shape != (n,):
            raise ValueError(f'{name} must have shape ({n},), got shape {arr.shape}')
    return arr


def _flags(name: str, value: object, n: int) -> np.ndarray:
    arr = np.asarray(value)
    if arr.shape != (n,) or arr.dtype != bool:
        raise ValueError(f'{name} must be {n} booleans, got {value!r}')
    return arr


_ZEROS: dict[int, np.ndarray] = {}
_UNITS: dict[int, np.ndarray] = {}


def _zeros(n: int) -> np.ndarray:
    z = _ZEROS.get(n)
    if z is None:
        z = _ZEROS[n] = np.zeros(n)
        z.setflags(write=False)
    return z


def _units(n: int) -> np.ndarray:
    u = _UNITS.get(n)
    if u is None:
        u = _UNITS[n] = np.eye(n) * _UNIT_ACCEL
        u.setflags(write=False)
    return u


class _Step:
    """The event-driven path of :func:`friction_step`: one physics step, one torque.

    The mode is kept as plain lists (``held``: bool per joint, stuck or locked; ``sigma``:
    the slip direction of each free joint with friction, 0.0 elsewhere): with a handful of
    joints that is cheaper than numpy's per-call overhead."""

    def __init__(self, model: Any, tau: np.ndarray, friction: JointFriction,
                 lock: np.ndarray | None) -> None:
        n = friction.n
        self.model = model
        self.n = n
        self.tau = tau.tolist()
        self.c, self.s, _ = friction._lists
        self.active = friction._active.tolist()
        self.lock = [False] * n if lock is None else lock.tolist()
        self.breakable = [a and not b for a, b in zip(self.active, self.lock)]
        self.zeros = _zeros(n)
        self.units = _units(n)

    def taup(self, sigma: list[float]) -> np.ndarray:
        """``tau - c sigma`` [N m]: the applied torque with the slipping joints' Coulomb
        friction (the same operations as the fast paths of :func:`friction_step`)."""
        return np.array([t - c * x for t, c, x in zip(self.tau, self.c, sigma)])

    # -------------------------------------------------------------- constrained dynamics
    def reduced(self, q: np.ndarray, qd: np.ndarray, taup: np.ndarray,
                free: tuple[int, ...], held: tuple[int, ...]
                ) -> tuple[np.ndarray, list[float]]:
        """``(qdd, lambda)``: the ``held`` joints constrained (qdd 0), the ``free`` ones
        moving by ``D_FF qdd_F = r_F``, ``r = taup - h``; ``lambda = D_SF qdd_F - r_S``
        (one value per held joint). Columns of D from inverse-dynamics differences, ``D
        e_j = (ID(q, qd, a e_j) - h) / a``."""
        inverse = self.model.inverse_dynamics
        h = inverse(q, qd, self.zeros)
        r = (taup - h).tolist()
        qdd = np.zeros(self.n)
        if not free:
            return qdd, [-r[i] for i in held]
        hl = h.tolist()
        if len(free) == 1:
            j = free[0]
            col = inverse(q, qd, self.units[j]).tolist()
            x = r[j] / ((col[j] - hl[j]) / _UNIT_ACCEL)
            qdd[j] = x
            return qdd, [(col[i] - hl[i]) / _UNIT_ACCEL * x - r[i] for i in held]
        cols = np.array([inverse(q, qd, self.units[j]) for j in free])
        cols = (cols - h) / _UNIT_ACCEL   # row k: column free[k] of D
        xs = np.linalg.solve(cols[:, free], np.array([r[j] for j in free]))
        qdd[list(free)] = xs
        lam = (cols[:, list(held)].T @ xs).tolist() if held else []
        return qdd, [lam[k] - r[i] for k, i in enumerate(held)]

    def advance(self, q0: np.ndarray, qd0: np.ndarray, taup: np.ndarray,
                free: tuple[int, ...], held: tuple[int, ...], h: float,
                first: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """One RK4 step of ``h`` [s] in the mode (held joints fixed, ``taup`` held);
        ``first`` the acceleration at the start if known."""
        if not held:
            return self.model.step(q0, qd0, taup, h, 1)

        def accel(q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
            if first is not None and q is q0 and qd is qd0:
                return first
            return self.reduced(q, qd, tau, free, held)[0]

        q1, qd1 = rk4_step(accel, q0, qd0, taup, h)
        # Bit for bit: the held joints' positions as they were (q + 0.0 would turn a -0.0
        # into 0.0), their velocities exactly zero.
        idx = list(held)
        q1[idx] = q0[idx]
        qd1[idx] = 0.0
        return q1, qd1

    # -------------------------------------------------------------- mode decision
    def decide(self, q: np.ndarray, qd: np.ndarray
               ) -> tuple[list[bool], list[float], np.ndarray | None]:
        """The mode at an instant: ``(held, sigma, qdd)``, ``qdd`` the mode's
        acceleration there when it was computed on the way (else None).

        Joints with friction at rest start stuck; while any of them needs a holding torque
        beyond its static friction, the most overloaded (largest ``|lambda_i| - s_i``, the
        lowest index on a tie) is released to slip along its net torque ``-lambda_i``, and
        the others are re-checked with it free."""
        v = qd.tolist()
        rest = [b and x == 0.0 for b, x in zip(self.breakable, v)]
        held = [r or b for r, b in zip(rest, self.lock)]
        sigma = [0.0 if h or not a else (1.0 if x > 0.0 else -1.0)
                 for h, a, x in zip(held, self.active, v)]
        if True not in rest:
            return held, sigma, None
        s = self.s
        while True:
            free = tuple(i for i, h in enumerate(held) if not h)
            stuck = tuple(i for i, h in enumerate(held) if h)
            if not any(rest[i] for i in stuck):
                return held, sigma, None
            qdd, lam = self.reduced(q, qd, self.taup(sigma), free, stuck)
            best, j, direction = 0.0, -1, 0.0
            for k, i in enumerate(stuck):
                excess = abs(lam[k]) - s[i]
                if rest[i] and excess > best:
                    best, j, direction = excess, i, (1.0 if lam[k] < 0.0 else -1.0)
            if j < 0:
                return held, sigma, qdd
            held[j] = False
            sigma[j] = direction

    # -------------------------------------------------------------- events
    def values(self, kinds: Sequence[_Kind], q: np.ndarray, qd: np.ndarray,
               taup: np.ndarray, sigma: list[float], free: tuple[int, ...],
               held: tuple[int, ...]) -> list[float]:
        """Each event function at a state: a slipping joint's ``sigma_i qd_i`` (kind 0,
        triggered at <= 0), a stuck joint's ``s_i - |lambda_i|`` (kind 1, triggered
        at < 0)."""
        lam: list[float] = []
        if any(kind == 1 for kind, _ in kinds):
            lam = self.reduced(q, qd, taup, free, held)[1]
        v = qd.tolist()
        return [sigma[i] * v[i] if kind == 0 else self.s[i] - abs(lam[held.index(i)])
                for kind, i in kinds]

    @staticmethod
    def triggered(kind: int, value: float) -> bool:
        return value <= 0.0 if kind == 0 else value < 0.0

    def locate(self, kinds: list[_Kind], end: tuple[np.ndarray, np.ndarray],
               end_values: list[float], start_values: list[float],
               step: Callable[[float], tuple[np.ndarray, np.ndarray]],
               evaluate: Callable[[np.ndarray, np.ndarray], list[float]], length: float
               ) -> tuple[float, tuple[np.ndarray, np.ndarray]]:
        """The earliest event of the interval: ``(theta, state)``, the state at the
        fraction ``theta`` of ``length`` [s] just past the first crossing (within
        :data:`EVENT_TOLERANCE`) of a triggered event function. Each candidate is located
        in turn inside the bracket the ones before it left (Illinois: regula falsi, the
        stagnant end's value halved; bisection when a value sits on zero or the bracket
        failed to halve in two iterations; never within half a tolerance of an end, so
        that once one end sits on the root the next point closes the bracket)."""
        tol = EVENT_TOLERANCE / length
        hi, hi_state, hi_values = 1.0, end, end_values
        for idx, (kind, _) in enumerate(kinds):
            fhi = hi_values[idx]
            if not self.triggered(kind, fhi):
                continue
            lo, flo = 0.0, start_values[idx]
            side = 0
            before = [math.inf, math.inf]
            for _ in range(_MAX_ITERATIONS):
                width = hi - lo
                if not width > tol:
                    break
                if flo > 0.0 > fhi and width <= 0.5 * before[0]:
                    m = lo + width * flo / (flo - fhi)
                else:
                    m = lo + 0.5 * width
                # Never within half a tolerance of an end: once one end sits on the root,
                # the next point lands just across it and closes the bracket.
                m = min(max(m, lo + 0.5 * tol), hi - 0.5 * tol)
                if not lo < m < hi:
                    m = lo + 0.5 * width
                    if not lo < m < hi:
                        break   # the bracket is down to adjacent floats
                before = [before[1], width]
                state = step(m)
                values = evaluate(*state)
                fm = values[idx]
                if self.triggered(kind, fm):
                    hi, fhi, hi_state, hi_values = m, fm, state, values
                    if side == -1:
                        flo *= 0.5
                    side = -1
                else:
                    lo, flo = m, fm
                    if side == 1:
                        fhi *= 0.5
                    side = 1
        return hi, hi_state

    # -------------------------------------------------------------- the step
    def run(self, q: np.ndarray, qd: np.ndarray, dt: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """Integrate ``dt`` [s] from (q, qd): ``(q, qd, held mask, work)``."""
        work = 0.0
        if True in self.lock and any(x != 0.0 for x, b in zip(qd.tolist(), self.lock) if b):
            qd, lost = self.catch(q, qd)
            work += lost
        left = dt
        held, sigma, first = self.decide(q, qd)
        moved = False
        for events in range(MAX_EVENTS + 1):
            if all(held) or not left > 0.0:
                break   # all held: nothing moves, the holding torque stays as it is
            free = tuple(i for i, h in enumerate(held) if not h)
            fixed = tuple(i for i, h in enumerate(held) if h)
            taup = self.taup(sigma)
            q1, qd1 = self.advance(q, qd, taup, free, fixed, left, first)
            moved = True
            v1 = qd1.tolist()
            kinds: list[_Kind] = [(0, i) for i in free if sigma[i] * v1[i] <= 0.0
                                  and sigma[i] != 0.0]
            kinds += [(1, i) for i in fixed if self.breakable[i]]
            values = self.values(kinds, q1, qd1, taup, sigma, free, fixed) if kinds else []
            hits = [(kv, x) for kv, x in zip(kinds, values) if self.triggered(kv[0], x)]
            if not hits or events == MAX_EVENTS:
                work += self.slip_work(q, q1, sigma)
                q, qd = q1, qd1
                break
            kinds = [kv for kv, _ in hits]

            def step(theta: float, q0=q, qd0=qd, taup=taup, free=free, fixed=fixed,
                     left=left, first=first) -> tuple[np.ndarray, np.ndarray]:
                return self.advance(q0, qd0, taup, free, fixed, theta * left, first)

            def evaluate(qx: np.ndarray, qdx: np.ndarray, kinds=kinds, taup=taup,
                         sigma=sigma, free=free, fixed=fixed) -> list[float]:
                return self.values(kinds, qx, qdx, taup, sigma, free, fixed)

            theta, (q1, qd1) = self.locate(kinds, (q1, qd1), [x for _, x in hits],
                                           evaluate(q, qd), step, evaluate, left)
            work += self.slip_work(q, q1, sigma)
            qd1 = qd1.copy()
            v1 = qd1.tolist()
            for i in free:
                if sigma[i] != 0.0 and sigma[i] * v1[i] <= 0.0:
                    qd1[i] = 0.0
            q, qd = q1, qd1
            left = 0.0 if theta >= 1.0 else left * (1.0 - theta)
            held, sigma, first = self.decide(q, qd)
        if not moved:
            q, qd = q.copy(), qd.copy()
        return q, qd, np.array(held), work

    def slip_work(self, q0: np.ndarray, q1: np.ndarray, sigma: list[float]) -> float:
        """``sum c_i max(sigma_i dq_i, 0)`` [J] over one interval of fixed signs."""
        work = 0.0
        for c, x, a, b in zip(self.c, sigma, q0.tolist(), q1.tolist()):
            if x != 0.0:
                work += c * max(x * (b - a), 0.0)
        return work

    def catch(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, float]:
        """A brake catching moving joints: ``qd_L -> 0`` with ``(D qd)_F`` kept (the
        impulse acts on the locked joints only). The new velocities and the kinetic energy
        lost [J]."""
        d = np.asarray(self.model.mass_matrix(q), dtype=float)
        lock = np.array(self.lock)
        free, locked = np.flatnonzero(~lock), np.flatnonzero(lock)
        new = qd.copy()
        if free.size:
            new[free] = qd[free] + np.linalg.solve(d[np.ix_(free, free)],
                                                   d[np.ix_(free, locked)] @ qd[locked])
        new[locked] = 0.0
        lost = 0.5 * (qd @ d @ qd - new @ d @ new)
        return new, max(float(lost), 0.0)


def _pairs(q: np.ndarray, qd: np.ndarray) -> _State:
    """A 2-R state (q, qd) (2,) arrays as a pair of float pairs."""
    (x1, x2), (v1, v2) = q.tolist(), qd.tolist()
    return (x1, x2), (v1, v2)


class _Step2(_Step):
    """:class:`_Step` on the 2-R arm (:class:`~arm_dynamics.two_link.TwoLinkArm`), on
    plain floats: the state a pair of float pairs, the arm's float RK4 (``_step_float``,
    what its ``step`` runs for one state) and float inverse dynamics (``_tau_float``, what
    its ``inverse_dynamics`` runs); :meth:`run` is :meth:`_Step.run`'s loop line for line,
    :meth:`_advance` :meth:`_Step.advance` with :func:`~arm_dynamics.integrate.rk4_step`'s
    operations element by element, :meth:`_accel` :meth:`_Step.reduced`'s: the same bits
    without the (2,) arrays. :meth:`_Step.decide` and :meth:`_Step.locate` are shared. A
    brake, or a non-finite state, takes :class:`_Step`'s own methods (which refuse a
    non-finite state, as before)."""

    def __init__(self, model: Any, tau: np.ndarray, friction: JointFriction,
                 lock: np.ndarray | None) -> None:
        super().__init__(model, tau, friction, lock)
        self.inverse = model._tau_float
        self.rk4 = model._step_float

    def _accel(self, q1: float, q2: float, v1: float, v2: float, t1: float, t2: float,
               j: int) -> tuple[float, float, float]:
        """``(qdd_1, qdd_2, lambda)`` with joint ``j`` free, the other held: :meth:`_Step.
        reduced`'s operations on floats (finite arguments)."""
        inverse = self.inverse
        h1, h2 = inverse(q1, q2, v1, v2, 0.0, 0.0)
        r1, r2 = t1 - h1, t2 - h2
        if j == 0:
            c1, c2 = inverse(q1, q2, v1, v2, _UNIT_ACCEL, 0.0)
            x = r1 / ((c1 - h1) / _UNIT_ACCEL)
            return x, 0.0, (c2 - h2) / _UNIT_ACCEL * x - r2
        c1, c2 = inverse(q1, q2, v1, v2, 0.0, _UNIT_ACCEL)
        x = r2 / ((c2 - h2) / _UNIT_ACCEL)
        return 0.0, x, (c1 - h1) / _UNIT_ACCEL * x - r1

    def reduced(self, q: np.ndarray, qd: np.ndarray, taup: np.ndarray,
                free: tuple[int, ...], held: tuple[int, ...]
                ) -> tuple[np.ndarray, list[float]]:
        if len(free) != 1:
            return super().reduced(q, qd, taup, free, held)
        q1, q2 = q.tolist()
        v1, v2 = qd.tolist()
        if not math.isfinite(q1 + q2 + v1 + v2):
            return super().reduced(q, qd, taup, free, held)
        t1, t2 = taup.tolist()
        a1, a2, lam = self._accel(q1, q2, v1, v2, t1, t2, free[0])
        return _array([a1, a2]), [lam]

    def _advance(self, state: _State, taup: list[float], free: tuple[int, ...],
                 fixed: tuple[int, ...], h: float, first: list[float] | None) -> _State:
        """:meth:`_Step.advance` on floats."""
        (x1, x2), (v1, v2) = state
        t1, t2 = taup
        if not math.isfinite(x1 + x2 + v1 + v2 + t1 + t2) or not 0.0 < h < math.inf:
            q1, qd1 = _Step.advance(self, _array(state[0]), _array(state[1]), _array(taup),
                                    free, fixed, h, None if first is None
                                    else _array(first))
            return _pairs(q1, qd1)
        if not fixed:
            # model.step(q, qd, taup, h, 1) of the 2-R arm: its float RK4
            try:
                y1, y2, w1, w2 = self.rk4(x1, x2, v1, v2, t1, t2, h, 1)
            except (ValueError, OverflowError):  # math.cos(inf): diverged, as in step
                y1 = y2 = w1 = w2 = math.nan
            return (y1, y2), (w1, w2)
        j = free[0]
        accel = self._accel
        if first is not None:
            a1, a2 = first
        else:
            a1, a2, _ = accel(x1, x2, v1, v2, t1, t2, j)
        h2 = 0.5 * h
        # rk4_step: v2 = qd + h2 a1, a2 = fd(q + h2 qd, v2), ... element by element
        u1, u2 = v1 + h2 * a1, v2 + h2 * a2
        p1, p2 = x1 + h2 * v1, x2 + h2 * v2
        ok = math.isfinite(p1 + p2 + u1 + u2)
        if ok:
            b1, b2, _ = accel(p1, p2, u1, u2, t1, t2, j)
            w1, w2 = v1 + h2 * b1, v2 + h2 * b2
            p1, p2 = x1 + h2 * u1, x2 + h2 * u2
            ok = math.isfinite(p1 + p2 + w1 + w2)
        if ok:
            c1, c2, _ = accel(p1, p2, w1, w2, t1, t2, j)
            z1, z2 = v1 + h * c1, v2 + h * c2
            p1, p2 = x1 + h * w1, x2 + h * w2
            ok = math.isfinite(p1 + p2 + z1 + z2)
        if not ok:   # non-finite within the step: _Step's own path refuses it
            q1, qd1 = _Step.advance(self, _array(state[0]), _array(state[1]), _array(taup),
                                    free, fixed, h, None if first is None
                                    else _array(first))
            return _pairs(q1, qd1)
        d1, d2, _ = accel(p1, p2, z1, z2, t1, t2, j)
        h6 = h / 6.0
        y1 = x1 + h6 * (v1 + 2.0 * (u1 + w1) + z1)
        y2 = x2 + h6 * (v2 + 2.0 * (u2 + w2) + z2)
        # Bit for bit: the held joint's position as it was, its velocity exactly zero.
        if j == 0:
            return (y1, x2), (v1 + h6 * (a1 + 2.0 * (b1 + c1) + d1), 0.0)
        return (x1, y2), (0.0, v2 + h6 * (a2 + 2.0 * (b2 + c2) + d2))

    def _values(self, kinds: Sequence[_Kind], state: _State, taup: list[float],
                sigma: list[float], free: tuple[int, ...], held: tuple[int, ...]
                ) -> list[float]:
        """:meth:`_Step.values` on floats."""
        (q1, q2), v = state
        lam = 0.0
        if any(kind == 1 for kind, _ in kinds):
            if len(free) == 1 and math.isfinite(q1 + q2 + v[0] + v[1]):
                lam = self._accel(q1, q2, v[0], v[1], taup[0], taup[1], free[0])[2]
            else:
                return self.values(kinds, _array(state[0]), _array(v), _array(taup), sigma,
                                   free, held)
        return [sigma[i] * v[i] if kind == 0 else self.s[i] - abs(lam) for kind, i in kinds]

    def run(self, q: np.ndarray, qd: np.ndarray, dt: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """:meth:`_Step.run` on floats (no brake: a brake takes :meth:`_Step.run`)."""
        if True in self.lock:
            return super().run(q, qd, dt)
        work = 0.0
        left = dt
        held, sigma, first = self.decide(q, qd)
        state = _pairs(q, qd)
        for events in range(MAX_EVENTS + 1):
            if all(held) or not left > 0.0:
                break   # all held: nothing moves, the holding torque stays as it is
            free = tuple(i for i, h in enumerate(held) if not h)
            fixed = tuple(i for i, h in enumerate(held) if h)
            taup = [t - c * x for t, c, x in zip(self.tau, self.c, sigma)]
            acc = None if first is None else first.tolist()
            end = self._advance(state, taup, free, fixed, left, acc)
            v1 = end[1]
            kinds: list[_Kind] = [(0, i) for i in free if sigma[i] * v1[i] <= 0.0
                                  and sigma[i] != 0.0]
            kinds += [(1, i) for i in fixed if self.breakable[i]]
            values = self._values(kinds, end, taup, sigma, free, fixed) if kinds else []
            hits = [(kv, x) for kv, x in zip(kinds, values) if self.triggered(kv[0], x)]
            if not hits or events == MAX_EVENTS:
                work += self._work(state[0], end[0], sigma)
                state = end
                break
            kinds = [kv for kv, _ in hits]

            def step(theta: float, start=state, taup=taup, free=free, fixed=fixed,
                     left=left, acc=acc) -> _State:
                return self._advance(start, taup, free, fixed, theta * left, acc)

            def evaluate(qx: tuple[float, float], qdx: tuple[float, float], kinds=kinds,
                         taup=taup, sigma=sigma, free=free, fixed=fixed) -> list[float]:
                return self._values(kinds, (qx, qdx), taup, sigma, free, fixed)

            located = self.locate(kinds, end, [x for _, x in hits],  # type: ignore[arg-type]
                                  evaluate(*state), step, evaluate, left)  # type: ignore[arg-type]
            theta, end = located[0], cast(_State, located[1])
            work += self._work(state[0], end[0], sigma)
            v = list(end[1])
            for i in free:
                if sigma[i] != 0.0 and sigma[i] * v[i] <= 0.0:
                    v[i] = 0.0
            state = (end[0], (v[0], v[1]))
            left = 0.0 if theta >= 1.0 else left * (1.0 - theta)
            held, sigma, first = self.decide(_array(state[0]), _array(state[1]))
        return _array(state[0]), _array(state[1]), np.array(held), work

    def _work(self, q0: tuple[float, float], q1: tuple[float, float],
              sigma: list[float]) -> float:
        """:meth:`_Step.slip_work` on floats."""
        work = 0.0
        for c, x, a, b in zip(self.c, sigma, q0, q1):
            if x != 0.0:
                work += c * max(x * (b - a), 0.0)
        return work


# ---------------------------------------------------------------------------------- batch
def friction_step_batch(model: Any, q, qd, tau, dt: float, stuck,
                        friction: JointFriction | Sequence[JointFriction], locked=None
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`friction_step` for ``B`` arms at once, for sweeps.

    Parameters
    ----------
    model : one arm whose ``step`` takes a batch (B, n) (every row that arm), or a batch of
        arms with an ``arms`` sequence (:class:`~arm_dynamics.two_link.TwoLinkBatch`: row
        ``i`` is ``arms[i]``).
    q, qd, tau : (B, n) rad, rad/s, N m
    dt : s, > 0
    stuck : (B, n) bool
    friction : one :class:`JointFriction` for every row, or a sequence of B.
    locked : (B, n) bool or None

    Returns
    -------
    q, qd : (B, n); stuck : (B, n) bool; work : (B,) J.

    The rows in which every joint with friction slips and keeps its direction over the
    step, and none is locked, are stepped together by one batched ``model.step`` under
    ``tau - c sign(qd)``; every other row by :func:`friction_step` with its own arm. A
    row's result is :func:`friction_step`'s to rounding (the batched and single-state
    paths of a model may round differently).
    """
    q, qd, tau = (np.asarray(v, dtype=float) for v in (q, qd, tau))
    if q.ndim != 2:
        raise ValueError(f'q must have shape (B, n), got shape {q.shape}')
    rows, n = q.shape
    for name, arr in (('qd', qd), ('tau', tau)):
        if arr.shape != (rows, n):
            raise ValueError(f'{name} must have shape {(rows, n)}, got shape {arr.shape}')
    stuck = np.asarray(stuck)
    if stuck.shape != (rows, n) or stuck.dtype != bool:
        raise ValueError(f'stuck must be {(rows, n)} booleans, got {stuck!r}')
    lock = None if locked is None else np.asarray(locked)
    if lock is not None and (lock.shape != (rows, n) or lock.dtype != bool):
        raise ValueError(f'locked must be {(rows, n)} booleans, got {locked!r}')
    frictions = ([friction] * rows if isinstance(friction, JointFriction)
                 else list(friction))
    if len(frictions) != rows:
        raise ValueError(f'friction must be one JointFriction or {rows}, got '
                         f'{len(frictions)}')
    arms = getattr(model, 'arms', None)
    c = np.array([f.coulomb for f in frictions])
    active = np.array([f._active for f in frictions])
    sign = np.sign(qd)
    q1, qd1 = model.step(q, qd, tau - c * sign, dt, 1)
    fast = np.all(~active | (sign * qd1 > 0.0), axis=1) & np.all(~active | (sign != 0.0),
                                                                    axis=1)
    fast &= ~stuck.any(axis=1)
    if lock is not None:
        fast &= ~lock.any(axis=1)
    out_q, out_qd = np.array(q1, dtype=float), np.array(qd1, dtype=float)
    out_stuck = np.zeros((rows, n), dtype=bool)
    work = np.where(fast, np.sum(c * np.maximum(sign * (out_q - q), 0.0), axis=1), 0.0)
    for i in np.flatnonzero(~fast).tolist():
        arm = arms[i] if arms is not None else model
        out_q[i], out_qd[i], out_stuck[i], work[i] = friction_step(
            arm, q[i], qd[i], tau[i], dt, stuck[i], frictions[i],
            None if lock is None else lock[i])
    return out_q, out_qd, out_stuck, work
