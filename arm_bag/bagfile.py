"""What every bag tool shares about the files on disk (pure, no rclpy, no mcap import).

MCAP framing constants (magic, opcodes), :class:`BagError`, and the recording-state
marker: while a recorder writes a bag, the bag directory's ``metadata.yaml`` (rosbag2
metadata version 9, key ``rosbag2_bagfile_information``) has
``custom_data: {RECORDING_KEY: RECORDING_OPEN}`` and the recorder holds an exclusive
``fcntl.flock`` on the ``.mcap`` file (the kernel releases it when the process dies,
SIGKILL included); once the recorder closed the bag the marker is ``RECORDING_CLOSED``.
A bag marked open whose file nobody locks was left behind by a recorder that died:
:func:`arm_bag.recover.recover_bag` makes it a complete bag again.

Only regular files are read (:func:`regular_file`, :func:`open_regular`): a path is
``stat``-ed before it is opened, and opened with ``O_NONBLOCK`` and checked again with
``fstat``, so a FIFO, a device or a socket named as (or inside) a bag is refused, naming
it and its kind, and never read.
"""

from __future__ import annotations

import fcntl
import os
import stat
from collections.abc import Sequence
from pathlib import Path

MAGIC = b'\x89MCAP0\r\n'
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 1, 2, 3, 4, 5, 6
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_ATTACHMENT, OP_ATTACHMENT_INDEX = 7, 8, 9, 10
OP_STATISTICS, OP_METADATA, OP_METADATA_INDEX, OP_SUMMARY_OFFSET, OP_DATA_END = (
    11, 12, 13, 14, 15)

#: ``custom_data`` key in ``metadata.yaml`` holding the recording state.
RECORDING_KEY = 'arm_sim.recording'
#: Values of :data:`RECORDING_KEY`: a recorder is (or was, if it died) writing the bag ...
RECORDING_OPEN = 'open'
#: ... or the recorder closed the bag.
RECORDING_CLOSED = 'closed'
#: ``custom_data`` key: JSON {topic: messages lost before they reached the recorder}.
LOST_KEY = 'arm_sim.lost'
METADATA_FILE = 'metadata.yaml'
METADATA_ROOT = 'rosbag2_bagfile_information'
#: The recorder's disk-space reserve in the bag directory (see :mod:`arm_bag.writer`).
RESERVE_NAME = '.arm_sim_reserve'
#: The temporary file ``metadata.yaml`` is written to before it replaces it.
METADATA_TMP = '.metadata.yaml.tmp'
#: arm_sim's own files a recorder leaves in a bag directory only while it records (or if
#: it died): a recovery removes them.
OWN_TEMPORARY = (RESERVE_NAME, METADATA_TMP)
#: A ``metadata.yaml`` larger than this is not read (rosbag2's are a few KB) [bytes].
METADATA_MAX_BYTES = 16 << 20


class BagError(Exception):
    """The path is not a readable bag (the message names the path and the reason)."""


def file_kind(mode: int) -> str:
    """What a ``st_mode`` is, as words: 'a FIFO (named pipe)', 'a character device', ..."""
    if stat.S_ISREG(mode):
        return 'a regular file'
    if stat.S_ISDIR(mode):
        return 'a directory'
    if stat.S_ISFIFO(mode):
        return 'a FIFO (named pipe)'
    if stat.S_ISCHR(mode):
        return 'a character device'
    if stat.S_ISBLK(mode):
        return 'a block device'
    if stat.S_ISSOCK(mode):
        return 'a socket'
    return f'a special file (mode {stat.filemode(mode)})'


def _not_regular(path: str | os.PathLike, mode: int) -> str:
    return f'{path}: {file_kind(mode)}, not a regular file (only regular files are read)'


def path_stat(path: str | os.PathLike, error: type[BagError] = BagError) -> os.stat_result:
    """``os.stat(path)`` (symlinks followed); raises ``error`` naming the path and why it
    cannot be looked at (no such file, permission, ...), never with an empty reason."""
    try:
        return os.stat(path)
    except FileNotFoundError:
        raise error(f'{path}: no such file or directory') from None
    except (OSError, ValueError) as exc:
        why = getattr(exc, 'strerror', None) or str(exc) or type(exc).__name__
        raise error(f'{path}: cannot read: {why}') from None


def regular_file(path: str | os.PathLike, error: type[BagError] = BagError
                 ) -> os.stat_result:
    """The ``stat`` of ``path`` if it is a regular file (symlinks followed); else raises
    ``error`` naming the path and its kind (a FIFO, a device, a socket, a directory)."""
    st = path_stat(path, error)
    if not stat.S_ISREG(st.st_mode):
        raise error(_not_regular(path, st.st_mode))
    return st


def open_regular(path: str | os.PathLike, error: type[BagError] = BagError,
                 flags: int = os.O_RDONLY) -> int:
    """A descriptor of the regular file ``path``, opened for reading; raises ``error``
    (naming the path and its kind) for anything else, which is never opened: it is
    ``stat``-ed first, and opened with ``O_NONBLOCK`` and checked again with ``fstat``, so a
    FIFO put there in between cannot block the open either. The caller closes it."""
    regular_file(path, error)
    try:
        fd = os.open(path, flags | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except OSError as exc:
        raise error(f'{path}: cannot read: {exc.strerror or exc}') from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise error(_not_regular(path, st.st_mode))
        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
    except BaseException:
        os.close(fd)
        raise
    return fd


def read_metadata_text(path: str | os.PathLike) -> str | None:
    """The text of the ``metadata.yaml`` at ``path``, or None if there is none; raises
    :class:`BagError` if it is not a regular file, is larger than
    :data:`METADATA_MAX_BYTES`, or cannot be read (UnicodeDecodeError if not UTF-8)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise BagError(f'{path}: cannot read: {exc.strerror or exc}') from None
    if not stat.S_ISREG(st.st_mode):
        raise BagError(_not_regular(path, st.st_mode))
    if st.st_size > METADATA_MAX_BYTES:
        raise BagError(f'{path}: {st.st_size} bytes, more than a metadata.yaml holds '
                       f'({METADATA_MAX_BYTES} at most)')
    fd = open_regular(path)
    with os.fdopen(fd, 'rb') as f:
        data = f.read(METADATA_MAX_BYTES + 1)
    if len(data) > METADATA_MAX_BYTES:
        raise BagError(f'{path}: more than {METADATA_MAX_BYTES} bytes')
    return data.decode()


def recover_hint(path: str | os.PathLike) -> str:
    """The sentence that ends a damage error: how to keep what is intact."""
    return f'`arm-sim bag recover {path}` keeps what is intact'


def recording_state(bag_dir: str | os.PathLike) -> str | None:
    """The recording marker of the bag directory ``bag_dir``.

    Returns
    -------
    str or None
        :data:`RECORDING_OPEN`, :data:`RECORDING_CLOSED`, or None when ``bag_dir`` is not a
        directory, has no (readable) ``metadata.yaml`` or no marker in its ``custom_data``.
    """
    meta = Path(bag_dir) / METADATA_FILE
    import yaml

    try:
        text = read_metadata_text(meta)
        if text is None:
            return None
        # libyaml's parser when present: the same document, ~20x faster than pure Python
        doc = yaml.load(text, Loader=getattr(yaml, 'CSafeLoader', yaml.SafeLoader))
        custom = doc[METADATA_ROOT].get('custom_data') or {}
        state = custom.get(RECORDING_KEY)
    except (yaml.YAMLError, KeyError, TypeError, AttributeError, OSError,
            UnicodeDecodeError, BagError):
        return None
    return state if state in (RECORDING_OPEN, RECORDING_CLOSED) else None


def is_locked(mcap_path: str | os.PathLike) -> bool:
    """True when some process (a recorder) holds an exclusive ``flock`` on ``mcap_path``.

    Probes with a non-blocking shared lock on a new open file description, so it also
    sees a lock held by this very process on another descriptor. A missing or unreadable
    file, or one that is not a regular file (never opened), is not locked.
    """
    try:
        fd = open_regular(mcap_path)
    except BagError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return False
    finally:
        os.close(fd)  # closing the descriptor also drops the probe lock
    return False


def bag_metadata(topics: Sequence[tuple[str, str, str, str, int]],
                 files: Sequence[tuple[str, int | None, int | None, int]], *,
                 custom: dict[str, str] | None = None, base: dict | None = None) -> dict:
    """The content of ``rosbag2_bagfile_information`` (rosbag2 metadata version 9).

    Parameters
    ----------
    topics : list of (name, type, offered QoS YAML text, type hash, messages)
        One entry per topic (CDR).
    files : list of (path relative to the bag, first receive time [ns] or None,
        last receive time [ns] or None, messages)
        One entry per MCAP file.
    custom : dict, optional
        ``custom_data`` entries set now (on top of those in ``base``).
    base : dict, optional
        Earlier metadata whose fields not computed here (``ros_distro``,
        ``compression_*``, other ``custom_data`` keys) are kept.
    """
    import yaml

    base = dict(base or {})
    spans = [(s, e) for _, s, e, n in files if n and s is not None and e is not None]
    start = min(s for s, _ in spans) if spans else 0
    end = max(e for _, e in spans) if spans else start
    entries = []
    for name, type_name, qos, thash, count in topics:
        try:
            profiles = yaml.safe_load(qos) if qos else []
        except yaml.YAMLError:
            profiles = []
        entries.append({'topic_metadata': {
            'name': name, 'type': type_name, 'serialization_format': 'cdr',
            'offered_qos_profiles': profiles or [], 'type_description_hash': thash},
            'message_count': count})
    old = base.get('custom_data')
    merged = {**(old if isinstance(old, dict) else {}), **(custom or {})}
    return {
        'version': 9, 'storage_identifier': 'mcap',
        'duration': {'nanoseconds': end - start},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': sum(n for *_, n in files),
        'topics_with_message_count': entries,
        'compression_format': base.get('compression_format', ''),
        'compression_mode': base.get('compression_mode', ''),
        'relative_file_paths': [f for f, *_ in files],
        'files': [{'path': f, 'starting_time': {'nanoseconds_since_epoch': s or 0},
                   'duration': {'nanoseconds': (e - s) if n and s is not None
                                and e is not None else 0},
                   'message_count': n} for f, s, e, n in files],
        'custom_data': merged or None, 'ros_distro': base.get('ros_distro', 'jazzy')}
