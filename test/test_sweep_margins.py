"""Sweep columns of stability margins (``margins: true``) and a controller model from a
params file or a mapping (``control_model``). Pure tier: no ROS processes."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from arm_control.closed_loop import closed_loop, loop_margins
from arm_control.laws import Gains
from arm_sim import sweep
from arm_sim.cli import main
from arm_sim.sweep import COLUMNS, Scenario, SpecError, load_spec, parse_spec, run_chunk
from arm_sim.sweep.columns import MARGIN_COLUMNS
from arm_sim.sweep.margins import POINTS, refined_margins, scenario_margins
from arm_sim.sweep.plan import plan_scenario

REG = dict(task='regulation', start=(1.4782, 0.1845), goal=(0.5, 1.2), hold=0.3)


def write(tmp_path: Path, text: str, name: str = 'spec.yaml') -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


# ---------------------------------------------------------------------- margins
CASES = [
    Scenario(**REG, law='pd', kp=(100.0, 60.0), kd=(20.0, 12.0)),
    Scenario(**REG, law='computed_torque', kp=(400.0, 200.0), kd=(12.0, 30.0), payload=0.7,
             mass_error=0.2, length_error=-0.05),
    Scenario(**REG, law='pd_gravity', kp=(300.0, 100.0), kd=(10.0, 3.0), payload=1.5,
             control_rate=200.0, physics_step=0.0005),
    Scenario(**REG, law='pid', kp=(600.0, 300.0), kd=(60.0, 25.0), ki=(300.0, 150.0)),
]


@pytest.mark.parametrize('s', CASES, ids=[s.law for s in CASES])
def test_margin_columns_are_loop_margins_of_the_scenarios_closed_loop(s):
    """Each scenario's columns equal loop_margins(closed_loop(...)) built here from its law,
    gains, plant (payload), controller's model (errors) and control period, about the goal's
    joint angles: within 0.1 deg and 0.1 dB, the bandwidth within 0.1 %."""
    (row,) = run_chunk([(0, s)], margins=True)
    assert row['status'] == 'ok', row['message']
    q_goal = s.plant().inverse_kinematics(np.array(s.goal), 'down')
    loop = closed_loop(s.law, Gains(kp=s.kp, kd=s.kd, ki=s.ki, i_clamp=s.i_clamp),
                       s.plant(), q_goal, 1.0 / s.control_rate, model=s.model())
    for j, m in enumerate(loop_margins(loop), start=1):
        assert row[f'phase_margin_{j}'] == pytest.approx(m.phase_deg, abs=0.1)
        assert row[f'bandwidth_{j}'] == pytest.approx(m.gain_crossover, rel=1e-3)
        if math.isfinite(m.gain_db):
            assert row[f'gain_margin_{j}'] == pytest.approx(m.gain_db, abs=0.1)
        else:
            assert row[f'gain_margin_{j}'] == m.gain_db
        assert 0.0 < row[f'phase_margin_{j}'] < 90.0


def test_400_points_refined_agree_with_6000_points_within_0_1_deg_and_0_1_db():
    """refined_margins (400 log-spaced points + 32 in each interval with a crossing) vs
    loop_margins' 6000 points over a grid of laws and gains, with and without a period
    of delay (which makes the gain margins finite)."""
    plant = sweep.ROBOT.with_payload(0.5)
    model = sweep.ROBOT.with_errors(0.1, 0.0)
    q = plant.inverse_kinematics(np.array([0.5, 1.2]), 'down')
    checked = finite = 0
    for law in ('pd', 'computed_torque', 'pd_gravity', 'pid'):
        for kp in (20.0, 200.0, 900.0):
            for kd in (4.0, 20.0, 60.0):
                for delay in (0, 1):
                    g = Gains(kp=(kp, kp / 2), kd=(kd, kd / 2), ki=(kp / 2, kp / 4))
                    loop = closed_loop(law, g, plant, q, 0.01, model=model, delay=delay)
                    fast, full = refined_margins(loop), loop_margins(loop)
                    assert POINTS == 400
                    for a, b in zip(fast, full):
                        for k, tol in (('phase_deg', 0.1), ('gain_db', 0.1),
                                       ('lower_gain_db', 0.1)):
                            x, y = getattr(a, k), getattr(b, k)
                            if math.isfinite(y):
                                assert x == pytest.approx(y, abs=tol), (law, kp, kd, k)
                                finite += k == 'gain_db'
                            else:
                                assert x == y or (math.isnan(x) and math.isnan(y))
                        checked += 1
    assert checked == 4 * 3 * 3 * 2 * 2 and finite > 20


def test_a_law_without_linearisation_is_nan_with_the_reason(monkeypatch):
    monkeypatch.setattr(sweep.margins, 'LINEAR_LAWS', ('pd',))
    (row,) = run_chunk([(0, CASES[3])], margins=True)
    assert row['status'] == 'ok'
    assert all(math.isnan(row[c]) for c in MARGIN_COLUMNS)
    assert row['message'] == "margins: no linearisation of law 'pid'"


def test_an_unstable_linearised_loop_says_so_in_the_message():
    s = Scenario(**REG, law='pd', kp=(100.0, 60.0), kd=(20.0, 80.0))  # kd T too large
    values, note = scenario_margins(s, plan_scenario(s).set_point)
    assert note and 'unstable' in note and '|z|' in note


def test_a_spec_without_margins_has_exactly_the_columns_it_had(tmp_path, capsys):
    spec = parse_spec({'scenario': REG, 'axes': {'law': ['pd', 'computed_torque']}})
    assert not spec.margins and spec.columns == COLUMNS
    assert not set(MARGIN_COLUMNS) & set(run_chunk([(0, spec.scenarios()[0])])[0])
    path = write(tmp_path, yaml.safe_dump({'scenario': {**REG, 'start': list(REG['start']),
                                                        'goal': list(REG['goal'])}}))
    out = tmp_path / 'r.csv'
    assert main(['sweep', str(path), '--output', str(out), '--json', '--quiet',
                 '--workers', '1']) == 0
    assert json.loads(capsys.readouterr().out)['columns'] == list(COLUMNS)
    with open(out, newline='') as f:
        assert tuple(next(csv.reader(f))) == COLUMNS


@pytest.mark.parametrize('text, message', [
    ('margins: yes please', "margins must be true or false (true: add the stability-margin "
     "columns), got 'yes please'"),
    ('margins: 1', 'margins must be true or false'),
    ('plot: {x: kp_1, y: phase_margin_1}', "plot: column 'phase_margin_1' needs 'margins: "
     "true'"),
    ('scenario: {control_model: {link_mass: [1, 2]}}',
     "scenario.control_model: key 'link_mass' unknown (known: link_lengths"),
    ('scenario: {control_model: {link_masses: [2.0, -3.5]}}',
     'scenario.control_model: control_model.link_masses must be >= 0 kg, got -3.5'),
    ('scenario: {control_model: {link_masses: [2.0, 3.5, 1.0]}}',
     'control_model.link_masses has 3 values but the robot has 2 joints'),
    ('scenario: {control_model: missing.yaml}',
     'scenario.control_model: missing.yaml: cannot read it: No such file or directory'),
    ('scenario: {control_model: 7}',
     'scenario.control_model: must be a params file (FILE.yaml) or a mapping'),
    ('scenario: {control_model: {link_masses: [2, 3]}, mass_error: 0.1}',
     "control_model (in scenario) and mass_error both set the controller's model"),
    ('scenario: {length_error: 0.1}\naxes: {variant: [{control_model: {link_masses: [2, 3]}}]}',
     "control_model (in axes.variant[0]) and length_error both set"),
    ('axes: {control_model: {link_masses: [2, 3]}}',
     'axes.control_model: must be a list of models'),
])
def test_bad_margins_and_control_model_values_are_one_line_with_exit_2(
        tmp_path, capsys, monkeypatch, text, message):
    monkeypatch.setattr(sweep.cli, 'run_sweep', lambda *a, **k: pytest.fail('ran'))
    path = write(tmp_path, text)
    assert main(['sweep', str(path), '--quiet']) == 2
    err = capsys.readouterr().err
    assert err.startswith(f'arm-sim sweep: {path}: ') and err.count('\n') == 1, err
    assert message in err, err


def test_the_shipped_margins_spec_loads_and_a_tiny_version_runs(tmp_path, capsys):
    spec = load_spec(sweep.shipped_specs()['margins'])
    assert spec.margins and spec.plot is not None and 'phase_margin_1' in spec.plot.y
    assert len(spec.scenarios()) >= 20
    doc = yaml.safe_load(sweep.shipped_specs()['margins'].read_text())
    doc['axes'] = {'kp': [9.0, 900.0], 'kd': [24.0]}
    doc['scenario']['hold'] = 0.5
    path = write(tmp_path, yaml.safe_dump(doc))
    out, png = tmp_path / 'm.csv', tmp_path / 'm.png'
    assert main(['sweep', str(path), '--output', str(out), '--plot', str(png), '--quiet',
                 '--workers', '1']) == 0
    with open(out, newline='') as f:
        table = list(csv.DictReader(f))
    assert tuple(table[0]) == COLUMNS + MARGIN_COLUMNS
    pm = [float(r['phase_margin_1']) for r in table]
    assert 0 < pm[1] < pm[0] < 90  # higher kp, less phase margin
    assert all(r['gain_margin_1'] in ('inf',) or float(r['gain_margin_1']) > 0 for r in table)
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_margin_columns_reach_the_json_with_infinity_as_a_string(tmp_path, capsys):
    path = write(tmp_path, 'margins: true\nscenario: {task: regulation, law: pd, hold: 0.2}\n')
    assert main(['sweep', str(path), '--json', '--quiet', '--workers', '1']) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc['columns'][-len(MARGIN_COLUMNS):] == list(MARGIN_COLUMNS)
    (row,) = doc['rows']
    assert isinstance(row['phase_margin_1'], float)
    assert row['gain_margin_1'] == 'inf' or isinstance(row['gain_margin_1'], float)


# ---------------------------------------------------------------------- control_model
def test_the_sweeps_control_model_specs_are_the_controllers():
    from arm_control.controller_node import CONTROL_PARAMS

    assert all(any(p is q for q in CONTROL_PARAMS) for p in sweep.spec.CONTROL_MODEL_PARAMS), \
        'one table, shared'


def params_file(tmp_path: Path, controller: dict, robot: dict | None = None) -> Path:
    doc = {'/**': {'ros__parameters': robot or {}},
           '/**/controller': {'ros__parameters': {'law': 'computed_torque', **controller}}}
    return write(tmp_path, yaml.safe_dump(doc), 'params.yaml')


def test_a_control_model_file_or_mapping_is_the_controllers_model(tmp_path):
    plant = sweep.ROBOT.with_payload(1.0)
    values = {f'control_model.{k}': list(getattr(plant, k)) for k in sweep.spec.MODEL_KEYS}
    params_file(tmp_path, values)
    spec_path = write(tmp_path, 'scenario: {control_model: params.yaml, payload: 1.0}\n'
                      'axes: {kp: [100, 400]}\n')  # relative to the spec's folder
    spec = load_spec(spec_path)
    assert spec.uses_control_model and spec.columns[-1] == 'control_model'
    for s in spec.scenarios():
        m = s.model()
        for k in sweep.spec.MODEL_KEYS:
            np.testing.assert_allclose(getattr(m, k), getattr(plant, k), rtol=1e-15)
        assert m.gravity == plant.gravity
    rows = run_chunk([(i, s) for i, s in enumerate(spec.scenarios())])
    assert [r['control_model'] for r in rows] == ['params.yaml'] * 2
    assert all(math.isnan(r['mass_error']) and math.isnan(r['length_error']) for r in rows)
    # the correct model tracks far better than the nominal one (payload unmodelled)
    nominal = run_chunk([(0, Scenario(**REG, payload=1.0))])[0]
    correct = run_chunk([(0, Scenario(**REG, payload=1.0, control_model={
        'link_masses': list(plant.link_masses), 'com_distances': list(plant.com_distances),
        'link_inertias': list(plant.link_inertias)}))])[0]
    assert correct['control_model'] == 'inline'
    assert abs(correct['final_error_1']) < 0.1 * abs(nominal['final_error_1'])


def test_a_params_file_without_a_controller_model_or_with_bad_values_is_refused(tmp_path):
    params_file(tmp_path, {})
    with pytest.raises(SpecError, match='sets no /\\*\\*/controller control_model'):
        parse_spec({'scenario': {'control_model': 'params.yaml'}}, base=tmp_path)
    params_file(tmp_path, {'control_model.link_masses': [2.0, 'x']})
    with pytest.raises(SpecError, match="params.yaml: .*control_model.link_masses"):
        parse_spec({'scenario': {'control_model': 'params.yaml'}}, base=tmp_path)
    params_file(tmp_path, {'control_model.link_masses': [2.0, 3.0]},
                robot={'link_lengths': [1.0, -0.8]})
    with pytest.raises(SpecError, match="link_lengths"):
        parse_spec({'scenario': {'control_model': 'params.yaml'}}, base=tmp_path)
    with pytest.raises(ValueError, match='both set the controller'):
        Scenario(mass_error=0.1, control_model={'link_masses': [2.0, 3.0]})
