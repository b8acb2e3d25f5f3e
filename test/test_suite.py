"""The suite end to end: simulator + controller + planner as real processes (lockstep)."""

from __future__ import annotations

import pathlib
import subprocess
import sys

import numpy as np
import pytest
from conftest import NewRun, count, events, statuses, values
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from arm_bag.reader import read_bag
from arm_dynamics import TwoLinkArm
from arm_sim.client import stamp_of as stamp
from arm_sim.launcher import config_file, node_env

ARM = TwoLinkArm()
Q0 = np.array([-0.4, 1.2])
PS = ARM.forward_kinematics(Q0)
PF = np.array([0.5, 1.2])
CONFIG = config_file()


def goal(x: float, y: float) -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id = 'base_link'
    msg.pose.position.x, msg.pose.position.y = float(x), float(y)
    return msg


def start_suite(launch, ns: str | None = None, sim: dict | None = None):
    # No /clock remap: the nodes resolve it in their namespace themselves.
    for name, params in (('simulator', {'timing_mode': 'lockstep', **(sim or {})}),
                         ('controller', {}), ('planner', {})):
        launch(name, params_file=CONFIG, params=params, namespace=ns)


def connect(ros, prefix: str = ''):
    """Wait until the loop runs and the planner holds a joint state (its /diagnostics
    summary leaves 'waiting for joint_states')."""
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    planner = f'/{prefix}planner'.replace('//', '/')
    states = ros.collect(JointState, f'{prefix}joint_states', qos=1000)
    trajs = ros.collect(JointTrajectory, f'{prefix}arm_controller/joint_trajectory')
    goals = ros.publisher(PoseStamped, f'{prefix}goal_pose')
    ros.wait_for(lambda: states and stamp(states[-1]) > 0.1, timeout=30,
                 what=f'the {prefix or "/"} loop to run')
    ros.wait_for(lambda: any(s.message.startswith(('ready', 'last'))
                             for s in statuses(diags, planner, 'summary')),
                 what=f'{planner} ready')
    ros.wait_matched(goals, [planner])
    ros.wait_for(lambda: ros.node.count_publishers(
        f'{prefix}arm_controller/joint_trajectory') > 0, what='the planner')
    return states, trajs, goals


def move(ros, states, trajs, goals, target, settle: float = 1.0):
    """Send a goal, wait for its plan and for the motion plus ``settle`` s; returns the
    plan and the states from the plan's arrival on."""
    n = len(trajs)
    goals.publish(goal(*target))
    ros.wait_for(lambda: len(trajs) > n, what='a plan')
    t0 = stamp(trajs[-1]) or stamp(states[-1])  # the plan starts at its stamp
    end = trajs[-1].points[-1].time_from_start
    duration = end.sec + end.nanosec * 1e-9
    k = len(states)
    ros.wait_for(lambda: stamp(states[-1]) >= t0 + duration + settle, timeout=60,
                 what='the motion to finish')
    return trajs[-1], states[k - 1:]


def tip(states) -> np.ndarray:
    return ARM.forward_kinematics(np.array([m.position for m in states]))


def test_a_regulation_goal_is_reached_within_a_millimetre(ros, launch):
    start_suite(launch)
    states, trajs, goals = connect(ros)
    _, run = move(ros, states, trajs, goals, PF)
    miss = np.hypot(*(tip(run)[-1] - PF))
    assert miss < 1e-3, f'tip {miss * 1e3:.3f} mm from the goal (bound 1 mm)'


def test_a_straight_line_under_computed_torque_stays_within_a_millimetre(ros, launch):
    start_suite(launch)
    states, trajs, goals = connect(ros)
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    # Duration from the shipped speed limits (0.5 m/s, 1 m/s^2, quintic): 5.3 s here.
    assert ros.set_params('/planner', mode='straight_line')[0].successful
    # Paused while the goal is planned and accepted: a lockstep simulator running on would
    # make the line start in the past by however long planning took (timing, not control).
    pause = ros.pause_simulator_now(diags)
    ros.wait_for(lambda: stamp(states[-1]) >= pause - 1e-9, what='the paused state')
    start = tip(states[-1:])[0]
    n, accepted = len(trajs), count(diags, 'controller', 'trajectory_accepted')
    goals.publish(goal(*PF))
    ros.wait_for(lambda: len(trajs) > n and
                 count(diags, 'controller', 'trajectory_accepted') > accepted,
                 what='the plan, accepted by the controller')
    end = trajs[-1].points[-1].time_from_start
    finish = pause + end.sec + end.nanosec * 1e-9 + 1.0
    k = len(states)
    assert ros.set_params('/simulator', pause_at=finish)[0].successful
    ros.wait_for(lambda: stamp(states[-1]) >= finish - 1e-9, timeout=60,
                 what='the motion to finish')
    p = tip(states[k - 1:])
    u = (PF - start) / np.linalg.norm(PF - start)
    deviation = np.abs((p[:, 0] - start[0]) * u[1] - (p[:, 1] - start[1]) * u[0]).max()
    print(f'straight line: max deviation {deviation * 1e3:.3f} mm')
    # Measured here: 0.5-0.6 mm (5.3 s line, shipped gains, 100 Hz control).
    assert deviation < 1e-3, f'tip left the line by {deviation * 1e3:.3f} mm (bound 1 mm)'
    assert np.hypot(*(p[-1] - PF)) < 1e-3


def test_a_line_goal_while_moving_fast_stops_first_then_keeps_the_same_bound(ros, launch):
    start_suite(launch)
    states, trajs, goals = connect(ros)
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    paths = ros.collect(Path, 'planner/path')
    # A fast joint move (the shipped config plans regulation synchronised), paused at its
    # middle, where the joints are fastest.
    assert ros.set_params('/planner', joint_max_velocity=4.0,
                          joint_max_acceleration=20.0)[0].successful
    pause = ros.pause_simulator_now(diags)
    n = len(trajs)

    def accepted() -> int:
        return count(diags, '/controller', 'trajectory_accepted')

    k = accepted()
    goals.publish(goal(-0.9, 1.2))
    ros.wait_for(lambda: len(trajs) > n, what='the fast move')
    # Time moves on only once the controller has the move (under load it can come late).
    ros.wait_for(lambda: accepted() > k, what='the controller to accept the fast move')
    end = trajs[-1].points[-1].time_from_start
    middle = pause + 0.5 * (end.sec + end.nanosec * 1e-9)
    assert ros.set_params('/simulator', pause_at=middle)[0].successful
    ros.wait_for(lambda: stamp(states[-1]) >= middle - 1e-9, what='the middle of the move')
    assert np.abs(states[-1].velocity).max() >= 2.0, 'moving at >= 2 rad/s'
    # The line goal comes while the arm moves that fast.
    # The stop decelerates at joint_max_acceleration, still 20 rad/s^2: a hard stop (0.29
    # s from 3.8 rad/s), then a hold while the tracking settles, then the line. (At the
    # shipped 3 rad/s^2 the shoulder would pass its limit: refused, rightly.)
    assert ros.set_params('/planner', mode='straight_line')[0].successful
    n, m, k = len(trajs), len(paths), accepted()
    goals.publish(goal(*PF))
    ros.wait_for(lambda: len(trajs) > n and len(paths) > m, what='the line plan')
    ros.wait_for(lambda: accepted() > k, what='the controller to accept the line')
    line = trajs[-1]
    assert np.abs(line.points[0].velocities).max() >= 2.0, 'planned from the velocity'
    path = paths[-1]
    line_start = path.poses[0].header.stamp.sec + path.poses[0].header.stamp.nanosec * 1e-9
    assert line_start > stamp(line), 'the line starts once the arm is at rest'
    a = np.array([path.poses[0].pose.position.x, path.poses[0].pose.position.y])
    assert ros.set_params('/simulator', pause_at=-1.0)[0].successful
    end = line.points[-1].time_from_start
    finish = stamp(line) + end.sec + end.nanosec * 1e-9 + 1.0
    ros.wait_for(lambda: stamp(states[-1]) >= finish, timeout=60, what='the line to finish')
    on_line = tip([m for m in states if stamp(m) >= line_start])
    u = (PF - a) / np.linalg.norm(PF - a)
    deviation = np.abs((on_line[:, 0] - a[0]) * u[1] - (on_line[:, 1] - a[1]) * u[0]).max()
    print(f'line after a stop from {np.abs(line.points[0].velocities).max():.2f} rad/s: '
          f'max deviation {deviation * 1e3:.3f} mm')
    assert deviation < 1e-3, f'tip left the line by {deviation * 1e3:.3f} mm (bound 1 mm)'
    assert np.hypot(*(on_line[-1] - PF)) < 1e-3


def test_two_arms_in_two_namespaces_do_not_interfere(ros, launch):
    start_suite(launch, ns='/arm1')
    start_suite(launch, ns='/arm2', sim={'initial_positions': [0.2, 0.9]})
    a1 = connect(ros, '/arm1/')
    a2 = connect(ros, '/arm2/')
    clocks = ros.collect(Clock, '/arm2/clock')
    ros.wait_for(lambda: clocks, what='/arm2/clock')
    _, run = move(ros, *a1, PF)
    assert np.hypot(*(tip(run)[-1] - PF)) < 1e-3, 'arm1 reached its goal'
    arm2 = np.array([m.position for m in a2[0]])
    assert np.abs(arm2 - [0.2, 0.9]).max() < 1e-9, 'arm2 stayed where it was held'
    assert not a2[1], 'arm2 got no plan'
    assert len(ros.node.get_publishers_info_by_topic('/clock')) == 0, 'no shared /clock'


def test_nodes_started_in_a_namespace_run_on_their_own_simulators_clock(ros, launch):
    # As a user would with ros2 run ... --ros-args -r __ns:=/arm3: no /clock remap given.
    start_suite(launch, ns='/arm3')
    connect(ros, '/arm3/')

    def subscribed(name: str) -> list[str]:
        try:
            return [t for t, _ in ros.node.get_subscriber_names_and_types_by_node(name,
                                                                                  '/arm3')]
        except Exception:  # rclpy's NodeNameNonExistentError: not seen yet
            return []

    def clock_subscribers():
        return {name for name in ('controller', 'planner') if '/arm3/clock' in subscribed(name)}

    ros.wait_for(lambda: clock_subscribers() == {'controller', 'planner'},
                 what='controller and planner to subscribe /arm3/clock')
    for name in ('controller', 'planner'):
        assert '/clock' not in subscribed(name), f'/arm3/{name} does not listen to /clock'
    clocks = ros.collect(Clock, '/arm3/clock')
    ros.wait_for(lambda: clocks and clocks[-1].clock.sec + clocks[-1].clock.nanosec > 0,
                 what='the simulated clock to run on /arm3/clock')


def run_cli(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    from conftest import DOMAIN_ID
    return subprocess.run([sys.executable, '-m', 'arm_sim.cli', *args, '--domain-id',
                           str(DOMAIN_ID)], capture_output=True, text=True, timeout=timeout,
                          env=node_env(DOMAIN_ID))


def test_arm_sim_goal_reports_reached_and_refused(ros, launch):
    start_suite(launch)
    connect(ros)
    done = run_cli('goal', str(PF[0]), str(PF[1]), '--mode', 'straight_line')
    assert done.returncode == 0, done.stderr
    last = done.stdout.splitlines()[-1]
    assert last.startswith('reached: tip at') and float(last.split(', ')[2].split()[0]) < 1.0
    refused = run_cli('goal', '3.0', '0.0')
    assert refused.returncode == 3, refused.stdout + refused.stderr
    lines = refused.stderr.strip().splitlines()
    assert len(lines) == 1 and 'refused' in lines[0] and 'reach' in lines[0], lines


@pytest.mark.parametrize('args, message', [
    (['goal', 'nan', '1'], 'goal must be finite'),
])
def test_arm_sim_goal_rejects_bad_arguments_in_one_line(args, message):
    out = run_cli(*args, timeout=30)
    assert out.returncode == 1 and out.stderr.count('\n') == 1 and message in out.stderr


@pytest.mark.parametrize('extra, stopped', [
    ([], 'simulator (0), controller (0), planner (0), recorder (0)'),
    (['--composed', '--no-record'], 'composed (0), planner (0)'),
])
def test_arm_sim_bringup_runs_the_suite_in_real_time_and_stops_it_cleanly(ros, tmp_path,
                                                                          extra, stopped):
    import signal

    from conftest import DOMAIN_ID
    states = ros.collect(JointState, 'joint_states', qos=1000)
    proc = subprocess.Popen([sys.executable, '-m', 'arm_sim.cli', 'bringup', '--out',
                             str(tmp_path / 'run'), '--domain-id', str(DOMAIN_ID), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=node_env(DOMAIN_ID))
    try:
        # Real time (the shipped default): the simulator holds the start until the
        # controller's first command, then the controller holds the arm there.
        ros.wait_for(lambda: states and stamp(states[-1]) > 0.5, timeout=30,
                     what='simulated time to run under the controller')
        q = np.array([m.position for m in states])
        assert np.abs(q - Q0).max() < 1e-6, 'the arm never dropped'
        if '--composed' in extra:
            done = run_cli('goal', str(PF[0]), str(PF[1]), timeout=60)
            assert done.returncode == 0, done.stdout + done.stderr
            assert done.stdout.splitlines()[-1].startswith('reached: tip at')
    finally:
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, out
    assert f'stopped: {stopped}' in out
    if '--no-record' not in extra:
        bag = read_bag(tmp_path / 'run' / 'bag')
        assert bag.warnings == [], 'closed cleanly, nothing lost'
        stamps = np.unique(bag.joint_states.stamp)
        seen = {int(stamp(m) * 1e9 + 0.5) for m in states}
        if '--composed' not in extra:  # composed: the loop runs before the recorder matches
            assert stamps[0] == 0, 'from the first state on'
        assert seen <= set(stamps.tolist()), 'every state this test saw is in the bag'
        assert '/clock' in bag.topics


def test_a_goal_sent_right_after_a_controller_restart_is_executed(ros, launch):
    """The first send may reach no live controller (the new one is not matched yet, the old
    one still counts) or reach it before its first joint state: the planner sends again,
    planned from the latest state, until the controller confirms; the controller keeps an
    early trajectory until its first state. So the goal is executed, never lost."""
    start_suite(launch)
    states, trajs, goals = connect(ros)
    diags = ros.collect(DiagnosticArray, '/diagnostics')

    def planner_events(kinds, since):
        return [v for s in statuses(diags[since:], '/planner') for v in [values(s)]
                if v.get('event', '').startswith(kinds)]

    for k, target in enumerate((PF, PS, PF)):
        old = [p for p in launch.procs if p.name == 'controller' and p.alive()][0]
        assert old.stop() == 0
        stamp_then = stamp(states[-1])  # lockstep: time stands still until it answers
        launch('controller', params_file=CONFIG)
        n = len(diags)
        goals.publish(goal(*target))  # at once: the new controller may not be matched yet
        outcome = ros.wait_for(lambda: planner_events(('plan_accepted', 'goal_'), n),
                               timeout=30, what=f'goal {k} accepted or refused')[0]
        if outcome['event'] == 'goal_unsent' and stamp(states[-1]) == stamp_then:
            # 10 sends over 10 s reached no controller, and time never moved: the new
            # controller never heard the simulator either (it answers every state).
            pytest.xfail('Fast DDS left the restarted controller deaf to its peers '
                         '(eProsima/Fast-DDS#5053; docs/limitations.md)')
        assert outcome['event'] == 'plan_accepted', outcome
        start = float(outcome['start_time'])
        end = trajs[-1].points[-1].time_from_start
        run_until = start + end.sec + end.nanosec * 1e-9 + 1.0
        ros.wait_for(lambda: stamp(states[-1]) >= run_until, timeout=60,
                     what='the motion to finish')
        reached = ARM.forward_kinematics(np.array(states[-1].position))
        assert np.hypot(*(reached - target)) < 1e-3, f'goal {k} reached'


def test_a_motion_cut_by_a_simulator_restart_is_planned_again_and_finished(ros, launch):
    import signal
    start_suite(launch)
    states, trajs, goals = connect(ros)
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    verdicts = ros.collect(DiagnosticStatus, 'arm_controller/trajectory_status')

    def planner_event(kind):
        return [values(s) for s in events(diags, '/planner', kind)]

    pause = ros.pause_simulator_now(diags)
    goals.publish(goal(*PF))
    ros.wait_for(lambda: planner_event('plan_accepted'), what='the plan accepted')
    assert ros.set_params('/simulator', pause_at=pause + 0.6)[0].successful
    ros.wait_for(lambda: stamp(states[-1]) >= pause + 0.6 - 1e-9, what='half the motion')
    assert np.abs(np.array(states[-1].velocity)).max() > 0.3, 'cut mid-motion'
    simulator = next(p for p in launch.procs if p.name == 'simulator')
    simulator.stop(signal.SIGKILL)
    k = len(states)
    launch('simulator', params_file=CONFIG, params={'timing_mode': 'lockstep'})
    try:
        replanned = ros.wait_for(lambda: planner_event('replanned'), timeout=30,
                                 what='the planner to plan the goal again')[0]
    except pytest.fail.Exception as exc:  # what did the controller say, and the planner?
        said = [(s.message, {kv.key: kv.value for kv in s.values}) for s in verdicts]
        planner = [(s.message, values(s)) for s in statuses(diags, '/planner')][-6:]
        pytest.fail(f'{exc}; trajectory_status seen here: {said}; planner: {planner}')
    assert float(replanned['goal_x']) == PF[0] and float(replanned['goal_y']) == PF[1]

    new_run = NewRun(states, k)

    def reached():
        run = new_run()
        return run and np.hypot(*(tip(run)[-1] - PF)) < 1e-3 and (
            np.abs(run[-1].velocity).max() < 1e-3)

    try:
        ros.wait_after_restart(reached, new_run.stuck, 'simulator', timeout=60,
                               what='the new arm to reach the goal')
    except pytest.xfail.Exception:
        raise
    except pytest.fail.Exception:
        run = new_run() or []
        summary = [f'{s.message} {[(kv.key, kv.value) for kv in s.values]}'
                   for s in statuses(diags[-20:], '/simulator', 'summary')]
        pytest.fail(f'the new arm did not reach the goal: {len(run)} new states, the last '
                    f'at t={stamp(run[-1]) if run else None} s, tip '
                    f'{tip(run[-1:]).tolist() if run else None}; last states '
                    f'{[stamp(m) for m in states[-5:]]}; simulator: {summary[-1:]}')


def node_children(pid: int) -> list[int]:
    """PIDs of the processes whose parent is ``pid``."""
    found = []
    for proc in pathlib.Path('/proc').iterdir():
        try:
            if proc.name.isdigit() and int(
                    (proc / 'stat').read_text().rsplit(')', 1)[1].split()[1]) == pid:
                found.append(int(proc.name))
        except (OSError, IndexError, ValueError):
            continue
    return found


def running(pid: int) -> bool:
    """The process exists and is not a zombie (a zombie has exited)."""
    try:
        return pathlib.Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0] != 'Z'
    except (OSError, IndexError):
        return False


def test_a_killed_bringup_takes_its_nodes_with_it_and_its_bag_is_closed(ros, tmp_path):
    import signal

    from conftest import DOMAIN_ID
    states = ros.collect(JointState, 'joint_states', qos=1000)
    proc = subprocess.Popen([sys.executable, '-m', 'arm_sim.cli', 'bringup', '--out',
                             str(tmp_path / 'run'), '--domain-id', str(DOMAIN_ID)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT,
                            env=node_env(DOMAIN_ID))
    try:
        ros.wait_for(lambda: states and stamp(states[-1]) > 0.2, timeout=30,
                     what='the suite to run')
        nodes = node_children(proc.pid)
        assert len(nodes) == 5, nodes  # simulator, controller, planner, recorder, visualizer
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    # Each node gets SIGTERM from the kernel when its parent dies, and stops cleanly.
    ros.wait_for(lambda: not any(running(p) for p in nodes), timeout=30,
                 what='every node of the killed bringup to exit')
    meta = (tmp_path / 'run' / 'bag' / 'metadata.yaml').read_text()
    assert 'arm_sim.recording: closed' in meta, 'the recorder closed its bag on SIGTERM'
    bag = read_bag(tmp_path / 'run' / 'bag')
    assert bag.warnings == [] and len(bag.joint_states) > 20
