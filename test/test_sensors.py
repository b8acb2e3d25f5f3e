"""Sensors and actuators of the simulated arm (issue 23, "Sensors"): the measurement model
(:mod:`arm_dynamics.sensors`), the actuation delay in :class:`SimulatorCore`, the true state
in bags and analysis, and one process-level run of the simulator node.

Every effect is checked against an independent derivation: sample statistics against the
setting, quantisation against the definition of a count, delays against a shifted series
and a hand-rolled loop of ``TwoLinkArm.step``; the defaults against the core without the
module, bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from arm_bag.analysis import analyze
from arm_bag.msgdefs import QosProfile, qos_yaml, schema_text, type_hash
from arm_bag.reader import read_bag
from arm_bag.synthetic import joint_state_block, open_bag, write_run
from arm_dynamics import TwoLinkArm
from arm_dynamics.sensors import ActuationDelay, SensorModel, measure_series
from arm_dynamics.simulation import SimulatorCore

ARM = TwoLinkArm()
LIMITS = [60.0, 20.0]
STEP_NS, PERIOD_NS = 1_000_000, 10_000_000
NAMES = ['joint1', 'joint2']
Q0 = np.array([-0.4, 1.2])
GOAL = np.array([0.3, 0.6])


def make_core(**kw) -> SimulatorCore:
    return SimulatorCore(ARM, q0=Q0, qd0=[0.0, 0.0], effort_limits=LIMITS,
                         physics_step_ns=STEP_NS, control_period_ns=PERIOD_NS,
                         velocity_limit=1000.0, joint_names=NAMES, **kw)


def pd(q, qd) -> np.ndarray:
    """A closed-loop command from a (measured) state: PD plus gravity towards GOAL."""
    return 100.0 * (GOAL - np.asarray(q)) - 20.0 * np.asarray(qd) + ARM.gravity_vector(q)


def closed_loop(core: SimulatorCore, periods: int):
    """Lockstep as the node runs it: the command answering each published state (the
    measurement) is computed from it, then one period is integrated. Returns the published
    (q, qd, effort) and the true (q, qd), each (periods + 1, 2)."""
    pub, true = [], []
    for k in range(periods + 1):
        view, tv = core.joint_view(), core.true_view()
        pub.append((view.position, view.velocity, view.effort))
        true.append((tv.position, tv.velocity))
        if k < periods:
            core.command = pd(view.position, view.velocity)
            core.advance()
    q, qd, tau = (np.array([p[i] for p in pub]) for i in range(3))
    return q, qd, tau, np.array([t[0] for t in true]), np.array([t[1] for t in true])


# ---------------------------------------------------------------------- the measurement
N_SAMPLES = 2000


@pytest.mark.parametrize('seed', [0, 1, 12345])
def test_noise_has_the_set_standard_deviation_and_zero_mean(seed):
    """2,000 states: each joint's sample standard deviation of (measured - true) within 5%
    of its setting, and its mean within 3 standard errors (sigma / sqrt(N)) of zero."""
    sq, sqd = np.array([0.01, 0.002]), np.array([0.1, 0.05])
    rng = np.random.default_rng(999)  # true states: any motion, independent of the noise
    q = rng.uniform(-3, 3, (N_SAMPLES, 2))
    qd = rng.uniform(-5, 5, (N_SAMPLES, 2))
    qm, qdm = measure_series(q, qd, position_noise=sq, velocity_noise=sqd, seed=seed)
    for err, sigma in ((qm - q, sq), (qdm - qd, sqd)):
        std = err.std(axis=0, ddof=1)
        assert np.all(np.abs(std / sigma - 1) < 0.05), (std, sigma)
        assert np.all(np.abs(err.mean(axis=0)) < 3 * sigma / math.sqrt(N_SAMPLES)), \
            (err.mean(axis=0), sigma)
    # the noise is drawn per state from default_rng(seed): positions then velocities
    z = np.random.default_rng(seed).standard_normal((N_SAMPLES, 4))
    assert np.array_equal(qm, q + sq * z[:, :2]) and np.array_equal(qdm, qd + sqd * z[:, 2:])


def test_encoder_positions_are_whole_counts_within_half_a_count():
    """counts N: every measured position is k * 2 pi / N for an integer k, the nearest
    count to the (noisy) position; velocity is not quantised; a joint with 0 is ideal."""
    rng = np.random.default_rng(5)
    q = rng.uniform(-7, 7, (500, 2))
    qd = rng.uniform(-2, 2, (500, 2))
    counts = 4096
    qm, qdm = measure_series(q, qd, encoder_resolution=[counts, 0])
    step = 2 * math.pi / counts
    k = qm[:, 0] / step
    assert np.abs(k - np.round(k)).max() < 1e-9, 'a whole number of counts'
    assert np.abs(qm[:, 0] - q[:, 0]).max() <= step / 2 + 1e-12, 'the nearest count'
    assert np.array_equal(qm[:, 1], q[:, 1]) and np.array_equal(qdm, qd)
    assert len(np.unique(np.round(k))) > 400, 'really quantised, not constant'
    # with noise, still whole counts of the noisy position
    qn, _ = measure_series(q, qd, encoder_resolution=[1000, 360], position_noise=[0.01, 0.01],
                           seed=3)
    steps = 2 * math.pi / np.array([1000, 360])
    kn = qn / steps
    assert np.abs(kn - np.round(kn)).max() < 1e-9
    z = np.random.default_rng(3).standard_normal((500, 4))[:, :2]
    assert np.abs(qn - (q + 0.01 * z)).max() <= steps.max() / 2 + 1e-12


@pytest.mark.parametrize('k', [1, 3, 7])
def test_a_sensing_delay_of_k_periods_shifts_the_measurement_by_exactly_k(k):
    rng = np.random.default_rng(11)
    q, qd = rng.normal(size=(200, 2)), rng.normal(size=(200, 2))
    settings = dict(position_noise=[0.01, 0.02], velocity_noise=[0.3, 0.1],
                    encoder_resolution=[2000, 0], seed=42)
    q0m, qd0m = measure_series(q, qd, **settings)
    qkm, qdkm = measure_series(q, qd, sensing_delay=k, **settings)
    assert np.array_equal(qkm[k:], q0m[:-k]) and np.array_equal(qdkm[k:], qd0m[:-k])
    assert (qkm[:k] == q0m[0]).all() and (qdkm[:k] == qd0m[0]).all(), \
        'before k states: the first one measured'


def test_the_core_publishes_the_measurement_delayed_and_the_true_state_beside_it():
    """Through SimulatorCore: joint_states (joint_view) at period j is the true state of
    period j - k, exactly, under a closed loop that sees only the delayed measurement."""
    k = 4
    core = make_core(sensors=SensorModel(2, sensing_delay=k))
    q, qd, _, qt, qdt = closed_loop(core, 150)
    assert np.array_equal(q[k:], qt[:-k]) and np.array_equal(qd[k:], qdt[:-k])
    assert (q[:k] == Q0).all()
    assert np.ptp(qt[:, 0]) > 0.3, 'the arm moved'


def test_seed_same_is_bit_identical_and_another_seed_differs():
    def run(seed):
        core = make_core(sensors=SensorModel(2, position_noise=[1e-3, 1e-3],
                                             velocity_noise=[1e-2, 1e-2],
                                             encoder_resolution=[8192, 8192],
                                             sensing_delay=1, seed=seed),
                         actuation_delay=1)
        return closed_loop(core, 200)

    a, b, c = run(7), run(7), run(8)
    assert all(x.tobytes() == y.tobytes() for x, y in zip(a, b)), 'same seed: same bits'
    assert not np.array_equal(a[0], c[0]), 'another seed: other measurements'
    assert not np.array_equal(a[3], c[3]), '... and, in closed loop, another motion'
    # the published measurement is the sensor model's of the true states, for the seed
    qm, qdm = measure_series(a[3], a[4], position_noise=[1e-3, 1e-3],
                             velocity_noise=[1e-2, 1e-2], encoder_resolution=[8192, 8192],
                             sensing_delay=1, seed=7)
    assert np.array_equal(qm, a[0]) and np.array_equal(qdm, a[1])


def test_defaults_are_bit_identical_to_the_core_without_sensors():
    """The node's defaults (every sensor and actuator setting 0) publish, bit for bit,
    what the core without the module publishes."""
    from arm_dynamics.simulator_node import SIM_PARAMS

    spec = {s.name: s.default for s in SIM_PARAMS}
    sensors = SensorModel(2, position_noise=spec['position_noise'],
                          velocity_noise=spec['velocity_noise'],
                          encoder_resolution=spec['encoder_resolution'],
                          sensing_delay=spec['sensing_delay'], seed=spec['noise_seed'])
    assert not sensors.enabled and spec['actuation_delay'] == 0
    plain = closed_loop(make_core(), 300)
    with_module = closed_loop(make_core(sensors=sensors,
                                        actuation_delay=spec['actuation_delay']), 300)
    assert all(x.tobytes() == y.tobytes() for x, y in zip(plain, with_module))
    assert all(x.tobytes() == y.tobytes() for x, y in zip(plain[:2], plain[3:])), \
        'published = true'


def test_a_resent_state_carries_the_same_measurement_and_draws_nothing():
    sensors = SensorModel(2, position_noise=[0.1, 0.1], seed=1)
    core = make_core(sensors=sensors)
    first = core.joint_view()
    assert core.joint_view() == first == core.joint_view(), 're-sent: same measurement'
    for _ in range(5):
        core.advance()
    assert sensors.measured == 6, 'one draw per state: the initial one and five periods'
    state = sensors.rng.bit_generator.state
    views = [core.joint_view() for _ in range(3)]
    assert views[0] == views[1] == views[2] and sensors.rng.bit_generator.state == state


# ---------------------------------------------------------------------- the actuation delay
@pytest.mark.parametrize('k', [1, 2, 5])
def test_an_actuation_delay_of_k_applies_the_command_answering_state_j_minus_k(k):
    """The torque applied over [t_j, t_j + T] is the command answering the state at
    t_(j-k) (zero for j < k): the closed loop against a hand-rolled loop of
    ``TwoLinkArm.step`` that keeps its own list of commands."""
    periods = 150
    core = make_core(actuation_delay=k)
    q, qd, tau, _, _ = closed_loop(core, periods)
    # independent: the plant integrates u[j - k], the controller answers each state
    hq, hqd, commands, applied = [Q0.copy()], [np.zeros(2)], [], [np.zeros(2)]
    for j in range(periods):
        commands.append(pd(hq[j], hqd[j]))
        u = commands[j - k] if j >= k else np.zeros(2)
        u = np.clip(u, -np.array(LIMITS), LIMITS)
        a, b = ARM.step(hq[j], hqd[j], u, STEP_NS * 1e-9, PERIOD_NS // STEP_NS)
        hq.append(a)
        hqd.append(b)
        applied.append(u)
    assert np.array_equal(q, np.array(hq)) and np.array_equal(qd, np.array(hqd))
    assert np.array_equal(tau, np.array(applied)), 'effort = the torque applied'
    assert (tau[1:k + 1] == 0).all() and (tau[k + 1:] != 0).any()
    undelayed = closed_loop(make_core(), periods)
    assert np.abs(undelayed[0] - q).max() > 1e-3, 'the delay changes the motion'


def test_actuation_fifo_open_loop_and_reset():
    fifo = ActuationDelay(2, 3)
    out = [fifo(np.array([float(j), -float(j)])) for j in range(10)]
    assert [o[0] for o in out] == [0.0, 0.0, 0.0] + [float(j) for j in range(7)]
    fifo.clear()
    assert fifo(np.array([9.0, 9.0])).tolist() == [0.0, 0.0]
    same = np.array([1.0, 2.0])
    assert ActuationDelay(2, 0)(same) is same, 'no delay: the command itself'
    # the core: a reset restarts the line (zero torque for k periods, as at start)
    core = make_core(actuation_delay=2,
                     sensors=SensorModel(2, sensing_delay=2, position_noise=[1e-3, 0.0]))
    for _ in range(5):
        core.command = np.array([5.0, 1.0])
        core.advance()
    assert core.applied.tolist() == [5.0, 1.0]
    core.reset()
    at_reset = core.joint_view().position
    assert at_reset[1] == Q0[1] and abs(at_reset[0] - Q0[0]) < 5e-3, \
        'the reset state is measured at once (no noise on joint 2)'
    published = []
    for expected in ([0.0, 0.0], [0.0, 0.0], [5.0, 1.0]):
        core.command = np.array([5.0, 1.0])
        core.advance()
        assert core.applied.tolist() == expected
        published.append(core.joint_view().position)
    assert published[0] == published[1] == at_reset != published[2], \
        'then held while the delay line refills, as at start'


def test_bad_sensor_settings_are_refused_with_the_reason():
    with pytest.raises(ValueError, match='position_noise must have 2 values'):
        SensorModel(2, position_noise=[0.1])
    with pytest.raises(ValueError, match='velocity_noise must be finite and >= 0'):
        SensorModel(2, velocity_noise=[-1.0, 0.0])
    with pytest.raises(ValueError, match='whole counts'):
        SensorModel(2, encoder_resolution=[100.5, 0])
    with pytest.raises(ValueError, match='sensing_delay must be a whole number'):
        SensorModel(2, sensing_delay=-1)
    with pytest.raises(ValueError, match='noise_seed'):
        SensorModel(2, seed=-3)
    with pytest.raises(ValueError, match='actuation_delay'):
        ActuationDelay(2, 1.5)  # type: ignore[arg-type]


# ---------------------------------------------------------------------- bags and analysis
def _bag_with_true_states(path, true_stamps_drop: int = 0):
    """A regulation segment whose measured positions carry a known 0.02 rad offset on
    joint 1 and whose true ones track the reference to 0.01 rad exactly."""
    w, ch = open_bag(path)
    ty = 'sensor_msgs/msg/JointState'
    true_ch = w.add_topic('/simulator/true_joint_states', ty, schema_text(ty),
                          qos_yaml([QosProfile()]), type_hash(ty))
    t = np.arange(7) * 0.5
    q_true = np.stack([np.array([0.0, 0.5, 1.2, 1.1, 1.01, 1.0, 1.0]), np.full(7, 0.5)], 1)
    q_meas = q_true + [0.02, 0.0]
    qd, tau = np.tile([1.0, 0.0], (7, 1)), np.tile([60.0, 5.0], (7, 1))
    ref = q_true - 0.01
    stamp0 = 1_000_000_000
    write_run(w, ch, 1_000_000_000, t, q_meas, qd, tau, ref,
              (np.array([[0.0, 0.5], [1.0, 0.5]]), np.array([0.0, 3.0])), stamp0=stamp0)
    stamps = stamp0 + np.round(t * 1e9).astype(np.int64)
    for i, data in enumerate(joint_state_block(stamps, q_true, qd, tau)):
        if i >= true_stamps_drop:
            w.write(true_ch, data, 2_000_000_000 + i)
    w.close()
    return q_true, q_meas


def test_analysis_reports_tracking_on_the_true_state_and_says_so(tmp_path):
    q_true, _ = _bag_with_true_states(tmp_path / 'bag')
    bag = read_bag(tmp_path / 'bag')
    assert bag.true_joint_states is not None
    assert np.array_equal(bag.true_joint_states.position, q_true)
    assert bag.joint_states is not None and bag.joint_states.topic == '/joint_states'
    rep = analyze(tmp_path / 'bag')
    seg = rep.segments[0]
    assert rep.state_source == 'true_joint_states' and rep.to_dict()['state_source'] == \
        'true_joint_states'
    # the true state is 0.01 rad off the reference on both joints (the measured 0.03 / 0.01)
    assert seg.tracking_rms == pytest.approx([0.01, 0.01], abs=1e-12)
    assert seg.overshoot[0] == pytest.approx(20.0) and rep.run['energy'] == \
        pytest.approx(60.0), 'on the true positions'
    from arm_bag.report import format_table
    row = [line for line in format_table([rep]).splitlines() if line.startswith('positions')]
    assert row and row[0].split()[-1] == 'true_joint_states', 'the table says it too'


def test_analysis_without_a_complete_true_state_uses_joint_states_as_before(tmp_path):
    _bag_with_true_states(tmp_path / 'partial', true_stamps_drop=2)
    rep = analyze(tmp_path / 'partial')
    assert rep.state_source == 'joint_states' and 'state_source' not in rep.to_dict(), \
        'implied: the JSON of a bag without true states is what it was'
    assert any('no true state for 2 of 7' in w for w in rep.warnings)
    assert rep.segments[0].tracking_rms == pytest.approx([0.03, 0.01], abs=1e-12)
    from arm_bag.report import format_table
    assert 'positions from' not in format_table([rep]), 'the table as it was'


# ---------------------------------------------------------------------- the node
def test_node_publishes_the_seeded_measurement_and_the_true_state_with_the_same_stamps(
        ros, launch):
    """A lockstep simulator with noise, an encoder and both delays: joint_states and
    simulator/true_joint_states carry the same stamps; each measurement is what
    sensors.py computes from the true states for the seed; a second run with the same seed
    publishes the same bits."""
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    from arm_sim.client import stamp_of

    settings = {'position_noise': [0.002, 0.001], 'velocity_noise': [0.02, 0.01],
                'encoder_resolution': [16384.0, 0.0], 'sensing_delay': 2,
                'actuation_delay': 1, 'noise_seed': 2024}
    periods = 60
    runs = []
    for _run in range(2):
        launch('simulator', params={'timing_mode': 'lockstep', **settings})
        meas = ros.collect(JointState, 'joint_states')
        true = ros.collect(JointState, 'simulator/true_joint_states')
        pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
        ros.wait_for(lambda: meas and true, timeout=30, what='first states on both topics')
        answered: set[float] = set()

        def answer() -> float:
            t = stamp_of(meas[-1])
            if t not in answered:
                answered.add(t)
                pub.publish(Float64MultiArray(data=[15.0, -4.0]))
            return t

        ros.wait_for(lambda: answer() >= periods * 0.01 - 1e-9
                     and any(stamp_of(m) >= periods * 0.01 - 1e-9 for m in true),
                     timeout=40, what=f'{periods} periods')
        by_stamp_m = {stamp_of(m): m for m in reversed(meas)}  # first of each stamp
        by_stamp_t = {stamp_of(m): m for m in reversed(true)}
        stamps = sorted(set(by_stamp_m) & set(by_stamp_t))
        assert all(s > stamps[-1] for s in set(by_stamp_m) ^ set(by_stamp_t)), \
            'the same stamps (one topic may be a state ahead when read)'
        assert len(stamps) > periods and stamps[0] == 0.0
        for m in meas:  # a re-sent state repeats its measurement
            assert list(m.position) == list(by_stamp_m[stamp_of(m)].position)
        qt = np.array([by_stamp_t[s].position for s in stamps])
        qdt = np.array([by_stamp_t[s].velocity for s in stamps])
        qm = np.array([by_stamp_m[s].position for s in stamps])
        qdm = np.array([by_stamp_m[s].velocity for s in stamps])
        ref_q, ref_qd = measure_series(
            qt, qdt, position_noise=settings['position_noise'],
            velocity_noise=settings['velocity_noise'],
            encoder_resolution=settings['encoder_resolution'],
            sensing_delay=settings['sensing_delay'], seed=settings['noise_seed'])
        assert np.array_equal(qm, ref_q) and np.array_equal(qdm, ref_qd), \
            'the measurement is sensors.py of the true states for the seed'
        effort = np.array([by_stamp_t[s].effort for s in stamps])
        assert (effort[1] == 0).all() and effort[2] == pytest.approx([15.0, -4.0]), \
            'actuation delay 1: zero torque over the first period'
        runs.append((qm.tobytes(), qdm.tobytes(), qt.tobytes(), len(stamps)))
        launch.procs[-1].stop()
        ros.reset()
    n = min(runs[0][3], runs[1][3])
    assert runs[0][0][:n * 16] == runs[1][0][:n * 16] and \
        runs[0][2][:n * 16] == runs[1][2][:n * 16], 'same seed: the same bits'
