"""Topic-level tests of the ``visualizer`` node (a real process on a private domain).

The test's own node plays the suite: it publishes ``joint_states`` with stamps,
``planner/path`` (transient local) and ``goal_pose``, and reads ``markers`` and
``robot_description``.
"""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import pytest
import yourdfpy
from conftest import events, goal_msg
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from visualization_msgs.msg import Marker, MarkerArray

from arm_common.node import latched_qos
from arm_dynamics import TwoLinkArm
from arm_dynamics.urdf import urdf_from_params

LENGTHS = [1.2, 0.6]  # m: not the defaults, so the node must use its parameters
ARM = TwoLinkArm(link_lengths=tuple(LENGTHS))
TRAIL = 0.05  # s
PERIOD_NS = 10_000_000  # 10 ms between the states sent
TOL = 1e-9  # m


def state(k: int, q, names=('joint1', 'joint2')) -> JointState:
    msg = JointState(name=list(names), position=[float(v) for v in q])
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * PERIOD_NS, 1_000_000_000)
    return msg


def stamp_ns(header) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def by_ns(array: MarkerArray) -> dict[str, Marker]:
    return {m.ns: m for m in array.markers}


def xy(marker: Marker) -> np.ndarray:
    return np.array([[p.x, p.y] for p in marker.points]).reshape(-1, 2)


def path_msg(points: np.ndarray, frame: str = 'base_link') -> Path:
    msg = Path()
    msg.header.frame_id = frame
    for x, y in points:
        pose = PoseStamped()
        pose.header.frame_id = frame
        pose.pose.position.x, pose.pose.position.y = float(x), float(y)
        pose.pose.orientation.w = 1.0
        msg.poses.append(pose)
    return msg


def latched(ros, msg_type, topic: str, publish: bool = True):
    """A transient-local publisher (``publish``) or subscription (else: returns the list
    it appends to) of the test node, removed at the end of the test."""
    if publish:
        entity = ros.node.create_publisher(msg_type, topic, latched_qos())
        ros._entities.append(entity)
        return entity
    received: list = []
    ros._entities.append(ros.node.create_subscription(msg_type, topic, received.append,
                                                      latched_qos()))
    return received


def test_markers_are_forward_kinematics_of_the_joint_states_with_trail_goal_and_path(
        ros, launch):
    launch('visualizer', params={'link_lengths': LENGTHS, 'trail_length': TRAIL})
    arrays = ros.collect(MarkerArray, 'markers')
    states = ros.publisher(JointState, 'joint_states', qos=1000)
    paths = latched(ros, Path, 'planner/path')
    goals = ros.publisher(PoseStamped, 'goal_pose')
    # Named: a subscription of a node stopped in an earlier test can linger in the graph.
    for pub in (states, goals, paths):
        ros.wait_matched(pub, ['visualizer'], 20)
    path = np.linspace([0.5, 1.2], [1.4, 0.2], 7)
    paths.publish(path_msg(path))
    goal = (0.5, 1.2)
    goals.publish(goal_msg(*goal, frame=''))  # empty frame = the marker frame
    rng = np.random.default_rng(7)
    qs = np.cumsum(rng.normal(0.0, 0.05, (400, 2)), axis=0) + [-0.4, 1.2]
    sent: dict[int, np.ndarray] = {}

    def complete() -> MarkerArray | None:
        """The newest array that shows the goal and the path."""
        for array in reversed(arrays):
            m = by_ns(array)
            if m['goal'].action == Marker.ADD and m['path'].action == Marker.ADD:
                return array
        return None

    k = 0
    while True:  # a state every spin until the markers show what was sent
        states.publish(state(k, qs[k % len(qs)]))
        sent[k * PERIOD_NS] = qs[k % len(qs)]
        k += 1
        ros.executor.spin_once(timeout_sec=0.005)
        if complete() and len(arrays) >= 3 or k > 20_000:
            break
    array = ros.wait_for(complete, 10, 'markers with the goal and the path')
    assert len({tuple(sorted(by_ns(a))) for a in arrays}) == 1, 'the same markers each time'
    for array in arrays:
        t = stamp_ns(array.markers[0].header)
        assert t in sent, 'stamped with a joint state stamp'
        q = sent[t]
        m = by_ns(array)
        assert set(m) == {'links', 'joints', 'tip', 'trail', 'goal', 'path'}
        for marker in array.markers:
            assert marker.header.frame_id == 'base_link' and stamp_ns(marker.header) == t
        tip = ARM.forward_kinematics(q)
        elbow = LENGTHS[0] * np.array([np.cos(q[0]), np.sin(q[0])])
        assert m['links'].type == Marker.LINE_LIST
        assert np.abs(xy(m['links']) - [[0, 0], elbow, elbow, tip]).max() < TOL
        assert m['joints'].type == Marker.SPHERE_LIST
        assert np.abs(xy(m['joints']) - [[0, 0], elbow]).max() < TOL
        p = m['tip'].pose.position
        assert m['tip'].type == Marker.SPHERE and np.abs([p.x - tip[0], p.y - tip[1]]).max() < TOL
        # The trail: the tip at every state of the last TRAIL s up to this one.
        window = [sent[s] for s in sorted(sent) if t - TRAIL * 1e9 <= s <= t]
        trail = m['trail']
        assert len(window) == min(t // PERIOD_NS + 1, round(TRAIL * 1e9 / PERIOD_NS) + 1)
        assert trail.type == Marker.LINE_STRIP
        if len(window) < 2:  # markers drawn after the first state only: no line yet
            assert trail.action == Marker.DELETE
            continue
        assert trail.action == Marker.ADD and len(trail.points) == len(window)
        assert np.abs(xy(trail) - ARM.forward_kinematics(np.array(window))).max() < TOL
    assert len(arrays) >= 3 and len(by_ns(arrays[-1])['trail'].points) == 6, 'a full trail'
    m = by_ns(array)
    assert np.abs(xy(m['path']) - path).max() < TOL
    g = m['goal'].pose.position
    assert (g.x, g.y) == goal


def test_robot_description_reaches_a_late_subscriber_and_is_the_urdf(ros, launch):
    launch('visualizer', params={'link_lengths': LENGTHS})
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    ros.wait_for(lambda: any(s.name == 'visualizer: summary' for d in diags
                             for s in d.status), 20, 'the visualizer to run')
    # Subscribed only now: transient local delivers the one sent at start.
    texts = latched(ros, String, 'robot_description', publish=False)
    ros.wait_for(lambda: texts, 10, 'robot_description')
    text = texts[0].data
    assert text == urdf_from_params({'link_lengths': LENGTHS})
    robot = yourdfpy.URDF.load(io.StringIO(text), load_meshes=False,
                               build_collision_scene_graph=False)
    assert set(robot.link_map) == {'base_link', 'link1', 'link2', 'tool0'}
    assert robot.joint_map['joint2'].origin[0, 3] == pytest.approx(LENGTHS[0])


def test_bad_input_is_reported_and_never_stops_the_markers(ros, launch):
    node = launch('visualizer')
    arrays = ros.collect(MarkerArray, 'markers')
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    states = ros.publisher(JointState, 'joint_states')
    goals = ros.publisher(PoseStamped, 'goal_pose')
    paths = latched(ros, Path, 'planner/path')
    # Named: a subscription of a node stopped in an earlier test can linger in the graph.
    for pub in (states, goals, paths):
        ros.wait_matched(pub, ['visualizer'], 20)
    # Its immediate reports reach us only once our /diagnostics subscription has matched
    # its publisher: wait for its periodic summary first (seen missed once under load).
    ros.wait_for(lambda: any(s.name.startswith('visualizer') for d in diags for s in d.status),
                 20, "the visualizer's /diagnostics")
    bad = [state(1, [0.1, 0.2], names=('joint1', 'elbow')),
           JointState(name=['joint1', 'joint2'], position=[0.1]),
           state(2, [float('nan'), 0.2]),
           state(3, [0.1, float('inf')])]
    for msg in bad:
        states.publish(msg)
    goals.publish(goal_msg(1.0, 0.5, frame='world'))
    goals.publish(goal_msg(float('nan'), 0.5))
    paths.publish(path_msg(np.array([[0.0, 1.0], [np.inf, 1.0]])))

    def counted(kind: str) -> int:
        return max((int(v.value) for d in diags for s in d.status
                    if s.name == f'visualizer: {kind}' for v in s.values
                    if v.key == 'count'), default=0)

    ros.wait_for(lambda: counted('rejected_joint_state') == 4 and counted('rejected_goal') == 2
                 and counted('rejected_path') == 1, 10, 'every bad message reported')
    assert events(diags, 'visualizer', 'rejected_joint_state'), 'reported at once'
    assert not arrays, 'nothing drawn from bad joint states'
    q = [0.3, -0.5]
    ros.wait_for(lambda: (states.publish(state(5, q)), arrays)[1], 10, 'markers')
    m = by_ns(arrays[-1])
    assert m['goal'].action == Marker.DELETE and m['path'].action == Marker.DELETE
    assert m['trail'].action == Marker.DELETE, 'one state: no trail line yet'
    p = m['tip'].pose.position
    tip = TwoLinkArm().forward_kinematics(np.array(q))
    assert abs(p.x - tip[0]) < TOL and abs(p.y - tip[1]) < TOL
    assert node.alive()
    log = node.output()
    for text in ('joint_states without joints', "frame_id 'world'", 'planner/path refused'):
        assert text in log, 'the first of each kind is logged'


def test_help_lists_the_parameters_and_bad_ones_are_refused():
    run = [sys.executable, '-m', 'arm_sim.visualizer_node']
    out = subprocess.run([*run, '--help'], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0
    for name in ('frame_id', 'rate', 'trail_length', 'link_lengths', '[Hz]'):
        assert name in out.stdout


def test_a_bad_rate_is_refused_at_start(launch):
    node = launch('visualizer', params={'rate': 0.0})
    assert node.proc.wait(30) == 2
    assert 'rate' in node.output()
