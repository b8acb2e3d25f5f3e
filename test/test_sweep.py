"""``arm-sim sweep``: spec validation, the batch path against the nodes' single-state path,
the metrics against ``arm-sim analyze``, outputs, process pool and Dask (no ROS)."""

from __future__ import annotations

import csv
import itertools
import json
import math
import multiprocessing
import os
import re
import resource
import signal
import subprocess
import sys
import threading
import time
import tracemalloc
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from arm_bag.analysis import analyze
from arm_bag.synthetic import ROBOT as BAG_ROBOT
from arm_bag.synthetic import open_bag, write_run
from arm_common import cluster
from arm_control.laws import BATCH_LAWS, ControlLaw, Gains, law_torque
from arm_dynamics.batch import BatchSimulator
from arm_dynamics.simulation import SimulatorCore
from arm_dynamics.two_link import TwoLinkArm, TwoLinkBatch
from arm_sim import sweep
from arm_sim.cli import main
from arm_sim.sweep import (
    COLUMNS,
    METRIC_COLUMNS,
    PF,
    PS,
    STATUSES,
    PlotSpec,
    Scenario,
    default_plot,
    load_spec,
    make_chunks,
    parse_spec,
    plot_sweep,
    run_chunk,
    run_single,
    run_sweep,
    sweep_figure,
    write_csv,
)

RNG = np.random.default_rng(7)
#: Short scenarios that exercise every law, mismatch, both tasks and two control rates.
MIX = [Scenario(start=PF, goal=PS, duration=0.5, hold=0.2, law=law, payload=p,
                mass_error=e, length_error=le, control_rate=rate, kp=kp, kd=kd,
                ki=(300.0, 150.0))
       for law, kp, kd in (('computed_torque', (100.0, 60.0), (20.0, 12.0)),
                           ('pd_gravity', (600.0, 300.0), (60.0, 25.0)),
                           ('pd', (600.0, 300.0), (60.0, 25.0)),
                           ('pid', (600.0, 300.0), (60.0, 25.0)))
       for p, e, le in ((0.0, 0.0, 0.0), (0.7, 0.1, -0.05))
       for rate in (100.0, 500.0)]
MIX += [Scenario(task='regulation', regulation_profile=prof, start=PS, goal=PF, hold=0.5,
                 duration=0.6, law='computed_torque') for prof in ('synchronized', 'set_point')]


def numbers(row: dict) -> dict:
    return {c: row[c] for c in METRIC_COLUMNS}


def assert_rows_close(a: dict, b: dict, tol: float) -> None:
    for c in COLUMNS:
        x, y = a[c], b[c]
        if isinstance(x, float) and isinstance(y, float):
            assert (np.isnan(x) and np.isnan(y)) or abs(x - y) <= tol * max(1.0, abs(x)), (
                f'{c}: {x!r} vs {y!r}')
        else:
            assert x == y, f'{c}: {x!r} vs {y!r}'


def refuse_to_run(*_args, **_kwargs):
    raise AssertionError('the sweep ran: the refusal must come before the run')


def write_spec(tmp_path: Path, text: str) -> Path:
    p = tmp_path / 'spec.yaml'
    p.write_text(text)
    return p


# ---------------------------------------------------------------------- batch = single
def test_batch_dynamics_equal_each_arm_alone_to_1e_12():
    arms = [TwoLinkArm(link_masses=tuple(RNG.uniform(0.5, 4, 2)),
                       link_lengths=tuple(RNG.uniform(0.3, 1.5, 2)),
                       com_distances=tuple(RNG.uniform(0.1, 0.3, 2)),
                       link_inertias=tuple(RNG.uniform(0.01, 0.2, 2)),
                       joint_damping=tuple(RNG.uniform(0, 0.5, 2))) for _ in range(50)]
    batch = TwoLinkBatch(arms)
    q, qd, x = (RNG.uniform(-3, 3, (50, 2)) for _ in range(3))
    one = np.array([[*a.forward_dynamics(q[i], qd[i], x[i]),
                     *a.inverse_dynamics(q[i], qd[i], x[i]), *a.gravity_vector(q[i]),
                     *np.concatenate(a.step(q[i], qd[i], x[i], 1e-3, 5))]
                    for i, a in enumerate(arms)])
    many = np.hstack([batch.forward_dynamics(q, qd, x), batch.inverse_dynamics(q, qd, x),
                      batch.gravity_vector(q), *batch.step(q, qd, x, 1e-3, 5)])
    assert np.abs(many - one).max() <= 1e-12 * max(1.0, np.abs(one).max())


def test_batch_dynamics_refuse_a_state_of_the_wrong_shape_naming_it():
    batch = TwoLinkBatch([TwoLinkArm(), TwoLinkArm()])
    with pytest.raises(ValueError, match=r'qd must have shape \(2, 2\)'):
        batch.forward_dynamics(np.zeros((2, 2)), np.zeros((3, 2)), np.zeros((2, 2)))
    with pytest.raises(ValueError, match='arms must hold at least one'):
        TwoLinkBatch([])


@pytest.mark.parametrize('law', BATCH_LAWS)
def test_the_batch_law_equals_the_controllers_law_row_by_row(law):
    gains = Gains(kp=(300.0, 100.0), kd=(30.0, 10.0), ki=(200.0, 80.0), i_clamp=(5.0, 2.0))
    model = TwoLinkArm(link_masses=(2.2, 1.4))
    q, qd, qr, qdr, qddr = (RNG.uniform(-1, 1, (20, 2)) for _ in range(5))
    integral = RNG.uniform(-2, 2, (20, 2))
    single = []
    for i in range(20):
        c = ControlLaw(law, gains, model, (60.0, 20.0), integral=integral[i].copy())
        single.append((c(q[i], qd[i], qr[i], qdr[i], qddr[i], 0.01).raw, c.integral))
    raw, new = law_torque(law, *(np.asarray(v) for v in (gains.kp, gains.kd, gains.ki,
                                                          gains.i_clamp)),
                          np.array([60.0, 20.0]), TwoLinkBatch([model] * 20), integral, q, qd,
                          qr, qdr, qddr, 0.01)
    assert np.abs(raw - np.array([s[0] for s in single])).max() <= 1e-12 * 100
    assert np.abs(new - np.array([s[1] for s in single])).max() <= 1e-12


def test_the_batch_simulator_steps_each_arm_as_the_simulator_core_does():
    arms = [TwoLinkArm(), TwoLinkArm().with_payload(0.8), TwoLinkArm(link_masses=(2.5, 1.0))]
    q0, qd0 = RNG.uniform(-1, 1, (3, 2)), RNG.uniform(-1, 1, (3, 2))
    limits = np.array([[60.0, 20.0], [30.0, 10.0], [5.0, 5.0]])
    timing = dict(physics_step_ns=1_000_000, control_period_ns=5_000_000, velocity_limit=1e3)
    batch = BatchSimulator(arms, q0=q0, qd0=qd0, effort_limits=limits, **timing)
    cores = [SimulatorCore(a, q0=q0[i], qd0=qd0[i], effort_limits=limits[i],
                           joint_names=('j1', 'j2'), **timing) for i, a in enumerate(arms)]
    for _ in range(40):
        command = RNG.uniform(-50, 50, (3, 2))  # often beyond the limits: saturated
        batch.advance(command)
        for i, core in enumerate(cores):
            core.set_command(command[i])
            core.advance()
        assert np.array_equal(batch.applied, [c.applied for c in cores])
        gap = max(np.abs(batch.q - [c.q for c in cores]).max(),
                  np.abs(batch.qd - [c.qd for c in cores]).max() * 1e-2)
        assert gap <= 1e-12, gap
    assert batch.periods == 40 and batch.alive.all() and (batch.diverged_at == -1).all()
    assert not any(c.diverged for c in cores)


def test_a_diverging_arm_of_the_batch_is_held_with_zero_torque_and_the_others_go_on():
    arms = [TwoLinkArm(), TwoLinkArm().with_payload(0.5), TwoLinkArm()]
    q0 = np.array([[0.1, 0.5], [0.2, 0.4], [-0.3, 1.0]])
    timing = dict(physics_step_ns=1_000_000, control_period_ns=10_000_000, velocity_limit=50.0)
    batch = BatchSimulator(arms, q0=q0, qd0=np.zeros((3, 2)),
                           effort_limits=np.full((3, 2), 1e6), **timing)
    others = BatchSimulator([arms[0], arms[2]], q0=q0[[0, 2]], qd0=np.zeros((2, 2)),
                            effort_limits=np.full((2, 2), 1e6), **timing)
    held = None
    for k in range(1, 21):
        command = np.array([[5.0, 1.0], [3000.0, -3000.0], [-5.0, 0.0]])  # arm 1 runs away
        before = batch.q[1].copy(), batch.qd[1].copy()
        batch.advance(command)
        others.advance(command[[0, 2]])
        if batch.diverged_at[1] == k:  # this period: back to the last good state
            held = before
        if held is not None:
            assert np.array_equal(batch.q[1], held[0]) and np.array_equal(batch.qd[1], held[1])
            assert (batch.applied[1] == 0.0).all()
        assert np.abs(batch.q[[0, 2]] - others.q).max() <= 1e-12
        assert np.array_equal(batch.applied[[0, 2]], others.applied)
    assert held is not None and 1 <= batch.diverged_at[1] < 20, batch.diverged_at
    assert batch.diverged_at[[0, 2]].tolist() == [-1, -1]
    assert batch.alive.tolist() == [True, False, True]
    assert np.abs(held[1]).max() <= 50.0  # the held state is a good one
    with pytest.raises(ValueError, match=r'q0 must have shape \(3, 2\)'):
        BatchSimulator(arms, q0=np.zeros((2, 2)), qd0=np.zeros((3, 2)),
                       effort_limits=np.ones((3, 2)), **timing)


def test_a_batch_of_mixed_scenarios_runs_as_each_does_alone_through_simulate():
    for chunk in make_chunks(MIX, 64):
        rows, runs = run_chunk(chunk, keep_runs=True)
        for (i, s), row, run in zip(chunk, rows, runs):
            alone, ref = run_single(i, s, keep_run=True)
            assert run is not None and ref is not None and len(run.t) == len(ref.t)
            gap = max(np.abs(run.q - ref.q).max(), np.abs(run.qd - ref.qd).max() * 1e-2,
                      np.abs(run.effort - ref.effort).max() * 1e-2)
            assert gap <= 1e-12, f'{s.law}, payload {s.payload}: batch vs single {gap:.2e}'
            assert_rows_close(row, alone, 1e-9)


def test_one_sweep_point_gives_the_metrics_arm_sim_analyze_gives_for_its_run(tmp_path):
    s = Scenario(start=PF, goal=PS, duration=0.8, hold=0.5, law='computed_torque')
    (row,) = run_chunk([(0, s)])
    # The same scenario through the nodes' pure path, recorded as the recorder would.
    _, run = run_single(0, s, keep_run=True)
    planned = sweep.plan_scenario(s)
    assert run is not None and planned.trajectory is not None and planned.line is not None
    w, ch = open_bag(tmp_path / 'bag', robot=BAG_ROBOT)
    start_ns = 2_000_000_000
    traj = planned.trajectory
    write_run(w, ch, 1000, run.t, run.q, run.qd, run.effort, run.q_des,
              trajectory=(traj.positions, traj.times), stamp0=start_ns,
              path_xy=np.array([planned.line[0], (planned.line[0] + planned.line[1]) / 2,
                                planned.line[1]]))
    w.close()
    seg = analyze(tmp_path / 'bag').to_dict()['segments'][0]
    assert seg['mode'] == 'straight_line'
    for key in ('deviation_max', 'deviation_rms', 'line_overshoot_end',
                'line_overshoot_start', 'energy'):
        assert abs(seg[key] - row[key]) <= 1e-9, key
    for key in ('tracking_rms', 'tracking_max', 'final_error', 'torque_peak', 'torque_rms',
                'saturated_fraction'):
        for j in (0, 1):
            assert abs(seg[key][j] - row[f'{key}_{j + 1}']) <= 1e-9, key
    # and the demo's fast line, as the demo's README table reports it
    assert round(row['deviation_max'] * 1e3, 2) == 3.49
    assert round(row['torque_peak_1'], 1) == 47.7


def test_regulation_metrics_match_analyze_settling_and_overshoot(tmp_path):
    s = Scenario(task='regulation', regulation_profile='set_point', start=PS, goal=PF,
                 hold=2.0, law='pd_gravity', kp=(400.0, 200.0), kd=(40.0, 20.0))
    (row,), (run,) = run_chunk([(0, s)], keep_runs=True)
    assert run is not None
    w, ch = open_bag(tmp_path / 'bag', robot=BAG_ROBOT)
    sp = sweep.plan_scenario(s).set_point
    write_run(w, ch, 1000, run.t, run.q, run.qd, run.effort, run.q_des,
              trajectory=(np.array([sp]), np.zeros(1)), stamp0=1_000_000_000)
    w.close()
    seg = analyze(tmp_path / 'bag').to_dict()['segments'][0]
    assert seg['mode'] == 'regulation'
    assert abs(seg['settling_time_overall'] - row['settling_time_overall']) <= 1e-9
    for j in (0, 1):
        assert abs(seg['overshoot'][j] - row[f'overshoot_{j + 1}']) <= 1e-9


def test_a_diverging_or_refused_scenario_is_a_row_with_its_reason_not_an_error():
    wild = Scenario(law='pd', kp=(1e5, 1e5), kd=(0.0, 0.0), control_rate=10.0, hold=1.0,
                    duration=0.5, effort_limits=(1e6, 1e6))
    far = Scenario(goal=(3.0, 0.0))
    rows = run_sweep([wild, far], workers=1)
    assert rows[0]['status'] == 'diverged' and 'diverged at t=' in rows[0]['message']
    assert rows[1]['status'] == 'refused' and 'out of reach' in rows[1]['message']
    assert np.isnan(rows[1]['torque_peak_1'])


# ---------------------------------------------------------------------- spec
@pytest.mark.parametrize('text, message', [
    ('scenario: {gian: 3}', "spec.yaml: key 'gian' unknown (known: task, start"),
    ('axes: {duration: []}', 'axes.duration: no values'),
    ('axes: {duration: [0.5, -1]}', 'axes.duration: duration must be > 0 s, got -1 (range '
     '(0, 3600])'),
    ('scenario: {payload: -0.5}', 'scenario.payload: payload must be >= 0 kg, got -0.5'),
    ('scenario: {kp: [100, -2]}', 'scenario.kp: kp[1] must be >= 0'),
    ('scenario: {law: 5}', "law must be one of pd, pd_gravity, computed_torque, pid; got 5"),
    ('axes: {law: [pd, lqr]}', "law must be one of pd, pd_gravity, computed_torque, pid; "
     "got 'lqr'"),
    ('axes: {duration: {linspace: [0.5, 1.0]}}', 'linspace takes [first, last, count'),
    ('scenario: {control_rate: 300}', 'not a whole multiple of physics_step'),
    ("scenario: {duration: fastest, feasibility: ignore}", "feasibility must be stretch"),
    ('sweep: random', 'samples must be an integer in [1,'),
    ('axes: {payload: {uniform: [1, 0]}}', "key 'uniform' unknown (known: linspace, logspace)"),
    ('[1, 2]', 'a spec is a mapping'),
    ('scenario: {kp: [1, 2, 3]}', 'kp must be a number or two numbers'),
    ('axes: {variant: [{law: pd, gian: 1}]}', "axes.variant[0]: key 'gian' unknown"),
    ('scenario: {task: [', 'not YAML'),
    # bounded: every number in its range, the work sized before anything is built
    ('scenario: {kp: [1.0e+308, 1.0e+308]}', 'scenario.kp: kp[0] must be <= 1e+06 1/s^2 '
     '(computed_torque), N m/rad (others), got 1e+308 (range [0, 1e+06])'),
    ('axes: {ki: [.inf]}', 'axes.ki: ki must be finite, got inf'),
    ('scenario: {payload: 0x' + 'f' * 300 + '}', 'scenario.payload: payload must be <= 10000, '
     'got an integer of 1200 bits'),
    ('scenario: {control_rate: 0.01}', 'control_rate must be >= 0.1 Hz, got 0.01'),
    ('scenario: {goal: [100, 0]}', 'goal[0] must be <= 10 m, got 100'),
    ('axes: {payload: {linspace: [0, 3, 1000000000]}}',
     'axes.payload: 1000000000 values, more than 100000 per axis'),
    ('scenario: {hold: 3600, control_rate: 1000}', 'is 3601000 control samples, more than'),
    ('axes: {law: [pd, pid]}\nplot: {x: law, y: [torque_peak_1]}',
     "plot: x: column 'law' holds text; x must be a number column"),
    ('scenario: {duration: fastest}\nplot: {x: duration_requested, y: [torque_peak_1]}',
     "plot: x: column 'duration_requested' is 'fastest' in some scenarios"),
    ('axes: {law: [lqr]}', "law must be one of pd, pd_gravity, computed_torque, pid; got "
     "'lqr'"),
])
def test_a_bad_spec_is_one_line_naming_the_value_with_exit_2(tmp_path, capsys, monkeypatch,
                                                             text, message):
    monkeypatch.setattr(sweep.cli, 'run_sweep', refuse_to_run)
    path = write_spec(tmp_path, text)
    assert main(['sweep', str(path), '--quiet']) == 2
    err = capsys.readouterr().err
    assert err.startswith(f'arm-sim sweep: {path}: ') and err.count('\n') == 1, err
    assert message in err, err


def test_a_missing_spec_file_is_one_line_with_exit_2(tmp_path, capsys):
    assert main(['sweep', str(tmp_path / 'nope.yaml')]) == 2
    err = capsys.readouterr().err
    assert 'cannot read it' in err and err.count('\n') == 1


def test_help_explains_every_setting_with_its_unit(capsys):
    with pytest.raises(SystemExit) as exc:
        main(['sweep', '--help'])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for text in ('payload [kg]', 'duration [s]', 'control_rate [Hz]', 'effort_limits [N m]',
                 "'fastest'", 'linspace', 'uniform', '--dask SCHEDULER_ADDRESS'):
        assert text in out, text


def test_the_shipped_specs_load_and_expand():
    shipped = sweep.shipped_specs()
    assert {'line_speed', 'payload', 'gains'} <= set(shipped)
    for name, path in shipped.items():
        spec = load_spec(path)
        assert spec.question and len(spec.scenarios()) >= 20, name
        assert spec.plot is not None


def test_a_grid_is_every_combination_and_a_random_sweep_is_reproducible():
    grid = parse_spec({'axes': {'duration': {'linspace': [1.0, 2.0, 3]},
                                'variant': [{'law': 'pd'}, {'law': 'pid', 'ki': 10}]}})
    got = [(s.duration, s.law, s.ki) for s in grid.scenarios()]
    assert got == [(d, law, ki) for d in (1.0, 1.5, 2.0)
                   for law, ki in (('pd', (50.0, 30.0)), ('pid', (10.0, 10.0)))]
    doc = {'sweep': 'random', 'samples': 5, 'seed': 3,
           'axes': {'payload': {'uniform': [0, 2]}, 'goal': {'uniform': [[0.4, 1.0],
                                                                         [0.6, 1.2]]}}}
    a, b = parse_spec(doc).scenarios(), parse_spec(doc).scenarios()
    assert a == b and len({s.payload for s in a}) == 5
    assert all(0.4 <= s.goal[0] <= 0.6 and 1.0 <= s.goal[1] <= 1.2 for s in a)


# ---------------------------------------------------------------------- outputs
SMALL = """name: small
question: does it run?
scenario: {start: [0.5, 1.2], goal: [1.4782, 0.1845], hold: 0.2}
axes:
  duration: [0.6, 1.2, 2.0]
  law: [computed_torque, pd_gravity]
plot: {x: duration, y: [torque_peak_1, deviation_max], by: law}
"""


def test_the_cli_writes_a_csv_a_png_and_json_with_the_documented_columns(tmp_path, capsys):
    spec = write_spec(tmp_path, SMALL)
    out, png = tmp_path / 'r.csv', tmp_path / 'r.png'
    assert main(['sweep', str(spec), '--output', str(out), '--plot', str(png), '--json',
                 '--workers', '1']) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc['scenarios'] == 6 and doc['status']['ok'] == 6
    with open(out, newline='') as f:
        table = list(csv.reader(f))
    assert tuple(table[0]) == COLUMNS and len(table) == 7
    for col in COLUMNS:  # every column is documented in the module docstring
        base = col[:-2] if col[-2:] in ('_1', '_2') else col
        assert f'``{base}``' in (sweep.__doc__ or ''), col
    dev = table[0].index('deviation_max')
    assert all(0.0 < float(r[dev]) < 1.0 for r in table[1:])
    data = png.read_bytes()
    assert data[:8] == b'\x89PNG\r\n\x1a\n' and 20_000 < len(data) < 2_000_000


def test_plot_draws_the_default_question_without_a_plot_section(tmp_path):
    import matplotlib.pyplot as plt

    spec = parse_spec({'axes': {'payload': [0.0, 1.0], 'law': ['pd_gravity', 'pid']},
                       'scenario': {'hold': 0.1, 'duration': 0.5}})
    rows = run_sweep(spec.scenarios(), workers=1)
    assert [r['status'] for r in rows] == ['ok'] * 4
    # The default question: the numeric axis across, one curve per law, the peak torques
    # and the straight line's deviation up.
    ps = default_plot(spec)
    assert ps == PlotSpec(x='payload', y=('torque_peak_1', 'torque_peak_2', 'deviation_max'),
                          by='law')
    fig = sweep_figure(spec, rows)
    try:
        axes = fig.axes
        assert [ax.get_ylabel() for ax in axes] == [
            'torque_peak_1 [N m]', 'torque_peak_2 [N m]', 'deviation_max [m]']
        assert axes[-1].get_xlabel() == 'payload [kg]'
        for ax, col, limit in zip(axes, ps.y, (60.0, 20.0, None)):
            lines = ax.get_lines()
            curves = {ln.get_label(): ln for ln in lines if ln.get_label().startswith('law')}
            assert sorted(curves) == ['law = pd_gravity', 'law = pid'], col
            for law in ('pd_gravity', 'pid'):
                mine = sorted((r['payload'], r[col]) for r in rows if r['law'] == law)
                xy = curves[f'law = {law}'].get_xydata().tolist()
                assert xy == [[x, y] for x, y in mine], (col, law)
            # the effort limit on the torque panels, nothing else
            others = [ln.get_ydata()[0] for ln in lines if ln not in curves.values()]
            assert others == ([] if limit is None else [limit]), col
    finally:
        plt.close(fig)
    path = plot_sweep(spec, rows, tmp_path / 'p.png')
    assert path.read_bytes()[:4] == b'\x89PNG'


def test_csv_leaves_undefined_metrics_empty(tmp_path):
    rows = run_sweep([Scenario(goal=(3.0, 0.0))], workers=1)
    write_csv(rows, tmp_path / 'r.csv')
    with open(tmp_path / 'r.csv', newline='') as f:
        (row,) = list(csv.DictReader(f))
    assert row['status'] == 'refused' and row['torque_peak_1'] == ''


# ---------------------------------------------------------------------- parallel
def test_two_worker_processes_give_the_rows_one_process_gives():
    scenarios = MIX[:8]
    one = run_sweep(scenarios, workers=1, chunk_size=3)
    two = run_sweep(scenarios, workers=2, chunk_size=3)
    for a, b in zip(one, two):
        assert_rows_close(a, b, 0.0)


def test_a_local_sweep_does_not_import_dask(tmp_path):
    spec = write_spec(tmp_path, SMALL)
    code = ('import sys; from arm_sim.cli import main; '
            f"rc = main(['sweep', {str(spec)!r}, '--quiet', '--workers', '2', "
            "'--chunk-size', '2']); "
            "sys.exit(rc or (3 if any(m.split('.')[0] in ('dask', 'distributed') "
            "for m in sys.modules) else 0))")
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr


def small_bag(path: Path) -> Path:
    """A bag with one regulation segment (synthetic: no ROS)."""
    w, ch = open_bag(path)
    t = np.arange(200) * 0.01
    goal = np.array([0.4, -0.3])
    q = goal + 0.2 * np.exp(-t / 0.3)[:, None]
    write_run(w, ch, 1000, t, q, np.gradient(q, t, axis=0), 5 * (goal - q),
              np.tile(goal, (len(t), 1)), (np.array([q[0], goal]), np.array([0.0, 1.0])))
    w.close()
    return path


@pytest.mark.timeout(180)
def test_a_dask_cluster_gives_the_rows_and_the_analyses_a_local_run_gives(tmp_path, capsys):
    distributed = pytest.importorskip('distributed')
    scenarios = MIX[:6]
    local = run_sweep(scenarios, workers=1, chunk_size=2)
    bags = [str(small_bag(tmp_path / 'a')), str(tmp_path / 'missing'),
            str(small_bag(tmp_path / 'b'))]
    code = main(['analyze', *bags, '--json'])
    local_out = capsys.readouterr()
    local_cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1,
                                             processes=True, dashboard_address=None)
    try:
        remote = run_sweep(scenarios, dask=local_cluster.scheduler_address, chunk_size=2)
        remote_code = main(['analyze', *bags, '--json', '--dask',
                            local_cluster.scheduler_address])
        remote_out = capsys.readouterr()
    finally:
        local_cluster.close()
    for a, b in zip(local, remote):
        assert_rows_close(a, b, 0.0)
    assert code == remote_code == 4, 'the missing bag: exit 4 either way'
    assert remote_out.out == local_out.out and json.loads(remote_out.out)
    assert remote_out.err == local_out.err


def test_an_unreachable_dask_scheduler_is_one_line(tmp_path, capsys, monkeypatch):
    pytest.importorskip('distributed')
    monkeypatch.setattr(cluster, 'CONNECT_TIMEOUT', '1s')
    spec = write_spec(tmp_path, SMALL)
    assert main(['sweep', str(spec), '--quiet', '--dask', 'tcp://127.0.0.1:9']) == 1
    err = capsys.readouterr().err
    assert 'cannot reach the Dask scheduler' in err and err.count('\n') == 1


# ---------------------------------------------------------------------- bounded specs

def billion_laughs(levels: int = 9) -> str:
    """A YAML alias bomb: ``levels`` nested anchors, each a list of ten aliases of the one
    before (10^levels leaves under ``question`` once expanded), in a few hundred bytes."""
    lines = ['name: bomb', 'question:', f"  - &a1 [{', '.join(['lol'] * 10)}]"]
    lines += [f"  - &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(2, levels + 1)]
    return '\n'.join(lines) + '\n'


@pytest.mark.timeout(30)
def test_a_yaml_alias_bomb_is_refused_before_anything_is_expanded(tmp_path, capsys):
    path = write_spec(tmp_path, billion_laughs())
    assert path.stat().st_size < 1000
    pytest.importorskip('yaml')  # imported before measuring
    tracemalloc.start()
    try:
        with pytest.raises(sweep.SpecError, match=r'line 3: YAML anchors and aliases \(&a1\) '
                           'are not accepted'):
            load_spec(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2_000_000, f'{peak} bytes: the aliases were expanded'
    assert main(['sweep', str(path), '--quiet']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'anchors and aliases' in err, err


@pytest.mark.parametrize('text, message', [
    ('scenario: &s {payload: 1.0}', 'line 1: YAML anchors and aliases (&s) are not accepted'),
    ('base: &b {payload: 1.0}\nscenario: {<<: *b}', '(&b) are not accepted'),
    ('question: ' + '[' * 200 + ']' * 200, 'line 1: nested more than 16 levels deep'),
    ('question: "' + 'x' * 1_000_001 + '"', 'more than 1000000 bytes: a spec is a short text'),
    ('name: \xff\n', 'not UTF-8 text'),
])
def test_a_spec_file_that_could_grow_unbounded_is_refused_in_one_line(tmp_path, capsys, text,
                                                                      message):
    path = tmp_path / 'spec.yaml'
    path.write_bytes(text.encode('latin-1'))
    assert main(['sweep', str(path), '--quiet']) == 2
    err = capsys.readouterr().err
    assert err.startswith(f'arm-sim sweep: {path}: ') and err.count('\n') == 1, err
    assert message in err, err


@pytest.mark.timeout(60)
@pytest.mark.parametrize('doc, message', [
    ({'axes': {'payload': {'linspace': [0, 3, 10**9]}}},
     'axes.payload: 1000000000 values, more than 100000 per axis'),
    ({'axes': {'payload': {'logspace': [0.1, 3, 10**12]}}},
     'axes.payload: 1000000000000 values, more than 100000 per axis'),
    ({'axes': {'hold': [0.5] * 100_001}}, 'axes.hold: 100001 values, more than 100000'),
    ({'axes': {'payload': {'linspace': [0, 3, 1000]}, 'mass_error': {'linspace': [0, 1, 1000]},
               'length_error': [0.0, 0.1]}},
     'the grid has 2000000 scenarios (payload 1000 x mass_error 1000 x length_error 2), more '
     'than 1000000'),
    ({'sweep': 'random', 'samples': 10**9, 'axes': {'payload': {'uniform': [0, 1]}}},
     'samples must be an integer in [1, 1000000], got 1000000000'),
    ({'scenario': {'hold': 3600.0, 'control_rate': 1e5, 'physics_step': 1e-5}},
     'scenario 0: duration 1 s + hold 3600 s at control_rate 100000 Hz is 360100000 control '
     'samples, more than 1000000 per scenario'),
    ({'scenario': {'hold': 100.0, 'control_rate': 1000.0, 'physics_step': 1e-6}},
     'duration 1 s + hold 100 s at physics_step 1e-06 s is 101000000 RK4 steps, more than '
     '10000000 per scenario'),
])
def test_work_over_the_limits_is_refused_before_anything_is_built(doc, message):
    tracemalloc.start()
    try:
        with pytest.raises(ValueError) as exc:
            parse_spec(doc).scenarios()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert message in str(exc.value)
    assert peak < 20_000_000, f'{peak} bytes: the work was built before it was checked'


def test_a_plan_stretched_past_the_scenario_limits_is_a_refused_row(monkeypatch):
    monkeypatch.setattr(sweep.spec, 'MAX_SAMPLES', 100)
    s = Scenario(duration='fastest', hold=0.5)  # asks 0 + 0.5 s: 50 samples at 100 Hz
    with pytest.raises(ValueError, match='is 101 control samples, more than 100'):
        Scenario(duration=0.51, hold=0.5)
    for row in (run_chunk([(0, s)])[0], run_single(0, s)):
        assert row['status'] == 'refused' and math.isnan(row['samples'])  # not run
        assert row['duration'] > 0.5, row['duration']  # fastest: the planner's duration
        assert row['message'].startswith(f"planned duration {row['duration']:g} s + hold "
                                         '0.5 s at control_rate 100 Hz is '), row['message']


def test_a_chunk_over_the_batch_budget_runs_as_several_batches_with_the_same_rows(
        monkeypatch):
    items = list(enumerate(MIX[:4]))  # computed torque at 100 and 500 Hz: 0.713 s planned
    whole = {r['index']: r for c in make_chunks(MIX[:4], 10) for r in run_chunk(c)}
    sizes = []
    real = sweep.run._run_batch
    monkeypatch.setattr(sweep.run, 'MAX_BATCH_SAMPLES', 200)
    monkeypatch.setattr(sweep.run, '_run_batch',
                        lambda s, *a: sizes.append(len(s)) or real(s, *a))
    cut = {r['index']: r for c in make_chunks(MIX[:4], 10) for r in run_chunk(c)}
    assert sizes == [2, 1, 1], sizes  # 100 Hz: 2 x 93 <= 200; 500 Hz: 458 > 200, one by one
    assert sorted(cut) == [i for i, _ in items]
    for i in cut:
        assert_rows_close(cut[i], whole[i], 0.0)


def test_workers_are_at_most_4_per_cpu(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sweep.run.os, 'cpu_count', lambda: 2)
    monkeypatch.setattr(sweep.cli, 'run_sweep', refuse_to_run)
    assert sweep.max_workers() == 8
    spec = write_spec(tmp_path, SMALL)
    assert main(['sweep', str(spec), '--workers', '300']) == 2
    assert capsys.readouterr().err == ('arm-sim sweep: --workers must be in [1, 8] (4 per CPU, '
                                       '2 CPUs), got 300\n')
    with pytest.raises(ValueError, match=r'workers must be in \[1, 8\] \(4 per CPU\), got 9'):
        run_sweep(MIX[:2], workers=9)
    with pytest.raises(SystemExit):
        main(['sweep', '--help'])
    out = capsys.readouterr().out
    assert 'at most 4 per CPU: 8 here' in out and '--workers: 4 per CPU' in out


def test_every_numeric_setting_has_a_physical_range():
    for p in sweep.SETTINGS.values():
        if p.kind in ('double', 'doubles'):
            assert p.minimum is not None and p.maximum is not None, p.name
            assert -1e6 <= p.minimum < p.maximum <= 1e6, p.name
    for gain in ('kp', 'kd', 'ki', 'i_clamp'):  # as the controller node's gains.* (<= 1e6)
        assert sweep.SETTINGS[gain].maximum == sweep.MAX_GAIN == 1e6


def corners(names: Sequence[str]) -> list[tuple]:
    """Every combination of each setting's extremes (just inside a strict minimum)."""
    ends = []
    for n in names:
        p = sweep.SETTINGS[n]
        assert p.minimum is not None and p.maximum is not None
        ends.append((p.minimum + 1e-9 if p.strict_min else p.minimum, p.maximum))
    return list(itertools.product(*ends))


@pytest.mark.timeout(120)
def test_settings_at_the_ends_of_their_ranges_end_in_rows_not_tracebacks():
    """No combination of in-range values raises: at the corners of the gains, effort limits,
    payload and model errors, under every law, at the slowest, a usual and a fast rate
    (a seeded sample of the corners: bounded), plus the planner's corner cases."""
    rng = np.random.default_rng(5)
    names = ('kp', 'kd', 'ki', 'i_clamp', 'effort_limits', 'payload', 'mass_error',
             'length_error')
    ends = corners(names)
    scenarios = [Scenario(law=law, control_rate=rate, physics_step=step, duration=0.3,
                          hold=0.05, **dict(zip(names, ends[k])))
                 for law in BATCH_LAWS
                 for rate, step in ((0.1, 1.0), (100.0, 1e-3), (1e4, 1e-4))
                 for k in rng.choice(len(ends), 16, replace=False)]
    far, tiny = (10.0, -10.0), (1e-9, 1e-9)
    scenarios += [Scenario(start=PF, goal=PS, duration='fastest', effort_limits=tiny),
                  Scenario(duration='fastest', feasibility='refuse', effort_limits=(1e6, 1e6),
                           hold=0.0),
                  Scenario(duration=1e-9, feasibility='ignore', time_scaling='trapezoidal'),
                  Scenario(task='regulation', regulation_profile='set_point', elbow='up',
                           duration=0.2, hold=0.0, kp=1e6, kd=1e6),
                  Scenario(start=far, goal=far), Scenario(goal=(-10.0, -10.0))]
    rows = run_sweep(scenarios, workers=1)
    assert len(rows) == len(scenarios)
    seen = set()
    for r in rows:
        seen.add(r['status'])
        assert r['status'] in STATUSES
        if r['status'] == 'ok':
            for j in (1, 2):
                assert r[f'torque_peak_{j}'] <= r[f'effort_limit_{j}'] * (1 + 1e-12), r
        else:
            assert r['message'], r
    assert seen == set(STATUSES)


# ---------------------------------------------------------------------- bounded outputs
@pytest.mark.parametrize('where, message', [
    ('missing/r.{ext}', 'cannot write missing/r.{ext}: its directory does not exist'),
    ('.', 'cannot write .: it is a directory'),
    ('/proc/r.{ext}', 'cannot write /proc/r.{ext}: No such file or directory (ENOENT)'),
])
def test_an_output_that_cannot_be_created_is_refused_before_the_run(tmp_path, capsys,
                                                                    monkeypatch, where,
                                                                    message):
    monkeypatch.setattr(sweep.cli, 'run_sweep', refuse_to_run)
    monkeypatch.chdir(tmp_path)
    spec = write_spec(tmp_path, SMALL)
    for flag, ext in (('--output', 'csv'), ('--plot', 'png')):
        assert main(['sweep', str(spec), flag, where.format(ext=ext), '--quiet']) == 2
        err = capsys.readouterr().err
        assert err == f'arm-sim sweep: {message.format(ext=ext)}\n', err
    assert sorted(p.name for p in tmp_path.iterdir()) == ['spec.yaml']


def test_a_plot_format_matplotlib_cannot_write_is_refused_before_the_run(tmp_path, capsys,
                                                                         monkeypatch):
    monkeypatch.setattr(sweep.cli, 'run_sweep', refuse_to_run)
    spec = write_spec(tmp_path, SMALL)
    assert main(['sweep', str(spec), '--plot', str(tmp_path / 'p.xyz')]) == 2
    err = capsys.readouterr().err
    assert 'p.xyz: cannot draw a .xyz file (formats: ' in err and err.count('\n') == 1


@pytest.mark.skipif(not Path('/dev/full').exists(), reason='needs /dev/full')
def test_a_full_device_is_one_line_naming_it_and_the_errno(tmp_path, capsys):
    spec = write_spec(tmp_path, SMALL)
    assert main(['sweep', str(spec), '--output', '/dev/full', '--workers', '1', '--quiet']) == 1
    err = capsys.readouterr().err
    assert err == 'arm-sim sweep: cannot write /dev/full: No space left on device (ENOSPC)\n'


def run_cli(args: Sequence[str], **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'arm_sim.cli', *args], capture_output=True,
                          text=True, timeout=120, **kwargs)


def small_file_limit() -> None:
    """In the child: files of at most 20 kB (beyond: EFBIG, as on a full disk; Python
    ignores SIGXFSZ)."""
    resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))


@pytest.mark.parametrize('old', [None, 'the old results\n'])
def test_a_disk_full_in_the_csv_leaves_the_old_file_or_none_never_a_cut_one(tmp_path, old):
    out = tmp_path / 'r.csv'  # the payload sweep's CSV has 48 kB
    if old is not None:
        out.write_text(old)
    done = run_cli(['sweep', 'payload', '--output', str(out), '--workers', '1', '--quiet'],
                   preexec_fn=small_file_limit)
    assert done.returncode == 1, done.stderr
    assert done.stderr == f'arm-sim sweep: cannot write {out}: File too large (EFBIG)\n'
    assert (out.read_text() if out.exists() else None) == old
    assert sorted(p.name for p in tmp_path.iterdir()) == ([] if old is None else ['r.csv'])


@pytest.mark.skipif(not Path('/dev/full').exists(), reason='needs /dev/full')
@pytest.mark.parametrize('text, lines', [(SMALL, 7), ('scenario: {hold: 0.1}', 2)],
                         ids=['12 kB: fails while written', '2 kB: fails when flushed'])
def test_json_to_a_full_disk_is_one_line_not_a_traceback(tmp_path, text, lines):
    spec = write_spec(tmp_path, text)
    with open('/dev/full', 'w') as full:
        done = subprocess.run([sys.executable, '-m', 'arm_sim.cli', 'sweep', str(spec),
                               '--json', '--workers', '1', '--quiet', '--output',
                               str(tmp_path / 'r.csv')],
                              stdout=full, stderr=subprocess.PIPE, text=True, timeout=120)
    assert done.returncode == 1
    assert done.stderr == ('arm-sim sweep: cannot write stdout: No space left on device '
                           '(ENOSPC) (the JSON is incomplete)\n')
    assert len((tmp_path / 'r.csv').read_text().splitlines()) == lines  # the CSV came first


@pytest.mark.parametrize('plot, message', [
    ('{x: law, y: [torque_peak_1]}', "plot: x: column 'law' holds text; x must be a number"),
    ('{x: payload, y: [torque_peak_1, status]}', "plot: y: column 'status' holds text"),
    ('{x: duration_requested, y: [torque_peak_1]}',
     "plot: x: column 'duration_requested' is 'fastest' in some scenarios"),
    ('{x: payload, y: [torque_peak_1, torque_peak_2, energy, samples, duration, index, '
     'payload, hold, energy]}', 'plot: y has 9 columns, more than 8 panels'),
    ('{x: index, y: [energy], by: hold}', "plot: by: 'hold' is drawn from a range"),
])
def test_a_plot_that_cannot_be_drawn_is_refused_before_the_run(tmp_path, capsys, monkeypatch,
                                                               plot, message):
    monkeypatch.setattr(sweep.cli, 'run_sweep', refuse_to_run)
    spec = write_spec(tmp_path, 'sweep: random\nsamples: 4\naxes: {payload: [0.0, 1.0], '
                      'duration: [fastest, 0.5], law: [pd, pid], hold: {uniform: [0.1, 0.2]}}'
                      f'\nplot: {plot}\n')
    assert main(['sweep', str(spec), '--quiet']) == 2
    err = capsys.readouterr().err
    assert err.startswith(f'arm-sim sweep: {spec}: ') and err.count('\n') == 1, err
    assert message in err, err


def test_a_grid_with_too_many_curves_is_refused_before_the_run(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sweep.cli, 'run_sweep', refuse_to_run)
    spec = write_spec(tmp_path, 'axes: {payload: {linspace: [0, 2, 51]}, hold: [0.1, 0.2]}\n'
                      'plot: {x: hold, y: [energy], by: payload}\n')
    assert main(['sweep', str(spec), '--quiet']) == 2
    assert "plot: by: 'payload' has 51 values, more than 50 curves" in capsys.readouterr().err


def test_the_default_plot_draws_curves_only_for_an_axis_of_few_values():
    spec = parse_spec({'sweep': 'random', 'samples': 3,
                       'axes': {'payload': {'uniform': [0, 2]},
                                'mass_error': {'uniform': [0, 0.2]}, 'law': ['pd', 'pid']}})
    # mass_error (a range: one curve per scenario) is passed over for law
    assert default_plot(spec) == PlotSpec(
        x='payload', y=('torque_peak_1', 'torque_peak_2', 'deviation_max'), by='law')


@pytest.mark.timeout(120)
def test_a_plot_failing_after_the_run_still_writes_the_csv_and_the_json(tmp_path, capsys):
    # 51 planned durations, each its own curve: known only after the run
    spec = write_spec(tmp_path, 'scenario: {hold: 0.02}\naxes: {duration: {linspace: [1.0, '
                      '2.0, 51]}}\nplot: {x: index, y: [energy], by: duration}\n')
    out, png = tmp_path / 'r.csv', tmp_path / 'r.png'
    assert main(['sweep', str(spec), '--quiet', '--json', '--output', str(out), '--plot',
                 str(png), '--workers', '1']) == 1
    captured = capsys.readouterr()
    assert captured.err == (f"arm-sim sweep: cannot draw {png}: ValueError: plot: by 'duration' "
                            'has 51 values, more than 50 curves\n')
    assert json.loads(captured.out)['scenarios'] == 51
    with open(out, newline='') as f:
        assert len(list(csv.reader(f))) == 52
    assert sorted(p.name for p in tmp_path.iterdir()) == ['r.csv', 'spec.yaml']


# ---------------------------------------------------------------------- interruption
def test_an_interrupt_stops_run_sweep_with_the_finished_rows():
    scenarios = MIX[:6]

    def interrupt(_count: int) -> None:
        raise KeyboardInterrupt

    with pytest.raises(sweep.SweepStopped) as exc:
        run_sweep(scenarios, workers=1, chunk_size=2, progress=interrupt)
    first = run_chunk(make_chunks(scenarios, 2)[0])
    assert exc.value.total == 6 and exc.value.reason is None
    assert [r['index'] for r in exc.value.rows] == sorted(r['index'] for r in first)


@pytest.mark.timeout(120)
def test_an_interrupt_terminates_the_worker_processes_at_once():
    """The first chunk is short, the others long (minutes in all): interrupted when the
    first is done, the sweep stops within seconds and no worker is left."""
    short = [Scenario(duration=0.3, hold=0.1, payload=p) for p in (0.0, 0.1)]
    long = [Scenario(duration=0.5, hold=3000.0, payload=0.1 * k) for k in range(2, 8)]
    stopped_at = []

    def interrupt(_count: int) -> None:
        stopped_at.append(time.monotonic())
        raise KeyboardInterrupt

    with pytest.raises(sweep.SweepStopped) as exc:
        run_sweep(short + long, workers=2, chunk_size=2, progress=interrupt)
    assert time.monotonic() - stopped_at[0] < 10.0
    assert [r['index'] for r in exc.value.rows] == [0, 1] and exc.value.total == 8
    assert multiprocessing.active_children() == []


def worker_manners(out) -> None:
    """In a forked child: the sweep's worker initializer, then what it set."""
    import ctypes

    sweep.run._worker_init(os.getppid())
    deathsig = ctypes.c_int(-1)
    ctypes.CDLL(None, use_errno=True).prctl(2, ctypes.byref(deathsig), 0, 0, 0)  # GET
    out.send((signal.getsignal(signal.SIGINT) == signal.SIG_IGN,
              signal.getsignal(signal.SIGTERM) == signal.SIG_DFL, deathsig.value))


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='prctl is Linux only')
def test_a_worker_leaves_ctrl_c_to_the_main_process_and_dies_with_it():
    """Ctrl-C reaches every process of the group: a worker ignores it (the main process
    stops the sweep and terminates the workers with SIGTERM, which a worker does not catch)
    and asks the kernel for SIGTERM when the main process dies."""
    ctx = multiprocessing.get_context('fork')
    mine, theirs = ctx.Pipe()
    child = ctx.Process(target=worker_manners, args=(theirs,))
    child.start()
    try:
        assert mine.poll(30), 'the child did not report'
        assert mine.recv() == (True, True, signal.SIGTERM)
    finally:
        child.join(10)
    assert child.exitcode == 0


def test_a_failing_chunk_stops_the_sweep_with_one_line_and_the_finished_rows(
        tmp_path, capsys, monkeypatch):
    real = sweep.run.run_chunk

    def fragile(items, keep_runs=False):  # SMALL's chunks of 2: [0, 2], [4], [1, 3], [5]
        if any(i == 4 for i, _ in items):
            raise RuntimeError('boom')
        return real(items, keep_runs)

    monkeypatch.setattr(sweep.run, 'run_chunk', fragile)
    spec, out = write_spec(tmp_path, SMALL), tmp_path / 'r.csv'
    assert main(['sweep', str(spec), '--quiet', '--workers', '1', '--chunk-size', '2',
                 '--output', str(out)]) == 1
    err = capsys.readouterr().err
    assert err == ('arm-sim sweep: stopped: a chunk of 1 scenario (index 4) failed: '
                   f'RuntimeError: boom: 2 of 6 scenarios finished; wrote {out}\n'), err
    with open(out, newline='') as f:
        table = list(csv.reader(f))
    assert tuple(table[0]) == COLUMNS and [r[0] for r in table[1:]] == ['0', '2']


LONG = """name: long
scenario: {hold: 20.0}
axes:
  payload: {linspace: [0.0, 2.0, 5000]}
"""
PROGRESS = r'^\[sweep\] (\d+)/5000 scenarios'


class SweepProcess:
    """``arm-sim sweep ARGS`` in a process group of its own; its stderr lines collected as
    they come."""

    def __init__(self, args: Sequence[str], stdout=subprocess.DEVNULL) -> None:
        self.proc = subprocess.Popen([sys.executable, '-m', 'arm_sim.cli', 'sweep', *args],
                                     stdout=stdout, stderr=subprocess.PIPE, text=True,
                                     start_new_session=True)
        self.lines: list[str] = []
        self.eof = False
        self.changed = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            with self.changed:
                self.lines.append(line.rstrip('\n'))
                self.changed.notify_all()
        with self.changed:
            self.eof = True
            self.changed.notify_all()

    def wait_for(self, pattern: str, timeout: float) -> re.Match:
        """The first stderr line matching ``pattern`` (fails at ``timeout`` s, or when
        stderr is closed without it)."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while True:
                for line in self.lines:
                    m = re.search(pattern, line)
                    if m:
                        return m
                left = deadline - time.monotonic()
                assert left > 0 and not self.eof, (
                    f'no line {pattern!r} (exit {self.proc.poll()}): {self.lines}')
                self.changed.wait(min(left, 0.5))

    def stop(self) -> None:
        """Kill whatever of the group is left (the test's cleanup)."""
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait(10)


def stat_of(pid: int) -> list[str] | None:
    """/proc/PID/stat after the command name (state first), or None if gone."""
    try:
        text = Path(f'/proc/{pid}/stat').read_text()
    except OSError:
        return None
    return text[text.rindex(')') + 2:].split()


def children(pid: int) -> dict[int, str]:
    """The running children of ``pid``: pid -> start time (tells a reused pid apart)."""
    out = {}
    for p in Path('/proc').iterdir():
        if not p.name.isdigit():
            continue
        st = stat_of(int(p.name))
        if st is not None and int(st[1]) == pid:
            out[int(p.name)] = st[19]
    return out


def running(pid: int, started: str) -> bool:
    st = stat_of(pid)
    return st is not None and st[19] == started and st[0] not in 'ZXx'


@pytest.mark.timeout(240)
@pytest.mark.parametrize('sig, output', [(signal.SIGINT, 'csv'), (signal.SIGTERM, 'json')],
                         ids=['SIGINT-csv', 'SIGTERM-json'])
def test_a_signal_stops_a_long_sweep_within_seconds_with_the_finished_rows(tmp_path, sig,
                                                                           output):
    """Ctrl-C reaches the whole process group (SIGINT to the group); ``kill`` sends SIGTERM
    to the main process. Either way the sweep of 5000 scenarios (minutes) stops within
    seconds, writes the rows finished and says how many."""
    spec, out, js = write_spec(tmp_path, LONG), tmp_path / 'r.csv', tmp_path / 'r.json'
    args = [str(spec), '--workers', '2', '--chunk-size', '8']
    args += ['--output', str(out)] if output == 'csv' else ['--json']
    with open(js, 'w') as stdout:
        run = SweepProcess(args, stdout=stdout)
        try:
            run.wait_for(PROGRESS, timeout=120)  # evidence that it runs: chunks finished
            workers = children(run.proc.pid)
            assert len(workers) == 2, workers
            done_before = max(int(m.group(1)) for line in run.lines
                              if (m := re.search(PROGRESS, line)))
            if sig == signal.SIGINT:
                os.killpg(run.proc.pid, sig)
            else:
                run.proc.send_signal(sig)
            code = run.proc.wait(timeout=10)
        finally:
            run.stop()
    name = signal.Signals(sig).name
    message = run.wait_for(rf'^arm-sim sweep: interrupted by {name}: (\d+) of 5000 scenarios '
                           r'finished; wrote (.*)$', timeout=5)
    assert code == 130
    assert not any('Traceback' in line for line in run.lines), run.lines
    finished = int(message.group(1))
    assert done_before <= finished < 5000
    if output == 'csv':
        assert message.group(2) == str(out)
        with open(out, newline='') as f:
            table = list(csv.reader(f))
        assert tuple(table[0]) == COLUMNS and len(table) == finished + 1
        assert all(len(r) == len(COLUMNS) and r[COLUMNS.index('status')] == 'ok'
                   for r in table[1:])
        index = [int(r[0]) for r in table[1:]]
    else:
        assert message.group(2) == 'the JSON (stdout)'
        doc = json.loads(js.read_text())
        assert doc['interrupted'] == {'signal': name, 'error': None, 'finished': finished,
                                      'total': 5000}
        assert doc['scenarios'] == len(doc['rows']) == finished
        index = [r['index'] for r in doc['rows']]
    assert index == sorted(set(index)) and 0 <= index[0] and index[-1] < 5000
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith('.partial')] == []
    assert not any(running(pid, started) for pid, started in workers.items())


@pytest.mark.timeout(240)
def test_killing_the_sweep_leaves_no_worker_running(tmp_path):
    run = SweepProcess([str(write_spec(tmp_path, LONG)), '--workers', '2', '--chunk-size',
                        '8'])
    try:
        run.wait_for(PROGRESS, timeout=120)
        workers = children(run.proc.pid)
        assert len(workers) == 2, workers
        run.proc.kill()  # SIGKILL: the main process has no say
        run.proc.wait(10)
        deadline = time.monotonic() + 10.0
        while (left := [p for p, s in workers.items() if running(p, s)]) and (
                time.monotonic() < deadline):
            time.sleep(0.05)
        assert left == [], f'workers still running 10 s after the main process died: {left}'
    finally:
        run.stop()
