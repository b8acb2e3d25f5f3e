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
  each joint state, stamped with its header stamp (:func:`arm_sim.live.arm_transforms`);
* ``/tf_static`` (``tf2_msgs/msg/TFMessage``, latched: sent again to each client that
  subscribes): what robot_state_publisher puts there for the URDF served on
  ``/robot_description``, one transform per fixed joint (the suite's arms: ``link<n> ->
  tool0``, ``(l_n, 0, 0)``, identity rotation), stamped 0 as the visualizer's
  (:class:`arm_sim.tf.FrameTree`); sent again when a ROS publisher's ``robot_description``
  changes them (one that is no URDF keeps the last ones: ``unreadable_robot_description``).
  A URDF without fixed joints gives an empty TFMessage, so the channel is always there.

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

As foxglove_bridge does, it also serves ``/rosout`` (``rcl_interfaces/msg/Log``), every
node's parameters (``/<node>.<parameter>``: get and set through each node's parameter
services, asked asynchronously and answered from :meth:`LiveNode.poll`, so the executor never
waits; a set the node refuses is reported to the clients with its reason, ``live:
refused_parameter``; changes from ``/parameter_events`` go to the clients that subscribe),
every ROS service of the graph (``/simulator/reset``, ``/simulator/hold``, ...; called
asynchronously, the response returned, a failure reported with its reason, ``live:
failed_service_call``) and the connection graph (read every second of wall time, sent when
it changed, while a client subscribes to it).

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
import importlib
import json
import time
from collections import defaultdict
from collections.abc import Generator, Sequence
from dataclasses import dataclass
from typing import Any

from builtin_interfaces.msg import Time
from rcl_interfaces.msg import Parameter, ParameterEvent, ParameterValue
from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import String

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
    PARAM_TIMEOUT,
    ROSOUT_TOPIC,
    ROSOUT_TYPE,
    SERVICE_TIMEOUT,
    TF_STATIC_TOPIC,
    TF_STATIC_TYPE,
    TF_TOPIC,
    Bridge,
    ClientChannel,
    ClientMessage,
    ConnectionRefusal,
    ParamGet,
    ParamSet,
    ParamValue,
    Request,
    RosParam,
    ServiceCall,
    arm_transforms,
    build_graph,
    cdr_header,
    cdr_string,
    fill_message,
    fill_value_msg,
    joint_positions,
    message_to_json,
    node_name,
    param_name,
    ros_param_from_msg,
    ros_value,
    split_param_name,
    stamp_refusal,
    text_refusal,
)
from arm_sim.tf import FrameTree, Transform
from arm_sim.visualizer_node import tf_message

SUMMARY = '''
Serves the suite's topics over the Foxglove WebSocket protocol (foxglove-sdk; subprotocol
foxglove.sdk.v1 or foxglove.websocket.v1, other handshakes refused with the reason): each topic
as a channel (cdr, ros2msg schema), raw CDR forwarded at its receive time on simulated time;
/robot_description (the URDF from the robot parameters), /tf (foxglove.FrameTransforms
base_link -> link1 -> link2 -> tool0 from the joint states) and /tf_static
(tf2_msgs/TFMessage, latched: the URDF's fixed joints, link<n> -> tool0, as
robot_state_publisher publishes them) for the 3D panel; a client's
goal_pose (Publish pose) and simulator/push (a WrenchStamped tip push, Publish panel) are
published into ROS; /rosout, every node's parameters (/<node>.<parameter>, get and set),
every ROS service (e.g. /simulator/reset) and the connection graph, as foxglove_bridge offers
them. Connect Foxglove to ws://localhost:PORT.
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
GRAPH_PERIOD = 1.0  # s (wall): how often the ROS graph is read (services, connection graph)
#: What the node leaves a parameter request [s, wall]: within the client's wait.
PARAM_BUDGET = 0.8 * PARAM_TIMEOUT
SERVICE_BUDGET = 0.8 * SERVICE_TIMEOUT


class Call:
    """One asynchronous ROS service call, driven from :meth:`LiveNode.poll` (never waited
    on): sent once the service is there, given up at ``deadline`` (monotonic [s])."""

    def __init__(self, client: Any, request: Any, deadline: float, what: str) -> None:
        self.client, self.request, self.deadline, self.what = client, request, deadline, what
        self.future: Any = None
        self.result: Any = None
        self.error: str | None = None
        self.finished = False

    def step(self) -> bool:
        """Advance; True once answered or failed (:attr:`result` or :attr:`error`)."""
        if self.finished:
            return True
        now = time.monotonic()
        if self.future is None:
            if self.client.service_is_ready():
                self.future = self.client.call_async(self.request)
            elif now > self.deadline:
                return self._end(error=f'{self.what}: the service is not available')
            else:
                return False
        if self.future.done():
            exc = self.future.exception()
            if exc is not None:
                return self._end(error=f'{self.what}: {exc}')
            return self._end(result=self.future.result())
        if now > self.deadline:
            self.client.remove_pending_request(self.future)
            return self._end(error=f'{self.what}: no answer in time')
        return False

    def _end(self, result: Any = None, error: str | None = None) -> bool:
        self.result, self.error, self.finished = result, error, True
        return True


def _wait(calls: Sequence[Call]) -> Generator[None, None, None]:
    """Yield (to the next poll) until every call is finished."""
    while not all([c.step() for c in calls]):  # a list: every call steps
        yield


def service_class(type_name: str) -> Any:
    """The rclpy service class of ``pkg/srv/Type``."""
    pkg, kind, name = type_name.split('/')
    return getattr(importlib.import_module(f'{pkg}.{kind}'), name)


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
        topics[ROSOUT_TOPIC] = ROSOUT_TYPE  # every node's log, as foxglove_bridge sends it
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
        # /tf_static: not ROS's (left out above, like tf) but the fixed joints of the URDF
        # served on /robot_description, as robot_state_publisher would publish them.
        self.tf_static = self.resolve_topic_name(TF_STATIC_TOPIC)
        self.static: list[Transform] | None = None  # the transforms last sent on it
        try:
            self.bridge.add_ros_channel(self.tf_static, TF_STATIC_TYPE, latched=True)
        except MessageDefinitionError as exc:
            self.get_logger().warn(f'not serving {self.tf_static}: type {TF_STATIC_TYPE} '
                                   f'unavailable: {exc}')
        else:
            self._send_static(FrameTree(urdf).static_transforms())
        for o in self.outlets.values():
            o.publisher = self.create_publisher(o.cls, o.channel.topic, 10)
        # Parameters, services and the connection graph (requests answered from poll()).
        self.jobs: list[tuple[Request, Generator[None, None, None]]] = []
        self.param_clients: dict[tuple[str, str], Any] = {}  # (node, kind) -> client
        self.service_clients: dict[tuple[str, str], Any] = {}  # (service, type) -> client
        self.counts = {'parameter_requests': 0, 'parameters_set': 0, 'service_calls': 0}
        self.create_subscription(ParameterEvent, '/parameter_events', self._on_parameter_event,
                                 QoSProfile(depth=QUEUE_DEPTH,
                                            reliability=ReliabilityPolicy.RELIABLE))
        self.create_timer(POLL_PERIOD, self.poll, clock=steady_clock())
        self.create_timer(GRAPH_PERIOD, self.read_graph, clock=steady_clock())
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
            if topic == self.description and self.tf_static in self.bridge.channels:
                self._description_static(data)
        except Exception as exc:  # never die on a message (the SDK's own errors included)
            self.diag.problem('internal_error', f'{topic}: not forwarded, handling it failed: '
                              f'{exc!r}', 'ERROR', topic=topic)

    def _description_static(self, data: bytes) -> None:
        """/tf_static for a ROS publisher's ``robot_description`` (raw CDR): its fixed
        joints, sent if they differ from the last ones; one that is no URDF keeps them
        (reported)."""
        try:
            static = FrameTree(deserialize_message(data, String).data).static_transforms()
        except Exception as exc:  # rclpy raises a bare error on a malformed message
            self.diag.problem('unreadable_robot_description', f'{self.description}: no fixed '
                              f'joints read from it ({exc}); {self.tf_static} keeps the last '
                              'ones')
            return
        self._send_static(static)

    def _send_static(self, static: list[Transform]) -> None:
        """Send ``static`` (a URDF's fixed joints) on /tf_static (latched), stamped 0,
        unless they are the ones sent last."""
        if static == self.static:
            return
        self.static = static
        self.bridge.forward(self.tf_static, serialize_message(tf_message(static, Time())),
                            self.sim_ns)

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
                elif isinstance(item, Request):
                    self._start(item)
                else:
                    self._publish(item)
            except Exception as exc:  # never die on what a client sent
                self.diag.problem('internal_error', f'a client message failed: {exc!r}',
                                  'ERROR')
        self._step_jobs()
        if self.bridge.graph_wanted and self.bridge.graph is None:
            self.read_graph()  # a first subscriber: at once, not at the next period
        self.diag.set('OK', f'serving {self.bridge.url}', url=self.bridge.url,
                      forwarded=self.forwarded, **self.counts,
                      **{o.channel.counter: o.published for o in self.outlets.values()})

    # ------------------------------------------------------------------ client requests
    def _start(self, req: Request) -> None:
        """Begin answering a client's request (a job stepped by each poll)."""
        if isinstance(req, ParamGet):
            job = self._get_job(req)
            self.counts['parameter_requests'] += 1
        elif isinstance(req, ParamSet):
            job = self._set_job(req)
            self.counts['parameter_requests'] += 1
        elif isinstance(req, ServiceCall):
            job = self._service_job(req)
            self.counts['service_calls'] += 1
        else:
            req.fail(f'unknown request {type(req).__name__}')
            return
        self.jobs.append((req, job))

    def _step_jobs(self) -> None:
        """Advance each request's job; a job that fails fails its request (reported)."""
        running = []
        for req, job in self.jobs:
            try:
                next(job)
                running.append((req, job))
            except StopIteration:
                if not req.done:
                    req.fail('no answer')
            except Exception as exc:  # never die on a client's request
                req.fail(f'failed: {exc!r}')
                self.diag.problem('internal_error', f'client {req.client}: a request failed: '
                                  f'{exc!r}', 'ERROR')
        self.jobs = running

    def _param_client(self, node: str, kind: str) -> Any:
        """The node's client of ``node``'s parameter service ``kind`` (made once)."""
        key = (node, kind)
        if key not in self.param_clients:
            srv = {'get': GetParameters, 'set': SetParameters, 'list': ListParameters}[kind]
            name = {'get': 'get_parameters', 'set': 'set_parameters',
                    'list': 'list_parameters'}[kind]
            self.param_clients[key] = self.create_client(srv, f'{node}/{name}')
        return self.param_clients[key]

    def _param_nodes(self, kind: str) -> set[str]:
        """The nodes offering parameter service ``kind`` now (hidden ones left out)."""
        suffix = {'get': '/get_parameters', 'list': '/list_parameters',
                  'set': '/set_parameters'}[kind]
        return {name[:-len(suffix)] for name, _ in self.get_service_names_and_types()
                if name.endswith(suffix) and '/_' not in name}

    def _get_calls(self, wanted: dict[str, list[str]], deadline: float) -> dict[str, Call]:
        return {node: Call(self._param_client(node, 'get'), GetParameters.Request(names=names),
                           deadline, f'{node}/get_parameters')
                for node, names in wanted.items() if names}

    @staticmethod
    def _values(wanted: dict[str, list[str]], calls: dict[str, Call]) -> dict[str, RosParam]:
        """Foxglove name -> value, from finished GetParameters calls (a node that failed,
        or answered a different count: an undeclared name, is left out)."""
        out: dict[str, RosParam] = {}
        for node, call in calls.items():
            values = list(call.result.values) if call.result is not None else []
            if len(values) == len(wanted[node]):
                out.update({param_name(node, n): ros_param_from_msg(v)
                            for n, v in zip(wanted[node], values)})
        return out

    def _get_job(self, req: ParamGet) -> Generator[None, None, None]:
        """Ask each node's parameter services (every node's list first, for all)."""
        deadline = time.monotonic() + PARAM_BUDGET
        wanted: dict[str, list[str]] = defaultdict(list)
        if req.names:
            for name in req.names:
                try:
                    node, param = split_param_name(name)
                except ValueError:
                    continue  # no such parameter: left out, as foxglove_bridge does
                wanted[node].append(param)
            nodes = self._param_nodes('get')
            wanted = defaultdict(list, {n: p for n, p in wanted.items() if n in nodes})
        else:
            lists = {node: Call(self._param_client(node, 'list'), ListParameters.Request(),
                                deadline, f'{node}/list_parameters')
                     for node in sorted(self._param_nodes('list'))}
            yield from _wait(list(lists.values()))
            for node, call in lists.items():
                if call.result is not None:
                    wanted[node] = list(call.result.result.names)
        calls = self._get_calls(wanted, deadline)
        yield from _wait(list(calls.values()))
        values = self._values(wanted, calls)
        req.answer([ParamValue(n, v) for n, v in values.items()])

    def _set_job(self, req: ParamSet) -> Generator[None, None, None]:
        """Set parameters through their nodes: their current types first (a whole number
        for a double), then SetParameters; refusals reported with the node's reason."""
        deadline = time.monotonic() + PARAM_BUDGET
        refusals: list[tuple[str, str]] = []
        wanted: dict[str, list[str]] = defaultdict(list)
        given: dict[str, tuple[Any, str | None]] = {}
        nodes = self._param_nodes('set')
        for name, value, hint in req.values:
            try:
                node, param = split_param_name(name)
            except ValueError as exc:
                refusals.append((name, str(exc)))
                continue
            if node not in nodes:
                refusals.append((name, f'no node {node} offers parameters'))
                continue
            wanted[node].append(param)
            given[name] = (value, hint)
        calls = self._get_calls(wanted, deadline)
        yield from _wait(list(calls.values()))
        before = self._values(wanted, calls)
        sets: dict[str, tuple[list[str], Call]] = {}
        after: dict[str, RosParam] = dict(before)
        for node, params in wanted.items():
            msgs, names = [], []
            for param in params:
                name = param_name(node, param)
                value, hint = given[name]
                current = before.get(name)
                try:
                    ros = ros_value(value, hint, current.type if current else None)
                except ValueError as exc:
                    refusals.append((name, str(exc)))
                    continue
                msgs.append(Parameter(name=param, value=fill_value_msg(ParameterValue(), ros)))
                names.append(name)
            if msgs:
                sets[node] = (names, Call(self._param_client(node, 'set'),
                                          SetParameters.Request(parameters=msgs), deadline,
                                          f'{node}/set_parameters'))
        yield from _wait([c for _, c in sets.values()])
        for names, call in sets.values():
            if call.result is None:
                refusals.extend((n, call.error or 'no answer') for n in names)
                continue
            for name, msg, result in zip(names, call.request.parameters, call.result.results):
                if result.successful:
                    after[name] = ros_param_from_msg(msg.value)
                    self.counts['parameters_set'] += 1
                    self.get_logger().info(f'client {req.client}: parameter {name} set to '
                                           f'{after[name].value!r}')
                else:
                    refusals.append((name, result.reason or 'refused'))
        for name, reason in refusals:
            text = f'client {req.client}: parameter {name} not set: {reason}'
            self.diag.problem('refused_parameter', text, client=req.client, parameter=name)
            self.bridge.status(text)  # each one: a client's own action, answered
        req.answer([ParamValue(n, after[n]) for n, _, _ in req.values if n in after])

    def _service_job(self, call: ServiceCall) -> Generator[None, None, None]:
        """Call a ROS service for a client: its request (cdr or json) deserialised, sent
        asynchronously, the response serialised in the request's encoding."""
        try:
            cls = service_class(call.type_name)
            if call.encoding == 'cdr':
                request = deserialize_message(call.payload, cls.Request)
            elif call.encoding == 'json':
                request = fill_message(cls.Request(), json.loads(call.payload or b'{}'))
            else:
                raise ValueError(f'encoding {call.encoding!r} is not accepted (cdr, json)')
        except Exception as exc:  # rclpy raises a bare error on malformed CDR
            self._service_failed(call, f'{call.service}: not a {call.type_name} request: {exc}')
            return
        key = (call.service, call.type_name)
        if key not in self.service_clients:
            self.service_clients[key] = self.create_client(cls, call.service)
        ros = Call(self.service_clients[key], request, time.monotonic() + SERVICE_BUDGET,
                   call.service)
        yield from _wait([ros])
        if ros.result is None:
            self._service_failed(call, ros.error or f'{call.service}: no response')
            return
        if call.encoding == 'cdr':
            data = serialize_message(ros.result)
        else:
            data = json.dumps(message_to_json(ros.result)).encode()
        call.answer(data)
        shown = json.dumps(message_to_json(ros.result))
        self.get_logger().info(f'client {call.client}: called {call.service}: '
                               f'{shown[:200]}')

    def _service_failed(self, call: ServiceCall, reason: str) -> None:
        call.fail(reason)
        self.diag.problem('failed_service_call', f'client {call.client}: {reason}',
                          client=call.client, service=call.service)

    def _on_parameter_event(self, msg: ParameterEvent) -> None:
        """A node's new or changed parameters, to the clients that subscribe to them."""
        try:
            self.bridge.publish_parameters(
                [ParamValue(param_name(msg.node, p.name), ros_param_from_msg(p.value))
                 for p in list(msg.new_parameters) + list(msg.changed_parameters)])
        except Exception as exc:  # never die on a message
            self.diag.problem('internal_error', f'a parameter event failed: {exc!r}', 'ERROR')

    # ------------------------------------------------------------------ the ROS graph
    def read_graph(self) -> None:
        """Read the ROS graph (wall period :data:`GRAPH_PERIOD`): the services offered to
        clients follow it; while a client subscribes to the connection graph, it is sent
        when it changed. Never raises."""
        try:
            services = {name: types[0] for name, types in self.get_service_names_and_types()
                        if types and '/_' not in name}
            for problem in self.bridge.set_services(services):
                self.get_logger().warn(problem)
            if not self.bridge.graph_wanted:
                return
            topics = [t for t, _ in self.get_topic_names_and_types()]
            pubs = {t: [node_name(i.node_namespace, i.node_name)
                        for i in self.get_publishers_info_by_topic(t)] for t in topics}
            subs = {t: [node_name(i.node_namespace, i.node_name)
                        for i in self.get_subscriptions_info_by_topic(t)] for t in topics}
            providers: dict[str, list[str]] = defaultdict(list)
            for name, ns in self.get_node_names_and_namespaces():
                try:
                    offered = self.get_service_names_and_types_by_node(name, ns)
                except Exception:  # gone between the two calls
                    continue
                for service, _ in offered:
                    providers[service].append(node_name(ns, name))
            self.bridge.publish_graph(build_graph(pubs, subs, providers))
        except Exception as exc:  # the graph must not stop the node
            self.diag.problem('internal_error', f'reading the ROS graph failed: {exc!r}',
                              'ERROR')

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
