"""The demo end to end: four node processes, the lecture's tasks, a bag and a picture."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from arm_bag.analysis import analyze
from arm_bag.reader import read_bag
from arm_sim.launcher import node_env


def run_demo(out, domain: int) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'arm_sim.cli', 'demo', '--out', str(out),
                           '--domain-id', str(domain)], capture_output=True, text=True,
                          timeout=180, env=node_env(domain))


@pytest.fixture(scope='module')
def demo_runs(tmp_path_factory):
    from conftest import DOMAIN_ID
    base = tmp_path_factory.mktemp('demo')
    runs = [(base / f'run{k}', run_demo(base / f'run{k}', DOMAIN_ID)) for k in (1, 2)]
    for out, res in runs:
        assert res.returncode == 0, f'{out}: {res.stdout[-2000:]}\n{res.stderr[-2000:]}'
    return runs


def test_demo_runs_the_tasks_and_answers_the_lectures_questions(demo_runs):
    out, res = demo_runs[0]
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
    # Bounds (measured: settle 1.14 s, final 2e-6 rad, lines 0.57 / 1.49 / 67 mm).
    assert reg['settling_time_overall'] < 2.0
    assert np.abs(reg['final_error']).max() < 1e-4, 'regulation holds the goal'
    assert slow['deviation_max'] < 1e-3, 'slow line under computed torque: < 1 mm'
    assert fast_ct['deviation_max'] < 3e-3, 'fast line under computed torque: < 3 mm'
    assert fast_pd['deviation_max'] > 10 * fast_ct['deviation_max'], (
        'plain PD leaves the line far more than computed torque at the same speed')
    assert np.abs(fast_pd['final_error']).max() > 1e-2, 'and keeps a gravity error'
    assert max(fast_ct['torque_peak']) > max(slow['torque_peak']), 'faster needs more torque'


def test_two_lockstep_demo_runs_record_identical_joint_states(demo_runs):
    states = []
    for out, _ in demo_runs:
        js = read_bag(out / 'bag').joint_states
        stamps, first = np.unique(js.stamp, return_index=True)  # heartbeats repeat a stamp
        states.append((stamps, js.position[first], js.velocity[first], js.effort[first]))
    (a, b) = states
    assert len(a[0]) > 1000
    for x, y in zip(a, b):
        assert np.array_equal(x, y), 'bit-identical joint states'
