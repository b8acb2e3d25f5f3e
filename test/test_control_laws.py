"""Control laws in closed loop with the exact plant, through simulate() (no ROS)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import fsolve

from arm_control.core import ControllerCore
from arm_control.laws import (
    GAINS,
    LAW_TABLE,
    LAWS,
    ControlLaw,
    Gains,
    gains_markdown,
    law_torque,
    laws_markdown,
    lqr_gain,
)
from arm_control.trajectory import Trajectory, TrajectoryError, TrajectoryPoint
from arm_dynamics import TwoLinkArm, simulate

PLANT = TwoLinkArm()
LIMITS = (60.0, 20.0)
Q0 = np.array([-0.4, 1.2])
GOAL = np.array([0.3, 0.6])


def run(law: ControlLaw, trajectory: Trajectory, duration: float, plant=PLANT, q0=Q0,
        dt=1e-3):
    core = ControllerCore(('joint1', 'joint2'), law)
    core.trajectory, core.start = trajectory, 0.0
    refs = []

    def torque(t, q, qd):
        step = core.update(t, q, qd)
        refs.append(step.q_des)
        return step.command.tau

    res = simulate(model=plant, q0=q0, qd0=[0.0, 0.0], torque=torque, duration=duration,
                   dt=dt)
    return res, np.array(refs)


def set_point(q) -> Trajectory:
    return Trajectory(Q0, [0, 0], np.zeros(1), np.array([q], dtype=float))


def quintic_move(q_from, q_to, duration) -> Trajectory:
    return Trajectory(q_from, [0, 0], np.array([0.0, duration]),
                      np.array([q_from, q_to], dtype=float), np.zeros((2, 2)),
                      np.zeros((2, 2)))


def test_pd_with_gravity_compensation_reaches_the_set_point_exactly():
    law = ControlLaw('pd_gravity', Gains(kp=(200, 100), kd=(40, 20)), PLANT, LIMITS)
    res, _ = run(law, set_point(GOAL), 6.0)
    err = np.abs(res.q[-1] - GOAL).max()
    assert err < 1e-6, f'steady-state error {err:.2e} rad (bound 1e-6)'


def test_plain_pd_leaves_the_steady_state_error_theory_predicts():
    kp = np.array([200.0, 100.0])
    law = ControlLaw('pd', Gains(kp=tuple(kp), kd=(40, 20)), PLANT, LIMITS)
    res, _ = run(law, set_point(GOAL), 8.0)
    # At rest: Kp (q_goal - q) = g(q).
    q_rest = fsolve(lambda q: kp * (GOAL - q) - PLANT.gravity_vector(q), GOAL, xtol=1e-13)
    assert np.abs(res.qd[-1]).max() < 1e-6, 'the arm has come to rest'
    gap = np.abs(res.q[-1] - q_rest).max()
    assert gap < 1e-4, f'resting point differs from Kp e = g(q) by {gap:.2e} rad (bound 1e-4)'
    assert np.abs(GOAL - q_rest).max() > 1e-2, 'gravity really leaves an error'


def test_computed_torque_with_exact_model_tracks_a_quintic_trajectory():
    law = ControlLaw('computed_torque', Gains(kp=(400, 400), kd=(40, 40)), PLANT, LIMITS)
    res, refs = run(law, quintic_move(Q0, GOAL, 1.5), 2.0)
    err = np.abs(res.q - refs).max()
    assert err < 1e-5, f'max tracking error {err:.2e} rad (bound 1e-5 at 1 ms control)'
    assert np.abs(res.tau).max() > 1.0, 'the move needs real torque'


def test_payload_mismatch_grows_the_error_and_pid_removes_the_steady_state_part():
    m1, m2 = PLANT.link_masses
    heavy = TwoLinkArm(link_masses=(m1, 1.2 * m2))  # 20% payload on link 2, unmodelled
    ct = ControlLaw('computed_torque', Gains(kp=(100, 100), kd=(20, 20)), PLANT, LIMITS)
    exact, _ = run(ct, set_point(GOAL), 4.0)
    ct.reset()
    mismatched, _ = run(ct, set_point(GOAL), 4.0, plant=heavy)
    e_exact = np.abs(exact.q[-1] - GOAL).max()
    e_mis = np.abs(mismatched.q[-1] - GOAL).max()
    assert e_exact < 1e-6 and e_mis > 1e-3, f'mismatch error {e_mis:.2e} vs exact {e_exact:.2e}'
    pid = ControlLaw('pid', Gains(kp=(300, 150), kd=(60, 25), ki=(300, 150),
                                  i_clamp=(60, 20)), PLANT, LIMITS)
    fixed, _ = run(pid, set_point(GOAL), 12.0, plant=heavy)
    e_pid = np.abs(fixed.q[-1] - GOAL).max()
    assert e_pid < 1e-4, f'PID steady-state error {e_pid:.2e} rad (bound 1e-4)'


@pytest.mark.parametrize('law', ['pd', 'pd_gravity', 'computed_torque', 'pid'])
def test_torque_never_exceeds_the_limits(law):
    limits = (15.0, 5.0)  # below what a fast move wants
    ctrl = ControlLaw(law, Gains(kp=(400, 400), kd=(40, 40)), PLANT, limits)
    res, _ = run(ctrl, quintic_move(Q0, GOAL + 1.0, 0.4), 1.0)
    assert (np.abs(res.tau) <= np.array(limits) + 1e-12).all()
    assert (np.abs(res.tau) >= np.array(limits) - 1e-9).any(), 'the limits were reached'


def test_pid_integral_is_clamped():
    ctrl = ControlLaw('pid', Gains(kp=(0, 0), kd=(0, 0), ki=(1000, 1000), i_clamp=(3, 2)),
                      PLANT, (1e3, 1e3))
    for _ in range(100):
        cmd = ctrl(np.zeros(2), np.zeros(2), np.ones(2), np.zeros(2), np.zeros(2), 0.01)
    assert cmd.tau.tolist() == [3.0, 2.0]


def test_controller_holds_the_first_measured_position_until_a_trajectory_arrives():
    core = ControllerCore(('joint1', 'joint2'), ControlLaw('pd_gravity', Gains(), PLANT,
                                                             LIMITS))
    step = core.update(5.0, Q0, np.zeros(2))
    assert step.q_des.tolist() == Q0.tolist() and core.holding_start
    step = core.update(5.5, Q0 + 0.05, np.zeros(2))
    assert step.q_des.tolist() == Q0.tolist()


def test_invalid_trajectory_keeps_the_current_reference():
    core = ControllerCore(('joint1', 'joint2'), ControlLaw('pd', Gains(), PLANT, LIMITS))
    core.update(0.0, Q0, np.zeros(2))
    with pytest.raises(TrajectoryError, match='unknown joint'):
        core.set_trajectory(['joint1', 'elbow'], [TrajectoryPoint(1.0, [0, 0])], 0.0, Q0,
                            np.zeros(2))
    assert core.update(0.1, Q0, np.zeros(2)).q_des.tolist() == Q0.tolist()


# ---------------------------------------------------------------------- the law registry
def test_pid_with_its_default_gains_holds_the_demo_pose_with_no_steady_state_error():
    """The defaults of the registry: the integral reaches the 20.66 N m of gravity at the
    demo's start pose (the old 20 N m clamp left 8.2e-3 rad there for ever)."""
    assert abs(PLANT.gravity_vector(Q0)[0]) > 20.0, 'the pose needs more than the old clamp'
    law = ControlLaw('pid', Gains(), PLANT, LIMITS)
    res, _ = run(law, set_point(Q0), 30.0, dt=0.01)
    err = np.abs(res.q[-1] - Q0).max()
    assert err < 1e-6, f'steady-state error {err:.2e} rad (bound 1e-6)'


def test_pids_default_integral_clamp_exceeds_the_largest_gravity_torque_of_the_arm():
    q = np.stack(np.meshgrid(np.linspace(-np.pi, np.pi, 721),
                             np.linspace(-np.pi, np.pi, 721)), -1).reshape(-1, 2)
    largest = np.abs(PLANT.gravity_vector(q)).max(axis=0)
    np.testing.assert_allclose(largest, [30.41, 5.886], atol=5e-3)  # stretched horizontally
    assert (np.array(Gains().i_clamp) > largest).all()
    assert (np.array(Gains().i_clamp) <= np.array(LIMITS)).all()


def test_the_controllers_law_choices_and_help_come_from_the_registry():
    from arm_control.controller_node import CONTROL_PARAMS
    spec = {s.name: s for s in CONTROL_PARAMS}
    assert spec['law'].choices == tuple(LAW_TABLE) == LAWS
    for law in LAW_TABLE.values():
        assert law.formula in spec['law'].description
    for gain in GAINS:
        assert spec[f'gains.{gain.name}'].default == list(gain.default)
        assert spec[f'gains.{gain.name}'].unit == gain.unit


def test_the_docs_law_and_gain_tables_are_the_registrys():
    text = (Path(__file__).resolve().parents[1] / 'docs' / 'nodes.md').read_text()
    for fn in (laws_markdown, gains_markdown):
        marker = f'<!-- generated: arm_control.laws.{fn.__name__} -->\n'
        assert marker in text, f'docs/nodes.md lacks {marker.strip()}'
        block = text.split(marker, 1)[1].split('<!-- end generated -->', 1)[0]
        assert block == fn(), (f'docs/nodes.md is out of date; replace the block after '
                               f'{marker.strip()} with:\n{fn()}')


def test_every_law_of_the_registry_gives_its_formulas_torque():
    """Each entry's torque function against the formula it states, at random states."""
    rng = np.random.default_rng(7)
    gains = Gains(kp=(120.0, 70.0), kd=(15.0, 9.0), ki=(40.0, 20.0), i_clamp=(30.0, 8.0))
    kp, kd = np.array(gains.kp), np.array(gains.kd)
    for _ in range(20):
        q, qd, qr, qdr, qddr = rng.uniform(-1, 1, (5, 2))
        e, ed = qr - q, qdr - qd
        expected = {
            'pd': kp * e + kd * ed,
            'pd_gravity': kp * e + kd * ed + PLANT.gravity_vector(q),
            'computed_torque': PLANT.mass_matrix(q) @ (qddr + kd * ed + kp * e)
            + PLANT.coriolis_matrix(q, qd) @ qd + PLANT.gravity_vector(q),
            'pid': kp * e + kd * ed + np.clip(np.array(gains.ki) * e * 0.01,
                                              -np.array(gains.i_clamp), gains.i_clamp),
            'lqr': PLANT.gravity_vector(qr) + lqr_gain(
                PLANT, qr, (gains.lqr_q, gains.lqr_qd, gains.lqr_r), 0.01) @ np.r_[e, ed],
        }
        for name in LAW_TABLE:
            raw = ControlLaw(name, gains, PLANT, (1e6, 1e6))(q, qd, qr, qdr, qddr, 0.01).raw
            np.testing.assert_allclose(raw, expected[name], rtol=1e-12, atol=1e-12,
                                       err_msg=name)



# ---------------------------------------------------------------------- lqr
GOAL_Q = np.array([0.3, 0.9])


def test_lqrs_linearised_closed_loop_has_the_eigenvalues_the_design_chose():
    """The controller's torque, differentiated about the goal (central differences of the
    implementation), closes the sampled plant ``(Ad, Bd)``; its eigenvalues equal those of
    ``Ad - Bd K`` that the Riccati design chose, and lie inside the unit circle."""
    gains = Gains()
    law = ControlLaw('lqr', gains, PLANT, (1e6, 1e6))
    ad, bd = PLANT.linearize(GOAL_Q, np.zeros(2), PLANT.gravity_vector(GOAL_Q), period=0.01)
    designed = np.linalg.eigvals(ad - bd @ lqr_gain(
        PLANT, GOAL_Q, (gains.lqr_q, gains.lqr_qd, gains.lqr_r), 0.01))
    h = 1e-6
    x0 = np.r_[GOAL_Q, 0.0, 0.0]

    def tau(x):
        return law(x[:2], x[2:], GOAL_Q, np.zeros(2), np.zeros(2), 0.01).raw
    k_impl = -np.stack([(tau(x0 + h * e) - tau(x0 - h * e)) / (2 * h) for e in np.eye(4)], -1)
    realised = np.linalg.eigvals(ad - bd @ k_impl)
    np.testing.assert_allclose(np.sort_complex(realised), np.sort_complex(designed),
                               atol=1e-7)
    assert np.abs(designed).max() < 1.0, 'the design is stable'


def test_lqr_brings_the_arm_to_the_goal_and_holds_it_with_no_error():
    law = ControlLaw('lqr', Gains(), PLANT, LIMITS)
    res, _ = run(law, set_point(GOAL_Q), 5.0, dt=0.01)
    err = np.abs(res.q[-1] - GOAL_Q).max()
    assert err < 1e-9, f'steady-state error {err:.2e} rad (gravity feed-forward is exact)'
    assert np.abs(res.qd[-1]).max() < 1e-8


def test_lqr_refuses_a_batch_and_is_left_out_of_the_batch_laws():
    from arm_control.laws import BATCH_LAWS
    assert 'lqr' in LAWS and 'lqr' not in BATCH_LAWS
    g = Gains()
    with pytest.raises(ValueError, match='not for a batch'):
        law_torque('lqr', *(np.asarray(v) for v in (g.kp, g.kd, g.ki, g.i_clamp)),
                   np.array(LIMITS), PLANT, np.zeros((3, 2)), np.zeros((3, 2)),
                   np.zeros((3, 2)), np.zeros((3, 2)), np.zeros((3, 2)), np.zeros((3, 2)),
                   0.01, weights=(g.lqr_q, g.lqr_qd, g.lqr_r))
