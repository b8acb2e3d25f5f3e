"""A publisher created while the recorder runs (issue 35): every message it sent after its
match is in the bag, or the recorder reports exactly how many are not.

DDS matches each side on its own: the test's publisher matches the recorder's subscription
(so it sends) before the recorder's side has matched the publisher, which drops what comes
from a writer it does not know yet; once it matches, only what the publisher still keeps
(its history: 10 messages, 10 ms at 1 kHz) is sent again. What is missing is always the
publisher's first messages, and the number of the first one recorded says how many.
"""

from __future__ import annotations

import contextlib
import json
import signal
import time

import pytest
import yaml
from conftest import DOMAIN_ID, statuses, values
from control_msgs.msg import JointTrajectoryControllerState
from diagnostic_msgs.msg import DiagnosticArray
from mcap.reader import make_reader
from sensor_msgs.msg import JointState

from arm_bag.reader import read_bag
from arm_bag.recorder_node import SETTLED
from arm_bag.writer import UNRECORDED_START_KEY
from arm_common.gate import SubscriberGate

N = 3000      # messages published
RATE = 1000.0  # Hz (wall clock)
TOPIC = '/joint_states'


def recorder_status(diags: list) -> dict:
    """Latest key/values the recorder reported on /diagnostics."""
    found = statuses(diags, '/recorder', 'summary')
    return values(found[-1]) if found else {}


def state(k: int) -> JointState:
    """Publication ``k`` (1, 2, ...): stamped k ms, so the bag tells which arrived."""
    msg = JointState(name=['joint1', 'joint2'], position=[0.001 * k, -0.5],
                     velocity=[0.0, 0.0], effort=[0.0, 0.0])
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * 1_000_000, 1_000_000_000)
    return msg


@contextlib.contextmanager
def new_participant():
    """A node in a participant of its own, made now (as a process started now has): the
    recorder and it discover each other while the publisher already sends."""
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    node = rclpy.create_node('late_publisher', context=context)
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


def accounted(diags: list, topic: str) -> int:
    """Messages of ``topic`` the recorder says it received, lost or missed at the start."""
    s = recorder_status(diags)
    return sum(int(s.get(f'{key} {topic}', 0))
               for key in ('received', 'lost', 'unrecorded_start'))


@pytest.mark.parametrize('when', ['starting', 'settled'])
def test_a_publisher_created_while_recording_is_recorded_or_its_missing_start_counted_exactly(
        ros, launch, tmp_path, when):
    """``starting``: the publisher is made as the recorder starts (the issue's case: its
    first messages were missing, and '0 lost' said); ``settled``: after the recorder has
    seen every publisher there was (it then knows they are loss, not a start before it)."""
    out = tmp_path / 'bag'
    proc = launch('recorder', params={'output': str(out), 'flush_period': 0.2})
    diags = ros.collect(DiagnosticArray, '/diagnostics', qos=1000)
    if when == 'settled':
        ros.wait_for(lambda: SETTLED in proc.output(), 30,
                     'the recorder to have seen every publisher there was when it started')
    with new_participant() as node:
        # The default history (10): a user's publisher, not one deep enough to hide the
        # race (with 10000 every message arrives).
        pub = node.create_publisher(JointState, 'joint_states', 10)
        state_pub = node.create_publisher(JointTrajectoryControllerState,
                                          'arm_controller/controller_state', 10)
        gate = SubscriberGate(node, [pub, state_pub], ['recorder'])
        ros.wait_for(gate.open, 30, 'the publishers to match the recorder')
        start = time.perf_counter()
        for k in range(1, N + 1):  # at RATE, a node's pace (not a wait on an outcome)
            pub.publish(state(k))
            ahead = start + k / RATE - time.perf_counter()
            if ahead > 0:
                time.sleep(ahead)
        ros.wait_for(lambda: accounted(diags, TOPIC) >= N, 30,
                     f'the recorder to account for all {N} joint states')
        # controller_state is recorded by default (its type is built into the venv by
        # interfaces/build_interfaces.py).
        for _ in range(10):
            state_pub.publish(JointTrajectoryControllerState(joint_names=['joint1', 'joint2']))
        ros.wait_for(lambda: accounted(diags, '/arm_controller/controller_state') >= 10, 30,
                     'the recorder to account for the 10 controller states')
        assert proc.stop(signal.SIGINT) == 0, proc.output()

    meta = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    lost = json.loads(meta['custom_data'].get('arm_sim.lost', '{}')).get(TOPIC, 0)
    start_missed = json.loads(meta['custom_data'].get(UNRECORDED_START_KEY, '{}')).get(
        TOPIC, 0)
    bag = read_bag(out)
    recorded = [round(s / 1e6) for s in bag.joint_states.stamp]
    with open(out / 'bag_0.mcap', 'rb') as f:
        seqs = [m.sequence for _, ch, m in make_reader(f).iter_messages() if ch.topic == TOPIC]
    missing = N - len(recorded)
    assert recorded == list(range(missing + 1, N + 1)), (
        f'the last {len(recorded)} in order, each once; missing: the first {missing}')
    assert seqs == recorded, 'the MCAP sequence is the publication number'
    assert lost + start_missed == missing, (
        f'{missing} missing, {lost} counted lost, {start_missed} unrecorded start')
    if when == 'settled':  # it appeared while the recorder recorded: loss, as loss
        assert start_missed == 0 and lost == missing
    status = recorder_status(diags)
    assert int(status.get(f'lost {TOPIC}', 0)) == lost
    assert int(status.get(f'unrecorded_start {TOPIC}', 0)) == start_missed
    if missing:
        assert f'first message on {TOPIC} (number {missing + 1} of its publisher' in (
            proc.output())

    counts = {t['topic_metadata']['name']: t for t in meta['topics_with_message_count']}
    ctrl = counts['/arm_controller/controller_state']
    assert ctrl['topic_metadata']['type'] == 'control_msgs/msg/JointTrajectoryControllerState'
    ctrl_lost = sum(json.loads(meta['custom_data'].get(key, '{}')).get(
        '/arm_controller/controller_state', 0) for key in ('arm_sim.lost', UNRECORDED_START_KEY))
    assert ctrl['message_count'] >= 1 and ctrl['message_count'] + ctrl_lost == 10
    with open(out / 'bag_0.mcap', 'rb') as f:
        schemas = {s.name: s.data.decode() for s in make_reader(f).get_summary().schemas.values()}
    assert 'trajectory_msgs/JointTrajectoryPoint reference' in schemas[
        'control_msgs/msg/JointTrajectoryControllerState']
