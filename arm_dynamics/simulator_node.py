"""``simulator`` node: integrates the arm and publishes ``joint_states`` and ``clock``.

Thin ROS shell around :class:`arm_dynamics.simulation.SimulatorCore` (the physics) and
:class:`arm_dynamics.timing.Timekeeper` (when time advances): parameters in,
``effort_controller/commands`` (std_msgs/Float64MultiArray) in, JointState and Clock out,
``~/reset`` (std_srvs/Trigger), and ``/diagnostics``. The node only feeds the two pure
objects messages and wall time; see :mod:`arm_dynamics.timing` for the timing modes.
"""

from __future__ import annotations

import math
import time

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from rclpy.timer import Timer
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool, Trigger

from arm_common.gate import WAIT_FOR_NODES, SubscriberGate
from arm_common.node import (
    STREAM_DEPTH,
    ConfigError,
    Diagnostics,
    clock_in_namespace,
    declare_parameters,
    on_parameter_changes,
    run_node,
    steady_clock,
)
from arm_common.params import ParamSpec
from arm_common.throttle import GrowingIntervals
from arm_dynamics.disturbance import DisturbanceError, Disturbances, Event
from arm_dynamics.friction import JointFriction
from arm_dynamics.limits import JointLimits
from arm_dynamics.models import joint_count
from arm_dynamics.robot import ROBOT_PARAMS
from arm_dynamics.sensors import SensorModel, whole_counts_reason
from arm_dynamics.simulation import (
    CommandError,
    SimulatorCore,
    initial_position_reason,
    initial_velocity_reason,
    make_model,
    validate_command,
)
from arm_dynamics.timing import (
    APPLY,
    MAX_CATCH_UP,
    REMOVED_MODES,
    STALE,
    TIMING_MODES,
    Timekeeper,
    Window,
    answer_tag,
    parse_answer_tag,
)

HOLD_LEASE = 30.0  # s (wall): a hold nobody released in this long is released (reported)

SUMMARY = '''
Simulates the robot model (the 2-R arm, a planar n-link chain or the geared single link)
and publishes joint_states
(sensor_msgs/JointState: position rad, velocity rad/s, applied effort N m, stamped in
simulated time) and clock (rosgraph_msgs/Clock); takes effort_controller/commands
(std_msgs/Float64MultiArray, N m per joint, saturated at effort_limits). Service ~/reset
(std_srvs/Trigger) restores the initial state; ~/hold (std_srvs/SetBool) holds simulated
time at the current state (true; the reply's message names it, joint_states@SEC.NANOSEC)
until released (false): the planner holds it while it plans a goal. Reports on
/diagnostics (statuses "simulator: summary" and one per problem or event kind, e.g.
"simulator: waiting_for_command").

timing_mode: lockstep (one control period, 1/publish_rate, per valid command for the
current state: deterministic, as fast as the closed loop runs), real_time (the same
lockstep at wall-clock pace: simulated time never runs ahead of the wall clock times
real_time_factor, and a late controller makes it wait: the results are lockstep's, bit for
bit) or wall_clock (opt-in: periods integrated on the wall clock's schedule with whatever
command is held then: the results depend on the machine). A silent controller makes time
stand still and is reported, never replaced by zero torque (except in wall_clock).
Simulated time is the only time that changes the physics.

Sensors and actuators (all off by default): joint_states is the measurement (noise,
encoder counts, sensing_delay, drawn from noise_seed) and the command acts
actuation_delay periods late; with any of them on, simulator/true_joint_states
(sensor_msgs/JointState, same stamp) carries the true state.

A real arm (robot parameters, all off by default): geared motors (gear_ratios,
motor_inertias, motor_damping) and stick/slip friction (coulomb_friction,
static_friction) on every joint. Pushes and faults at exact simulated times from
disturbance_file (a YAML scenario: config/disturbances/example.yaml), live tip pushes on
simulator/push (geometry_msgs/WrenchStamped: force x, y in N, base frame, held push_duration
s); each start and end is published on simulator/events (diagnostic_msgs/DiagnosticStatus,
values time_ns, kind, edge, label) and logged; simulator/true_joint_states then carries the
true applied torque (motor plus push) as its effort.
'''

SIM_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec('physics_step', 'double', 0.001, 'Fixed RK4 integration step', 's',
              minimum=1e-6, maximum=0.1, read_only=True),
    ParamSpec('publish_rate', 'double', 100.0,
              'State and clock publication rate in simulated time; 1/publish_rate is the '
              'control period (a whole multiple of physics_step) that one lockstep command '
              'advances', 'Hz', minimum=0.1, maximum=10000.0, read_only=True),
    ParamSpec('initial_positions', 'doubles', [-0.4, 1.2],
              'Initial and reset joint positions (single_link_geared: first value = link '
              'angle from hanging down); applied at start and on reset; within the joint '
              'limits plus fault_position_margin (refused beyond: a runaway at once)', 'rad',
              minimum=-100.0, maximum=100.0, per_joint=True, fill=0.0,
              relation=initial_position_reason),
    ParamSpec('initial_velocities', 'doubles', [0.0, 0.0],
              'Initial and reset joint velocities (single_link_geared: first value = link '
              'speed); within fault_velocity_factor times velocity_limits and within '
              'velocity_limit (refused beyond: a fault at once)', 'rad/s', minimum=-1000.0,
              maximum=1000.0, per_joint=True, fill=0.0, relation=initial_velocity_reason),
    ParamSpec('command_timeout', 'double', 0.5,
              'Wall-clock time without a valid command that is reported (a WARN with the '
              'time waited); time keeps standing still until the answer comes. wall_clock '
              'only: the torque also goes to zero until commands return, as a drive '
              'watchdog would. 0 disables', 's', minimum=0.0, maximum=3600.0),
    ParamSpec('timing_mode', 'string', 'real_time', 'How simulated time advances',
              choices=TIMING_MODES, hints=tuple(REMOVED_MODES.items())),
    ParamSpec('wait_for_command', 'bool', True,
              'wall_clock: hold the initial state (no integration, time stands at its start) '
              'until the first valid command; false = integrate from the start (the arm '
              'falls until commanded). lockstep and real_time always wait for it'),
    ParamSpec('real_time_factor', 'double', 1.0,
              'Simulated seconds per wall second that real_time (and wall_clock) paces to; '
              'real_time never runs faster, and slower only while the loop cannot keep up',
              'x', minimum=0.0, strict_min=True, maximum=1000.0),
    ParamSpec('pause_at', 'double', -1.0,
              'Simulated time at which the simulation pauses (state held, commands kept); '
              'set it later, or negative, to resume. Negative = never', 's', maximum=1e9),
    ParamSpec('velocity_limit', 'double', 1000.0,
              'Any joint speed above this counts as divergence: integration stops and the '
              'last good state is held until reset', 'rad/s', minimum=0.0, strict_min=True,
              read_only=True),
    ParamSpec('enforce_position_limits', 'bool', False,
              'Joint position limits act as hard end stops (a joint reaching one stops '
              'there); otherwise a state outside the limits is only reported',
              read_only=True),
    ParamSpec('fault_position_margin', 'double', 0.5,
              'Runaway envelope: a joint this far beyond a position limit is a fault '
              '(ERROR, state held until ~/reset)', 'rad', minimum=0.0, maximum=100.0,
              read_only=True),
    ParamSpec('fault_velocity_factor', 'double', 2.0,
              'Runaway envelope: a joint faster than this times its speed limit is a fault',
              '', minimum=1.0, maximum=1000.0, read_only=True),
    ParamSpec('position_noise', 'doubles', [0.0, 0.0],
              'Sensors: standard deviation of the Gaussian noise on each measured joint '
              'position (joint_states; simulator/true_joint_states has the true state; '
              'single_link_geared: first value, on the motor shaft); 0 = none', 'rad',
              minimum=0.0, maximum=10.0, per_joint=True, fill=0.0, read_only=True),
    ParamSpec('velocity_noise', 'doubles', [0.0, 0.0],
              'Sensors: standard deviation of the Gaussian noise on each measured joint '
              'velocity; 0 = none', 'rad/s', minimum=0.0, maximum=1000.0, per_joint=True,
              fill=0.0, read_only=True),
    ParamSpec('encoder_resolution', 'doubles', [0.0, 0.0],
              'Sensors: encoder counts per revolution of each joint (whole numbers): the '
              'measured position is rounded to the nearest count, 2 pi/counts rad; '
              '0 = ideal', 'counts/rev', minimum=0.0, maximum=1e9, per_joint=True, fill=0.0,
              read_only=True,
              relation=lambda v: whole_counts_reason(v['encoder_resolution'])),
    ParamSpec('sensing_delay', 'int', 0,
              'Sensors: the state published at t_j is the measurement of the state at '
              't_(j-k), k whole control periods (before that: the first state measured)',
              'periods', minimum=0, maximum=1000, read_only=True),
    ParamSpec('actuation_delay', 'int', 0,
              'Actuators: the command answering the state at t_j is applied over '
              '[t_(j+k), t_(j+k+1)], k whole control periods (zero torque before); the '
              'lockstep hand-shake is unchanged', 'periods', minimum=0, maximum=1000,
              read_only=True),
    ParamSpec('noise_seed', 'int', 0,
              'Sensors: seed of the noise generator (numpy PCG64): the same seed gives the '
              'same measurements, bit for bit', '', minimum=0, maximum=1e9,
              read_only=True),
    ParamSpec('disturbance_file', 'string', '',
              'Pushes and faults at exact simulated times: a YAML scenario (see '
              'config/disturbances/example.yaml; times on the physics_step grid); empty = '
              'none', read_only=True, allow_empty=True),
    ParamSpec('push_duration', 'double', 0.1,
              'How long a live push on simulator/push is held (a pulse from the next control '
              'period); a whole multiple of physics_step', 's', minimum=0.0, strict_min=True,
              maximum=3600.0, read_only=True),
    ParamSpec('geared.motor_inertia', 'double', 0.005, 'Geared link: motor inertia Jm',
              'kg m^2', minimum=0.0, strict_min=True, read_only=True),
    ParamSpec('geared.load_inertia', 'double', 1.0,
              'Geared link: link inertia about the joint Jl', 'kg m^2', minimum=0.0,
              read_only=True),
    ParamSpec('geared.motor_damping', 'double', 0.01, 'Geared link: motor damping Bm',
              'N m s/rad', minimum=0.0, read_only=True),
    ParamSpec('geared.load_damping', 'double', 0.5, 'Geared link: load damping Bl',
              'N m s/rad', minimum=0.0, read_only=True),
    ParamSpec('geared.gear_ratio', 'double', 50.0, 'Geared link: gear ratio n (motor turns '
              'per link turn)', '', minimum=0.0, strict_min=True, read_only=True),
    ParamSpec('geared.mass', 'double', 2.0, 'Geared link: link mass M', 'kg', minimum=0.0,
              read_only=True),
    ParamSpec('geared.length', 'double', 0.5, 'Geared link: joint axis to link CG l', 'm',
              minimum=0.0, read_only=True),
    ParamSpec('geared.effort_limit', 'double', 1.0, 'Geared link: motor torque limit',
              'N m', minimum=0.0, strict_min=True, read_only=True),
    WAIT_FOR_NODES,
)


def _ns(seconds: float) -> int:
    return int(round(seconds * 1e9))


def _pause_ns(pause_at: float) -> int | None:
    return None if pause_at < 0 else _ns(pause_at)


def _static_default(robot: dict) -> dict:
    """The robot parameters with each ``static_friction`` of 0 replaced by the joint's
    ``coulomb_friction`` (0 = no break-away torque beyond the Coulomb one)."""
    coulomb = list(robot.get('coulomb_friction') or [])
    static = list(robot.get('static_friction') or [])
    return {**robot, 'static_friction': [s if s > 0 else c for s, c in zip(static, coulomb)]}


class SimulatorNode(Node):
    """See the module docstring."""

    def __init__(self) -> None:
        super().__init__('simulator', cli_args=clock_in_namespace())
        p = declare_parameters(self, ROBOT_PARAMS + SIM_PARAMS, joints=joint_count)
        robot = {s.name: p[s.name] for s in ROBOT_PARAMS}
        step_ns, period_ns = _ns(p['physics_step']), _ns(1.0 / p['publish_rate'])
        if period_ns % step_ns:
            raise ConfigError(
                f"publish_rate: its period 1/{p['publish_rate']:g} Hz = {period_ns} ns must "
                f"be a whole multiple of physics_step = {step_ns} ns")
        geared = {k.split('.', 1)[1]: v for k, v in p.items()
                  if k.startswith('geared.') and k != 'geared.effort_limit'}
        geared['gravity'] = robot['gravity']
        try:
            model = make_model(robot, geared)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        self.params = p
        self.n = model.n_dof
        self.geared = p['model'] == 'single_link_geared'
        limits = [p['geared.effort_limit']] if self.geared else robot['effort_limits']
        q0, qd0 = self._initial_state(model, p['initial_positions'],
                                      p['initial_velocities'])
        joint_limits = envelope = None
        if not self.geared:  # the geared link's motor shaft has no joint limits of its own
            try:
                joint_limits = JointLimits.from_params(robot)
            except ValueError as exc:
                raise ConfigError(str(exc)) from None
            envelope = joint_limits.envelope(p['fault_position_margin'],
                                             p['fault_velocity_factor'])
            # An initial state beyond it was refused by declare_parameters (the relations
            # of initial_positions and initial_velocities), as a run-time change is.
        n = self.n  # the model's state: single_link_geared takes each list's first value
        sensors = SensorModel(n, position_noise=p['position_noise'][:n],
                              velocity_noise=p['velocity_noise'][:n],
                              encoder_resolution=p['encoder_resolution'][:n],
                              sensing_delay=p['sensing_delay'], seed=p['noise_seed'])
        try:
            if self.geared:  # its state is the motor shaft: the robot's friction is not its
                if any(robot['coulomb_friction']) or any(robot['static_friction']):
                    raise ValueError('model single_link_geared takes no coulomb_friction or '
                                     'static_friction (its damping is geared.*)')
                friction = None
            else:
                friction = JointFriction.from_params(_static_default(robot), n)
            disturbances = (Disturbances.load(p['disturbance_file'], n=n,
                                              joint_names=robot['joint_names'][:n],
                                              physics_step_ns=step_ns,
                                              tip_forces=not self.geared)
                            if p['disturbance_file'].strip() else None)
        except (ValueError, DisturbanceError) as exc:
            raise ConfigError(str(exc)) from None
        self.push_ns = _ns(p['push_duration'])
        if self.push_ns % step_ns:
            raise ConfigError(f"push_duration {p['push_duration']:g} s is not a whole "
                              f"multiple of physics_step {p['physics_step']:g} s")
        try:
            self.core = SimulatorCore(
                model, q0=q0, qd0=qd0, effort_limits=limits, physics_step_ns=step_ns,
                control_period_ns=period_ns, velocity_limit=p['velocity_limit'],
                joint_names=robot['joint_names'], joint_limits=joint_limits,
                hard_stops=p['enforce_position_limits'], envelope=envelope, sensors=sensors,
                actuation_delay=p['actuation_delay'], friction=friction,
                disturbances=disturbances)
        except ValueError as exc:  # the geared link with friction or disturbances
            raise ConfigError(f"model {p['model']}: {exc}") from None
        self.keeper = Timekeeper(mode=p['timing_mode'], period_ns=period_ns,
                                 real_time_factor=p['real_time_factor'],
                                 hold_until_command=p['wait_for_command'],
                                 report_after_ns=_ns(p['command_timeout']))
        self.keeper.pause_at_ns = _pause_ns(p['pause_at'])
        self.state_pub = self.create_publisher(JointState, 'joint_states', STREAM_DEPTH)
        self.clock_pub = self.create_publisher(Clock, 'clock', STREAM_DEPTH)
        # The true state beside the measurement. Always advertised (a recorder subscribes
        # what has a publisher: arm-sim demo waits for it), published only when the two can
        # differ (a sensor or actuator effect on): with the defaults, bags are what they were.
        self.true_pub = self.create_publisher(JointState, 'simulator/true_joint_states',
                                              STREAM_DEPTH)
        self.publish_true = (sensors.enabled or p['actuation_delay'] > 0
                             or disturbances is not None)
        self.events_pub = self.create_publisher(DiagnosticStatus, 'simulator/events',
                                                STREAM_DEPTH)
        self.create_subscription(WrenchStamped, 'simulator/push', self._on_push, 10)
        # The first state waits for wait_for_nodes (e.g. the recorder) to match joint_states
        # and clock; until then time is held at t = 0 and nothing is published.
        self.gate = SubscriberGate(self, [self.state_pub, self.clock_pub],
                                   p['wait_for_nodes'])
        self.cmd_sub = self.create_subscription(Float64MultiArray,
                                                'effort_controller/commands',
                                                self._on_command, 10)
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.create_service(SetBool, '~/hold', self._on_hold)
        self.diag = Diagnostics(self, sim_time=lambda: self.core.time)
        self.timed_out = False  # wall_clock watchdog: torque zeroed until commands return
        self.last_command_wall = time.monotonic_ns()
        self.held_since: int | None = None  # wall ns a client's hold began
        self.holds = 0
        self.wait_reported: float | None = None  # wall s waited at the last wait report
        self.wait_log = GrowingIntervals()  # the log lines of real_time_waits
        self.window: Window | None = None
        self.windows = 0  # reporting windows closed (each ~1 s of wall time)
        self.rt_timer: Timer | None = None
        self._anchors = 0  # keeper.anchors when the pacing timer was last aligned
        self._make_rt_timer()
        self.create_timer(0.05, self._housekeeping, clock=steady_clock())
        on_parameter_changes(self, SIM_PARAMS, self._validate_change, self._apply_change,
                             values=self.params)
        self.keeper.held = not self.gate.opened
        self.publish_state(new_state=True)
        if not self.gate.opened:
            self._summarise()
        self.get_logger().info(
            f"{p['model']} in {p['timing_mode']} mode: physics step {p['physics_step']:g} s, "
            f"publishing at {p['publish_rate']:g} Hz, q0={self.core.q.tolist()}")

    # ------------------------------------------------------------------ parameters
    def _initial_state(self, model, positions, velocities):
        if self.geared:
            n = model.gear_ratio
            return [positions[0] * n], [velocities[0] * n]
        return positions, velocities  # one per joint: declare_parameters sized them

    def _validate_change(self, changed: dict) -> str | None:
        joints = len(self.params['joint_names'])
        for key in ('initial_positions', 'initial_velocities'):
            values = changed.get(key)
            if values is not None and not (len(values) == joints or self.geared and values):
                return (f'{key} has {len(values)} values but the robot has {joints} joints '
                        f'(got {list(values)})')
        return None  # then the relations, as at start (initial state within the envelope)

    def _apply_change(self, changed: dict) -> None:
        self.params.update(changed)
        k = self.keeper
        if 'initial_positions' in changed or 'initial_velocities' in changed:
            q0, qd0 = self._initial_state(self.core.model, self.params['initial_positions'],
                                          self.params['initial_velocities'])
            self.core.q0[:], self.core.qd0[:] = q0, qd0
        if 'timing_mode' in changed:
            k.set_mode(changed['timing_mode'])
        if 'real_time_factor' in changed:
            k.real_time_factor = changed['real_time_factor']
        if 'timing_mode' in changed or 'real_time_factor' in changed:
            self._make_rt_timer()
        if 'command_timeout' in changed:
            k.report_after_ns = _ns(changed['command_timeout'])
        if 'wait_for_command' in changed:
            k.hold_until_command = changed['wait_for_command']
        if 'pause_at' in changed:
            k.pause_at_ns = _pause_ns(changed['pause_at'])
        k.reanchor(time.monotonic_ns())
        self._try_step()
        self.get_logger().info(f'parameters changed: {changed}')

    def _make_rt_timer(self) -> None:
        """The pacing timer: real_time (one tick per control period of wall time, aligned
        with the pacing anchor) and wall_clock; none in lockstep: answers pace it."""
        if self.rt_timer is not None:
            self.destroy_timer(self.rt_timer)
            self.rt_timer = None
        if self.keeper.mode == 'lockstep':
            return
        # Whole nanoseconds, rounded up: a tick never fires before its period is due
        # (rclpy truncates the float seconds it is given).
        wall_ns = max(math.ceil(self.core.period_ns / self.params['real_time_factor']),
                      100_000)
        callback = self._on_rt_tick if self.mode == 'real_time' else self._on_wall_tick
        self.rt_timer = self.create_timer((wall_ns + 0.5) * 1e-9, callback,
                                          clock=steady_clock())

    # ------------------------------------------------------------------ stepping
    @property
    def mode(self) -> str:
        return self.keeper.mode

    @property
    def paused(self) -> bool:
        return self.keeper.paused(self.core.time_ns)

    def _step_and_publish(self) -> None:
        """One control period with the held command, then publish the new state."""
        core = self.core
        was_diverged = core.diverged
        core.advance()
        for event in core.events:
            self._publish_event(event)
        if core.diverged and not was_diverged:
            kind = 'runaway' if core.diverged.startswith('runaway') else 'diverged'
            self.diag.problem(kind, core.diverged, 'ERROR', q=core.q.tolist(),
                              qd=core.qd.tolist())
            self._summarise()  # every summary from now on says ERROR, until ~/reset
        elif not core.diverged:
            outside = core.outside_limits
            if outside:
                self.diag.problem('outside_limits', f'state outside the joint limits: '
                                  f'{outside}', q=core.q.tolist(), qd=core.qd.tolist())
        self.publish_state(new_state=True)

    def _try_step(self) -> None:
        """Answered modes: integrate the current period if its answer is in and time may
        move (real_time: its end is due on the wall clock)."""
        k = self.keeper
        if k.may_step(self.core.time_ns, time.monotonic_ns()):
            self._step_and_publish()
        if k.anchors != self._anchors and self.rt_timer is not None:
            self._anchors = k.anchors
            self.rt_timer.reset()  # ticks from the new anchor: each lands on a due time

    def _on_rt_tick(self) -> None:
        self._try_step()

    def _on_wall_tick(self) -> None:
        k = self.keeper
        overruns = k.overruns
        steps = 0
        while steps < MAX_CATCH_UP and k.periods_due(self.core.time_ns,
                                                     time.monotonic_ns()) > 0:
            k.before_advance(self.core.time_ns)
            self._step_and_publish()
            steps += 1
        if k.overruns > overruns:
            win = self.window
            self.diag.problem('overrun', f'cannot keep up with real_time_factor '
                              f'{k.real_time_factor:g}: {k.behind_s:.3f} s of simulated time '
                              'given up so far; continuing from here at the same pace'
                              + (f' (achieved {win.real_time_factor:.2f}x)' if win else ''),
                              simulated_time_given_up=f'{k.behind_s:.3f}')

    def _publish_event(self, event: Event) -> None:
        """A push or fault starting or ending: simulator/events, the log and /diagnostics."""
        fault = event.kind not in ('tip_force', 'joint_torque')
        sec = event.time_ns * 1e-9
        self.events_pub.publish(DiagnosticStatus(
            level=DiagnosticStatus.WARN if fault else DiagnosticStatus.OK,
            name=f"simulator: {'fault' if fault else 'push'}", message=event.description,
            values=[KeyValue(key='time_ns', value=str(event.time_ns)),
                    KeyValue(key='kind', value=event.kind),
                    KeyValue(key='edge', value=event.edge),
                    KeyValue(key='label', value=event.label)]))
        self.get_logger().info(f'{event.description} ({event.edge}, {event.label}) at '
                               f't={sec:.3f} s')
        self.diag.event('fault' if fault else 'push', event.description, time=f'{sec:.9f}',
                        edge=event.edge, label=event.label)
        self.publish_true = True

    def _on_push(self, msg: WrenchStamped) -> None:
        """A live tip push: held push_duration from the next control period."""
        force = (msg.wrench.force.x, msg.wrench.force.y)
        try:
            if self.geared:
                raise ValueError('the geared link has no tip to push')
            push = self.core.push(force, self.push_ns)
        except ValueError as exc:
            self.diag.problem('rejected_push', f'push {list(force)} N refused: {exc}')
            return
        self.publish_true = True
        self.get_logger().info(f'live push {list(push.value)} N for '
                               f"{self.params['push_duration']:g} s from "
                               f't={push.start_ns * 1e-9:.3f} s')

    def _on_command(self, msg: Float64MultiArray) -> None:
        answers = parse_answer_tag(msg.layout.dim[0].label) if msg.layout.dim else None
        try:
            values = validate_command(msg.data, self.n)
        except CommandError as exc:
            self.diag.problem('rejected_command', f'{exc}; keeping the last good command',
                              refused=str(exc))
            return
        now = time.monotonic_ns()
        k = self.keeper
        waited = k.overdue_s(self.core.time_ns, now)
        verdict = k.on_command(answers, self.core.time_ns, now)
        if verdict == STALE:
            return
        if self.core.accepts_command():  # else lost on the way (a commands_dropped fault)
            self.core.command = values
        self.last_command_wall = now
        if waited is not None:
            self.diag.event('controller_back', f'a command for t={self.core.time:.3f} s came '
                            f'after {waited:.2f} s (wall); the results are unaffected',
                            waited_wall=f'{waited:.3f}')
        if self.timed_out:
            self.timed_out = False
            self.get_logger().info('effort commands resumed')
        if verdict == APPLY:
            self._on_wall_tick()  # wall_clock: the answer may be what a due period waits for
        else:  # answered (HOLD: kept until the pause or hold ends)
            self._try_step()

    def publish_state(self, new_state: bool = False) -> None:
        if not self.gate.opened:
            return  # the first state goes out once the gate opens (_housekeeping)
        view = self.core.joint_view()
        msg = JointState(name=list(view.names), position=view.position,
                         velocity=view.velocity, effort=view.effort)
        sec, nsec = divmod(self.core.time_ns, 1_000_000_000)
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nsec
        if self.publish_true:  # before the measurement: a reader of it has both
            true = self.core.true_view()
            true_msg = JointState(name=list(true.names), position=true.position,
                                  velocity=true.velocity, effort=true.effort)
            true_msg.header.stamp = msg.header.stamp
            self.true_pub.publish(true_msg)
        self.state_pub.publish(msg)
        clock = Clock()
        clock.clock = msg.header.stamp
        self.clock_pub.publish(clock)
        self.keeper.on_published(self.core.time_ns, time.monotonic_ns(), new_state,
                                 self._links() if self.keeper.counts_links else None)

    def _links(self) -> int:
        """Matched joint_states subscribers plus effort command publishers: a rise means
        someone new may have missed the current state or its answer (the re-send rule of
        an untagged controller, :meth:`arm_dynamics.timing.Timekeeper.heartbeat_due`)."""
        return self.state_pub.get_subscription_count() + self.cmd_sub.get_publisher_count()

    def _housekeeping(self) -> None:
        now = time.monotonic_ns()
        k = self.keeper
        if not self.gate.opened and self.gate.ready(self.diag, 'the first state'):
            self.publish_state(new_state=True)
            if self.held_since is None:  # no client holds time meanwhile
                self._release(now)
        sim = self.core.time_ns
        waited = k.overdue_s(sim, now)
        if waited is None:
            self.wait_reported = None
        elif self.wait_reported is None or waited - self.wait_reported >= 1.0:
            self.wait_reported = waited  # once a second of waiting: counts are of waits
            self.diag.problem('waiting_for_command', f'no command answering the state at '
                              f't={self.core.time:.3f} s for {waited:.2f} s (wall): simulated '
                              f'time stands still until one comes ({self.mode})',
                              waited_wall=f'{waited:.3f}')
        timeout = _ns(self.params['command_timeout'])
        if self.mode == 'wall_clock' and (k.holding() or k.stopped(sim)):
            self.last_command_wall = now  # no commands are due
        elif (self.mode == 'wall_clock' and timeout > 0 and k.started and not self.timed_out
                and now - self.last_command_wall > timeout):
            self.timed_out = True
            self.core.clear_command()
            self.diag.problem('command_timeout', f"no valid effort command for "
                              f"{self.params['command_timeout']:g} s (wall): torque set to "
                              'zero until commands return (wall_clock watchdog)',
                              command_timeout=f"{self.params['command_timeout']:g}")
        if self.held_since is not None and now - self.held_since > HOLD_LEASE * 1e9:
            self.diag.problem('hold_expired', f'simulated time was held at t={self.core.time:.3f}'
                              f' s for {HOLD_LEASE:g} s (wall) and nobody released it: '
                              'released (did the planner die?)')
            self._release(now)
        if k.heartbeat_due(sim, now, self._links() if k.counts_links and not k.answered
                           else None):
            self.publish_state()
        win = k.window(sim, now)
        if win is not None:
            self.window = win
            self.windows += 1
            if win.late:
                self.diag.problem(
                    'late_periods', f'{win.late} of {win.periods} control periods in the last '
                    f'{win.wall_s:.1f} s (wall) were integrated before the controller answered '
                    f'their state: achieved {win.answered_rate:.0f} Hz of '
                    f"{self.params['publish_rate']:g} Hz (wall_clock: the results depend on "
                    'the machine)',
                    late_fraction=f'{win.late_fraction:.4f}',
                    achieved_control_rate=f'{win.answered_rate:.1f}')
            if self.mode == 'real_time':
                self._report_waits(win, now)
            self._summarise()

    def _report_waits(self, win: Window, now: int) -> None:
        """``real_time_waits``: on /diagnostics (WARN) each window with waits, as every
        problem; in the log the first wait once, then a summary with the totals at growing
        intervals (:class:`arm_common.throttle.GrowingIntervals`: 5 s, then every 30 s), not a
        line a second under load."""
        k, kind = self.keeper, 'real_time_waits'
        line = self.wait_log.note(now * 1e-9, win.waits, win.waited_s)
        if win.waits:  # on /diagnostics each window; the log gets the summaries below
            self.diag.problem(
                kind, f'simulated time waited for the controller {win.waits} time(s) '
                f'in the last {win.wall_s:.1f} s (wall), {win.waited_s:.3f} s in all: achieved '
                f'{win.real_time_factor:.2f}x of {k.real_time_factor:g}x real time (the '
                'results are unaffected)', log=False, waits=win.waits,
                waited_wall=f'{win.waited_s:.3f}',
                achieved_real_time_factor=f'{win.real_time_factor:.3f}')
        if line is None:
            return
        totals = (f'{k.waits} time(s), {k.waited_s:.3f} s (wall) in all since the start; '
                  f'achieved {k.paced_real_time_factor:.2f}x of {k.real_time_factor:g}x real '
                  'time (the results are unaffected)')
        if line.first:
            self.get_logger().warning(
                f'simulated time waited for the controller {line.count} time(s) in the last '
                f'{win.wall_s:.1f} s (wall), {line.amount:.3f} s: {totals}; further waits are '
                f'summarised after {self.wait_log.intervals[0]:g} s, then every '
                f'{self.wait_log.intervals[-1]:g} s (/diagnostics: {kind}, every second)')
        else:
            self.get_logger().warning(
                f'simulated time waited for the controller {line.count} more time(s) in the '
                f'last {line.span:.0f} s (wall), {line.amount:.3f} s: {totals}')

    def _summarise(self) -> None:
        core, k, win = self.core, self.keeper, self.window
        if core.diverged:
            level, message = 'ERROR', core.diverged
        elif self.paused:
            level, message = 'OK', f'paused at t={core.time:.3f} s (pause_at)'
        elif not self.gate.opened:
            level, message = 'OK', ('holding the first state until '
                                    f"{', '.join(self.gate.nodes)} subscribed (wait_for_nodes)")
        elif k.held:
            level, message = 'OK', f'held at t={core.time:.3f} s (~/hold: a goal is planned)'
        elif k.holding():
            level, message = 'OK', 'holding the initial state until the first command'
        elif not k.started:
            level, message = 'WARN', f'waiting for the first command ({self.mode})'
        elif self.timed_out:
            level, message = 'WARN', 'command timeout: applying zero torque'
        elif k.overdue_s(core.time_ns, time.monotonic_ns()) is not None:
            level, message = 'WARN', f'waiting for a command ({self.mode}: time stands still)'
        else:
            level, message = 'OK', f'running ({self.mode})'
        self.diag.set(level, message, timing_mode=self.mode,
                      paused_at='' if not self.paused else f'{core.time:.9f}',
                      achieved_real_time_factor=f'{win.real_time_factor:.2f}' if win else '0',
                      window=self.windows,
                      commands_received=k.commands, stale_commands_ignored=k.stale,
                      control_periods=k.periods, late_periods=k.late_periods,
                      late_waits=k.late_waits, longest_wait_wall=f'{k.longest_wait_s:.3f}',
                      overruns=k.overruns, simulated_time_given_up=f'{k.behind_s:.3f}',
                      real_time_waits=k.waits, real_time_waited_wall=f'{k.waited_s:.3f}',
                      real_time_slips=k.slips,
                      paced_real_time_factor=f'{k.paced_real_time_factor:.3f}',
                      held='' if not k.held else f'{core.time:.9f}', holds=self.holds,
                      saturated_joints=[n for n, s in zip(core.joint_names, core.saturated)
                                        if s],
                      friction_work=f'{core.friction_work:.6f}',
                      stuck_joints=[n for n, s in zip(core.joint_names, core.stuck) if s])

    def timing_summary(self) -> str:
        """One line on how simulated time was paced (logged at shutdown; ``arm-sim
        bringup`` prints it)."""
        k = self.keeper
        text = (f'timing: {self.mode}, {k.periods} control periods to t={self.core.time:.3f} s'
                f', {k.late_waits} wait(s) for the controller longer than command_timeout '
                f'(longest {k.longest_wait_s:.3f} s wall)')
        if self.mode == 'real_time':
            text += (f'; achieved {k.paced_real_time_factor:.3f}x of {k.real_time_factor:g}x'
                     f' real time while running, time waited for the controller {k.waits} '
                     f'time(s) ({k.waited_s:.3f} s wall), pacing restarted {k.slips} time(s);'
                     ' the results are those of lockstep')
        elif self.mode == 'wall_clock':
            text += (f'; {k.late_periods} late period(s) integrated without their answer '
                     '(wall_clock: the results depend on the machine)')
        return text

    def destroy_node(self) -> None:
        self.get_logger().info(self.timing_summary())
        super().destroy_node()

    def _on_hold(self, request: SetBool.Request, response: SetBool.Response):
        """Hold simulated time at the current state (``data`` true) or release it. The
        reply names the state held, ``joint_states@SEC.NANOSEC``; an answer to it that
        comes meanwhile is kept and applied on release, as while paused."""
        now = time.monotonic_ns()
        if request.data:
            if not self.keeper.held:
                self.holds += 1
            self.keeper.held = True
            self.held_since = now
        elif self.keeper.held:
            self._release(now)
        response.success = True
        response.message = answer_tag(self.core.time_ns)
        return response

    def _release(self, now: int) -> None:
        self.keeper.held = not self.gate.opened  # before the first state: still held
        self.held_since = None
        self.keeper.reanchor(now)
        if self.mode == 'wall_clock':
            self._on_wall_tick()
        else:
            self._try_step()

    def _on_reset(self, _request: Trigger.Request, response: Trigger.Response):
        faulted = self.core.diverged
        self.core.reset()
        self.keeper.reanchor(time.monotonic_ns())
        self.publish_state(new_state=True)
        response.success = True
        response.message = (f'reset to q={self.core.q.tolist()} qd={self.core.qd.tolist()} '
                            f'at t={self.core.time:.3f} s')
        self.get_logger().info(response.message)
        # Said at once (event 'reset'), with the fault it cleared, and in the summary: a
        # planner refusing goals for the fault learns it is over.
        self.diag.event('reset', response.message, cleared=faulted or '')
        self._summarise()
        return response


def main(args: list[str] | None = None) -> int:
    return run_node(SimulatorNode, prog='simulator', summary=SUMMARY,
                    specs=ROBOT_PARAMS + SIM_PARAMS, args=args)


if __name__ == '__main__':
    raise SystemExit(main())
