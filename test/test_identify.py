"""Identification from bags (``arm-sim identify``, :mod:`arm_dynamics.identify`).

Pure tier: no ROS processes. The excitation runs through the closed loop the nodes run in
lockstep (the controller's computed-torque law with the NOMINAL model, the simulator's
held, saturated command and 1 ms RK4 on a plant carrying an unmodelled 1 kg tip payload:
:class:`~arm_dynamics.batch.BatchSimulator`, as the sweeps run it), written to a bag as the
recorder writes one (joint states with the effort held over the period ending there, the
robot record), and read back by ``arm-sim identify``.

The acceptance excitation is this module's :func:`multisine`: six sines per joint from 0.2
to 1.5 Hz, each joint its own frequencies and phases, amplitudes falling as 1/f (0.5 rad in
all), faded in and out over 1 s, about q = (1.0, 1.2) rad; 20 s. It stays within the
default effort limits (60, 20) N m with the payload. The planner's chirp
(arm_planner.excitation.chirp, the recipe docs/identify.md gives) is tested too.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from arm_bag.synthetic import open_bag, write_run
from arm_control.laws import law_torque
from arm_dynamics import identify as ident
from arm_dynamics.batch import BatchSimulator
from arm_dynamics.limits import DEFAULT_EFFORT
from arm_dynamics.robot import ROBOT_DEFAULTS
from arm_dynamics.two_link import TwoLinkArm, TwoLinkBatch
from arm_sim import identify_cli

NOMINAL = TwoLinkArm()          # the robot of config/arm.yaml
PAYLOAD = 1.0                   # kg at the tip, unknown to the controller
PERIOD_NS, STEP_NS = 10_000_000, 1_000_000   # control period, RK4 step
KP, KD = (100.0, 60.0), (20.0, 12.0)         # config/arm.yaml's computed-torque gains


# ---------------------------------------------------------------------- helpers
def multisine(t: np.ndarray, q0, amplitude, freqs, phases, fade: float = 1.0
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A multi-sine excitation about ``q0`` (2,) [rad]: for joint j, the sines of
    ``freqs[j]`` [Hz] with ``phases[j]`` [rad] and amplitudes proportional to 1/f, summing
    to ``amplitude[j]`` [rad], times a quintic fade in and out over ``fade`` [s] (so it
    starts and ends at rest at ``q0``). Returns q, qd, qdd (N, 2) at the times ``t`` (N,)
    [s], exactly differentiated."""
    dur = float(t[-1])
    w, wd, wdd = np.ones_like(t), np.zeros_like(t), np.zeros_like(t)
    for s, sign in ((t, 1.0), (dur - t, -1.0)):
        m = s < fade
        x = s[m] / fade
        w[m] = 10 * x ** 3 - 15 * x ** 4 + 6 * x ** 5
        wd[m] = sign * (30 * x ** 2 - 60 * x ** 3 + 30 * x ** 4) / fade
        wdd[m] = (60 * x - 180 * x ** 2 + 120 * x ** 3) / fade ** 2
    q, qd, qdd = (np.zeros((len(t), 2)) for _ in range(3))
    for j in range(2):
        om = 2 * np.pi * np.asarray(freqs[j], dtype=float)
        a = amplitude[j] * (1 / om) / np.sum(1 / om)
        arg = np.outer(t, om) + phases[j]
        s, sd, sdd = np.sin(arg) @ a, (np.cos(arg) * om) @ a, -(np.sin(arg) * om ** 2) @ a
        q[:, j] = q0[j] + w * s
        qd[:, j] = wd * s + w * sd
        qdd[:, j] = wdd * s + 2 * wd * sd + w * sdd
    return q, qd, qdd


def excitation(seed: int, q0=(1.0, 1.2), duration: float = 20.0, amplitude=(0.5, 0.5),
               fmax: float = 1.5):
    """(t, q_des, qd_des, qdd_des) of a random multi-sine (six sines per joint between
    0.2 Hz and ``fmax``, log-spaced, jittered by +-10 %, random phases)."""
    rng = np.random.default_rng(seed)
    t = np.arange(round(duration * 1e9 / PERIOD_NS) + 1) * (PERIOD_NS * 1e-9)
    freqs = [np.geomspace(0.2, fmax, 6) * rng.uniform(0.9, 1.1, 6) for _ in range(2)]
    phases = [rng.uniform(0, 2 * np.pi, 6) for _ in range(2)]
    return (t, *multisine(t, q0, amplitude, freqs, phases))


def closed_loop(plant: TwoLinkArm, model: TwoLinkArm, q_des, qd_des, qdd_des):
    """The lockstep closed loop: at each tick the computed-torque law (``model``) on the
    measured state, saturated at the effort limits, held over the period while ``plant``
    takes 1 ms RK4 steps. Returns q, qd, effort (N, 2); effort[k] the torque applied over
    the period ending at tick k (0 at the first state, as the simulator publishes it)."""
    n = len(q_des)
    lim = np.array([DEFAULT_EFFORT])
    sim = BatchSimulator([plant], q0=q_des[:1], qd0=qd_des[:1], effort_limits=lim,
                         physics_step_ns=STEP_NS, control_period_ns=PERIOD_NS,
                         velocity_limit=1000.0)
    batch = TwoLinkBatch([model])
    q, qd, effort = (np.zeros((n, 2)) for _ in range(3))
    q[0], qd[0] = sim.q[0], sim.qd[0]
    z = np.zeros((1, 2))
    for k in range(n - 1):
        raw, _ = law_torque('computed_torque', np.array([KP]), np.array([KD]), z, z, lim,
                            batch, z, sim.q, sim.qd, q_des[k:k + 1], qd_des[k:k + 1],
                            qdd_des[k:k + 1], PERIOD_NS * 1e-9)
        sim.advance(np.clip(raw, -lim, lim))
        q[k + 1], qd[k + 1], effort[k + 1] = sim.q[0], sim.qd[0], sim.applied[0]
    assert sim.alive.all()
    return q, qd, effort


def write_bag(path: Path, t, q, qd, effort, q_des, robot: dict | None = None) -> Path:
    """A bag as the recorder writes one: the robot record (the nominal robot parameters:
    the payload is unmodelled), joint states and the reference."""
    w, ch = open_bag(path, robot=dict(ROBOT_DEFAULTS) if robot is None else robot)
    write_run(w, ch, 1_000_000_000, t, q, qd, effort, q_des)
    w.close()
    return path


def excitation_bag(path: Path, seed: int, q0=(1.0, 1.2), payload: float = PAYLOAD) -> Path:
    t, q_des, qd_des, qdd_des = excitation(seed, q0)
    q, qd, effort = closed_loop(NOMINAL.with_payload(payload), NOMINAL, q_des, qd_des, qdd_des)
    return write_bag(path, t, q, qd, effort, q_des)


@pytest.fixture(scope='module')
def bags(tmp_path_factory) -> tuple[Path, Path]:
    """The identification bag and the held-out bag (another seed and configuration)."""
    d = tmp_path_factory.mktemp('identify')
    return excitation_bag(d / 'excite', 1), excitation_bag(d / 'holdout', 2, q0=(0.9, 1.0))


def random_states(rng, n=200):
    return (rng.uniform(-np.pi, np.pi, (n, 2)), rng.normal(0, 3, (n, 2)),
            rng.normal(0, 20, (n, 2)))


ARMS = (NOMINAL, NOMINAL.with_payload(1.0), NOMINAL.with_payload(2.7),
        TwoLinkArm(link_lengths=(0.7, 1.3), com_distances=(0.2, 0.9), link_masses=(5.0, 0.4),
                   link_inertias=(0.3, 0.01), gravity=3.7, joint_damping=(0.8, 0.25)))


# ---------------------------------------------------------------------- (a) the regressor
@pytest.mark.parametrize('arm', ARMS, ids=['nominal', 'payload1', 'payload2.7', 'other'])
def test_the_regressor_times_the_base_parameters_is_the_models_inverse_dynamics(arm):
    """Y(q, q', q'') pi(arm) = TwoLinkArm.inverse_dynamics to 1e-10 N m at 200 random
    states (|q''| ~ 20 rad/s^2, torques ~ 100 N m), for the nominal arm, with_payload's and
    an arm with other lengths, gravity and damping; likewise D q' (momentum) and the energy
    (kinetic + potential, TwoLinkArm.energy)."""
    q, qd, qdd = random_states(np.random.default_rng(7))
    l1, g0 = arm.link_lengths[0], arm.gravity
    pi = ident.base_parameters(arm)
    np.testing.assert_allclose(ident.regressor(q, qd, qdd, l1, g0) @ pi,
                               arm.inverse_dynamics(q, qd, qdd), rtol=0, atol=1e-10)
    np.testing.assert_allclose(ident.momentum_regressor(q, qd, l1) @ pi,
                               np.einsum('nij,nj->ni', arm.mass_matrix(q), qd), atol=1e-10)
    ke, pe = arm.energy(q, qd)
    np.testing.assert_allclose(ident.energy_regressor(q, qd, l1, g0) @ pi, ke + pe,
                               atol=1e-10)
    # tau = d/dt(D q') + n: with d/dt(D q') = D q'' + D' q' (D' from the model by
    # central differences along q', step 1e-6 s: error ~1e-9)
    h = 1e-6
    ddot = (arm.mass_matrix(q + h * qd) - arm.mass_matrix(q - h * qd)) / (2 * h)
    lhs = (np.einsum('nij,nj->ni', arm.mass_matrix(q), qdd)
           + np.einsum('nij,nj->ni', ddot, qd) + ident.rest_regressor(q, qd, l1, g0) @ pi)
    np.testing.assert_allclose(lhs, arm.inverse_dynamics(q, qd, qdd), atol=1e-7)


def test_a_tip_payload_moves_the_base_parameters_along_the_payload_direction():
    """pi(with_payload(p)) - pi = p (l1^2, l1, l2^2, l2, 0, 0) to 1e-12 (TwoLinkArm's own
    parallel-axis construction against the grouping)."""
    for arm in ARMS:
        for p in (0.3, 1.0, 4.0):
            np.testing.assert_allclose(
                ident.base_parameters(arm.with_payload(p)) - ident.base_parameters(arm),
                p * ident.payload_direction(arm), atol=1e-12)


def test_the_period_regressor_gives_the_torque_held_over_an_rk4_period():
    """One 10 ms period of TwoLinkArm.step (10 RK4 steps of 1 ms, torque held) from 200
    random states: the integrated momentum form of the end states gives back the held
    torque to 1e-6 of its size (the cubic Hermite + Gauss-Legendre quadrature, O(T^4);
    trapezoidal quadrature is ~100x worse here)."""
    rng = np.random.default_rng(3)
    arm = ARMS[3]
    q0 = rng.uniform(-np.pi, np.pi, (200, 2))
    qd0 = rng.normal(0, 2, (200, 2))
    tau = rng.normal(0, 5, (200, 2))
    q1, qd1 = TwoLinkBatch([arm] * 200).step(q0, qd0, tau, 1e-3, 10)
    periods = ident.HoldPeriods(q0, qd0, q1, qd1, np.full(200, 0.01), tau,
                                np.arange(200) * PERIOD_NS)
    got = ident.predict(ident.base_parameters(arm), periods, arm.link_lengths[0], arm.gravity)
    assert np.abs(got - tau).max() < 1e-6 * np.abs(tau).max()


def test_hold_periods_pair_states_one_period_apart_and_skip_gaps_and_repeats():
    """A lost state (a 20 ms gap: two torques held) and a re-sent state (same stamp) give no
    period; each period takes the effort of its end state."""
    stamps = np.array([0, 10, 20, 20, 40, 50]) * 1_000_000
    q = np.arange(12, dtype=float).reshape(6, 2)
    p = ident.hold_periods(stamps, q, q + 100, q + 200)
    assert p.end_ns.tolist() == [10_000_000, 20_000_000, 50_000_000]
    np.testing.assert_array_equal(p.tau, (q + 200)[[1, 2, 5]])
    np.testing.assert_array_equal(p.q0, q[[0, 1, 4]])
    assert np.allclose(p.period, 0.01)


# ---------------------------------------------------------------------- (b) acceptance
def test_identify_recovers_an_unmodelled_1kg_tip_payload_from_a_bag(bags, capsys):
    """ACCEPTANCE. The 20 s excitation through the closed loop (computed torque with the
    nominal model, the plant carrying 1 kg at the tip), recorded to a bag; ``arm-sim
    identify BAG --holdout OTHER --json``.

    Measured here: payload 1.0000000 kg, error ~6e-10 kg (tolerance 0.02 kg); every base
    parameter within ~3e-9 of the true arm's (tolerance 1e-5); regressor condition number
    2.1 (columns scaled); held-out bag (another seed, about q = (0.9, 1.0) rad): torque
    prediction error ~1e-8 N m RMS per joint, ~1e-7 % of the RMS torque (tolerance 0.1 %),
    where the nominal model is off by ~7.0 / 5.3 N m = 33 / 59 %.
    """
    excite, holdout = bags
    code = identify_cli.main([str(excite), '--holdout', str(holdout), '--json'])
    out = capsys.readouterr()
    assert code == 0, out.err
    doc = json.loads(out.out)
    true = ident.base_parameters(NOMINAL.with_payload(PAYLOAD))
    est = np.array([p['estimate'] for p in doc['parameters']])
    nominal = np.array([p['nominal'] for p in doc['parameters']])
    np.testing.assert_allclose(nominal, ident.base_parameters(NOMINAL), atol=1e-12)
    np.testing.assert_allclose(est, true, atol=1e-5)
    assert abs(doc['payload_kg']['estimate'] - PAYLOAD) < 0.02
    assert doc['condition_number'] < 10
    hold = doc['holdout']
    assert max(hold['rms_error_percent']) < 0.1
    assert min(hold['nominal_rms_error_percent']) > 10     # the payload is not small
    # the text form says the same
    code = identify_cli.main([str(excite), '--holdout', str(holdout)])
    text = capsys.readouterr().out
    assert code == 0
    assert 'tip payload over the nominal arm: 1.0000 kg' in text
    assert 'held-out check' in text and 'nominal model' in text


def test_the_planners_chirp_excitation_identifies_the_payload_too(tmp_path, capsys):
    """The recipe docs/identify.md gives a user: arm_planner.excitation.chirp (the planner's
    chirp mode), both joints, 0.2 rad, log sweep 0.2-1.5 Hz, 20 s about q = (1.0, 1.2) rad,
    with the 1 kg payload. Both joints move with the same signal and the elbow saturates
    ~13 % of the time (the bag holds the applied torque, so that does no harm). Measured:
    payload error ~2e-9 kg (tolerance 0.02 kg), condition number 3.4."""
    excitation_module = pytest.importorskip('arm_planner.excitation')
    t = np.arange(2001) * (PERIOD_NS * 1e-9)
    q_des, qd_des, qdd_des = excitation_module.chirp(
        t, centre=(1.0, 1.2), amplitude=0.2, f0=0.2, f1=1.5, duration=20.0,
        period=PERIOD_NS * 1e-9)
    q, qd, effort = closed_loop(NOMINAL.with_payload(PAYLOAD), NOMINAL, q_des, qd_des, qdd_des)
    bag = write_bag(tmp_path / 'chirp', t, q, qd, effort, q_des)
    assert identify_cli.main([str(bag), '--json']) == 0
    doc = json.loads(capsys.readouterr().out)
    assert abs(doc['payload_kg']['estimate'] - PAYLOAD) < 0.02
    assert doc['condition_number'] < 10


def test_the_standard_errors_are_honest_under_torque_noise(bags):
    """With Gaussian noise on the recorded torque (0.5 N m, both joints: the least-squares
    assumption), 20 noise draws on the same bag: the payload's spread across draws matches
    its reported standard error (ratio 0.5-2; measured 1.13, SE 0.0013 kg) and the estimates
    scatter about the truth (|mean error| < 3 SE / sqrt(20))."""
    from arm_bag.reader import read_bag

    js = read_bag(bags[0]).joint_states
    assert js is not None
    clean = ident.hold_periods(js.stamp, js.position, js.velocity, js.effort)
    rng = np.random.default_rng(11)
    masses, ses = [], []
    for _ in range(20):
        noisy = ident.HoldPeriods(clean.q0, clean.qd0, clean.q1, clean.qd1, clean.period,
                                  clean.tau + rng.normal(0, 0.5, clean.tau.shape),
                                  clean.end_ns)
        est = ident.identify(noisy, NOMINAL.link_lengths[0], NOMINAL.gravity)
        m, se = ident.payload_mass(est, NOMINAL)
        masses.append(m)
        ses.append(se)
    spread, se = float(np.std(masses, ddof=1)), float(np.mean(ses))
    assert 0.5 < spread / se < 2.0
    assert abs(np.mean(masses) - PAYLOAD) < 3 * se / np.sqrt(20)
    assert se < 0.02


# ---------------------------------------------------------------------- (c) params file
def _controller_model(params_file: Path) -> TwoLinkArm:
    """The controller's model from a params file, the way the controller node builds it
    (ControllerNode.__init__): its /** and /**/controller sections resolved against
    ROBOT_PARAMS + CONTROL_PARAMS by arm_common.params.resolve (the node's start-up
    check), then ``control_model.<key> or <key>``."""
    from arm_common.params import resolve
    from arm_control.controller_node import CONTROL_PARAMS
    from arm_control.model_params import controller_model
    from arm_dynamics.models import joint_count
    from arm_dynamics.robot import ROBOT_PARAMS

    data = yaml.safe_load(params_file.read_text())
    given = {**data['/**']['ros__parameters'], **data['/**/controller']['ros__parameters']}
    specs = ROBOT_PARAMS + CONTROL_PARAMS
    names = {s.name for s in specs}
    p = resolve(specs, {k: v for k, v in given.items() if k in names}, joint_count)
    model = controller_model(p)
    assert isinstance(model, TwoLinkArm)
    return model


def _line_deviation(control_model: str | dict | None, gains: dict) -> float:
    """deviation_max [m] of the payload sweep's scenario (config/sweeps/payload.yaml: the
    1 s line Pf -> Ps, 1 kg at the tip) with the sweep's ``control_model`` setting (a
    params file, a mapping of model parameters; None: the nominal model), through the
    sweep's own closed loop and metric (arm_sim.sweep.run_chunk)."""
    from arm_sim.sweep import Scenario, load_spec, run_chunk, shipped_specs

    spec = load_spec(shipped_specs()['payload'])
    scenario = Scenario(**{**spec.scenario, 'payload': PAYLOAD, 'law': 'computed_torque',
                           'control_model': control_model, **gains})
    (row,) = run_chunk([(0, scenario)])
    assert row['status'] == 'ok', row['message']
    return float(row['deviation_max'])


def test_the_params_file_loads_into_the_controller_and_fixes_the_payload_sweep(
        bags, tmp_path, capsys):
    """The params file ``--params-out`` writes passes the controller's own parameter
    checks (CONTROL_PARAMS via arm_common.params.resolve) and gives the controller a model
    with the true arm's base parameters; run through the payload sweep's closed loop (1 s
    line, 1 kg payload, config/sweeps/payload.yaml's two computed-torque variants), the
    line deviation with it is within 10 % of the correct model's (the plant itself), and
    the nominal model's is far larger.

    Measured: kp (100, 60): nominal 483.21 mm, identified 1.4149 mm, correct 1.4149 mm
    (difference ~1e-8 relative); kp (400, 400): nominal 87.13 mm, identified 0.5815 mm,
    correct 0.5815 mm.
    """
    out = tmp_path / 'identified.yaml'
    assert identify_cli.main([str(bags[0]), '--params-out', str(out)]) == 0
    assert f'wrote {out}' in capsys.readouterr().out
    model = _controller_model(out)
    plant = NOMINAL.with_payload(PAYLOAD)
    np.testing.assert_allclose(ident.base_parameters(model), ident.base_parameters(plant),
                               atol=1e-5)
    assert model.link_masses[1] == pytest.approx(plant.link_masses[1], abs=0.02)
    spec_gains = [dict(kp=(100.0, 60.0), kd=(20.0, 12.0)), dict(kp=(400.0, 400.0),
                                                               kd=(40.0, 40.0))]
    for gains in spec_gains:
        before = _line_deviation(None, gains)
        after = _line_deviation(str(out), gains)   # the params file, as a sweep reads it
        correct = _line_deviation({k: np.asarray(getattr(plant, k)).tolist()
                                   for k in identify_cli.MODEL_KEYS}, gains)
        assert abs(after - correct) <= 0.10 * correct, (before, after, correct)
        assert before > 10 * correct, (before, after, correct)


def test_the_params_file_keeps_the_base_file_and_sets_only_the_controller_model(
        bags, tmp_path):
    """--nominal FILE is the base of --params-out: every other parameter as in it."""
    base = Path(__file__).resolve().parents[1] / 'config' / 'arm.yaml'
    out = tmp_path / 'p.yaml'
    assert identify_cli.main([str(bags[0]), '--nominal', str(base), '--params-out',
                              str(out)]) == 0
    a, b = yaml.safe_load(base.read_text()), yaml.safe_load(out.read_text())
    extra = {k: v for k, v in b['/**/controller']['ros__parameters'].items()
             if k.startswith('control_model.')}
    assert set(extra) == {f'control_model.{k}' for k in identify_cli.MODEL_KEYS}
    for k in extra:
        del b['/**/controller']['ros__parameters'][k]
    assert a == b


# ---------------------------------------------------------------------- (d) errors
def _error(capsys, argv: list[str]) -> tuple[int, str]:
    code = identify_cli.main(argv)
    err = capsys.readouterr().err
    assert 'Traceback' not in err
    return code, err


def test_a_missing_bag_is_one_line_and_exit_4(capsys, tmp_path):
    code, err = _error(capsys, [str(tmp_path / 'nope')])
    assert code == 4
    assert err.count('\n') == 1 and err.startswith('arm-sim identify: ')
    assert 'nope' in err


def test_a_bag_with_no_motion_is_one_line_and_exit_3(capsys, tmp_path):
    """The arm held at rest: nothing but gravity; the message names what is not excited."""
    n = 300
    t = np.arange(n) * 0.01
    q = np.tile([0.3, 1.0], (n, 1))
    tau = np.tile(NOMINAL.gravity_vector(q[0]), (n, 1))
    bag = write_bag(tmp_path / 'still', t, q, np.zeros((n, 2)), tau, q)
    code, err = _error(capsys, [str(bag)])
    assert code == 3
    assert err.count('\n') == 1 and 'does not excite' in err and 'ZZ1R' in err


def test_a_bag_without_velocities_is_refused(capsys, tmp_path):
    n = 50
    t = np.arange(n) * 0.01
    q = np.tile([0.3, 1.0], (n, 1))
    bag = write_bag(tmp_path / 'nan', t, q, np.full((n, 2), np.nan), q, q)
    code, err = _error(capsys, [str(bag)])
    assert code == 3 and err.count('\n') == 1 and 'velocity' in err


def test_an_unwritable_params_out_is_one_line_and_exit_2_before_any_work(
        capsys, tmp_path, bags):
    blocker = tmp_path / 'file'
    blocker.write_text('')
    for target in (blocker / 'out.yaml', tmp_path):   # under a file; a directory
        code, err = _error(capsys, [str(bags[0]), '--params-out', str(target)])
        assert code == 2 and err.count('\n') == 1 and '--params-out' in err
    code, err = _error(capsys, [str(bags[0]), '--plot', str(tmp_path / 'x.nosuchformat')])
    assert code == 2 and err.count('\n') == 1


def test_a_bad_nominal_file_is_one_line_and_exit_2(capsys, tmp_path, bags):
    bad = tmp_path / 'bad.yaml'
    bad.write_text("/**:\n  ros__parameters:\n    link_masses: [2.0, -1.0]\n")
    code, err = _error(capsys, [str(bags[0]), '--nominal', str(bad)])
    assert code == 2 and err.count('\n') == 1 and 'link_masses' in err
    code, err = _error(capsys, [str(bags[0]), '--nominal', str(tmp_path / 'none.yaml')])
    assert code == 2 and err.count('\n') == 1


def test_help_names_the_units(capsys):
    assert identify_cli.main(['--help']) == 0
    text = capsys.readouterr().out
    for unit in ('kg m^2', 'kg m', 'N m s/rad', '[kg]', 'N m RMS'):
        assert unit in text


def test_the_plot_is_written(bags, tmp_path, capsys):
    out = tmp_path / 'id.png'
    assert identify_cli.main([str(bags[0]), '--holdout', str(bags[1]), '--plot',
                              str(out)]) == 0
    assert out.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_the_subcommand_registers_in_a_parser():
    """add_identify_parser adds ``identify`` to an arm-sim-like parser (what arm_sim.cli
    will call)."""
    import argparse

    parser = argparse.ArgumentParser(prog='arm-sim')
    sub = parser.add_subparsers(dest='command', required=True)
    identify_cli.add_identify_parser(sub)
    args = parser.parse_args(['identify', 'a', 'b', '--holdout', 'c', '--json'])
    assert args.func is identify_cli.run_identify
    assert args.bags == ['a', 'b'] and args.holdout == 'c' and args.json
