"""The simulator's plant side for a batch of two-link arms, free of ROS: what a parameter
sweep steps.

:class:`BatchSimulator` is :class:`~arm_dynamics.simulation.SimulatorCore`'s sampled-data
loop for ``B`` arms at once, each with its own parameters (:class:`~arm_dynamics.two_link.
TwoLinkBatch`): each control period it takes the command of every arm, holds it over the
period saturated at that arm's effort limits while the plants take fixed RK4 physics
steps, and checks each arm for divergence (a state faster than ``velocity_limit`` or
non-finite, as the simulator's ``velocity_limit``). A diverged arm stops: it keeps its last
good state, with zero torque applied, for the rest of the run; the others go on. No joint
limits, hard stops or runaway envelope (the sweep's arms run free).

The real arm, per row, as :class:`~arm_dynamics.simulation.SimulatorCore` has it (all off
by default; off, the loop above bit for bit):

* friction (:class:`~arm_dynamics.friction.JointFriction`): each row, each physics step,
  :func:`~arm_dynamics.friction.friction_step` of its arm, to rounding, with every mode
  batched (:class:`_Period`): each row's mode (slipping; one joint stuck and held, the
  other moving by the constrained dynamics; both held; a break-away from rest) decided at
  the start of the period, all rows stepped together by one RK4 step per physics step,
  each in its mode, a row keeping its mode from step to step while no event happens. A
  row with an event in a step (a velocity reaching zero, a break-away within the step,
  both joints leaving rest) is that row's :func:`~arm_dynamics.friction.friction_step`
  for that step (its event location), then decided afresh;
* sensors (:class:`~arm_dynamics.sensors.SensorModel`'s settings: noise drawn from each row's
  own ``noise_seed`` generator in the same order, encoder counts, a sensing delay line):
  :attr:`BatchSimulator.measured` is what each row's controller sees;
* an actuation delay (:class:`~arm_dynamics.sensors.ActuationDelay`): each row's command
  applied its own number of periods late, zero torque before.

The control law is the caller's (e.g. :func:`arm_control.laws.law_torque` on the (B, 2)
state): this module knows the plants only.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from arm_dynamics.friction import _UNIT_ACCEL, JointFriction, friction_step
from arm_dynamics.sensors import SensorModel, _periods
from arm_dynamics.two_link import TwoLinkArm, TwoLinkBatch, _make_inverse, _rk4

#: Noise draws are taken from each row's generator this many states at a time (the same
#: values as one draw per state: a Generator's normals do not depend on how they are asked).
NOISE_BLOCK = 256


class BatchSimulator:
    """``B`` two-link plants, each under its own held, saturated torque command.

    Row ``i`` of every (B, 2) array belongs to ``plants[i]``.

    Parameters
    ----------
    plants : sequence of B :class:`~arm_dynamics.two_link.TwoLinkArm`, B >= 1
    q0, qd0 : (B, 2) rad, rad/s -- the initial states.
    effort_limits : (B, 2) N m, > 0 -- each applied torque is clipped to +-limits.
    physics_step_ns : int, ns > 0 -- the RK4 step.
    control_period_ns : int, ns -- a whole multiple of the physics step; one
        :meth:`advance` is one control period.
    velocity_limit : rad/s -- an arm with any |qd| above it, or a non-finite state, after
        a period has diverged.
    friction : B :class:`~arm_dynamics.friction.JointFriction` or None (none).
    sensors : B mappings of :class:`~arm_dynamics.sensors.SensorModel` keywords
        (``position_noise``, ``velocity_noise``, ``encoder_resolution``, ``sensing_delay``,
        ``seed``) or None (ideal).
    actuation_delay : B whole numbers of control periods >= 0, or None (0).

    Attributes
    ----------
    q, qd : (B, 2) rad, rad/s -- the current states (a diverged arm: its last good one).
    applied : (B, 2) N m -- the torque applied over the last period (zero before the
        first, and for an arm that diverged in it or before).
    alive : (B,) bool -- the arms that have not diverged.
    diverged_at : (B,) int -- the number of the period (1 = the first :meth:`advance`)
        after which each arm diverged; -1 while it has not.
    periods : int -- control periods advanced so far.
    dt : s -- the physics step; ``substeps`` RK4 steps per control period.
    measured : ((B, 2), (B, 2)) rad, rad/s -- the measurement of the current state each
        row's controller sees (the true state itself without sensors).
    stuck : (B, 2) bool -- the joints held by static friction at the end of the last step.
    """

    def __init__(self, plants: Sequence[TwoLinkArm], *, q0, qd0, effort_limits,
                 physics_step_ns: int, control_period_ns: int,
                 velocity_limit: float, friction: Sequence[JointFriction] | None = None,
                 sensors: Sequence[Mapping[str, Any]] | None = None,
                 actuation_delay: Sequence[int] | None = None) -> None:
        if physics_step_ns <= 0 or control_period_ns % physics_step_ns:
            raise ValueError(
                f'control period {control_period_ns} ns must be a whole multiple of the '
                f'physics step {physics_step_ns} ns')
        self.plant = TwoLinkBatch(plants)
        b = len(self.plant)
        shape = (b, 2)
        arrays = {}
        for name, value in (('q0', q0), ('qd0', qd0), ('effort_limits', effort_limits)):
            arr = np.array(value, dtype=float)
            if arr.shape != shape:
                raise ValueError(f'{name} must have shape {shape} (one row per plant), got '
                                 f'{arr.shape}')
            arrays[name] = arr
        self.q, self.qd, self.limits = arrays['q0'], arrays['qd0'], arrays['effort_limits']
        self.dt = physics_step_ns * 1e-9
        self.substeps = control_period_ns // physics_step_ns
        self.velocity_limit = velocity_limit
        self.applied = np.zeros(shape)
        self.alive = np.ones(b, dtype=bool)
        self.diverged_at = np.full(b, -1)
        self.periods = 0
        self.stuck = np.zeros(shape, dtype=bool)
        self.friction = _Friction(self.plant, friction) if friction is not None else None
        if self.friction is not None and not self.friction.enabled:
            self.friction = None
        self.sensors = _Sensors(b, sensors) if sensors is not None else None
        if self.sensors is not None and not self.sensors.enabled:
            self.sensors = None
        delays = np.zeros(b, dtype=int) if actuation_delay is None else np.array(
            [_periods('actuation_delay', k) for k in actuation_delay])
        if delays.shape != (b,) or (delays < 0).any():
            raise ValueError(f'actuation_delay must be {b} whole numbers of periods >= 0, got '
                             f'{actuation_delay!r}')
        self.delays = delays
        self._queue = (np.zeros((int(delays.max()) + 1, b, 2)) if delays.any() else None)
        self.measured = (self.q, self.qd)
        self._sense()

    def __len__(self) -> int:
        return len(self.plant)

    def _sense(self) -> None:
        """Measure the state just reached (once per state, as SimulatorCore does)."""
        if self.sensors is not None:
            self.measured = self.sensors.measure(self.q, self.qd)
        else:
            self.measured = (self.q, self.qd)

    def _delayed(self, command: np.ndarray) -> np.ndarray:
        """The command to apply this period: each row's given ``delay`` periods ago (zero
        before), as :class:`~arm_dynamics.sensors.ActuationDelay`."""
        if self._queue is None:
            return command
        size = len(self._queue)
        p = self.periods - 1  # this period, from 0
        self._queue[p % size] = command
        rows = np.arange(len(self.delays))
        out = self._queue[(p - self.delays) % size, rows]
        return np.where((p >= self.delays)[:, None], out, 0.0)

    def advance(self, command) -> None:
        """Integrate one control period: ``command`` (B, 2) [N m] (each row's given its
        actuation delay ago, zero before) held, saturated at the effort limits (zero for a
        diverged arm), ``substeps`` RK4 steps of ``dt`` (with friction: :class:`_Period`,
        friction_step's rule for each row and step); then every arm that went faster than
        ``velocity_limit`` or non-finite is diverged (its state put back to the last good
        one, its applied torque zero); then the new state is measured (:attr:`measured`)."""
        self.periods += 1
        command = self._delayed(np.asarray(command, dtype=float))
        tau = np.clip(command, -self.limits, self.limits)
        if not self.alive.all():
            tau = np.where(self.alive[:, None], tau, 0.0)
        if self.friction is None:
            q, qd = self.plant.step(self.q, self.qd, tau, self.dt, self.substeps)
        else:
            with np.errstate(all='ignore'):
                q, qd, self.stuck = self.friction.period(self.q, self.qd, tau, self.dt,
                                                         self.substeps, self.stuck)
        with np.errstate(invalid='ignore'):
            bad = ~(np.abs(qd).max(axis=1) <= self.velocity_limit) | ~np.isfinite(q).all(1)
        bad &= self.alive
        if bad.any():
            self.diverged_at[bad] = self.periods
            self.alive &= ~bad
            tau = np.where(bad[:, None], 0.0, tau)
        if not self.alive.all():
            held = ~self.alive[:, None]
            q, qd = np.where(held, self.q, q), np.where(held, self.qd, qd)
            self.stuck &= ~held & (qd == 0.0)
        self.q, self.qd, self.applied = q, qd, tau
        self._sense()


def _per_row(name: str, values: Sequence[Any], rows: int) -> list[Any]:
    out = list(values)
    if len(out) != rows:
        raise ValueError(f'{name} must give one value per row ({rows}), got {len(out)}')
    return out


class _Friction:
    """The friction of B rows, and their periods with it (:class:`_Period`)."""

    def __init__(self, plant: TwoLinkBatch, friction: Sequence[JointFriction]) -> None:
        rows = _per_row('friction', friction, len(plant))
        bad = [i for i, f in enumerate(rows) if not isinstance(f, JointFriction) or f.n != 2]
        if bad:
            raise ValueError(f'friction[{bad[0]}] must be a JointFriction of 2 joints, got '
                             f'{rows[bad[0]]!r}')
        self.plant = plant
        self.rows = rows
        self.arrays = _arrays(rows)
        self.enabled = bool(self.arrays[2].any())
        self.k = np.array(plant._k)   # (8, B)
        #: ((q, qd) bytes, the held rows' terms) at the end of the last period: the next
        #: period's decision reuses them if it starts from that state, bit for bit.
        self.held: tuple[tuple[bytes, bytes], dict[int, tuple[Any, ...]]] | None = None

    def period(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, dt: float, n: int,
               stuck: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``n`` physics steps of ``dt`` [s] under the held ``tau``: (q, qd, stuck)."""
        key = (q.tobytes(), qd.tobytes())
        cache = self.held[1] if self.held is not None and self.held[0] == key else None
        period = _Period(self.plant, q, qd, tau, dt, stuck, self.rows, self.arrays, self.k,
                         cache)
        q1, qd1, stuck1 = period.run(n)
        self.held = (q1.tobytes(), qd1.tobytes()), period.held_terms()
        return q1, qd1, stuck1


def _arrays(friction: Sequence[JointFriction]) -> tuple[Any, ...]:
    """(coulomb (B, 2), static (B, 2), active (B, 2), every joint active) of the rows."""
    c = np.array([f.coulomb for f in friction], dtype=float).reshape(-1, 2)
    s = np.array([f.static for f in friction], dtype=float).reshape(-1, 2)
    active = s > 0.0
    return c, s, active, bool(active.all())


def batch_friction_step(plant: TwoLinkBatch, q: np.ndarray, qd: np.ndarray, tau: np.ndarray,
                        dt: float, stuck: np.ndarray, friction: Sequence[JointFriction],
                        arrays: tuple[Any, ...] | None = None
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One physics step of ``dt`` [s] of B two-link arms with joint friction: row ``i``
    is :func:`~arm_dynamics.friction.friction_step` of ``plant.arms[i]`` with
    ``friction[i]`` (no brakes), to rounding (the batched RK4 and inverse dynamics use
    numpy's ``cos``/``sin``, the single arm ``math``'s; the operations are
    :func:`~arm_dynamics.friction.friction_step`'s, in its order). :class:`_Period` of one
    step.

    Parameters: q, qd, tau (B, 2) rad, rad/s, N m; stuck (B, 2) bool (the last step's);
    ``arrays``: :func:`_arrays` of the rows, precomputed. Returns (q, qd, stuck), (B, 2)
    each, new arrays; a row that went non-finite is NaN.
    """
    if arrays is None:
        arrays = _arrays(friction)
    return _Period(plant, q, qd, tau, dt, stuck, friction, arrays).run(1)


class _Period:
    """B two-link arms with joint friction under a held torque, stepped ``n`` physics
    steps of ``dt`` [s]: each row, each step, :func:`~arm_dynamics.friction.friction_step`
    of its arm, to rounding.

    The mode of each row (:meth:`decide`, friction_step's decision batched) is one of:

    * slipping: no joint with friction at rest (each slips along its velocity), or one
      at rest whose holding torque ``lambda`` (the constrained dynamics, from inverse-
      dynamics differences: :func:`_held_terms`, :func:`_held_lambda`) exceeds its
      static friction: it breaks away along ``-lambda``;
    * one joint held: one joint with friction at rest, ``|lambda| <=`` its static
      friction; the other joint moves by the constrained dynamics, the held one's
      position carried through bit for bit, its velocity exactly 0.0;
    * frozen: both joints at rest with friction and both holding torques ``g(q) - tau``
      within the static friction (nothing moves; the decision repeats itself while the
      torque is held);
    * a row for :func:`~arm_dynamics.friction.friction_step` itself: both at rest and not
      both held (a break-away from rest of both joints).

    Every step, the slipping and one-held rows take one batched RK4 step together (the
    acceleration of each row in its mode, :func:`_modal_accel`); a row is kept if no
    event happened in its step: each slipping joint with
    friction kept its direction (``sigma_i qd_i > 0`` at the end), a held joint's
    holding torque stayed in band at the end, the state is finite. A row with an event
    (a velocity reaching zero, a break-away within the step) is that row's
    :func:`~arm_dynamics.friction.friction_step` (event location) from the step's start,
    and is decided afresh for the next step; the others keep their mode (the decision
    friction_step would make at the next step's start is the same: same signs, same
    holding torque, same torque). A row that went non-finite is NaN and frozen. The held
    rows' torque-free terms at the end of the period (:meth:`held_terms`) are what the
    next period's decision needs of them, if it starts from that state (``cache``).

    Parameters: q, qd, tau (B, 2) rad, rad/s, N m (tau held over the period); dt s; stuck
    (B, 2) bool, the flags of the step before; ``friction`` B
    :class:`~arm_dynamics.friction.JointFriction` and ``arrays`` their :func:`_arrays`;
    ``k`` (8, B) the rows' lumped constants (None: ``plant``'s); ``cache``
    :meth:`held_terms` of the period that ended in (q, qd), or None. :meth:`run` steps.
    """

    def __init__(self, plant: TwoLinkBatch, q: np.ndarray, qd: np.ndarray, tau: np.ndarray,
                 dt: float, stuck: np.ndarray, friction: Sequence[JointFriction],
                 arrays: tuple[Any, ...], k: np.ndarray | None = None,
                 cache: dict[int, tuple[Any, ...]] | None = None) -> None:
        self.plant, self.friction, self.dt = plant, friction, dt
        self.c, self.s, self.active, self.every = arrays
        #: The lumped constants (a, b, d, e, g1, g2, b1, b2) of the rows, (8, B).
        self.k = np.array(plant._k) if k is None else k
        self.tau = tau
        self.stuck: np.ndarray | None = stuck
        self.x1, self.x2, self.v1, self.v2 = q[:, 0], q[:, 1], qd[:, 0], qd[:, 1]
        #: No row (B,) bool, shared by the mode masks until a decision sets one of them.
        self.none = np.zeros(len(q), dtype=bool)
        self.h0 = self.h1 = self.frozen = self.scalar = self.dead = self.none
        self.any0 = self.any1 = self.anyf = self.anys = False
        self.sg1 = self.sg2 = self.t1 = self.t2 = np.zeros(len(q))
        self.scalar_stuck: dict[int, np.ndarray] = {}   # rows last stepped by friction_step
        self.groups: list[tuple[int, np.ndarray, tuple[Any, ...], np.ndarray, np.ndarray,
                                np.ndarray]] = []
        #: The held rows' :func:`_held_terms` at the start state, by held joint: (rows,
        #: constants, static friction, terms) (:meth:`held_terms` of the period before).
        self.cache = cache or {}
        self.ends: list[tuple[Any, ...]] = []   # the same at the end of the last step
        #: The acceleration of the rows in their modes, and the (sigma == 0) masks of
        #: :meth:`step`'s sign check (None: every sigma non-zero); None: to be made.
        self.accel: Callable[..., tuple[np.ndarray, np.ndarray]] | None = None
        self.unsigned: tuple[np.ndarray, np.ndarray] | None = None
        self.decide(None)

    # ------------------------------------------------------------------ decision
    def decide(self, idx: np.ndarray | None) -> None:
        """The mode of the rows ``idx`` (None: every row) at the current state."""
        c, s, tau = self.c, self.s, self.tau
        if idx is None:
            x1, x2, v1, v2 = self.x1, self.x2, self.v1, self.v2
            cc, ss, tt = c, s, tau
        else:
            x1, x2, v1, v2 = self.x1[idx], self.x2[idx], self.v1[idx], self.v2[idx]
            cc, ss, tt = c[idx], s[idx], tau[idx]
        sg1, sg2 = np.sign(v1), np.sign(v2)
        t1, t2 = tt[:, 0] - cc[:, 0] * sg1, tt[:, 1] - cc[:, 1] * sg2
        r1, r2 = v1 == 0.0, v2 == 0.0
        if not self.every:
            act = self.active if idx is None else self.active[idx]
            r1 &= act[:, 0]
            r2 &= act[:, 1]
        dead = None
        if idx is not None:   # after friction_step: a row may have gone non-finite
            dead = ~np.isfinite(x1 + x2 + v1 + v2)
            r1 &= ~dead
            r2 &= ~dead
        rest = r1 | r2
        if idx is None and not _count(rest):
            # The common decision: every joint with friction slipping.
            if not self.every:   # a joint without friction never has an event
                act = self.active
                sg1, sg2 = np.where(act[:, 0], sg1, 0.0), np.where(act[:, 1], sg2, 0.0)
            self.sg1, self.sg2, self.t1, self.t2 = sg1, sg2, t1, t2
            self.accel = None
            return
        m = len(v1)
        h0, h1 = np.zeros(m, dtype=bool), np.zeros(m, dtype=bool)
        frozen, scalar = np.zeros(m, dtype=bool), np.zeros(m, dtype=bool)
        if dead is not None:
            frozen |= dead
        groups = []
        cached = self.cache if idx is None else {}
        if _count(rest):
            rows_of = np.arange(len(self.tau)) if idx is None else idx   # global rows
            for hold, one, held in ((0, r1 & ~r2, h0), (1, r2 & ~r1, h1)):
                if not _count(one):
                    continue
                sub = one.nonzero()[0]
                ts = (t1[sub], t2[sub])
                known = cached.get(hold)
                if (known is not None and known[0].shape == sub.shape
                        and not _count(known[0] != sub)):
                    k, s_hold, terms = known[1:]
                else:
                    k = tuple(self.k[:, rows_of[sub]])
                    s_hold = ss[sub, hold]
                    terms = _held_terms(k, hold, x1[sub], x2[sub], v1[sub], v2[sub])
                lam = _held_lambda(terms, hold, *ts)
                away = np.abs(lam) - s_hold > 0.0   # breaks away at the start
                if _count(away):
                    keep = ~away
                    held[sub[keep]] = True
                    rows = sub[away]
                    direction = np.where(lam[away] < 0.0, 1.0, -1.0)
                    if hold == 0:
                        sg1[rows] = direction
                        t1[rows] = tt[rows, 0] - cc[rows, 0] * direction
                    else:
                        sg2[rows] = direction
                        t2[rows] = tt[rows, 1] - cc[rows, 1] * direction
                    if _count(keep):
                        groups.append((hold, rows_of[sub[keep]], tuple(x[keep] for x in k),
                                       s_hold[keep], ts[0][keep], ts[1][keep]))
                else:
                    held[sub] = True
                    groups.append((hold, rows_of[sub], k, s_hold, *ts))
            both = (r1 & r2).nonzero()[0]
            if both.size:
                # Every joint at rest: the holding torque -(tau - h), h = g(q) here.
                zero = np.zeros(both.size)
                g1, g2 = _make_inverse(tuple(self.k[:, rows_of[both]]), np.cos, np.sin)(
                    x1[both], x2[both], v1[both], v2[both], zero, zero)
                sb, tb = ss[both], tt[both]
                ok = ((np.abs(-(tb[:, 0] - g1)) <= sb[:, 0])
                      & (np.abs(-(tb[:, 1] - g2)) <= sb[:, 1]))
                frozen[both[ok]] = True
                scalar[both[~ok]] = True
        if not self.every:   # a joint without friction never has an event
            act = self.active if idx is None else self.active[idx]
            sg1, sg2 = np.where(act[:, 0], sg1, 0.0), np.where(act[:, 1], sg2, 0.0)
        if idx is None:
            self.sg1, self.sg2, self.t1, self.t2 = sg1, sg2, t1, t2
            self.h0, self.h1, self.frozen, self.scalar = h0, h1, frozen, scalar
            self.any0, self.any1 = _count(h0) > 0, _count(h1) > 0
            self.anyf, self.anys = _count(frozen) > 0, _count(scalar) > 0
            self.groups = groups
            self.accel = None
            return
        for name, value in (('sg1', sg1), ('sg2', sg2), ('t1', t1), ('t2', t2),
                            ('h0', h0), ('h1', h1), ('frozen', frozen), ('scalar', scalar),
                            ('dead', dead)):
            arr = getattr(self, name)
            if arr is self.none:
                arr = np.zeros(len(arr), dtype=bool)
                setattr(self, name, arr)
            arr[idx] = value
        self.any0, self.any1 = _count(self.h0) > 0, _count(self.h1) > 0
        self.anyf, self.anys = _count(self.frozen) > 0, _count(self.scalar) > 0
        self.accel = None
        self.groups = []
        for hold, mask, any_held in ((0, self.h0, self.any0), (1, self.h1, self.any1)):
            if any_held:
                rows = mask.nonzero()[0]
                self.groups.append((hold, rows, tuple(self.k[:, rows]), self.s[rows, hold],
                                    self.t1[rows], self.t2[rows]))

    # ------------------------------------------------------------------ stepping
    def run(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``n`` steps; returns (q, qd, stuck), (B, 2) each, new arrays."""
        for j in range(n):
            self.step(j == n - 1)
        x1, x2 = self.x1, self.x2
        q1, qd1 = _pair(x1, x2), _pair(self.v1, self.v2)
        if self.any0 or self.any1 or self.anyf:
            frozen = self.frozen & ~self.dead
            stuck = _pair(self.h0 | frozen, self.h1 | frozen)
        else:
            stuck = np.zeros((len(x1), 2), dtype=bool)
        for i, flags in self.scalar_stuck.items():
            stuck[i] = flags
        return q1, qd1, stuck

    def held_terms(self) -> dict[int, tuple[Any, ...]]:
        """The held rows' :func:`_held_terms` at the end state, by held joint (the rows
        friction_step stepped last left out): what :meth:`decide` needs of them at the
        start of the next period (the state-only half of the holding torque)."""
        out = {}
        drop = list(self.scalar_stuck)
        for hold, rows, k, s_hold, terms in self.ends:
            if drop:
                keep = ~np.isin(rows, drop)
                if not keep.all():
                    if not keep.any():
                        continue
                    rows, s_hold = rows[keep], s_hold[keep]
                    k, terms = tuple(x[keep] for x in k), tuple(x[keep] for x in terms)
            out[hold] = (rows, k, s_hold, terms)
        return out

    def flags(self, i: int, scalar: dict[int, np.ndarray]) -> np.ndarray:
        """Row ``i``'s stuck flags after the last step (friction_step's argument;
        ``scalar``: the flags of the rows friction_step stepped then)."""
        flags = scalar.get(i)
        if flags is not None:
            return flags
        if self.frozen[i] and not self.dead[i]:
            return np.ones(2, dtype=bool)
        return np.array([bool(self.h0[i]), bool(self.h1[i])])

    def step(self, last: bool) -> None:
        """One physics step of every row (see the class); ``last``: the period's last."""
        x1, x2, v1, v2 = self.x1, self.x2, self.v1, self.v2
        dt = self.dt
        h0, h1, frozen = self.h0, self.h1, self.frozen
        any0, any1, anyf = self.any0, self.any1, self.anyf
        if self.accel is None:   # the modes changed: their acceleration and sign checks
            self.accel = (self.plant._acc if not (any0 or any1)
                          else _modal_accel(self.plant._k, h0 if any0 else None,
                                            h1 if any1 else None))
            self.unsigned = ((self.sg1 == 0.0, self.sg2 == 0.0)
                             if any0 or any1 or not self.every else None)
        k1, k2, w1, w2 = _rk4(self.accel, (x1, x2, v1, v2, self.t1, self.t2), dt, 1)
        # Bit for bit: a held joint's position as it was (q + 0.0 would turn a -0.0 into
        # 0.0); its velocity is qd + dt/6 (0.0 + ...) = 0.0 already.
        if any0:
            k1 = np.where(h0, x1, k1)
        if any1:
            k2 = np.where(h1, x2, k2)
        if anyf:
            k1, k2 = np.where(frozen, x1, k1), np.where(frozen, x2, k2)
            w1, w2 = np.where(frozen, v1, w1), np.where(frozen, v2, w2)
        # Events: a slipping joint with friction (sigma != 0) whose velocity did not keep
        # its sign; a held joint's holding torque out of band; a non-finite state.
        sg1, sg2 = self.sg1, self.sg2
        if self.unsigned is not None:   # a joint held, or without friction: no check
            z1, z2 = self.unsigned
            ok = ((sg1 * w1 > 0.0) | z1) & ((sg2 * w2 > 0.0) | z2)
        else:
            ok = (sg1 * w1 > 0.0) & (sg2 * w2 > 0.0)
        if anyf:
            ok |= frozen
        if self.anys:
            ok &= ~self.scalar
        ends = []
        for hold, rows, k, s_hold, t1, t2 in self.groups:
            p1, p2 = k1[rows], k2[rows]
            terms = _held_terms(k, hold, p1, p2, w1[rows], w2[rows])
            lam = _held_lambda(terms, hold, t1, t2)
            bad = (s_hold - np.abs(lam) < 0.0) | ~np.isfinite(p1 + p2)
            if _count(bad):
                ok[rows[bad]] = False
            ends.append((hold, rows, k, s_hold, terms))
        self.ends = ends
        previous, self.scalar_stuck = self.scalar_stuck, {}
        if _count(ok) < len(ok):
            redo = (~ok).nonzero()[0]
            arms, friction, tau = self.plant.arms, self.friction, self.tau
            stuck = self.stuck
            for i in redo.tolist():
                q0 = np.array((x1[i], x2[i]))
                qd0 = np.array((v1[i], v2[i]))
                flags = stuck[i] if stuck is not None else self.flags(i, previous)
                try:
                    q1, qd1, out, _ = friction_step(arms[i], q0, qd0, tau[i], dt, flags,
                                                    friction[i])
                except ValueError:  # non-finite within the step: friction_step refuses it
                    q1 = qd1 = np.full(2, math.nan)
                    out = np.zeros(2, dtype=bool)
                k1[i], k2[i], w1[i], w2[i] = q1[0], q1[1], qd1[0], qd1[1]
                self.scalar_stuck[i] = out
            self.x1, self.x2, self.v1, self.v2 = k1, k2, w1, w2
            if not last:
                self.decide(redo)
        else:
            self.x1, self.x2, self.v1, self.v2 = k1, k2, w1, w2
        self.stuck = None   # from now on: self.flags


def _count(mask: np.ndarray) -> int:
    """The number of True in ``mask`` (``mask.any()``'s answer, cheaper for small arrays)."""
    return int(np.count_nonzero(mask))


def _pair(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.stack((a, b), -1)`` of two (B,) arrays, (B, 2) (cheaper for small arrays)."""
    out = np.empty((len(a), 2), dtype=a.dtype)
    out[:, 0] = a
    out[:, 1] = b
    return out


def _modal_accel(k: tuple[Any, ...], h0: np.ndarray | None, h1: np.ndarray | None
                 ) -> Callable[..., tuple[np.ndarray, np.ndarray]]:
    """qdd(q1, q2, qd1, qd2, t1, t2) [rad/s^2] of B rows, each in its mode ((B,) arrays
    in rad, rad/s, N m; ``k`` the rows' lumped constants): :func:`~arm_dynamics.
    two_link._make_accel`'s formula (operation for operation), except the rows ``h0``
    (joint 1 held: qdd 0.0; joint 2 by the constrained dynamics) and ``h1`` (joint 2 held,
    joint 1 free), whose free joint's acceleration is :func:`_held_terms` and
    :func:`_held_lambda`'s ``r_f / D_f`` (the same operations, the terms shared with the
    free formula computed once)."""
    a, b, d, e, g1, g2, b1, b2 = k
    b2x = 2.0 * b
    eu = e * _UNIT_ACCEL
    cos, sin, where = np.cos, np.sin, np.where

    def accel(q1, q2, qd1, qd2, t1, t2):
        c2 = cos(q2)
        bs2 = b * sin(q2)
        gc12 = g2 * cos(q1 + q2)
        d11 = a + b2x * c2
        d12 = d + b * c2
        pp = bs2 * qd2 * (2.0 * qd1 + qd2)
        g1c = g1 * cos(q1)
        bv1 = b1 * qd1
        qq = bs2 * qd1 * qd1
        bv2 = b2 * qd2
        r1 = t1 + pp - g1c - gc12 - bv1
        r2 = t2 - qq - gc12 - bv2
        det = d11 * e - d12 * d12
        y1, y2 = (e * r1 - d12 * r2) / det, (d11 * r2 - d12 * r1) / det
        if h1 is not None:   # joint 1 free: h1 and its column, as _held_terms
            hh = (((0.0 - pp) + g1c) + gc12) + bv1
            col = ((((d11 * _UNIT_ACCEL) - pp) + g1c) + gc12) + bv1
            y1 = where(h1, (t1 - hh) / ((col - hh) / _UNIT_ACCEL), y1)
            y2 = where(h1, 0.0, y2)
        if h0 is not None:   # joint 2 free
            hh = ((0.0 + qq) + gc12) + bv2
            col = ((eu + qq) + gc12) + bv2
            y2 = where(h0, (t2 - hh) / ((col - hh) / _UNIT_ACCEL), y2)
            y1 = where(h0, 0.0, y1)
        return y1, y2

    return accel


def _held_terms(k: tuple[np.ndarray, ...], hold: int, p1: np.ndarray, p2: np.ndarray,
                v1: np.ndarray, v2: np.ndarray) -> tuple[np.ndarray, ...]:
    """The constrained dynamics of M rows with joint ``hold`` stuck (qdd 0) and the other,
    ``f``, free, at the state (p, v) [rad, rad/s]: ``(h_f, h_hold, D_f, D_hold)`` (M,)
    each, ``h = ID(q, qd, 0)`` [N m] and ``D_j = (ID(q, qd, U e_f)_j - h_j) / U`` (the
    column ``f`` of the mass matrix, ``U`` = :data:`~arm_dynamics.friction._UNIT_ACCEL`),
    the terms of :func:`_held_lambda` that do not depend on the torque.

    :meth:`~arm_dynamics.friction._Step.reduced`'s operations for one free joint, bit for
    bit: the inverse dynamics are :func:`~arm_dynamics.two_link._make_inverse`'s terms in
    its order, with the products by a zero acceleration left out (each is a signed zero
    added to a sum that is +0 or to a non-zero term: the same bits), and each term
    computed once for ``h`` and the column."""
    a, b, d, e, g1, g2, b1, b2 = k
    c2 = np.cos(p2)
    bs2 = b * np.sin(p2)
    gc12 = g2 * np.cos(p1 + p2)
    pp = bs2 * v2 * (2.0 * v1 + v2)
    g1c = g1 * np.cos(p1)
    bv1 = b1 * v1
    qq = bs2 * v1 * v1
    bv2 = b2 * v2
    h1 = (((0.0 - pp) + g1c) + gc12) + bv1
    h2 = ((0.0 + qq) + gc12) + bv2
    if hold == 1:   # joint 1 free: column 1 of D
        col1 = (((((a + 2.0 * b * c2) * _UNIT_ACCEL) - pp) + g1c) + gc12) + bv1
        col2 = ((((d + b * c2) * _UNIT_ACCEL) + qq) + gc12) + bv2
        return h1, h2, (col1 - h1) / _UNIT_ACCEL, (col2 - h2) / _UNIT_ACCEL
    col1 = (((((d + b * c2) * _UNIT_ACCEL) - pp) + g1c) + gc12) + bv1
    col2 = (((e * _UNIT_ACCEL) + qq) + gc12) + bv2
    return h2, h1, (col2 - h2) / _UNIT_ACCEL, (col1 - h1) / _UNIT_ACCEL


def _held_lambda(terms: tuple[np.ndarray, ...], hold: int, t1: np.ndarray, t2: np.ndarray
                 ) -> np.ndarray:
    """The holding torque ``lambda`` [N m] (M,) of the held joint under ``taup`` = (t1, t2)
    [N m], from :func:`_held_terms`: ``r = taup - h``, ``qdd_f = r_f / D_f``, ``lambda =
    D_hold qdd_f - r_hold`` (:meth:`~arm_dynamics.friction._Step.reduced`'s operations)."""
    hf, hh, df, dh = terms
    tf, th = (t1, t2) if hold == 1 else (t2, t1)
    return dh * ((tf - hf) / df) - (th - hh)


class _Sensors:
    """B rows of :class:`~arm_dynamics.sensors.SensorModel` settings, measured together:
    the same noise draws (each row's own generator, in order), counts and delay line."""

    def __init__(self, rows: int, settings: Sequence[Mapping[str, Any]]) -> None:
        models = [SensorModel(2, **dict(m)) for m in _per_row('sensors', settings, rows)]
        self.models = models
        self.enabled = any(m.enabled for m in models)
        self.pn = np.array([m.position_noise for m in models])
        self.vn = np.array([m.velocity_noise for m in models])
        self.noisy = np.array([m.noisy for m in models])
        self.any_noisy, self.all_noisy = bool(self.noisy.any()), bool(self.noisy.all())
        self.quantised = np.array([m.quantised for m in models])
        self.any_quantised = bool(self.quantised.any())
        self.all_quantised = bool(self.quantised.all())
        self.step = np.array([m.step for m in models])
        self.delay = np.array([m.sensing_delay for m in models])
        #: The one sensing delay of every row, or None.
        self.same_delay = int(self.delay[0]) if (self.delay == self.delay[0]).all() else None
        size = int(self.delay.max()) + 1
        self.line_q = np.zeros((size, rows, 2))
        self.line_qd = np.zeros((size, rows, 2))
        self.count = 0
        self.noise_q = self.noise_qd = np.zeros((0, rows, 2))
        self.base = 0
        self.rows = np.arange(rows)

    def _draws(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The noise of state ``k``: position [rad] and velocity [rad/s] (B, 2) each, the
        standard normals times each row's standard deviations (zeros where a row has no
        noise)."""
        if k - self.base >= len(self.noise_q):
            block = np.zeros((NOISE_BLOCK, len(self.models), 4))
            for i in np.flatnonzero(self.noisy).tolist():
                block[:, i] = self.models[i].rng.standard_normal((NOISE_BLOCK, 4))
            self.noise_q = self.pn * block[:, :, :2]
            self.noise_qd = self.vn * block[:, :, 2:]
            self.base = k
        return self.noise_q[k - self.base], self.noise_qd[k - self.base]

    def measure(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The measurement of the state just reached, q [rad], qd [rad/s] (B, 2): (B, 2)
        each, :meth:`~arm_dynamics.sensors.SensorModel.measure`'s operations row by row."""
        k = self.count
        self.count += 1
        mq, mqd = q, qd
        if self.any_noisy:
            nq, nqd = self._draws(k)
            mq, mqd = q + nq, qd + nqd
            if not self.all_noisy:
                noisy = self.noisy[:, None]
                mq, mqd = np.where(noisy, mq, q), np.where(noisy, mqd, qd)
        if self.any_quantised:
            counted = np.rint(mq / self.step) * self.step   # np.round's rint, bit for bit
            mq = counted if self.all_quantised else np.where(self.quantised, counted, mq)
        size = len(self.line_q)
        if size == 1:
            return mq, mqd
        self.line_q[k % size], self.line_qd[k % size] = mq, mqd
        if self.same_delay is not None:
            j = max(k - self.same_delay, 0) % size
            return self.line_q[j].copy(), self.line_qd[j].copy()
        idx = np.maximum(k - self.delay, 0) % size
        return self.line_q[idx, self.rows], self.line_qd[idx, self.rows]
