"""CDR decoding of the message types the analysis needs (pure, numpy only).

Two paths:

* :func:`decode_joint_states_bulk` decodes many ``sensor_msgs/JointState`` messages of equal
  length at once: the CDR layout of a JointState is fixed once its frame id, joint names and
  array lengths are, so a group of equal-length messages is viewed as a numpy structured
  array at the offsets found in the first message. Every message of the group is validated
  (all bytes other than the stamp and the float64 values must equal the template's);
  those that differ are decoded one by one.
* Per-message decoders (:func:`decode_joint_state`, :func:`decode_joint_trajectory`,
  :func:`decode_path`, :func:`decode_pose_stamped`, :func:`decode_diagnostic_status`) for
  everything else.

CDR (XCDR1, little endian, as ROS 2 writes it): a 4-byte encapsulation header
``00 01 00 00``, then the fields; primitives are aligned to their size relative to the
byte after the header; strings are a uint32 length (including the NUL) and the bytes;
sequences a uint32 count and the elements. Malformed input raises :class:`CdrError`.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

_U32 = struct.Struct('<I')
_I32U32 = struct.Struct('<iI')


class CdrError(ValueError):
    """A message is not the CDR encoding of the expected type."""


class Cursor:
    """Reads little-endian CDR from ``data`` (bytes-like, including the 4-byte header)."""

    __slots__ = ('data', 'pos', 'end', 'gaps')

    def __init__(self, data: bytes | memoryview) -> None:
        if len(data) < 4:
            raise CdrError(f'message of {len(data)} bytes is shorter than the CDR header')
        if data[0] != 0 or data[1] != 1:
            raise CdrError(f'unsupported CDR encapsulation {bytes(data[:2]).hex()} '
                           '(only little-endian CDR, 0001)')
        self.data = data
        self.pos = 4
        self.end = len(data)
        self.gaps: list[tuple[int, int]] = []  # padding (start, end): may hold any bytes

    def align(self, n: int) -> None:
        pad = (-(self.pos - 4)) % n
        if pad:
            self.gaps.append((self.pos, self.pos + pad))
            self.pos += pad

    def _need(self, n: int) -> None:
        if self.pos + n > self.end:
            raise CdrError(f'message truncated: needs {n} bytes at offset {self.pos}, '
                           f'has {self.end - self.pos}')

    def byte(self) -> int:
        """A ``byte``/``uint8`` (no alignment)."""
        self._need(1)
        v = self.data[self.pos]
        self.pos += 1
        return int(v)

    def u32(self) -> int:
        self.align(4)
        self._need(4)
        (v,) = _U32.unpack_from(self.data, self.pos)
        self.pos += 4
        return v

    def time(self) -> int:
        """builtin_interfaces/Time or Duration as integer nanoseconds."""
        self.align(4)
        self._need(8)
        sec, nsec = _I32U32.unpack_from(self.data, self.pos)
        self.pos += 8
        return sec * 1_000_000_000 + nsec

    def string(self) -> str:
        n = self.u32()
        self._need(n)
        raw = bytes(self.data[self.pos:self.pos + n])
        self.pos += n
        return raw[:-1].decode('utf-8', 'replace') if n else ''

    def strings(self) -> list[str]:
        return [self.string() for _ in range(self.u32())]

    def float64s(self) -> np.ndarray:
        n = self.u32()
        if n:
            self.align(8)
        self._need(8 * n)
        out = np.frombuffer(self.data, '<f8', n, self.pos).copy()
        self.pos += 8 * n
        return out

    def float64(self, count: int) -> tuple[float, ...]:
        self.align(8)
        self._need(8 * count)
        out = struct.unpack_from(f'<{count}d', self.data, self.pos)
        self.pos += 8 * count
        return out

    def header(self) -> tuple[int, str]:
        stamp = self.time()
        return stamp, self.string()


@dataclass(frozen=True)
class JointStateLayout:
    """Byte offsets (from the start of the message, header included) of one JointState."""

    length: int
    names: tuple[str, ...]
    position: tuple[int, int]   # (offset of the float64 data, count)
    velocity: tuple[int, int]
    effort: tuple[int, int]
    gaps: tuple[tuple[int, int], ...] = ()


def decode_joint_state(data: bytes | memoryview):
    """One JointState -> (stamp [ns], names, position, velocity, effort, layout)."""
    c = Cursor(data)
    stamp, _frame = c.header()
    names = tuple(c.strings())
    fields = []
    arrays = []
    for _ in range(3):
        n = c.u32()
        if n:
            c.align(8)
        fields.append((c.pos, n))
        c._need(8 * n)
        arrays.append(np.frombuffer(data, '<f8', n, c.pos).copy())
        c.pos += 8 * n
    if c.end - c.pos > 7:
        raise CdrError(f'{c.end - c.pos} bytes after the end of a JointState')
    if c.end > c.pos:  # trailing padding
        c.gaps.append((c.pos, c.end))
    layout = JointStateLayout(len(data), names, fields[0], fields[1], fields[2],
                              tuple(c.gaps))
    return stamp, names, arrays[0], arrays[1], arrays[2], layout


@dataclass
class JointStateArrays:
    """Decoded JointStates of one joint-name set: ``stamp`` (N,) int64 ns, ``index`` (N,)
    positions in the input, ``position``/``velocity``/``effort`` (N, J) float64 (NaN where
    a message left the array empty)."""

    names: tuple[str, ...]
    index: np.ndarray
    stamp: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray


def _bulk_group(rows: np.ndarray, layout: JointStateLayout, template: np.ndarray):
    """Decode an (M, L) uint8 block laid out like ``layout``; returns (ok mask, stamp,
    [pos, vel, eff]) with arrays only for the rows that validated."""
    length = layout.length
    const = np.ones(length, bool)
    const[4:12] = False  # header.stamp
    for off, n in (layout.position, layout.velocity, layout.effort):
        const[off:off + 8 * n] = False
    for a, b in layout.gaps:
        const[a:b] = False
    # A row is valid iff (row XOR template) AND mask is zero, mask = 0xff on the constant
    # bytes: computed on whole words, one pass; rows are told apart only if one differs.
    rows = np.ascontiguousarray(rows)
    word = next(w for w in (8, 4, 2, 1) if length % w == 0)
    wtype = np.dtype(f'<u{word}')
    mask = np.where(const, np.uint8(0xFF), np.uint8(0)).view(wtype)
    diff = rows.view(wtype) ^ template.view(wtype)
    diff &= mask
    if diff.any():
        ok = ~diff.any(axis=1)
        good = rows[ok]
    else:
        ok = np.ones(len(rows), bool)
        good = rows
    fields: dict[str, tuple[Any, int]] = {'sec': ('<i4', 4), 'nsec': ('<u4', 8)}
    for key, (off, n) in zip(('p', 'v', 'e'), (layout.position, layout.velocity,
                                               layout.effort)):
        if n:
            fields[key] = (('<f8', (n,)), off)
    dtype = np.dtype({'names': list(fields), 'formats': [f[0] for f in fields.values()],
                      'offsets': [f[1] for f in fields.values()], 'itemsize': length})
    rec = good.view(dtype)[:, 0]
    stamp = rec['sec'].astype(np.int64) * 1_000_000_000 + rec['nsec']
    width = len(layout.names)
    out = []
    for key in ('p', 'v', 'e'):
        if key in fields and fields[key][0][1][0] == width:
            out.append(np.array(rec[key], dtype=np.float64))
        else:
            out.append(np.full((len(good), width), np.nan))
    return ok, stamp, out


def decode_joint_states_bulk(buf: np.ndarray, offsets: np.ndarray,
                             lengths: np.ndarray) -> tuple[list[JointStateArrays], int]:
    """Decode JointStates stored in ``buf`` (uint8) at ``offsets`` with ``lengths`` bytes.

    Returns one :class:`JointStateArrays` per joint-name set (most messages first) and the
    number of undecodable messages. ``index`` in each refers to positions in ``offsets``.
    """
    offsets = np.asarray(offsets, np.int64)
    lengths = np.asarray(lengths, np.int64)
    by_names: dict[tuple[str, ...], list] = {}
    bad = 0
    singles: list[int] = []
    uniq = [int(lengths[0])] if len(lengths) and (lengths == lengths[0]).all() else (
        np.unique(lengths).tolist())
    for length in uniq:
        idx = np.arange(len(lengths)) if len(uniq) == 1 else np.flatnonzero(lengths == length)
        first = int(offsets[idx[0]])
        try:
            *_, layout = decode_joint_state(buf[first:first + length].data)
        except CdrError:
            singles.extend(idx.tolist())
            continue
        if length < 16 or len(buf) < length:
            singles.extend(idx.tolist())
            continue
        view = np.lib.stride_tricks.as_strided(buf, (len(buf) - length + 1, length), (1, 1))
        rows = view[offsets[idx]]
        ok, stamp, arrays = _bulk_group(rows, layout, rows[0].copy())
        by_names.setdefault(layout.names, []).append((idx[ok], stamp, *arrays))
        singles.extend(idx[~ok].tolist())
    for i in singles:
        off, n = int(offsets[i]), int(lengths[i])
        try:
            stamp, names, p, v, e, _ = decode_joint_state(buf[off:off + n].data)
        except CdrError:
            bad += 1
            continue
        width = len(names)
        arrays = [a[None, :] if len(a) == width else np.full((1, width), np.nan)
                  for a in (p, v, e)]
        by_names.setdefault(names, []).append((np.array([i]), np.array([stamp]), *arrays))
    result = []
    for names, parts in by_names.items():
        if len(parts) == 1:  # one length, all valid: already in order, nothing to copy
            result.append(JointStateArrays(names, *parts[0]))
            continue
        index = np.concatenate([p[0] for p in parts])
        order = np.argsort(index, kind='stable')
        cat = [np.concatenate([p[k] for p in parts])[order] for k in range(1, 5)]
        result.append(JointStateArrays(names, index[order], *cat))
    result.sort(key=lambda r: -len(r.index))
    return result, bad


@dataclass
class JointTrajectoryMsg:
    """A decoded trajectory_msgs/JointTrajectory: ``positions`` (P, J) rad,
    ``time_from_start`` (P,) s; ``stamp`` [ns] (0 = start now); ``velocities`` [rad/s] and
    ``accelerations`` [rad/s^2]: per point, as received (possibly empty). Not the
    controller's :class:`arm_control.trajectory.Trajectory`, which samples a motion."""

    stamp: int
    joint_names: tuple[str, ...]
    positions: np.ndarray
    time_from_start: np.ndarray
    velocities: tuple[np.ndarray, ...] = ()
    accelerations: tuple[np.ndarray, ...] = ()


def decode_joint_trajectory(data: bytes | memoryview) -> JointTrajectoryMsg:
    c = Cursor(data)
    stamp, _ = c.header()
    names = tuple(c.strings())
    rows, times, vels, accs = [], [], [], []
    for _ in range(c.u32()):
        pos = c.float64s()
        vels.append(c.float64s())
        accs.append(c.float64s())
        c.float64s()
        rows.append(pos)
        times.append(c.time() * 1e-9)
    width = len(names)
    if any(len(r) != width for r in rows):
        raise CdrError(f'trajectory point positions do not match the {width} joint names')
    positions = np.array(rows, dtype=np.float64).reshape(len(rows), width)
    return JointTrajectoryMsg(stamp, names, positions, np.array(times, dtype=np.float64),
                              tuple(vels), tuple(accs))


def _pose_xy(c: Cursor) -> tuple[float, float]:
    x, y, _z = c.float64(3)
    c.float64(4)
    return x, y


def decode_path(data: bytes | memoryview) -> tuple[int, str, np.ndarray, int]:
    """nav_msgs/Path -> (stamp [ns], frame_id, xy (P, 2) m, the first pose's stamp [ns],
    or the path's when it has no pose)."""
    c = Cursor(data)
    stamp, frame = c.header()
    xy = []
    first = stamp
    for k in range(c.u32()):
        pose_stamp, _ = c.header()
        first = pose_stamp if k == 0 else first
        xy.append(_pose_xy(c))
    return stamp, frame, np.array(xy, dtype=np.float64).reshape(len(xy), 2), first


def decode_pose_stamped(data: bytes | memoryview) -> tuple[int, str, float, float]:
    """geometry_msgs/PoseStamped -> (stamp [ns], frame_id, x [m], y [m])."""
    c = Cursor(data)
    stamp, frame = c.header()
    x, y = _pose_xy(c)
    return stamp, frame, x, y


@dataclass(frozen=True)
class DiagnosticStatusMsg:
    """A decoded diagnostic_msgs/DiagnosticStatus: ``level`` (0 OK, 1 WARN, 2 ERROR, 3
    STALE), ``name``, ``message``, ``hardware_id`` and ``values``, the (key, value) string
    pairs in message order."""

    level: int
    name: str
    message: str
    hardware_id: str
    values: tuple[tuple[str, str], ...] = ()

    def value(self, key: str, default: str | None = None) -> str | None:
        """The value of the first pair with ``key`` (``default`` if none)."""
        return next((v for k, v in self.values if k == key), default)


def decode_diagnostic_status(data: bytes | memoryview) -> DiagnosticStatusMsg:
    """diagnostic_msgs/DiagnosticStatus: byte level, string name, string message, string
    hardware_id, KeyValue[] values (KeyValue: string key, string value)."""
    c = Cursor(data)
    level = c.byte()
    name, message, hardware_id = c.string(), c.string(), c.string()
    values = tuple((c.string(), c.string()) for _ in range(c.u32()))
    if c.end - c.pos > 7:
        raise CdrError(f'{c.end - c.pos} bytes after the end of a DiagnosticStatus')
    return DiagnosticStatusMsg(level, name, message, hardware_id, values)


# ---------------------------------------------------------------------- encoding
class Writer:
    """Builds little-endian CDR (with the 4-byte header), for tests and benchmarks."""

    def __init__(self) -> None:
        self.buf = bytearray(b'\x00\x01\x00\x00')

    def align(self, n: int) -> None:
        self.buf += b'\x00' * ((-(len(self.buf) - 4)) % n)

    def byte(self, v: int) -> None:
        self.buf += bytes((int(v) & 0xFF,))

    def u32(self, v: int) -> None:
        self.align(4)
        self.buf += _U32.pack(v)

    def time(self, ns: int) -> None:
        self.align(4)
        sec, nsec = divmod(int(ns), 1_000_000_000)
        self.buf += _I32U32.pack(sec, nsec)

    def string(self, s: str) -> None:
        b = s.encode() + b'\x00'
        self.u32(len(b))
        self.buf += b

    def float64s(self, values, with_count: bool = True) -> None:
        values = [float(v) for v in values]
        if with_count:
            self.u32(len(values))
        if values:
            self.align(8)
            self.buf += struct.pack(f'<{len(values)}d', *values)

    def header(self, stamp_ns: int, frame_id: str = '') -> None:
        self.time(stamp_ns)
        self.string(frame_id)


def encode_joint_state(stamp_ns: int, names, position, velocity, effort,
                       frame_id: str = '') -> bytes:
    """sensor_msgs/JointState as CDR bytes."""
    w = Writer()
    w.header(stamp_ns, frame_id)
    w.u32(len(names))
    for n in names:
        w.string(n)
    for arr in (position, velocity, effort):
        w.float64s(arr)
    return bytes(w.buf)


def encode_joint_trajectory(stamp_ns: int, names, positions, times_s,
                            velocities=None) -> bytes:
    """trajectory_msgs/JointTrajectory (positions, and ``velocities`` per point if given)
    as CDR bytes."""
    w = Writer()
    w.header(stamp_ns)
    w.u32(len(names))
    for n in names:
        w.string(n)
    w.u32(len(positions))
    for k, (row, t) in enumerate(zip(positions, times_s)):
        w.float64s(row)
        w.float64s([] if velocities is None else velocities[k])
        for _ in range(2):
            w.float64s([])
        w.time(int(round(t * 1e9)))
    return bytes(w.buf)


def encode_path(stamp_ns: int, xy, frame_id: str = 'base_link',
                pose_stamp_ns: int | None = None) -> bytes:
    """nav_msgs/Path of planar poses (z = 0, identity orientation) as CDR bytes; the poses
    are stamped ``pose_stamp_ns`` (default: the path's stamp)."""
    w = Writer()
    w.header(stamp_ns, frame_id)
    w.u32(len(xy))
    for x, y in xy:
        w.header(stamp_ns if pose_stamp_ns is None else pose_stamp_ns, frame_id)
        w.float64s([x, y, 0.0, 0.0, 0.0, 0.0, 1.0], with_count=False)
    return bytes(w.buf)



def encode_diagnostic_status(level: int, name: str, message: str, hardware_id: str = '',
                             values=()) -> bytes:
    """diagnostic_msgs/DiagnosticStatus as CDR bytes; ``values``: (key, value) string pairs
    or a mapping."""
    pairs = list(values.items()) if hasattr(values, 'items') else list(values)
    w = Writer()
    w.byte(level)
    for text in (name, message, hardware_id):
        w.string(text)
    w.u32(len(pairs))
    for key, value in pairs:
        w.string(str(key))
        w.string(str(value))
    return bytes(w.buf)
