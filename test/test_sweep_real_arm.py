"""Sweeps of the real arm (motors, friction, sensors, delays): the sweep's plant is the
simulator core's, the friction sweep stops inside the band s / kp, the delay sweep goes
unstable where the linearised loop says (pure: no ROS)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from arm_sim.sweep import PF, PS, Scenario, load_spec, parse_spec, run_chunk, run_single
from arm_sim.sweep.columns import COLUMNS, REAL_COLUMNS
from arm_sim.sweep.run import run_core
from arm_sim.sweep.spec import SpecError, shipped_specs

#: config/real_arm.yaml's values.
REAL_ARM = dict(gear_ratios=(100.0, 80.0), motor_inertias=(1.2e-5, 6e-6),
                motor_damping=(1e-5, 1e-5), coulomb_friction=(1.5, 0.5),
                static_friction=(1.95, 0.65), position_noise=(4e-4, 4e-4),
                velocity_noise=(0.01, 0.01), encoder_resolution=(16384.0, 16384.0),
                sensing_delay=1, noise_seed=1)
REG = dict(task='regulation', start=PS, goal=PF, duration=1.0, hold=1.0)
#: Threshold of the peak-to-peak joint motion over the last half of the hold above which a
#: run counts as unstable [rad] (stable runs of delay_gain: < 1e-3; unstable: > 2e-3).
OSCILLATING = 1e-3


def _mixed() -> list[Scenario]:
    """Friction, motors and each sensor setting, under three laws, in one chunk."""
    out = [Scenario(**REG, law='pd_gravity', kp=(600.0, 300.0), kd=(60.0, 25.0), **REAL_ARM),
           Scenario(**REG, law='pd', kp=(600.0, 300.0), kd=(60.0, 25.0),
                    coulomb_friction=(1.5, 0.5)),
           Scenario(**REG, law='pd_gravity', kp=(400.0, 200.0), kd=(40.0, 20.0),
                    coulomb_friction=(3.0, 1.0), static_friction=(0.0, 1.5),
                    actuation_delay=2, encoder_resolution=(4096.0, 0.0)),
           Scenario(**REG, law='pd_gravity', kp=(600.0, 300.0), kd=(60.0, 25.0),
                    gear_ratios=(50.0, 50.0), motor_inertias=(2e-5, 2e-5),
                    position_noise=(1e-3, 0.0), velocity_noise=(0.0, 0.05), noise_seed=7),
           Scenario(start=PF, goal=PS, duration=0.8, hold=0.3, law='computed_torque',
                    kp=(100.0, 60.0), kd=(20.0, 12.0), **REAL_ARM),
           Scenario(start=PF, goal=PS, duration=0.8, hold=0.3, law='computed_torque',
                    kp=(100.0, 60.0), kd=(20.0, 12.0))]   # an ideal row among real ones
    return out


def test_a_real_arm_sweep_row_equals_the_simulator_core_run_bit_for_bit():
    # Tolerance: 0 (bit for bit). The batch's RK4 and inverse dynamics use numpy's cos/sin
    # where SimulatorCore's single arm uses math's; both are correctly rounded on this
    # platform for these arguments in practice, and the batched friction cases do
    # friction_step's operations in its order. Should a platform's libm differ, the state
    # would differ by rounding (1e-15) and could flip a stick/slip decision.
    scenarios = _mixed()
    for law in ('pd_gravity', 'pd', 'computed_torque'):
        chunk = [(i, s) for i, s in enumerate(scenarios) if s.law == law]
        rows, runs = run_chunk(chunk, keep_runs=True)
        for (i, s), row, run in zip(chunk, rows, runs):
            alone, ref = run_single(i, s, keep_run=True)  # SimulatorCore for a real arm
            assert run is not None and ref is not None
            for name in ('q', 'qd', 'effort', 'q_des'):
                assert np.array_equal(getattr(run, name), getattr(ref, name)), (i, name)
            for c in COLUMNS + REAL_COLUMNS:
                x, y = row[c], alone[c]
                assert x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y)), c


def test_the_core_run_uses_the_measurement_and_every_real_setting_changes_the_run():
    base = Scenario(**REG, law='pd_gravity', kp=(600.0, 300.0), kd=(60.0, 25.0))
    ideal = run_single(0, base, keep_run=True)[1]
    # gear_ratios alone changes nothing (n^2 times no rotor): with a rotor it does
    rotor = Scenario(**{**base.__dict__, 'motor_inertias': (1e-5, 1e-5)})
    geared = Scenario(**{**rotor.__dict__, 'gear_ratios': (50.0, 50.0)})
    assert not np.array_equal(run_chunk([(0, rotor)], keep_runs=True)[1][0].q,
                              run_chunk([(0, geared)], keep_runs=True)[1][0].q)
    for key, value in (('motor_inertias', (1e-5, 1e-5)),
                       ('motor_damping', (1e-4, 1e-4)), ('coulomb_friction', (1.0, 0.5)),
                       ('static_friction', (1.0, 0.5)), ('position_noise', (1e-3, 1e-3)),
                       ('velocity_noise', (0.1, 0.1)), ('encoder_resolution', (512.0, 512.0)),
                       ('sensing_delay', 1), ('actuation_delay', 1)):
        s = Scenario(**{**base.__dict__, key: value,
                        **({'gear_ratios': (10.0, 10.0)} if key.startswith('motor') else {})})
        assert s.real
        run = run_chunk([(0, s)], keep_runs=True)[1][0]
        assert run is not None and not np.array_equal(run.q, ideal.q), key


def test_friction_stops_pd_gravity_inside_the_band_static_over_kp():
    spec = load_spec(shipped_specs()['friction_gain'])
    scenarios = spec.scenarios()
    rows, runs = run_chunk(list(enumerate(scenarios)), keep_runs=True)
    assert len(rows) == 33
    for s, row, run in zip(scenarios, rows, runs):
        assert row['status'] == 'ok' and run is not None
        # come to rest: stuck (velocity exactly 0), or at low gains still creeping (an
        # overdamped joint approaches the Coulomb edge kp e = c only exponentially)
        assert np.abs(run.qd[-1]).max() <= 1e-3, s.kp
        for j in (1, 2):
            band = s.friction().static[j - 1] / s.kp[j - 1]
            assert row[f'friction_band_{j}'] == band
            # inside the band, to rounding (1e-12 rad): kp e + g_model - g = tau - g held
            assert abs(row[f'final_error_{j}']) <= band + 1e-12, (s.kp, j)
    # the band is reached, not just respected: some run stops in its outer half
    assert max(abs(r['final_error_1']) / r['friction_band_1'] for r in rows) > 0.5


def test_the_delay_sweep_goes_unstable_where_the_linearised_loop_predicts():
    spec = load_spec(shipped_specs()['delay_gain'])
    scenarios = spec.scenarios()
    rows = run_chunk(list(enumerate(scenarios)), margins=True)
    assert isinstance(rows, list)
    found: dict[int, list[tuple[float, bool, float]]] = {}
    for s, row in zip(scenarios, rows):
        unstable = row['status'] == 'diverged' or max(
            row['hold_oscillation_1'], row['hold_oscillation_2']) > OSCILLATING
        found.setdefault(s.actuation_delay, []).append(
            (s.kp[0], unstable, row['pole_radius']))
        # Tolerance on the boundary: a loop within 2% of |z| = 1 may take longer than the
        # hold to show which side it is on; every other point must agree.
        if abs(row['pole_radius'] - 1.0) > 0.02:
            assert unstable == (row['pole_radius'] > 1.0), (s.actuation_delay, s.kp)
    for delay, points in found.items():
        points.sort()
        predicted = next((kp for kp, _, r in points if r > 1.0), None)
        seen = next((kp for kp, u, _ in points if u), None)
        # the first unstable gain of the grid is the predicted one (grid step: x1.25)
        assert seen == predicted, (delay, seen, predicted)
    # more delay, unstable from a lower gain (delays 2 and 3 unstable over the whole grid)
    firsts = [next(kp for kp, u, _ in sorted(found[d]) if u) for d in sorted(found)]
    assert firsts == sorted(firsts, reverse=True) and firsts[0] > firsts[1]


@pytest.mark.parametrize('doc, message', [
    ({'scenario': {'static_friction': [1.0, 0.2], 'coulomb_friction': [1.5, 0.5]}},
     'static_friction[0] = 1 N m is below coulomb_friction[0] = 1.5 N m'),
    ({'scenario': {'encoder_resolution': 100.5}},
     'encoder_resolution must be whole counts per revolution'),
    ({'scenario': {'sensing_delay': 1.5}}, 'scenario.sensing_delay: sensing_delay must be '
     'an integer, got 1.5'),
    ({'axes': {'actuation_delay': [0, -1]}}, 'axes.actuation_delay: actuation_delay must '
     'be >= 0'),
    ({'scenario': {'gear_ratios': 0.0}}, 'scenario.gear_ratios: gear_ratios must be > 0'),
    ({'scenario': {'coulomb_friction': [1.0, -0.5]}}, 'coulomb_friction[1] must be >= 0 N m'),
    ({'scenario': {'noise_seed': True}}, 'noise_seed must be a number, got True'),
    ({'plot': {'x': 'kp_1', 'y': 'friction_band_1'}},
     "plot: column 'friction_band_1' needs a real-arm setting"),
])
def test_a_bad_real_arm_setting_is_one_line_naming_it(doc, message):
    with pytest.raises((SpecError, ValueError), match=None) as info:
        parse_spec(doc).scenarios()
    assert message in str(info.value) and '\n' not in str(info.value)


def test_real_arm_columns_appear_only_in_a_spec_that_gives_a_real_arm_setting():
    assert parse_spec({'scenario': REG | {'start': list(PS), 'goal': list(PF)}}).columns \
        == COLUMNS
    spec = parse_spec({'axes': {'sensing_delay': [0, 1, 2]}, 'margins': True})
    assert set(REAL_COLUMNS) <= set(spec.columns) and spec.columns[-1] == 'pole_radius'
    assert [s.sensing_delay for s in spec.scenarios()] == [0, 1, 2]


def test_the_core_run_reports_a_divergence_as_the_batch_does():
    s = Scenario(**REG, law='pd', kp=(1e5, 1e5), kd=(0.0, 0.0), actuation_delay=3,
                 effort_limits=(1e6, 1e6), coulomb_friction=(0.1, 0.1))
    row = run_chunk([(0, s)])[0]
    alone = run_single(0, s)
    assert row['status'] == alone['status'] == 'diverged'
    assert row['message'] == alone['message']
    assert run_core is not None
