"""Recover a damaged or unfinished bag: keep every intact record, write a complete bag (pure).

Like ``mcap recover`` and ``ros2 bag reindex``: the MCAP file is read record by record;
every schema, channel and metadata record, every loose message and every chunk whose CRC
and decompression check out is kept, damaged or incomplete chunks are dropped, and
reading stops cleanly where the file is cut (a killed recorder, a full disk). A complete
MCAP file (profile ``ros2``, chunked, CRCs on, the compression found) is written with
``mcap.writer.Writer`` to a temporary file beside the original, fsynced and atomically
renamed over it (or written to another directory), and ``metadata.yaml`` is rewritten
from what was kept, with the recording marker set to ``closed``.
"""

from __future__ import annotations

import fcntl
import io
import os
import struct
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from mcap.exceptions import McapError
from mcap.records import Channel, Chunk, DataEnd, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk, get_chunk_data_stream
from mcap.writer import CompressionType, Writer

from arm_bag.bagfile import (
    MAGIC,
    METADATA_FILE,
    METADATA_ROOT,
    RECORDING_CLOSED,
    RECORDING_KEY,
    RECORDING_OPEN,
    BagError,
    bag_metadata,
    is_locked,
    recording_state,
)

__all__ = ['RECORDING_CLOSED', 'RECORDING_KEY', 'RECORDING_OPEN', 'RecoveryError',
           'RecoveryReport', 'is_locked', 'recording_state', 'recover_bag']

LIBRARY = 'arm_sim arm_bag recover'
ROSBAG2_RECORD = 'rosbag2'
_COMPRESSION = {'': CompressionType.NONE, 'zstd': CompressionType.ZSTD,
                'lz4': CompressionType.LZ4}
#: What a damaged record can make the mcap library's parsers raise.
_PARSE_ERRORS = (McapError, struct.error, ValueError, UnicodeDecodeError, EOFError,
                 IndexError, KeyError, OverflowError, MemoryError)


class RecoveryError(BagError):
    """Nothing recoverable at the path (not MCAP, no intact message), or it is still being
    recorded; the message names the path and the reason."""


@dataclass
class _Parsed:
    """What one MCAP file holds that is intact."""

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    metadata: list[Metadata] = field(default_factory=list)
    messages: list[Message] = field(default_factory=list)
    compression: str | None = None
    chunk_size: int = 0           # largest uncompressed chunk kept [bytes]
    chunks_kept: int = 0
    dropped: list[str] = field(default_factory=list)
    dropped_messages: int = 0     # counted where the damage still told how many
    good_end: int = 8             # file offset after the last intact record [bytes]
    finished: bool = False        # the footer and closing magic were read


@dataclass
class RecoveryReport:
    """What :func:`recover_bag` kept and dropped.

    ``messages``: messages kept; ``topics``: topic -> messages kept; ``chunks_kept``;
    ``dropped``: one reason per dropped chunk / record / cut; ``dropped_messages``:
    messages known to be lost (a dropped chunk whose index still counted them, messages
    on channels whose definition was lost); ``cut_bytes``: bytes after the last intact
    record [bytes]; ``files``: the MCAP files written; ``compression``.
    """

    path: str
    output: str
    messages: int = 0
    topics: dict[str, int] = field(default_factory=dict)
    chunks_kept: int = 0
    dropped: list[str] = field(default_factory=list)
    dropped_messages: int = 0
    cut_bytes: int = 0
    files: list[str] = field(default_factory=list)
    compression: str = 'none'

    def summary(self) -> str:
        """One line: what was kept and dropped."""
        text = (f'kept {self.messages} messages, dropped {self.cut_bytes} bytes at the end '
                f'({self.chunks_kept} chunks kept)')
        if self.dropped:
            text += f', {len(self.dropped)} damaged part(s) dropped ({self.dropped[0]}'
            text += ', ...)' if len(self.dropped) > 1 else ')'
        if self.dropped_messages:
            text += f', {self.dropped_messages} messages known lost'
        return text


# ---------------------------------------------------------------------- reading
def _chunk_records(chunk: Chunk) -> list:
    """The records of an intact chunk; raises when its CRC, decompression or size is
    wrong or its records do not parse."""
    stream, size = get_chunk_data_stream(chunk, validate_crc=True)
    if size != chunk.uncompressed_size:
        raise ValueError(f'decompressed to {size} bytes, the chunk says '
                         f'{chunk.uncompressed_size}')
    plain = Chunk(compression='', data=stream.read(size), message_start_time=0,
                  message_end_time=0, uncompressed_crc=0, uncompressed_size=size)
    return breakup_chunk(plain)


def _parse(data: bytes, name: str) -> _Parsed:
    """Every intact record of the MCAP file ``data`` (named ``name`` in reasons).

    Top-level records come from the library's StreamReader with ``emit_chunks``; chunks are
    checked one by one (CRC, decompression, size) so a damaged chunk is dropped and the
    reading goes on. The StreamReader is not asked to check CRCs itself: it raises on the
    first bad chunk or data-section CRC and cannot resume, which would lose every intact
    chunk after the damage.
    """
    out = _Parsed()
    if len(data) < 8 or data[:8] != MAGIC:
        raise RecoveryError(f'{name}: not an MCAP file (bad magic at byte 0)')
    stream = io.BytesIO(data)
    reader = StreamReader(stream, emit_chunks=True, record_size_limit=len(data))
    in_summary = False
    try:
        for rec in reader.records:
            if isinstance(rec, Chunk):
                _take_chunk(out, rec, stream.tell(), name)
            elif isinstance(rec, Schema):
                out.schemas.setdefault(rec.id, rec)
            elif isinstance(rec, Channel):
                out.channels.setdefault(rec.id, rec)
            elif isinstance(rec, Metadata) and not in_summary:
                out.metadata.append(rec)
            elif isinstance(rec, Message) and not in_summary:
                out.messages.append(rec)
            elif isinstance(rec, DataEnd):
                in_summary = True
            elif isinstance(rec, Footer):
                out.finished = True
            out.good_end = stream.tell()
        out.good_end = len(data)  # the closing magic was read too
    except _PARSE_ERRORS as exc:
        out.finished = False
        if out.good_end < len(data):
            why = ' '.join(str(exc).split()) or type(exc).__name__
            out.dropped.append(f'{name}: stopped at byte {out.good_end} ({why}): the '
                               f'{len(data) - out.good_end} bytes after it are cut or damaged')
    known = [m for m in out.messages if m.channel_id in out.channels]
    lost = len(out.messages) - len(known)
    if lost:
        out.dropped.append(f'{name}: {lost} messages on channels whose definition was lost')
        out.dropped_messages += lost
        out.messages = known
    return out


def _take_chunk(out: _Parsed, chunk: Chunk, end: int, name: str) -> None:
    at = end - 9 - (40 + len(chunk.compression.encode()) + len(chunk.data))
    try:
        records = _chunk_records(chunk)
    except Exception as exc:  # zstd/lz4 raise their own types; any failure drops it
        why = ' '.join(str(exc).split()) or type(exc).__name__
        out.dropped.append(f'{name}: chunk at byte {at} dropped ({why})')
        return
    for rec in records:
        if isinstance(rec, Schema):
            out.schemas.setdefault(rec.id, rec)
        elif isinstance(rec, Channel):
            out.channels.setdefault(rec.id, rec)
        elif isinstance(rec, Message):
            out.messages.append(rec)
    out.chunks_kept += 1
    out.chunk_size = max(out.chunk_size, chunk.uncompressed_size)
    if out.compression is None:
        out.compression = chunk.compression


# ---------------------------------------------------------------------- metadata
def _metadata(file_names: list[str], channels: list[Channel], schemas: dict[int, Schema],
              counts: dict[int, int], files: list[tuple[int, int, int]],
              base: dict | None = None) -> dict:
    """rosbag2 metadata of the recovered files (:func:`arm_bag.bagfile.bag_metadata`):
    ``channels`` one per topic, ``schemas`` id -> mcap Schema, ``counts`` channel id ->
    messages, ``files`` per file (first, last receive time [ns], messages); fields of
    ``base`` (the previous metadata) not computed here are kept."""
    topics = []
    for ch in channels:
        schema = schemas.get(ch.schema_id)
        topics.append((ch.topic, schema.name if schema else '',
                       ch.metadata.get('offered_qos_profiles', ''),
                       ch.metadata.get('topic_type_hash', ''), counts.get(ch.id, 0)))
    spans = [(name, s, e, n) for name, (s, e, n) in zip(file_names, files, strict=True)]
    return bag_metadata(topics, spans, custom={RECORDING_KEY: RECORDING_CLOSED}, base=base)


# ---------------------------------------------------------------------- writing
def _fsync_dir(directory: Path) -> None:
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def _atomic(target: Path) -> Iterator[io.BufferedWriter]:
    """A binary file that replaces ``target`` atomically (fsynced) when the block ends."""
    tmp = target.with_name(f'.{target.name}.{os.getpid()}.tmp')
    try:
        with open(tmp, 'wb') as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)
    _fsync_dir(target.parent)


def _write_mcap(f: io.BufferedWriter, parsed: _Parsed, metadata_yaml: str) -> None:
    writer = Writer(f, chunk_size=parsed.chunk_size or 1 << 20,
                    compression=_COMPRESSION.get(parsed.compression or '',
                                                 CompressionType.NONE),
                    enable_crcs=True, enable_data_crcs=True)
    writer.start(profile='ros2', library=LIBRARY)
    schema_ids = {sid: writer.register_schema(s.name, s.encoding, s.data)
                  for sid, s in sorted(parsed.schemas.items())}
    channel_ids = {cid: writer.register_channel(c.topic, c.message_encoding,
                                                schema_ids.get(c.schema_id, 0),
                                                dict(c.metadata))
                   for cid, c in sorted(parsed.channels.items())}
    for rec in parsed.metadata:
        if rec.name != ROSBAG2_RECORD:
            writer.add_metadata(rec.name, dict(rec.metadata))
    for m in parsed.messages:
        writer.add_message(channel_ids[m.channel_id], m.log_time, m.data, m.publish_time,
                           m.sequence)
    writer.add_metadata(ROSBAG2_RECORD, {'serialized_metadata': metadata_yaml})
    writer.finish()


def _bag_files(path: Path) -> tuple[Path | None, list[Path], dict | None]:
    """(bag directory or None for a bare file, its MCAP files, its metadata or None)."""
    bag_dir = path if path.is_dir() else path.parent
    meta = None
    meta_path = bag_dir / METADATA_FILE
    if meta_path.is_file():
        try:
            doc = yaml.safe_load(meta_path.read_text())
            meta = doc[METADATA_ROOT] if isinstance(doc[METADATA_ROOT], dict) else None
        except (yaml.YAMLError, KeyError, TypeError, OSError, UnicodeDecodeError):
            meta = None
    listed = [bag_dir / f for f in (meta or {}).get('relative_file_paths') or []
              if isinstance(f, str)]
    if path.is_file():
        if path not in listed:
            return None, [path], None  # a bare .mcap (or one metadata.yaml does not list)
        return bag_dir, [f for f in listed if f.is_file()], meta
    if not path.is_dir():
        raise RecoveryError(f'{path}: no such file or directory')
    files = [f for f in listed if f.is_file()] or sorted(path.glob('*.mcap'))
    if not files:
        raise RecoveryError(f'{path}: not a bag (no .mcap file)')
    return bag_dir, files, meta


def _lock(stack: ExitStack, f: Path) -> None:
    """Hold an exclusive lock on ``f`` while recovering it (fails if a recorder has it)."""
    fd = os.open(f, os.O_RDONLY)
    stack.callback(os.close, fd)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise RecoveryError(f'{f}: still being recorded (a recorder holds its lock); '
                            'stop the recorder first') from None


def recover_bag(path: str | os.PathLike, output: str | os.PathLike | None = None
                ) -> RecoveryReport:
    """Recover the bag at ``path`` (a bag directory or an ``.mcap`` file).

    Parameters
    ----------
    path : str or PathLike
        A rosbag2 directory (every MCAP file it lists) or an ``.mcap`` file (if its
        directory's ``metadata.yaml`` lists it, the whole bag is recovered).
    output : str or PathLike, optional
        A directory to write the recovered bag to (created; it must not exist or be
        empty). Default: replace the damaged files in place, atomically, and rewrite
        ``metadata.yaml`` (the files that are intact and finished are left as they are).

    Returns
    -------
    RecoveryReport

    Raises
    ------
    RecoveryError
        Not MCAP, no intact message in a file, the bag is still being recorded, or
        ``output`` exists and is not an empty directory.
    """
    src = Path(path)
    bag_dir, files, meta = _bag_files(src)
    out_dir = Path(output) if output is not None else None
    if out_dir is not None:
        if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
            raise RecoveryError(f'output {str(out_dir)!r} exists and is not an empty '
                                'directory')
    report = RecoveryReport(str(src), str(out_dir or src))
    parsed: list[tuple[Path, _Parsed]] = []
    with ExitStack() as stack:
        for f in files:
            _lock(stack, f)
            data = f.read_bytes()
            p = _parse(data, str(f))
            if not p.messages:
                why = f'; {p.dropped[0]}' if p.dropped else ''
                raise RecoveryError(f'{f}: nothing recoverable: no intact message{why}')
            report.cut_bytes += len(data) - p.good_end
            parsed.append((f, p))
        counts: list[dict[int, int]] = []
        spans = []
        for _f, p in parsed:
            c: dict[int, int] = {}
            for m in p.messages:
                c[m.channel_id] = c.get(m.channel_id, 0) + 1
            counts.append(c)
            times = [m.log_time for m in p.messages]
            spans.append((min(times), max(times), len(times)))
        names = [f.name for f, _ in parsed]
        # one topic per channel of the first file that defines it (same ids in every file)
        channels: dict[str, Channel] = {}
        schemas: dict[int, Schema] = {}
        total: dict[int, int] = {}
        for (_f, p), c in zip(parsed, counts, strict=True):
            for ch in p.channels.values():
                channels.setdefault(ch.topic, ch)
            for sid, s in p.schemas.items():
                schemas.setdefault(sid, s)
            for cid, n in c.items():
                topic = p.channels[cid].topic
                tid = channels[topic].id
                total[tid] = total.get(tid, 0) + n
        doc = _metadata(names, list(channels.values()), schemas, total, spans, meta)
        text = yaml.safe_dump(doc, sort_keys=False)
        target_dir = out_dir or (bag_dir if bag_dir is not None else src.parent)
        if out_dir is not None:
            out_dir.mkdir(parents=True, exist_ok=True)
        for f, p in parsed:
            intact = p.finished and not p.dropped and p.good_end == f.stat().st_size
            report.messages += len(p.messages)
            report.chunks_kept += p.chunks_kept
            report.dropped += p.dropped
            report.dropped_messages += p.dropped_messages
            report.compression = p.compression or 'none'
            for m in p.messages:
                topic = p.channels[m.channel_id].topic
                report.topics[topic] = report.topics.get(topic, 0) + 1
            target = target_dir / f.name
            if out_dir is None and intact:
                continue
            with _atomic(target) as fh:
                _write_mcap(fh, p, text)
            report.files.append(str(target))
        if bag_dir is not None or out_dir is not None:
            with _atomic(target_dir / METADATA_FILE) as fh:
                fh.write(yaml.safe_dump({METADATA_ROOT: doc}, sort_keys=False).encode())
    return report
