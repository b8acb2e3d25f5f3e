"""Topic-level tests of "real time that never changes the physics": goals that start at the
state they were planned from, untagged (timer-driven) controllers, and a loaded real-time
suite that never runs away (real node processes on a private domain)."""

from __future__ import annotations

import random
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import count, statuses, values
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from test_controller_node import duration
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from arm_control.trajectory import Trajectory, TrajectoryPoint, validate_trajectory
from arm_dynamics import TwoLinkArm
from arm_sim.client import stamp_of as stamp
from arm_sim.launcher import config_file

ARM = TwoLinkArm()
CONFIG = config_file()
Q0 = np.array([-0.4, 1.2])
PS = ARM.forward_kinematics(Q0)
PF = np.array([0.5, 1.2])
JOINTS = ['joint1', 'joint2']
BUSY = 'while True: pass'
PERIOD = 0.01


def goal(x: float, y: float) -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id = 'base_link'
    msg.pose.position.x, msg.pose.position.y = float(x), float(y)
    return msg


def ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def suite(launch, ros, mode: str, sim: dict | None = None):
    for name, params in (('simulator', {'timing_mode': mode, **(sim or {})}),
                         ('controller', {}), ('planner', {})):
        launch(name, params_file=CONFIG, params=params)
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    states = ros.collect(JointState, 'joint_states', qos=10000)
    refs = ros.collect(JointState, 'arm_controller/reference', qos=10000)
    trajs = ros.collect(JointTrajectory, 'arm_controller/joint_trajectory')
    goals = ros.publisher(PoseStamped, 'goal_pose')
    ros.wait_for(lambda: states and stamp(states[-1]) > 0.1, timeout=30, what='the loop')
    # Every reference from here on reaches us: the subscription has matched.
    ros.wait_for(lambda: refs, timeout=30, what="the controller's references")
    ros.wait_for(lambda: any(s.message.startswith(('ready', 'last'))
                             for s in statuses(diags, '/planner', 'summary')),
                 what='the planner ready')
    ros.wait_matched(goals, ['planner'])
    return diags, states, refs, trajs, goals


def runaways(diags) -> list[str]:
    return [s.message for kind in ('runaway', 'diverged')
            for s in statuses(diags, '/simulator', kind)]


def accepted(diags) -> int:
    return sum(1 for s in statuses(diags, '/controller', 'trajectory_accepted')
               if values(s).get('event') == 'trajectory_accepted')


@pytest.mark.parametrize('mode', ['lockstep', 'real_time'])
def test_goals_sent_at_random_moments_start_at_the_state_they_were_planned_from(
        ros, launch, mode):
    """Five goals at random wall moments to a free-running suite: the planner holds time
    while it plans, so each trajectory starts at the state it was planned from and the
    controller follows it from its first control period, bit for bit (before the hold the
    plan reached the controller 0.07-0.52 s of simulated time after its start)."""
    diags, states, refs, trajs, goals = suite(launch, ros, mode)
    rng = random.Random(21)
    targets = [PF, PS, PF, PS, PF]
    for k, target in enumerate(targets):
        if k % 2:
            assert ros.set_params('/planner', mode='straight_line', duration=1.0)[0].successful
        else:
            assert ros.set_params('/planner', mode='regulation', duration=0.0)[0].successful
        end = time.monotonic() + rng.uniform(0.0, 0.6)  # a random wall moment
        ros.wait_for(lambda e=end: time.monotonic() >= e, what='the random moment')
        n = len(trajs)
        goals.publish(goal(*target))
        ros.wait_for(lambda n=n: len(trajs) > n, what=f'plan {k}')
        traj = trajs[-1]
        start = ns(traj)
        span = traj.points[-1].time_from_start
        finish = start + span.sec * 1_000_000_000 + span.nanosec + 1_000_000_000
        ros.wait_for(lambda f=finish: ns(states[-1]) >= f and ns(refs[-1]) >= f, timeout=60,
                     what=f'motion {k} to finish')
        by_stamp = {ns(m): m for m in states}
        refs_at = {ns(r): r for r in refs}
        held = by_stamp[start]  # the simulator published the state it was planned from
        q, qd = np.array(held.position), np.array(held.velocity)
        points = [TrajectoryPoint(p.time_from_start.sec + p.time_from_start.nanosec * 1e-9,
                                  p.positions, p.velocities, p.accelerations)
                  for p in traj.points]
        times, pos, vel, acc = validate_trajectory(traj.joint_names, points, JOINTS)
        plan = Trajectory(q, qd, times, pos, vel, acc)
        t0 = stamp(traj)
        checked = 0
        for t_ns in range(start + 10_000_000, finish, 10_000_000):
            ref = refs_at[t_ns]
            want = plan.sample(stamp(ref) - t0)
            assert np.array_equal(ref.position, want[0]) and np.array_equal(
                ref.velocity, want[1]), (f'goal {k}: the reference at t = {t_ns} ns is not '
                                         'the plan sampled there')
            checked += 1
        assert checked >= 100
        tip = ARM.forward_kinematics(np.array(states[-1].position))
        assert np.hypot(*(tip - target)) < 1e-3, f'goal {k} reached within 1 mm'
    assert not runaways(diags)


def test_a_timer_driven_untagged_controller_drives_the_real_time_simulator(ros, launch):
    """A plain Float64MultiArray publisher on a wall-clock timer, written here (PD plus
    gravity on the latest state, no tag): each command answers the state published last,
    so simulated time advances at most one period per command and never ahead of the wall
    clock; the arm reaches the set point."""
    launch('simulator', params_file=CONFIG, params={'timing_mode': 'real_time'})
    states = ros.collect(JointState, 'joint_states', qos=1000)
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: states, what='the first state')
    target = np.array([0.2, 0.9])
    kp, kd = np.array([400.0, 150.0]), np.array([60.0, 20.0])
    sent = []

    def control() -> None:
        m = states[-1]
        q, qd = np.array(m.position), np.array(m.velocity)
        tau = kp * (target - q) - kd * qd + ARM.gravity_vector(q)
        pub.publish(Float64MultiArray(data=tau.tolist()))
        sent.append(time.monotonic())

    timer = ros.node.create_timer(1.0 / 150.0, control)  # wall clock, faster than 100 Hz
    try:
        first = time.monotonic()
        ros.wait_for(lambda: stamp(states[-1]) >= 3.0, timeout=60, what='3 s simulated')
        wall = time.monotonic() - first
    finally:
        ros.node.destroy_timer(timer)
    assert stamp(states[-1]) <= wall + 0.05, 'never ahead of the wall clock'
    stamps = sorted({ns(m) for m in states})
    assert len(stamps) - 1 <= len(sent), 'at most one period per command'
    assert np.abs(np.array(states[-1].position) - target).max() < 2e-3, 'set point reached'
    assert not runaways(diags)


def test_a_loaded_fast_real_time_suite_survives_goals_while_moving_and_a_huge_trajectory(
        ros, launch):
    """real_time_factor 20 under two busy loops (the loop cannot keep up: time waits), a
    goal while moving fast, and a valid 100,000-point trajectory that stalls the controller
    for a while: no runaway, every goal reached."""
    burners = [subprocess.Popen([sys.executable, '-c', BUSY]) for _ in range(2)]
    try:
        diags, states, refs, trajs, goals = suite(launch, ros, 'real_time',
                                                  {'real_time_factor': 20.0})
        assert ros.set_params('/planner', mode='straight_line', duration=0.8)[0].successful
        n = len(trajs)
        goals.publish(goal(*PF))
        ros.wait_for(lambda: len(trajs) > n, what='the fast line')
        start = stamp(trajs[-1])
        ros.wait_for(lambda: stamp(states[-1]) >= start + 0.4, timeout=60,
                     what='halfway along the line')
        assert max(np.abs(m.velocity).max() for m in states if stamp(m) >= start) > 0.5, (
            'moving fast when the next goal comes')
        n = len(trajs)
        goals.publish(goal(*PS))  # a goal while moving: stop, then the new line
        ros.wait_for(lambda: len(trajs) > n, what='the plan while moving')
        span = trajs[-1].points[-1].time_from_start
        finish = stamp(trajs[-1]) + span.sec + span.nanosec * 1e-9 + 1.0
        ros.wait_for(lambda: stamp(states[-1]) >= finish, timeout=120, what='the second line')
        tip = ARM.forward_kinematics(np.array(states[-1].position))
        assert np.hypot(*(tip - PS)) < 1e-3, 'the goal given while moving is reached'
        # A valid 100,000-point trajectory (10 s at 0.1 ms) back to Q0's neighbour.
        q_now = np.array(states[-1].position)
        q_end = q_now + np.array([0.3, -0.2])
        big = JointTrajectory(joint_names=JOINTS)
        s = np.linspace(0.0, 1.0, 100_001)[1:]
        blend = s ** 3 * (10 - 15 * s + 6 * s ** 2)
        for k, b in enumerate(blend, start=1):
            t = k * 1e-4
            big.points.append(JointTrajectoryPoint(
                positions=(q_now + b * (q_end - q_now)).tolist(), time_from_start=duration(t)))
        before = accepted(diags)
        ros.publisher(JointTrajectory, 'arm_controller/joint_trajectory').publish(big)
        ros.wait_for(lambda: accepted(diags) > before, timeout=60,
                     what='the 100,000-point trajectory accepted')
        event = [values(s) for s in statuses(diags, '/controller', 'trajectory_accepted')
                 if values(s).get('points') == '100000']
        assert event, 'accepted: the 100,000-point trajectory'
        t_start = float(event[-1]['start_time'])
        ros.wait_for(lambda: stamp(states[-1]) >= t_start + 11.0, timeout=120,
                     what='the big trajectory to finish')
        assert np.abs(np.array(states[-1].position) - q_end).max() < 1e-3, 'followed to its end'
        assert not runaways(diags), runaways(diags)
    finally:
        for b in burners:
            b.kill()
            b.wait()



def bringup_run(ros, tmp_path, mode: str) -> tuple:
    """``arm-sim bringup --timing-mode MODE`` with a params file that pauses the simulator
    at t = 3 s; there a goal is sent (the planner plans from that state), then time runs to
    6 s; returns the bag's distinct joint states (stamps, positions, velocities, efforts)."""
    import signal

    import yaml
    from conftest import DOMAIN_ID

    from arm_bag.reader import read_bag
    from arm_sim.launcher import node_env
    params = yaml.safe_load(CONFIG.read_text())
    params.setdefault('/**/simulator', {}).setdefault('ros__parameters', {})['pause_at'] = 3.0
    params_file = tmp_path / f'{mode}.yaml'
    params_file.write_text(yaml.safe_dump(params))
    diags = ros.collect(DiagnosticArray, '/diagnostics')

    def paused_at(t: float) -> bool:
        return any(values(s).get('paused_at') and abs(float(values(s)['paused_at']) - t) < 1e-9
                   for s in statuses(diags, '/simulator', 'summary'))

    out = tmp_path / mode
    proc = subprocess.Popen([sys.executable, '-m', 'arm_sim.cli', 'bringup', '--out', str(out),
                             '--domain-id', str(DOMAIN_ID), '--timing-mode', mode,
                             '--params-file', str(params_file)], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=node_env(DOMAIN_ID))
    try:
        ros.wait_for(lambda: paused_at(3.0), timeout=90, what='the pause at t = 3 s')
        ros.wait_for(lambda: any(s.message.startswith(('ready', 'last'))
                                 for s in statuses(diags, '/planner', 'summary')),
                     what='the planner ready')
        goals = ros.publisher(PoseStamped, 'goal_pose')
        ros.wait_matched(goals, ['planner'])
        # Counted from the controller's periodic reports too: its one immediate report of
        # the acceptance can go out before we are matched with a controller started last.
        before = count(diags, '/controller', 'trajectory_accepted')
        goals.publish(goal(*PF))
        ros.wait_for(lambda: count(diags, '/controller', 'trajectory_accepted') > before,
                     timeout=30, what='the plan accepted')
        assert ros.set_params('/simulator', pause_at=6.0)[0].successful
        ros.wait_for(lambda: paused_at(6.0), timeout=90, what='the pause at t = 6 s')
    except pytest.fail.Exception as exc:  # say what the nodes said
        logs = '\n'.join(f'--- {f.name}\n' + f.read_text()[-3000:]
                         for f in sorted((out / 'logs').glob('*.log')))
        pytest.fail(f'{exc}\n{logs}')
    finally:
        proc.send_signal(signal.SIGTERM)
        text, _ = proc.communicate(timeout=60)
        ros.reset()
    assert proc.returncode == 0, text
    assert f'timing: {mode}' in text, 'bringup prints how time was paced'
    js = read_bag(out / 'bag').joint_states
    stamps, first = np.unique(js.stamp, return_index=True)
    return stamps, js.position[first], js.velocity[first], js.effort[first]


def test_bringup_in_real_time_records_lockstep_states_bit_for_bit(ros, tmp_path):
    """The same scenario through ``arm-sim bringup`` in lockstep and in real time (with
    two busy loops): the bags hold the same joint states, every one from 0 to 6 s, bit for
    bit."""
    lockstep = bringup_run(ros, tmp_path, 'lockstep')
    burners = [subprocess.Popen([sys.executable, '-c', BUSY]) for _ in range(2)]
    try:
        real_time = bringup_run(ros, tmp_path, 'real_time')
    finally:
        for b in burners:
            b.kill()
            b.wait()
    assert lockstep[0][0] == 0 and lockstep[0][-1] == 6_000_000_000
    assert (np.diff(lockstep[0]) == 10_000_000).all(), 'every state from the first'
    for name, x, y in zip(('stamps', 'positions', 'velocities', 'efforts'), lockstep,
                          real_time):
        assert np.array_equal(x, y), f'real_time {name} differ from lockstep'
    k3 = int(np.searchsorted(lockstep[0], 3_000_000_000))
    assert np.abs(lockstep[1][-1] - lockstep[1][k3]).max() > 0.1, 'the goal moved the arm'
