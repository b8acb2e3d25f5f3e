"""Read an arm_sim bag (a rosbag2 directory or a bare ``.mcap``) into numpy arrays, fast.

No ROS install is needed. The MCAP file is read into memory and its records are walked
directly: chunks are decompressed (zstd, lz4) and the message offsets come from the
message-index records that follow each chunk, so messages are located with numpy instead of
one Python object per message. JointState messages are decoded in bulk
(:func:`arm_bag.cdr.decode_joint_states_bulk`); the few trajectory, path and goal messages
one by one. A truncated file (a killed recorder, a full disk) is read up to its last
complete chunk, which is scanned record by record; a file without footer, summary or
``metadata.yaml`` is fine. Problems that still allow analysis are listed in
``BagData.warnings``; a file that cannot be read raises :class:`BagError`.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from arm_bag.cdr import (
    CdrError,
    JointTrajectoryMsg,
    decode_joint_states_bulk,
    decode_joint_trajectory,
    decode_path,
    decode_pose_stamped,
)
from arm_bag.writer import (
    MAGIC,
    OP_CHANNEL,
    OP_CHUNK,
    OP_FOOTER,
    OP_MESSAGE,
    OP_MESSAGE_INDEX,
    OP_METADATA,
    OP_SCHEMA,
)

JOINT_STATE = 'sensor_msgs/msg/JointState'
TRAJECTORY = 'trajectory_msgs/msg/JointTrajectory'
PATH = 'nav_msgs/msg/Path'
POSE_STAMPED = 'geometry_msgs/msg/PoseStamped'
ROBOT_RECORD = 'arm_sim_robot'
_U16, _U32, _U64 = struct.Struct('<H'), struct.Struct('<I'), struct.Struct('<Q')


class BagError(Exception):
    """The path is not a readable bag (the message names the path and the reason)."""


@dataclass
class JointStates:
    """JointState messages of one topic: ``stamp`` (N,) header stamps [ns], ``log_time``
    (N,) receive times [ns], ``position`` [rad], ``velocity`` [rad/s], ``effort`` [N m]
    (N, J), NaN where a message left an array empty; sorted by receive time."""

    topic: str
    names: tuple[str, ...]
    stamp: np.ndarray
    log_time: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray

    def __len__(self) -> int:
        return len(self.stamp)


@dataclass
class TrajectoryMsg:
    """A trajectory_msgs/JointTrajectory received at ``log_time`` [ns]: the decoded message
    in ``trajectory``."""

    log_time: int
    trajectory: JointTrajectoryMsg


@dataclass
class PathMsg:
    """A nav_msgs/Path: ``xy`` (P, 2) [m], received at ``log_time`` [ns], header stamp
    ``stamp`` [ns] (arm_sim's planner stamps it like its trajectory); ``start`` [ns]: its
    first pose's stamp, when the path starts (later than ``stamp`` for a line the planner
    begins by bringing a moving arm to rest)."""

    log_time: int
    frame_id: str
    xy: np.ndarray
    stamp: int = 0
    start: int = 0


@dataclass
class GoalMsg:
    log_time: int
    frame_id: str
    x: float
    y: float


@dataclass
class BagData:
    """What :func:`read_bag` found. ``topics`` maps topic -> (type, message count)."""

    path: str
    topics: dict[str, tuple[str, int]] = field(default_factory=dict)
    joint_states: JointStates | None = None
    reference: JointStates | None = None
    trajectories: list[TrajectoryMsg] = field(default_factory=list)
    paths: list[PathMsg] = field(default_factory=list)
    goals: list[GoalMsg] = field(default_factory=list)
    robot: dict | None = None
    warnings: list[str] = field(default_factory=list)
    truncated: bool = False
    message_count: int = 0


# ---------------------------------------------------------------------- MCAP scanning
@dataclass
class _Channel:
    id: int
    topic: str
    schema: str
    encoding: str


@dataclass
class _Chunk:
    piece: int             # 0: offsets into the file, 1: into the decompressed arena
    base: int              # where the chunk's records start in that piece
    size: int              # bytes of records
    indexes: dict[int, np.ndarray] = field(default_factory=dict)  # channel -> (N, 2) u8
    scan: bool = False     # no (trustworthy) message index: walk the records


class _Scan:
    """All records of one MCAP file; messages located as (piece, offset) pairs."""

    def __init__(self, data: bytes, name: str) -> None:
        if data[:8] != MAGIC:
            raise BagError(f'{name}: not an MCAP file (bad magic)')
        self.name = name
        self.file = np.frombuffer(data, np.uint8)
        self.channels: dict[int, _Channel] = {}
        self.schemas: dict[int, str] = {}
        self.metadata: dict[str, dict[str, str]] = {}
        self.chunks: list[_Chunk] = []
        self.loose: list[int] = []  # file offsets of top-level message records
        self.truncated = False
        self.warnings: list[str] = []
        self._decompressed: list[bytes] = []
        self._walk(data)
        self.arena = (np.frombuffer(b''.join(self._decompressed), np.uint8)
                      if self._decompressed else np.zeros(0, np.uint8))
        self.pieces = (self.file, self.arena)

    def _walk(self, data: bytes) -> None:
        pos, end = 8, len(data)
        last_chunk: _Chunk | None = None
        arena_size = 0
        while True:
            if pos + 9 > end:
                self.truncated = True
                break
            op, length = data[pos], _U64.unpack_from(data, pos + 1)[0]
            body = pos + 9
            if body + length > end:
                self.truncated = True
                break
            try:
                if op == OP_CHUNK:
                    last_chunk = self._chunk(data, body, length, arena_size)
                    if last_chunk.piece == 1:
                        arena_size += last_chunk.size
                    self.chunks.append(last_chunk)
                elif op == OP_MESSAGE_INDEX and last_chunk is not None:
                    ch = _U16.unpack_from(data, body)[0]
                    n = _U32.unpack_from(data, body + 2)[0]
                    last_chunk.indexes[ch] = np.frombuffer(data, '<u8', n // 8,
                                                           body + 6).reshape(-1, 2)
                elif op == OP_MESSAGE:
                    self.loose.append(pos)
                else:
                    self._other(op, data, body)
            except (struct.error, ValueError, IndexError, UnicodeDecodeError) as exc:
                self.warnings.append(f'{self.name}: bad record (opcode {op}) at byte {pos}: '
                                     f'{exc}; stopped reading there')
                self.truncated = True
                break
            if op == OP_FOOTER:
                break
            pos = body + length
        if self.truncated:
            if self.chunks:
                self.chunks[-1].scan = True
            if not any('bad record' in w for w in self.warnings):
                self.warnings.append(f'{self.name}: file is truncated at byte {pos} (no '
                                     'footer): read up to the last complete record')

    def _chunk(self, data: bytes, body: int, length: int, arena_size: int) -> _Chunk:
        _start, _end, usize, _crc = struct.unpack_from('<QQQI', data, body)
        p = body + 28
        clen = _U32.unpack_from(data, p)[0]
        compression = bytes(data[p + 4:p + 4 + clen]).decode()
        p += 4 + clen
        rlen = _U64.unpack_from(data, p)[0]
        p += 8
        if p + rlen > body + length:
            raise ValueError('chunk records overrun the chunk')
        if compression == '':
            return _Chunk(0, p, rlen)
        raw = data[p:p + rlen]
        if compression == 'zstd':
            import zstandard

            out = zstandard.ZstdDecompressor().decompress(raw, max_output_size=usize)
        elif compression == 'lz4':
            import lz4.frame

            out = lz4.frame.decompress(raw)
        else:
            raise ValueError(f'unsupported chunk compression {compression!r}')
        if len(out) != usize:
            raise ValueError(f'chunk decompressed to {len(out)} bytes, expected {usize}')
        self._decompressed.append(out)
        return _Chunk(1, arena_size, usize)

    def _other(self, op: int, data: bytes, body: int) -> None:
        if op == OP_SCHEMA:
            sid = _U16.unpack_from(data, body)[0]
            name, p = _read_str(data, body + 2)
            _enc, p = _read_str(data, p)
            self.schemas[sid] = name
        elif op == OP_CHANNEL:
            cid, sid = struct.unpack_from('<HH', data, body)
            topic, p = _read_str(data, body + 4)
            enc, p = _read_str(data, p)
            self.channels[cid] = _Channel(cid, topic, self.schemas.get(sid, ''), enc)
        elif op == OP_METADATA:
            name, p = _read_str(data, body)
            n = _U32.unpack_from(data, p)[0]
            p += 4
            stop = p + n
            values = {}
            while p < stop:
                k, p = _read_str(data, p)
                v, p = _read_str(data, p)
                values[k] = v
            self.metadata[name] = values

    def _scan_records(self, piece: int, base: int, size: int) -> dict[int, list[int]]:
        """Walk a chunk's records: channel -> message offsets (slow path)."""
        buf = self.pieces[piece]
        raw = buf[base:base + size].tobytes()
        out: dict[int, list[int]] = {}
        pos = 0
        while pos + 9 <= size:
            op, length = raw[pos], _U64.unpack_from(raw, pos + 1)[0]
            if pos + 9 + length > size:
                break
            if op == OP_MESSAGE and length >= 22:
                out.setdefault(_U16.unpack_from(raw, pos + 9)[0], []).append(base + pos)
            elif op == OP_SCHEMA or op == OP_CHANNEL:
                self._other(op, raw, pos + 9)
            pos += 9 + length
        return out

    def locate(self) -> dict[int, list[tuple[int, np.ndarray]]]:
        """channel -> [(piece, absolute record offsets)], in file order."""
        out: dict[int, list[tuple[int, np.ndarray]]] = {}
        for chunk in self.chunks:
            found: dict[int, np.ndarray] = {}
            if chunk.indexes and not chunk.scan and not (set(chunk.indexes)
                                                         - set(self.channels)):
                buf = self.pieces[chunk.piece]
                for ch, idx in chunk.indexes.items():
                    offs = idx[:, 1].astype(np.int64) + chunk.base
                    if len(offs) and (offs.max() + 31 > chunk.base + chunk.size
                                      or (buf[offs] != OP_MESSAGE).any()):
                        found = {}
                        chunk.scan = True
                        break
                    found[ch] = np.sort(offs)
            if chunk.scan or not chunk.indexes:
                found = {ch: np.array(v, np.int64) for ch, v in
                         self._scan_records(chunk.piece, chunk.base, chunk.size).items()}
            for ch, offs in found.items():
                out.setdefault(ch, []).append((chunk.piece, offs))
        if self.loose:
            loose = np.array(self.loose, np.int64)
            chans = self.file[loose[:, None] + np.arange(9, 11)].copy().view('<u2')[:, 0]
            for ch in np.unique(chans).tolist():
                out.setdefault(ch, []).append((0, loose[chans == ch]))
        return out


def _read_str(data, p: int) -> tuple[str, int]:
    n = _U32.unpack_from(data, p)[0]
    return bytes(data[p + 4:p + 4 + n]).decode(), p + 4 + n


def _gather_u64(buf: np.ndarray, offs: np.ndarray, at: int) -> np.ndarray:
    return buf[offs[:, None] + np.arange(at, at + 8)].copy().view('<u8')[:, 0]


# ---------------------------------------------------------------------- bag level
def mcap_files(path: str | Path) -> tuple[list[Path], dict | None, list[str]]:
    """The MCAP file(s) of a bag directory or a bare ``.mcap``, its metadata (or None)
    and warnings; raises :class:`BagError` if there is no bag at ``path``."""
    p = Path(path)
    warnings: list[str] = []
    if p.is_file():
        return [p], None, warnings
    if not p.is_dir():
        raise BagError(f'{path}: no such file or directory')
    meta = None
    meta_path = p / 'metadata.yaml'
    if meta_path.is_file():
        import yaml

        try:
            doc = yaml.safe_load(meta_path.read_text())
            meta = doc['rosbag2_bagfile_information']
            files = [p / f for f in meta.get('relative_file_paths', [])]
        except (yaml.YAMLError, KeyError, TypeError, OSError, UnicodeDecodeError) as exc:
            warnings.append(f'{meta_path}: unreadable ({type(exc).__name__}); ignoring it')
            meta, files = None, []
        if meta is not None and meta.get('storage_identifier') not in (None, 'mcap'):
            raise BagError(f"{path}: storage {meta.get('storage_identifier')!r} is not "
                           'supported (only mcap)')
        missing = [f for f in files if not f.is_file()]
        if missing:
            warnings.append(f'{path}: files named in metadata.yaml are missing: '
                            + ', '.join(f.name for f in missing))
        files = [f for f in files if f.is_file()]
    else:
        warnings.append(f'{path}: no metadata.yaml; reading the .mcap files found there')
        files = []
    if not files:
        files = sorted(p.glob('*.mcap'))
    if not files:
        raise BagError(f'{path}: not a bag (no .mcap file)')
    return files, meta, warnings


def read_bag(path: str | Path) -> BagData:
    """Read the arm_sim topics of the bag at ``path`` (see the module docstring).

    Topics are chosen by type and name suffix, so namespaced runs (``/arm2/joint_states``)
    and foreign bags with a ``joint_states`` topic work: ``joint_states`` and
    ``arm_controller/reference`` (JointState), ``joint_trajectory`` (JointTrajectory),
    ``planner/path`` (Path), ``goal_pose`` (PoseStamped).
    """
    files, meta, warnings = mcap_files(path)
    bag = BagData(str(path), warnings=warnings)
    per_topic: dict[str, list] = {}
    for f in files:
        try:
            data = f.read_bytes()
        except OSError as exc:
            raise BagError(f'{f}: cannot read: {exc.strerror or exc}') from None
        if len(data) < 8 or data[:8] != MAGIC:
            raise BagError(f'{f}: not an MCAP file')
        scan = _Scan(data, f.name)
        bag.warnings += scan.warnings
        bag.truncated |= scan.truncated
        if ROBOT_RECORD in scan.metadata and bag.robot is None:
            bag.robot = _robot(scan.metadata[ROBOT_RECORD])
        for ch, places in scan.locate().items():
            channel = scan.channels.get(ch)
            if channel is None:
                bag.warnings.append(f'{f.name}: messages on unknown channel {ch} skipped')
                continue
            n = sum(len(o) for _, o in places)
            t, count = bag.topics.get(channel.topic, (channel.schema, 0))
            bag.topics[channel.topic] = (t, count + n)
            bag.message_count += n
            if channel.encoding == 'cdr':
                per_topic.setdefault(channel.topic, []).append((scan, places))
    if meta is not None and not bag.truncated:
        expected = meta.get('message_count')
        if isinstance(expected, int) and expected != bag.message_count:
            bag.warnings.append(f'{path}: metadata.yaml counts {expected} messages, the '
                                f'file holds {bag.message_count}')
    _decode_topics(bag, per_topic)
    return bag


def _robot(values: dict[str, str]) -> dict:
    """The robot record's values, JSON-decoded where they are JSON."""
    out = {}
    for k, v in values.items():
        try:
            out[k] = json.loads(v)
        except ValueError:
            out[k] = v
    return out


def _pick(bag: BagData, type_name: str, suffix: str) -> str | None:
    found = [t for t, (ty, _) in bag.topics.items()
             if ty == type_name and (t == suffix or t.endswith('/' + suffix)
                                     or t.lstrip('/') == suffix)]
    if not found:
        return None
    found.sort(key=lambda t: (-bag.topics[t][1], t))
    if len(found) > 1:
        bag.warnings.append(f'several {suffix} topics ({", ".join(found)}); using '
                            f'{found[0]}')
    return found[0]


def _raw_messages(parts) -> list[tuple[int, bytes]]:
    """(log_time, data) of every message in ``parts``, by receive time."""
    out = []
    for scan, places in parts:
        for piece, offs in places:
            buf = scan.pieces[piece]
            for o in offs.tolist():
                length = _U64.unpack_from(buf, o + 1)[0]
                log_time = _U64.unpack_from(buf, o + 15)[0]
                out.append((log_time, buf[o + 31:o + 9 + length].tobytes()))
    out.sort(key=lambda m: m[0])
    return out


def _joint_states(bag: BagData, topic: str, parts) -> JointStates | None:
    stamps, logs, pos, vel, eff = [], [], [], [], []
    names = None
    bad = other = 0
    for scan, places in parts:
        for piece, offs in places:
            buf = scan.pieces[piece]
            lengths = _gather_u64(buf, offs, 1).astype(np.int64) - 22
            log_time = _gather_u64(buf, offs, 15).astype(np.int64)
            groups, nbad = decode_joint_states_bulk(buf, offs + 31, lengths)
            bad += nbad
            for g in groups:
                if names is None:
                    names = g.names
                if g.names != names:
                    other += len(g.index)
                    continue
                stamps.append(g.stamp)
                logs.append(log_time[g.index])
                pos.append(g.position)
                vel.append(g.velocity)
                eff.append(g.effort)
    if bad:
        bag.warnings.append(f'{topic}: {bad} messages could not be decoded as JointState')
    if other:
        bag.warnings.append(f'{topic}: {other} messages with joint names other than '
                            f'{list(names or ())} ignored')
    if names is None:
        return None
    log = np.concatenate(logs)
    order = np.argsort(log, kind='stable')
    return JointStates(topic, names, np.concatenate(stamps)[order], log[order],
                       np.concatenate(pos)[order], np.concatenate(vel)[order],
                       np.concatenate(eff)[order])


def _decode_topics(bag: BagData, per_topic: dict[str, list]) -> None:
    js = _pick(bag, JOINT_STATE, 'joint_states')
    if js and js in per_topic:
        bag.joint_states = _joint_states(bag, js, per_topic[js])
    ref = _pick(bag, JOINT_STATE, 'arm_controller/reference')
    if ref and ref in per_topic:
        bag.reference = _joint_states(bag, ref, per_topic[ref])
    decoders = (('joint_trajectory', TRAJECTORY, decode_joint_trajectory,
                 lambda t, m: bag.trajectories.append(TrajectoryMsg(t, m))),
                ('planner/path', PATH, decode_path,
                 lambda t, m: bag.paths.append(PathMsg(t, m[1], m[2], m[0], m[3]))),
                ('goal_pose', POSE_STAMPED, decode_pose_stamped,
                 lambda t, m: bag.goals.append(GoalMsg(t, m[1], m[2], m[3]))))
    for suffix, type_name, decode, add in decoders:
        topic = _pick(bag, type_name, suffix)
        if not topic or topic not in per_topic:
            continue
        bad = 0
        for log_time, data in _raw_messages(per_topic[topic]):
            try:
                add(log_time, decode(data))
            except CdrError:
                bad += 1
        if bad:
            bag.warnings.append(f'{topic}: {bad} messages could not be decoded as '
                                f'{type_name}')
