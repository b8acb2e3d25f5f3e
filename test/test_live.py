"""The live view: ``arm-sim bringup --foxglove`` serves the suite over the Foxglove WebSocket
protocol (arm_sim.live, arm_sim.live_node), checked with a real WebSocket client."""

from __future__ import annotations

import asyncio
import json
import math
import re
import signal
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import yaml
from conftest import statuses
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from arm_bag.msgdefs import schema_text
from arm_bag.recorder_node import message_class
from arm_bag.topics import KNOWN_TOPICS
from arm_dynamics import TwoLinkArm
from arm_dynamics.disturbance import MAX_LOAD
from arm_sim.launcher import config_file, node_env
from arm_sim.live import (
    CLIENT_CHANNELS,
    FRAMES,
    GOAL_CHANNEL,
    PARAMETER_BOOL,
    PARAMETER_BOOL_ARRAY,
    PARAMETER_BYTE_ARRAY,
    PARAMETER_DOUBLE,
    PARAMETER_DOUBLE_ARRAY,
    PARAMETER_INTEGER,
    PARAMETER_INTEGER_ARRAY,
    PARAMETER_NOT_SET,
    PARAMETER_STRING,
    PARAMETER_STRING_ARRAY,
    PUSH_CHANNEL,
    Bridge,
    Graph,
    RosParam,
    ServiceCall,
    Stamped,
    accepted_topic,
    arm_transforms,
    build_graph,
    cdr_header,
    cdr_string,
    client_channel_refusal,
    fill_message,
    fill_value_msg,
    foxglove_value,
    joint_positions,
    message_to_json,
    node_name,
    param_name,
    pose_from_json,
    pose_refusal,
    resolved_client_topics,
    ros_param_from_msg,
    ros_value,
    service_schemas,
    split_param_name,
    stamp_refusal,
    text_refusal,
)

websockets = pytest.importorskip('websockets')
pytest.importorskip('foxglove')

#: The SDK speaks the Foxglove WebSocket protocol v1 under the name ``foxglove.sdk.v1``;
#: ``foxglove.websocket.v1`` is the protocol's original name.
SUBPROTOCOLS = ['foxglove.sdk.v1', 'foxglove.websocket.v1']
ARM = TwoLinkArm()
PF = np.array([0.5, 1.2])
SUITE_TOPICS = {'/joint_states': 'sensor_msgs/msg/JointState',
                '/arm_controller/reference': 'sensor_msgs/msg/JointState',
                '/effort_controller/commands': 'std_msgs/msg/Float64MultiArray',
                '/planner/path': 'nav_msgs/msg/Path',
                '/goal_pose': 'geometry_msgs/msg/PoseStamped',
                '/clock': 'rosgraph_msgs/msg/Clock',
                '/robot_description': 'std_msgs/msg/String'}


# ---------------------------------------------------------------------- pure parts
def compose(transforms) -> dict[str, np.ndarray]:
    """Homogeneous 4x4 pose of every frame in the root frame of a transform tree."""
    poses = {FRAMES[0]: np.eye(4)}
    for t in transforms:
        x, y, z, w = t.rotation if hasattr(t, 'rotation') else t['rotation']
        tr = t.translation if hasattr(t, 'translation') else t['translation']
        m = np.eye(4)
        m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
        m[:3, 3] = tr
        parent = t.parent if hasattr(t, 'parent') else t['parent']
        child = t.child if hasattr(t, 'child') else t['child']
        poses[child] = poses[parent] @ m
    return poses


def test_the_frames_compose_to_the_arms_forward_kinematics():
    rng = np.random.default_rng(3)
    arm = TwoLinkArm(link_lengths=(1.2, 0.6))
    for q in rng.uniform(-math.pi, math.pi, (200, 2)):
        tfs = arm_transforms(arm, q)
        assert [(t.parent, t.child) for t in tfs] == list(zip(FRAMES, FRAMES[1:]))
        poses = compose(tfs)
        assert np.allclose(poses['tool0'][:2, 3], arm.forward_kinematics(q), atol=1e-12)
        assert np.allclose(poses['link2'][:2, 3], 1.2 * np.array([np.cos(q[0]),
                                                                  np.sin(q[0])]), atol=1e-12)
        heading = math.atan2(poses['tool0'][1, 0], poses['tool0'][0, 0])
        assert abs(math.remainder(heading - q.sum(), 2 * math.pi)) < 1e-12
    with pytest.raises(ValueError, match='q must be two finite'):
        arm_transforms(arm, [0.0, math.nan])


def test_joint_positions_are_taken_by_name():
    assert joint_positions(['joint2', 'joint1'], [2.0, 1.0], ['joint1', 'joint2']) == [1.0, 2.0]
    assert joint_positions(['joint1'], [1.0], ['joint1', 'joint2']) is None


def test_the_robot_description_is_a_cdr_string():
    text = '<robot name="ä"/>'
    assert deserialize_message(cdr_string(text), String).data == text


def test_client_goals_json_and_refusals():
    pose = pose_from_json(b'{"header": {"stamp": {"sec": 3, "nsec": 5}, "frame_id": "base_link"},'
                          b' "pose": {"position": {"x": 0.5, "y": 1.2}}}')
    assert (pose.sec, pose.nanosec, pose.frame_id) == (3, 5, 'base_link')
    assert pose.position == (0.5, 1.2, 0.0) and pose.orientation == (0.0, 0.0, 0.0, 1.0)
    with pytest.raises(ValueError, match='pose.position.x must be a finite number'):
        pose_from_json('{"pose": {"position": {"x": "far"}}}')
    with pytest.raises(ValueError, match='not JSON'):
        pose_from_json(b'\x00\x01')
    with pytest.raises(ValueError, match='pose must be an object with position and orientation'):
        pose_from_json('{"pose": 3}')
    with pytest.raises(ValueError, match='a PoseStamped must be a JSON object'):
        pose_from_json('[]')


# ---------------------------------------------------------------------- client channels
ACCEPTED = resolved_client_topics()


def test_the_client_channels_are_one_table_of_goal_pose_and_simulator_push():
    """One row per topic clients may publish: its ROS type (a suite topic's, with its
    schema installed), what the node counts and reports, and its numeric fields."""
    assert [(c.topic, c.type_name, c.kind, c.counter, c.rejected) for c in CLIENT_CHANNELS] == [
        ('goal_pose', 'geometry_msgs/msg/PoseStamped', 'goal', 'goals_published',
         'rejected_goal'),
        ('simulator/push', 'geometry_msgs/msg/WrenchStamped', 'push', 'pushes_published',
         'rejected_push')]
    assert [[(v.path, v.keys, v.bound) for v in c.vectors] for c in CLIENT_CHANNELS] == [
        [('pose.position', 'xyz', None), ('pose.orientation', 'xyzw', None)],
        [('wrench.force', 'xyz', MAX_LOAD), ('wrench.torque', 'xyz', MAX_LOAD)]]
    for c in CLIENT_CHANNELS:
        assert KNOWN_TOPICS[c.topic] == c.type_name and schema_text(c.type_name)
        assert message_class(c.type_name).__name__ == c.short_type
    assert ACCEPTED == {'/goal_pose': 'geometry_msgs/msg/PoseStamped',
                        '/simulator/push': 'geometry_msgs/msg/WrenchStamped'}
    assert resolved_client_topics(lambda t: '/arm2/' + t) == {
        '/arm2/goal_pose': 'geometry_msgs/msg/PoseStamped',
        '/arm2/simulator/push': 'geometry_msgs/msg/WrenchStamped'}


@pytest.mark.parametrize('cls, row', [(PoseStamped, GOAL_CHANNEL), (WrenchStamped, PUSH_CHANNEL)])
def test_a_rows_fields_fill_and_read_its_ros_message(cls, row):
    """What the node publishes from a JSON message is that message, field by field, and
    survives CDR as the CDR path reads it."""
    vectors = tuple(tuple(float(10 * i + j + 1) for j in range(len(v.keys)))
                    for i, v in enumerate(row.vectors))
    msg = row.fill(cls(), Stamped(3, 5, 'base_link', vectors))
    back = deserialize_message(serialize_message(msg), cls)
    assert (back.header.stamp.sec, back.header.stamp.nanosec, back.header.frame_id) == (
        3, 5, 'base_link')
    assert row.read(back) == vectors
    assert cdr_header(serialize_message(msg)) == (3, 5, 'base_link')


def test_a_foxglove_push_is_read_from_json():
    """What Foxglove's Publish panel sends on /simulator/push: the rest takes the message's
    defaults (zero stamp, empty frame, zero torque)."""
    push = PUSH_CHANNEL.from_json('{"wrench": {"force": {"x": 0, "y": -30, "z": 0}}}')
    assert push == Stamped(0, 0, '', ((0.0, -30.0, 0.0), (0.0, 0.0, 0.0)))
    push = PUSH_CHANNEL.from_json(json.dumps({
        'header': {'stamp': {'sec': 2, 'nsec': 7}, 'frame_id': 'base_link'},
        'wrench': {'force': {'x': 1e6, 'y': -1e6}, 'torque': {'z': 0.5}}}))
    assert push == Stamped(2, 7, 'base_link', ((1e6, -1e6, 0.0), (0.0, 0.0, 0.5)))
    assert PUSH_CHANNEL.describe(push.vectors) == 'wrench.force (1e+06, -1e+06, 0) N'
    assert GOAL_CHANNEL.describe(((0.5, 1.2, 0.0), (0.0, 0.0, 0.0, 1.0))) == ''


@pytest.mark.parametrize('doc, reason', [
    ({'wrench': {'force': {'x': 'hard'}}}, "wrench.force.x must be a finite number, got 'hard'"),
    ({'wrench': {'force': {'y': math.inf}}}, 'wrench.force.y must be a finite number, got inf'),
    ({'wrench': {'force': {'z': True}}}, 'wrench.force.z must be a finite number, got True'),
    ({'wrench': {'torque': {'z': math.nan}}}, 'wrench.torque.z must be a finite number'),
    ({'wrench': {'force': {'y': -2e6}}},
     'wrench.force.y = -2e+06 N is too large: at most 1e+06 N in magnitude'),
    ({'wrench': {'torque': {'x': 1e7}}},
     'wrench.torque.x = 1e+07 N m is too large: at most 1e+06 N m in magnitude'),
    ({'wrench': {'force': {'x': 10**400}}}, 'wrench.force.x must be a finite number'),
    ({'wrench': 3}, 'wrench must be an object with force and torque'),
    ({'wrench': {'force': [0, -30]}}, 'wrench.force must be an object with x, y, z'),
    ({'header': {'stamp': {'sec': 0, 'nanosec': -1}}}, 'nanosec = -1 is outside [0, 1e9)'),
    ({'header': {'stamp': {'sec': -5}}}, 'header.stamp is negative'),
    ({'header': {'stamp': {'sec': 2**40}}}, 'overflows'),
    ({'header': {'stamp': {'sec': 1.5}}}, 'header.stamp must hold integers'),
    ({'header': {'frame_id': 'base_link\x00x'}}, 'NUL'),
    ({'header': {'frame_id': 7}}, 'header.frame_id must be a string'),
    ([0, -30], 'a WrenchStamped must be a JSON object'),
])
def test_client_json_pushes_with_a_bad_field_are_refused_naming_it(doc, reason):
    with pytest.raises(ValueError, match=re.escape(reason)):
        PUSH_CHANNEL.from_json(json.dumps(doc))


def test_pushes_are_checked_as_the_cdr_path_reads_them():
    ok = ((0.0, -30.0, 0.0), (0.0, 0.0, 0.0))
    assert PUSH_CHANNEL.refusal(0, 0, '', ok) is None
    assert PUSH_CHANNEL.refusal(0, 0, '', ((MAX_LOAD, -MAX_LOAD, 0.0), ok[1])) is None
    assert 'wrench.torque.y must be a finite number, got nan' in PUSH_CHANNEL.refusal(
        0, 0, '', (ok[0], (0.0, math.nan, 0.0)))
    assert 'wrench.force.z = 1.5e+06 N is too large' in PUSH_CHANNEL.refusal(
        0, 0, '', ((0.0, 0.0, 1.5e6), ok[1]))
    assert 'NUL' in PUSH_CHANNEL.refusal(0, 0, 'a\x00b', ok)
    assert 'negative' in PUSH_CHANNEL.refusal(-1, 0, '', ok)
    with pytest.raises(ValueError, match='not JSON'):
        PUSH_CHANNEL.from_json(b'\xff')


def test_only_the_tables_topics_types_and_encodings_are_taken_from_clients():
    for topic, encoding, schema in [
            ('/goal_pose', 'cdr', 'geometry_msgs/msg/PoseStamped'),
            ('goal_pose', 'json', 'geometry_msgs/PoseStamped'),
            ('/simulator/push', 'json', 'geometry_msgs/msg/WrenchStamped'),
            ('simulator/push', 'cdr', 'geometry_msgs/WrenchStamped'),
            ('/simulator/push', 'json', '')]:
        assert client_channel_refusal(topic, ACCEPTED, encoding, schema) is None, topic
    assert accepted_topic('simulator/push', ACCEPTED) == '/simulator/push'
    assert accepted_topic('/cmd', ACCEPTED) is None
    assert client_channel_refusal('/cmd', ACCEPTED, 'cdr', '') == (
        "only /goal_pose and /simulator/push can be published into ROS, not '/cmd'")
    assert 'only /goal_pose can be' in client_channel_refusal(
        '/push', {'/goal_pose': 'geometry_msgs/msg/PoseStamped'}, 'cdr', '')
    assert client_channel_refusal('/simulator/push', ACCEPTED, 'protobuf', '') == (
        "/simulator/push: encoding 'protobuf' is not accepted (accepted: cdr, json)")
    assert client_channel_refusal('/simulator/push', ACCEPTED, 'cdr',
                                  'geometry_msgs/msg/PoseStamped') == (
        "/simulator/push: schema 'geometry_msgs/msg/PoseStamped' is not "
        'geometry_msgs/msg/WrenchStamped')
    assert 'schema' in client_channel_refusal('/goal_pose', ACCEPTED, 'cdr',
                                              'geometry_msgs/msg/Pose')
    # In a namespace only the resolved names are taken.
    arm2 = resolved_client_topics(lambda t: '/arm2/' + t)
    assert client_channel_refusal('/arm2/simulator/push', arm2, 'json', '') is None
    assert 'only /arm2/goal_pose and /arm2/simulator/push' in client_channel_refusal(
        '/simulator/push', arm2, 'json', '')


def test_stamps_frame_ids_and_numbers_are_validated():
    assert stamp_refusal(0, 0) is None and stamp_refusal(2**31 - 1, 999_999_999) is None
    assert 'negative' in stamp_refusal(-5, 0)
    assert 'overflows' in stamp_refusal(2**31, 0)
    assert 'nanosec = -1 is outside [0, 1e9)' in stamp_refusal(0, -1)
    assert 'nanosec = 1000000000 is outside' in stamp_refusal(0, 1_000_000_000)
    assert 'must be an integer' in stamp_refusal(1.5, 0)
    assert 'must be an integer' in stamp_refusal(0, True)
    assert text_refusal('base_link', 'frame') is None
    assert 'NUL' in text_refusal('base\x00link', 'frame')
    assert 'must be a string' in text_refusal(3, 'frame')
    ok = ((0.5, 1.2, 0.0), (0.0, 0.0, 0.0, 1.0))
    assert pose_refusal(1, 2, 'base_link', *ok) is None
    assert 'pose.position.y' in pose_refusal(1, 2, '', (0.5, math.inf, 0.0), ok[1])
    assert 'pose.orientation.w' in pose_refusal(1, 2, '', ok[0], (0, 0, 0, math.nan))


@pytest.mark.parametrize('doc, reason', [
    ({'header': {'stamp': {'sec': 0, 'nanosec': -1}}}, 'nanosec = -1 is outside [0, 1e9)'),
    ({'header': {'stamp': {'sec': 1, 'nsec': 2_000_000_000}}}, 'nanosec = 2000000000'),
    ({'header': {'stamp': {'sec': -5, 'nanosec': 0}}}, 'negative'),
    ({'header': {'stamp': {'sec': 2**40}}}, 'overflows'),
    ({'header': {'frame_id': 'base_link\x00x'}}, 'NUL'),
    ({'header': {'frame_id': 7}}, 'must be a string'),
])
def test_client_json_goals_with_bad_stamps_or_frames_are_refused(doc, reason):
    with pytest.raises(ValueError, match=re.escape(reason)):
        pose_from_json(json.dumps(doc))


def test_the_header_is_read_from_the_bytes_as_sent():
    """rclpy cuts a string at its first NUL; the bytes (forwarded to clients) keep it."""
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = -5, 7
    msg.header.frame_id = 'baseXlink'
    raw = serialize_message(msg).replace(b'baseXlink', b'base\x00link')
    assert deserialize_message(raw, JointState).header.frame_id == 'base'
    assert cdr_header(raw) == (-5, 7, 'base\x00link')
    clock = Clock()
    clock.clock.sec, clock.clock.nanosec = 3, 4
    assert cdr_header(serialize_message(clock), frame=False) == (3, 4, '')
    with pytest.raises(ValueError):
        cdr_header(b'\x00\x01\x00\x00\x01')


# ---------------------------------------------------------------------- protobuf
def _varint(b: bytes, i: int) -> tuple[int, int]:
    v = shift = 0
    while True:
        c = b[i]
        i += 1
        v |= (c & 0x7F) << shift
        shift += 7
        if c < 0x80:
            return v, i


def _fields(b: bytes) -> list[tuple[int, object]]:
    """Protobuf wire fields (number, value): varint ints, fixed64 as double, bytes."""
    out: list[tuple[int, object]] = []
    i = 0
    while i < len(b):
        key, i = _varint(b, i)
        num, wt = key >> 3, key & 7
        if wt == 0:
            v, i = _varint(b, i)
            out.append((num, v))
        elif wt == 1:
            out.append((num, struct.unpack_from('<d', b, i)[0]))
            i += 8
        elif wt == 2:
            n, i = _varint(b, i)
            out.append((num, b[i:i + n]))
            i += n
        elif wt == 5:
            out.append((num, struct.unpack_from('<f', b, i)[0]))
            i += 4
        else:
            raise ValueError(f'wire type {wt}')
    return out


def decode_frame_transforms(b: bytes) -> list[dict]:
    """foxglove.FrameTransforms (protobuf): transforms = 1; in each FrameTransform
    timestamp = 1 (seconds 1, nanos 2), parent 2, child 3, translation 4 (x 1, y 2, z 3),
    rotation 5 (x 1, y 2, z 3, w 4)."""
    out = []
    for num, raw in _fields(b):
        assert num == 1
        t: dict = {'stamp': 0, 'translation': [0.0] * 3, 'rotation': [0.0] * 4}
        for n, v in _fields(raw):  # type: ignore[arg-type]
            if n == 1:
                d = dict(_fields(v))  # type: ignore[arg-type]
                t['stamp'] = int(d.get(1, 0)) * 1_000_000_000 + int(d.get(2, 0))
            elif n in (2, 3):
                t['parent' if n == 2 else 'child'] = v.decode()  # type: ignore[union-attr]
            elif n in (4, 5):
                key, size = ('translation', 3) if n == 4 else ('rotation', 4)
                for k, x in _fields(v):  # type: ignore[arg-type]
                    if 1 <= k <= size:
                        t[key][k - 1] = x
        out.append(t)
    return out


# -------------------------------------------------------- parameters, services, graph
def test_parameter_names_are_foxglove_bridges_node_dot_parameter():
    assert param_name('/simulator', 'pause_at') == '/simulator.pause_at'
    assert split_param_name('/simulator.pause_at') == ('/simulator', 'pause_at')
    assert split_param_name('/arm/sim.qos_overrides./tf.depth') == (
        '/arm/sim', 'qos_overrides./tf.depth')
    assert node_name('/', 'simulator') == '/simulator' and node_name('/arm', 'sim') == '/arm/sim'
    for bad in ('pause_at', '/simulator', '/simulator.', 'simulator.pause_at', '/.x'):
        with pytest.raises(ValueError, match='/<node>.<parameter>'):
            split_param_name(bad)


ROS_AND_FOXGLOVE = [
    (RosParam(PARAMETER_BOOL, True), True, None),
    (RosParam(PARAMETER_INTEGER, 7), 7, None),
    (RosParam(PARAMETER_DOUBLE, 2.0), 2.0, 'float64'),
    (RosParam(PARAMETER_STRING, 'real_time'), 'real_time', None),
    (RosParam(PARAMETER_BYTE_ARRAY, b'\x00\xff'), b'\x00\xff', 'byte_array'),
    (RosParam(PARAMETER_BOOL_ARRAY, [True, False]), [True, False], None),
    (RosParam(PARAMETER_INTEGER_ARRAY, [1, -2]), [1, -2], None),
    (RosParam(PARAMETER_DOUBLE_ARRAY, [1.0, 0.8]), [1.0, 0.8], 'float64_array'),
    (RosParam(PARAMETER_STRING_ARRAY, ['joint1', 'joint2']), ['joint1', 'joint2'], None),
    (RosParam(PARAMETER_NOT_SET), None, None),
]


@pytest.mark.parametrize('ros, value, hint', ROS_AND_FOXGLOVE)
def test_parameter_values_map_both_ways_through_the_ros_message(ros, value, hint):
    from rcl_interfaces.msg import ParameterValue

    assert foxglove_value(ros) == (value, hint)
    assert ros_value(value, hint, ros.type) == ros
    msg = fill_value_msg(ParameterValue(), ros)  # the real message takes it
    assert ros_param_from_msg(msg) == ros
    assert ros_param_from_msg(deserialize_message(serialize_message(msg), ParameterValue)) == ros


def test_a_whole_number_set_on_a_double_parameter_is_a_double():
    assert ros_value(1000, None, PARAMETER_DOUBLE) == RosParam(PARAMETER_DOUBLE, 1000.0)
    assert ros_value(1000, 'float64') == RosParam(PARAMETER_DOUBLE, 1000.0)
    assert ros_value(1000, None, PARAMETER_INTEGER) == RosParam(PARAMETER_INTEGER, 1000)
    assert ros_value([1, 2], None, PARAMETER_DOUBLE_ARRAY) == RosParam(
        PARAMETER_DOUBLE_ARRAY, [1.0, 2.0])
    assert ros_value([1, 2.5]) == RosParam(PARAMETER_DOUBLE_ARRAY, [1.0, 2.5])
    assert ros_value([], None, PARAMETER_STRING_ARRAY) == RosParam(PARAMETER_STRING_ARRAY, [])
    assert ros_value('AAE=', 'byte_array') == RosParam(PARAMETER_BYTE_ARRAY, b'\x00\x01')
    # A type the node refuses is still sent: the node's reason is the one reported.
    assert ros_value('x', None, PARAMETER_DOUBLE) == RosParam(PARAMETER_STRING, 'x')


@pytest.mark.parametrize('value, current, reason', [
    ({'a': 1}, None, 'hold no maps'),
    ([1, 'a'], None, 'one kind'),
    ([], PARAMETER_DOUBLE, 'empty array'),
    (2**63, PARAMETER_INTEGER, 'beyond a 64-bit integer'),
    ([2**63], None, 'beyond a 64-bit integer'),
])
def test_values_no_ros_parameter_holds_are_refused_with_the_reason(value, current, reason):
    with pytest.raises(ValueError, match=reason):
        ros_value(value, None, current)


def test_service_schemas_are_the_srv_halves_with_their_definitions():
    request, response = service_schemas('std_srvs/srv/Trigger')
    assert request.strip() == '' and 'bool success' in response
    assert 'string message' in response
    request, response = service_schemas('std_srvs/srv/SetBool')
    assert 'bool data' in request and 'bool success' in response
    request, _ = service_schemas('rcl_interfaces/srv/SetParameters')
    # The types it uses follow, as in a ros2msg schema.
    assert 'MSG: rcl_interfaces/Parameter\n' in request
    assert 'MSG: rcl_interfaces/ParameterValue\n' in request
    with pytest.raises(LookupError, match='<pkg>/srv/<Type>'):
        service_schemas('std_msgs/msg/String')
    with pytest.raises(LookupError, match='no .srv file'):
        service_schemas('std_srvs/srv/NoSuch')


def test_service_requests_and_responses_in_json():
    from std_srvs.srv import SetBool, Trigger

    assert fill_message(SetBool.Request(), {'data': True}).data is True
    with pytest.raises(ValueError, match='nope: no such field'):
        fill_message(SetBool.Request(), {'nope': 1})
    with pytest.raises(ValueError, match='must be a JSON object'):
        fill_message(SetBool.Request(), [1])
    assert message_to_json(Trigger.Response(success=True, message='reset')) == {
        'success': True, 'message': 'reset'}
    state = JointState(name=['a'], position=[0.5])
    state.header.frame_id = 'base_link'
    doc = message_to_json(state)
    assert doc['header']['frame_id'] == 'base_link' and doc['position'] == [0.5]
    assert json.dumps(doc)


def test_a_service_call_in_json_is_answered_in_json_and_cdr_still_in_cdr():
    """Both of the server's supportedEncodings reach the node and come back labelled as
    called (a json call once got "Unsupported encoding" from the SDK: the advertisement
    declared cdr). The node's side is played here by a thread answering the Bridge's
    ServiceCall as :meth:`LiveNode._service_job` does, in the call's encoding."""
    from std_srvs.srv import SetBool

    bridge = Bridge(port=0)
    calls: list[tuple[str, bool]] = []
    stop = threading.Event()

    def node() -> None:
        while not stop.is_set():
            for request in bridge.poll():
                if not isinstance(request, ServiceCall):
                    continue
                if request.encoding == 'json':
                    req = fill_message(SetBool.Request(), json.loads(request.payload))
                else:
                    req = deserialize_message(request.payload, SetBool.Request)
                calls.append((request.encoding, req.data))
                resp = SetBool.Response(success=True, message=f'held: {req.data}')
                request.answer(json.dumps(message_to_json(resp)).encode()
                               if request.encoding == 'json' else serialize_message(resp))
            stop.wait(0.01)

    async def call(ws, sid: int, call_id: int, encoding: str, payload: bytes):
        await ws.send(struct.pack('<BIII', 2, sid, call_id, len(encoding))
                      + encoding.encode() + payload)
        while True:
            m = await asyncio.wait_for(ws.recv(), 15)
            if isinstance(m, str):
                doc = json.loads(m)
                assert doc['op'] != 'serviceCallFailure', doc
                continue
            if m[0] == 3:
                got_sid, got_call, n = struct.unpack_from('<III', m, 1)
                assert (got_sid, got_call) == (sid, call_id)
                return m[13:13 + n].decode(), bytes(m[13 + n:])

    async def session() -> None:
        async with websockets.connect(bridge.url, subprotocols=SUBPROTOCOLS) as ws:
            sid = None
            while sid is None:
                doc = json.loads(await asyncio.wait_for(ws.recv(), 10))
                if doc['op'] == 'serverInfo':
                    assert doc['supportedEncodings'] == ['cdr', 'json']
                if doc['op'] == 'advertiseServices':
                    (svc,) = doc['services']
                    assert (svc['name'], svc['type']) == ('/simulator/hold',
                                                          'std_srvs/srv/SetBool')
                    sid = svc['id']
            encoding, data = await call(ws, sid, 1, 'json', b'{"data": true}')
            assert encoding == 'json'
            assert json.loads(data) == {'success': True, 'message': 'held: True'}
            encoding, data = await call(ws, sid, 2, 'cdr',
                                        serialize_message(SetBool.Request(data=False)))
            assert encoding == 'cdr'
            assert deserialize_message(data, SetBool.Response).message == 'held: False'

    thread = threading.Thread(target=node, daemon=True)
    thread.start()
    try:
        assert bridge.set_services({'/simulator/hold': 'std_srvs/srv/SetBool'}) == []
        asyncio.run(asyncio.wait_for(session(), 60))
    finally:
        stop.set()
        thread.join(5)
        bridge.stop()
    assert calls == [('json', True), ('cdr', False)]


def test_the_connection_graph_is_sorted_merged_and_compares_by_content():
    g = build_graph({'/joint_states': ['/simulator'], '/clock': ['/simulator'],
                     '/lonely': []},
                    {'/joint_states': ['/live', '/controller', '/live']},
                    {'/simulator/reset': ['/simulator']})
    assert g == Graph(published=(('/clock', ('/simulator',)),
                                 ('/joint_states', ('/simulator',))),
                      subscribed=(('/joint_states', ('/controller', '/live')),),
                      services=(('/simulator/reset', ('/simulator',)),))
    same = build_graph({'/clock': ['/simulator'], '/joint_states': ['/simulator']},
                       {'/joint_states': ['/controller', '/live']},
                       {'/simulator/reset': ['/simulator']})
    assert same == g and build_graph({}, {}, {}) != g


# ---------------------------------------------------------------------- the live suite
class Client:
    """A Foxglove WebSocket client: advertisements, subscriptions, messages by topic."""

    def __init__(self, ws) -> None:
        self.ws = ws
        self.channels: dict[str, dict] = {}
        self.subs: dict[int, str] = {}
        self.messages: dict[str, list[tuple[int, bytes]]] = {}
        self.statuses: list[dict] = []
        self.server_info: dict = {}
        self.times: list[int] = []

    async def pump(self, until, timeout: float, what: str):
        """Receive until ``until()`` is truthy; fail after ``timeout`` s (wall)."""
        end = time.monotonic() + timeout
        while not until():
            left = end - time.monotonic()
            if left <= 0:
                pytest.fail(f'timed out after {timeout:g} s waiting for {what}')
            try:
                m = await asyncio.wait_for(self.ws.recv(), min(left, 1.0))
            except TimeoutError:
                continue
            self.handle(m)
        return until()

    def handle(self, m) -> None:
        if isinstance(m, str):
            doc = json.loads(m)
            if doc['op'] == 'serverInfo':
                self.server_info = doc
            elif doc['op'] == 'advertise':
                self.channels.update({c['topic']: c for c in doc['channels']})
            elif doc['op'] == 'status':
                self.statuses.append(doc)
            return
        if m[0] == 1:
            sub, log_time = struct.unpack_from('<IQ', m, 1)
            self.messages.setdefault(self.subs[sub], []).append((log_time, bytes(m[13:])))
        elif m[0] == 2:
            self.times.append(struct.unpack_from('<Q', m, 1)[0])

    async def subscribe(self, *topics: str) -> None:
        subs = []
        for topic in topics:
            sid = len(self.subs) + 1
            self.subs[sid] = topic
            subs.append({'id': sid, 'channelId': self.channels[topic]['id']})
        await self.ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))


def _read_lines(proc: subprocess.Popen, lines: list[str]) -> None:
    for line in proc.stdout:  # type: ignore[union-attr]
        lines.append(line)


def test_bringup_foxglove_serves_topics_the_robot_and_takes_goals(ros, tmp_path):
    """bringup --foxglove 0 (a free port, so sessions side by side do not collide): the
    suite's topics as cdr/ros2msg channels, joint states at the publish rate, /tf matching
    the forward kinematics of the joint states, the URDF, and a client's goal_pose moves
    the arm there."""
    from conftest import DOMAIN_ID

    rate = yaml.safe_load(config_file().read_text())['/**/simulator']['ros__parameters'][
        'publish_rate']
    proc = subprocess.Popen([sys.executable, '-m', 'arm_sim.cli', 'bringup', '--no-record',
                             '--foxglove', '0', '--out', str(tmp_path / 'run'),
                             '--domain-id', str(DOMAIN_ID)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=node_env(DOMAIN_ID))
    lines: list[str] = []
    reader = threading.Thread(target=_read_lines, args=(proc, lines), daemon=True)
    reader.start()
    try:
        end = time.monotonic() + 60
        while not any('Foxglove: open connection' in s for s in lines):
            assert proc.poll() is None, ''.join(lines)
            assert time.monotonic() < end, f'no Foxglove line within 60 s: {"".join(lines)}'
            time.sleep(0.05)  # polling a child's output: nothing to spin
        url = re.search(r'(ws://\S+)', next(s for s in lines if 'Foxglove' in s)).group(1)
        asyncio.run(asyncio.wait_for(_session(url, rate), 180))
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        reader.join(5)
    out = ''.join(lines)
    assert proc.returncode == 0, out
    assert re.search(r'stopped: .*live \(0\)', out), out


async def _session(url: str, rate: float) -> None:
    async with websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        c = Client(ws)
        await c.pump(lambda: c.server_info and set(SUITE_TOPICS) <= set(c.channels)
                     and '/tf' in c.channels, 30, 'the suite\'s channels')
        assert {'clientPublish', 'time'} <= set(c.server_info['capabilities'])
        assert 'cdr' in c.server_info['supportedEncodings']
        for topic, type_name in SUITE_TOPICS.items():
            ch = c.channels[topic]
            assert (ch['encoding'], ch['schemaEncoding'], ch['schemaName']) == (
                'cdr', 'ros2msg', type_name), ch
            assert ch['schema'] == schema_text(type_name)
        assert c.channels['/tf']['schemaName'] == 'foxglove.FrameTransforms'
        await c.subscribe('/joint_states', '/tf', '/robot_description')

        # The URDF (latched: sent to a client that subscribes late).
        await c.pump(lambda: c.messages.get('/robot_description'), 30, 'the URDF')
        urdf = deserialize_message(c.messages['/robot_description'][-1][1], String).data
        assert all(f'<link name="{f}"' in urdf for f in FRAMES)

        # Joint states at the simulator's publish rate, in simulated time.
        def states() -> list[JointState]:
            return [deserialize_message(d, JointState)
                    for _, d in c.messages.get('/joint_states', [])]

        await c.pump(lambda: len(c.messages.get('/joint_states', [])) >= 300, 60,
                     '300 joint states')
        got = states()
        stamps = np.unique([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in got])
        moving = stamps[stamps > stamps[0]]  # past the hold at the start (re-sent)
        span = moving[-1] - moving[0]
        assert span > 1.0, f'joint states span {span:.3f} s of simulated time'
        measured = (len(moving) - 1) / span
        assert 0.95 * rate <= measured <= 1.0001 * rate, (
            f'{len(moving)} states over {span:.3f} s: {measured:.1f} Hz, publish_rate {rate}')

        # /tf: base_link -> link1 -> link2 -> tool0 from the joint state of the same stamp.
        by_stamp = {m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec: m
                    for m in got}
        await c.pump(lambda: len(c.messages.get('/tf', [])) >= 50, 30, 'transforms')
        checked = 0
        for _, data in c.messages['/tf']:
            tfs = decode_frame_transforms(data)
            assert [(t['parent'], t['child']) for t in tfs] == list(zip(FRAMES, FRAMES[1:]))
            state = by_stamp.get(tfs[0]['stamp'])
            if state is None:
                continue
            poses = compose(tfs)
            tip = ARM.forward_kinematics(np.array(state.position))
            assert np.allclose(poses['tool0'][:2, 3], tip, atol=1e-9)
            checked += 1
        assert checked >= 40, f'only {checked} transforms matched a joint state'

        # A client's goal (what Foxglove's Publish pose sends) moves the arm there.
        await ws.send(json.dumps({'op': 'advertise', 'channels': [{
            'id': 7, 'topic': '/goal_pose', 'encoding': 'cdr',
            'schemaName': 'geometry_msgs/msg/PoseStamped', 'schemaEncoding': 'ros2msg',
            'schema': schema_text('geometry_msgs/msg/PoseStamped')}]}))
        goal = PoseStamped()
        goal.header.frame_id = 'base_link'
        goal.pose.position.x, goal.pose.position.y = float(PF[0]), float(PF[1])
        goal.pose.orientation.w = 1.0
        n = len(c.messages['/joint_states'])

        def reached() -> bool:
            data = c.messages['/joint_states'][-1][1] if len(
                c.messages['/joint_states']) > n else None
            if data is None:
                return False
            m = deserialize_message(data, JointState)
            tip = ARM.forward_kinematics(np.array(m.position))
            return bool(np.hypot(*(tip - PF)) < 1e-3 and np.abs(m.velocity).max() < 1e-2)

        # Sent again while nothing happens: the server may take the advertisement a moment
        # after the first message (bounded: at most 5 sends).
        for _ in range(5):
            await ws.send(struct.pack('<BI', 1, 7) + serialize_message(goal))
            try:
                await c.pump(lambda: reached() or _moving(c, n), 5, 'the arm to start')
                break
            except pytest.fail.Exception:
                continue
        await c.pump(reached, 60, 'the arm to reach the client\'s goal')


def _moving(c: Client, n: int) -> bool:
    recent = c.messages['/joint_states'][n:]
    return any(np.abs(deserialize_message(d, JointState).velocity).max() > 1e-2
               for _, d in recent[-5:])


# ---------------------------------------------------------------------- bad input
class ThreadedClient:
    """A :class:`Client` receiving in its own thread and event loop, so the test's ROS node
    can publish and spin meanwhile."""

    def __init__(self, url: str) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.c: Client = self.run(self._connect(url))
        self.receiving = asyncio.run_coroutine_threadsafe(self._receive(), self.loop)

    def run(self, coro, timeout: float = 30.0):
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    async def _connect(self, url: str) -> Client:
        return Client(await websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None))

    async def _receive(self) -> None:
        async for m in self.c.ws:
            self.c.handle(m)

    def send(self, data) -> None:
        self.run(self.c.ws.send(data))

    def close(self) -> None:
        try:
            self.run(self.c.ws.close(), timeout=10)
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self.thread.join(10)


def _state(sec: int, nanosec: int, q=(0.1, 0.2), frame: str = '') -> JointState:
    msg = JointState(name=['joint1', 'joint2'], position=[float(v) for v in q],
                     velocity=[0.0, 0.0], effort=[0.0, 0.0])
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    msg.header.frame_id = frame
    return msg


def _clock(sec: int, nanosec: int = 0) -> Clock:
    msg = Clock()
    msg.clock.sec, msg.clock.nanosec = sec, nanosec
    return msg


def test_the_live_node_refuses_bad_stamps_frames_and_goals_and_keeps_serving(ros, launch):
    """Negative, overflowing and out-of-range stamps on joint_states and clock, a NUL in a
    frame id, non-finite positions, and a client's JSON goal with nanosec -1 (each once
    took the node down, exit 1): each is refused with its reason on /diagnostics, never
    forwarded or published, and the node goes on serving good messages (and stops cleanly
    at the end: the launch fixture checks its exit code)."""
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    goals = ros.collect(PoseStamped, 'goal_pose')
    live = launch('live', params={'port': 0})
    found = ros.wait_for(lambda: re.search(r'serving (ws://\S+)', live.output()), timeout=60,
                         what='the live node to serve')
    states_pub = ros.publisher(JointState, 'joint_states')
    clock_pub = ros.publisher(Clock, 'clock')
    client = ThreadedClient(found.group(1))
    try:
        c = client.c
        ros.wait_for(lambda: {'/joint_states', '/clock'} <= set(c.channels),
                     what='the channels')
        client.run(c.subscribe('/joint_states', '/clock'))
        ros.wait_for(lambda: states_pub.get_subscription_count() > 0
                     and clock_pub.get_subscription_count() > 0, what='the live node to subscribe')

        def reported(kind: str, reason: str) -> bool:
            return any(reason in s.message for s in statuses(diags, '/live', kind))

        nul = serialize_message(_state(1, 0, frame='baseXlink')).replace(b'baseXlink',
                                                                          b'base\x00link')
        bad = [(states_pub, _state(-5, 0), 'rejected_joint_state', 'header.stamp is negative'),
               (states_pub, _state(1, 2_000_000_000), 'rejected_joint_state',
                'header.stamp.nanosec = 2000000000 is outside [0, 1e9)'),
               (states_pub, nul, 'rejected_joint_state', 'contains a NUL character'),
               (states_pub, _state(1, 0, q=(math.nan, 0.2)), 'rejected_joint_state',
                'q must be two finite joint positions'),
               (clock_pub, _clock(-5), 'rejected_clock', 'clock is negative')]
        for pub, msg, kind, reason in bad:
            ros.wait_for(lambda: reported(kind, reason) or pub.publish(msg), timeout=30,
                         what=f'{kind}: {reason}')
            assert live.alive(), live.output()[-3000:]

        # Still serving: a good state and time are forwarded, with the state's frames.
        assert '/tf' not in c.channels, 'no frames were sent for a refused state'
        good = _state(1, 500_000_000)
        ros.wait_for(lambda: '/tf' in c.channels or states_pub.publish(good),
                     what='the frames of the good state')  # the channel comes with them
        client.run(c.subscribe('/tf'))
        ros.wait_for(lambda: c.messages.get('/tf') and c.messages.get('/clock')
                     or states_pub.publish(good) or clock_pub.publish(_clock(1, 500_000_000)),
                     what='the good state and time forwarded')
        stamps = [(m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id)
                  for m in (deserialize_message(d, JointState)
                            for _, d in c.messages.get('/joint_states', []))]
        assert stamps and set(stamps) == {(1, 500_000_000, '')}, 'only the good state'
        assert {deserialize_message(d, Clock).clock.sec for _, d in c.messages['/clock']} == {1}
        assert {t['stamp'] for _, d in c.messages['/tf']
                for t in decode_frame_transforms(d)} == {1_500_000_000}

        # A client's JSON goal with nanosec -1: refused with a status; a good one goes out.
        client.send(json.dumps({'op': 'advertise', 'channels': [{
            'id': 3, 'topic': '/goal_pose', 'encoding': 'json',
            'schemaName': 'geometry_msgs/msg/PoseStamped'}]}))
        goal = {'header': {'stamp': {'sec': 0, 'nanosec': -1}, 'frame_id': 'base_link'},
                'pose': {'position': {'x': 0.5, 'y': 1.2}}}
        data = struct.pack('<BI', 1, 3) + json.dumps(goal).encode()
        ros.wait_for(lambda: reported('rejected_goal', 'nanosec = -1 is outside [0, 1e9)')
                     or client.send(data), what='the bad goal refused')
        ros.wait_for(lambda: any('nanosec = -1' in s['message'] for s in c.statuses),
                     what='the status message to the client')
        assert live.alive(), live.output()[-3000:]
        assert not goals, 'nothing published into ROS'
        goal['header']['stamp']['nanosec'] = 5
        data = struct.pack('<BI', 1, 3) + json.dumps(goal).encode()
        ros.wait_for(lambda: goals or client.send(data), what='the good goal published')
        assert (goals[0].header.stamp.nanosec, goals[0].header.frame_id) == (5, 'base_link')
    finally:
        client.close()
    assert live.alive(), live.output()[-3000:]


# ---------------------------------------------------------------------- without foxglove-sdk
HIDE_FOXGLOVE = "import sys; sys.modules['foxglove'] = None; "


def test_bringup_with_foxglove_but_no_foxglove_sdk_is_refused_in_one_line_before_starting(
        tmp_path):
    out = tmp_path / 'run'
    res = subprocess.run(
        [sys.executable, '-c', HIDE_FOXGLOVE + 'from arm_sim.cli import main; '
         f"sys.exit(main(['bringup', '--foxglove', '--out', {str(out)!r}]))"],
        capture_output=True, text=True, timeout=60)
    assert res.returncode != 0
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and 'foxglove-sdk' in lines[0] and 'pip install' in lines[0], (
        res.stderr)
    assert 'Traceback' not in res.stderr + res.stdout
    assert not out.exists(), 'nothing started'


def test_the_live_node_without_foxglove_sdk_says_how_to_install_it_without_a_traceback():
    res = subprocess.run(
        [sys.executable, '-c', HIDE_FOXGLOVE + 'from arm_sim.live_node import main; '
         "sys.exit(main(['--ros-args', '-p', 'port:=0']))"],
        capture_output=True, text=True, timeout=60, env=node_env())
    assert res.returncode != 0
    text = res.stdout + res.stderr
    assert 'foxglove-sdk' in text and 'pip install' in text, text
    assert 'Traceback' not in text, text


# ---------------------------------------------------------------------- /tf_static
def _tf_static(c: Client) -> list[tuple[str, str, tuple, tuple, tuple]]:
    """The transforms of the latest /tf_static message a client got: (parent, child,
    translation [m], rotation (x, y, z, w), stamp (sec, nanosec))."""
    from tf2_msgs.msg import TFMessage

    msg = deserialize_message(c.messages['/tf_static'][-1][1], TFMessage)
    return [(t.header.frame_id, t.child_frame_id,
             (t.transform.translation.x, t.transform.translation.y,
              t.transform.translation.z),
             (t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z,
              t.transform.rotation.w), (t.header.stamp.sec, t.header.stamp.nanosec))
            for t in msg.transforms]


def test_the_live_node_serves_the_fixed_joints_on_tf_static_latched(ros, launch):
    """/tf_static as foxglove_bridge relays robot_state_publisher's: a ``cdr`` channel of
    ``tf2_msgs/msg/TFMessage`` (``ros2msg`` schema) with the URDF's fixed joint ``link2 ->
    tool0`` at (l2, 0, 0) m, identity rotation, stamped 0; latched, so a client that
    subscribes later gets it too. A ROS publisher's robot_description of another robot
    brings its fixed joints (``rpy`` as a quaternion, 1e-12); one that is no URDF is
    reported and changes nothing."""
    from arm_common.node import latched_qos

    diags = ros.collect(DiagnosticArray, '/diagnostics')
    live = launch('live', params={'port': 0})
    url = ros.wait_for(lambda: re.search(r'serving (ws://\S+)', live.output()), timeout=60,
                       what='the live node to serve').group(1)
    expected = [('link2', 'tool0', (float(ARM.link_lengths[1]), 0.0, 0.0),
                 (0.0, 0.0, 0.0, 1.0), (0, 0))]
    clients = []
    try:
        for _ in range(2):  # the second subscribes after the message went out
            client = ThreadedClient(url)
            clients.append(client)
            c = client.c
            ros.wait_for(lambda: '/tf_static' in c.channels, what='the /tf_static channel')
            ch = c.channels['/tf_static']
            assert (ch['encoding'], ch['schemaEncoding'], ch['schemaName']) == (
                'cdr', 'ros2msg', 'tf2_msgs/msg/TFMessage'), ch
            assert ch['schema'] == schema_text('tf2_msgs/msg/TFMessage')
            client.run(c.subscribe('/tf_static'))
            ros.wait_for(lambda: c.messages.get('/tf_static'), what='the static transforms')
            got = _tf_static(c)
            assert [g[:2] + g[4:] for g in got] == [e[:2] + e[4:] for e in expected]
            assert np.allclose(got[0][2], expected[0][2], atol=1e-12)
            assert np.allclose(got[0][3], expected[0][3], atol=1e-12)

        # Another robot's description from ROS: its fixed joints replace them.
        c = clients[0].c
        descriptions = ros.publisher(String, 'robot_description', latched_qos())
        other = ('<robot name="other"><link name="base_link"/><link name="tip"/>'
                 '<joint name="tip_joint" type="fixed"><parent link="base_link"/>'
                 '<child link="tip"/><origin xyz="0.1 0.2 0.3" rpy="0 0 1.5707963267948966"/>'
                 '</joint></robot>')
        descriptions.publish(String(data=other))
        ros.wait_for(lambda: _tf_static(c)[0][1] == 'tip', timeout=30,
                     what='the other robot\'s static transforms')
        ((parent, child, xyz, rot, stamp),) = _tf_static(c)
        assert (parent, child, stamp) == ('base_link', 'tip', (0, 0))
        assert np.allclose(xyz, (0.1, 0.2, 0.3), atol=1e-12)
        assert np.allclose(rot, (0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)), atol=1e-12)
        sent = len(c.messages['/tf_static'])

        # No URDF: reported, the last transforms stay (nothing new is sent).
        descriptions.publish(String(data='not a URDF'))
        ros.wait_for(lambda: any('no fixed joints read from it' in s.message for s in
                                 statuses(diags, '/live', 'unreadable_robot_description')),
                     timeout=30, what='the unreadable description reported')
        assert len(c.messages['/tf_static']) == sent
        assert live.alive(), live.output()[-3000:]
    finally:
        for client in clients:
            client.close()
