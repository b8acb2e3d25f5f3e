"""Live view without a ROS install: the suite's topics over the Foxglove WebSocket protocol.

The pure half of the ``live`` node (:mod:`arm_sim.live_node`, no rclpy here): a
:class:`Bridge` around the ``foxglove-sdk`` WebSocket server (module ``foxglove``, setup.py
extra ``foxglove``, imported only when a bridge is made) and the computations it needs.

* **ROS topics as channels**, as foxglove_bridge advertises them: topic = the resolved ROS
  name (``/joint_states``), message encoding ``cdr``, schema name = the ROS type
  (``sensor_msgs/msg/JointState``), schema encoding ``ros2msg``, schema text from
  :func:`arm_bag.msgdefs.schema_text`. Messages are forwarded as the raw CDR bytes, never
  deserialised. A latched topic's latest message is sent again when a client subscribes.
* **The robot**, as Foxglove's 3D panel draws it: the URDF (``/robot_description``,
  ``std_msgs/msg/String``, latched), the frames ``base_link -> link1 -> link2 -> tool0``
  from each joint state (:func:`arm_transforms`, the arm's own kinematics) as
  ``foxglove.FrameTransforms`` on ``/tf``, and ``/tf_static`` (``tf2_msgs/msg/TFMessage``,
  latched, a ROS channel like the others) with the URDF's fixed joints (``link<n> ->
  tool0``), as robot_state_publisher publishes them and foxglove_bridge relays them.
* **Client publishing**: a client-advertised channel on a topic of
  :data:`CLIENT_CHANNELS` (``cdr`` or ``json``) is handed to the node, which publishes it
  into ROS: ``goal_pose`` (``geometry_msgs/msg/PoseStamped``; Foxglove's "Publish pose"
  tool) and ``simulator/push`` (``geometry_msgs/msg/WrenchStamped``, a tip push; Foxglove's
  Publish panel). Other client channels are refused with a status message to the clients.
* **Both names of the protocol**: foxglove-sdk accepts only the subprotocol
  ``foxglove.sdk.v1``; stock clients offer ``foxglove.websocket.v1`` (the same protocol).
  The bridge's front (:mod:`arm_sim.live_front`) listens on the public address, relays
  each connection to the SDK's server on a loopback port with the name rewritten, and
  refuses any other handshake with the reason (:class:`ConnectionRefusal`).
* **Time**: the server advertises the ``time`` capability and the node broadcasts
  simulated time (the latest ``clock``), as foxglove_bridge does with ``use_sim_time``, so
  the 3D panel's time is the joint states' stamps' time.

* **Parameters, services, the connection graph** (capabilities ``parameters``,
  ``services``, ``connectionGraph``), as foxglove_bridge offers them: parameters named
  ``/<node>.<parameter>`` (:func:`param_name`), their values mapped both ways between
  ``rcl_interfaces/msg/ParameterValue`` and Foxglove's (:func:`foxglove_value`,
  :func:`ros_value`); ROS services advertised by name and type (no per-service encoding,
  so a call may be in ``cdr`` or ``json`` and is answered in the same; their ``.srv`` must
  be installed, :func:`service_schemas`); the graph as
  :class:`Graph` (:func:`build_graph`), sent when it changed. The SDK asks from its threads;
  each request (:class:`ParamGet`, :class:`ParamSet`, :class:`ServiceCall`) is handed to
  the node through :meth:`Bridge.poll` and the SDK's thread waits for the answer (at most
  :data:`PARAM_TIMEOUT`, :data:`SERVICE_TIMEOUT`), which the node gives from its own
  thread without ever waiting itself.
* **/rosout** (``rcl_interfaces/msg/Log``) is one more ROS channel.

* **Validation** (:func:`stamp_refusal`, :func:`text_refusal`,
  :meth:`ClientChannel.refusal`): a stamp or time that is negative, overflows
  ``builtin_interfaces/Time`` or has ``nanosec`` outside [0, 1e9), a frame id with a NUL
  character, a non-finite number and a push's force or torque component beyond
  :data:`~arm_dynamics.disturbance.MAX_LOAD` are refused with the reason, whether they
  come from a ROS topic or a client; the node reports them and keeps serving.

The SDK calls the listener from its own threads; they only queue work (:meth:`Bridge.poll`
takes it on the caller's thread), so every ROS call stays on the node's thread.

References: Foxglove WebSocket protocol v1 (``foxglove.websocket.v1``: advertise,
subscribe, clientAdvertise, clientMessageData); the ``foxglove.FrameTransforms`` schema;
the OMG CDR encapsulation (XCDR1, little endian) rosbag2 and rmw use.
"""

from __future__ import annotations

import functools
import json
import math
import queue
import struct
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

from arm_bag.cdr import Cursor
from arm_bag.msgdefs import (
    MessageDefinitionError,
    expanded_schema,
    schema_text,
    share_dirs,
)
from arm_common.stamps import NS_PER_S, stamp_refusal  # noqa: F401 (re-exported)
from arm_dynamics.disturbance import MAX_LOAD
from arm_dynamics.models import RobotModel
from arm_dynamics.urdf import link_frames

#: The port Foxglove connects to by default (``ws://localhost:8765``).
DEFAULT_PORT = 8765
#: What the live view says when foxglove-sdk is missing (one line, no traceback).
FOXGLOVE_MISSING = ("the live view needs foxglove-sdk, which is not installed: pip install "
                    "'foxglove-sdk==0.30.3' (or the arm_sim extra: pip install -e '.[foxglove]')")
#: WebSocket subprotocol of the Foxglove WebSocket protocol (its original name; the SDK's
#: own is ``foxglove.sdk.v1``: :mod:`arm_sim.live_front` accepts both).
SUBPROTOCOL = 'foxglove.websocket.v1'
#: Where the SDK's server listens behind the front (:mod:`arm_sim.live_front`).
BACKEND_HOST = '127.0.0.1'
DESCRIPTION_TOPIC = 'robot_description'
TF_TOPIC = 'tf'  # relative: /tf in the root namespace, as robot_state_publisher's
#: The fixed joints' transforms, latched, as robot_state_publisher's (relative, like /tf).
TF_STATIC_TOPIC = 'tf_static'
TF_STATIC_TYPE = 'tf2_msgs/msg/TFMessage'
GOAL_TOPIC = 'goal_pose'
GOAL_TYPE = 'geometry_msgs/msg/PoseStamped'
#: The simulator's live tip pushes (arm_dynamics.simulator_node: force x, y [N], base frame).
PUSH_TOPIC = 'simulator/push'
PUSH_TYPE = 'geometry_msgs/msg/WrenchStamped'
#: Encodings the server accepts from publishing clients, preferred first (Foxglove
#: publishes in the first one it supports).
CLIENT_ENCODINGS = ('cdr', 'json')
#: Frames, as the URDF names them for the 2-R arm (:mod:`arm_dynamics.urdf`; a chain of n
#: links has ``link1`` .. ``link<n>`` between base and tip).
FRAMES = ('base_link', 'link1', 'link2', 'tool0')
#: CDR encapsulation header: XCDR1, little endian, no options.
CDR_HEADER = b'\x00\x01\x00\x00'
#: How long [s, wall] a client's parameter request waits for the node's answer (the SDK's
#: thread of that client waits; the node's executor never does).
PARAM_TIMEOUT = 3.0
#: How long [s, wall] a client's service call waits for the ROS service's response.
SERVICE_TIMEOUT = 10.0
ROSOUT_TOPIC = '/rosout'
ROSOUT_TYPE = 'rcl_interfaces/msg/Log'


# ---------------------------------------------------------------------- kinematics
@dataclass(frozen=True)
class Transform:
    """The pose of ``child`` in ``parent``: ``translation`` [m] (x, y, z) and ``rotation``
    a unit quaternion (x, y, z, w)."""

    parent: str
    child: str
    translation: tuple[float, float, float]
    rotation: tuple[float, float, float, float]


def _about_z(angle: float) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w) of a rotation by ``angle`` [rad] about +z."""
    return (0.0, 0.0, math.sin(angle / 2), math.cos(angle / 2))


def arm_transforms(arm: RobotModel, q: Sequence[float]) -> list[Transform]:
    """The URDF's frame tree at joint positions ``q`` [rad] (n joints).

    ``base_link -> link1`` rotates by ``q1`` at the origin, ``link<i> -> link<i+1>`` by
    ``q<i+1>`` at the end of link ``i`` (``(l_i, 0, 0)``), and ``link<n> -> tool0`` is fixed
    at the tip, each child's x axis along its link (:mod:`arm_dynamics.urdf`). ``tool0`` is
    the tip of the model's :meth:`joint_points` expressed in ``link<n>`` (``(l_n, 0, 0)`` to
    rounding), so composing them gives that tip.

    Raises
    ------
    ValueError
        ``q`` is not n finite angles.
    """
    qa = [float(v) for v in q]
    n = arm.n_dof
    if len(qa) != n or not all(math.isfinite(v) for v in qa):
        count = 'two' if n == 2 else str(n)
        raise ValueError(f'q must be {count} finite joint positions [rad], got {list(q)}')
    points = arm.joint_points(qa)
    frames = (FRAMES[0],) + link_frames(n) + (FRAMES[-1],)
    out = [Transform(frames[0], frames[1], (0.0, 0.0, 0.0), _about_z(qa[0]))]
    out += [Transform(frames[i], frames[i + 1], (float(arm.link_lengths[i - 1]), 0.0, 0.0),
                      _about_z(qa[i])) for i in range(1, n)]
    # The tip in the last link's frame: rotate (tip - last joint) back by its angle.
    dx, dy = (float(v) for v in points[-1] - points[-2])
    angle = sum(qa)
    c, s = math.cos(angle), math.sin(angle)
    out.append(Transform(frames[n], frames[n + 1], (c * dx + s * dy, -s * dx + c * dy, 0.0),
                         (0.0, 0.0, 0.0, 1.0)))
    return out


def joint_positions(names: Sequence[str], positions: Sequence[float],
                    joint_names: Sequence[str]) -> list[float] | None:
    """The positions [rad] of ``joint_names`` in a JointState's ``names``/``positions``;
    None when one is missing (a state of other joints)."""
    index = {n: i for i, n in enumerate(names)}
    if not all(n in index and index[n] < len(positions) for n in joint_names):
        return None
    return [float(positions[index[n]]) for n in joint_names]


# ---------------------------------------------------------------------- validation
def text_refusal(text: object, what: str) -> str | None:
    """Why ``text`` is no usable string field (a frame id, a name), or None: it must be a
    str without NUL characters (a ROS string ends at its first NUL: 'base_link\\0x' would
    silently become 'base_link')."""
    if not isinstance(text, str):
        return f'{what} must be a string, got {text!r}'
    if '\x00' in text:
        return f'{what} {text!r} contains a NUL character'
    return None


def cdr_header(data: bytes, frame: bool = True) -> tuple[int, int, str]:
    """(sec, nanosec, frame_id) of a serialised message that begins with a
    ``std_msgs/Header`` (JointState, PoseStamped; frame id '' with ``frame`` False: one that
    begins with a ``builtin_interfaces/Time``, a Clock), read from the bytes as they were
    sent: rclpy's deserialisation cuts a string at its first NUL, which the bytes forwarded
    to a client still hold. Raises :class:`arm_bag.cdr.CdrError` (a ValueError) if
    malformed."""
    c = Cursor(data)
    sec = c.u32()
    nanosec = c.u32()
    return (sec - 2**32 if sec >= 2**31 else sec), nanosec, (c.string() if frame else '')


# ---------------------------------------------------------------------- client channels
def _finite(v: object) -> bool:
    """Is ``v`` a finite number (not a bool; an int too large for a float is not)?"""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    try:
        return math.isfinite(v)
    except OverflowError:
        return False


@dataclass(frozen=True)
class Vector:
    """A vector field of a client-published message: ``path`` from the message's root
    (``pose.position``), its components ``keys`` (a missing one takes the message's default:
    0, a quaternion's ``w`` 1) and the largest magnitude a component may have (None: any
    finite number), in ``unit``."""

    path: str
    keys: str
    bound: float | None = None
    unit: str = ''


@dataclass(frozen=True)
class Stamped:
    """A client's message, read and checked (:meth:`ClientChannel.from_json`): stamp
    [s, ns], frame id, and the components of each of its channel's vectors, in order."""

    sec: int
    nanosec: int
    frame_id: str
    vectors: tuple[tuple[float, ...], ...]


@dataclass(frozen=True)
class ClientChannel:
    """A topic clients may publish into ROS: one row of :data:`CLIENT_CHANNELS`.

    Attributes
    ----------
    topic : relative ROS name, resolved by the node as its publisher's (``goal_pose``)
    type_name : its ROS type, a message that begins with a ``std_msgs/Header``
    kind : what one message is (``goal``): the node reports a refused one as
        ``rejected_<kind>`` and logs ``<kind> published on <topic>``
    counter : the node's /diagnostics count of published ones (``goals_published``)
    vectors : the numeric fields checked (and read from JSON), each number finite
    logged : index of the vector the node's log line shows (None: none)
    """

    topic: str
    type_name: str
    kind: str
    counter: str
    vectors: tuple[Vector, ...]
    logged: int | None = None

    @property
    def short_type(self) -> str:
        """The type without its package (``PoseStamped``)."""
        return self.type_name.rsplit('/', 1)[-1]

    @property
    def rejected(self) -> str:
        """The node's /diagnostics kind of a refused message (``rejected_goal``)."""
        return f'rejected_{self.kind}'

    def refusal(self, sec: object, nanosec: object, frame_id: object,
                vectors: Sequence[Sequence[object]]) -> str | None:
        """Why a message with these fields cannot be published into ROS, or None: a valid
        stamp (:func:`stamp_refusal`), a frame id without NUL (:func:`text_refusal`), finite
        numbers, each within its vector's bound; the reason names the first bad field."""
        reason = (stamp_refusal(sec, nanosec, 'header.stamp')
                  or text_refusal(frame_id, 'header.frame_id'))
        if reason:
            return reason
        for vec, values in zip(self.vectors, vectors):
            for k, v in zip(vec.keys, values):
                if not _finite(v):
                    return f'{vec.path}.{k} must be a finite number, got {v!r}'
                if vec.bound is not None and abs(cast(float, v)) > vec.bound:
                    unit = f' {vec.unit}' if vec.unit else ''
                    return (f'{vec.path}.{k} = {v:g}{unit} is too large: at most '
                            f'{vec.bound:g}{unit} in magnitude')
        return None

    def from_json(self, data: bytes | str) -> Stamped:
        """Read one message a client sent JSON-encoded (ROS 2 ``nanosec`` or ROS 1
        ``nsec`` stamps; missing fields take the message's defaults).

        Raises
        ------
        ValueError
            Not JSON, or a field of the wrong kind (named), or refused by :meth:`refusal`.
        """
        try:
            doc = json.loads(data)
        except (ValueError, UnicodeDecodeError) as exc:
            raise ValueError(f'not JSON: {exc}') from None
        if not isinstance(doc, Mapping):
            raise ValueError(f'a {self.short_type} must be a JSON object')
        header = doc.get('header') or {}
        stamp = header.get('stamp') or {} if isinstance(header, Mapping) else None
        if not isinstance(header, Mapping) or not isinstance(stamp, Mapping):
            raise ValueError('header.stamp must be an object with sec and nanosec')
        sec, nsec = stamp.get('sec', 0), stamp.get('nanosec', stamp.get('nsec', 0))
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in (sec, nsec)):
            raise ValueError(f'header.stamp must hold integers, got {dict(stamp)!r}')
        frame = header.get('frame_id', '')
        vectors = tuple(_numbers(self._object(doc, vec.path), vec) for vec in self.vectors)
        reason = self.refusal(sec, nsec, frame, vectors)
        if reason:
            raise ValueError(reason)
        return Stamped(int(sec), int(nsec), frame, vectors)

    def _object(self, doc: Mapping[str, Any], path: str) -> Any:
        """The value at ``path`` in ``doc`` (a missing or null one: {}); ValueError naming
        the first object on the way that is none."""
        parts = path.split('.')
        node: Any = doc
        for i, part in enumerate(parts[:-1]):
            node = node.get(part) or {}
            if not isinstance(node, Mapping):
                where = '.'.join(parts[:i + 1])
                inside = dict.fromkeys(v.path.split('.')[i + 1] for v in self.vectors
                                       if v.path.startswith(where + '.'))
                raise ValueError(f'{where} must be an object with {" and ".join(inside)}')
        return node.get(parts[-1]) or {}

    def read(self, msg: Any) -> tuple[tuple[object, ...], ...]:
        """The vectors' components of a deserialised ROS message, unchecked."""
        return tuple(tuple(getattr(_field(msg, vec.path), k) for k in vec.keys)
                     for vec in self.vectors)

    def fill(self, msg: Any, value: Stamped) -> Any:
        """Set a (new) ROS message of :attr:`type_name` to ``value``; returns it."""
        msg.header.stamp.sec, msg.header.stamp.nanosec = value.sec, value.nanosec
        msg.header.frame_id = value.frame_id
        for vec, values in zip(self.vectors, value.vectors):
            target = _field(msg, vec.path)
            for k, v in zip(vec.keys, values):
                setattr(target, k, v)
        return msg

    def describe(self, value: Sequence[Sequence[object]]) -> str:
        """The logged vector of ``value`` (:attr:`logged`), e.g. ``wrench.force (0, -30, 0)
        N``; '' when the row logs none."""
        if self.logged is None:
            return ''
        vec = self.vectors[self.logged]
        numbers = ', '.join(f'{float(cast(float, v)):g}' for v in value[self.logged])
        return f'{vec.path} ({numbers})' + (f' {vec.unit}' if vec.unit else '')


def _field(msg: Any, path: str) -> Any:
    return functools.reduce(getattr, path.split('.'), msg)


def _numbers(d: Any, vec: Vector) -> tuple[float, ...]:
    if not isinstance(d, Mapping):
        raise ValueError(f'{vec.path} must be an object with {", ".join(vec.keys)}')
    out = []
    for k in vec.keys:
        v = d.get(k, 1.0 if k == 'w' else 0.0)
        if not _finite(v):
            raise ValueError(f'{vec.path}.{k} must be a finite number, got {v!r}')
        out.append(float(v))
    return tuple(out)


#: A goal for the tip (Foxglove's "Publish pose"; the planner takes it).
GOAL_CHANNEL = ClientChannel(GOAL_TOPIC, GOAL_TYPE, 'goal', 'goals_published',
                             (Vector('pose.position', 'xyz'),
                              Vector('pose.orientation', 'xyzw')))
#: A live tip push (the simulator holds force x, y for its push_duration); each component
#: bounded as the simulator bounds a push's (arm_dynamics.disturbance.MAX_LOAD).
PUSH_CHANNEL = ClientChannel(PUSH_TOPIC, PUSH_TYPE, 'push', 'pushes_published',
                             (Vector('wrench.force', 'xyz', MAX_LOAD, 'N'),
                              Vector('wrench.torque', 'xyz', MAX_LOAD, 'N m')), logged=0)
#: The topics clients may publish into ROS; every other client channel is refused.
CLIENT_CHANNELS: tuple[ClientChannel, ...] = (GOAL_CHANNEL, PUSH_CHANNEL)


def resolved_client_topics(resolve: Any = None) -> dict[str, str]:
    """Resolved topic -> ROS type of :data:`CLIENT_CHANNELS`; ``resolve`` maps a relative
    name to its resolved one (a node's ``resolve_topic_name``; None: the root namespace)."""
    return {(resolve(c.topic) if resolve else '/' + c.topic): c.type_name
            for c in CLIENT_CHANNELS}


def pose_refusal(sec: object, nanosec: object, frame_id: object,
                 position: Sequence[object], orientation: Sequence[object]) -> str | None:
    """Why a PoseStamped with these fields cannot be published into ROS, or None
    (:meth:`ClientChannel.refusal` of :data:`GOAL_CHANNEL`): a valid stamp, a frame id
    without NUL and finite numbers."""
    return GOAL_CHANNEL.refusal(sec, nanosec, frame_id, (position, orientation))


# ---------------------------------------------------------------------- messages
def cdr_string(text: str) -> bytes:
    """A ``std_msgs/msg/String`` serialised as CDR (XCDR1, little endian)."""
    raw = text.encode('utf-8')
    return CDR_HEADER + struct.pack('<I', len(raw) + 1) + raw + b'\x00'


@dataclass(frozen=True)
class GoalPose:
    """A ``geometry_msgs/msg/PoseStamped`` from a JSON client: stamp [s, ns], frame, position
    [m] (x, y, z) and orientation (x, y, z, w)."""

    sec: int
    nanosec: int
    frame_id: str
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]


def pose_from_json(data: bytes | str) -> GoalPose:
    """Read a PoseStamped a client sent JSON-encoded (:meth:`ClientChannel.from_json` of
    :data:`GOAL_CHANNEL`).

    Raises
    ------
    ValueError
        Not JSON, or a field of the wrong kind (named), a stamp that is negative, overflows
        or has ``nanosec`` outside [0, 1e9), a frame id with a NUL character, a non-finite
        number (:func:`pose_refusal`).
    """
    v = GOAL_CHANNEL.from_json(data)
    p, o = v.vectors
    return GoalPose(v.sec, v.nanosec, v.frame_id, (p[0], p[1], p[2]), (o[0], o[1], o[2], o[3]))


def accepted_topic(topic: str, accepted: Mapping[str, str]) -> str | None:
    """The resolved topic of ``accepted`` a client's channel ``topic`` names (the name
    without its leading slash counts too), or None."""
    return next((name for name in accepted if topic in (name, name.lstrip('/'))), None)


def client_channel_refusal(topic: str, accepted: Mapping[str, str], encoding: str,
                           schema_name: str) -> str | None:
    """Why a client channel cannot be published into ROS (None: it can): only a topic of
    ``accepted`` (resolved topic -> ROS type, :func:`resolved_client_topics`; e.g. ``/goal_pose``,
    or ``goal_pose``), as that type (an empty schema name is taken as it), in one of
    :data:`CLIENT_ENCODINGS`."""
    target = accepted_topic(topic, accepted)
    if target is None:
        names = list(accepted)
        listed = ', '.join(names[:-1]) + ' and ' + names[-1] if len(names) > 1 else ''.join(
            names)
        return f'only {listed} can be published into ROS, not {topic!r}'
    if encoding not in CLIENT_ENCODINGS:
        return (f'{topic}: encoding {encoding!r} is not accepted (accepted: '
                f'{", ".join(CLIENT_ENCODINGS)})')
    type_name = accepted[target]
    if schema_name and schema_name.replace('/msg/', '/') != type_name.replace('/msg/', '/'):
        return f'{topic}: schema {schema_name!r} is not {type_name}'
    return None


# ---------------------------------------------------------------------- parameters
#: rcl_interfaces/msg/ParameterType codes.
PARAMETER_NOT_SET, PARAMETER_BOOL, PARAMETER_INTEGER, PARAMETER_DOUBLE, PARAMETER_STRING = (
    0, 1, 2, 3, 4)
(PARAMETER_BYTE_ARRAY, PARAMETER_BOOL_ARRAY, PARAMETER_INTEGER_ARRAY, PARAMETER_DOUBLE_ARRAY,
 PARAMETER_STRING_ARRAY) = (5, 6, 7, 8, 9)
#: The field of rcl_interfaces/msg/ParameterValue that holds a value of each type.
VALUE_FIELDS = {PARAMETER_BOOL: 'bool_value', PARAMETER_INTEGER: 'integer_value',
                PARAMETER_DOUBLE: 'double_value', PARAMETER_STRING: 'string_value',
                PARAMETER_BYTE_ARRAY: 'byte_array_value',
                PARAMETER_BOOL_ARRAY: 'bool_array_value',
                PARAMETER_INTEGER_ARRAY: 'integer_array_value',
                PARAMETER_DOUBLE_ARRAY: 'double_array_value',
                PARAMETER_STRING_ARRAY: 'string_array_value'}
#: Foxglove's type hints (foxglove.ParameterType) a ROS type needs to survive JSON.
HINTS = {PARAMETER_DOUBLE: 'float64', PARAMETER_DOUBLE_ARRAY: 'float64_array',
         PARAMETER_BYTE_ARRAY: 'byte_array'}
_ARRAY_TYPES = (PARAMETER_BYTE_ARRAY, PARAMETER_BOOL_ARRAY, PARAMETER_INTEGER_ARRAY,
                PARAMETER_DOUBLE_ARRAY, PARAMETER_STRING_ARRAY)
_INT64 = (-2**63, 2**63 - 1)


@dataclass(frozen=True)
class RosParam:
    """A ROS parameter value as rcl_interfaces/msg/ParameterValue holds it: ``type`` (a
    ParameterType code) and ``value`` of that type (None when not set; bytes for a byte
    array; a list for the other arrays)."""

    type: int
    value: Any = None


def param_name(node: str, param: str) -> str:
    """The name foxglove_bridge gives parameter ``param`` of node ``node`` (fully qualified,
    ``/simulator``): ``/simulator.pause_at``."""
    return f'{node}.{param}'


def split_param_name(name: str) -> tuple[str, str]:
    """(node, parameter) of a Foxglove parameter name (``/simulator.pause_at`` ->
    ``('/simulator', 'pause_at')``; node and namespace names hold no dot, parameter names
    may: ``/n.qos_overrides./tf.depth``). ValueError naming the expected form."""
    node, dot, param = name.partition('.')
    if not dot or not param or not node.startswith('/') or node.endswith('/'):
        raise ValueError(f'{name!r} is no parameter name of the form /<node>.<parameter>')
    return node, param


def ros_param_from_msg(msg: Any) -> RosParam:
    """A :class:`RosParam` from an rcl_interfaces/msg/ParameterValue (any object with its
    fields): arrays as lists, a byte array as bytes."""
    kind = int(msg.type)
    field = VALUE_FIELDS.get(kind)
    if field is None:
        return RosParam(PARAMETER_NOT_SET)
    value = getattr(msg, field)
    if kind == PARAMETER_BYTE_ARRAY:
        return RosParam(kind, b''.join(b if isinstance(b, bytes) else bytes([b])
                                       for b in value))
    if kind in _ARRAY_TYPES:
        return RosParam(kind, list(value))
    return RosParam(kind, value)


def fill_value_msg(msg: Any, param: RosParam) -> Any:
    """Set an (empty) rcl_interfaces/msg/ParameterValue to ``param``; returns it."""
    msg.type = param.type
    field = VALUE_FIELDS.get(param.type)
    if field is not None:
        value = param.value
        if param.type == PARAMETER_BYTE_ARRAY:
            value = [bytes([b]) for b in value]
        setattr(msg, field, value)
    return msg


def foxglove_value(param: RosParam) -> tuple[Any, str | None]:
    """(native value, type hint) Foxglove shows for a ROS parameter, as foxglove_bridge
    sends it: a bool, int, float (hint ``float64``, so 1.0 stays a double), str, bytes
    (``byte_array``: base64 on the wire) or a list (a double array: ``float64_array``);
    None for a parameter not set."""
    if param.type not in VALUE_FIELDS:
        return None, None
    value = param.value
    if param.type == PARAMETER_DOUBLE:
        value = float(value)
    elif param.type == PARAMETER_DOUBLE_ARRAY:
        value = [float(v) for v in value]
    elif param.type == PARAMETER_BYTE_ARRAY:
        value = bytes(value)
    elif param.type in _ARRAY_TYPES:
        value = list(value)
    return value, HINTS.get(param.type)


def _number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def ros_value(value: Any, hint: str | None = None, current: int | None = None) -> RosParam:
    """The ROS parameter value of a value a client set (``hint`` Foxglove's type hint,
    ``current`` the parameter's ROS type now, if known): a whole number becomes a double
    for a double parameter (JSON cannot tell 2 from 2.0), an empty array takes the
    parameter's array type; the node then decides (it refuses a wrong type, a read-only
    parameter, a value out of range, with its reason).

    Raises
    ------
    ValueError
        A value no ROS parameter can hold (a map, an array of mixed kinds, an integer
        beyond int64, an empty array of a parameter not known to be an array).
    """
    if value is None:
        return RosParam(PARAMETER_NOT_SET)
    if isinstance(value, bool):
        return RosParam(PARAMETER_BOOL, value)
    if isinstance(value, (bytes, bytearray)) or hint == 'byte_array':
        if isinstance(value, str):
            import base64

            try:
                value = base64.b64decode(value, validate=True)
            except ValueError:
                raise ValueError('a byte array must be base64 text') from None
        if not isinstance(value, (bytes, bytearray)):
            raise ValueError(f'a byte array must be bytes, got {value!r}')
        return RosParam(PARAMETER_BYTE_ARRAY, bytes(value))
    if isinstance(value, int):
        if hint == 'float64' or current == PARAMETER_DOUBLE:
            return RosParam(PARAMETER_DOUBLE, float(value))
        if not _INT64[0] <= value <= _INT64[1]:
            raise ValueError(f'{value} is beyond a 64-bit integer')
        return RosParam(PARAMETER_INTEGER, value)
    if isinstance(value, float):
        return RosParam(PARAMETER_DOUBLE, value)
    if isinstance(value, str):
        return RosParam(PARAMETER_STRING, value)
    if isinstance(value, Mapping):
        raise ValueError('ROS parameters hold no maps')
    if isinstance(value, (list, tuple)):
        items = list(value)
        if not items:
            if hint == 'float64_array':
                return RosParam(PARAMETER_DOUBLE_ARRAY, [])
            if current in _ARRAY_TYPES and current != PARAMETER_BYTE_ARRAY:
                return RosParam(current, [])
            raise ValueError('cannot tell the type of an empty array of a parameter that is '
                             'not an array')
        if all(isinstance(v, bool) for v in items):
            return RosParam(PARAMETER_BOOL_ARRAY, items)
        if all(isinstance(v, str) for v in items):
            return RosParam(PARAMETER_STRING_ARRAY, items)
        if all(_number(v) for v in items):
            if (all(isinstance(v, int) for v in items) and hint != 'float64_array'
                    and current != PARAMETER_DOUBLE_ARRAY):
                if not all(_INT64[0] <= v <= _INT64[1] for v in items):
                    raise ValueError('an integer of the array is beyond a 64-bit integer')
                return RosParam(PARAMETER_INTEGER_ARRAY, items)
            return RosParam(PARAMETER_DOUBLE_ARRAY, [float(v) for v in items])
        raise ValueError('a ROS parameter array holds one kind: bools, integers, doubles or '
                         f'strings, got {items!r}')
    raise ValueError(f'no ROS parameter holds {value!r}')


@dataclass(frozen=True)
class ParamValue:
    """A parameter for Foxglove: its name (``/simulator.pause_at``) and :class:`RosParam`
    (None: no such parameter, left out of the answer)."""

    name: str
    param: RosParam | None


# ---------------------------------------------------------------------- services
def _find_srv(type_name: str) -> Path:
    parts = type_name.split('/')
    if len(parts) != 3 or parts[1] != 'srv':
        raise MessageDefinitionError(f'type name {type_name!r} is not of the form '
                                     '<pkg>/srv/<Type>')
    tried = []
    for d in share_dirs(parts[0]):
        path = d / 'srv' / f'{parts[2]}.srv'
        if path.is_file():
            return path
        tried.append(str(path))
    raise MessageDefinitionError(f'no .srv file for {type_name!r}; looked in: '
                                 + ', '.join(tried))


def _expanded(package: str, main: str) -> str:
    """``main`` (a .msg text, or one half of a .srv) followed by the definitions it uses,
    as a ``ros2msg`` schema (:func:`arm_bag.msgdefs.schema_text`'s layout)."""
    return expanded_schema(package, main.lstrip('\n'))


def service_schemas(type_name: str) -> tuple[str, str]:
    """The ``ros2msg`` schemas of the request and the response of service type
    ``type_name`` (``std_srvs/srv/Trigger``), from its installed ``.srv`` file, as
    foxglove_bridge advertises them. Raises
    :class:`~arm_bag.msgdefs.MessageDefinitionError` if it is not installed."""
    text = _find_srv(type_name).read_text()
    lines = text.splitlines()
    cut = next((i for i, line in enumerate(lines) if line.strip() == '---'), len(lines))
    package = type_name.split('/')[0]
    return (_expanded(package, '\n'.join(lines[:cut])),
            _expanded(package, '\n'.join(lines[cut + 1:])))


def message_to_json(msg: Any) -> Any:
    """A ROS message (or field value) as JSON-ready data (for a service's JSON response)."""
    if hasattr(msg, 'get_fields_and_field_types'):
        return {f: message_to_json(getattr(msg, f)) for f in msg.get_fields_and_field_types()}
    if isinstance(msg, (bytes, bytearray)):
        return list(msg)
    if isinstance(msg, (list, tuple)) or type(msg).__name__ in ('array', 'ndarray'):
        return [message_to_json(v) for v in msg]
    return msg


def fill_message(msg: Any, doc: Any, path: str = '') -> Any:
    """Set the fields of ROS message ``msg`` from JSON object ``doc`` (missing fields keep
    their defaults); returns it. ValueError naming a field the message does not have or a
    value of the wrong kind."""
    if not isinstance(doc, Mapping):
        raise ValueError(f'{path or "the request"} must be a JSON object')
    fields = msg.get_fields_and_field_types()
    for key, value in doc.items():
        where = f'{path}.{key}' if path else key
        if key not in fields:
            raise ValueError(f'{where}: no such field')
        current = getattr(msg, key)
        if hasattr(current, 'get_fields_and_field_types'):
            fill_message(current, value, where)
            continue
        try:
            setattr(msg, key, value)
        except (AssertionError, TypeError, ValueError) as exc:
            raise ValueError(f'{where}: {exc}') from None
    return msg


# ---------------------------------------------------------------------- connection graph
@dataclass(frozen=True)
class Graph:
    """The ROS graph as Foxglove's connection graph shows it: topic -> the nodes (fully
    qualified names) publishing it, topic -> those subscribing to it, service -> the nodes
    providing it; each sorted, so two graphs compare equal when the ROS graph is the same."""

    published: tuple[tuple[str, tuple[str, ...]], ...] = ()
    subscribed: tuple[tuple[str, tuple[str, ...]], ...] = ()
    services: tuple[tuple[str, tuple[str, ...]], ...] = ()


def _sorted_map(m: Mapping[str, Any]) -> tuple[tuple[str, tuple[str, ...]], ...]:
    return tuple((k, tuple(sorted(set(v)))) for k, v in sorted(m.items()) if v)


def build_graph(publishers: Mapping[str, Sequence[str]], subscribers: Mapping[str, Sequence[str]],
                providers: Mapping[str, Sequence[str]]) -> Graph:
    """A :class:`Graph` of topic -> publishing nodes, topic -> subscribing nodes, service ->
    providing nodes (entries with no node are left out, duplicates merged)."""
    return Graph(_sorted_map(publishers), _sorted_map(subscribers), _sorted_map(providers))


def node_name(namespace: str, name: str) -> str:
    """A node's fully qualified name (``/`` + ``simulator`` -> ``/simulator``)."""
    return namespace.rstrip('/') + '/' + name


# ---------------------------------------------------------------------- requests
class Request:
    """A client's request the node answers from its thread (:meth:`Bridge.poll` hands it
    over): the SDK thread that made it waits (:meth:`wait`) for :meth:`answer` or
    :meth:`fail`."""

    def __init__(self, client: int) -> None:
        self.client = client
        self.result: Any = None
        self.error: str | None = None
        self._done = threading.Event()

    def answer(self, result: Any) -> None:
        self.result = result
        self._done.set()

    def fail(self, reason: str) -> None:
        self.error = reason
        self._done.set()

    @property
    def done(self) -> bool:
        return self._done.is_set()

    def wait(self, timeout: float) -> bool:
        """Wait up to ``timeout`` [s] (wall) for the answer; True if it came."""
        return self._done.wait(timeout)


class ParamGet(Request):
    """Get parameters ``names`` (empty: every parameter of every node); answered with a
    list of :class:`ParamValue`."""

    def __init__(self, client: int, names: Sequence[str]) -> None:
        super().__init__(client)
        self.names = list(names)


class ParamSet(Request):
    """Set parameters: (name, native value, Foxglove type hint) each; answered with a list
    of :class:`ParamValue`, each parameter's value after the attempt (a refused one keeps
    its value; the node reports why)."""

    def __init__(self, client: int, values: Sequence[tuple[str, Any, str | None]]) -> None:
        super().__init__(client)
        self.values = list(values)


class ServiceCall(Request):
    """A client's call of ROS service ``service`` (type ``type_name``): ``encoding`` ``cdr``
    or ``json`` and the request's bytes; answered with the response's bytes, in the same
    encoding."""

    def __init__(self, client: int, service: str, type_name: str, call_id: int,
                 encoding: str, payload: bytes) -> None:
        super().__init__(client)
        self.service = service
        self.type_name = type_name
        self.call_id = call_id
        self.encoding = encoding
        self.payload = payload


# ---------------------------------------------------------------------- the server
@dataclass(frozen=True)
class ClientMessage:
    """A message a client published on an accepted channel: ``topic`` as the client named
    it, ``encoding`` ``cdr`` (``data`` the serialised message) or ``json``, and
    ``ros_topic`` the resolved topic of :data:`CLIENT_CHANNELS` it is for."""

    client: int
    topic: str
    encoding: str
    data: bytes
    ros_topic: str = ''


@dataclass(frozen=True)
class ConnectionRefusal:
    """A WebSocket handshake the server refused, and why (which subprotocols the client
    offered, which are accepted)."""

    text: str


#: What clients send the node (:meth:`Bridge.poll`).
Incoming = ClientMessage | ConnectionRefusal | str | Request


class Bridge:
    """The Foxglove WebSocket server and its channels (see the module docstring).

    Parameters
    ----------
    host : address to listen on (``127.0.0.1``: this machine only)
    port : TCP port, 0 for a free one (:attr:`port` tells which)
    client_topics : the topics clients may publish, resolved topic -> ROS type
        (:func:`resolved_client_topics`; None: :data:`CLIENT_CHANNELS` in the root namespace,
        ``/goal_pose`` and ``/simulator/push``)
    name : server name shown by Foxglove
    relay : serve through :class:`arm_sim.live_front.Front` (both subprotocol names, a
        reason for each refused handshake); False: the SDK alone on ``host``:``port``
        (``foxglove.sdk.v1`` only)

    Raises
    ------
    ImportError
        foxglove-sdk is not installed.
    OSError
        The port cannot be bound (the SDK's reason).
    """

    def __init__(self, host: str = '127.0.0.1', port: int = DEFAULT_PORT,
                 client_topics: Mapping[str, str] | None = None, name: str = 'arm_sim',
                 relay: bool = True) -> None:
        import foxglove
        from foxglove.websocket import Capability

        self._fox = foxglove
        self.client_topics = dict(resolved_client_topics() if client_topics is None
                                  else client_topics)
        self.context = foxglove.Context()
        self.channels: dict[str, Any] = {}
        self.latched: set[str] = set()
        self.last: dict[str, tuple[bytes, int]] = {}  # latched topic -> (data, log time)
        self.resend: set[str] = set()
        self.incoming: queue.SimpleQueue[Incoming] = queue.SimpleQueue()
        self._pending: set[Request] = set()  # requests an SDK thread waits on
        self.services: dict[str, str] = {}  # advertised service -> ROS type
        self.graph: Graph | None = None  # the connection graph last published
        self.graph_wanted = False  # a client subscribes to the connection graph
        self._stopping = False
        self._lock = threading.Lock()
        # (client, its channel) -> (topic as named, encoding, resolved topic)
        self._client_channels: dict[tuple[int, int], tuple[str, str, str]] = {}
        self._topic_of_id: dict[int, str] = {}
        self._unservable: set[str] = set()  # services that cannot be offered (reported)
        # With the relay (arm_sim.live_front) the SDK listens on a loopback port of its own
        # and the front on host:port, accepting both names of the protocol.
        sdk_host, sdk_port = (BACKEND_HOST, 0) if relay else (host, port)
        try:
            self.server = foxglove.start_server(
                name=name, host=sdk_host, port=sdk_port, context=self.context,
                capabilities=[Capability.ClientPublish, Capability.Time,
                              Capability.Parameters, Capability.Services,
                              Capability.ConnectionGraph],
                supported_encodings=list(CLIENT_ENCODINGS),
                server_listener=cast(Any, self))  # the callbacks it uses, below
        except RuntimeError as exc:
            raise OSError(f'cannot serve on {sdk_host}:{sdk_port}: {exc}') from None
        self.sdk_port = int(self.server.port)
        self.front: Any = None
        if relay:
            from arm_sim.live_front import Front

            try:
                self.front = Front(host, port, self.sdk_port, on_refusal=self._refused,
                                   backend_host=BACKEND_HOST)
            except OSError as exc:
                self.server.stop()
                raise OSError(f'cannot serve on {host}:{port}: '
                              f'{exc.strerror or exc}') from None
        self.host = host
        self.port = int(self.front.port) if self.front is not None else self.sdk_port
        self._tf: Any = None  # the FrameTransforms channel, made at the first use

    def _refused(self, text: str) -> None:
        self.incoming.put(ConnectionRefusal(text))

    @property
    def url(self) -> str:
        """``ws://HOST:PORT`` clients connect to."""
        return f'ws://{self.host}:{self.port}'

    # ------------------------------------------------------------ server -> clients
    def add_ros_channel(self, topic: str, type_name: str, latched: bool = False) -> None:
        """Advertise ROS topic ``topic`` (resolved name) of ``type_name`` as foxglove_bridge
        does (``cdr``, ``ros2msg``). Raises
        :class:`~arm_bag.msgdefs.MessageDefinitionError` when the type's definition is not
        installed."""
        schema = self._fox.Schema(name=type_name, encoding='ros2msg',
                                  data=schema_text(type_name).encode())
        channel = self._fox.Channel(topic, schema=schema, message_encoding='cdr',
                                    context=self.context)
        with self._lock:
            self.channels[topic] = channel
            self._topic_of_id[channel.id()] = topic
            if latched:
                self.latched.add(topic)

    def forward(self, topic: str, data: bytes, log_time: int) -> None:
        """Send one serialised message of ``topic`` at ``log_time`` [ns] to subscribers."""
        channel = self.channels[topic]
        if topic in self.latched:
            with self._lock:
                self.last[topic] = (data, log_time)
        channel.log(data, log_time=log_time)

    def send_transforms(self, transforms: Sequence[Transform], stamp_ns: int,
                        topic: str = '/' + TF_TOPIC) -> None:
        """Send ``transforms`` stamped ``stamp_ns`` [ns] as ``foxglove.FrameTransforms``."""
        from foxglove.channels import FrameTransformsChannel
        from foxglove.messages import (
            FrameTransform,
            FrameTransforms,
            Quaternion,
            Timestamp,
            Vector3,
        )

        if self._tf is None:
            self._tf = FrameTransformsChannel(topic, context=self.context)
        sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
        stamp = Timestamp(sec=sec, nsec=nsec)
        msg = FrameTransforms(transforms=[
            FrameTransform(timestamp=stamp, parent_frame_id=t.parent,
                           child_frame_id=t.child,
                           translation=Vector3(x=t.translation[0], y=t.translation[1],
                                               z=t.translation[2]),
                           rotation=Quaternion(x=t.rotation[0], y=t.rotation[1],
                                               z=t.rotation[2], w=t.rotation[3]))
            for t in transforms])
        self._tf.log(msg, log_time=int(stamp_ns))

    def broadcast_time(self, stamp_ns: int) -> None:
        """Tell clients the current (simulated) time [ns]."""
        self.server.broadcast_time(int(stamp_ns))

    def status(self, message: str, warning: bool = True) -> None:
        """Show ``message`` to every client."""
        level = self._fox.StatusLevel.Warning if warning else self._fox.StatusLevel.Info
        self.server.publish_status(message, level)

    def poll(self, limit: int = 1000) -> list[Incoming]:
        """Send latched topics again to new subscribers, and return what clients sent
        since the last call (a :class:`ClientMessage`, a :class:`ConnectionRefusal`, a
        str: a refused client channel, or a :class:`Request` to answer: a
        :class:`ParamGet`, :class:`ParamSet` or :class:`ServiceCall`), at most ``limit``
        items."""
        with self._lock:
            again = [(t, self.last[t]) for t in self.resend if t in self.last]
            self.resend.clear()
        for topic, (data, log_time) in again:
            self.channels[topic].log(data, log_time=log_time)
        out: list[Incoming] = []
        for _ in range(limit):
            try:
                out.append(self.incoming.get_nowait())
            except queue.Empty:
                break
        return out

    # ------------------------------------------------------------ parameters, services, graph
    def publish_parameters(self, values: Sequence[ParamValue]) -> None:
        """Send changed parameter values to the clients that subscribe to them (the SDK
        picks those)."""
        params = [self._fox_parameter(v) for v in values if v.param is not None]
        if params:
            self.server.publish_parameter_values(params)

    def _fox_parameter(self, v: ParamValue) -> Any:
        from foxglove import Parameter, ParameterType, ParameterValue

        value, hint = foxglove_value(v.param or RosParam(PARAMETER_NOT_SET))
        if isinstance(value, list) and not value and hint is None:
            return Parameter(v.name, value=ParameterValue.Array([]))
        kind = {'float64': ParameterType.Float64, 'float64_array': ParameterType.Float64Array,
                'byte_array': ParameterType.ByteArray}.get(hint or '')
        return Parameter(v.name, value=value, type=kind)

    def set_services(self, services: Mapping[str, str]) -> list[str]:
        """Advertise ROS services ``services`` (name -> type) to clients and withdraw the
        others, as foxglove_bridge does: each by name and type, called in any of the
        server's encodings (``cdr`` or ``json``) and answered in the call's. Returns why
        some could not be (their type's definition not installed, or the SDK's reason),
        once per service."""
        from foxglove import Service, ServiceSchema

        gone = [n for n, t in self.services.items() if services.get(n) != t]
        if gone:
            self.server.remove_services(gone)
            for n in gone:
                del self.services[n]
        problems: list[str] = []
        new = []
        for name, type_name in sorted(services.items()):
            if name in self.services or name in self._unservable:
                continue
            try:
                service_schemas(type_name)  # its definition is installed: callable
            except MessageDefinitionError as exc:
                self._unservable.add(name)
                problems.append(f'not offering service {name}: {exc}')
                continue
            # No per-service encoding: foxglove-sdk 0.30.3 refuses ("Unsupported encoding")
            # a call in any encoding but the one a service declares, and labels every
            # response with the declared response encoding. Undeclared, a call may use any
            # of the server's supportedEncodings (cdr, json; the protocol's rule) and is
            # answered in the request's. The price: the advertisement carries the type
            # name but empty requestSchema/responseSchema (the SDK sends no text then).
            schema = ServiceSchema(name=type_name)
            handler = functools.partial(self._call_service, name, type_name)
            new.append((name, type_name, Service(name, schema=schema, handler=handler)))
        if new:
            try:
                self.server.add_services([s for _, _, s in new])
                self.services.update({n: t for n, t, _ in new})
            except Exception as exc:  # the SDK's error: one at a time, to name the culprit
                for n, t, svc in new:
                    try:
                        self.server.add_services([svc])
                        self.services[n] = t
                    except Exception as one:
                        self._unservable.add(n)
                        problems.append(f'not offering service {n}: {one or exc}')
        return problems

    def publish_graph(self, graph: Graph) -> bool:
        """Send ``graph`` to the clients that subscribe to the connection graph (the SDK
        sends the difference, and the whole to a new subscriber); False (nothing sent) when
        it is the one last sent."""
        if graph == self.graph:
            return False
        g = self._fox.ConnectionGraph()
        for topic, nodes in graph.published:
            g.set_published_topic(topic, list(nodes))
        for topic, nodes in graph.subscribed:
            g.set_subscribed_topic(topic, list(nodes))
        for service, nodes in graph.services:
            g.set_advertised_service(service, list(nodes))
        self.server.publish_connection_graph(g)
        self.graph = graph
        return True

    def _ask(self, request: Request, timeout: float) -> bool:
        """Hand ``request`` to the node and wait for its answer (on the SDK's thread)."""
        if self._stopping:
            request.fail('the live node is stopping')
            return True
        with self._lock:
            self._pending.add(request)
        try:
            self.incoming.put(request)
            return request.wait(timeout)
        finally:
            with self._lock:
                self._pending.discard(request)

    def _call_service(self, name: str, type_name: str, request: Any) -> bytes:
        """The SDK's handler of a service call (on a thread of its own): the node calls
        the ROS service; the response, or an error naming why not."""
        call = ServiceCall(int(request.client_id), name, type_name, int(request.call_id),
                           str(request.encoding), bytes(request.payload))
        if not self._ask(call, SERVICE_TIMEOUT):
            raise RuntimeError(f'{name}: no response within {SERVICE_TIMEOUT:g} s')
        if call.error is not None:
            raise RuntimeError(call.error)
        return bytes(call.result)

    def stop(self) -> None:
        """Stop the server (clients are disconnected; requests waiting are failed)."""
        self._stopping = True
        with self._lock:
            waiting = list(self._pending)
        for r in waiting:
            r.fail('the live node is stopping')
        if self.front is not None:
            self.front.stop()
        self.server.stop()

    # ------------------------------------------------------------ listener (SDK threads)
    def on_subscribe(self, client: Any, channel: Any) -> None:
        with self._lock:
            topic = self._topic_of_id.get(channel.id)
            if topic in self.latched:
                self.resend.add(topic)

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        return None

    def on_client_advertise(self, client: Any, channel: Any) -> None:
        refusal = client_channel_refusal(channel.topic, self.client_topics, channel.encoding,
                                         channel.schema_name)
        target = accepted_topic(channel.topic, self.client_topics)
        if refusal or target is None:
            self.incoming.put(f'client {client.id}: {refusal}')
            return
        with self._lock:
            self._client_channels[(client.id, channel.id)] = (channel.topic, channel.encoding,
                                                              target)

    def on_client_unadvertise(self, client: Any, client_channel_id: int) -> None:
        with self._lock:
            self._client_channels.pop((client.id, client_channel_id), None)

    def on_get_parameters(self, client: Any, param_names: list[str],
                          request_id: str | None = None) -> list[Any]:
        """Parameters ``param_names`` (none: all), asked of their nodes by the node; waits
        up to :data:`PARAM_TIMEOUT` (a node that does not answer is left out)."""
        req = ParamGet(int(client.id), list(param_names))
        if not self._ask(req, PARAM_TIMEOUT) or req.error is not None:
            return []
        return [self._fox_parameter(v) for v in req.result if v.param is not None]

    def on_set_parameters(self, client: Any, parameters: list[Any],
                          request_id: str | None = None) -> list[Any]:
        """Set ``parameters`` through their nodes; returns their values afterwards (a
        refused one keeps its value, and the node tells the clients why)."""
        hints = {'Float64': 'float64', 'Float64Array': 'float64_array',
                 'ByteArray': 'byte_array'}
        values = [(p.name, p.get_value(),
                   hints.get(p.type.name) if p.type is not None else None)
                  for p in parameters]
        req = ParamSet(int(client.id), values)
        if not self._ask(req, PARAM_TIMEOUT) or req.error is not None:
            return []
        return [self._fox_parameter(v) for v in req.result if v.param is not None]

    def on_parameters_subscribe(self, param_names: list[str]) -> None:
        return None

    def on_parameters_unsubscribe(self, param_names: list[str]) -> None:
        return None

    def on_connection_graph_subscribe(self) -> None:
        self.graph_wanted = True

    def on_connection_graph_unsubscribe(self) -> None:
        self.graph_wanted = False

    def on_message_data(self, client: Any, client_channel_id: int, data: bytes) -> None:
        with self._lock:
            known = self._client_channels.get((client.id, client_channel_id))
        if known is not None:
            self.incoming.put(ClientMessage(client.id, known[0], known[1], bytes(data),
                                            known[2]))
