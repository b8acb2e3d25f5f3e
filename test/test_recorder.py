"""Topic-level tests of the ``recorder`` node (a real process on a private domain)."""

from __future__ import annotations

import signal
import subprocess
from pathlib import Path

import pytest
import yaml
from conftest import statuses, values
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState

from arm_bag.reader import read_bag

N = 200


def recorder_status(diags: list) -> dict:
    """Latest key/values the recorder reported on /diagnostics."""
    found = statuses(diags, '/recorder', 'summary')
    return values(found[-1]) | {'_message': found[-1].message} if found else {}


def recorder_endpoints(ros) -> set[bytes]:
    """GIDs of the recorder subscriptions on /joint_states the graph knows."""
    return {bytes(i.endpoint_gid) for i in ros.node.get_subscriptions_info_by_topic(
        '/joint_states') if i.node_name == 'recorder'}


def state(i: int) -> JointState:
    msg = JointState(name=['joint1', 'joint2'], position=[0.001 * i, -0.5],
                     velocity=[1.0, float(i)], effort=[2.0, -3.0])
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(i * 10_000_000, 1_000_000_000)
    return msg


def record(ros, launch, tmp_path: Path, n: int = N, **params):
    """Start a recorder, publish ``n`` joint states, wait until all are on disk."""
    out = tmp_path / 'bag'
    # A recorder killed by an earlier test stays in the graph until its lease expires:
    # wait for this recorder's own subscription, not just for any.
    ghosts = recorder_endpoints(ros)
    proc = launch('recorder', params={'output': str(out), 'flush_period': 0.2, **params})
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    # What a subscriber receives (CDR padding bytes differ from a local serialisation).
    received: list[bytes] = []
    ros._entities.append(ros.node.create_subscription(JointState, 'joint_states',
                                                      received.append, 1000, raw=True))
    pub = ros.publisher(JointState, 'joint_states', qos=1000)
    ros.wait_for(lambda: recorder_endpoints(ros) - ghosts and
                 pub.get_subscription_count() >= 2, 20,
                 'the recorder and the test to subscribe joint_states')
    for i in range(n):
        pub.publish(state(i))
    ros.wait_for(lambda: len(received) >= n and
                 int(recorder_status(diags).get('written', 0)) >= n, 20,
                 f'the recorder to report {n} messages written')
    return proc, out, received, diags


def rosbags_messages(path: Path) -> tuple[dict, list]:
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    out = {}
    with Reader(path) as reader:
        for conn, t, raw in reader.messages():
            store.deserialize_cdr(raw, conn.msgtype)  # every message deserialises
            out.setdefault(conn.topic, []).append((t, bytes(raw)))
        info = (reader.message_count, reader.start_time, reader.end_time)
    return out, info


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_recorded_messages_read_back_identical_with_rosbags(ros, launch, tmp_path, sig):
    proc, out, sent, _ = record(ros, launch, tmp_path)
    assert proc.stop(sig) == 0, proc.output()
    messages, (count, start, end) = rosbags_messages(out)
    assert [raw for _, raw in messages['/joint_states']] == sent, 'bytes and count'
    meta = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    assert meta['message_count'] == count == sum(len(v) for v in messages.values())
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in meta['topics_with_message_count']}
    assert counts['/joint_states'] == N
    assert counts == {k: len(v) for k, v in messages.items()} | {
        k: 0 for k in counts if k not in messages}
    assert meta['starting_time']['nanoseconds_since_epoch'] == start
    assert meta['duration']['nanoseconds'] == end - start - 1  # rosbags: end is exclusive
    bag = read_bag(out)
    assert bag.robot['link_lengths'] == [1.0, 0.8] and bag.warnings == []


def test_sigkill_loses_at_most_the_last_flush_and_the_rest_is_readable(ros, launch,
                                                                       tmp_path):
    proc, out, sent, diags = record(ros, launch, tmp_path)
    assert proc.stop(signal.SIGKILL) == -signal.SIGKILL
    ros.wait_gone('recorder')  # its lease: no later node may be handed its ports before
    meta = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    bag = read_bag(out)
    assert bag.truncated, 'no footer after SIGKILL'
    assert len(bag.joint_states) == N, 'everything flushed before the kill is readable'
    assert meta['message_count'] <= bag.message_count
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in meta['topics_with_message_count']}
    assert counts['/joint_states'] == N


def test_existing_output_directory_is_refused(tmp_path):
    from arm_sim.launcher import NodeProcess

    (tmp_path / 'bag').mkdir()
    proc = NodeProcess('recorder', params={'output': str(tmp_path / 'bag')},
                       log_path=tmp_path / 'rec.log', domain_id=0)
    assert proc.proc.wait(30) == 2
    lines = [x for x in proc.output().splitlines() if x.strip()]
    assert lines == [f"recorder: refused parameters: output '{tmp_path / 'bag'}' already "
                     'exists; refusing to overwrite it']


def test_full_disk_stops_recording_with_one_error_and_a_readable_bag(ros, launch, tmp_path):
    mnt = tmp_path / 'small'
    mnt.mkdir()
    if subprocess.run(['mount', '-t', 'tmpfs', '-o', 'size=256k', 'tmpfs', str(mnt)],
                      capture_output=True).returncode != 0:
        pytest.skip('cannot mount a tmpfs here (needs root)')
    try:
        proc = launch('recorder', params={'output': str(mnt / 'bag'), 'flush_period': 0.1,
                                          'chunk_size': 4096})
        diags = ros.collect(DiagnosticArray, '/diagnostics')
        pub = ros.publisher(JointState, 'joint_states', qos=1000)
        ros.wait_for(lambda: ros.node.count_subscribers('joint_states') >= 1, 20,
                     'the recorder to subscribe')
        i = 0

        def fill():
            nonlocal i
            for _ in range(50):
                pub.publish(state(i))
                i += 1
            return not proc.alive()

        ros.wait_for(fill, 30, 'the recorder to stop on the full disk')
        assert proc.proc.returncode == 1
        errors = [x for x in proc.output().splitlines() if 'ERROR' in x]
        assert len(errors) == 1 and 'No space left on device' in errors[0], proc.output()
        assert 'Traceback' not in proc.output()
        ros.wait_for(lambda: any(s.level in (2, b'\x02')
                                 for s in statuses(diags, '/recorder', 'summary')),
                     5, 'ERROR on /diagnostics')
        bag = read_bag(mnt / 'bag')
        assert len(bag.joint_states) > 100
        assert bag.joint_states.position[:, 0] == pytest.approx(
            0.001 * (bag.joint_states.stamp // 10_000_000))
    finally:
        subprocess.run(['umount', '-l', str(mnt)], check=False)
