"""``live`` node: the suite's topics served to Foxglove over WebSocket (no ROS install).

Thin ROS shell around :class:`arm_sim.live.Bridge` (foxglove-sdk, setup.py extra
``foxglove``). It subscribes the suite's topics raw (the recorder's
:data:`~arm_bag.recorder_node.KNOWN_TOPICS`, ``markers`` and ``robot_description`` among them),
forwards each message's CDR bytes on its channel at its receive time on simulated time
(the latest ``clock``; the server also broadcasts that time, as foxglove_bridge does with
``use_sim_time``), and adds what Foxglove's 3D panel needs to draw the arm:

* ``/robot_description`` (``std_msgs/msg/String``, latched): the URDF made from the robot
  parameters (:mod:`arm_dynamics.urdf`), replaced by what a ROS publisher of
  ``robot_description`` sends, if any;
* ``/tf`` (``foxglove.FrameTransforms``): ``base_link -> link1 -> link2 -> tool0`` from
  each joint state, stamped with its header stamp (:func:`arm_sim.live.arm_transforms`).

Clients connect with either name of the protocol, ``foxglove.sdk.v1`` (Foxglove) or
``foxglove.websocket.v1`` (``@foxglove/ws-protocol``, Lichtblick, PlotJuggler): the
server's front (:mod:`arm_sim.live_front`) listens on ``host``:``port`` and relays to the
SDK's server on a loopback port of its own. A handshake it refuses (no subprotocol, or
neither of these) gets HTTP 400 with the reason and is reported (``refused_connection``,
naming what the client offered).

A client's ``goal_pose`` (PoseStamped, ``cdr`` or ``json``: Foxglove's "Publish pose") is
published into ROS on ``goal_pose``. Start it with ``arm-sim bringup --foxglove [PORT]`` or
``arm-sim demo --foxglove [PORT]``; it logs ``serving ws://HOST:PORT`` once clients can
connect. A port that cannot be bound is refused (exit 2).

No message takes it down: a ``clock`` or ``joint_states`` stamp that is negative, overflows
or has ``nanosec`` outside [0, 1e9), a joint state's frame id with a NUL character or
non-finite positions, and a client's goal with any of these (or non-finite numbers) are
refused, not forwarded: a throttled warning in the log, a status message to the clients
(for theirs) and a /diagnostics report (``live: rejected_clock``,
``rejected_joint_state``, ``rejected_goal``, ``refused_channel``). Anything else that fails
while handling a message is reported as ``internal_error``; the node keeps serving.
"""

from __future__ import annotations

import functools

from geometry_msgs.msg import PoseStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState

from arm_bag.msgdefs import MessageDefinitionError
from arm_bag.recorder_node import KNOWN_TOPICS, LATCHED, message_class
from arm_common.node import (
    ConfigError,
    Diagnostics,
    clock_in_namespace,
    declare_parameters,
    run_node,
    steady_clock,
)
from arm_common.params import ParamSpec
from arm_common.throttle import Throttle
from arm_dynamics.models import joint_count, robot_model
from arm_dynamics.robot import ROBOT_PARAMS
from arm_dynamics.urdf import urdf_from_params
from arm_sim.live import (
    DEFAULT_PORT,
    DESCRIPTION_TOPIC,
    FOXGLOVE_MISSING,
    GOAL_TOPIC,
    TF_TOPIC,
    Bridge,
    ClientMessage,
    ConnectionRefusal,
    arm_transforms,
    cdr_header,
    cdr_string,
    joint_positions,
    pose_from_json,
    pose_refusal,
    stamp_refusal,
    text_refusal,
)

SUMMARY = '''
Serves the suite's topics over the Foxglove WebSocket protocol (foxglove-sdk; subprotocol
foxglove.sdk.v1 or foxglove.websocket.v1, other handshakes refused with the reason): each topic
as a channel (cdr, ros2msg schema), raw CDR forwarded at its receive time on simulated time;
/robot_description (the URDF from the robot parameters) and /tf (foxglove.FrameTransforms
base_link -> link1 -> link2 -> tool0 from the joint states) for the 3D panel; a client's
goal_pose (Publish pose) is published into ROS. Connect Foxglove to ws://localhost:PORT.
Stamps that are negative, overflow or have nanosec outside [0, 1e9), frame ids with NUL and
non-finite numbers (on clock, joint_states or a client's goal) are refused with a throttled
warning and a /diagnostics report (rejected_clock, rejected_joint_state, rejected_goal); the
node keeps serving.
'''
LIVE_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec('port', 'int', DEFAULT_PORT, 'TCP port of the WebSocket server (0: a free one, '
              'logged)', minimum=0, maximum=65535, read_only=True),
    ParamSpec('host', 'string', '127.0.0.1', 'Address the server listens on (127.0.0.1: this '
              'machine only; 0.0.0.0: every interface). The SDK itself listens on a loopback '
              'port behind it', read_only=True),
)
POLL_PERIOD = 0.02  # s (wall): how often client messages and new subscriptions are handled
QUEUE_DEPTH = 100  # messages each subscription keeps


class LiveNode(Node):
    """See the module docstring."""

    def __init__(self) -> None:
        super().__init__('live', cli_args=clock_in_namespace())
        p = declare_parameters(self, ROBOT_PARAMS + LIVE_PARAMS, joints=joint_count)
        robot = {s.name: p[s.name] for s in ROBOT_PARAMS}
        try:
            urdf = urdf_from_params(robot)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        self.arm = robot_model(robot)
        self.joint_names = list(robot['joint_names'])
        self.goal_topic = self.resolve_topic_name(GOAL_TOPIC)
        try:
            self.bridge = Bridge(p['host'], p['port'], goal_topic=self.goal_topic)
        except ImportError:
            raise ConfigError(FOXGLOVE_MISSING) from None
        except OSError as exc:
            raise ConfigError(str(exc)) from None
        self.sim_ns = 0
        self.forwarded = 0
        self.goals_published = 0
        self.diag = Diagnostics(self, sim_time=lambda: self.sim_ns * 1e-9)
        self.diag.set('OK', f'serving {self.bridge.url}', url=self.bridge.url)
        self.status_throttle = Throttle(1.0)  # status messages to the clients, per kind
        self.tf_topic = self.resolve_topic_name(TF_TOPIC)
        self.description = self.resolve_topic_name(DESCRIPTION_TOPIC)
        self.states = self.resolve_topic_name('joint_states')
        self.clock = self.resolve_topic_name('clock')
        topics = KNOWN_TOPICS  # the recorder's: markers and robot_description included
        latched = {self.resolve_topic_name(t) for t in LATCHED}
        self.subs = []
        for rel, type_name in topics.items():
            name = self.resolve_topic_name(rel)
            try:
                cls = message_class(type_name)
                self.bridge.add_ros_channel(name, type_name, latched=name in latched)
            except (ImportError, AttributeError, MessageDefinitionError) as exc:
                self.get_logger().warn(f'not serving {name}: type {type_name} unavailable: '
                                       f'{exc}')
                continue
            qos = QoSProfile(depth=QUEUE_DEPTH, reliability=ReliabilityPolicy.RELIABLE,
                             durability=(DurabilityPolicy.TRANSIENT_LOCAL if name in latched
                                         else DurabilityPolicy.VOLATILE))
            self.subs.append(self.create_subscription(
                cls, name, functools.partial(self._on_message, topic=name), qos, raw=True))
        if self.description in self.bridge.channels:
            self.bridge.forward(self.description, cdr_string(urdf), 0)
        self.goals = self.create_publisher(PoseStamped, GOAL_TOPIC, 10)
        self.create_timer(POLL_PERIOD, self.poll, clock=steady_clock())
        self.get_logger().info(f'serving {self.bridge.url} (Foxglove WebSocket; '
                               f'{len(self.bridge.channels)} topics, {self.tf_topic}, client '
                               f'publishing on {self.goal_topic})')

    # ------------------------------------------------------------------ ROS -> clients
    def _on_message(self, data: bytes, *, topic: str) -> None:
        """Forward one raw message; ``clock`` and ``joint_states`` are read first (time,
        frames) and refused, not forwarded, when invalid. Never raises: a message cannot
        take the node down."""
        try:
            tfs: tuple | None = None
            if topic == self.clock and not self._on_clock(data):
                return
            if topic == self.states:
                tfs = self._state_transforms(data)
                if tfs is None:
                    return
            self.bridge.forward(topic, data, self.sim_ns)
            self.forwarded += 1
            if tfs:
                self.bridge.send_transforms(tfs[0], tfs[1], self.tf_topic)
        except Exception as exc:  # never die on a message (the SDK's own errors included)
            self.diag.problem('internal_error', f'{topic}: not forwarded, handling it failed: '
                              f'{exc!r}', 'ERROR', topic=topic)

    def _on_clock(self, data: bytes) -> bool:
        """Take the simulated time from a ``clock`` message; False (reported) if refused."""
        try:
            sec, nanosec, _ = cdr_header(data, frame=False)
        except ValueError as exc:
            self.diag.problem('rejected_clock', f'{self.clock} refused: not a Clock ({exc})')
            return False
        reason = stamp_refusal(sec, nanosec, 'clock')
        if reason:
            self.diag.problem('rejected_clock', f'{self.clock} refused: {reason}; simulated '
                              f'time stays at {self.sim_ns * 1e-9:.3f} s', sec=sec,
                              nanosec=nanosec)
            return False
        self.sim_ns = sec * 1_000_000_000 + nanosec
        self.bridge.broadcast_time(self.sim_ns)
        return True

    def _state_transforms(self, data: bytes) -> tuple | None:
        """Check a joint state; None (reported) if refused, else (transforms, stamp [ns])
        to send, or () for a state of other joints (forwarded, nothing to draw)."""
        try:
            sec, nanosec, frame = cdr_header(data)
            msg = deserialize_message(data, JointState)
        except Exception as exc:  # rclpy raises a bare error on a malformed message
            self.diag.problem('rejected_joint_state', f'{self.states} refused: not a '
                              f'JointState ({exc})')
            return None
        reason = (stamp_refusal(sec, nanosec, 'header.stamp')
                  or text_refusal(frame, 'header.frame_id'))
        if reason:
            self.diag.problem('rejected_joint_state', f'{self.states} refused: {reason}',
                              sec=sec, nanosec=nanosec)
            return None
        q = joint_positions(msg.name, msg.position, self.joint_names)
        if q is None:
            return ()
        try:
            tfs = arm_transforms(self.arm, q)
        except ValueError as exc:
            self.diag.problem('rejected_joint_state', f'{self.states} refused: {exc}')
            return None
        return tfs, sec * 1_000_000_000 + nanosec

    # ------------------------------------------------------------------ clients -> ROS
    def poll(self) -> None:
        """Latched topics to new subscribers; clients' goals into ROS. Never raises."""
        try:
            items = self.bridge.poll()
        except Exception as exc:  # the SDK's errors must not stop the node
            self.diag.problem('internal_error', f'polling the clients failed: {exc!r}',
                              'ERROR')
            return
        for item in items:
            try:
                if isinstance(item, ConnectionRefusal):  # no client to tell: log it
                    self.diag.problem('refused_connection', item.text)
                elif isinstance(item, str):
                    self._tell_clients('refused_channel', item)
                else:
                    self._publish(item)
            except Exception as exc:  # never die on what a client sent
                self.diag.problem('internal_error', f'a client message failed: {exc!r}',
                                  'ERROR')
        self.diag.set('OK', f'serving {self.bridge.url}', url=self.bridge.url,
                      forwarded=self.forwarded, goals_published=self.goals_published)

    def _publish(self, m: ClientMessage) -> None:
        if m.encoding == 'cdr':
            try:  # refuse what is no PoseStamped
                sec, nanosec, frame = cdr_header(m.data)
                msg = deserialize_message(m.data, PoseStamped)
            except Exception as exc:  # rclpy raises a bare RuntimeError-like error
                self._refuse(m, f'not a CDR PoseStamped: {exc}')
                return
            pt, o = msg.pose.position, msg.pose.orientation
            reason = pose_refusal(sec, nanosec, frame, (pt.x, pt.y, pt.z),
                                  (o.x, o.y, o.z, o.w))
            if reason:
                self._refuse(m, reason)
                return
            self.goals.publish(m.data)
        else:
            try:
                pose = pose_from_json(m.data)
            except ValueError as exc:
                self._refuse(m, str(exc))
                return
            msg = PoseStamped()
            msg.header.stamp.sec, msg.header.stamp.nanosec = pose.sec, pose.nanosec
            msg.header.frame_id = pose.frame_id
            pt, o = msg.pose.position, msg.pose.orientation
            pt.x, pt.y, pt.z = pose.position
            o.x, o.y, o.z, o.w = pose.orientation
            self.goals.publish(msg)
        self.goals_published += 1
        self.get_logger().info(f'client {m.client}: goal published on {self.goal_topic}')

    def _refuse(self, m: ClientMessage, reason: str) -> None:
        self._tell_clients('rejected_goal', f'client {m.client}: {m.topic} ({m.encoding}) '
                           f'refused: {reason}', client=m.client)

    def _tell_clients(self, kind: str, text: str, **values) -> None:
        """Report a client's refused input: log and /diagnostics (throttled, counted) and a
        status message to the clients (at most one a second per kind)."""
        self.diag.problem(kind, text, **values)
        if self.status_throttle.ready(kind):
            self.bridge.status(text)

    def destroy_node(self) -> None:
        bridge = getattr(self, 'bridge', None)
        if bridge is not None:
            bridge.stop()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node(LiveNode, prog='live', summary=SUMMARY, specs=ROBOT_PARAMS + LIVE_PARAMS,
                    args=args, executor_type=SingleThreadedExecutor)


if __name__ == '__main__':
    raise SystemExit(main())
