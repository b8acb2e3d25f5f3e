"""The arm's transforms (``tf``, ``tf_static``) as robot_state_publisher would send them.

Pure tests of :mod:`arm_sim.tf` against two independent references: the model's own
``forward_kinematics`` (the tip, composed through every published transform) and
yourdfpy's forward kinematics of the URDF text (every link frame). One process test: the
visualizer publishes ``tf`` per joint state with its stamp and ``tf_static`` once
(transient local), and the recorder records both.
"""

from __future__ import annotations

import io
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yourdfpy

from arm_bag.topics import DEFAULT_TOPICS, KNOWN_TOPICS, LATCHED
from arm_dynamics.models import robot_model
from arm_dynamics.robot import resolve_robot
from arm_dynamics.urdf import urdf_from_params
from arm_sim.tf import FrameTree, Transform, chain, compose, quat_from_rpy, urdf_joints

ROOT = Path(__file__).resolve().parents[1]
#: Robot parameter sets: the default 2-R arm, another one, a 3-link chain, the geared link.
ROBOTS = {
    'two_link': {},
    'two_link_long': {'link_lengths': [1.2, 0.6]},
    'planar_chain_3': {'model': 'planar_chain', 'link_lengths': [0.7, 0.5, 0.3]},
    'single_link_geared': {'model': 'single_link_geared'},
}
TOL = 1e-12  # m, and for rotation-matrix entries


def joint_states(n: int, count: int = 50, seed: int = 3) -> np.ndarray:
    """``count`` joint positions [rad] of n joints, wide (several turns) and edge cases."""
    rng = np.random.default_rng(seed)
    qs = rng.uniform(-2 * np.pi, 2 * np.pi, (count, n))
    qs[0] = 0.0
    qs[1] = np.pi
    return qs


def matrix(t: Transform) -> np.ndarray:
    """4x4 homogeneous matrix of ``t`` (independent of arm_sim.tf's quaternion code)."""
    x, y, z, w = t.rotation
    rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                    [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                    [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rot, t.translation
    return out


def load(urdf: str) -> yourdfpy.URDF:
    return yourdfpy.URDF.load(io.StringIO(urdf), load_meshes=False,
                              build_collision_scene_graph=False)


@pytest.mark.parametrize('name', ROBOTS)
def test_frames_are_the_urdf_links_and_joints(name):
    params = ROBOTS[name]
    urdf = urdf_from_params(params)
    tree = FrameTree(urdf)
    n = robot_model(resolve_robot(params)).n_dof
    links = ['base_link'] + [f'link{i + 1}' for i in range(n)]
    assert tree.joint_names == tuple(resolve_robot(params)['joint_names'])
    moving = tree.transforms([0.0] * n)
    assert [(t.parent, t.child) for t in moving] == list(zip(links[:-1], links[1:]))
    (static,) = tree.static_transforms()
    assert (static.parent, static.child) == (links[-1], 'tool0')
    # Every non-root link of the URDF is the child of exactly one transform.
    robot = load(urdf)
    assert {t.child for t in moving} | {static.child} == set(robot.link_map) - {'base_link'}


@pytest.mark.parametrize('name', ROBOTS)
def test_composed_tip_is_the_models_forward_kinematics(name):
    params = ROBOTS[name]
    arm = robot_model(resolve_robot(params))
    tree = FrameTree(urdf_from_params(params))
    static = tree.static_transforms()
    for q in joint_states(arm.n_dof):
        tip = chain(tree.transforms(q) + static, 'base_link', 'tool0')
        assert np.abs(np.array(tip.translation[:2]) - arm.forward_kinematics(q)).max() < TOL
        assert tip.translation[2] == 0.0
        # tool0's x axis along the last link: at the summed angle in the plane.
        assert np.abs(matrix(tip)[:3, :3] - matrix(Transform(
            'a', 'b', (0, 0, 0), quat_from_rpy(0, 0, float(np.sum(q)))))[:3, :3]).max() < TOL


@pytest.mark.parametrize('name', ROBOTS)
def test_every_link_frame_matches_yourdfpy(name):
    urdf = urdf_from_params(ROBOTS[name])
    tree, robot = FrameTree(urdf), load(urdf)
    for q in joint_states(len(tree.joint_names), count=20):
        robot.update_cfg(dict(zip(tree.joint_names, q)))
        transforms = tree.transforms(dict(zip(tree.joint_names, q))) + tree.static_transforms()
        for link in robot.link_map:
            ours = matrix(chain(transforms, 'base_link', link))
            assert np.abs(ours - robot.get_transform(link, 'base_link')).max() < TOL, link


#: A URDF that exercises what the suite's do not: origins with rpy, tilted axes, a
#: prismatic joint, an unnormalised revolute axis (KDL, hence robot_state_publisher, and
#: yourdfpy normalise it) and a branch.
GENERAL = '''<?xml version="1.0"?>
<robot name="general">
  <link name="base"/><link name="a"/><link name="b"/><link name="c"/><link name="d"/>
  <joint name="ja" type="revolute">
    <parent link="base"/><child link="a"/>
    <origin xyz="0.1 -0.2 0.3" rpy="0.4 -0.5 0.6"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/>
  </joint>
  <joint name="jb" type="prismatic">
    <parent link="a"/><child link="b"/>
    <origin xyz="0.5 0 0" rpy="1.0 0.2 -0.3"/><axis xyz="0.6 0.8 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/>
  </joint>
  <joint name="jc" type="continuous">
    <parent link="b"/><child link="c"/>
    <origin xyz="0 0.2 0" rpy="0 0 0"/><axis xyz="0.3 -0.4 0.5"/>
  </joint>
  <joint name="jd" type="fixed">
    <parent link="a"/><child link="d"/><origin xyz="0 0 0.7" rpy="-0.2 0.1 2.5"/>
  </joint>
</robot>
'''


def test_rpy_origins_axes_and_prismatic_joints_match_yourdfpy():
    tree, robot = FrameTree(GENERAL), load(GENERAL)
    assert tree.joint_names == ('ja', 'jb', 'jc')
    assert [(t.parent, t.child) for t in tree.static_transforms()] == [('a', 'd')]
    rng = np.random.default_rng(11)
    for q in rng.uniform(-3, 3, (30, 3)):
        robot.update_cfg(dict(zip(tree.joint_names, q)))
        transforms = tree.transforms(q) + tree.static_transforms()
        for link in ('a', 'b', 'c', 'd'):
            ours = matrix(chain(transforms, 'base', link))
            assert np.abs(ours - robot.get_transform(link, 'base')).max() < TOL, link


def test_compose_and_chain_refuse_what_does_not_connect():
    a = Transform('x', 'y', (1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match='cannot compose'):
        compose(a, a)
    with pytest.raises(ValueError, match="no transform chain from 'x' to 'z'"):
        chain([a], 'x', 'z')
    assert chain([a], 'x', 'x').translation == (0.0, 0.0, 0.0)


def test_bad_positions_and_urdfs_are_refused_with_the_reason():
    tree = FrameTree(urdf_from_params())
    with pytest.raises(ValueError, match=r"no position for joints \['joint2'\]"):
        tree.transforms({'joint1': 0.1})
    with pytest.raises(ValueError, match='1 positions for the 2 joints'):
        tree.transforms([0.1])
    with pytest.raises(ValueError, match='finite'):
        tree.transforms([0.1, float('nan')])
    with pytest.raises(ValueError, match='not a URDF'):
        FrameTree('<robot')
    with pytest.raises(ValueError, match='root element is <sdf>'):
        FrameTree('<sdf/>')
    floating = GENERAL.replace('type="continuous"', 'type="floating"')
    with pytest.raises(ValueError, match="joint 'jc': type 'floating'"):
        urdf_joints(floating)
    with pytest.raises(ValueError, match="joint 'jc' axis"):
        urdf_joints(GENERAL.replace('0.3 -0.4 0.5', '0.3 nan 0.5'))
    twice = GENERAL.replace('<child link="d"/>', '<child link="c"/>')
    with pytest.raises(ValueError, match=r"links \['c'\] are the child of more"):
        FrameTree(twice)


def test_arm_sim_tf_does_not_import_rclpy():
    code = 'import sys, arm_sim.tf; print("rclpy" in sys.modules)'
    out = subprocess.run([sys.executable, '-c', code], cwd=ROOT, capture_output=True,
                         text=True, timeout=60)
    assert out.stdout.strip() == 'False', out.stderr


def test_tf_and_tf_static_are_recorded_by_default_tf_static_latched():
    assert KNOWN_TOPICS['tf'] == KNOWN_TOPICS['tf_static'] == 'tf2_msgs/msg/TFMessage'
    assert {'tf', 'tf_static'} <= set(DEFAULT_TOPICS)
    assert 'tf_static' in LATCHED and 'tf' not in LATCHED


def test_tf_message_carries_each_transform_with_the_stamp():
    from builtin_interfaces.msg import Time

    from arm_sim.visualizer_node import tf_message

    tree = FrameTree(urdf_from_params())
    transforms = tree.transforms([0.3, -1.1])
    msg = tf_message(transforms, Time(sec=12, nanosec=345))
    assert len(msg.transforms) == 2
    for t, m in zip(transforms, msg.transforms):
        assert (m.header.frame_id, m.child_frame_id) == (t.parent, t.child)
        assert (m.header.stamp.sec, m.header.stamp.nanosec) == (12, 345)
        v, r = m.transform.translation, m.transform.rotation
        assert (v.x, v.y, v.z) == t.translation and (r.x, r.y, r.z, r.w) == t.rotation


# ---------------------------------------------------------------------- process
CHAIN = ROBOTS['planar_chain_3']
PERIOD_NS = 10_000_000  # 10 ms between the states sent
N_STATES = 40


def _summary(diags: list, node: str) -> dict:
    from conftest import statuses, values

    found = statuses(diags, node, 'summary')
    return values(found[-1]) if found else {}


def _stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _check(msg, sent: dict, tree: FrameTree, arm) -> None:
    """One TFMessage: a sent state's stamp on every transform, and exactly the tree's
    transforms of that state; with tf_static, its tip is the forward kinematics."""
    stamps = {_stamp_ns(t.header.stamp) for t in msg.transforms}
    assert len(stamps) == 1 and stamps <= set(sent), 'stamped with a joint state stamp'
    q = sent[stamps.pop()]
    got = [Transform(t.header.frame_id, t.child_frame_id,
                     (t.transform.translation.x, t.transform.translation.y,
                      t.transform.translation.z),
                     (t.transform.rotation.x, t.transform.rotation.y,
                      t.transform.rotation.z, t.transform.rotation.w))
           for t in msg.transforms]
    assert got == tree.transforms(q)
    tip = chain(got + tree.static_transforms(), 'base_link', 'tool0')
    assert np.abs(np.array(tip.translation[:2]) - arm.forward_kinematics(q)).max() < TOL


def test_visualizer_publishes_tf_per_state_and_tf_static_once_and_the_bag_has_them(
        ros, launch, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState
    from tf2_msgs.msg import TFMessage

    from arm_common.node import latched_qos

    out = tmp_path / 'bag'
    recorder = launch('recorder', params={'output': str(out), 'flush_period': 0.2})
    launch('visualizer', params={**CHAIN, 'wait_for_nodes': ['recorder']})
    arm = robot_model(resolve_robot(CHAIN))
    tree = FrameTree(urdf_from_params(CHAIN))
    names = list(tree.joint_names)
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    tfs = ros.collect(TFMessage, 'tf', qos=1000)
    states = ros.publisher(JointState, 'joint_states', qos=1000)
    # Named: a subscription of a node stopped in an earlier test can linger in the graph.
    ros.wait_matched(states, ['visualizer', 'recorder'], 20)
    qs = joint_states(len(names), count=N_STATES, seed=5)
    sent: dict[int, np.ndarray] = {}

    def publish(k: int) -> None:
        msg = JointState(name=names, position=[float(v) for v in qs[k % N_STATES]])
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * PERIOD_NS, 1_000_000_000)
        sent[k * PERIOD_NS] = qs[k % N_STATES]
        states.publish(msg)

    # A state every 0.2 s until this test's subscription gets transforms (the first ones
    # may go out before it matched; the visualizer holds at most 1000 while its gate waits
    # for the recorder, so they come slowly: none is dropped however long the gate takes),
    # then N_STATES more, each of which must arrive.
    k = 0
    end = time.monotonic() + 30
    while not tfs and time.monotonic() < end:
        publish(k)
        k += 1
        pause = time.monotonic() + 0.2  # a publisher's pace, not a wait on an outcome
        while not tfs and time.monotonic() < pause:
            ros.executor.spin_once(timeout_sec=0.02)
    assert tfs, 'no transforms within 30 s'
    first = k
    for _ in range(N_STATES):
        publish(k)
        k += 1
    last = (k - 1) * PERIOD_NS
    ros.wait_for(lambda: any(_stamp_ns(m.transforms[0].header.stamp) == last for m in tfs),
                 15, 'the transforms of the last state')
    received = {_stamp_ns(m.transforms[0].header.stamp) for m in tfs}
    assert {s * PERIOD_NS for s in range(first, k)} <= received, 'one tf per state'
    for msg in tfs:
        _check(msg, sent, tree, arm)
    # Subscribed only now: transient local delivers the one sent at start, and only it.
    statics: list = []
    ros._entities.append(ros.node.create_subscription(TFMessage, 'tf_static', statics.append,
                                                      latched_qos()))
    ros.wait_for(lambda: statics, 10, 'tf_static')
    (static,) = statics[0].transforms
    assert (static.header.frame_id, static.child_frame_id) == ('link3', 'tool0')
    assert (static.transform.translation.x, _stamp_ns(static.header.stamp)) == (0.3, 0)
    # The visualizer's figures as of the last state (its summary is current with every
    # state taken), with nothing held back. It took every state from the first it got on
    # (this test cannot see when the visualizer's side of the match was made, so the first
    # few may have found it not yet listening).
    at_last = f'{last * 1e-9:.9f}'
    figures = ros.wait_for(
        lambda: (v := _summary(diags, 'visualizer')).get('sim_time') == at_last
        and v.get('tf_held') == '0' and v, 15, 'the visualizer to report the last state')
    taken = int(figures['states'])
    assert k - first <= taken <= k, figures
    assert (figures['tf_sent'], figures['tf_dropped']) == (str(taken), '0'), 'one tf per state'
    # The recorder has every tf the visualizer sent (the gate held them until it matched).
    ros.wait_for(lambda: _summary(diags, '/recorder').get('received /tf') == str(taken), 15,
                 f'the recorder to receive the {taken} tf sent')
    assert recorder.stop(signal.SIGINT) == 0, recorder.output()
    assert len(statics) == 1, 'tf_static is sent once'
    with open(out / 'bag_0.mcap', 'rb') as f:
        reader = make_reader(f)
        bag: dict[str, list] = {'/tf': [], '/tf_static': []}
        for schema, channel, message in reader.iter_messages(topics=list(bag)):
            assert schema.name == 'tf2_msgs/msg/TFMessage'
            bag[channel.topic].append(deserialize_message(message.data, TFMessage))
    assert ([_stamp_ns(m.transforms[0].header.stamp) for m in bag['/tf']]
            == sorted(sent)[k - taken:]), 'every tf the visualizer sent, in order'
    for msg in bag['/tf']:
        _check(msg, sent, tree, arm)
    assert len(bag['/tf_static']) == 1 and bag['/tf_static'][0] == statics[0]
    metadata = (out / 'metadata.yaml').read_text()
    assert 'transient_local' in metadata.split('name: /tf_static', 1)[1].split('name: ')[0]
