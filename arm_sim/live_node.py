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

Clients may publish into ROS on the topics of :data:`arm_sim.live.CLIENT_CHANNELS`
(``cdr`` or ``json``), each resolved in the node's namespace as its publisher's: a
``goal_pose`` (PoseStamped: Foxglove's "Publish pose") on ``goal_pose``, and a tip push on
``simulator/push`` (WrenchStamped: Foxglove's Publish panel; the simulator holds force x, y
[N] for its ``push_duration``). Each published one is logged (``client 1: push published on
/simulator/push: wrench.force (0, -30, 0) N``) and counted on /diagnostics
(``goals_published``, ``pushes_published``). Start it with ``arm-sim bringup --foxglove
[PORT]`` or ``arm-sim demo --foxglove [PORT]``; it logs ``serving ws://HOST:PORT`` once clients can
connect. A port that cannot be bound is refused (exit 2).

No message takes it down: a ``clock`` or ``joint_states`` stamp that is negative, overflows
or has ``nanosec`` outside [0, 1e9), a joint state's frame id with a NUL character or
non-finite positions, and a client's goal with any of these (or non-finite numbers) are
refused, not forwarded: a throttled warning in the log, a status message to the clients
(for theirs) and a /diagnostics report (``live: rejected_clock``,
``rejected_joint_state``, ``rejected_goal``, ``refused_channel``); so is a client's push
with any of these or a force or torque component beyond 1e6 (``rejected_push``). Anything
else that fails while handling a message is reported as ``internal_error``; the node keeps
serving.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

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
    CLIENT_CHANNELS,
    DEFAULT_PORT,
    DESCRIPTION_TOPIC,
    FOXGLOVE_MISSING,
    TF_TOPIC,
    Bridge,
    ClientChannel,
    ClientMessage,
    ConnectionRefusal,
    arm_transforms,
    cdr_header,
    cdr_string,
    joint_positions,
    stamp_refusal,
    text_refusal,
)

SUMMARY = '''
Serves the suite's topics over the Foxglove WebSocket protocol (foxglove-sdk; subprotocol
foxglove.sdk.v1 or foxglove.websocket.v1, other handshakes refused with the reason): each topic
as a channel (cdr, ros2msg schema), raw CDR forwarded at its receive time on simulated time;
/robot_description (the URDF from the robot parameters) and /tf (foxglove.FrameTransforms
base_link -> link1 -> link2 -> tool0 from the joint states) for the 3D panel; a client's
goal_pose (Publish pose) and simulator/push (a WrenchStamped tip push, Publish panel) are
published into ROS. Connect Foxglove to ws://localhost:PORT.
Stamps that are negative, overflow or have nanosec outside [0, 1e9), frame ids with NUL and
non-finite numbers (on clock, joint_states or a client's goal or push; a push's components
beyond 1e6) are refused with a throttled warning and a /diagnostics report (rejected_clock,
rejected_joint_state, rejected_goal, rejected_push); the node keeps serving.
'''
LIVE_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec('port', 'int', DEFAULT_PORT, 'TCP port of the WebSocket server (0: a free one, '
              'logged)', minimum=0, maximum=65535, read_only=True),
    ParamSpec('host', 'string', '127.0.0.1', 'Address the server listens on (127.0.0.1: this '
              'machine only; 0.0.0.0: every interface). The SDK itself listens on a loopback '
              'port behind it', read_only=True),
)


@dataclass
class Outlet:
    """A client channel's way into ROS: its row, its message class, the node's publisher on
    the resolved ``topic`` and how many it published."""

    channel: ClientChannel
    topic: str
    cls: Any
    publisher: Any
    published: int = 0


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
        # Clients' topics into ROS (arm_sim.live.CLIENT_CHANNELS), resolved as publishers'.
        self.outlets: dict[str, Outlet] = {}
        for row in CLIENT_CHANNELS:
            name = self.resolve_topic_name(row.topic)
            try:
                cls = message_class(row.type_name)
            except (ImportError, AttributeError) as exc:
                raise ConfigError(f'cannot publish {name}: type {row.type_name} '
                                  f'unavailable: {exc}') from None
            self.outlets[name] = Outlet(row, name, cls, None)
        try:
            self.bridge = Bridge(p['host'], p['port'], client_topics={
                name: o.channel.type_name for name, o in self.outlets.items()})
        except ImportError:
            raise ConfigError(FOXGLOVE_MISSING) from None
        except OSError as exc:
            raise ConfigError(str(exc)) from None
        self.sim_ns = 0
        self.forwarded = 0
        self.diag = Diagnostics(self, sim_time=lambda: self.sim_ns * 1e-9)
        self.diag.set('OK', f'serving {self.bridge.url}', url=self.bridge.url)
        self.status_throttle = Throttle(1.0)  # status messages to the clients, per kind
        self.tf_topic = self.resolve_topic_name(TF_TOPIC)
        self.description = self.resolve_topic_name(DESCRIPTION_TOPIC)
        self.states = self.resolve_topic_name('joint_states')
        self.clock = self.resolve_topic_name('clock')
        # The recorder's topics (markers and robot_description included), but not ROS's
        # tf/tf_static: this node sends the frames itself, as foxglove.FrameTransforms on
        # /tf (from each joint state), so the 3D panel gets each transform once.
        topics = {t: ty for t, ty in KNOWN_TOPICS.items() if t not in ('tf', 'tf_static')}
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
        for o in self.outlets.values():
            o.publisher = self.create_publisher(o.cls, o.channel.topic, 10)
        self.create_timer(POLL_PERIOD, self.poll, clock=steady_clock())
        self.get_logger().info(f'serving {self.bridge.url} (Foxglove WebSocket; '
                               f'{len(self.bridge.channels)} topics, {self.tf_topic}, client '
                               f'publishing on {", ".join(self.outlets)})')

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
        """Latched topics to new subscribers; clients' goals and pushes into ROS. Never
        raises."""
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
                      forwarded=self.forwarded,
                      **{o.channel.counter: o.published for o in self.outlets.values()})

    def _publish(self, m: ClientMessage) -> None:
        """Publish a client's message into ROS on its channel's topic, checked first
        (:meth:`ClientChannel.refusal`): a refused one is reported, not published."""
        o = self.outlets[m.ros_topic]
        row = o.channel
        if m.encoding == 'cdr':
            try:  # refuse what is no message of the type
                sec, nanosec, frame = cdr_header(m.data)
                msg = deserialize_message(m.data, o.cls)
            except Exception as exc:  # rclpy raises a bare RuntimeError-like error
                self._refuse(m, row, f'not a CDR {row.short_type}: {exc}')
                return
            vectors = row.read(msg)
            reason = row.refusal(sec, nanosec, frame, vectors)
            if reason:
                self._refuse(m, row, reason)
                return
            o.publisher.publish(m.data)
        else:
            try:
                value = row.from_json(m.data)
            except ValueError as exc:
                self._refuse(m, row, str(exc))
                return
            vectors = value.vectors
            o.publisher.publish(row.fill(o.cls(), value))
        o.published += 1
        detail = row.describe(vectors)
        self.get_logger().info(f'client {m.client}: {row.kind} published on {o.topic}'
                               + (f': {detail}' if detail else ''))

    def _refuse(self, m: ClientMessage, row: ClientChannel, reason: str) -> None:
        self._tell_clients(row.rejected, f'client {m.client}: {m.topic} ({m.encoding}) '
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
