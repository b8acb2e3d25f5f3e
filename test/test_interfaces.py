"""control_msgs and tf2_msgs: importable, Jazzy's type hashes, usable by rclpy.

``./run.sh setup`` builds them into the venv from the Jazzy definitions
(``interfaces/build_interfaces.py``, docs/interfaces.md); on a real ROS 2 Jazzy install the
real packages are used instead. Either way the types must carry the RIHS01 type hashes of
Jazzy's release, or a MoveIt / ros2_control on a real install would not match our topics
and actions.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import DOMAIN_ID

from arm_sim.launcher import node_env

#: RIHS01 hashes of ROS 2 Jazzy's types (control_msgs 5.8.0, tf2_msgs 0.36.4, with Jazzy's
#: std_msgs/geometry_msgs/trajectory_msgs 5.3 and action_msgs/builtin_interfaces 2.0).
#: Sources:
#: [seen] reported by ``ros2 topic info --verbose`` on real Jazzy systems, in public
#:        notes: TFMessage on /tf (and in a Jazzy rosbag2 metadata.yaml), and
#:        JointTrajectoryControllerState on a ros2_control controller_state topic
#:        (control_msgs >= 5.3, which added speed_scaling_factor).
#: [computed] no published copy found: computed by rosidl_generator_type_description 4.6.6
#:        (the Jazzy generator) from the control_msgs 5.8.0 definitions and the installed
#:        Jazzy dependencies; the same pipeline reproduces the [seen] hashes above and the
#:        shipped hashes of the installed trajectory_msgs wheel.
EXPECTED_HASHES = {
    'tf2_msgs/msg/TFMessage':  # [seen]
        'RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087',
    'control_msgs/msg/JointTrajectoryControllerState':  # [seen]
        'RIHS01_51d8dd89cc624cbe9daaeeb4d80d6de9b86168ffdc3be41fefc0953e3c26e480',
    'control_msgs/msg/JointTolerance':  # [computed]
        'RIHS01_c254f9cece0f3b733017b6990fd46d1326e25242d6b8844398c97d9a88e7d648',
    'control_msgs/msg/JointComponentTolerance':  # [computed]
        'RIHS01_739ea7566931944d33830fa10f1bf5e7a7fbdc3172bce7a7eaac642bd6e3ffa4',
    'control_msgs/action/FollowJointTrajectory':  # [computed]
        'RIHS01_738ebcb7a2d7cfa42f9f1001cc99ce3a4383d1cfe508015d9be8485e4b1c66f6',
    'control_msgs/action/FollowJointTrajectory_Goal':  # [computed]
        'RIHS01_8a9060704b269608f5a340934cc26e66869dd14bdac29e2e7fd9ec8b9882d205',
    'control_msgs/action/FollowJointTrajectory_Result':  # [computed]
        'RIHS01_8002e99ed2c14c6faa522f2a93c26d744c5982f254f9e98ff9c6f19789bdb220',
    'control_msgs/action/FollowJointTrajectory_Feedback':  # [computed]
        'RIHS01_3fd0aaecf71725121ae1ff7f01098a5e0da581e672be18a6b2c286cb43d96b49',
    'control_msgs/action/FollowJointTrajectory_SendGoal':  # [computed]
        'RIHS01_b13789dddc325a7a962825c45e28c77d37237ec129dd0c34dc5994562938c57f',
    'control_msgs/action/FollowJointTrajectory_GetResult':  # [computed]
        'RIHS01_e3ceb38e3e1867c8dc0f46014df26e90eb93422f27e9e97f936e07f94be4bc8b',
    'control_msgs/action/FollowJointTrajectory_FeedbackMessage':  # [computed]
        'RIHS01_80398fcb9674a79081a9906e2ccf0c804dd7cb15e22e362e606ee87186beab71',
    # msg/GripperCommand shares its file name with action/GripperCommand: the build must
    # not mix their descriptions up (rosidl_cli 4.6.6 pairs files by stem).
    'control_msgs/msg/GripperCommand':  # [computed]
        'RIHS01_57eb8f326c9889ca8bb34ead82cc94cc09bf6bc5c3b6c09546dca3a00b589890',
}


def share_dirs(package: str) -> list[Path]:
    """share/<package> in the venv and in every AMENT_PREFIX_PATH prefix."""
    prefixes = [sys.prefix] + os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep)
    return [Path(p) / 'share' / package for p in prefixes
            if p and (Path(p) / 'share' / package / 'package.xml').is_file()]


def described_hash(type_name: str) -> str:
    """The hash in the installed type description ``share/<pkg>/<kind>/<Type>.json``
    of the type's interface file (a subtype, FollowJointTrajectory_Goal, is in
    FollowJointTrajectory.json)."""
    import json

    package, kind, name = type_name.split('/')
    for share in share_dirs(package):
        file = share / kind / (name.split('_')[0] + '.json')
        if file.is_file():
            hashes = {h['type_name']: h['hash_string']
                      for h in json.loads(file.read_text())['type_hashes']}
            return hashes[type_name]
    pytest.fail(f'no type description of {type_name} installed (share/{package})')


def test_types_import():
    from control_msgs.action import FollowJointTrajectory
    from control_msgs.msg import JointTolerance, JointTrajectoryControllerState
    from tf2_msgs.msg import TFMessage

    goal = FollowJointTrajectory.Goal()
    assert goal.trajectory.joint_names == []
    assert JointTolerance(name='j1', position=0.1).position == 0.1
    assert JointTrajectoryControllerState().speed_scaling_factor == 0.0
    assert TFMessage().transforms == []
    # The C type support loads (rclpy needs it to publish or serve the type).
    for t in (FollowJointTrajectory, JointTolerance, JointTrajectoryControllerState, TFMessage):
        t.__class__.__import_type_support__()
    assert TFMessage._TYPE_SUPPORT is not None
    assert FollowJointTrajectory._TYPE_SUPPORT is not None


@pytest.mark.parametrize('type_name', sorted(EXPECTED_HASHES))
def test_type_description_hash_is_jazzys(type_name):
    assert described_hash(type_name) == EXPECTED_HASHES[type_name]


def test_tfmessage_round_trips_through_cdr():
    from geometry_msgs.msg import TransformStamped
    from rclpy.serialization import deserialize_message, serialize_message
    from tf2_msgs.msg import TFMessage

    t = TransformStamped(child_frame_id='link_1')
    t.header.frame_id = 'base_link'
    t.header.stamp.sec, t.header.stamp.nanosec = 12, 345
    t.transform.translation.x, t.transform.rotation.z, t.transform.rotation.w = 0.5, 0.6, 0.8
    msg = TFMessage(transforms=[t, TransformStamped(child_frame_id='link_2')])
    data = serialize_message(msg)
    assert data[:4] == b'\x00\x01\x00\x00'  # CDR little endian
    back = deserialize_message(data, TFMessage)
    assert back == msg
    assert back.transforms[0].transform.rotation.w == 0.8


SERVER = r'''
import sys
import rclpy
from rclpy.action import ActionServer
from control_msgs.action import FollowJointTrajectory
from tf2_msgs.msg import TFMessage
from geometry_msgs.msg import TransformStamped

rclpy.init()
node = rclpy.create_node('interfaces_test_server')
tf_pub = node.create_publisher(TFMessage, 'interfaces_test/tf', 10)

def publish_tf():
    t = TransformStamped(child_frame_id='tool0')
    t.header.frame_id = 'base_link'
    t.header.stamp = node.get_clock().now().to_msg()
    t.transform.translation.z = 0.25
    t.transform.rotation.w = 1.0
    tf_pub.publish(TFMessage(transforms=[t]))

def execute(goal_handle):
    traj = goal_handle.request.trajectory
    feedback = FollowJointTrajectory.Feedback(joint_names=list(traj.joint_names))
    feedback.desired = traj.points[-1]
    goal_handle.publish_feedback(feedback)
    goal_handle.succeed()
    return FollowJointTrajectory.Result(
        error_code=FollowJointTrajectory.Result.SUCCESSFUL,
        error_string=f'{len(traj.points)} points for {",".join(traj.joint_names)}')

server = ActionServer(node, FollowJointTrajectory, 'interfaces_test/follow_joint_trajectory',
                      execute)
node.create_timer(0.1, publish_tf)
print('ready', flush=True)
try:
    rclpy.spin(node)
except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
    pass
'''


def test_follow_joint_trajectory_and_tf_between_processes(ros, tmp_path):
    """An ActionServer in a child process completes our FollowJointTrajectory goal, and
    the TFMessages it publishes arrive here; the graph shows Jazzy's type hashes."""
    from builtin_interfaces.msg import Duration
    from control_msgs.action import FollowJointTrajectory
    from control_msgs.msg import GripperCommand, JointTrajectoryControllerState
    from rclpy.action import ActionClient
    from tf2_msgs.msg import TFMessage
    from trajectory_msgs.msg import JointTrajectoryPoint

    log = (tmp_path / 'server.log').open('w+')
    proc = subprocess.Popen([sys.executable, '-c', SERVER], env=node_env(DOMAIN_ID),
                            stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT)
    client = ActionClient(ros.node, FollowJointTrajectory,
                          'interfaces_test/follow_joint_trajectory')
    try:
        tfs = ros.collect(TFMessage, 'interfaces_test/tf')
        ros.wait_for(lambda: proc.poll() is not None or client.server_is_ready(), 30.0,
                     'the action server')
        assert proc.poll() is None, Path(log.name).read_text()

        goal = FollowJointTrajectory.Goal()
        goal.trajectory.joint_names = ['joint_1', 'joint_2']
        goal.trajectory.points = [
            JointTrajectoryPoint(positions=[0.1, 0.2], time_from_start=Duration(sec=1)),
            JointTrajectoryPoint(positions=[0.3, 0.4], time_from_start=Duration(sec=2))]
        feedback: list = []
        sent = client.send_goal_async(goal, feedback_callback=feedback.append)
        ros.wait_for(sent.done, 15.0, 'the goal to be accepted')
        handle = sent.result()
        assert handle.accepted
        result = handle.get_result_async()
        ros.wait_for(result.done, 15.0, 'the result')
        assert result.result().result.error_code == FollowJointTrajectory.Result.SUCCESSFUL
        assert result.result().result.error_string == '2 points for joint_1,joint_2'
        if feedback:  # best effort: feedback may arrive after the result
            assert list(feedback[0].feedback.desired.positions) == [0.3, 0.4]

        ros.wait_for(lambda: tfs, 10.0, 'a TFMessage from the server process')
        t = tfs[-1].transforms[0]
        assert (t.header.frame_id, t.child_frame_id) == ('base_link', 'tool0')
        assert t.transform.translation.z == 0.25

        # The hashes the other process announces, as the C type support computes them.
        def announced(topic: str) -> str:
            infos = ros.node.get_publishers_info_by_topic(topic)
            return str(infos[0].topic_type_hash) if infos else ''

        for topic, type_name in (
                ('/interfaces_test/tf', 'tf2_msgs/msg/TFMessage'),
                ('/interfaces_test/follow_joint_trajectory/_action/feedback',
                 'control_msgs/action/FollowJointTrajectory_FeedbackMessage')):
            ros.wait_for(lambda: announced(topic), 10.0, f'the publisher of {topic}')
            assert announced(topic) == EXPECTED_HASHES[type_name], topic
        # and the ones of our own publishers
        for msg_type, type_name in (
                (JointTrajectoryControllerState,
                 'control_msgs/msg/JointTrajectoryControllerState'),
                (GripperCommand, 'control_msgs/msg/GripperCommand')):
            topic = '/interfaces_test/' + type_name.rsplit('/', 1)[1]
            ros.publisher(msg_type, topic)
            assert announced(topic) == EXPECTED_HASHES[type_name], type_name
    finally:
        client.destroy()
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()
