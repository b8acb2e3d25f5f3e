"""Read an arm_sim bag (a rosbag2 directory or a bare ``.mcap``) into numpy arrays, fast.

No ROS install is needed. The MCAP file is read into memory and its records are walked
directly: chunks are decompressed (zstd, lz4) and the message offsets come from the
message-index records that follow each chunk, so messages are located with numpy instead of
one Python object per message. JointState messages are decoded in bulk
(:func:`arm_bag.cdr.decode_joint_states_bulk`); the few trajectory, path and goal messages
one by one.

Integrity: everything the format lets a reader check is checked (magic at both ends,
record lengths, chunk sizes, decompression, chunk CRCs, the data-section and summary CRCs
when set, message indexes against their message records); any damage raises
:class:`BagError` naming the file, the byte offset and what is wrong, ending with the
``arm-sim bag recover`` hint. There are no silent partial reads, with two exceptions that
follow the recording marker (:mod:`arm_bag.bagfile`): a bag marked ``open`` whose file a
recorder still locks is read up to its last complete record (a warning says so, the file
is not touched), and one whose recorder died is recovered in place first
(:func:`arm_bag.recover.recover_bag`, one warning). A file without ``metadata.yaml`` is
fine. Problems that still allow analysis are listed in ``BagData.warnings``.
"""
from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from arm_bag.bagfile import (
    LOST_KEY,
    MAGIC,
    OP_CHANNEL,
    OP_CHUNK,
    OP_CHUNK_INDEX,
    OP_DATA_END,
    OP_FOOTER,
    OP_HEADER,
    OP_MESSAGE,
    OP_MESSAGE_INDEX,
    OP_METADATA,
    OP_SCHEMA,
    RECORDING_OPEN,
    BagError,
    is_locked,
    recording_state,
    recover_hint,
)
from arm_bag.cdr import (
    CdrError,
    JointTrajectoryMsg,
    decode_joint_states_bulk,
    decode_joint_trajectory,
    decode_path,
    decode_pose_stamped,
)

JOINT_STATE = 'sensor_msgs/msg/JointState'
TRAJECTORY = 'trajectory_msgs/msg/JointTrajectory'
PATH = 'nav_msgs/msg/Path'
POSE_STAMPED = 'geometry_msgs/msg/PoseStamped'
ROBOT_RECORD = 'arm_sim_robot'
_U16, _U32, _U64 = struct.Struct('<H'), struct.Struct('<I'), struct.Struct('<Q')


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
    lost: dict[str, int] = field(default_factory=dict)  # topic -> lost before the recorder


# ---------------------------------------------------------------------- MCAP scanning
class _Damage(Exception):
    """A record is damaged: ``offset`` [byte] in the file and what is wrong."""

    def __init__(self, offset: int, what: str) -> None:
        super().__init__(what)
        self.offset = offset
        self.what = what


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
    at: int = 0            # file offset of the chunk record
    indexes: dict[int, np.ndarray] = field(default_factory=dict)  # channel -> (N, 2) u8
    scan: bool = False     # no (trustworthy) message index: walk the records


def _str_at(data, p: int, limit: int) -> tuple[str, int]:
    """The length-prefixed UTF-8 string at ``p`` of a record ending at ``limit``."""
    if p + 4 > limit:
        raise _Damage(p, 'a string length runs past the end of its record')
    n = _U32.unpack_from(data, p)[0]
    if p + 4 + n > limit:
        raise _Damage(p, f'a string of {n} bytes runs past the end of its record')
    try:
        return bytes(data[p + 4:p + 4 + n]).decode(), p + 4 + n
    except UnicodeDecodeError:
        raise _Damage(p, 'a string is not valid UTF-8') from None


def _map_at(data, p: int, limit: int) -> tuple[dict[str, str], int]:
    """The length-prefixed string -> string map at ``p`` of a record ending at ``limit``."""
    if p + 4 > limit:
        raise _Damage(p, 'a map length runs past the end of its record')
    stop = p + 4 + _U32.unpack_from(data, p)[0]
    if stop > limit:
        raise _Damage(p, f'a map of {stop - p - 4} bytes runs past the end of its record')
    p += 4
    values = {}
    while p < stop:
        k, p = _str_at(data, p, stop)
        v, p = _str_at(data, p, stop)
        values[k] = v
    return values, p


class _Scan:
    """All records of one MCAP file, checked; messages located as (piece, offset) pairs.

    ``live``: the file is still being written (a recorder holds its lock): read up to the
    last complete record instead of requiring the footer; damage in complete records is
    still an error. Otherwise every check the format allows is made (magic at both ends,
    record lengths, chunk sizes, CRCs and decompression, data-section and summary CRCs,
    message indexes against the message records) and any damage raises :class:`BagError`
    naming the file, the byte offset and what is wrong.
    """

    def __init__(self, data: bytes, name: str, live: bool = False,
                 hint: str | None = None) -> None:
        self.name = name
        self.hint = hint or name
        if len(data) < 8 or data[:8] != MAGIC:
            if len(data) >= 16 and data[-8:] == MAGIC:  # an MCAP file with a damaged start
                raise self.error(0, 'bad MCAP magic at the start of the file')
            raise BagError(f'{name}: not an MCAP file (no MCAP magic at byte 0)')
        self.file = np.frombuffer(data, np.uint8)
        self.channels: dict[int, _Channel] = {}
        self.schemas: dict[int, str] = {}
        self.metadata: dict[str, dict[str, str]] = {}
        self.chunks: list[_Chunk] = []
        self.loose: list[int] = []  # file offsets of top-level message records
        self.truncated = False
        self.end = 8  # file offset after the last record read
        self.warnings: list[str] = []
        self._decompressed: list[bytes] = []
        try:
            self._walk(data, live)
        except _Damage as exc:
            raise self.error(exc.offset, exc.what) from None
        self.arena = (np.frombuffer(b''.join(self._decompressed), np.uint8)
                      if self._decompressed else np.zeros(0, np.uint8))
        self.pieces = (self.file, self.arena)
        self.located = self._locate()

    def error(self, offset: int, what: str) -> BagError:
        return BagError(f'{self.name}: byte {offset}: {what}; {recover_hint(self.hint)}')

    def _walk(self, data: bytes, live: bool) -> None:
        size = len(data)
        limit = size  # where the data section must end
        footer = None
        if not live:
            footer = size - 8 - 29
            if size < 8 + 9 + 29 + 8 or data[-8:] != MAGIC:
                raise _Damage(size, f'no MCAP magic at the end of the {size}-byte file: it '
                              'is cut or was never finished')
            if data[footer] != OP_FOOTER or _U64.unpack_from(data, footer + 1)[0] != 20:
                raise _Damage(footer, 'no footer record before the closing magic')
            sum_start, sum_offsets, sum_crc = struct.unpack_from('<QQI', data, footer + 9)
            if sum_start and not 8 < sum_start <= footer:
                raise _Damage(footer + 9, f'the footer puts the summary at byte {sum_start}, '
                              'outside the file')
            if sum_offsets and not sum_start <= sum_offsets <= footer:
                raise _Damage(footer + 17, f'the footer puts the summary offsets at byte '
                              f'{sum_offsets}, outside the summary')
            if sum_crc and sum_start and zlib.crc32(data[sum_start:footer + 25]) != sum_crc:
                raise _Damage(sum_start, f'summary CRC mismatch over bytes {sum_start} to '
                              f'{footer + 25} (stored {sum_crc:#010x})')
            limit = sum_start or footer
        pos = 8
        last_chunk: _Chunk | None = None
        arena_size = 0
        data_end = None
        while pos < limit:
            if pos + 9 > limit:
                if live:
                    self.truncated = True
                    break
                raise _Damage(pos, f'a record header is cut by the end of the data section '
                              f'at byte {limit}')
            op, length = data[pos], _U64.unpack_from(data, pos + 1)[0]
            body = pos + 9
            end = body + length
            if end > limit:
                if live:
                    self.truncated = True
                    break
                raise _Damage(pos, f'a record (opcode {op}) of {length} bytes runs past the '
                              f'end of the data section at byte {limit}')
            if pos == 8 and op != OP_HEADER:
                raise _Damage(pos, f'the first record has opcode {op}, not a header')
            if op == OP_CHUNK:
                last_chunk = self._chunk(data, pos, body, end, arena_size)
                if last_chunk.piece == 1:
                    arena_size += last_chunk.size
                self.chunks.append(last_chunk)
            elif op == OP_MESSAGE_INDEX:
                if last_chunk is None:
                    raise _Damage(pos, 'a message index that does not follow a chunk')
                if length < 6:
                    raise _Damage(pos, f'a message index record of only {length} bytes')
                ch, n = struct.unpack_from('<HI', data, body)
                if n % 16 or 6 + n > length:
                    raise _Damage(pos, f'a message index of {n} bytes does not fit its record')
                if ch in last_chunk.indexes:
                    raise _Damage(pos, f'a second message index for channel {ch}')
                last_chunk.indexes[ch] = np.frombuffer(data, '<u8', n // 8,
                                                       body + 6).reshape(-1, 2)
            else:
                last_chunk = None
                if op == OP_MESSAGE:
                    if length < 22:
                        raise _Damage(pos, f'a message record of only {length} bytes')
                    self.loose.append(pos)
                elif op == OP_DATA_END:
                    if length < 4:
                        raise _Damage(pos, f'a data end record of only {length} bytes')
                    data_end = pos
                    pos = end
                    break
                elif op == OP_FOOTER:
                    raise _Damage(pos, 'a footer record inside the data section')
                else:
                    self._other(op, data, body, end)
            pos = end
        self.end = pos
        if live:
            if self.chunks:  # its message indexes may not all be written yet
                self.chunks[-1].scan = True
            return
        if data_end is None or pos != limit:
            raise _Damage(pos, 'the data section does not end with a data end record where '
                          'the footer says the summary starts')
        crc = _U32.unpack_from(data, data_end + 9)[0]
        if crc and zlib.crc32(data[:data_end]) != crc:
            raise _Damage(data_end, f'data section CRC mismatch over bytes 0 to {data_end} '
                          f'(stored {crc:#010x})')
        assert footer is not None
        self._summary(data, limit, footer)

    def _summary(self, data: bytes, start: int, footer: int) -> None:
        """Check the framing of the summary section (``start`` to ``footer``) and read its
        schemas and channels; chunk indexes must point at chunks of the data section."""
        starts = {c.at for c in self.chunks}
        pos = start
        while pos < footer:
            if pos + 9 > footer:
                raise _Damage(pos, 'a summary record header runs into the footer')
            op, length = data[pos], _U64.unpack_from(data, pos + 1)[0]
            end = pos + 9 + length
            if end > footer:
                raise _Damage(pos, f'a summary record (opcode {op}) of {length} bytes runs '
                              'into the footer')
            if op in (OP_SCHEMA, OP_CHANNEL):
                self._other(op, data, pos + 9, end)
            elif op == OP_CHUNK_INDEX:
                if length < 32:
                    raise _Damage(pos, f'a chunk index record of only {length} bytes')
                at = _U64.unpack_from(data, pos + 9 + 16)[0]
                if at not in starts:
                    raise _Damage(pos, f'a chunk index points at byte {at}, where no chunk '
                                  'starts')
            elif op in (OP_MESSAGE, OP_CHUNK, OP_MESSAGE_INDEX, OP_HEADER, OP_FOOTER,
                        OP_DATA_END):
                raise _Damage(pos, f'a record with opcode {op} inside the summary')
            pos = end

    def _chunk(self, data: bytes, at: int, body: int, end: int, arena_size: int) -> _Chunk:
        if end - body < 40:
            raise _Damage(at, f'a chunk record of only {end - body} bytes')
        _start, _end, usize, crc = struct.unpack_from('<QQQI', data, body)
        compression, p = _str_at(data, body + 28, end)
        if p + 8 > end:
            raise _Damage(at, 'the chunk records length runs past the chunk record')
        rlen = _U64.unpack_from(data, p)[0]
        p += 8
        if p + rlen != end:
            raise _Damage(at, f'the chunk says {rlen} bytes of records, its record holds '
                          f'{end - p}')
        raw = data[p:end]
        try:
            if compression == '':
                out = raw
            elif compression == 'zstd':
                import zstandard

                known = zstandard.frame_content_size(raw)
                if known not in (-1, usize):
                    raise ValueError(f'the zstd frame says {known} bytes')
                out = zstandard.ZstdDecompressor().decompress(raw, max_output_size=usize)
            elif compression == 'lz4':
                import lz4.frame

                out = lz4.frame.decompress(raw)
            else:
                raise _Damage(at, f'unsupported chunk compression {compression!r}')
        except _Damage:
            raise
        except Exception as exc:  # zstandard.ZstdError, lz4's RuntimeError, ... : damage
            why = ' '.join(str(exc).split()) or type(exc).__name__
            raise _Damage(at, f'{compression} chunk does not decompress: {why}') from None
        if len(out) != usize:
            raise _Damage(at, f'the chunk holds {len(out)} bytes of records, its header '
                          f'says {usize}')
        if crc and zlib.crc32(out) != crc:
            raise _Damage(at, f'chunk CRC mismatch (stored {crc:#010x}, computed '
                          f'{zlib.crc32(out):#010x})')
        if compression == '':
            return _Chunk(0, p, rlen, at)
        self._decompressed.append(out)
        return _Chunk(1, arena_size, usize, at)

    def _other(self, op: int, data, body: int, end: int) -> None:
        if op == OP_SCHEMA:
            if body + 2 > end:
                raise _Damage(body - 9, 'a schema record too short for its id')
            sid = _U16.unpack_from(data, body)[0]
            name, p = _str_at(data, body + 2, end)
            _enc, p = _str_at(data, p, end)
            self.schemas[sid] = name
        elif op == OP_CHANNEL:
            if body + 4 > end:
                raise _Damage(body - 9, 'a channel record too short for its ids')
            cid, sid = struct.unpack_from('<HH', data, body)
            topic, p = _str_at(data, body + 4, end)
            enc, p = _str_at(data, p, end)
            _map_at(data, p, end)
            if sid and sid not in self.schemas:
                raise _Damage(body - 9, f'channel {topic!r} refers to unknown schema {sid}')
            self.channels[cid] = _Channel(cid, topic, self.schemas.get(sid, ''), enc)
        elif op == OP_METADATA:
            name, p = _str_at(data, body, end)
            self.metadata[name], p = _map_at(data, p, end)
        elif op == OP_HEADER:
            _profile, p = _str_at(data, body, end)
            _str_at(data, p, end)

    def _records(self, chunk: _Chunk, start: int, stop: int, slow: bool,
                 out: dict[int, list[int]]) -> None:
        """Walk the records of ``chunk`` from ``start`` to ``stop`` (offsets in its piece):
        schemas and channels are read; messages are collected into ``out`` when ``slow``
        (no message index), else they are damage (a message the index does not list)."""
        buf = self.pieces[chunk.piece]
        raw = buf[start:stop].tobytes()
        pos, size = 0, stop - start
        while pos < size:
            where = f'record at byte {pos + start - chunk.base} of the chunk records'
            if pos + 9 > size:
                raise _Damage(chunk.at, f'{where}: a record header is cut')
            op, length = raw[pos], _U64.unpack_from(raw, pos + 1)[0]
            if pos + 9 + length > size:
                raise _Damage(chunk.at, f'{where}: {length} bytes run past the chunk')
            if op == OP_MESSAGE:
                if not slow:
                    raise _Damage(chunk.at, f'{where}: a message the message index misses')
                if length < 22:
                    raise _Damage(chunk.at, f'{where}: a message record of {length} bytes')
                out.setdefault(_U16.unpack_from(raw, pos + 9)[0], []).append(start + pos)
            elif op in (OP_SCHEMA, OP_CHANNEL):
                try:
                    self._other(op, raw, pos + 9, pos + 9 + length)
                except _Damage as exc:
                    raise _Damage(chunk.at, f'{where}: {exc.what}') from None
            elif op in (OP_CHUNK, OP_MESSAGE_INDEX, OP_FOOTER, OP_HEADER, OP_DATA_END):
                raise _Damage(chunk.at, f'{where}: opcode {op} inside a chunk')
            pos += 9 + length

    def _indexed(self, chunk: _Chunk) -> dict[int, np.ndarray]:
        """channel -> sorted message offsets of ``chunk`` from its message indexes, each
        checked against the message record it points at; the records between messages
        are walked (schemas, channels). Raises _Damage on any inconsistency."""
        buf = self.pieces[chunk.piece]
        base, size = chunk.base, chunk.size
        found: dict[int, np.ndarray] = {}
        for ch, idx in chunk.indexes.items():
            if not len(idx):
                continue
            rel = idx[:, 1]
            if size < 31 or (rel > size - 31).any():
                raise _Damage(chunk.at, f'the message index of channel {ch} points past its '
                              f'chunk of {size} bytes')
            offs = rel.astype(np.int64) + base
            lens = _gather_u64(buf, offs, 1)
            if ((buf[offs] != OP_MESSAGE).any() or (lens < 22).any()
                    or (lens > size).any() or (rel + 9 + lens > size).any()):
                raise _Damage(chunk.at, f'the message index of channel {ch} points at '
                              'something that is not a complete message record')
            chans = buf[offs[:, None] + np.arange(9, 11)].copy().view('<u2')[:, 0]
            if (chans != ch).any() or (_gather_u64(buf, offs, 15) != idx[:, 0]).any():
                raise _Damage(chunk.at, f'the message index of channel {ch} does not match '
                              'the channel or log time of its messages')
            found[ch] = np.sort(offs)
        if not found:
            self._records(chunk, base, base + size, False, {})
            return found
        offs = np.sort(np.concatenate(list(found.values())))
        ends = offs + 9 + _gather_u64(buf, offs, 1).astype(np.int64)
        if (ends[:-1] > offs[1:]).any():
            raise _Damage(chunk.at, 'message records listed in the message index overlap')
        gap_start = np.r_[base, ends]
        gap_stop = np.r_[offs, base + size]
        for i in np.flatnonzero(gap_start != gap_stop).tolist():
            self._records(chunk, int(gap_start[i]), int(gap_stop[i]), False, {})
        return found

    def _locate(self) -> dict[int, list[tuple[int, np.ndarray]]]:
        """channel -> [(piece, absolute record offsets)], in file order."""
        out: dict[int, list[tuple[int, np.ndarray]]] = {}
        try:
            for chunk in self.chunks:
                if chunk.indexes and not chunk.scan:
                    found = self._indexed(chunk)
                else:
                    walked: dict[int, list[int]] = {}
                    self._records(chunk, chunk.base, chunk.base + chunk.size, True, walked)
                    found = {ch: np.array(v, np.int64) for ch, v in walked.items()}
                for ch, offs in found.items():
                    out.setdefault(ch, []).append((chunk.piece, offs))
        except _Damage as exc:
            raise self.error(exc.offset, exc.what) from None
        if self.loose:
            loose = np.array(self.loose, np.int64)
            chans = self.file[loose[:, None] + np.arange(9, 11)].copy().view('<u2')[:, 0]
            for ch in np.unique(chans).tolist():
                out.setdefault(ch, []).append((0, loose[chans == ch]))
        return out


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
    state = recording_state(path) if Path(path).is_dir() else None
    per_topic: dict[str, list] = {}
    for f in files:
        scan = _open_scan(f, path, state, bag)
        bag.warnings += scan.warnings
        bag.truncated |= scan.truncated
        if ROBOT_RECORD in scan.metadata and bag.robot is None:
            bag.robot = _robot(scan.metadata[ROBOT_RECORD])
        for ch, places in scan.located.items():
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
    if meta is not None and not bag.truncated and state != RECORDING_OPEN:
        expected = meta.get('message_count')
        if isinstance(expected, int) and expected != bag.message_count:
            bag.warnings.append(f'{path}: metadata.yaml counts {expected} messages, the '
                                f'file holds {bag.message_count}')
    bag.lost = _lost(meta)
    for topic, n in sorted(bag.lost.items()):
        bag.warnings.append(f'{topic}: {n} messages were lost before the recorder (counted '
                            'by it from publisher sequence gaps and DDS loss events)')
    _decode_topics(bag, per_topic)
    return bag


def _lost(meta: dict | None) -> dict[str, int]:
    """Per-topic loss counts the recorder wrote to ``metadata.yaml`` (custom_data)."""
    custom = (meta or {}).get('custom_data')
    text = custom.get(LOST_KEY) if isinstance(custom, dict) else None
    if not text:
        return {}
    try:
        counts = json.loads(text)
        return {str(k): int(v) for k, v in counts.items() if int(v) > 0}
    except (ValueError, TypeError, AttributeError):
        return {}


def _read(f: Path) -> bytes:
    try:
        return f.read_bytes()
    except OSError as exc:
        raise BagError(f'{f}: cannot read: {exc.strerror or exc}') from None


def _open_scan(f: Path, path: str | Path, state: str | None, bag: BagData) -> _Scan:
    """Scan the MCAP file ``f`` of the bag at ``path`` (recording marker ``state``).

    A bag marked as being recorded is read up to its last complete record while its
    recorder holds the file's lock, and recovered in place first when the recorder died
    (:func:`arm_bag.recover.recover_bag`); any other damaged file raises BagError.
    """
    data = _read(f)
    if state != RECORDING_OPEN:
        return _Scan(data, str(f), hint=str(path))
    if is_locked(f):
        scan = _Scan(data, str(f), live=True, hint=str(path))
        bag.truncated |= scan.truncated
        bag.warnings.append(f'{f}: still being recorded (a recorder holds its lock): read '
                            f'up to its last complete record, byte {scan.end} of {len(data)}')
        return scan
    try:
        return _Scan(data, str(f), hint=str(path))
    except BagError as exc:
        damage = str(exc)
    from arm_bag.recover import RecoveryError, recover_bag

    try:
        report = recover_bag(f)
    except (RecoveryError, OSError) as exc:
        raise BagError(f'{damage} (automatic recovery failed: {exc})') from None
    bag.warnings.append(f'{f}: recovered unfinished recording: {report.summary()}')
    return _Scan(_read(f), str(f), hint=str(path))


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
