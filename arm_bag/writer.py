"""rosbag2 bag writer on the ``mcap`` library: ``<dir>/<name>_0.mcap`` + ``metadata.yaml``.

Pure (no rclpy). The MCAP file is written by :class:`mcap.writer.Writer` and follows the
``ros2`` profile as rosbag2 (Jazzy) writes it: schema encoding ``ros2msg``, message
encoding ``cdr``, channel metadata ``offered_qos_profiles`` and ``topic_type_hash``, and on
close a metadata record ``rosbag2`` whose ``serialized_metadata`` is the bag metadata YAML.
``metadata.yaml`` is rosbag2 metadata version 9. Every chunk carries the CRC of its
records and the data end record the CRC of the whole data section, so a reader can tell a
damaged file from an intact one (:mod:`arm_bag.reader` checks both).

Durability:

* Messages are buffered in the open chunk, which is written when it exceeds ``chunk_size``
  bytes or on :meth:`BagWriter.flush` (the recorder calls it on a wall-clock timer; each
  flush also rewrites ``metadata.yaml`` atomically). A process killed without warning loses
  only the messages since the last flush, and the file up to there is intact MCAP without a
  summary.
* While the bag is open, ``metadata.yaml`` says ``arm_sim.recording: open`` in its
  ``custom_data`` and the ``.mcap`` file holds an exclusive ``flock`` (the kernel drops it
  when the process dies, SIGKILL included). A bag still marked open whose file is not locked
  was left by a writer that died: :mod:`arm_bag.recover` completes it (arm_sim does this
  automatically when it opens such a bag; ``arm-sim bag recover DIR`` by hand).
* A full disk: a reserve file of ``2 * chunk_size + 32 KiB`` (``.arm_sim_reserve``) is
  allocated when the bag is created. The first write that fails with ENOSPC is cut back,
  the reserve is freed and the write retried; from then on no message is accepted
  (:class:`BagWriteError`) and :meth:`BagWriter.close` writes the summary and footer into
  the freed space, so the bag is complete. Any other write error leaves the file cut back to
  its last complete record (still marked open, so it is recovered the next time). The
  reserve is removed when the bag is closed, and, if the writer died, by the recovery:
  nothing but the bag is left in its directory.

Messages can be counted as lost (:meth:`BagWriter.count_lost`); the counts per topic are
written to ``metadata.yaml`` (``custom_data``: ``arm_sim.lost`` as JSON) so every reader
of the bag sees them; so are the messages a topic's publisher sent before the first one
in the bag when they are not known to be lost (:meth:`BagWriter.count_unrecorded_start`,
``arm_sim.unrecorded_start``).
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, cast

import yaml
from mcap.writer import CompressionType, Writer

from arm_bag.bagfile import (
    LOST_KEY,
    METADATA_TMP,
    RECORDING_CLOSED,
    RECORDING_KEY,
    RECORDING_OPEN,
    RESERVE_NAME,
    bag_metadata,
)

LIBRARY = 'arm_sim arm_bag (mcap python)'
#: custom_data key: per topic (JSON), the messages its publisher sent before the first one
#: in the bag, maybe before the recording began (see arm_bag.loss.before_first).
UNRECORDED_START_KEY = 'arm_sim.unrecorded_start'
COMPRESSIONS = ('none', 'zstd', 'lz4')
_COMPRESSION = {'none': CompressionType.NONE, 'zstd': CompressionType.ZSTD,
                'lz4': CompressionType.LZ4}
RESERVE_EXTRA = 32 * 1024  # bytes on top of two chunks: summary, footer, metadata


class BagWriteError(OSError):
    """Writing the bag failed (e.g. the disk is full); what was written stays readable."""


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


class _BagFile:
    """The stream the mcap ``Writer`` writes to: a file whose failed writes are cut back to
    the last complete write (each of the Writer's writes ends on a record boundary), and
    whose first ENOSPC is absorbed by freeing the reserve."""

    def __init__(self, path: Path, reserve: Path, reserve_bytes: int) -> None:
        self.path = path
        self.reserve = reserve
        self.file = open(path, 'xb', buffering=0)  # closed in BagWriter.close()
        self.pos = 0
        self.out_of_space = False
        self.error: BagWriteError | None = None
        try:
            fcntl.flock(self.file.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            with open(reserve, 'wb') as f:
                os.posix_fallocate(f.fileno(), 0, reserve_bytes)
        except OSError:
            self.file.close()
            path.unlink(missing_ok=True)
            reserve.unlink(missing_ok=True)
            raise

    def write(self, data) -> int:
        if self.error is not None:
            raise self.error
        view = memoryview(data)
        try:
            self._write_all(view)
        except OSError as exc:
            self._cut()
            if exc.errno not in (errno.ENOSPC, errno.EDQUOT) or self.out_of_space:
                self.error = BagWriteError(exc.errno, f'writing {self.path} failed: '
                                           f'{exc.strerror or exc}')
                raise self.error from exc
            self.out_of_space = True
            self.free_reserve()
            try:
                self._write_all(view)
            except OSError as again:
                self._cut()
                self.error = BagWriteError(again.errno, f'writing {self.path} failed: '
                                           f'{again.strerror or again}')
                raise self.error from again
        self.pos += len(view)
        return len(view)

    def _write_all(self, view: memoryview) -> None:
        done = 0
        while done < len(view):
            done += self.file.write(view[done:]) or 0

    def _cut(self) -> None:
        try:
            self.file.truncate(self.pos)
            self.file.seek(self.pos)
        except OSError:
            pass

    def free_reserve(self) -> None:
        self.reserve.unlink(missing_ok=True)

    def tell(self) -> int:
        return self.pos

    def flush(self) -> None:
        pass  # unbuffered


class BagWriter:
    """Write a rosbag2 bag directory with one MCAP file (see the module docstring).

    Parameters
    ----------
    directory : str or Path
        The bag directory; it must not exist (FileExistsError naming it).
    chunk_size : int, bytes, >= 1
        A chunk is written once its uncompressed size exceeds this.
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
        self.topics: dict[str, Topic] = {}
        self._by_channel: dict[int, Topic] = {}
        self._schemas: dict[str, int] = {}
        self.lost: dict[str, int] = {}
        self.unrecorded_start: dict[str, int] = {}
        self.message_count = 0           # written to the file
        self._pending = 0                # in the open chunk
        self.start_ns: int | None = None
        self.end_ns: int | None = None
        self.failed: str | None = None
        self.closed = False
        try:
            self._file = _BagFile(self.path, self.directory / RESERVE_NAME,
                                  2 * self.chunk_size + RESERVE_EXTRA)
        except OSError:
            self.directory.rmdir()
            raise
        # _BagFile has the three methods the Writer uses (write, tell, flush).
        self._mcap = Writer(cast(BinaryIO, self._file), chunk_size=self.chunk_size,
                            compression=_COMPRESSION[compression], enable_crcs=True,
                            enable_data_crcs=True)
        self._guard(lambda: self._mcap.start(profile='ros2', library=LIBRARY))

    # ------------------------------------------------------------------ low level
    def _guard(self, fn):
        """Run one mcap Writer call; a failed write marks the bag failed for good."""
        if self.failed:
            raise BagWriteError(errno.EIO, self.failed)
        try:
            out = fn()
        except BagWriteError as exc:
            self.failed = (f'{exc.strerror}; recording stopped, {self.message_count} '
                           'messages kept')
            raise BagWriteError(exc.errno, self.failed) from exc
        return out

    def _after_write(self, before: int) -> None:
        """The mcap Writer wrote the open chunk if the file grew: count its messages. After
        the reserve was spent, refuse everything from now on."""
        if self._file.pos != before and self._pending:
            for t in self.topics.values():
                t.count += t.pending
                t.pending = 0
            self.message_count += self._pending
            self._pending = 0
        if self._file.out_of_space and not self.failed:
            self.failed = (f'writing {self.path} failed: No space left on device; recording '
                           'stopped, '
                           f'{self.message_count + self._pending} messages kept (the bag '
                           'is complete)')

    # ------------------------------------------------------------------ topics
    def add_topic(self, name: str, type_name: str, schema: str, qos: str = '',
                  type_hash: str = '') -> int:
        """Register ``name`` (type ``pkg/msg/Type``, ``ros2msg`` schema text, QoS YAML text,
        RIHS01 hash); returns its channel id. Adding a known topic returns the same id."""
        if name in self.topics:
            return self.topics[name].channel_id
        before = self._file.pos

        def register() -> int:
            schema_id = self._schemas.get(type_name)
            if schema_id is None:
                schema_id = self._mcap.register_schema(type_name, 'ros2msg', schema.encode())
                self._schemas[type_name] = schema_id
            return self._mcap.register_channel(
                name, 'cdr', schema_id, {'offered_qos_profiles': qos,
                                         'topic_type_hash': type_hash})

        channel_id = self._guard(register)
        self._after_write(before)
        topic = Topic(channel_id, name, type_name, qos, type_hash)
        self.topics[name] = self._by_channel[channel_id] = topic
        return channel_id

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Write an MCAP metadata record ``name`` (string keys and values) now."""
        self._guard(lambda: self._mcap.add_metadata(
            name, {str(k): str(v) for k, v in data.items()}))

    # ------------------------------------------------------------------ messages
    def write(self, channel_id: int, data: bytes, log_time_ns: int,
              publish_time_ns: int | None = None, sequence: int = 0) -> None:
        """Append one serialized (CDR) message received at ``log_time_ns`` [ns];
        ``sequence`` is the publisher's sequence number (0 if unknown)."""
        topic = self._by_channel[channel_id]
        before = self._file.pos
        self._guard(lambda: self._mcap.add_message(
            channel_id, log_time_ns, data,
            log_time_ns if publish_time_ns is None else publish_time_ns, sequence))
        topic.pending += 1
        self._pending += 1
        self.start_ns = log_time_ns if self.start_ns is None else min(self.start_ns,
                                                                      log_time_ns)
        self.end_ns = log_time_ns if self.end_ns is None else max(self.end_ns, log_time_ns)
        self._after_write(before)

    def count_lost(self, topic: str, n: int) -> None:
        """Count ``n`` messages of ``topic`` as lost before they reached the bag."""
        if n > 0:
            self.lost[topic] = self.lost.get(topic, 0) + int(n)

    def set_lost(self, topic: str, n: int) -> None:
        """Set the count of ``topic``'s messages lost before they reached the bag."""
        if n > 0:
            self.lost[topic] = int(n)
        else:
            self.lost.pop(topic, None)

    def count_unrecorded_start(self, topic: str, n: int) -> None:
        """Count ``n`` messages of ``topic`` its publisher sent before the first one in the
        bag, perhaps before the recording began (not known to be lost)."""
        if n > 0:
            self.unrecorded_start[topic] = self.unrecorded_start.get(topic, 0) + int(n)

    def flush_chunk(self) -> None:
        """Write the open chunk (if any) and its message indexes to the file."""
        before = self._file.pos
        self._guard(self._mcap.flush)
        self._after_write(before)

    @property
    def pending(self) -> int:
        """Messages buffered in the open chunk (lost if the process is killed now)."""
        return self._pending

    def flush(self) -> None:
        """Write the open chunk and rewrite ``metadata.yaml`` with the counts so far."""
        self.flush_chunk()
        self.write_metadata_yaml()

    # ------------------------------------------------------------------ metadata
    def metadata(self) -> dict:
        """The bag metadata (the content of ``rosbag2_bagfile_information``)."""
        return bag_metadata(
            [(t.name, t.type, t.qos, t.type_hash, t.count) for t in self.topics.values()],
            [(self.file_name, self.start_ns, self.end_ns, self.message_count)],
            base={'ros_distro': self.ros_distro},
            custom={RECORDING_KEY: RECORDING_CLOSED if self.closed else RECORDING_OPEN,
                    **({LOST_KEY: json.dumps(self.lost, sort_keys=True)}
                       if self.lost else {}),
                    **({UNRECORDED_START_KEY: json.dumps(self.unrecorded_start,
                                                         sort_keys=True)}
                       if self.unrecorded_start else {})})

    def write_metadata_yaml(self) -> None:
        """Atomically (re)write ``metadata.yaml``; errors are raised as BagWriteError."""
        write_metadata_yaml(self.directory, self.metadata())

    # ------------------------------------------------------------------ close
    def close(self) -> None:
        """Write the last chunk, the ``rosbag2`` metadata record, the summary and footer,
        and ``metadata.yaml`` (marked closed). After a failed write the file is left cut
        back to its last complete record and still marked open (so it is recovered when
        next opened); the error is raised again."""
        if self.closed:
            return
        error: BagWriteError | None = None
        try:
            if self._file.error is None:
                self._finish_chunk()
                self.closed = True
                meta = yaml.safe_dump(self.metadata(), sort_keys=False)
                self._mcap.add_metadata('rosbag2', {'serialized_metadata': meta})
                self._mcap.finish()
        except BagWriteError as exc:
            self.closed = False
            error = exc
        finally:
            self._file.free_reserve()
            try:
                self._file.file.close()  # also drops the lock
            except OSError:
                pass
        if self._file.error is not None and error is None:
            error = self._file.error
        try:
            self.write_metadata_yaml()
        except BagWriteError as exc:
            error = error or exc
        self.closed = True
        if error is not None:
            raise BagWriteError(error.errno, self.failed or str(error.strerror or error))

    def _finish_chunk(self) -> None:
        """Write the open chunk, also after a full disk freed the reserve."""
        before = self._file.pos
        self._mcap.flush()
        self._after_write(before)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# ---------------------------------------------------------------------- metadata.yaml
def write_metadata_yaml(directory: Path, metadata: dict) -> None:
    """Atomically (re)write ``directory/metadata.yaml``; errors raise BagWriteError."""
    text = yaml.safe_dump({'rosbag2_bagfile_information': metadata}, sort_keys=False)
    tmp = directory / METADATA_TMP
    try:
        tmp.write_text(text)
        os.replace(tmp, directory / 'metadata.yaml')
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise BagWriteError(exc.errno, f'writing {directory}/metadata.yaml failed: '
                            f'{exc.strerror or exc}') from exc
