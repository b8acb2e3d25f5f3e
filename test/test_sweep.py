"""``arm-sim sweep``: spec validation, the batch path against the nodes' single-state path,
the metrics against ``arm-sim analyze``, outputs, process pool and Dask (no ROS)."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from arm_bag.analysis import analyze
from arm_bag.synthetic import ROBOT as BAG_ROBOT
from arm_bag.synthetic import open_bag, write_run
from arm_common import cluster
from arm_control.laws import LAWS, ControlLaw, Gains, law_torque
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


@pytest.mark.parametrize('law', LAWS)
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
])
def test_a_bad_spec_is_one_line_naming_the_value_with_exit_2(tmp_path, capsys, text,
                                                             message):
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
