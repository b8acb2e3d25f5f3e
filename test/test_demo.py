"""The demo end to end: four node processes, the lecture's tasks, a bag and a picture; and
the time model's promise: the same run records the same joint states under CPU load and
with the controller stalled mid-task."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import domain_held_elsewhere, statuses, values
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState

from arm_bag.analysis import analyze
from arm_bag.reader import read_bag
from arm_sim.client import stamp_of
from arm_sim.demo import start_pose
from arm_sim.launcher import config_file, node_env

BUSY = 'while True: pass'


def demo_command(out: Path, domain: int, mode: str = 'lockstep') -> list[str]:
    return [sys.executable, '-m', 'arm_sim.cli', 'demo', '--out', str(out), '--domain-id',
            str(domain), '--timing-mode', mode]


def run_demo(out: Path, domain: int) -> subprocess.CompletedProcess:
    return subprocess.run(demo_command(out, domain), capture_output=True, text=True,
                          timeout=300, env=node_env(domain))


def children(pid: int, name: str) -> list[int]:
    """PIDs of ``pid``'s child processes whose command line names ``name``."""
    found = []
    for proc in Path('/proc').iterdir():
        if not proc.name.isdigit():
            continue
        try:
            ppid = int((proc / 'stat').read_text().rsplit(')', 1)[1].split()[1])
            argv = (proc / 'cmdline').read_bytes().split(b'\0')
        except (OSError, IndexError, ValueError):
            continue
        if ppid == pid and any(Path(a.decode(errors='replace')).name == name
                               or a.decode(errors='replace').endswith(f'{name}_node')
                               for a in argv[:3]):
            found.append(int(proc.name))
    return found


def run_demo_with_stalled_controller(ros, out: Path, domain: int, at: float = 3.0,
                                     stall: float = 2.0, mode: str = 'lockstep'):
    """The demo, with its controller SIGSTOPped once simulated time passes ``at`` s (in
    the slow line) until the simulator has reported waiting ``stall`` s for it, then
    SIGCONT."""
    states = ros.collect(JointState, 'joint_states', qos=1000)
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    proc = subprocess.Popen(demo_command(out, domain, mode), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=node_env(domain))
    try:
        ros.wait_for(lambda: states and stamp_of(states[-1]) >= at, timeout=120,
                     what=f'the demo to reach t = {at} s')
        controller = ros.wait_for(lambda: children(proc.pid, 'controller'),
                                  what='the controller process')[0]
        os.kill(controller, signal.SIGSTOP)
        try:
            def waited() -> float:
                return max((float(values(s)['waited_wall']) for s in
                            statuses(diags, '/simulator', 'waiting_for_command')), default=0.0)
            ros.wait_for(lambda: waited() >= stall, timeout=30,
                         what=f'the simulator to report waiting {stall} s for the controller')
            t_stall = stamp_of(states[-1])
        finally:
            os.kill(controller, signal.SIGCONT)
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        ros.reset()
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr), t_stall


@pytest.fixture(scope='module')
def demo_runs(tmp_path_factory, ros_session):
    """The demo four times: alone, with two busy loops loading both cores, with the
    controller stalled for about 2 s in the middle of a task, and in real_time with two busy
    loops and the controller stalled for 1.5 s."""
    from conftest import DOMAIN_ID
    base = tmp_path_factory.mktemp('demo')
    runs = {'quiet': (base / 'quiet', run_demo(base / 'quiet', DOMAIN_ID))}
    burners = [subprocess.Popen([sys.executable, '-c', BUSY]) for _ in range(2)]
    try:
        runs['loaded'] = (base / 'loaded', run_demo(base / 'loaded', DOMAIN_ID))
    finally:
        for b in burners:
            b.kill()
            b.wait()
    res, t_stall = run_demo_with_stalled_controller(ros_session, base / 'stalled', DOMAIN_ID)
    runs['stalled'] = (base / 'stalled', res)
    runs['stalled_at'] = t_stall
    burners = [subprocess.Popen([sys.executable, '-c', BUSY]) for _ in range(2)]
    try:
        res, _ = run_demo_with_stalled_controller(ros_session, base / 'real_time', DOMAIN_ID,
                                                  stall=1.5, mode='real_time')
    finally:
        for b in burners:
            b.kill()
            b.wait()
    runs['real_time'] = (base / 'real_time', res)
    for label, (out, res) in ((k, v) for k, v in runs.items() if k != 'stalled_at'):
        assert res.returncode == 0, (f'{label}: {out}: {res.stdout[-2000:]}\n'
                                     f'{res.stderr[-2000:]}')
    return runs


def test_demo_runs_the_tasks_and_answers_the_lectures_questions(demo_runs):
    out, res = demo_runs['quiet']
    assert 'straight line Pf -> Ps, fast (0.8 s, plain PD)' in res.stdout
    assert (out / 'report.png').stat().st_size > 20_000, 'a real picture'
    report = analyze(out / 'bag').to_dict()
    segs = report['segments']
    assert [s['mode'] for s in segs] == ['regulation', 'straight_line', 'regulation',
                                        'straight_line', 'regulation', 'straight_line']
    limits = np.array(report['effort_limits'])
    for s in segs:
        assert (np.array(s['torque_peak']) <= limits + 1e-9).all(), 'torque within limits'
    reg, slow, fast_ct, fast_pd = segs[0], segs[1], segs[3], segs[5]
    # Bounds (measured: settle 1.15 s, final 2e-6 rad; lines 0.57 / 3.49 / 118.6 mm from
    # the commanded segment, of which past its end 0.002 / 3.41 / 99.7 mm).
    assert reg['settling_time_overall'] < 2.0
    assert np.abs(reg['final_error']).max() < 1e-4, 'regulation holds the goal'
    assert slow['deviation_max'] < 1e-3, 'slow line under computed torque: < 1 mm'
    assert slow['line_overshoot_end'] < 1e-4, 'and stops at its end'
    assert fast_ct['deviation_max'] < 5e-3, 'fast line under computed torque: < 5 mm'
    assert fast_ct['line_overshoot_end'] < 5e-3, 'overshooting its end by < 5 mm'
    assert fast_pd['deviation_max'] > 10 * fast_ct['deviation_max'], (
        'plain PD leaves the line far more than computed torque at the same speed')
    assert fast_pd['line_overshoot_end'] > 10 * fast_ct['line_overshoot_end'], (
        'and overshoots its end far more')
    assert np.abs(fast_pd['final_error']).max() > 1e-2, 'and keeps a gravity error'
    assert max(fast_ct['torque_peak']) > max(slow['torque_peak']), 'faster needs more torque'
    assert 'warning:' not in res.stdout, 'an undisturbed run has nothing to warn about'


def recorded_states(out: Path) -> tuple[np.ndarray, ...]:
    """Stamps and (position, velocity, effort) of every distinct recorded state (a state
    re-sent while the simulator waited repeats its stamp and values: counted once)."""
    js = read_bag(out / 'bag').joint_states
    stamps, first = np.unique(js.stamp, return_index=True)
    return stamps, js.position[first], js.velocity[first], js.effort[first]


@pytest.mark.parametrize('label', ['quiet', 'loaded', 'stalled', 'real_time'])
def test_the_demo_bag_holds_every_state_from_the_first_to_the_last(demo_runs, label):
    out = demo_runs[label][0]
    stamps = recorded_states(out)[0]
    assert stamps[0] == 0, 'from the first state'
    assert (np.diff(stamps) == 10_000_000).all(), 'every 10 ms state, none missing'
    bag = read_bag(out / 'bag')
    assert bag.lost == {} and bag.warnings == [], 'nothing lost, closed cleanly'
    assert {'/clock', '/joint_states', '/effort_controller/commands',
            '/arm_controller/reference', '/planner/path'} <= set(bag.topics)


@pytest.mark.parametrize('label', ['loaded', 'stalled', 'real_time'])
def test_demo_records_bit_identical_joint_states_under_load_and_a_stalled_controller(
        demo_runs, label):
    quiet = recorded_states(demo_runs['quiet'][0])
    other = recorded_states(demo_runs[label][0])
    assert len(quiet[0]) > 1000
    assert len(other[0]) == len(quiet[0]), 'same number of states'
    for name, x, y in zip(('stamps', 'positions', 'velocities', 'efforts'), quiet, other):
        assert np.array_equal(x, y), f'{label}: {name} differ from the undisturbed run'


def test_real_time_demo_reports_its_pace_and_the_wait_for_the_stalled_controller(demo_runs):
    """Real time under two busy loops with the controller SIGSTOPped 1.5 s: the wait is
    reported (on /diagnostics, so in the demo's warnings) and so is the pace reached,
    while the states equal lockstep's (test above)."""
    _, res = demo_runs['real_time']
    assert 'simulator reported waiting_for_command' in res.stdout, res.stdout[-3000:]
    line = next(x for x in res.stdout.splitlines() if x.startswith('timing: real_time'))
    factor = float(line.split('achieved ')[1].split('x')[0])
    assert 0.0 < factor <= 1.0 + 1e-3, f'never faster than the wall clock: {line}'


def test_a_stalled_controller_is_reported_in_the_demo_output(demo_runs):
    _, res = demo_runs['stalled']
    assert 1.0 < demo_runs['stalled_at'] < 16.0, 'the stall hit a task'
    lines = [line for line in res.stdout.splitlines() if line.startswith('warning:')]
    assert any('simulator reported waiting_for_command' in line for line in lines), (
        res.stdout[-3000:])
    quiet = analyze(demo_runs['quiet'][0] / 'bag').to_dict()['segments']
    stalled = analyze(demo_runs['stalled'][0] / 'bag').to_dict()['segments']
    assert stalled == quiet, 'the same table'


def decoded_with_own_schemas(bag: Path, topics: tuple[str, ...]) -> dict[str, list]:
    """The messages of ``topics`` in ``bag``, decoded by rosbags with the types the bag's
    own schemas define (an empty typestore: nothing else known), each also decodable with
    rosbags' Jazzy types."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    own, jazzy = get_typestore(Stores.EMPTY), get_typestore(Stores.ROS2_JAZZY)
    out: dict[str, list] = {t: [] for t in topics}
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic in topics]
        for conn in conns:
            own.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
        for conn, _, raw in reader.messages(connections=conns):
            jazzy.deserialize_cdr(raw, conn.msgtype)
            out[conn.topic].append(own.deserialize_cdr(raw, conn.msgtype))
    return out


def check_bag_markers(out: Path) -> int:
    """Every recorded MarkerArray is the forward kinematics (1e-9 m) of the recorded joint
    state of its stamp, its trail the tip over the 2 s of states before it, its path a
    recorded planner/path; robot_description is the URDF of the demo's parameters. Returns
    how many MarkerArrays were checked."""
    from arm_dynamics.urdf import urdf_from_params
    from arm_sim.demo import start_pose
    from arm_sim.launcher import config_file
    from arm_sim.urdf_cli import robot_params_from_file

    msgs = decoded_with_own_schemas(out / 'bag', ('/markers', '/robot_description',
                                                  '/joint_states', '/planner/path'))
    (description,) = msgs['/robot_description']
    assert description.data == urdf_from_params(robot_params_from_file(config_file()))
    arm = start_pose(config_file())[0]
    l1 = arm.link_lengths[0]
    states = {m.header.stamp.sec * 10**9 + m.header.stamp.nanosec: np.array(m.position)
              for m in msgs['/joint_states']}
    stamps = np.array(sorted(states))
    paths = [np.array([[p.pose.position.x, p.pose.position.y] for p in m.poses])
             for m in msgs['/planner/path']]
    arrays = msgs['/markers']
    assert len(arrays) >= 20, 'markers throughout the run'
    shown = {'goal': 0, 'path': 0}
    for array in arrays:
        m = {k.ns: k for k in array.markers}
        assert set(m) == {'links', 'joints', 'tip', 'trail', 'goal', 'path'}
        t = m['links'].header.stamp.sec * 10**9 + m['links'].header.stamp.nanosec
        assert all(k.header.frame_id == 'base_link' for k in array.markers)
        q = states[t]  # a recorded joint state has this very stamp
        tip = arm.forward_kinematics(q)
        elbow = l1 * np.array([np.cos(q[0]), np.sin(q[0])])

        def xy(marker) -> np.ndarray:
            return np.array([[p.x, p.y] for p in marker.points]).reshape(-1, 2)

        assert np.abs(xy(m['links']) - [[0.0, 0.0], elbow, elbow, tip]).max() < 1e-9
        assert np.abs(xy(m['joints']) - [[0.0, 0.0], elbow]).max() < 1e-9
        p = m['tip'].pose.position
        assert np.abs([p.x - tip[0], p.y - tip[1]]).max() < 1e-9
        window = stamps[(stamps >= t - 2_000_000_000) & (stamps <= t)]
        trail = xy(m['trail'])
        expected = arm.forward_kinematics(np.array([states[s] for s in window]))
        if len(window) < 2:  # the first state: no line yet
            assert m['trail'].action == 2 and not len(trail)  # DELETE
        else:
            assert trail.shape == expected.shape and np.abs(trail - expected).max() < 1e-9
        for ns in shown:
            shown[ns] += m[ns].action == 0  # ADD
        if m['path'].action == 0:
            assert any(len(pp) == len(xy(m['path'])) and np.abs(pp - xy(m['path'])).max()
                       < 1e-9 for pp in paths), 'a planned path'
    assert shown['goal'] and shown['path'], 'goals and paths shown'
    return len(arrays)


@pytest.mark.parametrize('label', ['quiet', 'loaded', 'stalled'])
def test_the_demo_bag_holds_markers_of_the_recorded_states_and_the_robot_description(
        demo_runs, label):
    assert check_bag_markers(demo_runs[label][0]) >= 20


def test_demo_energy_is_the_change_in_mechanical_energy_to_a_nanojoule(demo_runs):
    """config/arm.yaml has no damping: the work of the held torques over the run equals
    the change of kinetic plus potential energy (the integrator's error only), and the
    segments' energies add up to the run's (each period's work counted once)."""
    out, _ = demo_runs['quiet']
    report = analyze(out / 'bag').to_dict()
    stamps, q, qd, _ = recorded_states(out)
    arm = start_pose(config_file())[0]
    change = sum(arm.energy(q[-1], qd[-1])) - sum(arm.energy(q[0], qd[0]))
    assert abs(report['run']['energy'] - change) < 1e-9
    assert sum(s['energy'] for s in report['segments']) == pytest.approx(
        report['run']['energy'], abs=1e-9)


def test_a_demo_on_a_domain_another_run_holds_is_refused_in_one_line(tmp_path):
    """Two demos on one explicit --domain-id both failed with misleading reasons (timed
    out, too near a singularity): the second is refused at once, naming the first."""
    with domain_held_elsewhere(140) as (domain, other):
        res = subprocess.run(demo_command(tmp_path / 'out', domain), capture_output=True,
                             text=True, timeout=120, env=node_env(domain))
    assert res.returncode == 2, res.stdout + res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith(f'arm-sim demo: ROS domain {domain} is in use by another '
                               f'arm_sim run (pid {other.pid}: '), lines[0]
    assert not (tmp_path / 'out').exists(), 'nothing started'
