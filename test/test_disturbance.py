"""Pushes and faults at exact simulated times (:mod:`arm_dynamics.disturbance`), pure.

The physics is checked against independent derivations: the joint torque of a tip force by
virtual work (complex-step derivatives of a hand-written forward kinematics, and the 2-R
Jacobian by hand), an impulse by the momentum balance and the operational-space mobility,
the brakes by the Lagrange-multiplier (KKT) system. Timing is checked on the nanosecond
grid step by step; the scenario file by its example and one refusal per rule, each naming
the entry and the value.

Tolerances: 1e-12 (absolute and relative) for every physical quantity below -- each is a
few dozen flops from the other side, so rounding is ~1e-14; timing and masks exactly.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from arm_dynamics.disturbance import (
    MAX_FILE_BYTES,
    DisturbanceError,
    Disturbances,
    Fault,
    Push,
    apply_impulse,
    braked_forward_dynamics,
    engage_brakes,
)
from arm_dynamics.integrate import rk4_step
from arm_dynamics.planar_chain import PlanarChain
from arm_dynamics.two_link import TwoLinkArm

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / 'config' / 'disturbances' / 'example.yaml'
MS = 1_000_000                  # ns
S = 1_000_000_000               # ns
STEP = MS                       # the physics step of every schedule here: 1 ms
NAMES = ('joint1', 'joint2')
TOL = dict(rtol=1e-12, atol=1e-12)
TWO = TwoLinkArm()
THREE = PlanarChain(link_lengths=(0.9, 0.7, 0.5), com_distances=(0.45, 0.35, 0.25),
                    link_masses=(2.0, 1.5, 1.0), link_inertias=(0.1, 0.08, 0.05))
MODELS = [pytest.param(TWO, id='two_link'), pytest.param(THREE, id='planar_chain_3')]


def schedule(data, *, n=2, names=NAMES, step=STEP, **kw) -> Disturbances:
    return Disturbances.from_mapping(data, n=n, joint_names=names, physics_step_ns=step,
                                     source='scn.yaml', **kw)


def tip(x: float, y: float, at: float = 0.0, shape: str = 'step', **kw) -> dict:
    return {'at': at, 'tip_force': [x, y], 'shape': shape, **kw}


def fk(q, lengths):
    """Tip position, written out: sum of l_i (cos phi_i, sin phi_i), phi_i = q_1 + .. + q_i;
    works on complex q (for complex-step derivatives)."""
    phi = np.cumsum(q)
    return np.array([np.sum(lengths * np.cos(phi)), np.sum(lengths * np.sin(phi))])


def virtual_work_torque(q, lengths, force) -> np.ndarray:
    """tau_j = F . dp/dq_j (the work F does through a virtual displacement of joint j),
    dp/dq_j by complex step (no subtraction: exact to rounding)."""
    h = 1e-30
    n = len(q)
    cols = [fk(q + 1j * h * np.eye(n)[j], lengths).imag / h for j in range(n)]
    return np.array([np.dot(force, c) for c in cols])


def random_states(n: int, count: int = 5, seed: int = 7) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-math.pi, math.pi, (count, n))


# ---------------------------------------------------------------------- physics
@pytest.mark.parametrize('model', MODELS)
def test_tip_force_torque_is_jacobian_transpose_by_virtual_work(model):
    lengths = np.asarray(model.link_lengths)
    force = np.array([7.0, -30.0])
    d = schedule({'pushes': [tip(*force)]}, n=model.n_dof,
                 names=[f'j{i}' for i in range(model.n_dof)])
    for q in random_states(model.n_dof):
        np.testing.assert_allclose(fk(q, lengths).real, model.forward_kinematics(q), **TOL)
        np.testing.assert_allclose(d.external_torque(0, q, model),
                                   virtual_work_torque(q, lengths, force), **TOL)


def test_tip_force_torque_matches_the_hand_derived_two_link_jacobian():
    l1, l2 = TWO.link_lengths
    force = np.array([-4.0, 12.5])
    d = schedule({'pushes': [tip(*force)]})
    for q1, q2 in random_states(2, seed=3):
        s1, c1, s12, c12 = math.sin(q1), math.cos(q1), math.sin(q1 + q2), math.cos(q1 + q2)
        jac = np.array([[-l1 * s1 - l2 * s12, -l2 * s12], [l1 * c1 + l2 * c12, l2 * c12]])
        np.testing.assert_allclose(d.external_torque(0, [q1, q2], TWO), jac.T @ force, **TOL)


def test_pushes_superpose_and_nothing_active_gives_zeros_without_asking_the_model():
    d = schedule({'pushes': [tip(1.0, 2.0), tip(3.0, -5.0, at=0.5),
                             {'at': 0.0, 'joint_torque': [5.0, -1.0], 'shape': 'step'}]})
    q = np.array([0.3, 0.9])
    expected = TWO.jacobian(q).T @ np.array([4.0, -3.0]) + np.array([5.0, -1.0])
    np.testing.assert_allclose(d.external_torque(500 * MS, q, TWO), expected, **TOL)

    class NoModel:
        def jacobian(self, q):
            raise AssertionError('asked the model with no tip force active')

    pulse = schedule({'pushes': [tip(1.0, 0.0, at=1.0, shape='pulse', duration=0.1)]})
    out = pulse.external_torque(0, q, NoModel())
    assert out.shape == (2,) and not out.any()


@pytest.mark.parametrize('model', MODELS)
def test_tip_impulse_changes_momentum_by_jacobian_transpose_and_tip_velocity_by_mobility(
        model):
    impulse = np.array([2.0, -0.5])  # N s
    rng = np.random.default_rng(11)
    for q in random_states(model.n_dof):
        qd = rng.normal(size=model.n_dof)
        after = apply_impulse(model, q, qd, 'tip_force', impulse)
        mass, jac = model.mass_matrix(q), model.jacobian(q)
        np.testing.assert_allclose(mass @ (after - qd), jac.T @ impulse, **TOL)
        mobility = jac @ np.linalg.inv(mass) @ jac.T  # the operational-space Lambda^-1
        np.testing.assert_allclose(jac @ after - jac @ qd, mobility @ impulse, **TOL)


@pytest.mark.parametrize('model', MODELS)
def test_joint_impulse_changes_momentum_by_itself(model):
    impulse = np.linspace(0.5, -1.0, model.n_dof)  # N m s
    q, qd = random_states(model.n_dof, 1)[0], np.zeros(model.n_dof)
    after = apply_impulse(model, q, qd, 'joint_torque', impulse)
    np.testing.assert_allclose(model.mass_matrix(q) @ after, impulse, **TOL)
    with pytest.raises(ValueError, match="'tip_torque'"):
        apply_impulse(model, q, qd, 'tip_torque', impulse)


def test_impulses_are_reported_once_in_the_half_open_window_of_their_time():
    d = schedule({'pushes': [tip(2.0, 0.0, at=5.5, shape='impulse'),
                             tip(0.0, 1.0, at=1.0, shape='impulse'),
                             tip(9.0, 9.0, at=1.0)]})
    found = [p.start_ns for t in range(0, 10 * S, STEP)
             for p in d.impulses(t, t + STEP)]
    assert found == [1 * S, 5500 * MS]
    assert [p.start_ns for p in d.impulses(0, 10 * S)] == [1 * S, 5500 * MS]  # time order
    assert d.impulses(5500 * MS + 1, 6 * S) == [] and d.impulses(0, 1 * S) == []
    assert not d.external_torque(5500 * MS, [0.1, 0.2], TWO)[0] == 0.0  # the step only
    assert d.external_torque(999 * MS, [0.1, 0.2], TWO).tolist() == [0.0, 0.0]


@pytest.mark.parametrize('model', MODELS)
def test_brakes_stop_the_locked_joints_in_a_plastic_impact(model):
    n = model.n_dof
    rng = np.random.default_rng(5)
    for q in random_states(n):
        qd = rng.normal(size=n)
        locked = np.zeros(n, dtype=bool)
        locked[rng.integers(n)] = True
        after = engage_brakes(model, q, qd, locked)
        mass = model.mass_matrix(q)
        sel = np.eye(n)[locked]  # S: rows of the locked joints
        # independent: qd+ = qd - D^-1 S^T (S D^-1 S^T)^-1 S qd
        inv = np.linalg.inv(mass)
        expected = qd - inv @ sel.T @ np.linalg.solve(sel @ inv @ sel.T, sel @ qd)
        np.testing.assert_allclose(after, expected, **TOL)
        assert (after[locked] == 0.0).all()
        np.testing.assert_allclose((mass @ (after - qd))[~locked], 0.0, **TOL)
        assert after @ mass @ after <= qd @ mass @ qd + 1e-12  # no energy gained
    all_locked = np.ones(n, dtype=bool)
    assert engage_brakes(model, q, qd, all_locked).tolist() == [0.0] * n


@pytest.mark.parametrize('model', MODELS)
def test_braked_dynamics_solve_the_constrained_system_and_hold_the_joint_through_rk4(model):
    n = model.n_dof
    rng = np.random.default_rng(9)
    locked = np.zeros(n, dtype=bool)
    locked[0] = True
    for q in random_states(n):
        qd, tau = rng.normal(size=n), rng.normal(scale=5.0, size=n)
        qd[locked] = 0.0
        mass = model.mass_matrix(q)
        bias = (model.coriolis_matrix(q, qd) @ qd + model.gravity_vector(q)
                + model.damping_torque(qd))
        sel = np.eye(n)[locked]
        kkt = np.block([[mass, -sel.T], [sel, np.zeros((len(sel), len(sel)))]])
        qdd = np.linalg.solve(kkt, np.concatenate([tau - bias, np.zeros(len(sel))]))[:n]
        np.testing.assert_allclose(braked_forward_dynamics(model, q, qd, tau, locked), qdd,
                                   **TOL)

        def fd(q_, qd_, tau_):
            return braked_forward_dynamics(model, q_, qd_, tau_, locked)

        q1, qd1 = rk4_step(fd, q, qd, tau, 1e-3)
        assert q1[0] == q[0] and qd1[0] == 0.0  # exactly held
    assert braked_forward_dynamics(model, q, qd, tau, np.ones(n, bool)).tolist() == [0.0] * n


# ---------------------------------------------------------------------- timing
def test_a_pulse_is_active_exactly_over_at_to_at_plus_duration_on_the_step_grid():
    d = schedule({'pushes': [tip(0.0, -30.0, at=0.25, shape='pulse', duration=0.1)]})
    q = [0.4, 1.0]
    on = [t for t in range(0, 1 * S, STEP) if d.external_torque(t, q, TWO).any()]
    assert len(on) == 100
    assert on == list(range(250 * MS, 350 * MS, STEP))


def test_a_step_push_is_held_from_at_to_the_end():
    d = schedule({'pushes': [{'at': 4.0, 'joint_torque': [5.0, 0.0], 'shape': 'step'}]})
    assert d.external_torque(4 * S - STEP, [0, 0], TWO).tolist() == [0.0, 0.0]
    for t in (4 * S, 4 * S + STEP, 100 * S, 10**6 * S):
        assert d.external_torque(t, [0, 0], TWO).tolist() == [5.0, 0.0]


TIMELINE = {'faults': [
    {'at': 6.0, 'until': 7.0, 'torque_loss': {'joint': 2, 'fraction': 0.25}},
    {'at': 7.5, 'brake': {'joint': 1}},
    {'at': 8.0, 'until': 9.0, 'encoder_frozen': {'joint': 2}},
    {'at': 9.0, 'encoder_bias': {'joint': 1, 'bias': 0.05}},
    {'at': 10.0, 'until': 10.5, 'commands_dropped': {}},
]}


def test_faults_switch_torque_scale_brakes_and_dropped_commands_at_their_times():
    d = schedule(TIMELINE)
    for t in range(0, 12 * S, STEP):
        scale = d.torque_scale(t)
        assert scale.tolist() == ([1.0, 0.25] if 6 * S <= t < 7 * S else [1.0, 1.0]), t
        locked = d.locked(t)
        if t < 7500 * MS:
            assert locked is None, t
        else:
            assert locked is not None and locked.tolist() == [True, False], t
        assert d.commands_dropped(t) == (10 * S <= t < 10500 * MS), t


def test_torque_loss_defaults_to_no_torque_at_all():
    d = schedule({'faults': [{'at': 1.0, 'torque_loss': {'joint': 1}}]})
    assert d.torque_scale(1 * S).tolist() == [0.0, 1.0]


def measured(t_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """A made-up measurement that changes every sample."""
    x = t_ns * 1e-9
    return np.array([math.sin(x), math.cos(x)]), np.array([math.cos(x), -math.sin(x)])


def test_measure_holds_the_frozen_reading_with_zero_speed_and_adds_the_bias():
    d = schedule(TIMELINE)
    period = 10 * MS
    for t in range(0, 12 * S, period):
        q_m, qd_m = measured(t)
        q, qd = d.measure(t, q_m, qd_m)
        if not 8 * S <= t < 9 * S and t < 9 * S:
            assert q is q_m and qd is qd_m, t  # no encoder fault: the arguments themselves
            continue
        frozen = 8 * S <= t < 9 * S
        bias = 0.05 if t >= 9 * S else 0.0
        assert q[0] == q_m[0] + bias and qd[0] == qd_m[0], t
        if frozen:
            assert q[1] == measured(8 * S)[0][1] and qd[1] == 0.0, t
        else:
            assert q[1] == q_m[1] and qd[1] == qd_m[1], t
    q_m, qd_m = measured(12 * S)
    d.measure(12 * S, q_m, qd_m)
    assert q_m.tolist() == measured(12 * S)[0].tolist()  # the input is not changed in place


def test_a_frozen_and_biased_encoder_reads_the_held_value_plus_the_bias():
    d = schedule({'faults': [{'at': 1.0, 'until': 2.0, 'encoder_frozen': {'joint': 1}},
                             {'at': 1.5, 'encoder_bias': {'joint': 1, 'bias': -0.1}}]})
    held = measured(1 * S)[0][0]
    assert d.measure(1 * S, *measured(1 * S))[0][0] == held
    assert d.measure(1600 * MS, *measured(1600 * MS))[0][0] == held - 0.1
    q_m = measured(2 * S)[0]
    assert d.measure(2 * S, q_m, measured(2 * S)[1])[0][0] == q_m[0] - 0.1


def test_a_frozen_encoder_starting_between_samples_holds_the_first_measurement_after():
    d = schedule({'faults': [{'at': 1.003, 'until': 2.0, 'encoder_frozen': {'joint': 2}}]})
    for t in range(1 * S, 2 * S, 10 * MS):
        q, qd = d.measure(t, *measured(t))
        if t >= 1010 * MS:
            assert q[1] == measured(1010 * MS)[0][1] and qd[1] == 0.0


def test_events_report_each_start_and_end_once_in_time_order_within_the_window():
    d = schedule({**TIMELINE, 'pushes': [tip(0.0, -30.0, at=2.0, shape='pulse', duration=0.1),
                                         tip(2.0, 0.0, at=5.5, shape='impulse'),
                                         {'at': 4.0, 'joint_torque': [5, 0], 'shape': 'step'}]})
    seen = []
    period = 10 * MS
    for t0 in range(0, 12 * S, period):
        events = d.events(t0, t0 + period)
        assert all(t0 <= e.time_ns < t0 + period for e in events)
        seen.extend(events)
    expected = [(2 * S, 'pushes[0]', 'start'), (2100 * MS, 'pushes[0]', 'end'),
                (4 * S, 'pushes[2]', 'start'), (5500 * MS, 'pushes[1]', 'start'),
                (6 * S, 'faults[0]', 'start'), (7 * S, 'faults[0]', 'end'),
                (7500 * MS, 'faults[1]', 'start'), (8 * S, 'faults[2]', 'start'),
                (9 * S, 'faults[2]', 'end'), (9 * S, 'faults[3]', 'start'),
                (10 * S, 'faults[4]', 'start'), (10500 * MS, 'faults[4]', 'end')]
    assert [(e.time_ns, e.label, e.edge) for e in seen] == expected
    assert d.events(0, 12 * S) == seen  # one window: the same, in the same order
    assert d.events(2 * S, 2 * S) == [] and d.events(2 * S + 1, 2100 * MS) == []
    text = {(e.label, e.edge): e.description for e in seen}
    assert text['pushes[0]', 'start'] == 'push: tip force [0, -30] N pulse 0.1 s'
    assert text['pushes[1]', 'start'] == 'push: tip force [2, 0] N s impulse'
    assert text['faults[0]', 'start'] == ('fault: joint 2 (joint2) torque loss: delivers '
                                          '0.25 x its command until 7 s')
    assert text['faults[1]', 'start'] == 'fault: joint 1 (joint1) braked (to the end)'
    assert text['faults[3]', 'start'] == ('fault: joint 1 (joint1) encoder bias +0.05 rad '
                                          '(to the end)')
    assert text['faults[4]', 'end'] == 'fault end: effort commands dropped'
    assert all('\n' not in e.description for e in seen)


# ---------------------------------------------------------------------- live pushes
def test_a_live_push_joins_the_schedule_and_is_checked_against_the_arm_and_grid():
    d = schedule(None)
    assert not d.enabled and d.locked(0) is None and not d.commands_dropped(0)
    assert d.external_torque(0, [0, 0], TWO).tolist() == [0.0, 0.0]
    d.add_push(Push(3 * S, 3 * S + 50 * MS, 'joint_torque', (1.0, 2.0), 'pulse', label='live'))
    assert d.enabled
    assert d.external_torque(3 * S, [0, 0], TWO).tolist() == [1.0, 2.0]
    assert d.external_torque(3050 * MS, [0, 0], TWO).tolist() == [0.0, 0.0]
    assert [e.label for e in d.events(3 * S, 4 * S)] == ['live', 'live']
    with pytest.raises(DisturbanceError, match='start_ns 3000000500 is not on the physics'):
        d.add_push(Push(3 * S + 500, None, 'joint_torque', (1.0, 2.0), 'step'))
    with pytest.raises(DisturbanceError, match=r'joint_torque must have 2 values.*\[1\]'):
        d.add_push(Push(3 * S, None, 'joint_torque', (1.0,), 'step'))
    no_tip = schedule(None, tip_forces=False)
    with pytest.raises(DisturbanceError, match='no tip'):
        no_tip.add_push(Push(0, None, 'tip_force', (1.0, 2.0), 'impulse'))


@pytest.mark.parametrize('args, message', [
    ((0, None, 'tip_torque', (1.0, 2.0), 'step'), "'tip_torque'"),
    ((0, None, 'tip_force', (1.0, 2.0), 'ramp'), "'ramp'"),
    ((0, None, 'tip_force', (1.0, 2.0), 'pulse'), 'None'),
    ((5, 5, 'tip_force', (1.0, 2.0), 'pulse'), 'end_ns > start_ns 5'),
    ((0, 10, 'tip_force', (1.0, 2.0), 'step'), 'has no end_ns, got 10'),
    ((-1, None, 'tip_force', (1.0, 2.0), 'step'), '-1'),
    ((0, None, 'tip_force', (1.0, 2.0, 3.0), 'step'), '2 components'),
    ((0, None, 'tip_force', (math.nan, 2.0), 'step'), 'nan'),
])
def test_a_push_refuses_values_that_cannot_be_a_push(args, message):
    with pytest.raises(ValueError, match=message):
        Push(*args)


@pytest.mark.parametrize('args, message', [
    ((0, None, 'encoder_noise', 0), "'encoder_noise'"),
    ((5, 5, 'brake', 0), 'end_ns must be > start_ns 5'),
    ((0, None, 'brake', None), 'needs a joint index'),
    ((0, None, 'commands_dropped', 1), 'concerns no joint'),
    ((0, None, 'torque_loss', 0, 1.5), '1.5'),
])
def test_a_fault_refuses_values_that_cannot_be_a_fault(args, message):
    with pytest.raises(ValueError, match=message):
        Fault(*args)


# ---------------------------------------------------------------------- the file
def test_the_example_file_loads_with_its_pushes_and_faults():
    d = Disturbances.load(EXAMPLE, n=2, joint_names=NAMES, physics_step_ns=STEP)
    assert d.enabled
    assert [(p.kind, p.shape, p.start_ns, p.end_ns, p.value) for p in d.pushes] == [
        ('tip_force', 'pulse', 2 * S, 2100 * MS, (0.0, -30.0)),
        ('joint_torque', 'step', 4 * S, None, (5.0, 0.0)),
        ('tip_force', 'impulse', 5500 * MS, None, (2.0, 0.0))]
    assert [(f.kind, f.joint, f.start_ns, f.end_ns) for f in d.faults] == [
        ('torque_loss', 1, 6 * S, 7 * S), ('brake', 0, 7500 * MS, None),
        ('encoder_frozen', 1, 8 * S, 9 * S), ('encoder_bias', 0, 9 * S, None),
        ('commands_dropped', None, 10 * S, 10500 * MS)]
    assert d.faults[3].bias == 0.05
    # on a coarser grid its times still fall on steps; on 0.3 ms they do not
    Disturbances.load(EXAMPLE, n=2, joint_names=NAMES, physics_step_ns=5 * MS)
    with pytest.raises(DisturbanceError, match=r'example.yaml: pushes\[0\].at: 2.0 s is not'):
        Disturbances.load(EXAMPLE, n=2, joint_names=NAMES, physics_step_ns=300_000)


def test_joints_by_name_and_by_one_based_number_are_the_same_joint():
    by_number = schedule({'faults': [{'at': 1.0, 'brake': {'joint': 2}}]})
    by_name = schedule({'faults': [{'at': 1.0, 'brake': {'joint': 'joint2'}}]})
    assert by_number.faults == by_name.faults and by_name.faults[0].joint == 1


def test_an_empty_scenario_schedules_nothing():
    for data in (None, {}, {'pushes': None, 'faults': []}):
        d = schedule(data)
        assert not d.enabled and d.torque_scale(0).tolist() == [1.0, 1.0]


PULSE = tip(0.0, -30.0, at=2.0, shape='pulse', duration=0.1)
LOSS = {'at': 6.0, 'until': 7.0, 'torque_loss': {'joint': 2, 'fraction': 0.0}}


def with_push(**change) -> dict:
    return {'pushes': [{**PULSE, **change}]}


def with_fault(**change) -> dict:
    return {'faults': [{**LOSS, **change}]}


@pytest.mark.parametrize('data, where, value', [
    (with_push(at=2.0005), 'pushes[0].at', '2.0005 s is not on the physics step grid'),
    (with_push(at=1.0000000001), 'pushes[0].at', '1.0000000001 s is not a whole number of '
                                                  'nanoseconds'),
    (with_push(duration=0.0105), 'pushes[0].duration', '0.0105 s is not on the physics'),
    (with_fault(until=6.0), 'faults[0].until', '6.0 s must be after at 6.0'),
    (with_fault(until=5.0), 'faults[0].until', '5.0 s must be after at 6.0'),
    (with_push(at=-1.0), 'pushes[0].at', 'must be >= 0 s, got -1.0'),
    (with_push(at=math.nan), 'pushes[0].at', 'must be finite, got nan'),
    (with_push(at=True), 'pushes[0].at', 'got True'),
    (with_push(at='1e-3'), 'pushes[0].at', "'1e-3' (YAML reads 1e-3 as text"),
    (with_push(at=2e6), 'pushes[0].at', 'must be <= 1e+06 s, got 2000000.0'),
    (with_push(duration=-0.1), 'pushes[0].duration', 'must be > 0 s, got -0.1'),
    (with_push(duration=0), 'pushes[0].duration', 'must be > 0 s, got 0'),
    (with_push(shape='step'), 'pushes[0].duration', '0.1: only a pulse has a duration'),
    (with_push(shape='ramp'), 'pushes[0].shape', "one of step, pulse, impulse, got 'ramp'"),
    ({'pushes': [tip(1.0, 0.0, shape='pulse')]}, 'pushes[0].duration', 'missing'),
    (with_push(until=3.0), 'pushes[0].until', 'got until: 3.0'),
    (with_push(tip_force=[1.0, 2.0, 3.0]), 'pushes[0].tip_force', 'got 3: [1.0, 2.0, 3.0]'),
    (with_push(tip_force=[math.nan, 0.0]), 'pushes[0].tip_force[0]', 'finite, got nan'),
    (with_push(tip_force=[0.0, 1e9]), 'pushes[0].tip_force[1]', 'got 1000000000.0'),
    (with_push(tip_force='down'), 'pushes[0].tip_force', "got 'down'"),
    (with_push(joint_torque=[1.0, 2.0]), 'pushes[0]', "got ['tip_force', 'joint_torque']"),
    ({'pushes': [{'at': 1.0, 'joint_torque': [1.0], 'shape': 'step'}]},
     'pushes[0].joint_torque', 'must have 2 values (N m, one per joint), got 1: [1.0]'),
    ({'pushes': [{'at': 1.0, 'tip_torque': [1.0, 2.0], 'shape': 'step'}]},
     'pushes[0].tip_torque', 'unknown key'),
    ({'pushes': [{'tip_force': [1.0, 2.0], 'shape': 'step'}]}, 'pushes[0].at', 'missing'),
    ({'faults': [{'at': 1.0, 'encoder_noise': {'joint': 1}}]}, 'faults[0].encoder_noise',
     'unknown key'),
    ({'faults': [{'at': 1.0}]}, 'faults[0]', 'got none'),
    (with_fault(torque_loss={'joint': 0}), 'faults[0].torque_loss.joint', 'got 0'),
    (with_fault(torque_loss={'joint': 3}), 'faults[0].torque_loss.joint', 'got 3'),
    (with_fault(torque_loss={'joint': 'elbow'}), 'faults[0].torque_loss.joint',
     "(joint1, joint2), got 'elbow'"),
    (with_fault(torque_loss={'joint': True}), 'faults[0].torque_loss.joint', 'got True'),
    (with_fault(torque_loss={'fraction': 0.5}), 'faults[0].torque_loss.joint', 'missing'),
    (with_fault(torque_loss={'joint': 1, 'fraction': 1.5}), 'faults[0].torque_loss.fraction',
     'got 1.5'),
    (with_fault(torque_loss={'joint': 1, 'bias': 0.1}), 'faults[0].torque_loss.bias',
     'unknown key'),
    (with_fault(torque_loss=[2]), 'faults[0].torque_loss', 'got [2]'),
    ({'faults': [{'at': 1.0, 'encoder_bias': {'joint': 1}}]}, 'faults[0].encoder_bias.bias',
     'missing'),
    ({'faults': [{'at': 1.0, 'encoder_bias': {'joint': 1, 'bias': math.inf}}]},
     'faults[0].encoder_bias.bias', 'got inf'),
    ({'faults': [LOSS, {**LOSS, 'at': 6.5, 'until': None}]}, 'faults[1]',
     'overlaps faults[0] (until 7 s)'),
    ({'faults': [{'at': 1.0, 'brake': {'joint': 1}}, {'at': 5.0, 'brake': {'joint': 'joint1'}}]},
     'faults[1]', 'overlaps faults[0] (until the end)'),
    ({'pushes': {'at': 1.0}}, 'pushes', "must be a list of entries, got {'at': 1.0}"),
    ({'pushes': [3]}, 'pushes[0]', 'must be a mapping, got 3'),
    ({'push': []}, 'push', 'unknown key'),
    ({'pushes': [PULSE] * 1001}, 'pushes', '1001 entries'),
])
def test_a_bad_entry_is_refused_naming_the_file_the_entry_and_the_value(data, where, value):
    with pytest.raises(DisturbanceError) as err:
        schedule(data)
    message = str(err.value)
    assert message.startswith(f'scn.yaml: {where}: ') or message.startswith(
        f'scn.yaml: {where} '), message
    assert value in message, message


def test_faults_in_turn_on_one_joint_and_faults_on_other_joints_may_meet():
    d = schedule({'faults': [LOSS, {**LOSS, 'at': 7.0, 'until': 8.0},
                             {**LOSS, 'torque_loss': {'joint': 1}},
                             {'at': 6.5, 'brake': {'joint': 2}}]})
    assert len(d.faults) == 4


def test_tip_pushes_are_refused_for_a_model_without_a_tip():
    with pytest.raises(DisturbanceError, match=r'pushes\[0\].tip_force: .*no tip'):
        schedule({'pushes': [PULSE]}, tip_forces=False)


def test_the_setup_itself_is_checked():
    with pytest.raises(DisturbanceError, match=r"scn.yaml: joint_names must be 2 .*\['a'\]"):
        schedule(None, names=['a'])
    with pytest.raises(DisturbanceError, match='physics_step_ns must be an integer > 0, got 0'):
        schedule(None, step=0)
    with pytest.raises(DisturbanceError, match='a mapping'):
        schedule([PULSE])


def test_a_file_over_the_size_limit_is_refused_before_parsing(tmp_path):
    path = tmp_path / 'big.yaml'
    path.write_text('pushes: []\n' + '#' * MAX_FILE_BYTES + '\n')
    with pytest.raises(DisturbanceError, match=f'{path}: more than {MAX_FILE_BYTES} bytes'):
        Disturbances.load(path, n=2, joint_names=NAMES, physics_step_ns=STEP)


def test_yaml_aliases_and_deep_nesting_are_refused_while_composing(tmp_path):
    bomb = tmp_path / 'bomb.yaml'
    lines = ['a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]']
    lines += [f'a{i}: &a{i} [' + ', '.join([f'*a{i - 1}'] * 10) + ']' for i in range(1, 10)]
    bomb.write_text('\n'.join(lines) + '\npushes: *a9\n')
    with pytest.raises(DisturbanceError, match=fr'{bomb}: line 1: YAML anchors and aliases '
                                               r'\(&a0\)'):
        Disturbances.load(bomb, n=2, joint_names=NAMES, physics_step_ns=STEP)
    deep = tmp_path / 'deep.yaml'
    deep.write_text('pushes: ' + '[' * 50 + ']' * 50 + '\n')
    with pytest.raises(DisturbanceError, match=f'{deep}: line 1: nested more than'):
        Disturbances.load(deep, n=2, joint_names=NAMES, physics_step_ns=STEP)


def test_unreadable_non_utf8_and_non_yaml_files_are_refused_naming_the_file(tmp_path):
    missing = tmp_path / 'none.yaml'
    with pytest.raises(DisturbanceError, match=f'{missing}: cannot read it'):
        Disturbances.load(missing, n=2, joint_names=NAMES, physics_step_ns=STEP)
    latin = tmp_path / 'latin.yaml'
    latin.write_bytes(b'pushes: [] # caf\xe9\n')
    with pytest.raises(DisturbanceError, match=f'{latin}: not UTF-8'):
        Disturbances.load(latin, n=2, joint_names=NAMES, physics_step_ns=STEP)
    bad = tmp_path / 'bad.yaml'
    bad.write_text('pushes: [\n')
    with pytest.raises(DisturbanceError, match=f'{bad}: not YAML'):
        Disturbances.load(bad, n=2, joint_names=NAMES, physics_step_ns=STEP)
    entry = tmp_path / 'entry.yaml'
    entry.write_text('pushes:\n  - {at: 2.0005, tip_force: [0, 1], shape: step}\n')
    with pytest.raises(DisturbanceError, match=fr'{entry}: pushes\[0\].at: 2.0005 s'):
        Disturbances.load(entry, n=2, joint_names=NAMES, physics_step_ns=STEP)
