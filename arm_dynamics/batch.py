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

* friction (:class:`~arm_dynamics.friction.JointFriction`): the period one physics step at a
  time through :func:`batch_friction_step`, :func:`~arm_dynamics.friction.friction_step`'s
  rule with its common cases batched (every joint with friction slipping without an event;
  every joint stuck and held);
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
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from arm_dynamics.friction import JointFriction, friction_step
from arm_dynamics.sensors import SensorModel, _periods
from arm_dynamics.two_link import TwoLinkArm, TwoLinkBatch, _rk4

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
        diverged arm), ``substeps`` RK4 steps of ``dt`` (with friction: one physics step at
        a time, :func:`batch_friction_step`); then every arm that went faster than
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
            q, qd, stuck = self.q, self.qd, self.stuck
            with np.errstate(all='ignore'):
                for _ in range(self.substeps):
                    q, qd, stuck = self.friction.step(q, qd, tau, self.dt, stuck)
            self.stuck = stuck
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
    """The friction of B rows and :func:`batch_friction_step` with it."""

    def __init__(self, plant: TwoLinkBatch, friction: Sequence[JointFriction]) -> None:
        rows = _per_row('friction', friction, len(plant))
        bad = [i for i, f in enumerate(rows) if not isinstance(f, JointFriction) or f.n != 2]
        if bad:
            raise ValueError(f'friction[{bad[0]}] must be a JointFriction of 2 joints, got '
                             f'{rows[bad[0]]!r}')
        self.plant = plant
        self.rows = rows
        self.c = np.array([f.coulomb for f in rows])
        self.s = np.array([f.static for f in rows])
        self.active = self.s > 0.0
        self.enabled = bool(self.active.any())
        self.both = self.active.all(axis=1)

    def step(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, dt: float,
             stuck: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return batch_friction_step(self.plant, q, qd, tau, dt, stuck, self.rows,
                                   (self.c, self.s, self.active, self.both))


def batch_friction_step(plant: TwoLinkBatch, q: np.ndarray, qd: np.ndarray, tau: np.ndarray,
                        dt: float, stuck: np.ndarray, friction: Sequence[JointFriction],
                        arrays: tuple[Any, ...] | None = None
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One physics step of ``dt`` [s] of B two-link arms with joint friction: row ``i``
    is :func:`~arm_dynamics.friction.friction_step` of ``plant.arms[i]`` with
    ``friction[i]`` (no brakes), to rounding (the batched RK4 and inverse dynamics use
    numpy's ``cos``/``sin``, the single arm ``math``'s).

    The common cases are batched, in the tests :func:`~arm_dynamics.friction.friction_step`
    makes: every joint with friction slipping and keeping its direction over the step
    (one batched RK4 step under ``tau - c sign(qd)``, for all rows at once), and every
    joint at rest with friction and held (the holding torque ``g(q) - tau`` within the
    static friction: nothing moves). A row in neither (a joint stopping or breaking away
    in the step, one joint stuck while the other moves) is that row's ``friction_step``.

    Parameters: q, qd, tau (B, 2) rad, rad/s, N m; stuck (B, 2) bool (the last step's);
    ``arrays``: (coulomb, static, active, both active) of the rows, precomputed. Returns
    (q, qd, stuck), (B, 2) each; a row that went non-finite is NaN.
    """
    if arrays is None:
        c = np.array([f.coulomb for f in friction])
        s = np.array([f.static for f in friction])
        active = s > 0.0
        both = active.all(axis=1)
    else:
        c, s, active, both = arrays
    sign = np.sign(qd)
    taup = tau - c * sign
    k1, k2, v1, v2 = _rk4(plant._acc, (q[:, 0], q[:, 1], qd[:, 0], qd[:, 1], taup[:, 0],
                                       taup[:, 1]), dt, 1)
    q1 = np.stack((k1, k2), -1)
    qd1 = np.stack((v1, v2), -1)
    slipping = ~active | ((sign != 0.0) & (sign * qd1 > 0.0))
    fast = slipping[:, 0] & slipping[:, 1]
    out_stuck = np.zeros_like(stuck)
    if fast.all():
        return q1, qd1, out_stuck
    rest = both & (qd[:, 0] == 0.0) & (qd[:, 1] == 0.0) & ~fast
    if rest.any():
        zero = np.zeros(len(q))
        h1, h2 = plant._tau(q[:, 0], q[:, 1], qd[:, 0], qd[:, 1], zero, zero)
        held = rest & (np.abs(-(tau[:, 0] - h1)) <= s[:, 0]) & (np.abs(-(tau[:, 1] - h2))
                                                                <= s[:, 1])
        if held.any():
            q1[held], qd1[held] = q[held], qd[held]
            out_stuck[held] = True
            fast |= held
    at_rest = active & (qd == 0.0)
    one = ~fast & (at_rest[:, 0] != at_rest[:, 1])
    if one.any():
        idx = np.flatnonzero(one)
        ok, qo, qdo = _one_held(plant, idx, q[idx], qd[idx], taup[idx], dt,
                                np.where(at_rest[idx, 0], 0, 1), s[idx], active[idx],
                                sign[idx])
        done = idx[ok]
        q1[done], qd1[done] = qo[ok], qdo[ok]
        out_stuck[done] = at_rest[done]
        fast[done] = True
    arms = plant.arms
    for i in np.flatnonzero(~fast).tolist():
        try:
            q1[i], qd1[i], out_stuck[i], _ = friction_step(arms[i], q[i], qd[i], tau[i], dt,
                                                           stuck[i], friction[i])
        except ValueError:  # non-finite within the step: friction_step refuses it
            q1[i] = qd1[i] = math.nan
            out_stuck[i] = False
    return q1, qd1, out_stuck


def _one_held(plant: TwoLinkBatch, idx: np.ndarray, q: np.ndarray, qd: np.ndarray,
              taup: np.ndarray, dt: float, hold: np.ndarray, s: np.ndarray,
              active: np.ndarray, sign: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rows ``idx`` with one joint (``hold``) at rest with friction and the other free:
    :class:`~arm_dynamics.friction._Step`'s operations batched -- the mode decided (the
    held joint stays stuck while its holding torque is within its static friction), one
    constrained RK4 step (the free joint by ``D_ff qdd_f = r_f``, ``D_ff`` from
    inverse-dynamics differences), and the events checked at its end (the free joint's
    velocity keeping its sign, the holding torque staying in band). Returns ``(ok, q, qd)``:
    ``ok`` (M,) the rows stepped so (no break-away at the start, no event in the step);
    the others are left to :func:`~arm_dynamics.friction.friction_step`."""
    from arm_dynamics.friction import _UNIT_ACCEL
    from arm_dynamics.two_link import _make_inverse

    m = len(idx)
    rows = np.arange(m)
    free = 1 - hold
    inv = _make_inverse(tuple(k[idx] for k in plant._k), np.cos, np.sin)
    zero = np.zeros(m)
    unit = np.zeros((m, 2))
    unit[rows, free] = _UNIT_ACCEL
    u1, u2 = unit[:, 0], unit[:, 1]

    def reduced(qx: np.ndarray, qdx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a, b, c, d = qx[:, 0], qx[:, 1], qdx[:, 0], qdx[:, 1]
        h = np.stack(inv(a, b, c, d, zero, zero), -1)
        r = taup - h
        col = np.stack(inv(a, b, c, d, u1, u2), -1)
        hf = h[rows, free]
        x = r[rows, free] / ((col[rows, free] - hf) / _UNIT_ACCEL)
        qdd = np.zeros((m, 2))
        qdd[rows, free] = x
        lam = (col[rows, hold] - h[rows, hold]) / _UNIT_ACCEL * x - r[rows, hold]
        return qdd, lam

    s_hold = s[rows, hold]
    a1, lam = reduced(q, qd)
    ok = ~(np.abs(lam) - s_hold > 0.0)   # stays stuck at the start (decide)
    h2 = 0.5 * dt
    v2 = qd + h2 * a1
    a2 = reduced(q + h2 * qd, v2)[0]
    v3 = qd + h2 * a2
    a3 = reduced(q + h2 * v2, v3)[0]
    v4 = qd + dt * a3
    a4 = reduced(q + dt * v3, v4)[0]
    q1 = q + dt / 6.0 * (qd + 2.0 * (v2 + v3) + v4)
    qd1 = qd + dt / 6.0 * (a1 + 2.0 * (a2 + a3) + a4)
    q1[rows, hold] = q[rows, hold]
    qd1[rows, hold] = 0.0
    sigma = np.where(active[rows, free], sign[rows, free], 0.0)
    ok &= ~((sigma != 0.0) & (sigma * qd1[rows, free] <= 0.0))   # no velocity event
    ok &= ~(s_hold - np.abs(reduced(q1, qd1)[1]) < 0.0)          # no break-away event
    ok &= np.isfinite(q1).all(axis=1) & np.isfinite(qd1).all(axis=1)
    return ok, q1, qd1


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
        self.quantised = np.array([m.quantised for m in models])
        self.any_quantised = bool(self.quantised.any())
        self.step = np.array([m.step for m in models])
        self.delay = np.array([m.sensing_delay for m in models])
        size = int(self.delay.max()) + 1
        self.line_q = np.zeros((size, rows, 2))
        self.line_qd = np.zeros((size, rows, 2))
        self.count = 0
        self.noise = np.zeros((0, rows, 4))
        self.base = 0
        self.rows = np.arange(rows)

    def _draws(self, k: int) -> np.ndarray:
        """The standard normals of state ``k`` (B, 4) (zeros where a row has no noise)."""
        if k - self.base >= len(self.noise):
            block = np.zeros((NOISE_BLOCK, len(self.models), 4))
            for i in np.flatnonzero(self.noisy).tolist():
                block[:, i] = self.models[i].rng.standard_normal((NOISE_BLOCK, 4))
            self.noise = block
            self.base = k
        return self.noise[k - self.base]

    def measure(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        k = self.count
        self.count += 1
        mq, mqd = q, qd
        if self.noisy.any():
            z = self._draws(k)
            noisy = self.noisy[:, None]
            mq = np.where(noisy, q + self.pn * z[:, :2], q)
            mqd = np.where(noisy, qd + self.vn * z[:, 2:], qd)
        if self.any_quantised:
            mq = np.where(self.quantised, np.round(mq / self.step) * self.step, mq)
        size = len(self.line_q)
        if size == 1:
            return mq, mqd
        self.line_q[k % size], self.line_qd[k % size] = mq, mqd
        idx = np.maximum(k - self.delay, 0) % size
        return self.line_q[idx, self.rows], self.line_qd[idx, self.rows]
