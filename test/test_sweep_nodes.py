"""A sweep point equals the same scenario run through the real nodes in lockstep.

The demo's fast line Ps -> Pf (0.8 s, quintic, computed torque, 100 Hz control) is planned
by the planner node from the paused arm, tracked by the controller node and integrated by
the simulator node; the recorded joint states and references give the same metrics as
``arm-sim sweep`` computes for that scenario (the arm was held at rest at Ps before, as
the sweep assumes).
"""

from __future__ import annotations

import numpy as np
from conftest import events, values
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState
from test_suite import PF, connect, goal, start_suite

from arm_sim import sweep
from arm_sim.client import stamp_of as stamp

DURATION, HOLD = 0.8, 0.5  # s


def test_a_sweep_point_has_the_metrics_of_the_same_scenario_through_the_nodes(ros, launch):
    start_suite(launch)
    states, _, goals = connect(ros)
    refs = ros.collect(JointState, 'arm_controller/reference', qos=1000)
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    # The reference stream must reach this test before the motion: a subscription not yet
    # matched with the controller would miss the references the comparison needs.
    ros.wait_for(lambda: refs, 30, 'the reference stream')
    assert ros.set_params('/planner', mode='straight_line', duration=DURATION,
                          time_scaling='quintic')[0].successful
    pause = ros.pause_simulator_now(diags)
    goals.publish(goal(*PF))
    ros.wait_for(lambda: [values(s) for s in events(diags, '/planner', 'plan_accepted')],
                 what='the plan accepted')
    end = pause + DURATION + HOLD
    assert ros.set_params('/simulator', pause_at=end)[0].successful
    ros.wait_for(lambda: states and stamp(states[-1]) >= end - 1e-9, what='the motion')
    ros.wait_for(lambda: refs and stamp(refs[-1]) >= end - 1e-9, what='the references')

    s = sweep.Scenario(start=sweep.PS, goal=PF, duration=DURATION, hold=HOLD,
                       law='computed_torque', control_rate=100.0)
    (row,) = sweep.run_chunk([(0, s)])
    ref_by = {round(stamp(m), 6): m.position for m in refs}
    seen = {}
    for m in states:  # one per stamp (lockstep may re-send a state)
        if pause - 1e-9 <= stamp(m) <= end + 1e-9:
            seen[round(stamp(m), 6)] = m
    t = np.array(sorted(seen))
    ms = [seen[k] for k in t]
    got = sweep.segment_metrics(
        t - t[0], np.array([m.position for m in ms]), np.array([m.velocity for m in ms]),
        np.array([m.effort for m in ms]), np.array([ref_by[k] for k in t]),
        sweep.plan_scenario(s), s.effort_limits)
    assert len(t) == row['samples'], f'{len(t)} states vs {row["samples"]} in the sweep'
    for key, value in got.items():
        mine = [row[f'{key}_1'], row[f'{key}_2']] if f'{key}_1' in row else [row[key]]
        theirs = np.atleast_1d(np.array(value, dtype=float))
        assert np.allclose(theirs, mine, rtol=0, atol=1e-9, equal_nan=True), (
            f'{key}: nodes {theirs} vs sweep {mine}')
