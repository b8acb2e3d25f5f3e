"""rosbag2's sqlite3 storage (``ros2 bag record`` without ``-s mcap``) is read and analysed
like MCAP: the same bag in both storages gives the same data and the same report."""

from __future__ import annotations

import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml
from mcap.reader import make_reader
from test_analysis import synthetic_bag

from arm_bag.analysis import analyze
from arm_bag.reader import read_bag

#: rosbag2_storage_sqlite3's schema (sqlite_storage.cpp, Jazzy).
SCHEMA = """
CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);
CREATE TABLE metadata(id INTEGER PRIMARY KEY, metadata_version INTEGER NOT NULL,
                      metadata TEXT NOT NULL);
CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
                    serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL,
                    type_description_hash TEXT NOT NULL);
CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
                      timestamp INTEGER NOT NULL, data BLOB NOT NULL);
CREATE INDEX timestamp_idx ON messages (timestamp ASC);
"""


def to_sqlite(mcap_bag: Path, out: Path) -> int:
    """The messages of ``mcap_bag`` as rosbag2 writes them with the sqlite3 storage, into
    the bag directory ``out``; returns the message count."""
    out.mkdir()
    db = sqlite3.connect(out / 'bag_0.db3')
    db.executescript(SCHEMA)
    ids: dict[str, int] = {}
    n = 0
    for f in sorted(mcap_bag.glob('*.mcap')):
        with open(f, 'rb') as stream:
            for schema, channel, message in make_reader(stream).iter_messages(
                    log_time_order=False):
                if channel.topic not in ids:
                    ids[channel.topic] = len(ids) + 1
                    db.execute('INSERT INTO topics VALUES (?, ?, ?, ?, ?, ?)',
                               (ids[channel.topic], channel.topic, schema.name, 'cdr', '', ''))
                db.execute('INSERT INTO messages (topic_id, timestamp, data) VALUES (?, ?, ?)',
                           (ids[channel.topic], message.log_time, message.data))
                n += 1
    db.commit()
    db.close()
    meta = {'rosbag2_bagfile_information': {
        'version': 9, 'storage_identifier': 'sqlite3', 'relative_file_paths': ['bag_0.db3'],
        'message_count': n, 'topics_with_message_count': []}}
    (out / 'metadata.yaml').write_text(yaml.safe_dump(meta))
    return n


def test_a_sqlite3_bag_reads_and_analyses_as_its_mcap_twin(tmp_path):
    synthetic_bag(tmp_path / 'mcap', robot=False)
    n = to_sqlite(tmp_path / 'mcap', tmp_path / 'sqlite')
    a, b = read_bag(tmp_path / 'mcap'), read_bag(tmp_path / 'sqlite')
    assert b.message_count == a.message_count == n and b.warnings == []
    for field in ('stamp', 'log_time', 'position', 'velocity', 'effort'):
        assert np.array_equal(getattr(a.joint_states, field), getattr(b.joint_states, field))
        assert np.array_equal(getattr(a.reference, field), getattr(b.reference, field))
    assert len(b.trajectories) == len(a.trajectories) == 2 and len(b.paths) == 1
    mine, twin = analyze(tmp_path / 'mcap').to_dict(), analyze(tmp_path / 'sqlite').to_dict()
    for report in (mine, twin):
        report.pop('bag')
    assert twin == mine


def test_a_db3_file_named_alone_is_read_too(tmp_path):
    synthetic_bag(tmp_path / 'mcap', robot=False)
    to_sqlite(tmp_path / 'mcap', tmp_path / 'sqlite')
    bag = read_bag(tmp_path / 'sqlite' / 'bag_0.db3')
    assert len(bag.joint_states.stamp) == len(read_bag(tmp_path / 'mcap').joint_states.stamp)


def test_a_db3_that_is_not_sqlite_is_refused_in_one_line(tmp_path):
    bag = tmp_path / 'bag'
    bag.mkdir()
    (bag / 'bag_0.db3').write_bytes(b'not a database' * 100)
    res = subprocess.run([sys.executable, '-m', 'arm_sim.cli', 'analyze', str(bag)],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 4, res
    assert len(res.stderr.strip().splitlines()) == 1 and 'sqlite3' in res.stderr, res.stderr
    assert 'Traceback' not in res.stderr
