"""``planner`` node: goal poses in, torque-feasible joint trajectories out.

Thin ROS shell around :func:`arm_planner.planner.plan_goal`: ``goal_pose``
(geometry_msgs/PoseStamped) and ``joint_states`` in; ``arm_controller/joint_trajectory``
(trajectory_msgs/JointTrajectory) and ``planner/path`` (nav_msgs/Path) out; refusals on
``/diagnostics``. Every planner parameter can be changed at run time (validated); the robot
parameters are read-only.
"""

from __future__ import annotations

import json
import math
import time
from typing import Any

import numpy as np
from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from std_srvs.srv import SetBool
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from arm_common.gate import WAIT_FOR_NODES, SubscriberGate, unmatched
from arm_common.node import (
    SUMMARY_TASK,
    ConfigError,
    Diagnostics,
    clock_in_namespace,
    declare_parameters,
    latched_qos,
    on_parameter_changes,
    parse_status_name,
    run_node,
    steady_clock,
)
from arm_common.params import ParamSpec
from arm_dynamics.limits import JointLimits
from arm_dynamics.models import joint_count
from arm_dynamics.robot import ROBOT_PARAMS
from arm_dynamics.timing import parse_answer_tag
from arm_planner.excitation import SWEEPS
from arm_planner.kinematics import PlanningError
from arm_planner.planner import (
    ELBOW_CHOICES,
    FEASIBILITY,
    MAX_DURATION,
    MODES,
    PROFILES,
    REST_SPEED,
    Plan,
    PlannerSettings,
    make_arm,
    plan_goal,
)
from arm_planner.time_scaling import KINDS

SUMMARY = '''
Plans the arm's motion to each goal_pose (geometry_msgs/PoseStamped: x, y of the
end-effector target in the base frame; header.frame_id empty or base_frame; z and
orientation are ignored) from the latest joint_states, and publishes it on
arm_controller/joint_trajectory (trajectory_msgs/JointTrajectory, positions rad,
velocities rad/s, accelerations rad/s^2; header.stamp = the simulated time of the joint
state it was planned from, where the motion starts) and
planner/path (nav_msgs/Path of the end effector, frame base_frame, stamped like the
trajectory; transient local, depth 1: a display started later, e.g. RViz with durability
Transient Local, still gets the current plan's path).

mode regulation: the goal's joint angles as a set point, or a synchronized joint-space
profile (regulation_profile). mode straight_line: the end effector moves on the segment
from where it is to the goal. mode chirp: the goal's joint angles are the centre of a
frequency-response excitation (chirp.*): the arm is moved there first (synchronized, then
held 1 s) unless already at rest there, then a sine sweep chirp.f0 -> chirp.f1 of
chirp.amplitude runs, one point per chirp.period (arm-sim analyze --frf reads the run;
docs/frf.md). The predicted joint torques (inverse dynamics of the robot
parameters) are checked against effort_limits: too fast a plan is slowed down to the
fastest duration that fits (feasibility stretch) or refused (feasibility refuse).
Unreachable or near-singular goals, goals in another frame and non-finite goals are
refused on /diagnostics (one status per kind, e.g. "planner: goal_refused"); nothing is
published for them. A goal that comes before any joint state is held (waiting_for_state)
and planned from the first one; with none within 5 s (wall) it is refused
(goal_before_state). When
simulated time goes back or jumps during a planned motion (a restarted simulator, a reset),
the controller drops the motion, says so on arm_controller/trajectory_status with the state
it now holds, and the planner plans the goal again from that state (event replanned). A
trajectory is re-sent (up to 10 times, 1 s apart: one stamped with its state's time, e.g.
made at a hold, 3 times as it is, time still held; then, or when stamped 0, planned again
from the latest state) until the controller confirms it on
arm_controller/trajectory_status (every node that publishes there: arm-sim check's
reference node and a controller under test both take it; after 3 sends the confirmations
there are suffice); a refusal there, or no confirmation, is reported as
goal_refused_by_controller or goal_unsent.

Goals take effect at a simulated time that does not depend on how long planning took: on
each goal the planner first holds the simulator's time (its hold_service, std_srvs/SetBool,
default simulator/hold) at the current state, plans from exactly that state, and releases
the hold once the controller has confirmed (or refused) the trajectory, so the motion
starts at the state it was planned from. Without that service (another simulator, a real
arm) it plans from the latest joint state, as before; a plan from an arm at rest is then
stamped 0 (on arrival), so a short one is never refused as ended before it arrived.

While the simulator reports a fault on /diagnostics (runaway or diverged: the arm is held
frozen), every goal is refused naming the fault and the simulator's ~/reset.
'''

PLANNER_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec('mode', 'string', 'regulation', 'What a goal plans', choices=MODES),
    ParamSpec('elbow', 'string', 'keep',
              'Elbow branch of the goal configuration: up = q2 < 0, down = q2 > 0, keep = '
              "the current configuration's (a straight line cannot change it)",
              choices=ELBOW_CHOICES),
    ParamSpec('time_scaling', 'string', 'quintic',
              'Progress along the path over time (zero speed at both ends; quintic also '
              'zero acceleration)', choices=KINDS),
    ParamSpec('duration', 'double', 0.0,
              'Motion duration; 0 = the shortest within max_speed/max_acceleration '
              '(straight_line) or joint_max_velocity/joint_max_acceleration (synchronized)',
              's', minimum=0.0, maximum=MAX_DURATION),
    ParamSpec('max_speed', 'double', 0.5, 'Straight line: maximum end-effector speed', 'm/s',
              minimum=0.0, strict_min=True, maximum=100.0),
    ParamSpec('max_acceleration', 'double', 1.0,
              'Straight line: maximum end-effector acceleration', 'm/s^2', minimum=0.0,
              strict_min=True, maximum=1000.0),
    ParamSpec('joint_max_velocity', 'double', 1.5,
              'Synchronized regulation: maximum joint speed', 'rad/s', minimum=0.0,
              strict_min=True, maximum=1000.0),
    ParamSpec('joint_max_acceleration', 'double', 3.0,
              'Synchronized regulation: maximum joint acceleration', 'rad/s^2', minimum=0.0,
              strict_min=True, maximum=1e5),
    ParamSpec('regulation_profile', 'string', 'set_point',
              'Regulation: one point at the goal angles, or both joints moving together',
              choices=PROFILES),
    ParamSpec('feasibility', 'string', 'stretch',
              'A plan whose predicted torque exceeds effort_limits is slowed down to the '
              'fastest duration that fits (stretch) or refused (refuse)', choices=FEASIBILITY),
    ParamSpec('reach_margin', 'double', 0.01,
              'Goals must lie at least this far inside the reachable annulus '
              '|l1 - l2| <= r <= l1 + l2', 'm', minimum=0.0, maximum=100.0),
    ParamSpec('singularity_margin', 'double', 0.1,
              'Minimum |sin q2| at the goal and along a straight line', '', minimum=0.0,
              maximum=0.99),
    ParamSpec('chirp.amplitude', 'doubles', [0.001],
              'Mode chirp: peak deviation of each moved joint from the goal configuration, '
              'one value for all or one per joint (the planner refuses one whose torque '
              'up to chirp.f1 exceeds effort_limits, naming the largest that fits)', 'rad',
              minimum=0.0, strict_min=True, maximum=3.2),
    ParamSpec('chirp.f0', 'double', 0.05, 'Mode chirp: the sweep\'s start frequency', 'Hz',
              minimum=0.0, strict_min=True, maximum=1000.0),
    ParamSpec('chirp.f1', 'double', 17.0,
              'Mode chirp: the sweep\'s end frequency, above chirp.f0 and below the Nyquist '
              'rate of chirp.period', 'Hz', minimum=0.0, strict_min=True, maximum=1000.0),
    ParamSpec('chirp.duration', 'double', 40.0,
              'Mode chirp: the sweep\'s duration (a 5% fade in and out included); at least '
              'one period of chirp.f0', 's', minimum=0.0, strict_min=True, maximum=190.0),
    ParamSpec('chirp.sweep', 'string', 'log',
              'Mode chirp: log (equal time per octave) or linear frequency sweep',
              choices=SWEEPS),
    ParamSpec('chirp.joints', 'strings', [],
              'Mode chirp: the joints that move (names); empty = all', allow_empty=True),
    ParamSpec('chirp.period', 'double', 0.01,
              'Mode chirp: one trajectory point every this (the control period: the '
              "simulator's 1 / publish_rate), so the reference is the chirp at each state",
              's', minimum=0.0, strict_min=True, maximum=1.0),
    ParamSpec('base_frame', 'string', 'base_link',
              'Frame of goals (an empty frame_id means this one) and of planner/path'),
    ParamSpec('hold_service', 'string', 'simulator/hold',
              "The simulator's hold service (std_srvs/SetBool), relative to the "
              "planner's namespace: simulated time is held at the current state while a goal "
              'is planned and confirmed, so it starts exactly there; empty = never hold. '
              "Its node (simulator) is the one whose faults on /diagnostics refuse goals",
              read_only=True, allow_empty=True),
    WAIT_FOR_NODES,
)

#: The simulator's fault statuses (arm_dynamics.simulator_node: the tasks of a runaway and
#: of a diverged integration, and the prefixes of its ERROR summary while faulted).
FAULT_TASKS = ('runaway', 'diverged')
FAULT_SUMMARIES = ('runaway', 'integration diverged')


def settings_from(params: dict[str, Any]) -> PlannerSettings:
    """The pure planner's settings from node parameter values."""
    params = {k.replace('.', '_'): v for k, v in params.items()}
    names = [f for f in PlannerSettings.__dataclass_fields__ if f in params]
    values: dict[str, Any] = {n: (float(params[n]) if isinstance(params[n], int)
                                  and not isinstance(params[n], bool) else params[n])
                              for n in names}
    if 'chirp_amplitude' in values:
        values['chirp_amplitude'] = tuple(float(a) for a in values['chirp_amplitude'])
    if 'chirp_joints' in values:  # names -> indices (ValueError naming an unknown one)
        joints = list(params.get('joint_names', ()))
        unknown = [j for j in values['chirp_joints'] if j not in joints]
        if unknown:
            raise ValueError(f'chirp.joints {unknown} are not joints of this arm ({joints})')
        values['chirp_joints'] = tuple(joints.index(j) for j in values['chirp_joints'])
    return PlannerSettings(**values)


def _level(level: bytes | int) -> int:
    """A DiagnosticStatus level (a byte in Python messages) as an int."""
    return level if isinstance(level, int) else level[0]


def _duration(seconds: float) -> Duration:
    sec = int(math.floor(seconds))
    nanosec = int(round((seconds - sec) * 1e9))
    if nanosec >= 1_000_000_000:
        sec, nanosec = sec + 1, nanosec - 1_000_000_000
    return Duration(sec=sec, nanosec=nanosec)


def trajectory_message(plan: Plan, joint_names, start_ns: int = 0) -> JointTrajectory:
    """JointTrajectory of ``plan`` starting at simulated time ``start_ns`` [ns] (its
    header.stamp; 0 = on arrival)."""
    msg = JointTrajectory(joint_names=list(joint_names))
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(start_ns, 1_000_000_000)
    for t, q, qd, qdd in zip(plan.times, plan.q, plan.qd, plan.qdd):
        msg.points.append(JointTrajectoryPoint(
            positions=q.tolist(), velocities=qd.tolist(), accelerations=qdd.tolist(),
            time_from_start=_duration(float(t))))
    return msg


def path_message(plan: Plan, frame: str, stamp) -> Path:
    """nav_msgs/Path of the planned end-effector path in ``frame``, stamped like its
    trajectory. Each pose is stamped with the simulated time its path starts: the
    trajectory's, or for a line after a stop (the arm was moving) the line's own start,
    ``plan.stop_duration`` later, so that a reader measures the line from there."""
    msg = Path()
    msg.header.frame_id = frame
    msg.header.stamp = stamp
    ns = stamp.sec * 1_000_000_000 + stamp.nanosec
    if plan.profile == 'line' and plan.stop_duration > 0.0 and ns:
        ns += round(plan.stop_duration * 1e9)
    sec, nanosec = divmod(ns, 1_000_000_000)
    pose_header = Header(frame_id=frame, stamp=Time(sec=sec, nanosec=nanosec))
    for x, y in plan.display_path:
        pose = PoseStamped()
        pose.header = pose_header
        pose.pose.position.x, pose.pose.position.y = float(x), float(y)
        pose.pose.orientation.w = 1.0
        msg.poses.append(pose)
    return msg


FIRST_STATE = 'first joint state at'  # logged once (arm-sim bringup waits on it)
HOLD_WAIT = 2.0  # s (wall): a hold reply later than this: plan without it
CONTROLLER_WAIT = 5.0  # s (wall): how long a plan waits for a controller to subscribe
STATE_WAIT = 5.0  # s (wall): how long a goal waits for the first joint state
CONFIRM_WAIT = 1.0  # s (wall): re-send a trajectory no controller confirmed after this
#: Sends of the very same trajectory, time held, to a controller that gives verdicts
#: before it is planned again with time running: a loaded machine delayed the verdict
#: 1-2 s; a controller restarted meanwhile has no state while time is held, so it can
#: only take the trajectory once time runs again.
SAME_SENDS = 3
SENDS = 10  # at most this many sends of one trajectory (10 s: a controller restarted on
# a loaded machine took over 5 s to start and confirm)

class PlannerNode(Node):
    """See the module docstring."""

    def __init__(self) -> None:
        super().__init__('planner', cli_args=clock_in_namespace())
        p = declare_parameters(self, ROBOT_PARAMS + PLANNER_PARAMS, joints=joint_count)
        try:
            self.arm = make_arm(p)
            self.joint_limits = JointLimits.from_params(p)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        reason = self._validate(p)
        if reason:
            raise ConfigError(reason)
        self.params = p
        self.joint_names = list(p['joint_names'])
        self.limits = np.array(p['effort_limits'], dtype=float)
        self.q: np.ndarray | None = None
        self.qd: np.ndarray | None = None  # measured velocities (None: not given: at rest)
        self.t_ns = 0  # simulated time of self.q
        # the last trajectory a controller accepted: (its stamp ns, goal xy)
        self.active: tuple[int, tuple[float, float]] | None = None
        self.plans = 0
        self.traj_pub = self.create_publisher(JointTrajectory,
                                              'arm_controller/joint_trajectory', 10)
        # Latched: the current plan's path, for a display (RViz) that comes up later.
        self.path_pub = self.create_publisher(Path, 'planner/path', latched_qos())
        # A trajectory goes out once wait_for_nodes subscribe it (e.g. arm-sim check's
        # reference node) and every subscription the graph lists is matched.
        self.gate = SubscriberGate(self, [self.traj_pub], p['wait_for_nodes'])
        self.create_subscription(JointState, 'joint_states', self._on_joint_state, 10)
        self.create_subscription(PoseStamped, 'goal_pose', self._on_goal, 10)
        self.status_topic = self.resolve_topic_name('arm_controller/trajectory_status')
        self.create_subscription(DiagnosticStatus, 'arm_controller/trajectory_status',
                                 self._on_trajectory_status, 10)
        self.sent: dict | None = None  # the last trajectory, until a controller confirms it
        self.diag = Diagnostics(self, sim_time=lambda: None if self.q is None
                                else self.t_ns * 1e-9)
        self.diag.set('OK', 'waiting for joint_states', plans=0)
        self.pending: tuple | None = None  # (plan, wall deadline) awaiting a controller
        # A goal that came before the first joint state, and its wall deadline.
        self.held_goal: tuple[tuple[float, float], float] | None = None
        # Holding the simulator's time while a goal is planned (see SUMMARY).
        self.hold_client = (self.create_client(SetBool, p['hold_service'])
                            if p['hold_service'] else None)
        self.holding = False  # we hold the simulator's time
        self.held_ns: int | None = None  # ... at the state of this stamp (its reply said)
        # The simulator whose faults refuse goals: the node of the hold service, else the
        # one named simulator in our namespace; its fault (the reason), while it lasts.
        hold = self.resolve_service_name(p['hold_service']) if p['hold_service'] else ''
        self.simulator = (hold.rsplit('/', 1)[0] if hold.endswith('/hold') else
                          f"{self.get_namespace().rstrip('/')}/simulator")
        self.fault: str | None = None
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 10)
        # The goal whose hold reply is awaited: (goal, its number, wall deadline).
        self.hold_wait: tuple[tuple[float, float], int, float] | None = None
        self.goals = 0
        # A goal waiting for the held state: (goal, its stamp ns, wall deadline).
        self.awaiting: tuple[tuple[float, float], int, float] | None = None
        self.create_timer(0.02, self._send_pending, clock=steady_clock())
        on_parameter_changes(self, PLANNER_PARAMS, self._validate_change, self._apply_change)
        self.get_logger().info(f"planner ready: mode {p['mode']}, effort limits "
                               f'{self.limits.tolist()} N m, base frame {p["base_frame"]}')

    # ------------------------------------------------------------------ parameters
    def _validate(self, params: dict[str, Any]) -> str | None:
        lengths = params['link_lengths']
        if len(lengths) == 2:
            widest = min(lengths)  # half the annulus width: a margin beyond it leaves nothing
            if params['reach_margin'] >= widest:
                return (f"reach_margin {params['reach_margin']:g} m leaves no reachable goal: "
                        f'it must be < min(l1, l2) = {widest:g} m')
        elif params['reach_margin'] >= sum(lengths):
            return (f"reach_margin {params['reach_margin']:g} m leaves no reachable goal: it "
                    f'must be < the sum of the link lengths = {sum(lengths):g} m')
        return None

    def _validate_change(self, changed: dict[str, Any]) -> str | None:
        return self._validate({**self.params, **changed})

    def _apply_change(self, changed: dict[str, Any]) -> None:
        self.params.update(changed)
        self.get_logger().info(f'parameters changed: {changed}')

    # ------------------------------------------------------------------ callbacks
    def _on_joint_state(self, msg: JointState) -> None:
        try:
            names = list(msg.name)
            missing = [j for j in self.joint_names if j not in names]
            if missing:
                self.diag.problem('rejected_joint_state',
                                  f'joint_states without joints {missing} (has {names})')
                return
            if len(msg.position) != len(names):
                self.diag.problem('rejected_joint_state',
                                  f'joint_states has {len(msg.position)} positions for '
                                  f'{len(names)} names')
                return
            q = np.array([msg.position[names.index(j)] for j in self.joint_names], float)
            if not np.isfinite(q).all():
                self.diag.problem('rejected_joint_state',
                                  f'joint_states has non-finite positions {q.tolist()}')
                return
            qd = None
            if len(msg.velocity) == len(names):
                qd = np.array([msg.velocity[names.index(j)] for j in self.joint_names], float)
                if not np.isfinite(qd).all():
                    self.diag.problem('rejected_joint_state', f'joint_states has non-finite '
                                      f'velocities {qd.tolist()}')
                    return
            if self.q is None:
                self.diag.set('OK', 'ready: waiting for goal_pose')
                self.get_logger().info(f'{FIRST_STATE} t={msg.header.stamp.sec}.'
                                       f'{msg.header.stamp.nanosec:09d} s')
            self.q, self.qd = q, qd
            self.t_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            if self.held_goal is not None:  # a goal waited for this first state
                goal, self.held_goal = self.held_goal[0], None
                self._plan(goal, sends=0)
            if self.awaiting is not None and self.t_ns == self.awaiting[1]:
                goal, self.awaiting = self.awaiting[0], None  # the held state: plan from it
                self._plan(goal, sends=0)
        except Exception as exc:  # never die on a message
            self.diag.problem('internal_error', f'joint_states handling failed: {exc!r}',
                              'ERROR')

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        """Follow the simulator's fault: a runaway or diverged integration holds the arm
        frozen until its ``~/reset``, so goals are refused until then, naming it. Set by the
        fault's report (or an ERROR summary naming it), cleared by the reset's report (or
        a summary that no longer does); the simulator updates its summary at both."""
        try:
            for status in msg.status:
                named = parse_status_name(status.name)
                if named is None or named[0] != self.simulator:
                    continue
                task = named[1]
                event = any(kv.key == 'event' for kv in status.values)
                error = _level(status.level) == _level(DiagnosticStatus.ERROR)
                if task in FAULT_TASKS and event and error:
                    self.fault = status.message
                elif task == 'reset' and event:
                    self.fault = None
                elif task == SUMMARY_TASK:
                    faulted = error and status.message.startswith(FAULT_SUMMARIES)
                    self.fault = status.message if faulted else None
        except Exception as exc:  # never die on a message
            self.diag.problem('internal_error', f'/diagnostics handling failed: {exc!r}',
                              'ERROR')

    def _refuse_for_fault(self, goal: tuple[float, float]) -> bool:
        """Refuse ``goal`` (True) while the simulator reports a fault, naming it and the
        way out: nothing can move the frozen arm until the simulator's ~/reset."""
        if self.fault is None:
            return False
        reset = f'{self.simulator}/reset'
        self.diag.problem('goal_refused', f'goal_pose refused: the simulator reports a fault '
                          f'and holds the arm frozen: {self.fault}. Reset it first: its '
                          f'~/reset service (ros2 service call {reset} std_srvs/srv/Trigger)',
                          goal_x=goal[0], goal_y=goal[1])
        return True

    def _on_goal(self, msg: PoseStamped) -> None:
        try:
            self._handle_goal(msg)
        except Exception as exc:  # never die on a message
            self.diag.problem('internal_error', f'planning failed unexpectedly: {exc!r}',
                              'ERROR')

    def _handle_goal(self, msg: PoseStamped) -> None:
        base = self.params['base_frame']
        frame = msg.header.frame_id
        if frame not in ('', base):
            self.diag.problem('goal_wrong_frame', f'goal_pose refused: frame_id {frame!r} is '
                              f'not the base frame {base!r} (nor empty); no transform is done')
            return
        goal = np.array([msg.pose.position.x, msg.pose.position.y], dtype=float)
        if not np.isfinite(goal).all():
            self.diag.problem('goal_not_finite', f'goal_pose refused: non-finite position '
                              f'(x, y) = {goal.tolist()}', goal_x=goal[0], goal_y=goal[1])
            return
        target = (float(goal[0]), float(goal[1]))
        if self._refuse_for_fault(target):
            return
        if self.q is None:  # e.g. sent right after start-up: plan it from the first state
            self.held_goal = (target, time.monotonic() + STATE_WAIT)
            self.diag.problem('waiting_for_state', 'goal_pose held: no joint_states received '
                              f'yet; planned from the first one (refused after {STATE_WAIT:g} '
                              's without)', goal_x=target[0], goal_y=target[1])
            return
        self.goals += 1
        if self.hold_client is not None and self.hold_client.service_is_ready():
            # Hold time at the current state first; plan from that state once it is here.
            self.hold_wait = (target, self.goals, time.monotonic() + HOLD_WAIT)
            future = self.hold_client.call_async(SetBool.Request(data=True))
            future.add_done_callback(
                lambda f, goal=target, n=self.goals: self._on_held(f, goal, n))
            return
        self._plan(target, sends=0)

    def _on_held(self, future, goal: tuple[float, float], n: int) -> None:
        """The simulator holds its time at the state its reply names: plan ``goal`` from
        exactly that state (now, or when it arrives)."""
        try:
            reply = future.result()
            held = parse_answer_tag(reply.message) if reply is not None else None
            if self.hold_wait is None or self.hold_wait[1] != n:
                # A newer goal came meanwhile (it plans instead), or the reply came too late
                # (planned without it): we hold all the same, released once idle.
                self.holding = self.holding or held is not None
                return
            self.hold_wait = None
            if held is None:
                self.diag.problem('hold_failed', f'the simulator did not hold its time '
                                  f'({reply!r}): goal planned from the latest state')
                self._plan(goal, sends=0)
                return
            self.holding, self.held_ns = True, held
            if self.t_ns == held:
                self._plan(goal, sends=0)
            else:  # its state is still on the way to us
                self.awaiting = (goal, held, time.monotonic() + STATE_WAIT)
        except Exception as exc:  # never die on a reply
            self.diag.problem('internal_error', f'hold reply handling failed: {exc!r}',
                              'ERROR')

    def _release(self) -> None:
        """Let the simulator's time move on again (if we hold it)."""
        if self.holding and self.hold_client is not None:
            self.holding, self.held_ns = False, None
            self.hold_client.call_async(SetBool.Request(data=False))

    def _release_if_idle(self) -> None:
        """Release the hold once nothing of a goal is in flight any more (planned, sent
        and confirmed or refused, or given up)."""
        if self.holding and self.pending is None and self.sent is None \
                and self.awaiting is None and self.hold_wait is None:
            self._release()

    def _plan(self, goal: tuple[float, float], sends: int,
              start: tuple[np.ndarray, int] | None = None) -> None:
        """Plan ``goal`` from ``start`` = (q [rad], the stamp to give the trajectory [ns]:
        where it starts, 0 = on arrival; held there, so at rest), by default the latest
        joint state (position and velocity: a moving arm is brought to rest first) and its
        time, and queue it for sending (``sends`` = how often this goal's trajectory went
        out already)."""
        q, qd, t_ns = (start[0], None, start[1]) if start is not None else (
            self.q, self.qd, self.t_ns)
        if self._refuse_for_fault(goal):
            return
        at_rest = qd is None or bool((np.abs(qd) < REST_SPEED).all())
        if start is None and at_rest and not (self.holding and self.held_ns == t_ns):
            # Time runs on while we plan (no hold: none offered, it failed, or a re-send):
            # stamped with the state's time, a plan shorter than the planning took would
            # reach the controller already ended ("ends in the past"), a goal at the arm's
            # own position (a set point, 0 s) always. The arm is at rest and held where it
            # is, so the motion may start whenever it arrives: stamped 0, "on arrival".
            t_ns = 0
        try:
            plan = plan_goal(self.arm, self.limits, q, np.array(goal),
                             settings_from(self.params), self.joint_limits, qd_current=qd)
        except (PlanningError, ValueError) as exc:
            self.diag.problem('goal_refused', f'goal_pose refused: {exc}', goal_x=goal[0],
                              goal_y=goal[1])
            return
        self.pending = (plan, time.monotonic() + CONTROLLER_WAIT, t_ns, goal, sends)
        self._send_pending()

    def _on_trajectory_status(self, status: DiagnosticStatus) -> None:
        """The controller's word on a trajectory: the one we sent is settled, or the one
        it was executing was dropped by a time jump (then it is planned again from the
        state the controller holds)."""
        values = {kv.key: kv.value for kv in status.values}
        if status.message.startswith('dropped'):
            self._replan_dropped(values, status.message)
            return
        sent = self.sent
        if sent is None or values.get('stamp_ns') != str(sent['stamp']):
            return
        if _level(status.level) == 0:
            # Every node that gives verdicts must have taken it (arm-sim check runs its
            # reference node beside a controller that also takes trajectories): one that
            # matched late is sent it again while time is held. After SAME_SENDS the
            # verdicts there are are enough (a controller that died may still be counted).
            sent['accepted'][status.name] = (values, status.message)
            if len(sent['accepted']) < self.count_publishers(self.status_topic):
                return
            self._accept(sent)
            return
        self.sent = None
        self._release_if_idle()  # refused: time may move on
        self.active = None
        goal = sent['goal']
        if values.get('stale') == 'true' and sent['sends'] < SENDS and self.q is not None:
            # Planned from a state the (lockstep) simulation has since left behind while
            # the trajectory found its controller: plan it again from the latest state.
            self.get_logger().info(f'the controller {status.message}: planning {goal} again '
                                   'from the latest state')
            self._plan(goal, sends=sent['sends'])
            return
        self.diag.problem('goal_refused_by_controller', f'goal ({goal[0]:.4f}, '
                          f'{goal[1]:.4f}) m: the controller {status.message}',
                          goal_x=goal[0], goal_y=goal[1])

    def _accept(self, sent: dict[str, Any]) -> None:
        """The trajectory ``sent`` is taken: time may move on; it is the one in progress."""
        self.sent = None
        self._release_if_idle()
        self.active = (sent['stamp'], sent['goal'])
        values, message = next(iter(sent['accepted'].values()))
        # Where the controller started it (a plan stamped 0 starts on arrival).
        start = values.get('start_time') or f"{sent['stamp'] * 1e-9:.9f}"
        self.diag.event('plan_accepted', f'controller: {message}', start_time=start,
                        verdicts=len(sent['accepted']))

    def _replan_dropped(self, values: dict[str, str], message: str) -> None:
        active = self.active
        if active is None or values.get('stamp_ns') != str(active[0]):
            return  # not ours, or not the one in progress
        self.active = None
        try:
            q = np.array(json.loads(values['q']), dtype=float).reshape(len(self.joint_names))
            at_ns = int(values['at_ns'])
        except (KeyError, ValueError, TypeError) as exc:
            self.diag.problem('goal_interrupted', f'goal ({active[1][0]:.4f}, '
                              f'{active[1][1]:.4f}) m interrupted ({message}) and the '
                              f'controller did not say where it holds the arm ({exc!r}): send '
                              'it again', goal_x=active[1][0], goal_y=active[1][1])
            return
        goal = active[1]
        self.diag.event('replanned', f'goal ({goal[0]:.4f}, {goal[1]:.4f}) m planned again '
                        f'from q = {q.round(4).tolist()} rad, held since t = '
                        f'{at_ns * 1e-9:.3f} s: the controller {message}',
                        goal_x=goal[0], goal_y=goal[1])
        # Stamped zero (start on arrival): the controller holds exactly that q until the
        # plan comes, so it starts where the arm is, whenever it arrives.
        self._plan(goal, sends=0, start=(q, 0))

    def _confirm_sent(self) -> None:
        """Send the goal again until a controller confirms its trajectory: a publish can
        reach no live controller (one that just restarted and is not matched yet, while one
        that left still counts as a subscriber). A plan stamped with its state's time (made
        at a hold, or from a moving arm) goes again as it is (time still held, if it is) up
        to :data:`SAME_SENDS` sends, whether or not the graph lists a trajectory_status
        publisher yet: a controller's verdict publisher can be discovered after its
        trajectory subscription (its first verdict then lost), and taking it for one that
        gives none re-planned the goal with time running. After that, or for a plan stamped
        0, it is planned again from the latest state (time may have moved on meanwhile); at a
        standstill that is the same plan."""
        sent = self.sent
        if sent is None or time.monotonic() - sent['at'] < CONFIRM_WAIT:
            return
        if sent['accepted'] and sent['sends'] >= SAME_SENDS:
            self._accept(sent)  # taken by some, and the rest did not answer
            return
        if sent['sends'] >= SENDS:
            self.sent = None
            self.active = None
            goal = sent['goal']
            self.diag.problem('goal_unsent', f'goal ({goal[0]:.4f}, {goal[1]:.4f}) m dropped: '
                              f"no controller confirmed its trajectory in {sent['sends']} "
                              f'sends, {CONFIRM_WAIT:g} s apart', goal_x=goal[0], goal_y=goal[1])
            return
        if sent['stamp'] != 0 and sent['sends'] < SAME_SENDS:
            # The controller may only be slow to answer (a loaded machine), or its verdicts
            # may not reach us yet (its status publisher not discovered: none listed is no
            # proof it gives none). The very same trajectory again (time still held, when
            # made at a hold): how long the answer took cannot change the run.
            sent['sends'] += 1
            sent['at'] = time.monotonic()
            self.traj_pub.publish(sent['msg'])
            self.get_logger().info(f"no verdict on the trajectory to {sent['goal']} in "
                                   f'{CONFIRM_WAIT:g} s: the same trajectory sent again (send '
                                   f"{sent['sends']} of {SENDS})")
            return
        self.sent = None
        # A controller that does not confirm (not arm_sim's) must not keep time held:
        # the goal is sent again, planned from the latest state, with time moving.
        self._release()
        self.get_logger().info(f"no controller confirmed the trajectory to {sent['goal']} in "
                               f'{CONFIRM_WAIT:g} s: planning it again from the latest state '
                               f"(send {sent['sends'] + 1} of {SENDS})")
        self._plan(sent['goal'], sends=sent['sends'])

    def _unmatched(self) -> list[str]:
        """What a trajectory published now would miss: wait_for_nodes not subscribed yet,
        subscriptions the graph lists but the publisher has not matched (a volatile message
        reaches only matched readers)."""
        if not self.gate.ready(self.diag, 'the first trajectory'):
            return self.gate.missing()
        gap = unmatched(self, self.traj_pub)
        return [gap] if gap else []

    def _send_pending(self) -> None:
        """Publish the pending plan once a controller is matched: a trajectory published
        before the controller's subscription matches is lost (volatile QoS)."""
        self._confirm_sent()
        if self.awaiting is not None and time.monotonic() > self.awaiting[2]:
            goal, stamp_ns, _ = self.awaiting
            self.awaiting = None
            self.diag.problem('goal_before_state', f'goal_pose refused: the held state at '
                              f't={stamp_ns * 1e-9:.3f} s did not reach the planner in '
                              f'{STATE_WAIT:g} s', goal_x=goal[0], goal_y=goal[1])
        if self.hold_wait is not None and time.monotonic() > self.hold_wait[2]:
            goal, self.hold_wait = self.hold_wait[0], None
            self.diag.problem('hold_failed', f'no reply from the hold service in {HOLD_WAIT:g} '
                              's (wall): goal planned from the latest state, time running',
                              goal_x=goal[0], goal_y=goal[1])
            self._plan(goal, sends=0)
        self._release_if_idle()
        if self.held_goal is not None and time.monotonic() > self.held_goal[1]:
            goal, self.held_goal = self.held_goal[0], None
            self.diag.problem('goal_before_state', 'goal_pose refused: no joint_states received '
                              f'in {STATE_WAIT:g} s, so the start of the motion is unknown',
                              goal_x=goal[0], goal_y=goal[1])
        if self.pending is None:
            return
        plan, deadline, start_ns, goal, sends = self.pending
        matched = self.traj_pub.get_subscription_count()
        missing = self._unmatched()
        if matched == 0 or missing:
            if time.monotonic() <= deadline:
                return
            if matched == 0:
                self.pending = None
                self.diag.problem('goal_unsent', 'goal_pose dropped: no controller subscribed '
                                  f'to arm_controller/joint_trajectory for {CONTROLLER_WAIT:g} s')
                return
            self.get_logger().warning(f'trajectory sent after {CONTROLLER_WAIT:g} s without '
                                      f'{", ".join(missing)}')
        self.pending = None
        msg = trajectory_message(plan, self.joint_names, start_ns)
        self.traj_pub.publish(msg)
        self.sent = {'stamp': start_ns, 'at': time.monotonic(), 'sends': sends + 1,
                     'goal': goal, 'msg': msg, 'accepted': {}}
        sec, nanosec = divmod(start_ns, 1_000_000_000)
        self.path_pub.publish(path_message(plan, self.params['base_frame'],
                                           Time(sec=sec, nanosec=nanosec)))
        self.plans += 1
        line = plan.summary(self.limits)
        self.get_logger().info(line)
        self.diag.set('OK', f'last plan: {line}', plans=self.plans,
                      last_plan_messages=' | '.join(plan.messages))
        self.diag.event('plan_sent', line, start_time=f'{start_ns * 1e-9:.9f}',
                        duration=f'{float(plan.times[-1]):.9f}', goal_x=goal[0], goal_y=goal[1])


def main(args: list[str] | None = None) -> int:
    return run_node(PlannerNode, prog='planner', summary=SUMMARY,
                    specs=ROBOT_PARAMS + PLANNER_PARAMS, args=args)


if __name__ == '__main__':
    raise SystemExit(main())
