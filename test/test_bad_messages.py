"""No single message stops a node (issue 35, item 4): a ``/clock`` that is no valid time
(negative ``sec``, ``nanosec`` >= 1e9) is dropped by every node on simulated time, which
keeps its last good time, says so on /diagnostics (``rejected_clock``) and goes on; a
message a node's callback fails on is dropped and reported (``internal_error``). Both come
from one mechanism, ``arm_common.node.guard_messages``, which ``run_node`` applies to every
node. Real node processes on the test's private domain; the test's own node publishes the
bad messages and waits on evidence."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys

import numpy as np
from conftest import DOMAIN_ID, count, events, goal_msg, statuses, values
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

from arm_common.process import PARENT_ENV, stop_child
from arm_dynamics import TwoLinkArm
from arm_sim.client import stamp_of as stamp
from arm_sim.launcher import config_file, node_env

CONFIG = config_file()  # controller and planner on use_sim_time, as shipped
ARM = TwoLinkArm()
PERIOD = 0.01  # s, the control period of config/arm.yaml (publish_rate 100 Hz)
ON_SIM_TIME = ('/controller', '/planner', '/visualizer')


def bad_clock(sec: int, nanosec: int = 0) -> Clock:
    msg = Clock()
    msg.clock.sec, msg.clock.nanosec = sec, nanosec
    return msg


def refused(diags: list, node: str, text: str) -> list:
    """``node``'s rejected_clock statuses (immediate or periodic) whose message has
    ``text``."""
    return [s for s in statuses(diags, node, 'rejected_clock') if text in s.message]


def refuse_everywhere(ros, pub, msg: Clock, diags: list, text: str) -> dict[str, object]:
    """Publish ``msg`` until every node on simulated time has reported refusing it (the
    clock subscription is best effort, keep last 1: the simulator's own clock may replace
    one in a queue); returns each node's latest such status."""
    def seen() -> bool:
        return all(refused(diags, n, text) for n in ON_SIM_TIME)

    ros.wait_for(lambda: seen() or pub.publish(msg), timeout=20,
                 what=f'{", ".join(ON_SIM_TIME)} to refuse {text!r}')
    return {n: refused(diags, n, text)[-1] for n in ON_SIM_TIME}


def kept_time(status) -> float:
    """The time [s] a refusing node kept; a time the simulator published (a whole number
    of control periods, 1e-6 of a period), never the refused one."""
    v = values(status)
    kept = float(v['kept_time'])
    assert kept >= 0.0 and abs(kept / PERIOD - round(kept / PERIOD)) < 1e-6, v
    return kept


def test_a_bad_clock_is_dropped_and_every_node_keeps_its_time_and_goes_on(ros, launch):
    launch('simulator', params_file=CONFIG, params={'timing_mode': 'lockstep'})
    launch('controller', params_file=CONFIG)
    launch('planner', params_file=CONFIG)
    # On the wall clock at start: its clock subscription comes when use_sim_time is
    # switched on at run time (rclpy's TimeSource subscribes then), guarded as well.
    launch('visualizer', params_file=CONFIG, params={'use_sim_time': False})
    states = ros.collect(JointState, 'joint_states', qos=1000)
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    trajs = ros.collect(JointTrajectory, 'arm_controller/joint_trajectory')
    markers = ros.collect(MarkerArray, 'markers')
    ros.wait_for(lambda: states and stamp(states[-1]) > 0.05, timeout=30,
                 what='the closed loop to run')
    assert ros.set_params('/visualizer', use_sim_time=True)[0].successful
    clock = ros.publisher(Clock, '/clock')
    ros.wait_matched(clock, [n.lstrip('/') for n in ON_SIM_TIME], 20)

    # 1. A negative clock (rclpy's TimeSource raises ValueError on it).
    first = refuse_everywhere(ros, clock, bad_clock(-5), diags,
                              'clock is negative (sec = -5)')
    for node, status in first.items():
        assert status.level == DiagnosticStatus.WARN, (node, status)
        v = values(status)
        assert (v['topic'], v['sec'], v['nanosec']) == ('/clock', '-5', '0'), (node, v)
        assert 'the node keeps its time at' in status.message
    kept_before = {n: kept_time(s) for n, s in first.items()}

    # Every node goes on: the planner plans a goal, the controller takes it and drives the
    # arm there through the simulator, the visualizer draws it.
    goals = ros.publisher(PoseStamped, 'goal_pose')
    ros.wait_matched(goals, ['planner'], 20)
    target = np.array([0.5, 1.2])  # Pf of the demo, m
    n_markers = len(markers)
    goals.publish(goal_msg(*target))
    ros.wait_for(lambda: trajs, timeout=20, what="the planner's trajectory")
    ros.wait_for(lambda: events(diags, '/controller', 'trajectory_accepted'), timeout=20,
                 what='the controller to accept it')

    def arrived() -> bool:
        q, qd = np.array(states[-1].position), np.array(states[-1].velocity)
        tip = ARM.forward_kinematics(q)
        return bool(np.abs(tip - target).max() < 1e-3 and np.abs(qd).max() < 1e-3)

    ros.wait_for(arrived, timeout=60, what='the arm at the goal (1 mm, 1e-3 rad/s)')
    ros.wait_for(lambda: len(markers) > n_markers, what='new markers')

    # 2. nanosec >= 1e9 (rclpy would carry it into the seconds): refused the same way, and
    # the time each node kept now is the simulator's later time: its clock went on.
    second = refuse_everywhere(ros, clock, bad_clock(3, 2_000_000_000), diags,
                               'clock.nanosec = 2000000000 is outside [0, 1e9)')
    end = trajs[0].points[-1].time_from_start
    motion = end.sec + end.nanosec * 1e-9  # s, the planned motion's duration
    for node, status in second.items():
        v = values(status)
        assert (v['sec'], v['nanosec']) == ('3', '2000000000'), (node, v)
        # The goal came after the first refusal and the arm arrived before the second:
        # at least the motion's duration of simulated time between them (0.1 s: the
        # clock a node last took may be some periods behind the simulator's).
        assert kept_time(status) >= kept_before[node] + motion - 0.1, (node, v, motion)
        assert count(diags, node, 'rejected_clock') >= 2
    n = len(states)
    ros.wait_for(lambda: len(states) > n + 10, what='joint states after the bad clocks')
    assert not any(statuses(diags, node, 'internal_error') for node in ON_SIM_TIME)
    # The launch fixture stops every node with SIGINT: each must still run and exit 0.


#: A node made by run_node whose callback fails on some messages: ``divider/in`` [a, b]
#: gives ``divider/out`` [a / b]; [1, 0] raises ZeroDivisionError, [1] ValueError.
DIVIDER = '''
import sys
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray
from arm_common.node import Diagnostics, clock_in_namespace, run_node

class Divider(Node):
    def __init__(self):
        super().__init__('divider', cli_args=clock_in_namespace())
        self.diag = Diagnostics(self)
        self.pub = self.create_publisher(Float64MultiArray, 'divider/out', 10)
        self.create_subscription(Float64MultiArray, 'divider/in', self.divide, 10)

    def divide(self, msg):
        a, b = msg.data
        self.pub.publish(Float64MultiArray(data=[a / b]))

sys.exit(run_node(Divider, prog='divider', summary='divides', specs=()))
'''


def test_a_message_a_callback_fails_on_is_dropped_reported_and_the_node_goes_on(ros):
    env = node_env(DOMAIN_ID)
    env[PARENT_ENV] = str(os.getpid())  # it exits if the test process dies
    proc = subprocess.Popen([sys.executable, '-c', DIVIDER], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        out = ros.collect(Float64MultiArray, 'divider/out')
        diags = ros.collect(DiagnosticArray, '/diagnostics')
        pub = ros.publisher(Float64MultiArray, 'divider/in')
        ros.wait_matched(pub, ['divider'], 20)
        for data, error in (([1.0, 0.0], 'ZeroDivisionError'), ([1.0], 'ValueError')):
            k = count(diags, '/divider', 'internal_error')
            ros.wait_for(lambda: count(diags, '/divider', 'internal_error') > k
                         or proc.poll() is not None or pub.publish(
                             Float64MultiArray(data=data)),
                         what=f'the report of the {error}')
            assert proc.poll() is None, f'the node died on {data}'
            status = statuses(diags, '/divider', 'internal_error')[-1]
            v = values(status)
            assert status.level == DiagnosticStatus.ERROR
            assert v['topic'] == '/divider/in' and v['error'].startswith(error), v
            assert v['where'].endswith('in divide'), v
            assert 'message dropped' in status.message and error in status.message
        ros.wait_for(lambda: out or pub.publish(Float64MultiArray(data=[6.0, 3.0])),
                     what='the answer to a good message')
        assert list(out[-1].data) == [2.0]
        assert all(math.isfinite(x) for m in out for x in m.data)
    finally:
        code = stop_child(proc, signal.SIGINT, 10)
        log = proc.stdout.read() if proc.stdout else ''
    assert code == 0, f'divider exited {code}:\n{log}'
    assert 'Traceback' not in log, log
