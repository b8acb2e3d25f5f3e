"""``simulator`` node: integrates the arm and publishes ``joint_states`` and ``clock``.

Thin ROS shell around :class:`arm_dynamics.simulation.SimulatorCore`: parameters in,
``effort_controller/commands`` (std_msgs/Float64MultiArray) in, JointState and Clock out,
``~/reset`` (std_srvs/Trigger), and ``/diagnostics``.

Timing modes (parameter ``timing_mode``):

* ``real_time`` -- simulated time follows the wall clock times ``real_time_factor``; if the
  node cannot keep up it says so on /diagnostics and continues from where it is.
* ``as_fast_as_possible`` -- steps continuously, serving callbacks between steps.
* ``lockstep`` -- publishes the state, then advances one control period (1/publish_rate)
  only when a valid command arrives: deterministic, as fast as the loop allows. Before the
  first command it waits (re-sending the state every 0.2 s). If commands then stop for
  ``command_timeout``, the torque goes to zero and the simulator runs on in real time
  until commands return.
"""

from __future__ import annotations

import time

from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from arm_dynamics.simulation import CommandError, SimulatorCore, make_model, parse_answer_tag
from arm_sim.params import ROBOT_PARAMS, ParamSpec
from arm_sim.ros_common import (
    ConfigError,
    Diagnostics,
    declare_parameters,
    on_parameter_changes,
    run_node,
    steady_clock,
)

SUMMARY = '''
Simulates the 2-R arm (or the geared single link) and publishes joint_states
(sensor_msgs/JointState: position rad, velocity rad/s, applied effort N m, stamped in
simulated time) and clock (rosgraph_msgs/Clock); takes effort_controller/commands
(std_msgs/Float64MultiArray, N m per joint, saturated at effort_limits). Service ~/reset
(std_srvs/Trigger) restores the initial state. Reports on /diagnostics.

timing_mode: real_time (follows the wall clock times real_time_factor), as_fast_as_possible,
or lockstep (advances one control period, 1/publish_rate, per valid command: deterministic).
'''
MODES = ('real_time', 'as_fast_as_possible', 'lockstep')
HEARTBEAT = 0.2  # s (wall): lockstep re-sends the current state when no command came

SIM_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec('model', 'string', 'two_link', 'Simulated model',
              choices=('two_link', 'single_link_geared'), read_only=True),
    ParamSpec('physics_step', 'double', 0.001, 'Fixed RK4 integration step', 's',
              minimum=1e-6, maximum=0.1, read_only=True),
    ParamSpec('publish_rate', 'double', 100.0,
              'State and clock publication rate in simulated time; 1/publish_rate is the '
              'control period (a whole multiple of physics_step) that one lockstep command '
              'advances', 'Hz', minimum=0.1, maximum=10000.0, read_only=True),
    ParamSpec('initial_positions', 'doubles', [-0.4, 1.2],
              'Initial and reset joint positions (single_link_geared: first value = link '
              'angle from hanging down); applied at start and on reset', 'rad',
              minimum=-100.0, maximum=100.0),
    ParamSpec('initial_velocities', 'doubles', [0.0, 0.0],
              'Initial and reset joint velocities (single_link_geared: first value = link '
              'speed)', 'rad/s', minimum=-1000.0, maximum=1000.0),
    ParamSpec('command_timeout', 'double', 0.5,
              'Wall-clock time without a valid command after which the torque is set to '
              'zero (and reported); 0 disables', 's', minimum=0.0, maximum=3600.0),
    ParamSpec('timing_mode', 'string', 'real_time', 'How simulated time advances',
              choices=MODES),
    ParamSpec('real_time_factor', 'double', 1.0,
              'Simulated seconds per wall second in real_time mode', 'x', minimum=0.0,
              strict_min=True, maximum=1000.0),
    ParamSpec('pause_at', 'double', -1.0,
              'Simulated time at which the simulation pauses (state held, commands kept); '
              'set it later, or negative, to resume. Negative = never', 's', maximum=1e9),
    ParamSpec('velocity_limit', 'double', 1000.0,
              'Any joint speed above this counts as divergence: integration stops and the '
              'last good state is held until reset', 'rad/s', minimum=0.0, strict_min=True,
              read_only=True),
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
)


def _ns(seconds: float) -> int:
    return int(round(seconds * 1e9))


class SimulatorNode(Node):
    """See the module docstring."""

    def __init__(self) -> None:
        super().__init__('simulator')
        p = declare_parameters(self, ROBOT_PARAMS + SIM_PARAMS)
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
            model = make_model(p['model'], robot, geared)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        self.params = p
        self.n = model.n_dof
        limits = ([p['geared.effort_limit']] if self.n == 1 else robot['effort_limits'])
        q0, qd0 = self._initial_state(model, p['initial_positions'],
                                      p['initial_velocities'])
        self.core = SimulatorCore(model, q0=q0, qd0=qd0, effort_limits=limits,
                                  physics_step_ns=step_ns, control_period_ns=period_ns,
                                  velocity_limit=p['velocity_limit'],
                                  joint_names=robot['joint_names'])
        self.state_pub = self.create_publisher(JointState, 'joint_states', 10)
        self.clock_pub = self.create_publisher(Clock, 'clock', 10)
        self.create_subscription(Float64MultiArray, 'effort_controller/commands',
                                 self._on_command, 10)
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.diag = Diagnostics(self)
        self.commands = 0
        self.stale_commands = 0
        self.ever_commanded = False
        self.timed_out = False
        self.last_command_wall = time.monotonic()
        self.last_publish_wall = 0.0
        self.pending_answer = False  # lockstep: a command for the current state is held
        self.anchor: tuple[int, int] | None = None  # (wall ns, sim ns) for real-time pacing
        self.window = (time.monotonic(), 0)
        self.achieved_rtf = 0.0
        self.rt_timer = None
        self._make_rt_timer()
        self.create_timer(0.05, self._housekeeping, clock=steady_clock())
        on_parameter_changes(self, SIM_PARAMS, self._validate_change, self._apply_change)
        self.publish_state()
        self.get_logger().info(
            f"{p['model']} in {p['timing_mode']} mode: physics step {p['physics_step']:g} s, "
            f"publishing at {p['publish_rate']:g} Hz, q0={self.core.q.tolist()}")

    # ------------------------------------------------------------------ parameters
    def _initial_state(self, model, positions, velocities):
        if self.n == 1:
            n = model.gear_ratio
            return [positions[0] * n], [velocities[0] * n]
        if len(positions) != 2 or len(velocities) != 2:
            raise ConfigError('initial_positions and initial_velocities need 2 values each, '
                              f'got {list(positions)} and {list(velocities)}')
        return positions, velocities

    def _validate_change(self, changed: dict) -> str | None:
        for key in ('initial_positions', 'initial_velocities'):
            values = changed.get(key)
            if values is not None and not (len(values) == 2 or self.n == 1 and values):
                return f'{key} needs {max(self.n, 2)} values, got {list(values)}'
        return None

    def _apply_change(self, changed: dict) -> None:
        self.params.update(changed)
        if 'initial_positions' in changed or 'initial_velocities' in changed:
            q0, qd0 = self._initial_state(self.core.model, self.params['initial_positions'],
                                          self.params['initial_velocities'])
            self.core.q0[:], self.core.qd0[:] = q0, qd0
        if 'real_time_factor' in changed:
            self._make_rt_timer()
        if 'timing_mode' in changed or 'real_time_factor' in changed or 'pause_at' in changed:
            self.anchor = None
        if 'pause_at' in changed and not self.paused and self.pending_answer:
            self._lockstep_advance()
        self.get_logger().info(f'parameters changed: {changed}')

    def _make_rt_timer(self) -> None:
        if self.rt_timer is not None:
            self.destroy_timer(self.rt_timer)
        wall_period = self.core.period_ns * 1e-9 / self.params['real_time_factor']
        self.rt_timer = self.create_timer(max(wall_period, 1e-4), self._on_rt_tick,
                                          clock=steady_clock())

    # ------------------------------------------------------------------ stepping
    @property
    def mode(self) -> str:
        return self.params['timing_mode']

    def free_running(self) -> bool:
        return self.mode == 'as_fast_as_possible' and not self.paused

    def _real_time_paced(self) -> bool:
        return self.mode == 'real_time' or (self.mode == 'lockstep' and self.timed_out)

    @property
    def paused(self) -> bool:
        pause_at = self.params['pause_at']
        return pause_at >= 0 and self.core.time_ns >= round(pause_at * 1e9)

    def advance(self) -> bool:
        """One control period, unless paused; True if time moved."""
        if self.paused:
            return False
        was_diverged = self.core.diverged
        self.core.advance()
        if self.core.diverged and not was_diverged:
            self.diag.problem('diverged', self.core.diverged, 'ERROR')
        return True

    def _lockstep_advance(self) -> None:
        self.pending_answer = not self.advance()
        if not self.pending_answer:
            self.publish_state()

    def _on_rt_tick(self) -> None:
        if not self._real_time_paced():
            return
        now = time.monotonic_ns()
        if self.anchor is None:
            self.anchor = (now, self.core.time_ns)
        target = self.anchor[1] + (now - self.anchor[0]) * self.params['real_time_factor']
        period = self.core.period_ns
        moved = False
        for _ in range(5):
            if self.core.time_ns + period > target or not self.advance():
                break
            moved = True
        if self.paused:
            self.anchor = None
        elif self.core.time_ns + period <= target:
            behind = (target - self.core.time_ns) * 1e-9
            self.diag.problem('overrun', f'cannot keep up with real_time_factor '
                              f"{self.params['real_time_factor']:g}: {behind:.3f} s of "
                              f'simulated time behind; continuing from here (achieved '
                              f'{self.achieved_rtf:.2f}x)')
            self.anchor = (now, self.core.time_ns)
        if moved:
            self.publish_state()

    def step_free(self) -> None:
        """One control period in as_fast_as_possible mode."""
        if self.advance():
            self.publish_state()

    def _on_command(self, msg: Float64MultiArray) -> None:
        answers = parse_answer_tag(msg.layout.dim[0].label) if msg.layout.dim else None
        if (self.mode == 'lockstep' and answers is not None
                and answers != self.core.time_ns):
            # An answer to an older state (e.g. queued while a restarted controller caught
            # up): using it would leave two commands in flight and delay control for good.
            self.stale_commands += 1
            if self.timed_out:
                self.timed_out = False  # the controller is back: wait for its next answer
                self.get_logger().info('effort commands resumed (resynchronising lockstep)')
            return
        try:
            self.core.set_command(msg.data)
        except CommandError as exc:
            self.diag.problem('rejected_command', f'{exc}; keeping the last good command')
            return
        self.commands += 1
        self.ever_commanded = True
        self.last_command_wall = time.monotonic()
        if self.timed_out:
            self.timed_out = False
            self.get_logger().info('effort commands resumed')
        if self.mode == 'lockstep':
            self._lockstep_advance()

    def publish_state(self) -> None:
        view = self.core.joint_view()
        msg = JointState(name=list(view.names), position=view.position,
                         velocity=view.velocity, effort=view.effort)
        sec, nsec = divmod(self.core.time_ns, 1_000_000_000)
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nsec
        self.state_pub.publish(msg)
        clock = Clock()
        clock.clock = msg.header.stamp
        self.clock_pub.publish(clock)
        self.last_publish_wall = time.monotonic()

    def _housekeeping(self) -> None:
        now = time.monotonic()
        timeout = self.params['command_timeout']
        if self.paused:  # no commands are due while paused
            self.last_command_wall = now
        elif (timeout > 0 and self.ever_commanded and not self.timed_out
                and now - self.last_command_wall > timeout):
            self.timed_out = True
            self.anchor = None
            self.core.clear_command()
            self.diag.problem('command_timeout', f'no valid effort command for {timeout:g} s: '
                              'torque set to zero until commands return')
        if (self.mode == 'lockstep' and not self.timed_out and not self.paused
                and now - self.last_publish_wall > HEARTBEAT):
            self.publish_state()
        t0, s0 = self.window
        if now - t0 >= 1.0:
            self.achieved_rtf = (self.core.time_ns - s0) * 1e-9 / (now - t0)
            self.window = (now, self.core.time_ns)
            self._summarise()

    def _summarise(self) -> None:
        core = self.core
        if core.diverged:
            level, message = 'ERROR', core.diverged
        elif self.paused:
            level, message = 'OK', f'paused at t={core.time:.3f} s (pause_at)'
        elif self.timed_out:
            level, message = 'WARN', 'command timeout: applying zero torque'
        else:
            level, message = 'OK', f'running ({self.mode})'
        self.diag.set(level, message, sim_time=f'{core.time:.3f}', timing_mode=self.mode,
                      achieved_real_time_factor=f'{self.achieved_rtf:.2f}',
                      commands_received=self.commands,
                      stale_commands_ignored=self.stale_commands,
                      saturated_joints=[n for n, s in zip(core.joint_names, core.saturated)
                                        if s])

    def _on_reset(self, _request: Trigger.Request, response: Trigger.Response):
        self.core.reset()
        self.anchor = None
        self.publish_state()
        response.success = True
        response.message = (f'reset to q={self.core.q.tolist()} qd={self.core.qd.tolist()} '
                            f'at t={self.core.time:.3f} s')
        self.get_logger().info(response.message)
        return response


def _spin(executor, node: SimulatorNode, running) -> None:
    while running():
        if node.free_running():
            executor.spin_once(timeout_sec=0.0)
            node.step_free()
        else:
            executor.spin_once(timeout_sec=0.1)


def main(args: list[str] | None = None) -> int:
    return run_node(SimulatorNode, prog='simulator', summary=SUMMARY,
                    specs=ROBOT_PARAMS + SIM_PARAMS, args=args, spin=_spin)


if __name__ == '__main__':
    raise SystemExit(main())
