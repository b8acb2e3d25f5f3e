"""Topic-level tests of the ``recorder`` node (a real process on a private domain)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import DOMAIN_ID, statuses, values
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from arm_bag.reader import read_bag
from arm_bag.recorder_node import SETTLED
from arm_bag.writer import RESERVE_NAME
from arm_sim.launcher import node_env

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


def test_sigkill_loses_at_most_the_last_flush_and_the_bag_is_completed_when_opened(
        ros, launch, tmp_path):
    proc, out, sent, diags = record(ros, launch, tmp_path)
    killed = recorder_endpoints(ros)
    assert proc.stop(signal.SIGKILL) == -signal.SIGKILL
    # Its DDS lease (~20 s): no later node may be handed its ports before. The evidence is
    # its subscription leaving discovery; its node name can outlive it in the ROS graph
    # (seen once past 60 s, a late ros_discovery_info), which is not the lease.
    ros.wait_for(lambda: not recorder_endpoints(ros) & killed, 60,
                 "the killed recorder's subscription to leave discovery (its lease)")
    meta = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['custom_data']['arm_sim.recording'] == 'open', 'the recorder never closed it'
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in meta['topics_with_message_count']}
    assert counts['/joint_states'] == N, 'metadata.yaml is as new as the last flush'
    bag = read_bag(out)  # completes the unfinished bag first
    assert [w for w in bag.warnings if 'recovered unfinished recording' in w], bag.warnings
    assert len(bag.joint_states) == N, 'everything flushed before the kill is kept'
    messages, (count, _, _) = rosbags_messages(out)  # now every tool opens it
    assert [raw for _, raw in messages['/joint_states']] == sent
    meta = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['custom_data']['arm_sim.recording'] == 'closed'
    assert meta['message_count'] == count == bag.message_count
    assert sorted(p.name for p in out.iterdir()) == ['bag_0.mcap', 'metadata.yaml'], (
        'the dead recorder\'s reserve is gone with the recovery')


def test_a_start_without_output_names_it_as_required(tmp_path):
    from arm_sim.launcher import NodeProcess

    proc = NodeProcess('recorder', log_path=tmp_path / 'rec.log', domain_id=0)
    assert proc.proc.wait(30) == 2
    lines = [x for x in proc.output().splitlines() if x.strip()]
    assert lines == ['recorder: refused parameters: output is required: the bag directory '
                     'to create (-p output:=DIR; it must not exist)']


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
        # Matched on our side (what we publish reaches it), not only seen in the graph.
        ros.wait_for(lambda: pub.get_subscription_count() >= 1, 20,
                     'the recorder to subscribe')
        i = 0

        def fill():
            nonlocal i
            for _ in range(20):
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
        # Messages our flood lost on the way are counted, with a warning saying so (the
        # recorder's books balance); any other warning is a bag not closed properly.
        assert [w for w in bag.warnings if 'were lost before the recorder' not in w] == []
        assert not bag.truncated, 'complete: summary and footer fit'
        assert not (mnt / 'bag' / RESERVE_NAME).exists()
        assert bag.joint_states.position[:, 0] == pytest.approx(
            0.001 * (bag.joint_states.stamp // 10_000_000))
    finally:
        subprocess.run(['umount', '-l', str(mnt)], check=False)


def pace(rate: float):
    """Yield once per 1/rate s of wall clock (a publisher's pace, not a wait on an outcome)."""
    start = time.perf_counter()
    k = 0
    while True:
        k += 1
        yield
        ahead = start + k / rate - time.perf_counter()
        if ahead > 0:
            time.sleep(ahead)


def test_a_known_sequence_at_10k_messages_per_second_is_recorded_whole_and_in_order(
        ros, launch, tmp_path):
    n, rate = 10_000, 10_000.0
    out = tmp_path / 'bag'
    ghosts = recorder_endpoints(ros)
    proc = launch('recorder', params={'output': str(out), 'topics': ['joint_states']})
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    # Reliable with room for the whole run: what the recorder cannot take at once waits.
    pub = ros.publisher(JointState, 'joint_states', qos=n)
    ros.wait_for(lambda: recorder_endpoints(ros) - ghosts and
                 pub.get_subscription_count() >= 1, 20, 'the recorder to subscribe')
    data = [serialize_message(state(i)) for i in range(n)]
    for raw, _ in zip(data, pace(rate)):
        pub.publish(raw)
    ros.wait_for(lambda: int(recorder_status(diags).get('written', 0)) >= n, 60,
                 f'the recorder to report {n} messages written')
    assert proc.stop(signal.SIGINT) == 0, proc.output()
    assert sorted(p.name for p in out.iterdir()) == ['bag_0.mcap', 'metadata.yaml'], (
        'nothing but the bag after a clean close')
    bag = read_bag(out)
    stamps = bag.joint_states.stamp
    assert len(stamps) == n and bag.message_count == n, 'every message, once'
    assert (stamps == np.arange(n) * 10_000_000).all(), 'in the order they were sent'
    meta = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert 'arm_sim.lost' not in meta['custom_data']
    assert int(recorder_status(diags)['lost']) == 0


def test_lost_messages_are_counted_per_topic_from_the_publisher_sequence(ros, launch,
                                                                          tmp_path):
    """A publisher stopped (SIGSTOP) cannot lose anything, so loss is made where it
    happens: a recorder whose queue holds 1 message, flooded by a best-effort burst."""
    out = tmp_path / 'bag'
    ghosts = recorder_endpoints(ros)
    proc = launch('recorder', params={'output': str(out), 'topics': ['joint_states'],
                                      'queue_depth': 1})
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
    pub = ros.node.create_publisher(JointState, 'joint_states', qos)
    ros._entities.append(pub)
    ros.wait_for(lambda: recorder_endpoints(ros) - ghosts and
                 pub.get_subscription_count() >= 1, 20, 'the recorder to subscribe')
    # The recorder subscribes again best effort once it sees this publisher.
    ros.wait_for(lambda: 'best effort' in proc.output(), 20,
                 'the recorder to subscribe again best effort')
    ros.wait_matched(pub, ['recorder'], 20)
    n = 5000
    data = [serialize_message(state(i)) for i in range(n)]
    # The recorder counts from the first message it takes (what a publisher that existed
    # before it settled sent earlier is not its to count): once it has taken one, every
    # later publication is kept or counted, so the burst's n all are.
    ros.wait_for(lambda: int(recorder_status(diags).get('received', 0)) >= 1
                 or (pub.publish(data[0]) and False), 20,
                 'the recorder to take a first message')
    for raw in data:
        pub.publish(raw)
    last = data[-1]
    ros.wait_for(lambda: int(recorder_status(diags).get('received', 0))
                 + int(recorder_status(diags).get('lost', 0)) >= n
                 or (pub.publish(last) and False), 30,
                 'the recorder to account for every message sent')
    assert proc.stop(signal.SIGINT) == 0, proc.output()
    meta = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    lost = json.loads(meta['custom_data']['arm_sim.lost'])['/joint_states']
    assert lost > 0, 'a queue of 1 under a burst of 5000 loses messages'
    from mcap.reader import make_reader

    with open(next(out.glob('*.mcap')), 'rb') as f:
        seqs = [m.sequence for _, ch, m in make_reader(f).iter_messages()
                if ch.topic == '/joint_states']
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs), 'in order, each once'
    # Every publication between the first and the last recorded one is kept or counted.
    assert len(seqs) + lost == seqs[-1] - seqs[0] + 1
    # /diagnostics reports loss as it is confirmed; a jump still pending when the recorder
    # closes (no message came after it) is confirmed then: in the bag and the closing line.
    assert 0 < int(recorder_status(diags)['lost']) <= lost
    assert f'({lost} lost before the recorder' in proc.output()
    warned = [w for w in read_bag(out).warnings if 'lost before the recorder' in w]
    assert warned == [f'/joint_states: {lost} messages were lost before the recorder '
                      '(counted by it from publisher sequence gaps and DDS loss events)']


WRONG_TYPE_PUBLISHER = '''
import sys, rclpy
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node('wrong_type')
pub = node.create_publisher(String, 'joint_states', 10)
sys.stdin.read()
node.destroy_node()
rclpy.try_shutdown()
'''


def test_a_late_publisher_a_wrong_type_and_clock_are_recorded_as_rosbag2_does(
        ros, launch, tmp_path):
    out = tmp_path / 'bag'
    ghosts = recorder_endpoints(ros)
    proc = launch('recorder', params={'output': str(out)})
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    ros.wait_for(lambda: recorder_endpoints(ros) - ghosts, 20, 'the recorder to subscribe')
    # A wrong-type publisher on joint_states (another process: one participant cannot
    # have both types on a topic), then the right one; and /clock.
    wrong = subprocess.Popen([sys.executable, '-c', WRONG_TYPE_PUBLISHER],
                             env=node_env(DOMAIN_ID), stdin=subprocess.PIPE)
    try:
        # Room for every message in both publishers' histories: a reliable publisher with a
        # short history overwrites what a loaded recorder has not yet acknowledged (a real
        # loss, which the recorder then counts, seen here under two busy loops).
        pub = ros.publisher(JointState, 'joint_states', qos=1000)
        clock = ros.publisher(Clock, 'clock', qos=1000)
        ros.wait_for(lambda: pub.get_subscription_count() >= 1 and
                     clock.get_subscription_count() >= 1, 20, 'the recorder to match')
        for i in range(100):
            pub.publish(state(i))
            c = Clock()
            c.clock.sec, c.clock.nanosec = divmod(i * 10_000_000, 1_000_000_000)
            clock.publish(c)
        ros.wait_for(lambda: int(recorder_status(diags).get('received /joint_states', 0))
                     >= 100 and int(recorder_status(diags).get('received /clock', 0)) >= 100,
                     20, 'the recorder to receive the states and clocks')
        ros.wait_for(lambda: statuses(diags, '/recorder', 'wrong_type'), 20,
                     'the wrong-type report')
    finally:
        wrong.communicate(b'', timeout=30)  # its stdin closes: it exits
    assert proc.stop(signal.SIGINT) == 0, proc.output()
    messages, _ = rosbags_messages(out)
    assert len(messages['/joint_states']) == 100 and len(messages['/clock']) == 100
    meta = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    qos = {t['topic_metadata']['name']: t['topic_metadata']['offered_qos_profiles']
           for t in meta['topics_with_message_count'] if t['message_count']}
    assert set(qos) == {'/joint_states', '/clock', '/diagnostics'}
    assert all(qos.values()), 'offered QoS written for every recorded topic'
    assert len(qos['/joint_states']) == 1, 'the JointState publisher, not the String one'
    found = statuses(diags, '/recorder', 'wrong_type')[-1]
    assert 'std_msgs/msg/String' in found.message


SECOND_PUBLISHER = '''
import sys, time, rclpy
from sensor_msgs.msg import JointState
rclpy.init()
node = rclpy.create_node('second_publisher')
pub = node.create_publisher(JointState, 'joint_states', 1000)
while pub.get_subscription_count() < 2:  # the recorder and the test
    time.sleep(0.01)
sys.stdin.readline()  # go
for i in range(300):
    pub.publish(JointState(name=['joint1', 'joint2'], position=[1.0, 2.0]))
    time.sleep(0.0005)
sys.stdin.read()
node.destroy_node()
rclpy.try_shutdown()
'''


def test_two_publishers_interleaving_on_a_topic_are_not_taken_for_loss(ros, launch,
                                                                        tmp_path):
    out = tmp_path / 'bag'
    ghosts = recorder_endpoints(ros)
    proc = launch('recorder', params={'output': str(out), 'topics': ['joint_states']})
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    received = ros.collect(JointState, 'joint_states', qos=1000)
    pub = ros.publisher(JointState, 'joint_states', qos=1000)
    ros.wait_for(lambda: recorder_endpoints(ros) - ghosts and
                 pub.get_subscription_count() >= 2, 20, 'the recorder to subscribe')
    # One publisher first, alone: its numbers run 1..100, then the second one joins.
    for i in range(100):
        pub.publish(state(i))
    second = subprocess.Popen([sys.executable, '-c', SECOND_PUBLISHER],
                              env=node_env(DOMAIN_ID), stdin=subprocess.PIPE)
    try:
        ros.wait_for(lambda: ros.node.count_publishers('joint_states') >= 2, 20,
                     'the second publisher')
        second.stdin.write(b'go\n')
        second.stdin.flush()
        for i, _ in zip(range(100, 400), pace(2000.0)):  # alongside the second one
            pub.publish(state(i))
        ros.wait_for(lambda: len(received) >= 700, 30, 'the test to receive all 700')
        ros.wait_for(lambda: int(recorder_status(diags).get('received /joint_states', 0))
                     >= 700, 20, 'the recorder to receive all 700')
    finally:
        second.communicate(b'', timeout=30)
    assert proc.stop(signal.SIGINT) == 0, proc.output()
    meta = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert 'arm_sim.lost' not in meta['custom_data'], meta['custom_data']
    assert len(read_bag(out).joint_states) == 700


LATE_PUBLISHER = '''
import sys, time, rclpy
from std_msgs.msg import Int64
rclpy.init()
node = rclpy.create_node('late_publisher')
# Reliable with room for everything: once the recorder is matched nothing is lost.
pub = node.create_publisher(Int64, 'late_topic', 100000)
n, matched, give_up = 0, None, time.monotonic() + 30
while (matched is None and time.monotonic() < give_up) or (matched is not None
                                                          and n < matched + 200):
    # from its start on, as a node publishes
    n += 1
    pub.publish(Int64(data=n))
    if matched is None and pub.get_subscription_count() >= 1:
        matched = n
    time.sleep(0.001)
print(n, flush=True)
sys.stdin.read()  # stay until told: the recorder may still be taking what is queued
node.destroy_node()
rclpy.try_shutdown()
'''


def test_a_late_publisher_of_a_new_topic_is_recorded_or_counted_lost_from_its_first_message(
        ros, launch, tmp_path):
    """A topic the recorder does not know, whose publisher starts after the recorder and
    publishes at once: what it sent before the recorder's subscription was matched never
    arrives, and is counted lost from the number of the first message received, so
    recorded + counted lost = published, and the recorded ones are the last ones sent."""
    out = tmp_path / 'bag'
    proc = launch('recorder', params={'output': str(out), 'topics': ['late_topic']})
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    ros.wait_for(lambda: SETTLED in proc.output(), 30,
                 'the recorder to have seen every publisher there was when it started')
    late = subprocess.Popen([sys.executable, '-c', LATE_PUBLISHER], env=node_env(DOMAIN_ID),
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        published = int(late.stdout.readline())
        ros.wait_for(lambda: int(recorder_status(diags).get('received /late_topic', 0))
                     + int(recorder_status(diags).get('lost /late_topic', 0)) >= published,
                     30, f'the recorder to account for all {published} messages')
        assert proc.stop(signal.SIGINT) == 0, proc.output()
    finally:
        late.communicate('', timeout=30)
    meta = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    lost = json.loads(meta['custom_data'].get('arm_sim.lost', '{}')).get('/late_topic', 0)
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Int64

    with open(out / 'bag_0.mcap', 'rb') as f:
        recorded = [deserialize_message(m.data, Int64).data
                    for _, ch, m in make_reader(f).iter_messages() if ch.topic == '/late_topic']
    assert lost > 0, 'it published before the recorder could have subscribed'
    assert len(recorded) + lost == published
    assert recorded == list(range(lost + 1, published + 1)), 'the last ones, each once'
    assert int(recorder_status(diags)['lost /late_topic']) == lost
