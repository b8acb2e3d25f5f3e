"""The live view's front (arm_sim.live_front): both names of the Foxglove WebSocket protocol
accepted, refusals with their reason; checked in-process against the Bridge (foxglove-sdk)
with a Python ``websockets`` client speaking ``foxglove.websocket.v1``."""

from __future__ import annotations

import asyncio
import json
import socket
import struct

import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

from arm_sim.live_front import (
    LEGACY_SUBPROTOCOL,
    SDK_SUBPROTOCOL,
    Upgrade,
    upgrade_request,
    upgrade_response,
)

websockets = pytest.importorskip('websockets')
pytest.importorskip('foxglove')
InvalidStatus = pytest.importorskip('websockets.exceptions').InvalidStatus

from arm_sim.live import Bridge, ClientMessage, ConnectionRefusal  # noqa: E402

REQUEST = ('GET / HTTP/1.1\r\nHost: localhost:8765\r\nUpgrade: websocket\r\n'
           'Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n'
           'Sec-WebSocket-Version: 13\r\n{protocols}\r\n')


def request(*protocols: str) -> bytes:
    line = f'Sec-WebSocket-Protocol: {", ".join(protocols)}\r\n' if protocols else ''
    return REQUEST.format(protocols=line).encode()


# ---------------------------------------------------------------------- the handshake
def test_the_legacy_name_is_offered_to_the_sdk_under_its_own_and_answered_back():
    up = upgrade_request(request('foo', LEGACY_SUBPROTOCOL))
    assert isinstance(up, Upgrade) and up.legacy and up.offered == ('foo', LEGACY_SUBPROTOCOL)
    text = up.head.decode()
    assert text.endswith('\r\n\r\n') and text.count('Sec-WebSocket-Protocol') == 1
    assert 'Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n' in text
    assert 'Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n' in text  # the accept key holds
    answer = (b'HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\n'
              b'Sec-WebSocket-Accept: s3pPLMBiTxaQ9kYGzzhZRbK+xOo=\r\n'
              b'sec-websocket-protocol: foxglove.sdk.v1\r\n\r\n')
    status, head = upgrade_response(answer, legacy=True)
    assert status == 101
    assert head == answer.replace(b'foxglove.sdk.v1', b'foxglove.websocket.v1')
    assert upgrade_response(answer, legacy=False) == (101, answer)


def test_an_sdk_name_goes_through_unchanged():
    head = request(LEGACY_SUBPROTOCOL, SDK_SUBPROTOCOL)
    assert upgrade_request(head) == Upgrade(head, False, (LEGACY_SUBPROTOCOL, SDK_SUBPROTOCOL))
    head = request('foxglove.sdk.v1.1')  # a later SDK name: the SDK decides
    assert upgrade_request(head) == Upgrade(head, False, ('foxglove.sdk.v1.1',))


@pytest.mark.parametrize('head, reason', [
    (request(), 'offered no WebSocket subprotocol (accepted: foxglove.sdk.v1, '
                'foxglove.websocket.v1)'),
    (request('mqtt', 'foxglove.websocket.v2'),
     'offered subprotocols mqtt, foxglove.websocket.v2; accepted: foxglove.sdk.v1, '
     'foxglove.websocket.v1'),
    (b'GET / HTTP/1.1\r\nHost: x\r\n\r\n', 'not a WebSocket upgrade request'),
    (b'POST / HTTP/1.1\r\nUpgrade: websocket\r\n\r\n', 'not a WebSocket upgrade request'),
])
def test_other_requests_are_refused_with_what_was_offered(head, reason):
    refusal = upgrade_request(head)
    assert isinstance(refusal, str) and refusal.startswith(reason), refusal


# ---------------------------------------------------------------------- through the Bridge
@pytest.fixture
def bridge():
    b = Bridge(port=0)
    yield b
    b.stop()


def _state() -> bytes:
    msg = JointState(name=['joint1', 'joint2'], position=[0.25, -1.5], velocity=[0.5, 0.0],
                     effort=[1.0, 2.0])
    msg.header.stamp.sec, msg.header.stamp.nanosec = 3, 40_000_000
    return serialize_message(msg)


async def _session(bridge: Bridge, subprotocols: list[str]) -> str:
    """Connect, read serverInfo and the advertisement, subscribe to /joint_states, get a
    state; publish a goal as a client. Returns the subprotocol the server answered."""
    async with websockets.connect(bridge.url, subprotocols=subprotocols, max_size=None) as ws:
        info = json.loads(await asyncio.wait_for(ws.recv(), 10))
        assert info['op'] == 'serverInfo' and info['name'] == 'arm_sim'
        assert {'clientPublish', 'time'} <= set(info['capabilities'])
        adv = json.loads(await asyncio.wait_for(ws.recv(), 10))
        assert adv['op'] == 'advertise'
        channel = next(c for c in adv['channels'] if c['topic'] == '/joint_states')
        assert (channel['encoding'], channel['schemaName']) == ('cdr',
                                                                'sensor_msgs/msg/JointState')
        await ws.send(json.dumps({'op': 'subscribe',
                                  'subscriptions': [{'id': 9, 'channelId': channel['id']}]}))
        data = _state()
        got = None
        for _ in range(200):  # the subscription is taken asynchronously: send until one comes
            bridge.forward('/joint_states', data, 3_040_000_000)
            try:
                got = await asyncio.wait_for(ws.recv(), 0.05)
                break
            except TimeoutError:
                continue
        assert isinstance(got, bytes) and got[0] == 1, got
        assert struct.unpack_from('<IQ', got, 1) == (9, 3_040_000_000)
        msg = deserialize_message(got[13:], JointState)
        assert list(msg.position) == [0.25, -1.5] and list(msg.name) == ['joint1', 'joint2']
        await ws.send(json.dumps({'op': 'advertise', 'channels': [{
            'id': 4, 'topic': '/goal_pose', 'encoding': 'json',
            'schemaName': 'geometry_msgs/msg/PoseStamped'}]}))
        goal = b'{"pose": {"position": {"x": 0.5}}}'
        for _ in range(200):  # likewise the advertisement
            await ws.send(struct.pack('<BI', 1, 4) + goal)
            items = [i for i in bridge.poll() if isinstance(i, ClientMessage)]
            if items:
                assert (items[0].topic, items[0].encoding, items[0].data,
                        items[0].ros_topic) == ('/goal_pose', 'json', goal, '/goal_pose')
                break
            await asyncio.sleep(0.02)  # let the SDK's thread take it; bounded by the loop
        else:
            pytest.fail('the client goal never reached the bridge')
        return str(ws.subprotocol)


@pytest.mark.parametrize('offered, answered', [
    ([LEGACY_SUBPROTOCOL], LEGACY_SUBPROTOCOL),
    ([SDK_SUBPROTOCOL], SDK_SUBPROTOCOL),
    ([LEGACY_SUBPROTOCOL, SDK_SUBPROTOCOL], SDK_SUBPROTOCOL),
])
def test_both_names_get_the_protocol(bridge, offered, answered):
    bridge.add_ros_channel('/joint_states', 'sensor_msgs/msg/JointState')
    assert asyncio.run(asyncio.wait_for(_session(bridge, offered), 60)) == answered


async def _publish_push(bridge: Bridge) -> tuple[list[str], ClientMessage]:
    """Advertise /cmd (refused) and simulator/push (no leading slash: accepted); publish a
    push. Returns the refusals and the push as the bridge hands them to the node."""
    async with websockets.connect(bridge.url, subprotocols=[LEGACY_SUBPROTOCOL]) as ws:
        await ws.send(json.dumps({'op': 'advertise', 'channels': [
            {'id': 1, 'topic': '/cmd', 'encoding': 'json', 'schemaName': ''},
            {'id': 2, 'topic': 'simulator/push', 'encoding': 'json',
             'schemaName': 'geometry_msgs/msg/WrenchStamped'}]}))
        push = b'{"wrench": {"force": {"x": 0, "y": -30, "z": 0}}}'
        refusals: list[str] = []
        for _ in range(200):  # the advertisement is taken asynchronously: send until taken
            await ws.send(struct.pack('<BI', 1, 2) + push)
            items = bridge.poll()
            refusals += [i for i in items if isinstance(i, str)]
            pushes = [i for i in items if isinstance(i, ClientMessage)]
            if pushes:
                return refusals, pushes[0]
            await asyncio.sleep(0.02)  # let the SDK's thread take it; bounded by the loop
        pytest.fail('the client push never reached the bridge')


def test_a_push_channel_is_taken_and_other_topics_are_refused(bridge):
    refusals, push = asyncio.run(asyncio.wait_for(_publish_push(bridge), 60))
    assert (push.topic, push.encoding, push.ros_topic) == ('simulator/push', 'json',
                                                           '/simulator/push')
    assert json.loads(push.data)['wrench']['force']['y'] == -30
    assert len(refusals) == 1 and refusals[0].endswith(
        "only /goal_pose and /simulator/push can be published into ROS, not '/cmd'"), refusals


async def _refused(url: str, subprotocols: list[str] | None):
    with pytest.raises(InvalidStatus) as err:
        async with websockets.connect(url, subprotocols=subprotocols):
            pass
    return err.value.response


@pytest.mark.parametrize('offered, reason', [
    (['mqtt'], 'offered subprotocols mqtt; accepted: foxglove.sdk.v1, foxglove.websocket.v1'),
    (None, 'offered no WebSocket subprotocol'),
])
def test_a_refused_handshake_says_why_to_the_client_and_the_node(bridge, offered, reason):
    res = asyncio.run(_refused(bridge.url, offered))
    assert res.status_code == 400 and reason in res.body.decode()
    refusals = [i for i in bridge.poll() if isinstance(i, ConnectionRefusal)]
    assert len(refusals) == 1 and reason in refusals[0].text, refusals
    assert refusals[0].text.startswith('WebSocket handshake from 127.0.0.1:')


def test_a_port_in_use_is_refused_with_the_reason():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        s.listen()
        port = s.getsockname()[1]
        with pytest.raises(OSError, match=f'cannot serve on 127.0.0.1:{port}: .*in use'):
            Bridge(port=port)
