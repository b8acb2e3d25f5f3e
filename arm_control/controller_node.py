"""``controller`` node: joint-space control of the arm over ROS topics.

Thin shell around :class:`arm_control.core.ControllerCore`. In lockstep (``update_on:
joint_states``) each command names the state it answers (:func:`arm_dynamics.timing.
answer_tag`); a state that comes again (the simulator re-sends one that got no answer: the
command was lost, or published before the simulator had matched us) is answered again with
the very same command, never a recomputed one, so what happened meanwhile (a parameter or
trajectory change) cannot change the run.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointTrajectoryControllerState
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.node import Node
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from arm_common.gate import WAIT_FOR_NODES, SubscriberGate
from arm_common.node import (
    STREAM_DEPTH,
    ConfigError,
    Diagnostics,
    clock_in_namespace,
    declare_parameters,
    latched_qos,
    on_parameter_changes,
    run_node,
    steady_clock,
)
from arm_common.params import ParamSpec
from arm_common.stamps import stamp_refusal
from arm_control import follow
from arm_control.core import ControllerCore, Step
from arm_control.laws import GAINS, LAW_TABLE, LAWS, ControlLaw, Gains
from arm_control.model_params import CONTROL_MODEL_PARAMS, controller_model
from arm_control.trajectory import (
    StaleTrajectoryError,
    Trajectory,
    TrajectoryError,
    TrajectoryPoint,
)
from arm_dynamics.limits import JointLimits
from arm_dynamics.models import joint_count
from arm_dynamics.robot import ROBOT_PARAMS
from arm_dynamics.timing import answer_tag

SUMMARY = '''
Joint-space controller for the 2-R arm. Subscribes joint_states (sensor_msgs/JointState)
and arm_controller/joint_trajectory (trajectory_msgs/JointTrajectory, as ros2_controllers'
joint_trajectory_controller takes it: one point = set point; several = interpolated,
quintic/cubic/linear by what the points carry; header.stamp = start time, zero = on
arrival). Publishes effort_controller/commands (std_msgs/Float64MultiArray, N m) and
arm_controller/reference (JointState: desired position and velocity, commanded effort,
stamped like the state it answers) and arm_controller/trajectory_status
(diagnostic_msgs/DiagnosticStatus, transient local, depth 1: a late subscriber asking for
transient local gets the latest; OK "accepted" or WARN "refused: <reason>" for each
trajectory received, WARN "dropped: <reason>" when a time jump cuts the one in progress, with
keys at_ns and q = the state it holds from then on; key stamp_ns = its header stamp).
Until the first trajectory it holds the first measured position. Laws: pd, pd_gravity,
computed_torque, pid. Reports on /diagnostics (statuses "controller: summary" and one per
problem or event kind, e.g. "controller: trajectory_accepted").

A trajectory or a FollowJointTrajectory goal that arrives before the first joint state
waits for it and starts as if it had come just after it (refused after 5 s of wall time
without one: a new process may take a second to be matched with the simulator); what a goal
needs no state for (joint names, points, limits, tolerances) is answered at once, with the
same result code as later. When simulated time goes back or jumps (a restarted simulator,
a reset, a bag replay) the trajectory is dropped, the measured position held and the jump
reported; a restarted controller holds where the arm is.

Also serves arm_controller/follow_joint_trajectory (control_msgs/action/FollowJointTrajectory,
what MoveIt drives), as joint_trajectory_controller does: a goal's trajectory replaces the
current one; refused goals end at once with their result code (INVALID_JOINTS,
INVALID_GOAL, OLD_HEADER_TIMESTAMP) and the reason; path and goal tolerances (the goal's,
or where it leaves them 0 the constraints.* parameters) are checked on each joint state;
feedback (desired, actual, error) goes out with every command; a cancel, a violated
tolerance or a time jump holds the arm where it is; a trajectory on the topic preempts a
goal (aborted, with the reason) and a goal replaces a topic trajectory. Publishes
arm_controller/controller_state (control_msgs/msg/JointTrajectoryControllerState:
reference, feedback, error, output effort) with every command.
'''

EARLY_WAIT = 5.0  # s (wall): a trajectory received before any joint state waits this long

CONTROL_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec('law', 'string', 'computed_torque', 'Control law: ' + '; '.join(
        f'{law.name}: {law.formula}' for law in LAW_TABLE.values()), choices=LAWS),
) + tuple(
    ParamSpec(f'gains.{g.name}', 'doubles', list(g.default), g.description.capitalize(),
              g.unit, minimum=0.0, strict_min=g.positive, maximum=1e6, per_joint=True)
    for g in GAINS
) + (
    ParamSpec('update_on', 'string', 'joint_states',
              'When to compute a command: on every new joint state (use with the '
              "simulator's lockstep mode) or on a timer at control_rate",
              choices=('joint_states', 'timer'), read_only=True),
    ParamSpec('control_rate', 'double', 100.0, 'Command rate when update_on is timer', 'Hz',
              minimum=0.0, strict_min=True, maximum=10000.0, read_only=True),
    ParamSpec('state_timeout', 'double', 0.5,
              'Wall-clock age of the last joint state after which the controller stops '
              'commanding and reports (timer mode); commanding resumes with fresh states',
              's', minimum=0.0, strict_min=True, maximum=3600.0),
    ParamSpec('time_jump_threshold', 'double', 1.0,
              'A forward step of simulated time between two joint states longer than this '
              'is a time jump: the trajectory is dropped and the measured position held',
              's', minimum=0.0, strict_min=True, maximum=1e6, read_only=True),
    # FollowJointTrajectory defaults, as joint_trajectory_controller's constraints.* (there
    # constraints.<joint>.trajectory / .goal; here one list per kind, in joint order).
    ParamSpec('constraints.trajectory', 'doubles', [0.0, 0.0],
              'FollowJointTrajectory path tolerance: the largest |desired - measured| '
              "position of each joint while a goal's trajectory runs, beyond which the "
              'goal aborts (PATH_TOLERANCE_VIOLATED) and the arm holds; 0 = no check; used '
              "where a goal's path_tolerance leaves it 0",
              'rad', minimum=0.0, maximum=1e6, per_joint=True),
    ParamSpec('constraints.goal', 'doubles', [0.0, 0.0],
              'FollowJointTrajectory goal tolerance: the largest |final position - '
              'measured| of each joint for a goal to succeed once its trajectory has '
              "ended; 0 = no check; used where a goal's goal_tolerance leaves it 0",
              'rad', minimum=0.0, maximum=1e6, per_joint=True),
    ParamSpec('constraints.stopped_velocity_tolerance', 'double', 0.01,
              'FollowJointTrajectory: the largest joint speed at which a goal counts as '
              'reached (the goal velocity tolerance of each joint a goal leaves 0); '
              '0 = no check', 'rad/s', minimum=0.0, maximum=1e6),
    ParamSpec('constraints.goal_time', 'double', 0.0,
              "FollowJointTrajectory: how long after its trajectory's end a goal may take "
              'to come within the goal tolerance before it aborts '
              "(GOAL_TOLERANCE_VIOLATED) and the arm holds; 0 = no limit; used when a goal's "
              'goal_time_tolerance is 0', 's', minimum=0.0, maximum=1e6),
) + CONTROL_MODEL_PARAMS + (WAIT_FOR_NODES,)


def _stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def _stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def _seconds(d) -> float:
    """A builtin_interfaces Duration (or Time) in seconds."""
    return d.sec + d.nanosec * 1e-9


def _points(msg: JointTrajectory) -> list[TrajectoryPoint]:
    return [TrajectoryPoint(_seconds(p.time_from_start), p.positions, p.velocities,
                            p.accelerations) for p in msg.points]


def _duration(seconds: float) -> Duration:
    """``seconds`` >= 0 as a builtin_interfaces Duration (nanoseconds rounded)."""
    sec, nanosec = divmod(int(round(seconds * 1e9)), 1_000_000_000)
    return Duration(sec=sec, nanosec=nanosec)


def _tolerances(tols) -> list[follow.JointTolerance]:
    return [follow.JointTolerance(t.name, t.position, t.velocity, t.acceleration)
            for t in tols]


def _point(positions: np.ndarray, velocities: np.ndarray,
           accelerations: np.ndarray | None = None) -> JointTrajectoryPoint:
    point = JointTrajectoryPoint(positions=positions.tolist(),
                                 velocities=velocities.tolist())
    if accelerations is not None:
        point.accelerations = accelerations.tolist()
    return point


@dataclass
class _Waiting:
    """A goal that came before the first joint state: checked (everything that needs no
    state), then held until that state, when it starts exactly as if it had come just
    after it (:meth:`ControllerNode._start_waiting`); refused after :data:`EARLY_WAIT`."""

    handle: ServerGoalHandle
    started: Future  # set to the goal's end (a Future) or to (transition, Outcome)
    since: float  # s (wall) it came
    label: str


@dataclass
class _Goal:
    """The FollowJointTrajectory goal being executed."""

    handle: ServerGoalHandle
    done: Future  # set to (transition, follow.Outcome) when it ends
    monitor: follow.GoalMonitor
    trajectory: Trajectory  # its trajectory (the reference once it started)
    label: str  # short goal id for reports


_TRANSITION = {'succeed': 'succeed', 'abort': 'abort', 'cancel': 'canceled'}


def gains_from(p: dict) -> Gains:
    """The law's gains from the ``gains.*`` parameters (:data:`arm_control.laws.GAINS`)."""
    return Gains(**{g.name: p[f'gains.{g.name}'] for g in GAINS})


class ControllerNode(Node):
    """See SUMMARY."""

    def __init__(self) -> None:
        super().__init__('controller', cli_args=clock_in_namespace())
        p = declare_parameters(self, ROBOT_PARAMS + CONTROL_PARAMS, joints=joint_count)
        try:
            model = controller_model(p)
            law = ControlLaw(p['law'], gains_from(p), model, tuple(p['effort_limits']))
            limits = JointLimits.from_params(p)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        self.params = p
        self.core = ControllerCore(p['joint_names'], law,
                                   jump_threshold=p['time_jump_threshold'], limits=limits)
        self.cmd_pub = self.create_publisher(Float64MultiArray, 'effort_controller/commands',
                                             STREAM_DEPTH)
        self.ref_pub = self.create_publisher(JointState, 'arm_controller/reference',
                                             STREAM_DEPTH)
        # Latched: what became of the latest trajectory is the controller's state (what it
        # executes, or why not) for whoever looks later; each sender reads its own verdict
        # as it comes (one per trajectory received, seconds apart).
        self.status_pub = self.create_publisher(DiagnosticStatus,
                                                'arm_controller/trajectory_status',
                                                latched_qos())
        # Commands and references wait for wait_for_nodes (e.g. the recorder) to match them.
        self.gate = SubscriberGate(self, [self.cmd_pub, self.ref_pub], p['wait_for_nodes'])
        self.create_subscription(JointState, 'joint_states', self._on_state, 10)
        self.create_subscription(JointTrajectory, 'arm_controller/joint_trajectory',
                                 self._on_trajectory, 10)
        self.state_pub = self.create_publisher(JointTrajectoryControllerState,
                                               'arm_controller/controller_state',
                                               STREAM_DEPTH)
        self.goal: _Goal | None = None
        self.waiting: list[_Waiting] = []  # goals that came before the first state, in order
        self.follow_server: ActionServer | None = None
        # Goals are checked and answered in _control: a subclass that computes its own
        # updates (check_reference) executes none, so it does not offer the action.
        if type(self)._control is ControllerNode._control:
            # Every goal is accepted and answered with its result: a ROS 2 goal response
            # carries no code or reason, so a refused goal ends at once (aborted) with them.
            self.follow_server = ActionServer(
                self, FollowJointTrajectory, 'arm_controller/follow_joint_trajectory',
                execute_callback=self._execute_goal,
                goal_callback=lambda _request: GoalResponse.ACCEPT,
                cancel_callback=self._on_cancel)
        self.diag = Diagnostics(self, sim_time=lambda: self.core.last_time)
        self.latest: tuple[float, np.ndarray, np.ndarray] | None = None
        self.latest_wall = 0.0
        # lockstep: the last answer, re-sent verbatim if its state comes again, and whether
        # a simulator was matched when it went out
        self.answer: tuple[int, np.ndarray, Float64MultiArray, bool] | None = None
        self.resent = 0
        self.linked = False  # a state after one we answered came: the simulator hears us
        self.early: tuple[JointTrajectory, float] | None = None  # before any state (wall)
        self._orders: dict[tuple[str, ...], list[int]] = {}  # joint order per name list
        self.active_msg: JointTrajectory | None = None  # the accepted trajectory, if any
        self.stale = False
        self.saturations = 0
        if p['update_on'] == 'timer':
            self.create_timer(1.0 / p['control_rate'], self._on_timer, clock=steady_clock())
        self.create_timer(0.1, self._watch, clock=steady_clock())
        on_parameter_changes(self, CONTROL_PARAMS, self._validate_change, self._apply_change)
        self.get_logger().info(f"{p['law']} control, updating on {p['update_on']}")

    # ------------------------------------------------------------------ parameters
    def _validate_change(self, changed: dict) -> str | None:
        merged = {**self.params, **changed}
        n = len(self.core.joint_names)
        for spec in CONTROL_PARAMS:
            reason = (spec.joint_count_reason(changed[spec.name], n)
                      if spec.name in changed else None)
            if reason:
                return reason
        try:
            gains_from(merged)
        except ValueError as exc:
            return str(exc)
        return None

    def _apply_change(self, changed: dict) -> None:
        self.params.update(changed)
        law = self.core.law
        law.gains = gains_from(self.params)
        if law.law != self.params['law']:
            law.law = self.params['law']
            law.reset()
        self.get_logger().info(f'parameters changed: {changed}')

    def destroy_node(self) -> None:
        if self.follow_server is not None:  # not among the entities destroy_node frees
            self.follow_server.destroy()
            self.follow_server = None
        super().destroy_node()

    # ------------------------------------------------------------------ input
    def _on_state(self, msg: JointState) -> None:
        try:
            names = tuple(msg.name)
            order = self._orders.get(names)
            if order is None:  # once per name list: the same one every period
                order = [names.index(j) for j in self.core.joint_names]
                if len(self._orders) >= 8:  # name lists that keep changing: keep it bounded
                    self._orders.clear()
                self._orders[names] = order
            q = np.array([msg.position[i] for i in order], dtype=float)
            qd = (np.array([msg.velocity[i] for i in order], dtype=float) if msg.velocity
                  else np.zeros(len(order)))
        except (ValueError, IndexError):
            self.diag.problem('rejected_state', f'joint_states lacks joints '
                              f'{list(self.core.joint_names)} (got names {list(msg.name)}, '
                              f'{len(msg.position)} positions, {len(msg.velocity)} velocities)')
            return
        if not (np.isfinite(q).all() and np.isfinite(qd).all()):
            self.diag.problem('rejected_state', f'joint_states has non-finite values: '
                              f'q={q.tolist()} qd={qd.tolist()}')
            return
        bad_stamp = stamp_refusal(msg.header.stamp.sec, msg.header.stamp.nanosec)
        if bad_stamp:  # no simulated time: it would read as a jump (e.g. back to -5 s)
            self.diag.problem('rejected_state', f'joint_states refused: {bad_stamp}')
            return
        self.latest = (_stamp(msg), q, qd)
        self.latest_wall = time.monotonic()
        if self.stale:
            self.stale = False
            self.get_logger().info('fresh joint states: commanding again')
        if self.early is not None:
            traj, self.early = self.early[0], None
            self._on_trajectory(traj)
        if self.waiting:
            self._start_waiting()
        if self.params['update_on'] == 'joint_states':
            stamp_ns = _stamp_ns(msg)
            answer = self.answer
            if answer is not None and stamp_ns > answer[0]:
                self.linked = True
            if answer is not None and answer[0] == stamp_ns and np.array_equal(answer[1], q):
                self.resent += 1  # the same state again: its answer was lost or early
                self.cmd_pub.publish(answer[2])
                # Before the simulator ever took an answer of ours, a re-send is the
                # hand-shake of discovery (its subscription may match us after our publisher
                # matched it), not a loss.
                if answer[3] and self.linked:  # lost on the way
                    self.diag.problem('answer_resent', f'the state at t={self.latest[0]:.3f}'
                                      ' s came again (the simulator got no answer to it): '
                                      'the same command re-sent', resent_answers=self.resent)
                return
            self._control(stamp_ns)

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        if self.latest is None:
            # A controller that just started has no state yet: keep the trajectory until
            # the first one comes (refused after EARLY_WAIT, see _watch).
            self.early = (msg, time.monotonic())
            return
        t_now, q, qd = self.latest
        if self.active_msg is not None and _stamp_ns(msg) != 0 and msg == self.active_msg:
            # The very trajectory we execute, sent again (its sender did not read our
            # verdict in time): executed as it is, and the verdict said again.
            self._status(msg, DiagnosticStatus.OK, 'accepted: the same trajectory again, '
                         'executed as before', _stamp(msg))
            return
        start = _stamp(msg) or t_now
        try:
            traj = self.core.set_trajectory(msg.joint_names, _points(msg), start, q, qd,
                                            now=t_now)
        except TrajectoryError as exc:
            self._refuse(msg, f'{exc}; keeping the current reference', start_time=start,
                         stale=isinstance(exc, StaleTrajectoryError))
            return
        text = (f'{len(msg.points)} point(s) over {traj.duration:.3f} s from t={start:.3f} s')
        self.get_logger().info(f'new trajectory: {text}')
        self.diag.event('trajectory_accepted', text, start_time=f'{start:.9f}',
                        duration=f'{traj.duration:.9f}', points=len(msg.points))
        self._status(msg, DiagnosticStatus.OK, f'accepted: {text}', start)
        self.active_msg = msg
        if self.goal is not None:  # a topic trajectory preempts an action goal: it ends
            self._finish_goal(follow.Outcome(
                follow.INVALID_GOAL, f'preempted by a trajectory on '
                f'arm_controller/joint_trajectory: {text}'), 'abort')

    # ------------------------------------------------------------------ action
    async def _execute_goal(self, handle: ServerGoalHandle):
        """A goal from acceptance to result: started (or refused) at once, or, before the
        first joint state, checked and held until it (:class:`_Waiting`); then awaited
        without blocking the executor; _control, a cancel or a preempting trajectory ends
        it (:meth:`_finish_goal`)."""
        started = self._start_goal(handle)
        if isinstance(started, _Waiting):
            started = await started.started
        if isinstance(started, follow.Outcome):
            transition, outcome = 'abort', started
        elif isinstance(started, tuple):  # ended while it waited for the first state
            transition, outcome = started
        else:
            transition, outcome = await started
        if transition == 'cancel' and not handle.is_cancel_requested:
            transition = 'abort'  # (cannot happen: a cancel ends only the goal it names)
        getattr(handle, _TRANSITION[transition])()
        return FollowJointTrajectory.Result(error_code=outcome.code,
                                            error_string=outcome.text)

    def _goal_terms(self, handle: ServerGoalHandle) -> dict:
        """A goal's trajectory and tolerances as :mod:`arm_control.follow` takes them."""
        goal = handle.request
        p = self.params
        return dict(joint_names=goal.trajectory.joint_names, points=_points(goal.trajectory),
                    defaults=follow.default_tolerances(
                        p['constraints.trajectory'], p['constraints.goal'],
                        p['constraints.goal_time'],
                        p['constraints.stopped_velocity_tolerance']),
                    path=_tolerances(goal.path_tolerance),
                    goal=_tolerances(goal.goal_tolerance),
                    goal_time=_seconds(goal.goal_time_tolerance),
                    multi_dof_joints=list(goal.multi_dof_trajectory.joint_names))

    def _start_goal(self, handle: ServerGoalHandle) -> follow.Outcome | Future | _Waiting:
        """Make a goal's trajectory the reference (preempting the goal or topic trajectory
        in progress); returns the future of its end, the outcome of a refused goal, or,
        before the first joint state, the goal checked and held (:class:`_Waiting`)."""
        goal = handle.request
        label = bytes(handle.goal_id.uuid).hex()[:8]
        traj_msg = goal.trajectory
        terms = self._goal_terms(handle)
        try:
            if self.latest is None:
                # What needs no state is answered now, whatever the timing (an unknown
                # joint is INVALID_JOINTS before the first state as after it); the rest
                # waits for that state.
                follow.check_goal(self.core, **terms)
                waiting = _Waiting(handle, Future(), time.monotonic(), label)
                self.waiting.append(waiting)
                self.get_logger().info(f'goal {label} waits for the first joint state')
                return waiting
            t_now, q, qd = self.latest
            accepted = follow.accept_goal(self.core, stamp=_stamp(traj_msg), now=t_now, q=q,
                                          qd=qd, **terms)
        except follow.GoalError as exc:
            name = follow.CODE_NAMES[exc.code]
            self.diag.problem('rejected_goal', f'goal {label} refused ({name}): {exc}; '
                              'keeping the current reference', code=name)
            return follow.Outcome(exc.code, str(exc))
        if self.goal is not None:
            self._finish_goal(follow.Outcome(follow.INVALID_GOAL,
                                             f'preempted by goal {label}'), 'abort')
        self.active_msg = None  # a topic trajectory in progress is replaced too
        traj, start = accepted.trajectory, accepted.start
        monitor = follow.GoalMonitor(self.core.joint_names, accepted.tolerances, start,
                                     traj.duration)
        self.goal = _Goal(handle, Future(), monitor, traj, label)
        text = (f'goal {label}: {len(traj_msg.points)} point(s) over {traj.duration:.3f} s '
                f'from t={start:.3f} s')
        self.get_logger().info(f'new {text}')
        self.diag.event('goal_accepted', text, start_time=f'{start:.9f}',
                        duration=f'{traj.duration:.9f}', points=len(traj_msg.points))
        return self.goal.done

    def _start_waiting(self) -> None:
        """The first joint state came: start the goals that waited for it, in the order
        they came (a later one preempts an earlier one), before that state is answered."""
        waiting, self.waiting = self.waiting, []
        for w in waiting:
            w.started.set_result(self._start_goal(w.handle))

    def _end_waiting(self, waiting: _Waiting, transition: str,
                     outcome: follow.Outcome) -> None:
        """End a goal that is still waiting for the first joint state."""
        self.waiting.remove(waiting)
        name = follow.CODE_NAMES[outcome.code]
        if transition == 'abort':
            self.diag.problem('rejected_goal', f'goal {waiting.label} refused ({name}): '
                              f'{outcome.text}', code=name)
        else:
            self.get_logger().info(f'goal {waiting.label} canceled: {outcome.text}')
        waiting.started.set_result((transition, outcome))

    def _on_cancel(self, handle: ServerGoalHandle) -> CancelResponse:
        """Cancel the goal in progress: the arm holds the last measured position. A goal
        still waiting for the first joint state ends without moving anything."""
        for waiting in self.waiting:
            if waiting.handle is handle:
                self._end_waiting(waiting, 'cancel', follow.Outcome(
                    follow.SUCCESSFUL, 'canceled before the first joint state: nothing '
                    'moved'))
                return CancelResponse.ACCEPT
        goal = self.goal
        if goal is None or goal.handle is not handle:
            return CancelResponse.REJECT  # ended already (or never started)
        last = self.core.last or self.latest
        assert last is not None  # a goal starts only once a state came
        t, q, qd = last
        self.core.hold(t, q, qd)
        self._finish_goal(follow.Outcome(
            follow.SUCCESSFUL, f'canceled at t={t:.3f} s: holding {q.round(6).tolist()} rad'),
            'cancel')
        return CancelResponse.ACCEPT

    def _finish_goal(self, outcome: follow.Outcome, transition: str) -> None:
        """End the goal in progress (its execute coroutine sends the result)."""
        goal, self.goal = self.goal, None
        assert goal is not None
        kind = {'succeed': 'goal_succeeded', 'abort': 'goal_aborted',
                'cancel': 'goal_canceled'}[transition]
        name = follow.CODE_NAMES[outcome.code]
        text = f'goal {goal.label} {kind[5:]} ({name}): {outcome.text}'
        if transition == 'abort':
            self.diag.problem(kind, text, code=name)
        else:
            self.get_logger().info(text)
            self.diag.event(kind, text, code=name)
        goal.done.set_result((transition, outcome))

    def _status(self, msg: JointTrajectory, level: bytes, text: str,
                start: float | None, **values) -> None:
        """Say on arm_controller/trajectory_status what became of ``msg``: the topic
        interface has no reply of its own, and a sender must not take 'published' for
        'executed' (the planner re-sends until it reads one)."""
        status = DiagnosticStatus(level=level, name=self.get_fully_qualified_name(),
                                  message=text, hardware_id='arm_sim')
        status.values = [KeyValue(key='stamp_ns', value=str(_stamp_ns(msg))),
                         KeyValue(key='points', value=str(len(msg.points)))]
        if start is not None:
            status.values.append(KeyValue(key='start_time', value=f'{start:.9f}'))
        status.values += [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        self.status_pub.publish(status)

    def _refuse(self, msg: JointTrajectory, reason: str, start_time: float | None = None,
                stale: bool = False):
        extra: dict[str, Any] = ({} if start_time is None else
                                 {'start_time': f'{start_time:.9f}'})
        self.diag.problem('rejected_trajectory', f'trajectory refused: {reason}', **extra)
        self._status(msg, DiagnosticStatus.WARN, f'refused: {reason}', start_time,
                     stale=str(stale).lower())

    # ------------------------------------------------------------------ output
    def _on_timer(self) -> None:
        if self.latest is not None and not self.stale:
            self._control(None)

    def _control(self, stamp_ns: int | None) -> None:
        assert self.latest is not None  # called once a state has arrived
        if not self.gate.ready(self.diag, 'the first command'):
            return  # lockstep: the simulator re-sends the state; timer: the next tick
        t, q, qd = self.latest
        core = self.core
        moving = (self.active_msg is not None and core.last_time is not None
                  and core.trajectory is not None
                  and (core.next is not None
                       or core.last_time < core.start + core.trajectory.duration))
        step = core.update(t, q, qd)
        if step.jump:
            self.diag.problem('time_jump', f'{step.jump}: trajectory dropped, holding the '
                              f'measured position {q.round(4).tolist()} rad', q=q.tolist())
            if moving:  # a motion in progress: tell its sender, who may plan it again
                dropped, self.active_msg = self.active_msg, None
                self._status(dropped, DiagnosticStatus.WARN, f'dropped: {step.jump}', None,
                             at_ns=stamp_ns if stamp_ns is not None else int(round(t * 1e9)),
                             q=q.tolist())
        cmd = step.command
        out = Float64MultiArray(data=cmd.tau.tolist())
        if stamp_ns is not None:  # lockstep: name the state this command answers
            out.layout.dim = [MultiArrayDimension(label=answer_tag(stamp_ns),
                                                  size=len(out.data), stride=len(out.data))]
            # Was a simulator matched when it went out? (asked of the middleware only until
            # the simulator is known to hear us: not a call on every period's path)
            matched = self.linked or self.cmd_pub.get_subscription_count() > 0
            self.answer = (stamp_ns, q, out, matched)
        self.cmd_pub.publish(out)
        ref = JointState(name=list(self.core.joint_names), position=step.q_des.tolist(),
                         velocity=step.qd_des.tolist(), effort=cmd.tau.tolist())
        if stamp_ns is not None:
            ref.header.stamp.sec, ref.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        else:
            sec = int(t)
            ref.header.stamp.sec, ref.header.stamp.nanosec = sec, int(round((t - sec) * 1e9))
        self.ref_pub.publish(ref)
        if cmd.saturated.any():
            self.saturations += 1
            joints = [j for j, s in zip(self.core.joint_names, cmd.saturated) if s]
            self.diag.problem('saturation', f'torque saturated at the effort limits on '
                              f'{joints} (wanted {cmd.raw.round(2).tolist()} N m)', 'WARN',
                              joints=joints, wanted=cmd.raw.tolist())
        self._state_and_goal(step, t, q, qd, ref)

    def _state_and_goal(self, step: Step, t: float, q: np.ndarray, qd: np.ndarray,
                        ref: JointState) -> None:
        """controller_state, and the goal in progress (feedback, tolerances): built only
        for someone (about 40 us a period)."""
        watched = self.state_pub.get_subscription_count() > 0
        if not (watched or self.goal is not None):
            return
        desired = _point(step.q_des, step.qd_des, step.qdd_des)
        actual = _point(q, qd)
        error = _point(step.q_des - q, step.qd_des - qd)
        # As joint_trajectory_controller: the reference's (and so the error's)
        # time_from_start is how far into its trajectory the sample lies, the last point's
        # once it has ended (0 while a position is held).
        traj = self.core.trajectory
        into = 0.0 if traj is None else min(max(t - self.core.start, 0.0), traj.duration)
        desired.time_from_start = error.time_from_start = _duration(into)
        if watched:
            self.state_pub.publish(JointTrajectoryControllerState(
                header=ref.header, joint_names=ref.name, reference=desired,
                feedback=actual, error=error, output=JointTrajectoryPoint(effort=ref.effort),
                speed_scaling_factor=1.0))
        if self.goal is not None:
            self._follow(step, t, q, qd, FollowJointTrajectory.Feedback(
                header=ref.header, joint_names=ref.name, desired=desired, actual=actual,
                error=error))

    def _follow(self, step: Step, t: float, q: np.ndarray, qd: np.ndarray,
                feedback: FollowJointTrajectory.Feedback) -> None:
        """The goal in progress at the state (t, q, qd) its command ``step`` answered:
        feedback, then its tolerances checked once its trajectory is the reference."""
        goal = self.goal
        assert goal is not None
        if step.jump:
            self._finish_goal(follow.Outcome(
                follow.INVALID_GOAL, f'dropped: {step.jump}; holding the measured position '
                f'{q.round(6).tolist()} rad'), 'abort')
            return
        goal.handle.publish_feedback(feedback)
        if self.core.trajectory is not goal.trajectory:
            return  # it starts at a later state: the previous reference still answers
        outcome = goal.monitor.check(t, q, qd, step.q_des, step.qd_des)
        if outcome is None:
            return
        if not outcome.succeeded:  # as JTC: an aborted goal leaves the arm held where it is
            self.core.hold(t, q, qd)
        self._finish_goal(outcome, 'succeed' if outcome.succeeded else 'abort')

    def _watch(self) -> None:
        now = time.monotonic()
        if self.early is not None and now - self.early[1] > EARLY_WAIT:
            msg, self.early = self.early[0], None
            self._refuse(msg, f'no joint state within {EARLY_WAIT:g} s (wall) of it, so the '
                         'start of the motion is unknown')
        for waiting in [w for w in self.waiting if now - w.since > EARLY_WAIT]:
            self._end_waiting(waiting, 'abort', follow.Outcome(
                follow.INVALID_GOAL, f'no joint state within {EARLY_WAIT:g} s (wall) of '
                'the goal, so the start of the motion is unknown'))
        age = now - self.latest_wall
        if (self.params['update_on'] == 'timer' and self.latest is not None
                and not self.stale and age > self.params['state_timeout']):
            self.stale = True
            self.diag.problem('stale_state', f'no joint state for {age:.2f} s: stopped '
                              'commanding until fresh states arrive', age_wall=f'{age:.3f}')
        level = 'WARN' if self.stale or self.latest is None else 'OK'
        message = ('waiting for joint states' if self.latest is None else
                   'joint states stale' if self.stale else
                   f"{self.core.law.law} control")
        self.diag.set(level, message, law=self.core.law.law,
                      trajectories_accepted=self.core.trajectories_accepted,
                      holding_start=self.core.holding_start,
                      saturated_ticks=self.saturations, resent_answers=self.resent,
                      time_jumps=self.core.jumps,
                      goal='' if self.goal is None else self.goal.label)


def main(args: list[str] | None = None) -> int:
    return run_node(ControllerNode, prog='controller', summary=SUMMARY,
                    specs=ROBOT_PARAMS + CONTROL_PARAMS, args=args)


if __name__ == '__main__':
    raise SystemExit(main())
