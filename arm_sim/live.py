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
  ``std_msgs/msg/String``, latched) and the frames ``base_link -> link1 -> link2 -> tool0``
  from each joint state (:func:`arm_transforms`, the arm's own kinematics) as
  ``foxglove.FrameTransforms`` on ``/tf``.
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
from typing import Any, cast

from arm_bag.cdr import Cursor
from arm_bag.msgdefs import schema_text
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
NS_PER_S = 1_000_000_000
#: The latest ``builtin_interfaces/Time`` second: ``sec`` is an int32.
MAX_STAMP_SEC = 2**31 - 1


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
def stamp_refusal(sec: object, nanosec: object, what: str = 'header.stamp') -> str | None:
    """Why (``sec``, ``nanosec``) is no valid simulated time stamp, or None: both must be
    integers, ``sec`` in [0, 2^31 - 1] (simulated time starts at 0; builtin_interfaces/Time
    holds an int32) and ``nanosec`` in [0, 1e9) (more is a second and belongs in ``sec``).
    ``what`` names the field in the reason."""
    if isinstance(sec, bool) or not isinstance(sec, int):
        return f'{what}.sec must be an integer, got {sec!r}'
    if isinstance(nanosec, bool) or not isinstance(nanosec, int):
        return f'{what}.nanosec must be an integer, got {nanosec!r}'
    if sec < 0:
        return f'{what} is negative (sec = {sec}): simulated time starts at 0'
    if sec > MAX_STAMP_SEC:
        return (f'{what}.sec = {sec} overflows builtin_interfaces/Time (an int32: at most '
                f'{MAX_STAMP_SEC})')
    if not 0 <= nanosec < NS_PER_S:
        return f'{what}.nanosec = {nanosec} is outside [0, 1e9)'
    return None


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
        self.incoming: queue.SimpleQueue[ClientMessage | ConnectionRefusal | str] = (
            queue.SimpleQueue())
        self._lock = threading.Lock()
        # (client, its channel) -> (topic as named, encoding, resolved topic)
        self._client_channels: dict[tuple[int, int], tuple[str, str, str]] = {}
        self._topic_of_id: dict[int, str] = {}
        # With the relay (arm_sim.live_front) the SDK listens on a loopback port of its own
        # and the front on host:port, accepting both names of the protocol.
        sdk_host, sdk_port = (BACKEND_HOST, 0) if relay else (host, port)
        try:
            self.server = foxglove.start_server(
                name=name, host=sdk_host, port=sdk_port, context=self.context,
                capabilities=[Capability.ClientPublish, Capability.Time],
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

    def poll(self, limit: int = 1000) -> list[ClientMessage | ConnectionRefusal | str]:
        """Send latched topics again to new subscribers, and return what clients sent
        since the last call (a :class:`ClientMessage`, a :class:`ConnectionRefusal`, or a
        str: a refused client channel), at most ``limit`` items."""
        with self._lock:
            again = [(t, self.last[t]) for t in self.resend if t in self.last]
            self.resend.clear()
        for topic, (data, log_time) in again:
            self.channels[topic].log(data, log_time=log_time)
        out: list[ClientMessage | ConnectionRefusal | str] = []
        for _ in range(limit):
            try:
                out.append(self.incoming.get_nowait())
            except queue.Empty:
                break
        return out

    def stop(self) -> None:
        """Stop the server (clients are disconnected)."""
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

    def on_message_data(self, client: Any, client_channel_id: int, data: bytes) -> None:
        with self._lock:
            known = self._client_channels.get((client.id, client_channel_id))
        if known is not None:
            self.incoming.put(ClientMessage(client.id, known[0], known[1], bytes(data),
                                            known[2]))
