"""Read an arm_sim bag (a rosbag2 directory or a bare ``.mcap``) into numpy arrays, fast.

No ROS install is needed. The MCAP file is streamed: memory-mapped (files of at least
:data:`MMAP_MIN_BYTES`) and its records walked in file order, one chunk at a time: each
chunk is decompressed (zstd, lz4), its message offsets come from the message-index records
that follow it (messages are located with numpy, not one Python object per message), its
JointState messages are decoded in bulk into arrays at once
(:func:`arm_bag.cdr.decode_joint_states_bulk`), the few trajectory, path, goal and
simulator event messages copied, and then its decompressed bytes are dropped and its pages
of the file released, so the peak memory is the decoded arrays plus about one chunk, not
the file.

Integrity: everything the format lets a reader check is checked (magic at both ends,
record lengths, chunk sizes, decompression, chunk CRCs, the data-section and summary CRCs
when set, message indexes against their message records); any damage raises
:class:`BagError` naming the file, the byte offset and what is wrong, ending with the
``arm-sim bag recover`` hint. There are no silent partial reads, with two exceptions that
follow the recording marker (:mod:`arm_bag.bagfile`): a bag marked ``open`` whose file a
recorder still locks is read up to its last complete record (a warning says so, the file
is not touched), and one whose recorder died is recovered in place first
(:func:`arm_bag.recover.recover_bag`, one warning), whether the bag directory or its
``.mcap`` file (listed by the directory's ``metadata.yaml``) is named. A file without
``metadata.yaml`` is fine. Problems that still allow analysis are listed in
``BagData.warnings``. Only regular files are read: a FIFO, device or socket is refused
(:class:`BagError` naming it and its kind) and never opened.
"""
from __future__ import annotations

import json
import mmap
import os
import stat
import struct
import zlib
from collections.abc import Callable
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
    OP_STATISTICS,
    RECORDING_OPEN,
    BagError,
    is_locked,
    open_regular,
    path_stat,
    read_metadata_text,
    recording_state,
    recover_hint,
    regular_file,
)
from arm_bag.cdr import (
    CdrError,
    DiagnosticStatusMsg,
    JointTrajectoryMsg,
    decode_diagnostic_status,
    decode_joint_states_bulk,
    decode_joint_trajectory,
    decode_path,
    decode_pose_stamped,
)

JOINT_STATE = 'sensor_msgs/msg/JointState'
TRAJECTORY = 'trajectory_msgs/msg/JointTrajectory'
PATH = 'nav_msgs/msg/Path'
POSE_STAMPED = 'geometry_msgs/msg/PoseStamped'
DIAGNOSTIC_STATUS = 'diagnostic_msgs/msg/DiagnosticStatus'
ROBOT_RECORD = 'arm_sim_robot'
_U16, _U32, _U64 = struct.Struct('<H'), struct.Struct('<I'), struct.Struct('<Q')
#: Files of at least this many bytes are memory-mapped and streamed (pages released as
#: they are done with); smaller ones are read into memory (same code, same checks).
MMAP_MIN_BYTES = 1 << 20
_NO_BYTES = np.zeros(0, np.uint8)


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


#: The push kinds of :mod:`arm_dynamics.disturbance` (every other event kind is a fault).
PUSH_KINDS = ('tip_force', 'joint_torque')
#: The edges an event can be.
EDGES = ('start', 'end')


@dataclass(frozen=True)
class SimEvent:
    """A push or fault starting or ending (``simulator/events``, one DiagnosticStatus per
    edge, :class:`arm_dynamics.disturbance.Event`): ``time_ns`` the simulated time [ns]
    it happens at (its ``time_ns`` value), ``name`` ('simulator: push' or 'simulator:
    fault'), ``kind`` (e.g. 'tip_force', 'brake'), ``edge`` ('start' or 'end'), ``label``
    (its scenario entry, 'pushes[0]', 'faults[2]', or 'live'), ``description`` (the
    status message, one line) and ``level`` (0 OK: a push, 1 WARN: a fault)."""

    time_ns: int
    name: str
    kind: str
    edge: str
    label: str
    description: str
    level: int

    @property
    def is_push(self) -> bool:
        """A push (else a fault): by its name, or by its kind for another name."""
        if self.name.endswith((': push', ': fault')):
            return self.name.endswith(': push')
        return self.kind in PUSH_KINDS


def sim_event(msg: DiagnosticStatusMsg) -> SimEvent:
    """The :class:`SimEvent` a ``simulator/events`` status holds; CdrError if it is not
    one (no integer ``time_ns`` value, or an ``edge`` other than start/end)."""
    text = msg.value('time_ns')
    try:
        time_ns = int(text or '')
    except ValueError:
        raise CdrError(f'simulator event without an integer time_ns ({text!r})') from None
    edge = msg.value('edge', '') or ''
    if edge not in EDGES:
        raise CdrError(f"simulator event edge {edge!r} is not 'start' or 'end'")
    return SimEvent(time_ns, msg.name, msg.value('kind', '') or '', edge,
                    msg.value('label', '') or '', msg.message, msg.level)


@dataclass
class BagData:
    """What :func:`read_bag` found. ``topics`` maps topic -> (type, message count)."""

    path: str
    topics: dict[str, tuple[str, int]] = field(default_factory=dict)
    joint_states: JointStates | None = None
    reference: JointStates | None = None
    #: ``simulator/true_joint_states``: the true state beside the measured ``joint_states``
    #: (a simulator with sensor or actuator effects on); None when the bag has none.
    true_joint_states: JointStates | None = None
    trajectories: list[TrajectoryMsg] = field(default_factory=list)
    paths: list[PathMsg] = field(default_factory=list)
    goals: list[GoalMsg] = field(default_factory=list)
    #: ``simulator/events``: the pushes' and faults' starts and ends, by simulated time
    #: (at one time in the order received); empty when the bag has none.
    events: list[SimEvent] = field(default_factory=list)
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
    buf: np.ndarray        # uint8: the file, or the chunk's decompressed records
    base: int              # where the chunk's records start in ``buf``
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


#: What a scan hands over per chunk: (the scan: its ``channels`` known so far and
#: ``hints``, the chunk's bytes (uint8), channel -> sorted offsets of its message records
#: in those bytes).
Consumer = Callable[['_Scan', np.ndarray, dict[int, np.ndarray]], None]


class _Scan:
    """All records of one MCAP file, checked; messages located chunk by chunk.

    Each chunk's messages are handed to ``consume`` as soon as the chunk and its message
    indexes are read (then its decompressed bytes are dropped and, for a memory-mapped
    file, its pages released); top-level messages at the end. Without ``consume`` they are
    kept in ``located`` (channel -> [(bytes, offsets)]). A damaged message index is
    reported after the checks of the whole data section and summary, as when the file
    was checked before any message was located: the first damage found is the same.

    ``live``: the file is still being written (a recorder holds its lock): read up to the
    last complete record instead of requiring the footer; damage in complete records is
    still an error. Otherwise every check the format allows is made (magic at both ends,
    record lengths, chunk sizes, CRCs and decompression, data-section and summary CRCs,
    message indexes against the message records) and any damage raises :class:`BagError`
    naming the file, the byte offset and what is wrong.
    """

    def __init__(self, data: bytes | mmap.mmap, name: str, live: bool = False,
                 hint: str | None = None, consume: Consumer | None = None) -> None:
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
        self.hints: dict[int, int] = {}  # channel -> message count the summary announces
        self.located: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
        self._consume: Consumer = consume or self._keep
        self._mm = data if isinstance(data, mmap.mmap) else None
        self._pending: _Chunk | None = None  # read, its message indexes may follow
        self._deferred: _Damage | None = None  # first damaged message index
        self._crc = 0  # running CRC-32 of the data section up to _crc_pos
        self._crc_pos = 0
        self._released = 0  # file pages before this offset are released
        self._want_crc = not live
        try:
            self._walk(data, live)
            if self._deferred is not None:
                raise self._deferred
            self._loose()
        except _Damage as exc:
            raise self.error(exc.offset, exc.what) from None

    def _keep(self, scan: _Scan, buf: np.ndarray,
              found: dict[int, np.ndarray]) -> None:
        for ch, offs in found.items():
            self.located.setdefault(ch, []).append((buf, offs))

    def _crc_to(self, data: bytes | mmap.mmap, stop: int) -> int:
        """The data-section CRC-32 over bytes 0 to ``stop``, computed incrementally."""
        if stop > self._crc_pos:
            self._crc = zlib.crc32(memoryview(data)[self._crc_pos:stop], self._crc)
            self._crc_pos = stop
        return self._crc

    def _finish(self, chunk: _Chunk, data: bytes | mmap.mmap, pos: int) -> None:
        """Locate ``chunk``'s messages, hand them over and let its bytes go; ``pos``: where
        the walk is (everything before it is read)."""
        if self._deferred is None:
            try:
                if chunk.indexes and not chunk.scan:
                    found = self._indexed(chunk)
                else:
                    walked: dict[int, list[int]] = {}
                    self._records(chunk, chunk.base, chunk.base + chunk.size, True, walked)
                    found = {ch: np.array(v, np.int64) for ch, v in walked.items()}
            except _Damage as exc:
                self._deferred = exc
            else:
                self._consume(self, chunk.buf, found)
        chunk.buf, chunk.indexes = _NO_BYTES, {}
        if self._mm is not None and hasattr(mmap, 'MADV_DONTNEED'):
            stop = pos - pos % mmap.PAGESIZE
            if stop > self._released:
                if self._want_crc:
                    self._crc_to(data, stop)
                self._mm.madvise(mmap.MADV_DONTNEED, self._released, stop - self._released)
                self._released = stop

    def _loose(self) -> None:
        """Hand over the top-level (unchunked) message records, by channel."""
        if not self.loose:
            return
        loose = np.array(self.loose, np.int64)
        chans = self.file[loose[:, None] + np.arange(9, 11)].copy().view('<u2')[:, 0]
        self._consume(self, self.file,
                      {ch: loose[chans == ch] for ch in np.unique(chans).tolist()})

    def error(self, offset: int, what: str) -> BagError:
        return BagError(f'{self.name}: byte {offset}: {what}; {recover_hint(self.hint)}')

    def _walk(self, data: bytes | mmap.mmap, live: bool) -> None:
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
            if sum_start:
                self.hints = _announced_counts(data, sum_start, footer)
        pos = 8
        last_chunk: _Chunk | None = None
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
                if self._pending is not None:
                    self._finish(self._pending, data, pos)
                last_chunk = self._pending = self._chunk(data, pos, body, end)
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
        if self._pending is not None:
            # live: the last chunk's message indexes may not all be written yet
            self._pending.scan = live
            self._finish(self._pending, data, pos)
            self._pending = None
        if live:
            return
        if data_end is None or pos != limit:
            raise _Damage(pos, 'the data section does not end with a data end record where '
                          'the footer says the summary starts')
        crc = _U32.unpack_from(data, data_end + 9)[0]
        if crc and self._crc_to(data, data_end) != crc:
            raise _Damage(data_end, f'data section CRC mismatch over bytes 0 to {data_end} '
                          f'(stored {crc:#010x})')
        assert footer is not None
        self._summary(data, limit, footer)

    def _summary(self, data: bytes | mmap.mmap, start: int, footer: int) -> None:
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

    def _chunk(self, data: bytes | mmap.mmap, at: int, body: int, end: int) -> _Chunk:
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
        raw = memoryview(data)[p:end] if compression == '' else data[p:end]
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
            return _Chunk(self.file, p, rlen, at)
        return _Chunk(np.frombuffer(out, np.uint8), 0, usize, at)

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
        buf = chunk.buf
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
        buf = chunk.buf
        base, size = chunk.base, chunk.size
        found: dict[int, np.ndarray] = {}
        ends_of: dict[int, np.ndarray] = {}  # channel -> record ends, as found
        for ch, idx in chunk.indexes.items():
            if not len(idx):
                continue
            rel = idx[:, 1]
            if size < 31 or (rel > size - 31).any():
                raise _Damage(chunk.at, f'the message index of channel {ch} points past its '
                              f'chunk of {size} bytes')
            offs = rel.astype(np.int64) + base
            head = _headers(buf, offs)
            lens = head['len']
            if ((head['op'] != OP_MESSAGE).any() or (lens < 22).any()
                    or (lens > size).any() or (rel + 9 + lens > size).any()):
                raise _Damage(chunk.at, f'the message index of channel {ch} points at '
                              'something that is not a complete message record')
            if (head['chan'] != ch).any() or (head['log'] != idx[:, 0]).any():
                raise _Damage(chunk.at, f'the message index of channel {ch} does not match '
                              'the channel or log time of its messages')
            if len(offs) > 1 and (offs[1:] < offs[:-1]).any():
                order = np.argsort(offs, kind='stable')
                offs, lens = offs[order], lens[order]
            found[ch] = offs
            ends_of[ch] = offs + 9 + lens.astype(np.int64)
        if not found:
            self._records(chunk, base, base + size, False, {})
            return found
        if len(found) == 1:
            (offs,), (ends,) = found.values(), ends_of.values()
        else:
            offs = np.concatenate(list(found.values()))
            order = np.argsort(offs, kind='stable')
            offs, ends = offs[order], np.concatenate(list(ends_of.values()))[order]
        if (ends[:-1] > offs[1:]).any():
            raise _Damage(chunk.at, 'message records listed in the message index overlap')
        gap_start = np.r_[base, ends]
        gap_stop = np.r_[offs, base + size]
        for i in np.flatnonzero(gap_start != gap_stop).tolist():
            self._records(chunk, int(gap_start[i]), int(gap_stop[i]), False, {})
        return found


def _announced_counts(data: bytes | mmap.mmap, start: int, stop: int) -> dict[int, int]:
    """channel -> message count from the summary's statistics record (a capacity hint for
    the decoded arrays, checked against nothing: {} if absent or unreadable)."""
    try:
        pos = start
        while pos + 9 <= stop:
            op, length = data[pos], _U64.unpack_from(data, pos + 1)[0]
            if op == OP_STATISTICS and length >= 46:
                body = pos + 9 + 42
                end = body + 4 + _U32.unpack_from(data, body)[0]
                most = len(data) // 31  # a message record takes >= 31 bytes: caps a bad hint
                return {ch: min(n, most) for ch, n in (struct.unpack_from('<HQ', data, p) for p
                                                       in range(body + 4, min(end, stop) - 9, 10))}
            pos += 9 + length
    except (struct.error, IndexError, ValueError):
        pass
    return {}


#: The start of a message record: opcode, record length, channel id, log time.
_HEAD = np.dtype({'names': ['op', 'len', 'chan', 'log'], 'formats': ['u1', '<u8', '<u2', '<u8'],
                  'offsets': [0, 1, 9, 15], 'itemsize': 23})


def _headers(buf: np.ndarray, offs: np.ndarray) -> np.ndarray:
    """The first 23 bytes of the message records at ``offs`` of ``buf`` (uint8) as a
    structured (N,) array of :data:`_HEAD` (one row gather; ``offs + 23 <= len(buf)``)."""
    rows = np.lib.stride_tricks.as_strided(buf, (max(len(buf) - 22, 0), 23), (1, 1),
                                           writeable=False)
    return rows[offs].view(_HEAD)[:, 0]


def _gather_u64(buf: np.ndarray, offs: np.ndarray, at: int) -> np.ndarray:
    """The little-endian uint64 at ``offs + at`` of ``buf`` (uint8), for every offset: one
    row gather from an overlapping (len - 7, 8) view of ``buf``."""
    rows = np.lib.stride_tricks.as_strided(buf, (max(len(buf) - 7, 0), 8), (1, 1),
                                           writeable=False)
    return rows[offs + at].view('<u8')[:, 0]


# ---------------------------------------------------------------------- bag level
def mcap_files(path: str | Path) -> tuple[list[Path], dict | None, list[str]]:
    """The MCAP file(s) of a bag directory or a bare ``.mcap``, its metadata (or None)
    and warnings; raises :class:`BagError` if there is no bag at ``path`` or a file of it
    is not a regular file (a FIFO, a device, a socket: named with its kind, never opened)."""
    p = Path(path)
    warnings: list[str] = []
    st = path_stat(p)
    if not stat.S_ISDIR(st.st_mode):
        regular_file(p)
        return [p], None, warnings
    meta = None
    meta_path = p / 'metadata.yaml'
    files: list[Path] = []
    import yaml

    try:
        text = read_metadata_text(meta_path)
    except (BagError, OSError, UnicodeDecodeError) as exc:
        warnings.append(f'{meta_path}: unreadable ({_why(exc)}); ignoring it')
        text = None
    else:
        if text is None:
            warnings.append(f'{path}: no metadata.yaml; reading the .mcap files found there')
    if text is not None:
        try:
            doc = yaml.load(text,  # libyaml when present: ~20x faster
                            Loader=getattr(yaml, 'CSafeLoader', yaml.SafeLoader))
            meta = doc['rosbag2_bagfile_information']
            files = [p / f for f in meta.get('relative_file_paths', [])]
        except (yaml.YAMLError, KeyError, TypeError, AttributeError) as exc:
            warnings.append(f'{meta_path}: unreadable ({type(exc).__name__}); ignoring it')
            meta, files = None, []
        if meta is not None and meta.get('storage_identifier') not in (None, 'mcap'):
            raise BagError(f"{path}: storage {meta.get('storage_identifier')!r} is not "
                           'supported (only mcap)')
        missing = [f for f in files if not os.path.exists(f)]
        if missing:
            warnings.append(f'{path}: files named in metadata.yaml are missing: '
                            + ', '.join(f.name for f in missing))
        files = [f for f in files if f not in missing]
    if not files:
        files = sorted(p.glob('*.mcap'))
    if not files:
        raise BagError(f'{path}: not a bag (no .mcap file)')
    for f in files:  # a FIFO, device, socket or directory is refused, never opened
        regular_file(f)
    return files, meta, warnings


def _why(exc: BaseException) -> str:
    """The reason ``exc`` gives, never empty."""
    return str(getattr(exc, 'strerror', None) or exc) or type(exc).__name__


REFERENCE_SUFFIX = 'arm_controller/reference'
TRUE_STATE_SUFFIX = 'simulator/true_joint_states'


def _positions_only(topic: str) -> bool:
    """Lean reading keeps only the positions of these JointState topics."""
    return _is_topic(topic, REFERENCE_SUFFIX) or _is_topic(topic, TRUE_STATE_SUFFIX)
_COPIED = (TRAJECTORY, PATH, POSE_STAMPED)  # message types kept as bytes until the end
EVENTS_SUFFIX = 'simulator/events'


def _copied(type_name: str, topic: str) -> bool:
    """Are the messages of ``topic`` kept as bytes until the end (then decoded)?"""
    return type_name in _COPIED or (type_name == DIAGNOSTIC_STATUS
                                    and _is_topic(topic, EVENTS_SUFFIX))


@dataclass
class _Raw:
    """Message records copied out of a chunk: ``buf`` (uint8), record ``offs`` in it."""

    buf: np.ndarray
    offs: np.ndarray


@dataclass
class _Decoded:
    """A chunk's JointStates of one channel, decoded: per joint-name set (most messages
    first) ``[names, stamp, log_time, position, velocity, effort]`` (velocity and effort
    None when not kept), and the number of undecodable messages."""

    groups: list[list]
    bad: int


def _copy_records(buf: np.ndarray, offs: np.ndarray) -> _Raw:
    """The message records at ``offs`` of ``buf`` copied into a buffer of their own."""
    sizes = 9 + _gather_u64(buf, offs, 1).astype(np.int64)
    starts = np.r_[0, np.cumsum(sizes)[:-1]].astype(np.int64)
    idx = np.repeat(offs - starts, sizes) + np.arange(int(sizes.sum()))
    return _Raw(buf[idx], starts)


def _decode_states(buf: np.ndarray, offs: np.ndarray, positions_only: bool) -> _Decoded:
    """Bulk-decode the JointState message records at ``offs`` of ``buf``; only stamps,
    receive times and positions are kept if ``positions_only``."""
    head = _headers(buf, offs)
    lengths = head['len'].astype(np.int64) - 22
    log_time = head['log'].astype(np.int64)
    groups, bad = decode_joint_states_bulk(buf, offs + 31, lengths)
    return _Decoded([[g.names, g.stamp, log_time[g.index], g.position,
                      None if positions_only else g.velocity,
                      None if positions_only else g.effort] for g in groups], bad)


def _is_topic(topic: str, suffix: str) -> bool:
    """Does ``topic`` name ``suffix`` (e.g. ``/arm2/joint_states`` for ``joint_states``)?"""
    return topic == suffix or topic.endswith('/' + suffix) or topic.lstrip('/') == suffix


class _Columns:
    """Growing (capacity, ...) arrays of ``[stamp, log_time, position, velocity, effort]``
    (None: not kept), filled piece by piece: one allocation when the capacity is known."""

    def __init__(self, capacity: int) -> None:
        self.n = 0
        self.capacity = capacity
        self.data: list[np.ndarray | None] | None = None

    def append(self, arrays: list) -> None:
        m = len(arrays[0])
        if self.data is None:
            self.capacity = max(self.capacity, m)
            self.data = [None if a is None else np.empty((self.capacity, *a.shape[1:]), a.dtype)
                         for a in arrays]
        elif self.n + m > self.capacity:
            self.capacity = max(self.n + m, self.capacity * 3 // 2 + 1024)
            for i, d in enumerate(self.data):
                if d is not None:
                    grown = np.empty((self.capacity, *d.shape[1:]), d.dtype)
                    grown[:self.n] = d[:self.n]
                    self.data[i] = grown
        for d, a in zip(self.data, arrays):
            if d is not None:
                d[self.n:self.n + m] = a
        self.n += m

    def arrays(self) -> list[np.ndarray | None]:
        """The filled rows (a copy only if over 10% of the capacity went unused)."""
        assert self.data is not None
        n = self.n
        return [None if d is None else d[:n] if n * 10 >= 9 * len(d) else d[:n].copy()
                for d in self.data]


class _States:
    """The JointStates of one channel, decoded chunk by chunk in file order into
    :class:`_Columns` per joint-name set (the first set met is the one kept)."""

    def __init__(self, positions_only: bool, capacity: int) -> None:
        self.positions_only = positions_only
        self.capacity = capacity
        self.first: tuple[str, ...] | None = None
        self.columns: dict[tuple[str, ...], _Columns] = {}
        self.bad = 0

    def add(self, buf: np.ndarray, offs: np.ndarray) -> None:
        part = _decode_states(buf, offs, self.positions_only)
        self.bad += part.bad
        for names, *arrays in part.groups:
            if self.first is None:
                self.first = names
            col = self.columns.get(names)
            if col is None:
                col = self.columns[names] = _Columns(self.capacity if names == self.first
                                                     else 0)
            col.append(arrays)


class _Collector:
    """A scan's :data:`Consumer`: per channel, in file order, its messages as each chunk
    is read: JointStates decoded at once into :class:`_States`, trajectories, paths, goals
    and messages of channels not defined yet copied (:class:`_Raw`); other types only
    counted. ``lean``: keep only stamps, receive times and positions of the reference
    and true-state topics (what :mod:`arm_bag.analysis` uses)."""

    def __init__(self, lean: bool) -> None:
        self.lean = lean
        self.counts: dict[int, int] = {}
        self.parts: dict[int, list[_Raw]] = {}
        self.states: dict[int, _States] = {}

    def __call__(self, scan: _Scan, buf: np.ndarray, found: dict[int, np.ndarray]) -> None:
        for ch, offs in found.items():
            self.counts[ch] = self.counts.get(ch, 0) + len(offs)
            c = scan.channels.get(ch)
            if c is None:
                self.parts.setdefault(ch, []).append(_copy_records(buf, offs))
            elif c.encoding != 'cdr':
                continue
            elif c.schema == JOINT_STATE:
                self._sink(ch, c, scan.hints.get(ch, 0)).add(buf, offs)
            elif _copied(c.schema, c.topic):
                self.parts.setdefault(ch, []).append(_copy_records(buf, offs))

    def _sink(self, ch: int, c: _Channel, capacity: int) -> _States:
        sink = self.states.get(ch)
        if sink is None:
            sink = self.states[ch] = _States(
                self.lean and _positions_only(c.topic), capacity)
            for raw in self.parts.pop(ch, []):  # read before its channel was defined
                sink.add(raw.buf, raw.offs)
        return sink

    def finish(self, channels: dict[int, _Channel]) -> None:
        """After the scan: decode the JointStates of channels defined after them."""
        for ch in list(self.parts):
            c = channels.get(ch)
            if c is not None and c.encoding == 'cdr' and c.schema == JOINT_STATE:
                self._sink(ch, c, 0)


def read_bag(path: str | Path, lean: bool = False) -> BagData:
    """Read the arm_sim topics of the bag at ``path`` (see the module docstring).

    Topics are chosen by type and name suffix, so namespaced runs (``/arm2/joint_states``)
    and foreign bags with a ``joint_states`` topic work: ``joint_states`` and
    ``arm_controller/reference`` (JointState), ``simulator/true_joint_states``
    (JointState, :attr:`BagData.true_joint_states`), ``joint_trajectory``
    (JointTrajectory), ``planner/path`` (Path), ``goal_pose`` (PoseStamped),
    ``simulator/events`` (DiagnosticStatus, :attr:`BagData.events`).

    ``lean``: of the reference and true-state topics keep only what
    :mod:`arm_bag.analysis` uses (stamps, receive times, positions); their ``velocity``
    and ``effort`` are then read-only NaN views that take no memory.
    """
    sqlite_bag = _sqlite_files(path)
    if sqlite_bag is not None:
        return _read_sqlite(path, *sqlite_bag, lean)
    files, meta, warnings = mcap_files(path)
    bag = BagData(str(path), warnings=warnings)
    state = _recording_state(Path(path), files)
    per_topic: dict[str, list] = {}
    for f in files:
        scan, found = _open_scan(f, path, state, bag, lean)
        found.finish(scan.channels)
        bag.warnings += scan.warnings
        bag.truncated |= scan.truncated
        if ROBOT_RECORD in scan.metadata and bag.robot is None:
            bag.robot = _robot(scan.metadata[ROBOT_RECORD])
        for ch, n in found.counts.items():
            channel = scan.channels.get(ch)
            if channel is None:
                bag.warnings.append(f'{f.name}: messages on unknown channel {ch} skipped')
                continue
            t, count = bag.topics.get(channel.topic, (channel.schema, 0))
            bag.topics[channel.topic] = (t, count + n)
            bag.message_count += n
            if channel.encoding == 'cdr' and ch in found.states:
                per_topic.setdefault(channel.topic, []).append(found.states[ch])
            elif channel.encoding == 'cdr' and ch in found.parts:
                per_topic.setdefault(channel.topic, []).extend(found.parts[ch])
    if meta is not None and not bag.truncated and state != RECORDING_OPEN:
        expected = meta.get('message_count')
        if isinstance(expected, int) and expected != bag.message_count:
            bag.warnings.append(f'{path}: metadata.yaml counts {expected} messages, the '
                                f'file holds {bag.message_count}')
    bag.lost = _lost(meta)
    for topic, n in sorted(bag.lost.items()):
        bag.warnings.append(f'{topic}: {n} messages were lost before the recorder (counted '
                            'by it from publisher sequence gaps and DDS loss events)')
    _decode_topics(bag, per_topic, lean)
    return bag


def _sqlite_files(path: str | Path) -> tuple[list[Path], dict | None] | None:
    """The ``.db3`` files and metadata of a rosbag2 sqlite3 bag at ``path`` (a directory or
    a ``.db3`` file), or None if it is not one (:func:`arm_bag.sqlite.is_sqlite_bag`)."""
    from arm_bag.sqlite import is_sqlite_bag

    p = Path(path)
    if not p.is_dir():
        return ([p], None) if is_sqlite_bag(p, None) and regular_file(p) else None
    meta = None
    try:
        import yaml
        text = read_metadata_text(p / 'metadata.yaml')
        doc = yaml.safe_load(text) if text else None
        meta = doc['rosbag2_bagfile_information'] if isinstance(doc, dict) else None
    except (BagError, OSError, UnicodeDecodeError, KeyError, TypeError, ValueError):
        meta = None
    storage = meta.get('storage_identifier') if isinstance(meta, dict) else None
    if not is_sqlite_bag(p, storage if isinstance(storage, str) else None):
        return None
    named = meta.get('relative_file_paths') if isinstance(meta, dict) else None
    files = ([p / str(f) for f in named if (p / str(f)).exists()]
             if isinstance(named, list) else []) or sorted(p.glob('*.db3'))
    if not files:
        raise BagError(f'{path}: a sqlite3 bag without its .db3 file')
    for f in files:
        regular_file(f)
    return files, meta


def _read_sqlite(path: str | Path, files: list[Path], meta: dict | None,
                 lean: bool) -> BagData:
    """:func:`read_bag` for rosbag2's sqlite3 storage (:mod:`arm_bag.sqlite`): the same
    decoding, from records laid out as MCAP's."""
    from arm_bag.sqlite import read_db3

    bag = BagData(str(path))
    per_topic: dict[str, list] = {}
    for f in files:
        for t in read_db3(f):
            n = len(t.offs)
            old_type, count = bag.topics.get(t.name, (t.type_name, 0))
            bag.topics[t.name] = (old_type, count + n)
            bag.message_count += n
            if t.serialization != 'cdr':
                bag.warnings.append(f'{f.name}: {t.name} is {t.serialization!r}, not cdr: '
                                    'skipped')
            elif t.type_name == JOINT_STATE:
                sink = _States(lean and _positions_only(t.name), n)
                sink.add(t.buf, t.offs)
                per_topic.setdefault(t.name, []).append(sink)
            elif _copied(t.type_name, t.name):
                per_topic.setdefault(t.name, []).append(_Raw(t.buf, t.offs))
    if meta is not None:
        expected = meta.get('message_count')
        if isinstance(expected, int) and expected != bag.message_count:
            bag.warnings.append(f'{path}: metadata.yaml counts {expected} messages, the '
                                f'file holds {bag.message_count}')
    _decode_topics(bag, per_topic, lean)
    return bag


def _recording_state(path: Path, files: list[Path]) -> str | None:
    """The recording marker that applies to ``path``: a bag directory's own, or, for an
    ``.mcap`` file, that of the bag directory whose ``metadata.yaml`` lists it (so a killed
    recording is recovered whether its directory or its file is named)."""
    if path.is_dir():
        return recording_state(path)
    bag_dir = path.parent
    try:
        import yaml

        text = read_metadata_text(bag_dir / 'metadata.yaml')
        doc = yaml.load(text or '', Loader=getattr(yaml, 'CSafeLoader', yaml.SafeLoader))
        listed = doc['rosbag2_bagfile_information'].get('relative_file_paths') or []
    except (BagError, OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError,
            AttributeError):
        return None
    names = {(bag_dir / f).resolve() for f in listed if isinstance(f, str)}
    if all(f.resolve() in names for f in files):
        return recording_state(bag_dir)
    return None


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


def _read(f: Path) -> bytes | mmap.mmap:
    """The file's bytes: memory-mapped from :data:`MMAP_MIN_BYTES` on, else read (only a
    regular file: :func:`arm_bag.bagfile.open_regular`)."""
    fd = open_regular(f)
    try:
        with os.fdopen(fd, 'rb') as fh:
            size = os.fstat(fh.fileno()).st_size
            if size >= max(MMAP_MIN_BYTES, 1):
                return mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
            return fh.read(size)
    except (OSError, ValueError) as exc:
        raise BagError(f'{f}: cannot read: {_why(exc)}') from None


def _open_scan(f: Path, path: str | Path, state: str | None, bag: BagData,
               lean: bool = False) -> tuple[_Scan, _Collector]:
    """Scan the MCAP file ``f`` of the bag at ``path`` (recording marker ``state``), its
    messages taken by a :class:`_Collector` (``lean`` as in :func:`read_bag`).

    A bag marked as being recorded is read up to its last complete record while its
    recorder holds the file's lock, and recovered in place first when the recorder died
    (:func:`arm_bag.recover.recover_bag`); any other damaged file raises BagError.
    """
    data = _read(f)
    found = _Collector(lean)
    if state != RECORDING_OPEN:
        return _Scan(data, str(f), hint=str(path), consume=found), found
    if is_locked(f):
        scan = _Scan(data, str(f), live=True, hint=str(path), consume=found)
        bag.truncated |= scan.truncated
        bag.warnings.append(f'{f}: still being recorded (a recorder holds its lock): read '
                            f'up to its last complete record, byte {scan.end} of {len(data)}')
        return scan, found
    try:
        return _Scan(data, str(f), hint=str(path), consume=found), found
    except BagError as exc:
        damage = str(exc)
    del data  # let the mapping go before the file is repaired
    from arm_bag.recover import RecoveryError, recover_bag

    try:
        report = recover_bag(f)
    except (RecoveryError, OSError) as exc:
        raise BagError(f'{damage} (automatic recovery failed: {exc})') from None
    bag.warnings.append(f'{f}: recovered unfinished recording: {report.summary()}')
    found = _Collector(lean)  # what the damaged file's scan took is dropped
    return _Scan(_read(f), str(f), hint=str(path), consume=found), found


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
    found = [t for t, (ty, _) in bag.topics.items() if ty == type_name and _is_topic(t, suffix)]
    if not found:
        return None
    found.sort(key=lambda t: (-bag.topics[t][1], t))
    if len(found) > 1:
        bag.warnings.append(f'several {suffix} topics ({", ".join(found)}); using '
                            f'{found[0]}')
    return found[0]


def _raw_messages(parts: list) -> list[tuple[int, bytes]]:
    """(log_time, data) of every message in ``parts`` (:class:`_Raw`), by receive time."""
    out = []
    for part in parts:
        buf = part.buf
        for o in part.offs.tolist():
            length = _U64.unpack_from(buf, o + 1)[0]
            log_time = _U64.unpack_from(buf, o + 15)[0]
            out.append((log_time, buf[o + 31:o + 9 + length].tobytes()))
    out.sort(key=lambda m: m[0])
    return out


def _joint_states(bag: BagData, topic: str, sinks: list[_States]) -> JointStates | None:
    """The JointStates of ``topic`` from its channels' :class:`_States` in file order: the
    first joint-name set met is kept (others counted in a warning); by receive time."""
    names = next((k.first for k in sinks if k.first is not None), None)
    bad = sum(k.bad for k in sinks)
    other = sum(c.n for k in sinks for nm, c in k.columns.items() if nm != names)
    if bad:
        bag.warnings.append(f'{topic}: {bad} messages could not be decoded as JointState')
    if other:
        bag.warnings.append(f'{topic}: {other} messages with joint names other than '
                            f'{list(names or ())} ignored')
    if names is None:
        return None
    parts = [k.columns[names].arrays() for k in sinks if names in k.columns]
    count = sum(k.columns[names].n for k in sinks if names in k.columns)

    def take(i: int) -> np.ndarray | None:
        arrays = [p[i] for p in parts]
        for p in parts:
            p[i] = None
        if arrays[0] is None:
            return None
        return arrays[0] if len(arrays) == 1 else np.concatenate(arrays)  # type: ignore

    log = take(1)
    assert log is not None
    order = None
    if len(log) > 1 and not (log[1:] >= log[:-1]).all():  # else already by receive time
        order = np.argsort(log, kind='stable')
        log = log[order]

    def field(i: int) -> np.ndarray:
        a = take(i)
        if a is None:  # not kept: a read-only NaN view, no memory
            return np.broadcast_to(np.float64(np.nan), (count, len(names)))
        return a if order is None else a[order]

    stamp = field(0)
    return JointStates(topic, names, stamp, log, field(2), field(3), field(4))


def _decode_topics(bag: BagData, per_topic: dict[str, list], lean: bool = False) -> None:
    js = _pick(bag, JOINT_STATE, 'joint_states')
    if js and js in per_topic:
        bag.joint_states = _joint_states(bag, js, per_topic.pop(js))
    ref = _pick(bag, JOINT_STATE, REFERENCE_SUFFIX)
    if ref and ref in per_topic:
        bag.reference = _joint_states(bag, ref, per_topic.pop(ref))
    true = _pick(bag, JOINT_STATE, TRUE_STATE_SUFFIX)
    if true and true in per_topic:
        bag.true_joint_states = _joint_states(bag, true, per_topic.pop(true))
    decoders = (('joint_trajectory', TRAJECTORY, decode_joint_trajectory,
                 lambda t, m: bag.trajectories.append(TrajectoryMsg(t, m))),
                ('planner/path', PATH, decode_path,
                 lambda t, m: bag.paths.append(PathMsg(t, m[1], m[2], m[0], m[3]))),
                ('goal_pose', POSE_STAMPED, decode_pose_stamped,
                 lambda t, m: bag.goals.append(GoalMsg(t, m[1], m[2], m[3]))),
                (EVENTS_SUFFIX, DIAGNOSTIC_STATUS, decode_diagnostic_status,
                 lambda t, m: bag.events.append(sim_event(m))))
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
            what = ('simulator events (DiagnosticStatus with an integer time_ns and an '
                    'edge)' if suffix == EVENTS_SUFFIX else type_name)
            bag.warnings.append(f'{topic}: {bad} messages could not be decoded as {what}')
    bag.events.sort(key=lambda e: e.time_ns)  # stable: at one time, as received
