"""Bag integrity: damage is always a one-line BagError, recovery keeps what is intact, and
recovered bags open in every tool (rosbags, the mcap library, mcap_ros2)."""

from __future__ import annotations

import fcntl
import itertools
import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.writer import CompressionType, Writer

from arm_bag.bagfile import MAGIC, RECORDING_KEY, bag_metadata, is_locked, recording_state
from arm_bag.cdr import encode_joint_trajectory, encode_path
from arm_bag.msgdefs import QosProfile, qos_yaml, schema_text, type_hash
from arm_bag.reader import BagError, read_bag
from arm_bag.recover import RecoveryError, recover_bag
from arm_bag.synthetic import ROBOT, TOPICS, joint_state_block, open_bag, write_run

ROOT = Path(__file__).resolve().parents[1]
COMPRESSIONS = ('none', 'zstd', 'lz4')
JS = 'sensor_msgs/msg/JointState'
QOS = qos_yaml([QosProfile()])


def states(n: int) -> list[bytes]:
    """``n`` CDR JointStates 10 ms apart (positions sin/cos of time)."""
    t = np.arange(n) * 0.01
    q = np.c_[np.sin(t), np.cos(t)]
    return joint_state_block((t * 1e9).astype(np.int64), q, q, q)


class LibraryBag:
    """A rosbag2 directory written with ``mcap.writer.Writer`` as the recorder writes it:
    CRCs on, chunked, metadata.yaml with the recording marker ``open`` until finished."""

    def __init__(self, directory: Path, compression: str = 'zstd', chunk_size: int = 1500,
                 topics: dict[str, str] | None = None, crcs: bool = True) -> None:
        directory.mkdir(parents=True)
        self.dir = directory
        self.path = directory / f'{directory.name}_0.mcap'
        self.file = open(self.path, 'wb')
        self.w = Writer(self.file, chunk_size=chunk_size,
                        compression=CompressionType[compression.upper()],
                        enable_crcs=crcs, enable_data_crcs=crcs)
        self.w.start(profile='ros2', library='test')
        self.ch: dict[str, int] = {}
        for topic, ty in (topics or {'/joint_states': JS}).items():
            sid = self.w.register_schema(ty, 'ros2msg', schema_text(ty).encode())
            self.ch[topic] = self.w.register_channel(
                topic, 'cdr', sid, {'offered_qos_profiles': QOS,
                                    'topic_type_hash': type_hash(ty)})
        self.w.add_metadata('arm_sim_robot', {k: json.dumps(v) for k, v in ROBOT.items()})
        self.ends: list[int] = []  # file size after each flush [bytes]
        self.log = 1000
        self.topics = topics or {'/joint_states': JS}
        self.meta('open')

    def meta(self, state: str) -> None:
        info = {'version': 9, 'storage_identifier': 'mcap', 'ros_distro': 'jazzy',
                'relative_file_paths': [self.path.name], 'message_count': 0,
                'custom_data': {RECORDING_KEY: state, 'operator': 'test'}}
        (self.dir / 'metadata.yaml').write_text(
            yaml.safe_dump({'rosbag2_bagfile_information': info}))

    def write(self, topic: str, messages: list[bytes], flush: bool = True) -> None:
        for m in messages:
            self.w.add_message(self.ch[topic], self.log, m, self.log)
            self.log += 1000
        if flush:
            self.w.flush()
            self.ends.append(self.file.tell())

    def finish(self) -> Path:
        self.w.finish()
        self.file.close()
        self.meta('closed')
        return self.path

    def kill_mid_chunk(self) -> int:
        """Stop as a SIGKILL during the last chunk's write would: the file is cut halfway
        through the last flushed chunk. Returns the cut position [bytes]."""
        self.file.close()
        cut = (self.ends[-2] + self.ends[-1]) // 2
        self.path.write_bytes(self.path.read_bytes()[:cut])
        return cut


def small_bag(tmp_path: Path, compression: str) -> Path:
    """A finished bag of a few KB: 48 JointStates in 4 chunks (schema text 2 KB)."""
    bag = LibraryBag(tmp_path / f'small_{compression}', compression)
    for _ in range(4):
        bag.write('/joint_states', states(12))
    return bag.finish()


# ---------------------------------------------------------------------- validation
@pytest.mark.parametrize('compression', COMPRESSIONS)
def test_every_flipped_byte_and_every_cut_of_a_finished_bag_raises_bag_error(
        tmp_path, compression):
    """Each byte XOR 0xFF and a cut at every 7th position: always BagError naming the file,
    the byte offset and ending with the recover hint; never another exception."""
    path = small_bag(tmp_path, compression)
    data = path.read_bytes()
    assert len(read_bag(path).joint_states) == 48 and len(data) < 16_000
    target = tmp_path / 'damaged.mcap'
    hint = f'`arm-sim bag recover {target}` keeps what is intact'
    flips = (data[:i] + bytes([data[i] ^ 0xFF]) + data[i + 1:] for i in range(len(data)))
    cuts = (data[:i] for i in range(0, len(data), 7))
    passed = []
    for i, bad in enumerate(itertools.chain(flips, cuts)):
        target.write_bytes(bad)
        try:
            read_bag(target)
            passed.append(i)
        except BagError as exc:
            msg = str(exc)
            if bad[:8] == MAGIC or bad[-8:] == MAGIC:  # damaged MCAP, not 'not MCAP'
                assert msg.startswith(f'{target}: byte ') and msg.endswith(hint), msg
    assert passed == [], f'{len(passed)} damaged files read without an error'


def test_a_bag_without_crcs_is_read_and_its_cut_is_still_an_error(tmp_path):
    """CRC fields 0 (not set) are not checked; framing still is."""
    bag = LibraryBag(tmp_path / 'nocrc', 'none', crcs=False)
    bag.write('/joint_states', states(30))
    path = bag.finish()
    assert len(read_bag(path).joint_states) == 30
    data = path.read_bytes()
    path.write_bytes(data[:-20])
    with pytest.raises(BagError, match='no MCAP magic at the end'):
        read_bag(path)


def test_garbage_cdr_in_a_crc_valid_chunk_gives_warnings_not_exceptions(tmp_path):
    rng = np.random.default_rng(7)
    topics = {'/joint_states': JS,
              '/arm_controller/joint_trajectory': TOPICS['arm_controller/joint_trajectory'],
              '/planner/path': TOPICS['planner/path'],
              '/goal_pose': 'geometry_msgs/msg/PoseStamped'}
    bag = LibraryBag(tmp_path / 'garbage', 'zstd', topics=topics)
    good = states(5)
    traj = encode_joint_trajectory(0, ['joint1', 'joint2'], np.zeros((2, 2)), [0.0, 1.0])
    path_msg = encode_path(0, np.zeros((3, 2)))
    for topic, sample in zip(topics, (good[0], traj, path_msg, good[0][:60]), strict=True):
        junk = [rng.bytes(int(n)) for n in rng.integers(0, 300, 40)]
        headed = [b'\x00\x01\x00\x00' + rng.bytes(int(n)) for n in rng.integers(0, 300, 40)]
        flipped = []
        for _ in range(60):  # valid messages with a few random bytes overwritten
            m = bytearray(sample)
            for k in rng.integers(4, len(m), 3):
                m[k] = int(rng.integers(0, 256))
            flipped.append(bytes(m))
        bag.write(topic, junk + headed + flipped + good)
    bag.finish()
    data = read_bag(bag.dir)  # must not raise anything
    assert len(data.joint_states) >= 5, 'the intact JointStates are kept'
    assert any('could not be decoded' in w for w in data.warnings)


# ---------------------------------------------------------------------- recovery
def test_recovery_of_a_bag_killed_mid_chunk_keeps_every_complete_chunk(tmp_path):
    bag = LibraryBag(tmp_path / 'bag', 'lz4')
    for _ in range(5):
        bag.write('/joint_states', states(10))
    cut = bag.kill_mid_chunk()
    report = recover_bag(bag.dir)
    assert report.messages == 40, 'the 4 chunks written before the cut chunk'
    assert report.cut_bytes == cut - bag.ends[-2], 'everything after the last intact record'
    assert report.compression == 'lz4' and report.topics == {'/joint_states': 40}
    assert 'kept 40 messages' in report.summary()
    data = read_bag(bag.dir)
    assert len(data.joint_states) == 40 and data.warnings == []
    assert bag.path.read_bytes()[-8:] == MAGIC
    info = yaml.safe_load((bag.dir / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']
    assert info['custom_data'] == {RECORDING_KEY: 'closed', 'operator': 'test'}
    assert info['message_count'] == 40 and info['ros_distro'] == 'jazzy'
    assert info['starting_time']['nanoseconds_since_epoch'] == 1000
    assert info['duration']['nanoseconds'] == 39 * 1000
    topic = info['topics_with_message_count'][0]
    assert topic['message_count'] == 40
    assert topic['topic_metadata']['offered_qos_profiles'] == yaml.safe_load(QOS)
    assert topic['topic_metadata']['type_description_hash'] == type_hash(JS)
    from mcap.reader import make_reader

    with open(bag.path, 'rb') as f:
        records = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert yaml.safe_load(records['rosbag2']['serialized_metadata']) == info
    assert json.loads(records['arm_sim_robot']['link_lengths']) == ROBOT['link_lengths']


def test_recovery_drops_a_chunk_with_a_bad_crc_and_keeps_the_chunks_after_it(tmp_path):
    bag = LibraryBag(tmp_path / 'bag', 'none')
    for _ in range(4):
        bag.write('/joint_states', states(10))
    path = bag.finish()
    data = bytearray(path.read_bytes())
    data[bag.ends[1] - 300] ^= 0xFF  # inside the second chunk's messages
    path.write_bytes(bytes(data))
    with pytest.raises(BagError, match='chunk CRC mismatch'):
        read_bag(bag.dir)  # marked closed: damage is an error, not a partial read
    out = tmp_path / 'recovered'
    report = recover_bag(bag.dir, output=out)
    # the library wrote 5 chunks: schemas + the first message once they exceed chunk_size,
    # then 9 + 10 + 10 + 10 messages; the 10 of the damaged one are lost
    assert report.messages == 30 and report.chunks_kept == 4
    assert any('chunk at byte' in d and 'crc' in d.lower() for d in report.dropped)
    assert path.read_bytes() == bytes(data), 'with --output the original is untouched'
    assert len(read_bag(out).joint_states) == 30


def test_nothing_recoverable_is_a_recovery_error_and_changes_nothing(tmp_path):
    junk = tmp_path / 'junk.mcap'
    junk.write_bytes(b'not an mcap file at all')
    with pytest.raises(RecoveryError, match='not an MCAP file'):
        recover_bag(junk)
    bag = LibraryBag(tmp_path / 'empty', 'zstd', chunk_size=1 << 20)
    bag.write('/joint_states', states(3))  # one chunk, then its 63-byte message index
    bag.file.close()
    bag.path.write_bytes(bag.path.read_bytes()[:bag.ends[0] - 100])
    before = bag.path.read_bytes()
    with pytest.raises(RecoveryError, match='nothing recoverable'):
        recover_bag(bag.dir)
    assert bag.path.read_bytes() == before


# ---------------------------------------------------------------------- automatic
def test_reading_a_dead_recorders_bag_recovers_it_in_place_first(tmp_path):
    bag = LibraryBag(tmp_path / 'bag', 'zstd')
    for _ in range(3):
        bag.write('/joint_states', states(10))
    cut = bag.kill_mid_chunk()
    assert recording_state(bag.dir) == 'open' and not is_locked(bag.path)
    data = read_bag(bag.dir)
    assert len(data.joint_states) == 20
    assert [w for w in data.warnings if 'recovered unfinished recording' in w] == [
        w for w in data.warnings if 'kept 20 messages' in w
        and f'dropped {cut - bag.ends[-2]} bytes at the end' in w]
    assert len(data.warnings) == 1, data.warnings
    assert recording_state(bag.dir) == 'closed'
    assert read_bag(bag.dir).warnings == [], 'complete now'


def test_a_bag_still_being_recorded_is_read_up_to_its_last_chunk_and_left_alone(tmp_path):
    bag = LibraryBag(tmp_path / 'bag', 'none')
    for _ in range(3):
        bag.write('/joint_states', states(10))
    bag.w.add_message(bag.ch['/joint_states'], bag.log, states(1)[0], bag.log)
    with open(bag.path, 'rb') as lock:
        fcntl.flock(lock.fileno(), fcntl.LOCK_EX)
        assert is_locked(bag.path)
        before = bag.path.read_bytes()
        data = read_bag(bag.dir)
        assert bag.path.read_bytes() == before, 'not modified'
        assert len(data.joint_states) == 30, 'the three flushed chunks'
        assert any('still being recorded' in w for w in data.warnings)
        with pytest.raises(RecoveryError, match='still being recorded'):
            recover_bag(bag.dir)
    bag.file.close()


def test_a_damaged_bag_marked_closed_is_an_error_and_is_not_modified(tmp_path):
    bag = LibraryBag(tmp_path / 'bag', 'zstd')
    for _ in range(3):
        bag.write('/joint_states', states(10))
    bag.kill_mid_chunk()
    bag.meta('closed')
    before = bag.path.read_bytes()
    with pytest.raises(BagError, match=r'no MCAP magic at the end.*arm-sim bag recover'):
        read_bag(bag.dir)
    assert bag.path.read_bytes() == before


def test_synthetic_bags_read_cleanly_and_survive_a_cut_and_recovery(tmp_path):
    w, ch = open_bag(tmp_path / 'bag', compression='zstd', chunk_size=2000)
    z = np.zeros((40, 2))
    write_run(w, ch, 1000, np.arange(40) * 0.01, z, z, z, z)
    w.close()
    assert len(read_bag(tmp_path / 'bag').joint_states) == 40
    mcap = tmp_path / 'bag' / 'bag_0.mcap'
    from mcap.reader import make_reader

    with open(mcap, 'rb') as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and len(summary.chunk_indexes) > 2
    last = summary.chunk_indexes[-1]
    mcap.write_bytes(mcap.read_bytes()[:last.chunk_start_offset + last.chunk_length // 2])
    report = recover_bag(tmp_path / 'bag')
    assert 0 < report.messages < 80 and report.cut_bytes == last.chunk_length // 2
    assert len(read_bag(tmp_path / 'bag').joint_states) > 0


def test_metadata_of_no_topics_is_an_empty_bag_that_keeps_the_earlier_fields():
    doc = bag_metadata([], [('a.mcap', None, None, 0)], custom={RECORDING_KEY: 'closed'},
                       base={'custom_data': {'x': '1'}, 'ros_distro': 'rolling'})
    assert doc['message_count'] == 0 and doc['duration'] == {'nanoseconds': 0}
    assert doc['custom_data'] == {'x': '1', RECORDING_KEY: 'closed'}
    assert doc['ros_distro'] == 'rolling' and doc['relative_file_paths'] == ['a.mcap']


# ---------------------------------------------------------------------- interop
def test_a_recovered_bag_opens_in_rosbags_mcap_and_mcap_ros2(tmp_path):
    topics = {'/joint_states': JS,
              '/planner/path': TOPICS['planner/path']}
    bag = LibraryBag(tmp_path / 'bag', 'zstd', topics=topics)
    for k in range(4):
        bag.write('/planner/path', [encode_path(k, np.full((3, 2), 0.1 * k))], flush=False)
        bag.write('/joint_states', states(10))
    bag.kill_mid_chunk()
    report = recover_bag(bag.dir)
    assert report.topics == {'/joint_states': 30, '/planner/path': 3}

    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag.dir) as reader:
        decoded = [store.deserialize_cdr(raw, conn.msgtype)
                   for conn, _, raw in reader.messages()]
        assert reader.message_count == 33
    assert len(decoded) == 33
    assert {type(m).__name__ for m in decoded} == {'sensor_msgs__msg__JointState',
                                                 'nav_msgs__msg__Path'}

    from mcap.reader import make_reader

    with open(bag.path, 'rb') as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == 33
        assert sum(1 for _ in reader.iter_messages()) == 33

    from mcap_ros2.decoder import DecoderFactory

    with open(bag.path, 'rb') as f:
        decoded_ros2 = list(make_reader(f, decoder_factories=[DecoderFactory()])
                            .iter_decoded_messages())
    paths = [m for _, ch, _, m in decoded_ros2 if ch.topic == '/planner/path']
    assert len(decoded_ros2) == 33 and [len(p.poses) for p in paths] == [3, 3, 3]
    assert paths[2].poses[0].pose.position.x == pytest.approx(0.2)
    with warnings.catch_warnings():  # mcap_ros2.reader, the older helper, is deprecated
        warnings.simplefilter('ignore', DeprecationWarning)
        from mcap_ros2.reader import read_ros2_messages

        assert sum(1 for _ in read_ros2_messages(str(bag.path))) == 33


# ---------------------------------------------------------------------- CLI
def arm_sim(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'arm_sim.cli', *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)


def test_cli_bag_recover_prints_a_summary_and_per_topic_counts(tmp_path):
    bag = LibraryBag(tmp_path / 'bag', 'zstd')
    for _ in range(3):
        bag.write('/joint_states', states(10))
    bag.kill_mid_chunk()
    out = arm_sim('bag', 'recover', str(bag.dir), '--output', str(tmp_path / 'out'))
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert 'kept 20 messages' in lines[0] and lines[1:] == ['  /joint_states: 20 messages']
    assert len(read_bag(tmp_path / 'out').joint_states) == 20
    help_text = ' '.join(arm_sim('bag', 'recover', '--help').stdout.split())
    assert 'mcap recover' in help_text and 'ros2 bag reindex' in help_text


@pytest.mark.parametrize('kind', ['garbage', 'cut_chunkless'])
def test_cli_bag_recover_of_nothing_recoverable_is_one_line_exit_4(tmp_path, kind):
    target = tmp_path / 'x.mcap'
    if kind == 'garbage':
        target.write_bytes(b'not an mcap file at all')
    else:
        target.write_bytes(small_bag(tmp_path, 'zstd').read_bytes()[:40])
    out = arm_sim('bag', 'recover', str(target))
    assert out.returncode == 4 and 'Traceback' not in out.stderr
    assert len(out.stderr.splitlines()) == 1, out.stderr


def test_cli_analyze_of_a_corrupt_bag_is_one_line_exit_4(tmp_path):
    path = small_bag(tmp_path, 'lz4')
    data = bytearray(path.read_bytes())
    data[len(data) // 3] ^= 0xFF
    path.write_bytes(bytes(data))
    out = arm_sim('analyze', str(path))
    assert out.returncode == 4 and 'Traceback' not in out.stderr
    errors = [line for line in out.stderr.splitlines() if not line.startswith('warning:')]
    assert len(errors) == 1 and 'arm-sim bag recover' in errors[0], out.stderr
