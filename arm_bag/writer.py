"""rosbag2 bag writer: ``<dir>/<name>_0.mcap`` + ``<dir>/metadata.yaml`` (pure, no rclpy).

The MCAP file follows the ``ros2`` profile as rosbag2 (Jazzy) writes it: schema encoding
``ros2msg``, message encoding ``cdr``, channel metadata ``offered_qos_profiles`` and
``topic_type_hash``, and on close a metadata record ``rosbag2`` whose
``serialized_metadata`` is the bag metadata YAML. ``metadata.yaml`` is rosbag2 metadata
version 9.

Durability: messages are buffered in a chunk that is written when it exceeds
``chunk_size`` bytes or when :meth:`BagWriter.flush` is called (the recorder calls it on a
wall-clock timer); each flush also rewrites ``metadata.yaml`` (atomically) with the counts
written so far. A process killed without warning therefore loses only the messages since
the last flush, and the file up to that point is a readable (if footer-less) MCAP file.
If a write fails (e.g. ENOSPC), the file is truncated back to the end of the last complete
chunk, :class:`BagWriteError` is raised, and :meth:`BagWriter.close` then writes what it
can (summary and footer) so the bag stays readable.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np
import yaml

MAGIC = b'\x89MCAP0\r\n'
LIBRARY = 'arm_sim arm_bag'
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 1, 2, 3, 4, 5, 6
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_STATISTICS, OP_METADATA = 7, 8, 11, 12
OP_METADATA_INDEX, OP_SUMMARY_OFFSET, OP_DATA_END = 13, 14, 15
COMPRESSIONS = ('none', 'zstd', 'lz4')
_MSG_HEAD = struct.Struct('<BQHIQQ')  # opcode, length, channel, sequence, log, publish


class BagWriteError(OSError):
    """Writing the bag failed (e.g. the disk is full); the bag was left readable."""


def _str(s: str) -> bytes:
    b = s.encode()
    return struct.pack('<I', len(b)) + b


def _map_str(d: dict[str, str]) -> bytes:
    body = b''.join(_str(k) + _str(v) for k, v in d.items())
    return struct.pack('<I', len(body)) + body


def _record(op: int, body: bytes) -> bytes:
    return struct.pack('<BQ', op, len(body)) + body


@dataclass
class Topic:
    """One recorded topic (an MCAP channel)."""

    channel_id: int
    name: str
    type: str
    qos: str
    type_hash: str
    count: int = 0       # messages written to the file
    pending: int = 0     # messages in the open chunk


class BagWriter:
    """Write a rosbag2 bag directory with one MCAP file.

    Parameters
    ----------
    directory : str or Path
        The bag directory; it must not exist (FileExistsError naming it).
    chunk_size : int, bytes
        A chunk is written once its uncompressed size reaches this.
    compression : {'none', 'zstd', 'lz4'}
        Chunk compression.
    ros_distro : str
        Written to ``metadata.yaml``.
    """

    def __init__(self, directory: str | os.PathLike, *, chunk_size: int = 256 * 1024,
                 compression: str = 'none', ros_distro: str = 'jazzy') -> None:
        if compression not in COMPRESSIONS:
            raise ValueError(f'compression must be one of {COMPRESSIONS}, got {compression!r}')
        if int(chunk_size) < 1:
            raise ValueError(f'chunk_size must be >= 1 byte, got {chunk_size!r}')
        self.directory = Path(directory)
        if self.directory.exists():
            raise FileExistsError(f'output {str(self.directory)!r} already exists')
        self.directory.mkdir(parents=True)
        self.name = self.directory.name or 'bag'
        self.file_name = f'{self.name}_0.mcap'
        self.path = self.directory / self.file_name
        self.chunk_size = int(chunk_size)
        self.compression = compression
        self.ros_distro = ros_distro
        self._compress = _compressor(compression)
        self.topics: dict[str, Topic] = {}
        self._schemas: dict[str, int] = {}
        self._schema_records: list[bytes] = []
        self._channel_records: list[bytes] = []
        self._chunk_indexes: list[bytes] = []
        self._metadata_indexes: list[bytes] = []
        self._chunk = bytearray()
        self._chunk_index: dict[int, list[tuple[int, int]]] = {}
        self._chunk_times: list[int] = []
        self.message_count = 0           # written to the file
        self.start_ns: int | None = None
        self.end_ns: int | None = None
        self.chunk_count = 0
        self.metadata_count = 0
        self.failed: str | None = None
        self.closed = False
        self._file: BinaryIO = open(self.path, 'wb')  # closed in close()
        self._good = 0  # file offset after the last complete record group
        self._write(MAGIC + _record(OP_HEADER, _str('ros2') + _str(LIBRARY)))

    # ------------------------------------------------------------------ low level
    def _write(self, data: bytes | bytearray) -> None:
        if self.failed:
            raise BagWriteError(self.failed)
        try:
            self._file.write(data)
            self._file.flush()
        except OSError as exc:
            self._fail(exc)
        self._good = self._file.tell()

    def _fail(self, exc: OSError) -> None:
        self.failed = (f'writing {self.path} failed: {exc.strerror or exc}; recording '
                       f'stopped, {self.message_count} messages kept')
        try:  # the buffered file may still hold the failed bytes: drop it
            self._file.close()
        except OSError:
            pass
        try:  # reopen and cut the partial record so the file ends on a record boundary
            self._file = open(self.path, 'r+b')
            self._file.truncate(self._good)
            self._file.seek(self._good)
        except OSError:
            pass
        raise BagWriteError(exc.errno, self.failed) from exc

    # ------------------------------------------------------------------ topics
    def add_topic(self, name: str, type_name: str, schema: str, qos: str = '',
                  type_hash: str = '') -> int:
        """Register ``name`` (type ``pkg/msg/Type``, ``ros2msg`` schema text, QoS YAML text,
        RIHS01 hash); returns its channel id. Adding a known topic returns the same id."""
        if name in self.topics:
            return self.topics[name].channel_id
        schema_id = self._schemas.get(type_name)
        records = b''
        if schema_id is None:
            schema_id = len(self._schemas) + 1
            self._schemas[type_name] = schema_id
            rec = _record(OP_SCHEMA, struct.pack('<H', schema_id) + _str(type_name)
                          + _str('ros2msg') + _str(schema))
            self._schema_records.append(rec)
            records += rec
        channel_id = len(self.topics) + 1
        rec = _record(OP_CHANNEL, struct.pack('<HH', channel_id, schema_id) + _str(name)
                      + _str('cdr') + _map_str({'offered_qos_profiles': qos,
                                                 'topic_type_hash': type_hash}))
        self._channel_records.append(rec)
        self._write(records + rec)
        self.topics[name] = Topic(channel_id, name, type_name, qos, type_hash)
        self._chunk_index[channel_id] = []
        return channel_id

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Write an MCAP metadata record ``name`` (string keys and values) now."""
        self.flush_chunk()
        offset = self._file.tell()
        rec = _record(OP_METADATA, _str(name) + _map_str({str(k): str(v)
                                                          for k, v in data.items()}))
        self._write(rec)
        self.metadata_count += 1
        self._metadata_indexes.append(_record(
            OP_METADATA_INDEX, struct.pack('<QQ', offset, len(rec)) + _str(name)))

    # ------------------------------------------------------------------ messages
    def write(self, channel_id: int, data: bytes, log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        """Append one serialized (CDR) message received at ``log_time_ns`` [ns]."""
        chunk = self._chunk
        self._chunk_index[channel_id].append((log_time_ns, len(chunk)))
        self._chunk_times.append(log_time_ns)
        chunk += _MSG_HEAD.pack(OP_MESSAGE, 22 + len(data), channel_id, 0, log_time_ns,
                                log_time_ns if publish_time_ns is None else publish_time_ns)
        chunk += data
        if len(chunk) >= self.chunk_size:
            self.flush_chunk()

    def flush_chunk(self) -> None:
        """Write the open chunk (if any) and its message indexes to the file."""
        if not self._chunk_times:
            return
        raw = bytes(self._chunk)
        start, end = min(self._chunk_times), max(self._chunk_times)
        data = self._compress(raw)
        chunk_start = self._file.tell()
        body = (struct.pack('<QQQI', start, end, len(raw), 0) + _str(self.compression
                if self.compression != 'none' else '') + struct.pack('<Q', len(data)))
        head = struct.pack('<BQ', OP_CHUNK, len(body) + len(data)) + body
        parts = [head, data]
        index_offsets = {}
        pos = chunk_start + len(head) + len(data)
        counts = {}
        for ch, entries in self._chunk_index.items():
            if not entries:
                continue
            arr = np.asarray(entries, dtype='<u8').tobytes()
            rec = _record(OP_MESSAGE_INDEX, struct.pack('<HI', ch, len(arr)) + arr)
            index_offsets[ch] = pos
            pos += len(rec)
            parts.append(rec)
            counts[ch] = len(entries)
        index_length = pos - (chunk_start + len(head) + len(data))
        self._write(b''.join(parts))
        offsets = b''.join(struct.pack('<HQ', ch, off) for ch, off in index_offsets.items())
        self._chunk_indexes.append(_record(OP_CHUNK_INDEX, struct.pack(
            '<QQQQ', start, end, chunk_start, len(head) + len(data))
            + struct.pack('<I', len(offsets)) + offsets + struct.pack('<Q', index_length)
            + _str(self.compression if self.compression != 'none' else '')
            + struct.pack('<QQ', len(data), len(raw))))
        self.chunk_count += 1
        by_id = {t.channel_id: t for t in self.topics.values()}
        for ch, n in counts.items():
            by_id[ch].count += n
            self._chunk_index[ch] = []
        self.message_count += len(self._chunk_times)
        self.start_ns = start if self.start_ns is None else min(self.start_ns, start)
        self.end_ns = end if self.end_ns is None else max(self.end_ns, end)
        self._chunk = bytearray()
        self._chunk_times = []

    @property
    def pending(self) -> int:
        """Messages buffered in the open chunk (lost if the process is killed now)."""
        return len(self._chunk_times)

    def flush(self) -> None:
        """Write the open chunk and rewrite ``metadata.yaml`` with the counts so far."""
        self.flush_chunk()
        self.write_metadata_yaml()

    # ------------------------------------------------------------------ metadata
    def metadata(self) -> dict:
        """The bag metadata (the content of ``rosbag2_bagfile_information``)."""
        start = self.start_ns or 0
        duration = (self.end_ns - start) if self.end_ns is not None else 0
        topics = []
        for t in self.topics.values():
            qos = yaml.safe_load(t.qos) if t.qos else []
            topics.append({'topic_metadata': {
                'name': t.name, 'type': t.type, 'serialization_format': 'cdr',
                'offered_qos_profiles': qos or [], 'type_description_hash': t.type_hash},
                'message_count': t.count})
        return {
            'version': 9, 'storage_identifier': 'mcap',
            'duration': {'nanoseconds': duration},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': self.message_count,
            'topics_with_message_count': topics,
            'compression_format': '', 'compression_mode': '',
            'relative_file_paths': [self.file_name],
            'files': [{'path': self.file_name,
                       'starting_time': {'nanoseconds_since_epoch': start},
                       'duration': {'nanoseconds': duration},
                       'message_count': self.message_count}],
            'custom_data': None, 'ros_distro': self.ros_distro}

    def write_metadata_yaml(self) -> None:
        """Atomically (re)write ``metadata.yaml``; errors are raised as BagWriteError."""
        text = yaml.safe_dump({'rosbag2_bagfile_information': self.metadata()},
                              sort_keys=False)
        tmp = self.directory / '.metadata.yaml.tmp'
        try:
            tmp.write_text(text)
            os.replace(tmp, self.directory / 'metadata.yaml')
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            raise BagWriteError(exc.errno, f'writing {self.directory}/metadata.yaml failed: '
                                f'{exc.strerror or exc}') from exc

    # ------------------------------------------------------------------ close
    def close(self) -> None:
        """Write the last chunk, the ``rosbag2`` metadata record, the summary and footer,
        and ``metadata.yaml``. After a failure it writes what still fits; the first error
        is raised again at the end."""
        if self.closed:
            return
        self.closed = True
        error: BagWriteError | None = None
        try:
            if not self.failed:
                self.flush_chunk()
            self.failed = None  # retry with the smaller writes below (space was freed)
            self.add_metadata('rosbag2', {'serialized_metadata': yaml.safe_dump(
                self.metadata(), sort_keys=False)})
            self._write_summary()
        except BagWriteError as exc:
            error = exc
        finally:
            try:
                self._file.close()
            except OSError:
                pass
        try:
            self.write_metadata_yaml()
        except BagWriteError as exc:
            error = error or exc
        if error is not None:
            raise error

    def _write_summary(self) -> None:
        data_end = _record(OP_DATA_END, struct.pack('<I', 0))
        summary_start = self._file.tell() + len(data_end)
        groups: list[tuple[int, bytes]] = [
            (OP_SCHEMA, b''.join(self._schema_records)),
            (OP_CHANNEL, b''.join(self._channel_records)),
            (OP_STATISTICS, self._statistics()),
            (OP_CHUNK_INDEX, b''.join(self._chunk_indexes)),
            (OP_METADATA_INDEX, b''.join(self._metadata_indexes))]
        summary = bytearray()
        offsets = bytearray()
        for op, blob in groups:
            if blob:
                offsets += _record(OP_SUMMARY_OFFSET, struct.pack(
                    '<BQQ', op, summary_start + len(summary), len(blob)))
                summary += blob
        offset_start = summary_start + len(summary)
        footer = _record(OP_FOOTER, struct.pack('<QQI', summary_start, offset_start, 0))
        self._write(data_end + bytes(summary) + bytes(offsets) + footer + MAGIC)

    def _statistics(self) -> bytes:
        counts = b''.join(struct.pack('<HQ', t.channel_id, t.count)
                          for t in self.topics.values())
        return _record(OP_STATISTICS, struct.pack(
            '<QHIIII', self.message_count, len(self._schemas), len(self.topics), 0,
            self.metadata_count, self.chunk_count)
            + struct.pack('<QQ', self.start_ns or 0, self.end_ns or 0)
            + struct.pack('<I', len(counts)) + counts)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _compressor(name: str):
    if name == 'zstd':
        import zstandard

        return zstandard.ZstdCompressor(level=1).compress
    if name == 'lz4':
        import lz4.frame

        return lz4.frame.compress
    return lambda b: b

