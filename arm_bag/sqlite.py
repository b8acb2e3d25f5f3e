"""rosbag2's ``sqlite3`` storage, read-only: what ``ros2 bag record`` writes without ``-s mcap``.

A sqlite3 bag is a directory with ``metadata.yaml`` (``storage_identifier: sqlite3``) and
``<name>_<n>.db3`` files, each a SQLite database with a ``topics`` table (``id``, ``name``,
``type``, ``serialization_format``, ...) and a ``messages`` table (``topic_id``,
``timestamp`` = receive time [ns], ``data`` = the CDR-serialised message). See
rosbag2_storage_default_plugins' ``sqlite_storage.cpp`` for the schema.

:func:`read_db3` returns each topic's messages laid out as MCAP Message records (opcode,
length, channel, sequence, log time, publish time, data), so :mod:`arm_bag.reader` decodes
them with exactly the code it uses for MCAP. There is no ``arm_sim_robot`` record in such a
bag: analysis then takes the robot parameters from its defaults and says so.
"""

from __future__ import annotations

import sqlite3
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from arm_bag.bagfile import BagError

#: MCAP Message record header: opcode, record length, channel id, sequence, log time,
#: publish time (the data follows).
_HEADER = struct.Struct('<BQHIQQ')
_MESSAGE_OPCODE = 0x05


@dataclass
class Db3Topic:
    """One topic of a ``.db3`` file: its type, serialisation format and messages (as MCAP
    Message records in ``buf``, each starting at an offset in ``offs``, by receive time)."""

    name: str
    type_name: str
    serialization: str
    buf: np.ndarray
    offs: np.ndarray


def is_sqlite_bag(path: str | Path, storage: str | None) -> bool:
    """Is ``path`` a sqlite3 bag: a ``.db3`` file, or a directory whose metadata names the
    ``sqlite3`` storage (``storage``) or that holds ``.db3`` files and no ``.mcap``?"""
    p = Path(path)
    if p.is_file():
        return p.suffix == '.db3'
    if storage is not None:
        return storage == 'sqlite3'
    return p.is_dir() and any(p.glob('*.db3')) and not any(p.glob('*.mcap'))


def read_db3(path: Path) -> list[Db3Topic]:
    """Every topic of the rosbag2 sqlite3 file at ``path`` with its messages; raises
    :class:`BagError` (with SQLite's reason) if it is not one."""
    try:
        db = sqlite3.connect(f'file:{path}?mode=ro', uri=True)
    except sqlite3.Error as exc:
        raise BagError(f'{path}: not a readable sqlite3 bag ({exc})') from None
    try:
        topics = db.execute('SELECT id, name, type, serialization_format FROM topics '
                            'ORDER BY id').fetchall()
        out = []
        for topic_id, name, type_name, fmt in topics:
            rows = db.execute('SELECT timestamp, data FROM messages WHERE topic_id = ? '
                              'ORDER BY timestamp, id', (topic_id,)).fetchall()
            out.append(_records(str(name), str(type_name), str(fmt), topic_id, rows))
        return out
    except sqlite3.Error as exc:
        raise BagError(f'{path}: not a rosbag2 sqlite3 bag ({exc})') from None
    finally:
        db.close()


def _records(name: str, type_name: str, fmt: str, topic_id: int, rows) -> Db3Topic:
    parts: list[bytes] = []
    offs = np.empty(len(rows), np.int64)
    at = 0
    channel = int(topic_id) & 0xFFFF
    for k, (stamp, data) in enumerate(rows):
        data = bytes(data)
        offs[k] = at
        parts.append(_HEADER.pack(_MESSAGE_OPCODE, 22 + len(data), channel, 0, int(stamp),
                                  int(stamp)))
        parts.append(data)
        at += _HEADER.size + len(data)
    buf = np.frombuffer(b''.join(parts), np.uint8)
    return Db3Topic(name, type_name, fmt, buf, offs)
