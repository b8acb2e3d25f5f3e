"""Recover a damaged or unfinished bag: keep every intact record, write a complete bag (pure).

Like ``mcap recover`` and ``ros2 bag reindex``: the MCAP file is read record by record;
every schema, channel and metadata record, every loose message and every chunk whose CRC
and decompression check out is kept, damaged or incomplete chunks are dropped, and
reading stops cleanly where the file is cut (a killed recorder, a full disk). A complete
MCAP file (profile ``ros2``, chunked, CRCs on, the compression found) is written with
``mcap.writer.Writer`` to a temporary file beside the original, fsynced and atomically
renamed over it (or written to another directory), and ``metadata.yaml`` is rewritten
from what was kept, with the recording marker set to ``closed``.

Streaming: the file is read one record at a time (a chunk is read, checked, decompressed,
its messages written to the new file's open chunk, and dropped), so the peak memory is
about two chunks plus the new file's chunk (at least 1 MiB), whatever the size of the bag;
a record whose length runs past the end of the file stops the reading there instead of
being read. A file that ends with the MCAP magic is checked first without writing anything
and left alone if it is intact. A message is kept when its channel was defined before it
(or in the file's summary, when the file still has one).

Only regular files are read (:func:`arm_bag.bagfile.open_regular`): a FIFO, device or
socket is refused naming its kind. An in-place recovery also removes what a recorder that
died leaves in the bag directory besides the bag (its disk-space reserve
``.arm_sim_reserve`` and a half-written ``.metadata.yaml.tmp``), and the temporary files of
an earlier recovery that was killed.
"""

from __future__ import annotations

import fcntl
import io
import os
import struct
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, cast

import yaml
from mcap.exceptions import EndOfFile, McapError
from mcap.records import Channel, Chunk, DataEnd, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk, get_chunk_data_stream
from mcap.writer import CompressionType, Writer

from arm_bag.bagfile import (
    MAGIC,
    METADATA_FILE,
    METADATA_ROOT,
    OP_FOOTER,
    OWN_TEMPORARY,
    RECORDING_CLOSED,
    RECORDING_KEY,
    RECORDING_OPEN,
    BagError,
    bag_metadata,
    is_locked,
    open_regular,
    path_stat,
    read_metadata_text,
    recording_state,
    recover_hint,
    regular_file,
)

__all__ = ['RECORDING_CLOSED', 'RECORDING_KEY', 'RECORDING_OPEN', 'RecoveryError',
           'RecoveryReport', 'is_locked', 'recording_state', 'recover_advice', 'recover_bag']

LIBRARY = 'arm_sim arm_bag recover'
ROSBAG2_RECORD = 'rosbag2'
_COMPRESSION = {'': CompressionType.NONE, 'zstd': CompressionType.ZSTD,
                'lz4': CompressionType.LZ4}
#: What a damaged record can make the mcap library's parsers raise.
_PARSE_ERRORS = (McapError, struct.error, ValueError, UnicodeDecodeError, EOFError,
                 IndexError, KeyError, OverflowError, MemoryError)
#: The recovered file's chunks hold at least this many bytes (or the first chunk's size).
MIN_CHUNK = 1 << 20
#: A summary section larger than this is not read for channel definitions [bytes].
SUMMARY_MAX = 64 << 20
_U64 = struct.Struct('<Q')


class RecoveryError(BagError):
    """Nothing recoverable at the path (not MCAP, not a regular file, no intact message),
    or it is still being recorded; the message names the path and the reason."""


@dataclass
class _Parsed:
    """What one MCAP file holds that is intact (the messages themselves are handed on as
    they are read, not kept)."""

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    metadata: list[Metadata] = field(default_factory=list)
    counts: dict[int, int] = field(default_factory=dict)  # channel id -> messages kept
    first: int | None = None      # receive time of the earliest message kept [ns]
    last: int | None = None       # ... and of the latest [ns]
    compression: str | None = None
    chunk_size: int = 0           # largest uncompressed chunk kept [bytes]
    chunks_kept: int = 0
    dropped: list[str] = field(default_factory=list)
    dropped_messages: int = 0     # counted where the damage still told how many
    orphans: int = 0              # messages on a channel not defined before them
    good_end: int = 8             # file offset after the last intact record [bytes]
    finished: bool = False        # the footer and closing magic were read

    @property
    def messages(self) -> int:
        return sum(self.counts.values())


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
class _Source:
    """The MCAP file as the StreamReader reads it: a read that would run past the end of
    the file raises instead (a cut or damaged record length never makes it read what the
    file does not hold, nor allocate for it)."""

    def __init__(self, fh: BinaryIO, size: int) -> None:
        self.fh = fh
        self.size = size
        self.pos = fh.tell()

    def read(self, n: int = -1) -> bytes:
        if n is None or n < 0 or self.pos + n > self.size:
            raise EndOfFile(f'a read of {n} bytes at byte {self.pos} runs past the end of '
                            f'the {self.size}-byte file')
        data = self.fh.read(n)
        if len(data) != n:
            raise EndOfFile(f'the file ended at byte {self.pos + len(data)}')
        self.pos += n
        return data


#: What a message kept is handed to: (what the file held so far, the message).
Sink = Callable[[_Parsed, Message], None]


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


def _ends_with_magic(fh: BinaryIO, size: int) -> bool:
    if size < 16:
        return False
    fh.seek(size - 8)
    return fh.read(8) == MAGIC


def _summary_definitions(fh: BinaryIO, size: int) -> tuple[dict[int, Schema],
                                                            dict[int, Channel]]:
    """The schemas and channels the file's summary section repeats (when the file still
    has its footer): definitions for the messages of a chunk whose own were lost with a
    damaged chunk before it."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    footer = size - 8 - 29
    if footer < 8 + 9 or not _ends_with_magic(fh, size):
        return schemas, channels
    fh.seek(footer)
    tail = fh.read(29)
    if tail[0] != OP_FOOTER or _U64.unpack_from(tail, 1)[0] != 20:
        return schemas, channels
    start = _U64.unpack_from(tail, 9)[0]
    if not 8 < start < footer or footer - start > SUMMARY_MAX:
        return schemas, channels
    fh.seek(start)
    data = fh.read(footer - start)
    try:
        for rec in StreamReader(io.BytesIO(data), skip_magic=True,
                                record_size_limit=len(data)).records:
            if isinstance(rec, Schema):
                schemas.setdefault(rec.id, rec)
            elif isinstance(rec, Channel):
                channels.setdefault(rec.id, rec)
    except _PARSE_ERRORS:
        pass
    return schemas, channels


class _Walk:
    """One pass over an MCAP file: every intact record read in file order, each message
    whose channel is defined handed to ``sink`` at once (see :func:`_walk`)."""

    def __init__(self, name: str, sink: Sink | None,
                 fallback: tuple[dict[int, Schema], dict[int, Channel]]) -> None:
        self.name = name
        self.sink = sink
        self.out = _Parsed()
        self.fallback = fallback

    def message(self, m: Message) -> None:
        out = self.out
        cid = m.channel_id
        if cid not in out.channels:
            ch = self.fallback[1].get(cid)
            if ch is None:
                out.orphans += 1
                return
            out.channels[cid] = ch
            schema = self.fallback[0].get(ch.schema_id)
            if schema is not None:
                out.schemas.setdefault(schema.id, schema)
        out.counts[cid] = out.counts.get(cid, 0) + 1
        t = m.log_time
        out.first = t if out.first is None or t < out.first else out.first
        out.last = t if out.last is None or t > out.last else out.last
        if self.sink is not None:
            self.sink(out, m)

    def chunk(self, chunk: Chunk, end: int) -> None:
        out = self.out
        at = end - 9 - (40 + len(chunk.compression.encode()) + len(chunk.data))
        try:
            records = _chunk_records(chunk)
        except Exception as exc:  # zstd/lz4 raise their own types; any failure drops it
            why = ' '.join(str(exc).split()) or type(exc).__name__
            out.dropped.append(f'{self.name}: chunk at byte {at} dropped ({why})')
            return
        out.chunks_kept += 1
        out.chunk_size = max(out.chunk_size, chunk.uncompressed_size)
        if out.compression is None:
            out.compression = chunk.compression
        for rec in records:
            if isinstance(rec, Schema):
                out.schemas.setdefault(rec.id, rec)
            elif isinstance(rec, Channel):
                out.channels.setdefault(rec.id, rec)
            elif isinstance(rec, Message):
                self.message(rec)


def _walk(fh: BinaryIO, size: int, name: str, sink: Sink | None = None) -> _Parsed:
    """Every intact record of the MCAP file ``fh`` (``size`` bytes, named ``name`` in
    reasons), read in one pass; each message kept is handed to ``sink`` as it is read.

    Top-level records come from the library's StreamReader with ``emit_chunks``; chunks are
    checked one by one (CRC, decompression, size) so a damaged chunk is dropped and the
    reading goes on. The StreamReader is not asked to check CRCs itself: it raises on the
    first bad chunk or data-section CRC and cannot resume, which would lose every intact
    chunk after the damage.
    """
    fh.seek(0)
    if size < 8 or fh.read(8) != MAGIC:
        raise RecoveryError(f'{name}: not an MCAP file (bad magic at byte 0)')
    walk = _Walk(name, sink, _summary_definitions(fh, size))
    out = walk.out
    fh.seek(0)
    source = _Source(fh, size)
    # StreamReader only calls read() (it wraps anything but a RawIOBase as it is)
    reader = StreamReader(cast(BinaryIO, source), emit_chunks=True, record_size_limit=size)
    in_summary = False
    try:
        for rec in reader.records:
            if isinstance(rec, Chunk):
                walk.chunk(rec, source.pos)
            elif isinstance(rec, Schema):
                out.schemas.setdefault(rec.id, rec)
            elif isinstance(rec, Channel):
                out.channels.setdefault(rec.id, rec)
            elif isinstance(rec, Metadata) and not in_summary:
                out.metadata.append(rec)
            elif isinstance(rec, Message) and not in_summary:
                walk.message(rec)
            elif isinstance(rec, DataEnd):
                in_summary = True
            elif isinstance(rec, Footer):
                out.finished = True
            out.good_end = source.pos
        out.good_end = size  # the closing magic was read too
    except _PARSE_ERRORS as exc:
        out.finished = False
        if out.good_end < size:
            why = ' '.join(str(exc).split()) or type(exc).__name__
            out.dropped.append(f'{name}: stopped at byte {out.good_end} ({why}): the '
                               f'{size - out.good_end} bytes after it are cut or damaged')
    if out.orphans:
        out.dropped.append(f'{name}: {out.orphans} messages on channels whose definition '
                           'was lost')
        out.dropped_messages += out.orphans
    return out


def _intact(p: _Parsed, size: int) -> bool:
    return p.finished and not p.dropped and p.good_end == size


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


def _tmp_of(target: Path) -> Path:
    """The temporary file ``target`` is written to before it replaces it (one name per
    target, so one left by a killed recovery is found and replaced by the next)."""
    return target.with_name(f'.{target.name}.recover.tmp')


@contextmanager
def _atomic(target: Path) -> Iterator[io.BufferedWriter]:
    """A binary file that replaces ``target`` atomically (fsynced) when the block ends."""
    tmp = _tmp_of(target)
    try:
        with open(tmp, 'wb') as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)
    _fsync_dir(target.parent)


class _Output:
    """A recovered MCAP file being written to a temporary file beside ``target``: the
    messages go in as they are read (:meth:`message`, a :data:`Sink`); :meth:`finish`
    writes the metadata records, summary and footer, and moves it over ``target``."""

    def __init__(self, target: Path) -> None:
        self.target = target
        self.tmp = _tmp_of(target)
        self.file = open(self.tmp, 'wb')
        self.writer: Writer | None = None
        self.schema_ids: dict[int, int] = {}
        self.channel_ids: dict[int, int] = {}
        self.metadata_written = 0

    def _start(self, p: _Parsed) -> Writer:
        writer = Writer(self.file, chunk_size=max(p.chunk_size, MIN_CHUNK),
                        compression=_COMPRESSION.get(p.compression or '',
                                                     CompressionType.NONE),
                        enable_crcs=True, enable_data_crcs=True)
        writer.start(profile='ros2', library=LIBRARY)
        self.writer = writer
        for cid in sorted(p.channels):  # those known so far, in id order; others as met
            self._channel(writer, p, cid)
        self._metadata(writer, p)
        return writer

    def _metadata(self, writer: Writer, p: _Parsed) -> None:
        """Write the metadata records read since the last call (not the old rosbag2
        record: a new one is written at the end)."""
        for rec in p.metadata[self.metadata_written:]:
            if rec.name != ROSBAG2_RECORD:
                writer.add_metadata(rec.name, dict(rec.metadata))
        self.metadata_written = len(p.metadata)

    def _channel(self, writer: Writer, p: _Parsed, cid: int) -> int:
        out = self.channel_ids.get(cid)
        if out is None:
            c = p.channels[cid]
            sid = self.schema_ids.get(c.schema_id)
            if sid is None and c.schema_id in p.schemas:
                s = p.schemas[c.schema_id]
                sid = self.schema_ids[c.schema_id] = writer.register_schema(
                    s.name, s.encoding, s.data)
            out = self.channel_ids[cid] = writer.register_channel(
                c.topic, c.message_encoding, sid or 0, dict(c.metadata))
        return out

    def message(self, p: _Parsed, m: Message) -> None:
        writer = self.writer or self._start(p)
        writer.add_message(self._channel(writer, p, m.channel_id), m.log_time, m.data,
                           m.publish_time, m.sequence)

    def finish(self, p: _Parsed, metadata_yaml: str) -> None:
        writer = self.writer or self._start(p)
        for cid in sorted(p.channels):  # also the channels none of whose messages is left
            self._channel(writer, p, cid)
        self._metadata(writer, p)
        writer.add_metadata(ROSBAG2_RECORD, {'serialized_metadata': metadata_yaml})
        writer.finish()
        self.file.flush()
        os.fsync(self.file.fileno())
        self.file.close()
        os.replace(self.tmp, self.target)
        _fsync_dir(self.target.parent)

    def discard(self) -> None:
        self.file.close()
        self.tmp.unlink(missing_ok=True)


def _bag_files(path: Path) -> tuple[Path | None, list[Path], dict | None]:
    """(bag directory or None for a bare file, its MCAP files, its metadata or None); every
    file is a regular file (else RecoveryError naming it and its kind)."""
    import stat

    is_dir = stat.S_ISDIR(path_stat(path, RecoveryError).st_mode)
    if not is_dir:
        regular_file(path, RecoveryError)
    bag_dir = path if is_dir else path.parent
    meta = None
    try:
        text = read_metadata_text(bag_dir / METADATA_FILE)
        doc = yaml.safe_load(text) if text is not None else None
        if doc is not None:
            meta = doc[METADATA_ROOT] if isinstance(doc[METADATA_ROOT], dict) else None
    except (BagError, yaml.YAMLError, KeyError, TypeError, OSError, UnicodeDecodeError):
        meta = None
    listed = [bag_dir / f for f in (meta or {}).get('relative_file_paths') or []
              if isinstance(f, str)]
    present = [f for f in listed if os.path.exists(f)]
    if not is_dir:
        if path not in listed:
            return None, [path], None  # a bare .mcap (or one metadata.yaml does not list)
        files = present
    else:
        files = present or sorted(path.glob('*.mcap'))
        if not files:
            raise RecoveryError(f'{path}: not a bag (no .mcap file)')
    for f in files:  # a FIFO, device, socket or directory is refused, never opened
        regular_file(f, RecoveryError)
    return bag_dir, files, meta


def _lock(stack: ExitStack, f: Path) -> BinaryIO:
    """The regular file ``f`` opened for reading, with an exclusive lock held while it is
    recovered (fails if a recorder has it)."""
    fh = os.fdopen(open_regular(f, RecoveryError), 'rb')
    stack.callback(fh.close)
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise RecoveryError(f'{f}: still being recorded (a recorder holds its lock); '
                            'stop the recorder first') from None
    return fh


def _remove_leftovers(bag_dir: Path, files: list[Path]) -> None:
    """Remove what a recorder that died (its reserve, a half-written metadata.yaml) and a
    killed recovery (its temporary files) left in ``bag_dir``."""
    names = [*OWN_TEMPORARY, _tmp_of(bag_dir / METADATA_FILE).name,
             *(_tmp_of(f).name for f in files)]
    for name in names:
        (bag_dir / name).unlink(missing_ok=True)


def recover_advice(path: str | os.PathLike, writable: bool | None = None) -> str:
    """The recovery that works for the bag at ``path``, as the sentence that ends a damage
    error: in place (:func:`arm_bag.bagfile.recover_hint`) when the directory an in-place
    recovery writes (the bag directory, or an ``.mcap`` file's) can be written, otherwise
    ``arm-sim bag recover PATH --output DIR`` to a new directory on writable storage
    (read-only storage: an in-place recovery cannot work there).

    ``writable``: whether that directory can be written; None asks ``os.access`` (which
    sees a read-only mount even for root, though not a permission root ignores) of a
    directory that exists (for one that does not, the in-place hint stands)."""
    p = Path(path)
    where = p if p.is_dir() else p.parent
    if writable is None:  # a path that is not there is no question of storage
        writable = not where.exists() or os.access(where, os.W_OK)
    if writable:
        return recover_hint(path)
    return (f'{where} cannot be written (read-only?), so recover to a new directory on '
            f'writable storage: `arm-sim bag recover {path} --output DIR` keeps what is '
            'intact in DIR')


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
        ``metadata.yaml`` (the files that are intact and finished are left as they are),
        and remove what a recorder that died left in the bag directory.

    Returns
    -------
    RecoveryReport

    Raises
    ------
    RecoveryError
        Not a regular file, not MCAP, no intact message in a file, the bag is still being
        recorded, or ``output`` exists and is not an empty directory.
    """
    src = Path(path)
    bag_dir, files, meta = _bag_files(src)
    out_dir = Path(output) if output is not None else None
    if out_dir is not None:
        if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
            raise RecoveryError(f'output {str(out_dir)!r} exists and is not an empty '
                                'directory')
    report = RecoveryReport(str(src), str(out_dir or src))
    target_dir = out_dir or (bag_dir if bag_dir is not None else src.parent)
    parsed: list[tuple[Path, _Parsed, _Output | None]] = []
    with ExitStack() as stack:
        handles = [_lock(stack, f) for f in files]
        if out_dir is not None:
            out_dir.mkdir(parents=True, exist_ok=True)
        for f, fh in zip(files, handles, strict=True):
            size = os.fstat(fh.fileno()).st_size
            p: _Parsed | None = None
            output_file: _Output | None = None
            if out_dir is None and _ends_with_magic(fh, size):
                p = _walk(fh, size, str(f))  # maybe intact: look before writing anything
                if not _intact(p, size):
                    p = None
            if p is None:
                output_file = _Output(target_dir / f.name)
                stack.callback(output_file.discard)  # unless it was moved into place
                p = _walk(fh, size, str(f), output_file.message)
            if not p.messages:
                why = f'; {p.dropped[0]}' if p.dropped else ''
                raise RecoveryError(f'{f}: nothing recoverable: no intact message{why}')
            report.cut_bytes += size - p.good_end
            parsed.append((f, p, output_file))
        spans = [(p.first or 0, p.last or 0, p.messages) for _f, p, _o in parsed]
        names = [f.name for f, _p, _o in parsed]
        # one topic per channel of the first file that defines it (same ids in every file)
        channels: dict[str, Channel] = {}
        schemas: dict[int, Schema] = {}
        total: dict[int, int] = {}
        for _f, p, _o in parsed:
            for ch in p.channels.values():
                channels.setdefault(ch.topic, ch)
            for sid, s in p.schemas.items():
                schemas.setdefault(sid, s)
            for cid, n in p.counts.items():
                tid = channels[p.channels[cid].topic].id
                total[tid] = total.get(tid, 0) + n
        doc = _metadata(names, list(channels.values()), schemas, total, spans, meta)
        text = yaml.safe_dump(doc, sort_keys=False)
        for _f, p, output_file in parsed:
            report.messages += p.messages
            report.chunks_kept += p.chunks_kept
            report.dropped += p.dropped
            report.dropped_messages += p.dropped_messages
            report.compression = p.compression or 'none'
            for cid, n in p.counts.items():
                topic = p.channels[cid].topic
                report.topics[topic] = report.topics.get(topic, 0) + n
            if output_file is not None:
                output_file.finish(p, text)
                report.files.append(str(output_file.target))
        if bag_dir is not None or out_dir is not None:
            with _atomic(target_dir / METADATA_FILE) as fh_meta:
                fh_meta.write(yaml.safe_dump({METADATA_ROOT: doc}, sort_keys=False).encode())
        if out_dir is None and bag_dir is not None:
            _remove_leftovers(bag_dir, files)
    return report
