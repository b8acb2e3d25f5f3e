"""The simulator's state machine, free of ROS: what the ``simulator`` node steps.

:class:`SimulatorCore` owns the model state and simulated time (integer nanoseconds, so
time never drifts), holds the last valid effort command, saturates it at the effort
limits, integrates one control period at a time with fixed RK4 physics steps, and refuses
to let the state become non-finite or absurd: a state outside the runaway envelope (the
joint limits plus a margin) or faster than ``velocity_limit`` is a fault that stops
integration and keeps the last good position, at rest (zero velocity), until
:meth:`reset`. Optionally the joint limits act as hard end stops.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from arm_dynamics.disturbance import ArmModel, Disturbances, Event, Push, apply_impulse
from arm_dynamics.friction import JointFriction, friction_step
from arm_dynamics.integrate import Model, TipLoaded
from arm_dynamics.limits import JointLimits
from arm_dynamics.models import geared_link, robot_model
from arm_dynamics.sensors import ActuationDelay, SensorModel


class CommandError(ValueError):
    """An effort command that must not reach the physics; the message says why."""


def validate_command(data: Sequence[float], n: int) -> np.ndarray:
    """Return the command as a float array of length ``n`` or raise :class:`CommandError`."""
    if len(data) != n:
        raise CommandError(f'effort command must have {n} values, got {len(data)}')
    values = np.array(data, dtype=float)
    bad = [i for i, v in enumerate(values) if not math.isfinite(v)]
    if bad:
        raise CommandError(f'effort command has non-finite values at index {bad}: '
                           f'{values.tolist()}')
    return values


@dataclass(frozen=True)
class JointView:
    """How a model's state appears in a JointState message."""

    names: tuple[str, ...]
    position: list[float]
    velocity: list[float]
    effort: list[float]


class SimulatorCore:
    """Fixed-step simulation of one model under a held, saturated torque command.

    Parameters
    ----------
    model : a :class:`~arm_dynamics.models.RobotModel` or the geared link
    q0, qd0 : (n,) rad, rad/s -- initial (and reset) state.
    effort_limits : (n,) N m, > 0 -- the applied torque is clipped to +-limits.
    physics_step_ns : int, ns > 0 -- RK4 step.
    control_period_ns : int, ns -- a whole multiple of the physics step; one
        :meth:`advance` moves simulated time by this much.
    velocity_limit : rad/s -- any |qd| above it (or a non-finite state) counts as
        divergence, whatever the model.
    joint_names : names for :meth:`joint_view`.
    joint_limits : the arm's limits (None: none). A state outside them is reported by
        :attr:`outside_limits`; with ``hard_stops`` a joint reaching a position limit
        stops there (checked after every physics step: position put back on the limit,
        outward velocity removed).
    envelope : beyond this a state is a runaway fault (None: no envelope).
    sensors : the measurement of each new state (:class:`~arm_dynamics.sensors.
        SensorModel`, over the model's state (n,)); None: ideal, :meth:`joint_view` shows
        the true state.
    actuation_delay : int, control periods >= 0 -- the command held for a period is
        applied ``actuation_delay`` periods later (:class:`~arm_dynamics.sensors.
        ActuationDelay`; zero torque before); 0: at once.
    friction : Coulomb and static joint friction (:class:`~arm_dynamics.friction.
        JointFriction`), stick/slip located inside each physics step; None: none.
    disturbances : pushes and faults at exact simulated times (:class:`~arm_dynamics.
        disturbance.Disturbances`); None: none (:meth:`push` adds live ones).

    With friction or disturbances each physics step is taken on its own
    (:meth:`_integrate_real`: impulses, the delivered motor torque ``torque_scale *
    clip(command)`` plus the external load, brakes and friction); without them the period
    is the model's ``step`` of ``substeps`` steps, as before, bit for bit.

    :meth:`joint_view` is the measurement (what the node publishes on ``joint_states``),
    :meth:`true_view` the true state; each state is measured once, when it is reached
    (:meth:`advance`, :meth:`reset`), so a re-sent state carries the same measurement.
    """

    def __init__(self, model: Model, *, q0, qd0, effort_limits, physics_step_ns: int,
                 control_period_ns: int, velocity_limit: float,
                 joint_names: Sequence[str], joint_limits: JointLimits | None = None,
                 hard_stops: bool = False, envelope: JointLimits | None = None,
                 sensors: SensorModel | None = None, actuation_delay: int = 0,
                 friction: JointFriction | None = None,
                 disturbances: Disturbances | None = None) -> None:
        n = model.n_dof
        if physics_step_ns <= 0 or control_period_ns % physics_step_ns:
            raise ValueError(
                f'control period {control_period_ns} ns must be a whole multiple of the '
                f'physics step {physics_step_ns} ns')
        self.model = model
        self.n = n
        self.q0 = np.array(q0, dtype=float).reshape(n)
        self.qd0 = np.array(qd0, dtype=float).reshape(n)
        self.limits = np.array(effort_limits, dtype=float).reshape(n)
        self.dt = physics_step_ns * 1e-9
        self.substeps = control_period_ns // physics_step_ns
        self.period_ns = control_period_ns
        self.velocity_limit = velocity_limit
        self.joint_names = tuple(joint_names)
        self.joint_limits = joint_limits
        self.hard_stops = hard_stops and joint_limits is not None
        self.envelope = envelope
        self.sensors = sensors if sensors is not None and sensors.enabled else None
        if self.sensors is not None and self.sensors.n != n:
            raise ValueError(f'the sensor model measures {self.sensors.n} joints, the model '
                             f'has {n}')
        self.actuator = ActuationDelay(n, actuation_delay)
        if friction is not None and friction.n != n:
            raise ValueError(f'friction is given for {friction.n} joints, the model has {n}')
        self.friction = friction if friction is not None and friction.enabled else None
        self._frictionless = JointFriction.none(n)  # brakes or pushes without friction
        if (disturbances is not None or self.friction is not None) and not _pushable(model):
            raise ValueError(f'{type(model).__name__} takes no friction, pushes or faults '
                             '(it is no RobotModel: no mass matrix or Jacobian)')
        self.disturbances = disturbances
        self.physics_step_ns = physics_step_ns
        #: Energy [J] friction and brakes took since the start (reset keeps counting).
        self.friction_work = 0.0
        #: The events (push and fault starts and ends) of the last period integrated.
        self.events: list[Event] = []
        self.time_ns = 0
        self.reset()

    def reset(self) -> None:
        """Back to the initial state, zero torque, divergence cleared (time keeps going)."""
        self.q = self.q0.copy()
        self.qd = self.qd0.copy()
        self.command = np.zeros(self.n)
        self.applied = np.zeros(self.n)
        self.external = np.zeros(self.n)  # mean push torque over the last period [N m]
        self.stuck = np.zeros(self.n, dtype=bool)
        self.diverged: str | None = None
        self.actuator.clear()
        if self.sensors is not None:
            self.sensors.reset()
        self._sense()

    def _sense(self) -> None:
        """Measure the state just reached (once per state); encoder faults act on the
        measurement."""
        if self.sensors is not None:
            self.measured = self.sensors.measure(self.q, self.qd)
        dist = self.disturbances
        if dist is not None and dist.faults:
            q, qd = self.measured if self.sensors is not None else (self.q, self.qd)
            self.measured = dist.measure(self.time_ns, q, qd)

    @property
    def measuring(self) -> bool:
        """Can the published measurement differ from the true state?"""
        return self.sensors is not None or (self.disturbances is not None
                                            and bool(self.disturbances.faults))

    def accepts_command(self) -> bool:
        """Does an effort command arriving now reach the drive? (Not inside a
        ``commands_dropped`` fault: it is lost, the drive keeps the last one.)"""
        dist = self.disturbances
        return dist is None or not dist.commands_dropped(self.time_ns)

    def push(self, force, duration_ns: int) -> Push:
        """A live tip push: ``force`` (2,) [N, base frame] over ``duration_ns`` from the
        start of the next period (now). Raises ValueError naming a bad value."""
        if not _pushable(self.model):
            raise ValueError(f'{type(self.model).__name__} has no tip to push')
        if self.disturbances is None:
            self.disturbances = Disturbances(n=self.n, joint_names=self.joint_names[:self.n],
                                             physics_step_ns=self.physics_step_ns,
                                             source='live')
        push = Push(self.time_ns, self.time_ns + duration_ns, 'tip_force',
                    tuple(float(v) for v in force), 'pulse', label='live')
        self.disturbances.add_push(push)
        return push

    def set_command(self, data: Sequence[float]) -> None:
        """Hold a new effort command [N m]; raises :class:`CommandError` and keeps the old
        one if it is malformed."""
        self.command = validate_command(data, self.n)

    def clear_command(self) -> None:
        """Zero torque (wall_clock command watchdog), the commands queued by an actuation
        delay included."""
        self.command = np.zeros(self.n)
        self.actuator.clear()

    @property
    def saturated(self) -> np.ndarray:
        """Per joint: is the held command beyond the effort limit?"""
        return np.abs(self.command) > self.limits

    @property
    def time(self) -> float:
        """Simulated time [s]."""
        return self.time_ns * 1e-9

    def advance(self) -> None:
        """Integrate one control period with the held, saturated command (with an
        actuation delay: the one held ``actuation_delay`` periods ago), then measure the
        new state."""
        self._integrate()
        self._sense()

    def _integrate(self) -> None:
        self.time_ns += self.period_ns
        command = self.actuator(self.command)
        if self.diverged:
            self.applied = np.zeros(self.n)
            return
        self.applied = np.clip(command, -self.limits, self.limits)
        dist = self.disturbances
        self.events = dist.events(self.time_ns - self.period_ns, self.time_ns) if dist else []
        with np.errstate(all='ignore'):
            if self.friction is not None or (dist is not None and dist.enabled):
                q, qd = self._integrate_real(self.time_ns - self.period_ns)
            elif self.hard_stops and self.joint_limits is not None:
                q, qd = self.q, self.qd
                try:
                    for _ in range(self.substeps):
                        q, qd = self.joint_limits.hard_stop(
                            *self.model.step(q, qd, self.applied, self.dt, 1))
                except ValueError:  # went non-finite within the period: step refuses it
                    q = qd = np.full(self.n, np.nan)
            else:
                q, qd = self.model.step(self.q, self.qd, self.applied, self.dt, self.substeps)
        speed = float(np.max(np.abs(qd))) if np.isfinite(qd).all() else math.inf
        if not (np.isfinite(q).all() and speed <= self.velocity_limit):
            self._fault(f'integration diverged at t={self.time:.3f} s '
                        f'(|qd| = {speed:.3g} rad/s > {self.velocity_limit:g} or '
                        'non-finite); holding the last good position at rest until ~/reset')
            return
        runaway = self.envelope.violation(q, qd) if self.envelope is not None else None
        if runaway:
            self._fault(f'runaway at t={self.time:.3f} s: {runaway} (the runaway envelope: '
                        'joint limits plus margin); holding the last good position at rest '
                        'until ~/reset')
            return
        self.q, self.qd = q, qd

    def _integrate_real(self, t0_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """The period from ``t0_ns`` one physics step at a time: impulses at its start,
        the delivered torque (a torque loss scales the clipped command; the external load
        is added, never clipped; a tip force's ``J(q)^T F`` is part of the dynamics,
        :class:`~arm_dynamics.integrate.TipLoaded`, evaluated at every RK4 stage), brakes
        and friction (:func:`~arm_dynamics.friction.friction_step`), hard stops. Sets
        :attr:`applied` (the mean delivered motor torque) and :attr:`external` (the mean
        over the steps of the external torque at each step's start) [N m]."""
        model, dist, dt = cast(ArmModel, self.model), self.disturbances, self.dt
        friction = self.friction or self._frictionless
        q, qd, stuck = self.q, self.qd, self.stuck
        step = self.physics_step_ns
        delivered = np.zeros(self.n)
        external = np.zeros(self.n)
        work = 0.0
        try:
            for k in range(self.substeps):
                t = t0_ns + k * step
                tau = self.applied
                locked = None
                plant: ArmModel = model
                if dist is not None:
                    for p in dist.impulses(t, t + step):
                        qd = apply_impulse(model, q, qd, p.kind, p.array)
                        stuck = stuck & (qd == 0.0)
                    locked = dist.locked(t)
                    tau = tau * dist.torque_scale(t)
                    delivered += tau
                    load, force = dist.loads(t)
                    if force is not None:  # J(q)^T F inside the dynamics: every RK4 stage
                        plant = TipLoaded(model, force)
                        external += load + plant.load(q)  # reported: at the step's start
                    else:
                        external += load
                    tau = tau + load
                q, qd, stuck, w = friction_step(plant, q, qd, tau, dt, stuck, friction,
                                                locked)
                work += w
                if self.hard_stops and self.joint_limits is not None:
                    q, qd = self.joint_limits.hard_stop(q, qd)
                    stuck = stuck & (qd == 0.0)
        except ValueError:  # went non-finite within the period: a step refuses it
            return np.full(self.n, np.nan), np.full(self.n, np.nan)
        if dist is not None:
            self.applied = delivered / self.substeps
            self.external = external / self.substeps
        self.stuck = stuck
        self.friction_work += work
        return q, qd

    def _fault(self, reason: str) -> None:
        """Stop integrating: the last good position is held, at rest (zero velocity: a
        frozen arm does not move, and nobody reading the state should plan from a speed
        it no longer has), with no torque, until :meth:`reset`."""
        self.diverged = reason
        self.qd = np.zeros(self.n)
        self.applied = np.zeros(self.n)
        self.external = np.zeros(self.n)
        self.stuck = np.zeros(self.n, dtype=bool)

    @property
    def outside_limits(self) -> str | None:
        """Why the current state is outside the joint limits, or None."""
        if self.joint_limits is None:
            return None
        return self.joint_limits.violation(self.q, self.qd)

    def joint_view(self) -> JointView:
        """Positions [rad], velocities [rad/s] and applied efforts [N m] to publish on
        ``joint_states``: the measured state (the true one without sensors) in the model's
        own view of its state when it has one (:meth:`SingleLinkGeared.joint_view` shows
        motor shaft and link), else one entry per joint."""
        if not self.measuring:
            return self._view(self.q, self.qd)
        return self._view(*self.measured)

    def true_view(self) -> JointView:
        """:meth:`joint_view` of the true state (``simulator/true_joint_states``); its
        effort is the true applied torque: the motor's plus any push."""
        return self._view(self.q, self.qd, self.applied + self.external)

    def _view(self, q_: np.ndarray, qd_: np.ndarray,
              tau_: np.ndarray | None = None) -> JointView:
        tau_ = self.applied if tau_ is None else tau_
        q, qd, tau = q_.tolist(), qd_.tolist(), tau_.tolist()
        view = getattr(self.model, 'joint_view', None)
        if view is not None:
            return JointView(*view(self.joint_names, q, qd, tau))
        return JointView(self.joint_names[: self.n], q, qd, tau)


def _pushable(model: object) -> bool:
    """Does ``model`` have what friction, pushes and brakes use (a RobotModel's mass
    matrix, Jacobian and inverse dynamics; the geared link has not)?"""
    return all(hasattr(model, name) for name in ('mass_matrix', 'jacobian',
                                                 'inverse_dynamics'))


def _envelope(values: Mapping[str, Any]) -> JointLimits | None:
    """The runaway envelope the simulator parameters give (None: the geared link, whose
    motor shaft has no joint limits, or limits the robot's own check refuses)."""
    if values.get('model') == 'single_link_geared':
        return None
    try:
        limits = JointLimits.from_params(values)
    except ValueError:
        return None  # refused by position_limits_upper's own relation
    return limits.envelope(values['fault_position_margin'], values['fault_velocity_factor'])


def initial_position_reason(values: Mapping[str, Any]) -> str | None:
    """Why ``initial_positions`` (with the other simulator and robot parameters by name)
    would be a runaway fault at the first step: a joint beyond a position limit plus
    ``fault_position_margin``. None if not (the geared link has no limits)."""
    envelope = _envelope(values)
    if envelope is None:
        return None
    outside = envelope.position_violation(values['initial_positions'], 'initial position')
    if outside is None:
        return None
    return (f'initial_positions: {outside}, beyond the runaway envelope (joint limits plus '
            f"fault_position_margin {values['fault_position_margin']:g} rad): the first "
            'step would be a runaway fault')


def initial_velocity_reason(values: Mapping[str, Any]) -> str | None:
    """Why ``initial_velocities`` would be a fault at the first step (a ``~/reset`` to them
    an immediate one): a joint faster than ``fault_velocity_factor`` times its speed limit
    (the runaway envelope), or than ``velocity_limit`` (divergence; the geared link: its
    motor, the link's speed times the gear ratio). None if not."""
    qd0 = np.asarray(values['initial_velocities'], dtype=float)
    what = 'initial speed'
    if values.get('model') == 'single_link_geared':
        ratio = float(values['geared.gear_ratio'])
        qd0, what = qd0[:1] * ratio, f'motor initial speed (link x gear_ratio {ratio:g})'
    envelope = _envelope(values)
    outside = envelope.velocity_violation(qd0, what) if envelope is not None else None
    if outside is not None:
        return (f'initial_velocities: {outside}, beyond the runaway envelope (velocity_limits'
                f" times fault_velocity_factor {values['fault_velocity_factor']:g}): the "
                'first step would be a runaway fault')
    fastest = float(np.abs(qd0).max()) if qd0.size else 0.0
    if fastest > values['velocity_limit']:
        j = int(np.argmax(np.abs(qd0)))
        return (f'initial_velocities: joint {j + 1} {what} {fastest:.6g} rad/s > '
                f"velocity_limit {values['velocity_limit']:g} rad/s: the first step would "
                'count as divergence')
    return None


def make_model(robot: dict, geared: dict) -> Model:
    """Build the simulated model from node parameters: the robot's ``model`` through
    :func:`~arm_dynamics.models.robot_model`, except ``single_link_geared``, simulated from
    the ``geared.*`` parameters. Raises ValueError naming the parameter the physics refuses.
    """
    if robot.get('model') == 'single_link_geared':
        return geared_link(geared)
    return robot_model(robot)
