"""A stock Foxglove client against the live node: npm's ``@foxglove/ws-protocol``
``FoxgloveClient`` (test/js/client.js), which offers only ``foxglove.websocket.v1``, gets
the simulator's joint states, publishes a goal and pushes the arm (a WrenchStamped on
/simulator/push, as Foxglove's Publish panel sends it); a client offering something else is
refused with the reason in the node's log. The same client then gets and sets the simulator's
parameters (a read-only one refused with the node's reason), calls /simulator/reset, gets the
connection graph and /rosout, as foxglove_bridge offers them."""

from __future__ import annotations

import asyncio
import base64
import json
import re
import shutil
import subprocess
import threading
from pathlib import Path

import pytest
from conftest import statuses, values
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rcl_interfaces.msg import Log, ParameterEvent
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from arm_sim.launcher import config_file

websockets = pytest.importorskip('websockets')
pytest.importorskip('foxglove')
InvalidStatus = pytest.importorskip('websockets.exceptions').InvalidStatus

JS = Path(__file__).parent / 'js'
CONFIG = config_file()


@pytest.fixture(scope='module')
def js_client() -> list[str]:
    """The command that runs test/js/client.js, its packages installed (``npm ci`` from
    the lock file, once); skipped with the reason when node or npm cannot provide them."""
    node, npm = shutil.which('node'), shutil.which('npm')
    if not node or not npm:
        pytest.skip('node and npm are needed for the @foxglove/ws-protocol client')
    installed = JS / 'node_modules' / '@foxglove' / 'ws-protocol' / 'package.json'
    if not installed.exists() or installed.stat().st_mtime < (
            JS / 'package-lock.json').stat().st_mtime:
        try:
            res = subprocess.run([npm, 'ci', '--no-audit', '--no-fund'], cwd=JS,
                                 capture_output=True, text=True, timeout=180)
        except subprocess.TimeoutExpired:
            pytest.skip('npm ci in test/js took over 180 s (registry unreachable?)')
        if res.returncode != 0:
            tail = ' '.join((res.stderr or res.stdout).strip().splitlines()[-3:])
            pytest.skip(f'npm ci in test/js failed (registry unreachable?): {tail}')
    return [node, str(JS / 'client.js')]


class JsClient:
    """client.js as a process: its events (JSON lines) collected by a thread."""

    def __init__(self, cmd: list[str], url: str) -> None:
        self.proc = subprocess.Popen(cmd + [url], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
        self.events: list[dict] = []
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:  # type: ignore[union-attr]
            self.events.append(json.loads(line))

    def of(self, kind: str) -> list[dict]:
        return [e for e in list(self.events) if e['event'] == kind]

    def send(self, **cmd) -> None:
        self.proc.stdin.write(json.dumps(cmd) + '\n')  # type: ignore[union-attr]
        self.proc.stdin.flush()  # type: ignore[union-attr]

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self.send(cmd='close')
                self.proc.wait(10)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait()
        self.reader.join(5)

    def stderr(self) -> str:
        return self.proc.stderr.read() if self.proc.poll() is not None else ''  # type: ignore


async def _refused(url: str) -> tuple[int, str]:
    with pytest.raises(InvalidStatus) as err:
        async with websockets.connect(url, subprotocols=['foxglove.websocket.v2', 'mqtt']):
            pass
    return err.value.response.status_code, err.value.response.body.decode()


def test_a_stock_foxglove_client_gets_the_simulators_joint_states_publishes_a_goal_and_pushes(
        ros, launch, js_client):
    """The live node and the simulator (real time, 100 Hz); ``FoxgloveClient`` offering
    ``foxglove.websocket.v1`` is answered with that name, gets serverInfo and the channels,
    subscribes to /joint_states and gets states equal, field by field, to those the
    simulator published (matched by stamp: this test's own subscription sees them too);
    its JSON goal on /goal_pose is published into ROS, and so is its JSON push on
    /simulator/push (a WrenchStamped with the same force, which the simulator applies and
    the node counts). A client offering other subprotocols gets 400 with the reason, which
    the node logs."""
    states = ros.collect(JointState, 'joint_states')
    goals = ros.collect(PoseStamped, 'goal_pose')
    pushes = ros.collect(WrenchStamped, 'simulator/push')
    events = ros.collect(ParameterEvent, '/parameter_events')
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    live = launch('live', params={'port': 0})
    sim = launch('simulator', params_file=CONFIG, params={'timing_mode': 'real_time'})
    found = ros.wait_for(lambda: re.search(r'serving (ws://\S+)', live.output()), timeout=30,
                         what='the live node to serve')
    url = found.group(1)
    client = JsClient(js_client, url)
    try:
        def channels() -> dict[str, dict]:
            return {c['topic']: c for e in client.of('advertise') for c in e['channels']}

        ros.wait_for(lambda: client.of('serverInfo') and '/joint_states' in channels()
                     or client.proc.poll() is not None, timeout=20,
                     what='serverInfo and the channels')
        assert client.proc.poll() is None, (client.events, client.stderr())
        assert client.of('open')[0]['protocol'] == 'foxglove.websocket.v1'
        info = client.of('serverInfo')[0]['info']
        assert info['name'] == 'arm_sim' and {
            'clientPublish', 'time', 'parameters', 'parametersSubscribe', 'services',
            'connectionGraph'} <= set(info['capabilities'])
        ch = channels()['/joint_states']
        assert (ch['encoding'], ch['schemaEncoding'], ch['schemaName']) == (
            'cdr', 'ros2msg', 'sensor_msgs/msg/JointState')
        client.send(cmd='subscribe', topic='/joint_states')

        def received() -> list[JointState]:
            return [deserialize_message(base64.b64decode(e['data']), JointState)
                    for e in client.of('message') if e['topic'] == '/joint_states']

        def stamp(m: JointState) -> tuple[int, int]:
            return m.header.stamp.sec, m.header.stamp.nanosec

        def matched() -> list[tuple[JointState, JointState]]:
            published = {stamp(m): m for m in states}
            return [(m, published[stamp(m)]) for m in received() if stamp(m) in published]

        pairs = ros.wait_for(lambda: len(matched()) >= 20 and matched(), timeout=20,
                             what='20 joint states the simulator published, via the client')
        for got, sent in pairs:
            assert (list(got.name), list(got.position), list(got.velocity),
                    list(got.effort), got.header.frame_id) == (
                list(sent.name), list(sent.position), list(sent.velocity),
                list(sent.effort), sent.header.frame_id)

        # clientAdvertise + clientPublish: a JSON goal (what Foxglove's Publish pose sends).
        client.send(cmd='advertise', topic='/goal_pose', encoding='json',
                    schemaName='geometry_msgs/msg/PoseStamped')
        cid = ros.wait_for(lambda: client.of('advertised'), what='the advertisement')[0][
            'channelId']
        goal = json.dumps({'header': {'stamp': {'sec': 1, 'nanosec': 5},
                                      'frame_id': 'base_link'},
                           'pose': {'position': {'x': 0.5, 'y': 1.2}}})
        # Sent again while not yet published: the server takes the advertisement a moment
        # after it is sent.
        ros.wait_for(lambda: goals or client.send(cmd='publish', channelId=cid, text=goal),
                     timeout=20, what='the client goal published into ROS')
        g = goals[0]
        assert (g.header.stamp.nanosec, g.header.frame_id, g.pose.position.x,
                g.pose.position.y) == (5, 'base_link', 0.5, 1.2)

        # A push, as Foxglove's Publish panel sends it on /simulator/push.
        client.send(cmd='advertise', topic='/simulator/push', encoding='json',
                    schemaName='geometry_msgs/msg/WrenchStamped')
        pid = ros.wait_for(lambda: [e for e in client.of('advertised')
                                    if e['topic'] == '/simulator/push'],
                           what='the push advertisement')[0]['channelId']
        push = json.dumps({'wrench': {'force': {'x': 0, 'y': -30, 'z': 0}}})
        ros.wait_for(lambda: pushes or client.send(cmd='publish', channelId=pid, text=push),
                     timeout=20, what='the client push published into ROS')
        assert {(p.wrench.force.x, p.wrench.force.y, p.wrench.force.z, p.wrench.torque.z,
                 p.header.frame_id) for p in pushes} == {(0.0, -30.0, 0.0, 0.0, '')}
        ros.wait_for(lambda: 'live push [0.0, -30.0] N' in sim.output(), timeout=10,
                     what='the simulator to take the push')
        # The node logs it after publishing: the simulator may take it first.
        ros.wait_for(lambda: 'push published on /simulator/push: wrench.force (0, -30, 0) N'
                     in live.output(), timeout=10, what="the node's log of the push")
        ros.wait_for(lambda: any(int(values(s).get('pushes_published', 0)) >= 1
                                 for s in statuses(diags, '/live', 'summary')),
                     timeout=10, what='pushes_published on /diagnostics')

        _parameters_services_graph_and_rosout(ros, client, events, live)
        assert not client.of('error'), client.of('error')
    finally:
        client.close()

    # A client offering neither name: 400 with the reason, logged by the node.
    status, body = asyncio.run(asyncio.wait_for(_refused(url), 20))
    reason = 'offered subprotocols foxglove.websocket.v2, mqtt; accepted: foxglove.sdk.v1, ' \
             'foxglove.websocket.v1'
    assert status == 400 and reason in body, body
    ros.wait_for(lambda: reason in live.output(), timeout=10, what='the refusal in the log')
    assert live.alive(), live.output()[-3000:]


def _parameters_services_graph_and_rosout(ros, client: JsClient, events: list, live) -> None:
    """getParameters / setParameters of the simulator's parameters (``/simulator.<name>``,
    as foxglove_bridge names them): a get answers its values, a set of the writable
    ``pause_at`` (a whole number for a double) changes it in ROS (the simulator's parameter
    event) and is answered with the new value, a set of the read-only ``physics_step`` is
    refused with the simulator's reason (a status message) and answered with the old value;
    a call of /simulator/reset (std_srvs/srv/Trigger, CDR) is answered with success; the
    connection graph names /joint_states with the simulator as its publisher and
    /simulator/reset with it as provider; /rosout is a channel and brings log messages."""
    def answer(request_id: str) -> dict:
        found = ros.wait_for(lambda: [e for e in client.of('parameterValues')
                                      if e['id'] == request_id], timeout=10,
                             what=f'the parameterValues answering {request_id}')
        return {p['name']: p for p in found[0]['parameters']}

    client.send(cmd='subscribe', topic='/rosout')
    client.send(cmd='getParameters', names=['/simulator.pause_at', '/simulator.timing_mode',
                                            '/simulator.physics_step'], id='get1')
    got = answer('get1')
    assert got['/simulator.pause_at']['value'] == -1 and got['/simulator.pause_at'].get(
        'type') == 'float64', got
    assert got['/simulator.timing_mode']['value'] == 'real_time'
    step = got['/simulator.physics_step']['value']

    client.send(cmd='setParameters', id='set1', parameters=[
        {'name': '/simulator.pause_at', 'value': 1000}])
    assert answer('set1')['/simulator.pause_at']['value'] == 1000
    ros.wait_for(lambda: any(e.node == '/simulator' and any(
        p.name == 'pause_at' and p.value.double_value == 1000.0
        for p in e.changed_parameters) for e in events), timeout=10,
        what='pause_at changed in ROS')
    client.send(cmd='getParameters', names=['/simulator.pause_at'], id='get2')
    assert answer('get2')['/simulator.pause_at']['value'] == 1000

    client.send(cmd='setParameters', id='set2', parameters=[
        {'name': '/simulator.physics_step', 'value': 0.002, 'type': 'float64'}])
    assert answer('set2')['/simulator.physics_step']['value'] == step
    refusal = ros.wait_for(lambda: [e['status']['message'] for e in client.of('status')
                                    if 'parameter /simulator.physics_step not set' in
                                    e['status']['message']], timeout=10,
                           what='the refusal of physics_step')[0]
    assert 'read-only' in refusal or 'read only' in refusal, refusal

    # /simulator/reset, from the advertised services (std_srvs/srv/Trigger, called in CDR).
    def advertised() -> dict[str, dict]:
        return {s['name']: s for e in client.of('advertiseServices') for s in e['services']}

    reset = ros.wait_for(lambda: advertised().get('/simulator/reset'), timeout=10,
                         what='/simulator/reset advertised')
    assert reset['type'] == 'std_srvs/srv/Trigger', reset
    client.send(cmd='callService', service='/simulator/reset', callId=7, encoding='cdr',
                data=base64.b64encode(serialize_message(Trigger.Request())).decode())
    done = ros.wait_for(lambda: [e for e in client.of('serviceCallResponse')
                                 + client.of('serviceCallFailure')
                                 if e.get('callId', e.get('failure', {}).get('callId')) == 7],
                        timeout=15, what='the answer to /simulator/reset')[0]
    assert done['event'] == 'serviceCallResponse', done
    response = deserialize_message(base64.b64decode(done['data']), Trigger.Response)
    assert response.success and response.message.startswith('reset to'), response

    # The connection graph: /joint_states published by the simulator.
    client.send(cmd='subscribeConnectionGraph')

    def graph(key: str, ids: str) -> dict[str, set[str]]:
        out: dict[str, set[str]] = {}
        for e in client.of('connectionGraphUpdate'):
            for item in e['graph'].get(key, []):
                out[item['name']] = set(item[ids])
        return out

    ros.wait_for(lambda: '/simulator' in graph('publishedTopics', 'publisherIds').get(
        '/joint_states', set()), timeout=10, what='the connection graph')
    assert '/live' in graph('subscribedTopics', 'subscriberIds')['/joint_states']
    ros.wait_for(lambda: '/simulator' in graph('advertisedServices', 'providerIds').get(
        '/simulator/reset', set()), timeout=10, what='/simulator/reset in the graph')

    # /rosout: a Log channel (rcl_interfaces/msg/Log), and the reset's own log line.
    def logs() -> list[Log]:
        return [deserialize_message(base64.b64decode(e['data']), Log)
                for e in client.of('message') if e['topic'] == '/rosout']

    ros.wait_for(lambda: any(m.name == 'simulator' and m.msg.startswith('reset to')
                             for m in logs()), timeout=10, what='the reset on /rosout')
    # The node logs the call after answering it.
    ros.wait_for(lambda: 'client 1: called /simulator/reset: {"success": true' in live.output(),
                 timeout=10, what="the node's log of the call")


def test_a_stock_foxglove_client_gets_the_arms_fixed_joints_on_tf_static(ros, launch,
                                                                          js_client):
    """``FoxgloveClient`` sees /tf_static advertised as a ROS channel (``cdr``,
    ``tf2_msgs/msg/TFMessage``), subscribes after the node sent it and still gets it
    (latched): link2 -> tool0 at (l2, 0, 0) m of config/arm.yaml's arm, stamped 0."""
    import math

    import yaml
    from tf2_msgs.msg import TFMessage

    robot = yaml.safe_load(CONFIG.read_text())['/**']['ros__parameters']
    l2 = float(robot['link_lengths'][1])
    live = launch('live', params_file=CONFIG, params={'port': 0})
    url = ros.wait_for(lambda: re.search(r'serving (ws://\S+)', live.output()), timeout=30,
                       what='the live node to serve').group(1)
    client = JsClient(js_client, url)
    try:
        def channel() -> dict | None:
            return next((c for e in client.of('advertise') for c in e['channels']
                         if c['topic'] == '/tf_static'), None)

        ros.wait_for(lambda: channel() or client.proc.poll() is not None, timeout=20,
                     what='the /tf_static channel')
        ch = channel()
        assert ch is not None, (client.events, client.stderr())
        assert (ch['encoding'], ch['schemaEncoding'], ch['schemaName']) == (
            'cdr', 'ros2msg', 'tf2_msgs/msg/TFMessage')
        client.send(cmd='subscribe', topic='/tf_static')

        def static() -> list[TFMessage]:
            return [deserialize_message(base64.b64decode(e['data']), TFMessage)
                    for e in client.of('message') if e['topic'] == '/tf_static']

        ros.wait_for(static, timeout=10, what='the latched /tf_static message')
        (t,) = static()[-1].transforms
        assert (t.header.frame_id, t.child_frame_id) == ('link2', 'tool0')
        assert (t.header.stamp.sec, t.header.stamp.nanosec) == (0, 0)
        tr, rot = t.transform.translation, t.transform.rotation
        assert math.dist((tr.x, tr.y, tr.z), (l2, 0.0, 0.0)) < 1e-12
        assert math.dist((rot.x, rot.y, rot.z, rot.w), (0.0, 0.0, 0.0, 1.0)) < 1e-12
    finally:
        client.close()
    assert live.alive(), live.output()[-3000:]
