"""``visualizer`` node: the arm as visualization markers, its ``robot_description`` and
its transforms.

Thin ROS shell around :func:`arm_sim.markers.arm_markers` and :class:`arm_sim.tf.FrameTree`:
``joint_states``, ``planner/path`` (transient local) and ``goal_pose`` in; ``markers``
(visualization_msgs/MarkerArray), ``robot_description`` (std_msgs/String, transient
local, depth 1, the URDF of :mod:`arm_dynamics.urdf`), ``tf`` and ``tf_static``
(tf2_msgs/TFMessage, as robot_state_publisher publishes them from that URDF) out. Markers
are sent at most ``rate`` times per wall-clock second and only when a message changed
something; what they show depends on the messages alone. ``tf`` goes out once per joint
state, stamped with it; ``tf_static`` once, at start.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, PoseStamped, TransformStamped
from nav_msgs.msg import Path
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import ColorRGBA, Header, String
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker, MarkerArray

from arm_common.gate import WAIT_FOR_NODES, SubscriberGate
from arm_common.node import (
    ConfigError,
    Diagnostics,
    clock_in_namespace,
    declare_parameters,
    latched_qos,
    run_node,
    steady_clock,
)
from arm_common.params import ParamSpec
from arm_dynamics.models import joint_count, robot_model
from arm_dynamics.robot import ROBOT_PARAMS
from arm_dynamics.urdf import urdf_from_params
from arm_sim.markers import MarkerShape, TipTrail, arm_markers
from arm_sim.tf import FrameTree, Transform

SUMMARY = '''
Draws the arm for RViz and Foxglove. Subscribes joint_states (sensor_msgs/JointState),
planner/path (nav_msgs/Path, transient local) and goal_pose (geometry_msgs/PoseStamped);
publishes markers (visualization_msgs/MarkerArray in frame_id, stamped with the joint
state's stamp; namespaces links (LINE_LIST), joints (SPHERE_LIST), tip (SPHERE), trail
(LINE_STRIP of the tip over the last trail_length s of simulated time), goal (SPHERE) and
path (LINE_STRIP of the planned path); an element with nothing to show is sent as DELETE).
Positions are the forward kinematics of the joint state. Markers go out at most rate
times per wall-clock second, and only after a message changed them; their content depends
on the messages only. Also publishes robot_description (std_msgs/String, transient local,
depth 1, as robot_state_publisher does): the URDF made from the robot parameters (the text
arm-sim urdf prints). With publish_tf, also publishes what robot_state_publisher would from
that URDF: tf (tf2_msgs/TFMessage), for each joint state, one transform per movable joint
(parent link -> child link: the joint's origin times the rotation about its axis by the
position), stamped with the joint state's stamp; and tf_static (transient local), once, the
fixed joints (link<n> -> tool0), stamped 0. Joint states with missing joints, mismatched
lengths or non-finite positions, and goals or paths in another frame or not finite, are
dropped with a throttled warning and a /diagnostics entry (rejected_joint_state,
rejected_goal, rejected_path).
'''

VISUALIZER_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec('frame_id', 'string', 'base_link',
              "Frame of the markers (the URDF's root); goals and paths must be in it (or "
              'have an empty frame_id)', read_only=True),
    ParamSpec('rate', 'double', 30.0, 'Largest marker publishing rate (wall clock)', 'Hz',
              minimum=0.0, strict_min=True, maximum=1000.0, read_only=True),
    ParamSpec('trail_length', 'double', 2.0,
              "How far back the tip's trail reaches, in simulated time (0: no trail)", 's',
              minimum=0.0, maximum=3600.0, read_only=True),
    ParamSpec('publish_robot_description', 'bool', True,
              'Publish robot_description (false when robot_state_publisher does)',
              read_only=True),
    ParamSpec('publish_tf', 'bool', True,
              'Publish tf (the movable joints, per joint state, with its stamp) and tf_static '
              '(the fixed joints, once, transient local) from the URDF, as '
              'robot_state_publisher does (false when it runs)', read_only=True),
    WAIT_FOR_NODES,
)

#: Marker type of each :data:`arm_sim.markers.SHAPES` entry.
MARKER_TYPES = {'line_list': Marker.LINE_LIST, 'line_strip': Marker.LINE_STRIP,
                'sphere': Marker.SPHERE, 'sphere_list': Marker.SPHERE_LIST}
TRAIL_MAX_POINTS = 10_000  # states kept for the trail, whatever its length
JOINT_STATE_DEPTH = 1000  # a lockstep burst must not cost the trail states
#: tf's queue: a lockstep burst of joint states (each its tf) must not cost the recorder
#: transforms (tf2_ros's TransformBroadcaster keeps 100); also how many wait for the gate.
TF_DEPTH = JOINT_STATE_DEPTH


def tf_qos() -> QoSProfile:
    """QoS of ``tf``, as tf2_ros's TransformBroadcaster (reliable, volatile), keeping the
    last :data:`TF_DEPTH`."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=TF_DEPTH,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def _colour(rgba) -> ColorRGBA:
    r, g, b, a = (float(c) for c in rgba)
    return ColorRGBA(r=r, g=g, b=b, a=a)


def marker_message(shape: MarkerShape, header: Header) -> Marker:
    """visualization_msgs/Marker of ``shape`` (id 0 in its namespace): ADD with its
    points (a sphere's centre as its pose), or DELETE when it is not visible."""
    msg = Marker(header=header, ns=shape.ns, id=0, type=MARKER_TYPES[shape.shape])
    msg.pose.orientation.w = 1.0
    if not shape.visible:
        msg.action = Marker.DELETE
        return msg
    msg.action = Marker.ADD
    msg.scale.x, msg.scale.y, msg.scale.z = (float(s) for s in shape.scale)
    msg.color = _colour(shape.colour)
    if shape.shape == 'sphere':
        x, y, z = (float(v) for v in shape.points[0])
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = x, y, z
    else:
        msg.points = [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in shape.points]
        if shape.colours is not None:
            msg.colors = [_colour(c) for c in shape.colours]
    return msg


def tf_message(transforms: list[Transform], stamp: Time) -> TFMessage:
    """tf2_msgs/TFMessage of ``transforms``, each stamped ``stamp``."""
    out = []
    for t in transforms:
        msg = TransformStamped(child_frame_id=t.child)
        msg.header.frame_id, msg.header.stamp = t.parent, stamp
        tr, rot = msg.transform.translation, msg.transform.rotation
        tr.x, tr.y, tr.z = t.translation
        rot.x, rot.y, rot.z, rot.w = t.rotation
        out.append(msg)
    return TFMessage(transforms=out)


def markers_message(shapes: tuple[MarkerShape, ...], header: Header) -> MarkerArray:
    """MarkerArray of ``shapes``, every marker with ``header``."""
    return MarkerArray(markers=[marker_message(s, header) for s in shapes])


class VisualizerNode(Node):
    """See the module docstring."""

    def __init__(self) -> None:
        super().__init__('visualizer', cli_args=clock_in_namespace())
        p = declare_parameters(self, ROBOT_PARAMS + VISUALIZER_PARAMS,
                               joints=joint_count)
        robot = {s.name: p[s.name] for s in ROBOT_PARAMS}
        try:
            self.arm = robot_model(robot)
            urdf = urdf_from_params(robot)
            self.tree = FrameTree(urdf)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        if not p['frame_id']:
            raise ConfigError('frame_id must not be empty')
        self.frame = p['frame_id']
        self.joint_names = list(p['joint_names'])
        self.trail = TipTrail(round(p['trail_length'] * 1e9), TRAIL_MAX_POINTS)
        self.q: np.ndarray | None = None
        self.stamp: Time | None = None  # of the latest joint state
        self.t_ns = 0
        self.goal: tuple[float, float] | None = None
        self.path: np.ndarray | None = None
        self.changed = False  # something to show since the last markers
        self.sent = 0
        self.markers_pub = self.create_publisher(MarkerArray, 'markers', 10)
        self.publish_tf = bool(p['publish_tf'])
        self.states = 0  # joint states taken
        self.tf_sent = 0
        self.tf_dropped = 0  # held transforms pushed out while the gate was shut
        self.tf_held: deque[TFMessage] = deque(maxlen=TF_DEPTH)  # while the gate is shut
        gated = [self.markers_pub]
        if self.publish_tf:
            # Relative names: /tf and /tf_static in the root namespace, as
            # robot_state_publisher's (the launch file remaps its /tf to tf).
            self.tf_pub = self.create_publisher(TFMessage, 'tf', tf_qos())
            gated.append(self.tf_pub)
            # Latched, once, as robot_state_publisher's fixed joints. Stamp 0: tf2 keeps
            # static transforms for all time, and a viewer that looks them up by stamp
            # (Foxglove) finds one at or before every state.
            self.tf_static_pub = self.create_publisher(TFMessage, 'tf_static', latched_qos())
            static = self.tree.static_transforms()
            if static:
                self.tf_static_pub.publish(tf_message(static, Time()))
        self.gate = SubscriberGate(self, gated, p['wait_for_nodes'])
        if p['publish_robot_description']:
            # Latched as robot_state_publisher does: a display started later gets it.
            self.description_pub = self.create_publisher(String, 'robot_description',
                                                         latched_qos())
            self.description_pub.publish(String(data=urdf))
        self.create_subscription(JointState, 'joint_states', self._on_joint_state,
                                 JOINT_STATE_DEPTH)
        self.create_subscription(Path, 'planner/path', self._on_path, latched_qos())
        self.create_subscription(PoseStamped, 'goal_pose', self._on_goal, 10)
        self.diag = Diagnostics(self, sim_time=lambda: None if self.q is None
                                else self.t_ns * 1e-9)
        self.diag.set('OK', 'waiting for joint_states', markers_sent=0)
        self.create_timer(1.0 / p['rate'], self._publish, clock=steady_clock())
        self.get_logger().info(f"visualizer ready: markers in {self.frame} at up to "
                               f"{p['rate']:g} Hz, trail {p['trail_length']:g} s"
                               + (', tf and tf_static' if self.publish_tf else ''))

    # ------------------------------------------------------------------ callbacks
    def _on_joint_state(self, msg: JointState) -> None:
        try:
            names = list(msg.name)
            missing = [j for j in self.joint_names if j not in names]
            if missing:
                self._reject('rejected_joint_state',
                             f'joint_states without joints {missing} (has {names})')
                return
            if len(msg.position) != len(names):
                self._reject('rejected_joint_state', f'joint_states has {len(msg.position)} '
                             f'positions for {len(names)} names')
                return
            q = np.array([msg.position[names.index(j)] for j in self.joint_names], float)
            if not np.isfinite(q).all():
                self._reject('rejected_joint_state',
                             f'joint_states has non-finite positions {q.tolist()}')
                return
            self.q, self.stamp = q, msg.header.stamp
            self.states += 1
            self.t_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            self.trail.add(self.t_ns, q)
            self.changed = True
            if self.publish_tf:
                tf = tf_message(self.tree.transforms(dict(zip(self.joint_names, q))),
                                msg.header.stamp)
                if self.gate.opened and not self.tf_held:
                    self.tf_pub.publish(tf)
                    self.tf_sent += 1
                else:  # sent when the gate opens (the timer), in order
                    if len(self.tf_held) == self.tf_held.maxlen:  # the oldest goes: counted
                        self.tf_dropped += 1
                        self.diag.problem('tf_dropped', f'{self.tf_dropped} transform(s) '
                                          'dropped while waiting for wait_for_nodes (at most '
                                          f'{self.tf_held.maxlen} are held)',
                                          tf_dropped=self.tf_dropped)
                    self.tf_held.append(tf)
            self._figures()
        except Exception as exc:  # never die on a message
            self.diag.problem('internal_error', f'joint_states handling failed: {exc!r}',
                              'ERROR')

    def _frame_ok(self, kind: str, what: str, frame: str) -> bool:
        if frame in ('', self.frame):
            return True
        self._reject(kind, f'{what} refused: frame_id {frame!r} is not {self.frame!r} (nor '
                     'empty); no transform is done')
        return False

    def _on_goal(self, msg: PoseStamped) -> None:
        try:
            if not self._frame_ok('rejected_goal', 'goal_pose', msg.header.frame_id):
                return
            goal = (float(msg.pose.position.x), float(msg.pose.position.y))
            if not np.isfinite(goal).all():
                self._reject('rejected_goal', f'goal_pose refused: non-finite position '
                             f'(x, y) = {list(goal)}')
                return
            self.goal = goal
            self.changed = True
        except Exception as exc:  # never die on a message
            self.diag.problem('internal_error', f'goal_pose handling failed: {exc!r}',
                              'ERROR')

    def _on_path(self, msg: Path) -> None:
        try:
            if not self._frame_ok('rejected_path', 'planner/path', msg.header.frame_id):
                return
            xy = np.array([[p.pose.position.x, p.pose.position.y] for p in msg.poses],
                          dtype=float).reshape(-1, 2)
            if not np.isfinite(xy).all():
                self._reject('rejected_path', f'planner/path refused: {len(xy)} poses, some '
                             'not finite')
                return
            self.path = xy
            self.changed = True
        except Exception as exc:  # never die on a message
            self.diag.problem('internal_error', f'planner/path handling failed: {exc!r}',
                              'ERROR')

    def _reject(self, kind: str, reason: str) -> None:
        self.diag.problem(kind, reason)

    # ------------------------------------------------------------------ output
    def _publish(self) -> None:
        """The wall-clock throttle: send the markers if a message changed them (and the
        transforms held while the gate was shut)."""
        if (not self.changed or self.q is None) and not self.tf_held:
            return
        if not self.gate.ready(self.diag, 'the first markers and transforms'):
            return
        while self.tf_held:
            self.tf_pub.publish(self.tf_held.popleft())
            self.tf_sent += 1
        if not self.changed or self.q is None:
            self._figures()
            return
        self.changed = False
        try:
            shapes = arm_markers(self.arm, self.q, self.trail.points(self.arm), self.goal,
                                 self.path)
        except ValueError as exc:  # inputs are checked on arrival: not expected
            self.diag.problem('internal_error', f'markers failed: {exc}', 'ERROR')
            return
        header = Header(frame_id=self.frame, stamp=self.stamp)
        self.markers_pub.publish(markers_message(shapes, header))
        self.sent += 1
        self._figures()

    def _figures(self) -> None:
        """The summary's figures, current with every state taken and every message sent
        (so a report whose ``sim_time`` is a state's stamp counts that state's transforms)."""
        self.diag.set('OK', 'showing the arm', states=self.states, markers_sent=self.sent,
                      trail_points=len(self.trail), tf_sent=self.tf_sent,
                      tf_held=len(self.tf_held), tf_dropped=self.tf_dropped)


def main(args: list[str] | None = None) -> int:
    return run_node(VisualizerNode, prog='visualizer', summary=SUMMARY,
                    specs=ROBOT_PARAMS + VISUALIZER_PARAMS, args=args)


if __name__ == '__main__':
    raise SystemExit(main())
