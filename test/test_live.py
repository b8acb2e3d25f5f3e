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
from geometry_msgs.msg import PoseStamped
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from arm_bag.msgdefs import schema_text
from arm_dynamics import TwoLinkArm
from arm_sim.launcher import config_file, node_env
from arm_sim.live import (
    FRAMES,
    arm_transforms,
    cdr_string,
    goal_channel_refusal,
    joint_positions,
    pose_from_json,
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
    ok = goal_channel_refusal('/goal_pose', '/goal_pose', 'cdr', 'geometry_msgs/msg/PoseStamped')
    assert ok is None
    assert goal_channel_refusal('goal_pose', '/goal_pose', 'json',
                                'geometry_msgs/PoseStamped') is None
    assert 'only /goal_pose' in goal_channel_refusal('/cmd', '/goal_pose', 'cdr', '')
    assert 'encoding' in goal_channel_refusal('/goal_pose', '/goal_pose', 'protobuf', '')
    assert 'schema' in goal_channel_refusal('/goal_pose', '/goal_pose', 'cdr',
                                            'geometry_msgs/msg/Pose')


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
