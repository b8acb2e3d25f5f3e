"""``wait_for_nodes``: a node's first messages wait until the named nodes have matched them
(arm_common.gate), so a recorder started first holds every message of nodes started after
it (real node processes on a private domain)."""

from __future__ import annotations

import numpy as np
from conftest import statuses
from diagnostic_msgs.msg import DiagnosticArray
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from arm_bag.reader import read_bag
from arm_bag.recorder_node import SETTLED
from arm_sim.launcher import config_file

CONFIG = config_file()


def test_nodes_started_after_the_recorder_settled_lose_nothing_to_discovery(ros, launch,
                                                                           tmp_path):
    """The recorder first, until it says discovery has settled (from then on it counts what
    a new publisher sent before its subscription matched as lost); then the simulator,
    controller and visualizer with ``wait_for_nodes: [recorder]``. The bag holds every
    state and every command from t = 0, each topic's first message is its publisher's
    first, and nothing is counted lost."""
    recorder = launch('recorder', params_file=CONFIG, params={'output': str(tmp_path / 'bag')})
    ros.wait_for(lambda: SETTLED in recorder.output(), 30, 'the recorder to settle discovery')
    gate = {'wait_for_nodes': ['recorder']}
    launch('simulator', params_file=CONFIG,
                 params={'timing_mode': 'lockstep', 'pause_at': 1.0, **gate})
    launch('controller', params_file=CONFIG, params=gate)
    launch('visualizer', params_file=CONFIG, params=gate)
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    ros.wait_for(lambda: any(s.message.startswith('paused at t=1.000')
                             for s in statuses(diags, '/simulator', 'summary')), 60,
                 'the simulator to pause at t = 1 s')
    for proc in launch.procs[1:]:
        assert proc.stop() == 0
    assert recorder.stop() == 0
    bag = read_bag(tmp_path / 'bag')
    assert bag.lost == {} and bag.warnings == [], (bag.lost, bag.warnings)
    stamps = np.unique(bag.joint_states.stamp)
    assert stamps[0] == 0 and stamps[-1] == 1_000_000_000, 'every state from the first'
    assert (np.diff(stamps) == 10_000_000).all(), 'none missing'
    refs = np.unique(bag.reference.stamp)  # the controller's, one per state it answered
    assert refs[0] == 0 and refs[-1] >= 990_000_000, "the controller's from the first"
    assert (np.diff(refs) == 10_000_000).all(), 'none missing'


def test_the_simulator_holds_its_first_state_until_the_named_node_subscribes(ros, launch):
    """Named: this test's own node. The simulator says it holds its first state (summary)
    and sends nothing; once the test subscribes to both its streams (joint_states and
    clock), the first state it gets is t = 0."""
    launch('simulator', params_file=CONFIG,
           params={'timing_mode': 'lockstep', 'wait_for_nodes': ['arm_sim_test']})
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    ros.wait_for(lambda: any('holding the first state until arm_sim_test' in s.message
                             for s in statuses(diags, '/simulator', 'summary')), 30,
                 'the simulator to say it holds its first state')
    states = ros.collect(JointState, 'joint_states')
    ros.collect(Clock, 'clock')  # both of its streams: the gate waits for each
    ros.wait_for(lambda: states, 30, 'the first state once we subscribed')
    assert states[0].header.stamp.sec == 0 and states[0].header.stamp.nanosec == 0
    ros.wait_for(lambda: any(s.message.startswith('waiting for the first command')
                             for s in statuses(diags, '/simulator', 'summary')), 30,
                 'the simulator to wait for a controller, as without the gate')
