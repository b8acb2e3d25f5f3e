"""The robot-model seam's proof: ``model: planar_chain`` (n revolute links in the plane).

Its dynamics (one Newton-Euler routine) against Pinocchio on its own URDF and against the
2-R arm's closed form; the per-joint parameter rule; the planner's joint-space regulation
from numeric inverse kinematics; and over ROS: the simulator (lockstep and real_time)
against an independent DOP853 integration, the controller's four laws, the visualizer,
the recorder and ``analyze`` on a 3-link arm.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest
from conftest import goal_msg, statuses
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from scipy.integrate import solve_ivp
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from visualization_msgs.msg import MarkerArray

from arm_bag.analysis import analyze
from arm_dynamics.models import MODELS, RobotModel, joint_count, robot_model
from arm_dynamics.planar_chain import PlanarChain
from arm_dynamics.robot import resolve_robot
from arm_dynamics.two_link import TwoLinkArm
from arm_dynamics.urdf import urdf_from_params
from arm_planner.kinematics import PlanningError
from arm_planner.planner import PlannerSettings, plan_goal
from arm_sim.client import stamp_of as stamp
from arm_sim.urdf_cli import urdf_for_params_file

RNG = np.random.default_rng(20261125)
#: A 3-link arm, as a user would give it: lengths, and the rest per joint.
THREE = {'model': 'planar_chain', 'link_lengths': [1.0, 0.8, 0.6],
         'com_distances': [0.5, 0.4, 0.3], 'link_masses': [2.0, 1.5, 1.0],
         'link_inertias': [0.1, 0.08, 0.05], 'joint_damping': [0.1, 0.2, 0.05]}
CHAINS = {
    'n1': {'link_lengths': [0.7], 'com_distances': [0.3], 'link_masses': [1.2],
           'link_inertias': [0.02], 'joint_damping': [0.3]},
    'n3': {k: v for k, v in THREE.items() if k != 'model'},
    'n5': {'link_lengths': [0.5, 0.4, 0.4, 0.3, 0.2],
           'com_distances': [0.2, 0.2, 0.1, 0.15, 0.1],
           'link_masses': [1.0, 0.9, 0.8, 0.5, 0.3],
           'link_inertias': [0.02, 0.01, 0.01, 0.0, 0.003],
           'joint_damping': [0.0, 0.1, 0.0, 0.2, 0.0], 'gravity': 3.7},
}


# ---------------------------------------------------------------------- the model
def test_every_model_of_the_table_satisfies_the_robot_model_protocol():
    for name in MODELS:
        model = robot_model({'model': name})
        assert isinstance(model, RobotModel), name
        assert joint_count({'model': name}) == model.n_dof == 2
    assert isinstance(PlanarChain(**CHAINS['n5']), RobotModel)


@pytest.mark.parametrize('name', sorted(CHAINS))
def test_pinocchio_dynamics_of_its_urdf_equal_the_planar_chain_to_1e_9(name):
    """``pin.aba``, ``pin.rnea`` and ``pin.crba`` on the URDF arm_sim generates, at 100 random
    states (Pinocchio leaves the URDF's damping out of its algorithms: added here)."""
    params = {'model': 'planar_chain', **CHAINS[name]}
    arm = robot_model(resolve_robot(params))
    n = arm.n_dof
    model = pin.buildModelFromXML(urdf_from_params(params))
    model.gravity.linear = np.array([0.0, -arm.gravity, 0.0])
    data = model.createData()
    damping = np.array(arm.joint_damping)
    q = RNG.uniform(-math.pi, math.pi, (100, n))
    qd = RNG.uniform(-5.0, 5.0, (100, n))
    tau = RNG.uniform(-30.0, 30.0, (100, n))
    qdd = RNG.uniform(-20.0, 20.0, (100, n))
    ours = arm.forward_dynamics(q, qd, tau)
    theirs = np.array([pin.aba(model, data, *x, t - damping * x[1]) for *x, t in zip(q, qd, tau)])
    np.testing.assert_allclose(ours, theirs, rtol=1e-9, atol=1e-9 * np.abs(theirs).max())
    ours = arm.inverse_dynamics(q, qd, qdd)
    theirs = np.array([pin.rnea(model, data, *x) + damping * x[1] for x in zip(q, qd, qdd)])
    np.testing.assert_allclose(ours, theirs, rtol=1e-9, atol=1e-9 * np.abs(theirs).max())
    for k in range(5):
        d = pin.crba(model, data, q[k])
        d = np.triu(d) + np.triu(d, 1).T
        np.testing.assert_allclose(arm.mass_matrix(q[k]), d, rtol=1e-9, atol=1e-12)
        tip = model.getFrameId('tool0')
        pin.framesForwardKinematics(model, data, q[k])
        np.testing.assert_allclose(arm.forward_kinematics(q[k]),
                                   data.oMf[tip].translation[:2], atol=1e-12)


def test_with_two_links_the_chain_is_the_closed_form_2r_arm_to_rounding():
    kw = dict(link_lengths=(1.1, 0.7), com_distances=(0.6, 0.3), link_masses=(2.5, 1.0),
              link_inertias=(0.12, 0.05), gravity=9.81, joint_damping=(0.2, 0.1))
    chain, arm = PlanarChain(**kw), TwoLinkArm(**kw)
    q, qd, tau = (RNG.uniform(-3, 3, (50, 2)) for _ in range(3))
    for name, args, scale in (('mass_matrix', (q,), 1), ('coriolis_matrix', (q, qd), 1),
                              ('gravity_vector', (q,), 1), ('forward_dynamics', (q, qd, tau), 1),
                              ('inverse_dynamics', (q, qd, tau), 1), ('joint_points', (q,), 1),
                              ('jacobian', (q,), 1), ('jdot_qd', (q, qd), 1)):
        np.testing.assert_allclose(getattr(chain, name)(*args), getattr(arm, name)(*args),
                                   rtol=1e-12, atol=1e-12 * scale, err_msg=name)
    np.testing.assert_allclose(chain.energy(q, qd), arm.energy(q, qd), rtol=1e-12, atol=1e-12)


def test_the_chains_coriolis_matrix_makes_d_dot_minus_2c_skew_and_matches_the_bias():
    arm = PlanarChain(**CHAINS['n5'])
    q, qd = RNG.uniform(-2, 2, 5), RNG.uniform(-2, 2, 5)
    h = 1e-6
    d_dot = (arm.mass_matrix(q + h * qd) - arm.mass_matrix(q - h * qd)) / (2 * h)
    n = d_dot - 2.0 * arm.coriolis_matrix(q, qd)
    np.testing.assert_allclose(n, -n.T, atol=1e-8)
    np.testing.assert_allclose(
        arm.coriolis_matrix(q, qd) @ qd + arm.gravity_vector(q) + arm.damping_torque(qd),
        arm.bias(q, qd), rtol=1e-12, atol=1e-12)


def test_the_chain_conserves_energy_without_damping_or_torque():
    arm = PlanarChain(**{**CHAINS['n3'], 'joint_damping': [0.0] * 3})
    q, qd = np.array([0.3, -0.5, 1.0]), np.array([1.0, -0.5, 2.0])
    e0 = sum(arm.energy(q, qd))
    q1, qd1 = arm.step(q, qd, np.zeros(3), 1e-3, 2000)
    assert abs(sum(arm.energy(q1, qd1)) - e0) < 1e-7 * abs(e0) + 1e-9


def test_a_chain_singular_with_the_links_aligned_is_refused_naming_the_parameters():
    with pytest.raises(ValueError, match='mass matrix D\\(q\\) is singular'):
        PlanarChain(link_lengths=[1.0, 1.0], com_distances=[0.5, 0.0], link_masses=[1.0, 1.0],
                    link_inertias=[0.1, 0.0])


# ---------------------------------------------------------------------- parameters
def test_per_joint_parameters_not_given_take_each_joints_default():
    robot = resolve_robot({'model': 'planar_chain', 'link_lengths': [1.0, 0.8, 0.6, 0.4]})
    assert robot['joint_names'] == ['joint1', 'joint2', 'joint3', 'joint4']
    assert robot['effort_limits'] == [60.0, 20.0, 20.0, 20.0]
    assert robot['joint_damping'] == [0.0] * 4
    assert robot['position_limits_upper'] == pytest.approx([2 * math.pi] + [math.pi] * 3)
    assert robot['velocity_limits'] == [8.0] * 4
    assert robot_model(robot).n_dof == 4
    assert resolve_robot({})['link_lengths'] == [1.0, 0.8], 'the 2-R defaults unchanged'


@pytest.mark.parametrize('given, words', [
    ({'model': 'planar_chain', 'link_lengths': [1, 1, 1], 'joint_damping': [0.1, 0.1]},
     'joint_damping has 2 values but the robot has 3 joints'),
    ({'model': 'planar_chain', 'link_lengths': [1, 1], 'joint_names': ['a', 'b', 'c']},
     'joint_names has 3 values but the robot has 2 joints'),
    ({'link_lengths': [1.0, 0.8, 0.6]}, 'link_lengths has 3 values but model two_link has 2'),
    ({'model': 'planar_chain', 'link_lengths': []}, 'at least one value'),
    ({'model': 'seven_link'}, 'model must be one of two_link, planar_chain'),
])
def test_per_joint_parameters_of_the_wrong_length_are_refused_with_the_reason(given, words):
    with pytest.raises(ValueError, match=words.replace('(', '\\(')):
        resolve_robot(given)


def test_arm_sim_urdf_describes_the_chain_from_p_rules():
    text = urdf_for_params_file(None, ['model:=planar_chain', 'link_lengths:=[1.0, 0.5, 0.5]'])
    assert '<robot name="arm_sim_planar_chain">' in text
    for frame in ('link1', 'link2', 'link3', 'tool0'):
        assert f'name="{frame}"' in text
    assert 'name="joint3"' in text


# ---------------------------------------------------------------------- planner
def test_the_planner_regulates_a_chain_to_the_goal_by_numeric_ik():
    arm = robot_model(resolve_robot(THREE))
    q0 = np.array([-0.4, 1.2, 0.3])
    for profile in ('set_point', 'synchronized'):
        plan = plan_goal(arm, [60.0, 20.0, 20.0], q0, np.array([0.5, 1.2]),
                         PlannerSettings(regulation_profile=profile))
        assert np.hypot(*(arm.forward_kinematics(plan.q[-1]) - [0.5, 1.2])) < 1e-9
        assert plan.q.shape[1] == 3 and (plan.margin >= 0).all()


def test_the_planner_refuses_a_straight_line_for_a_chain_saying_why():
    arm = robot_model(resolve_robot(THREE))
    with pytest.raises(PlanningError, match='only the 2-R arm .* use mode regulation'):
        plan_goal(arm, [60.0, 20.0, 20.0], np.array([-0.4, 1.2, 0.3]), np.array([0.5, 1.2]),
                  PlannerSettings(mode='straight_line'))


def test_the_planner_refuses_an_unreachable_goal_for_a_chain_with_the_numbers():
    arm = robot_model(resolve_robot(THREE))
    with pytest.raises(PlanningError, match='out of reach: r = 3.0000 m'):
        plan_goal(arm, [60.0, 20.0, 20.0], np.array([-0.4, 1.2, 0.3]), np.array([3.0, 0.0]),
                  PlannerSettings())


# ---------------------------------------------------------------------- over ROS
def _chain_params(**extra) -> dict:
    return {**THREE, **extra}


@pytest.mark.parametrize('mode', ['lockstep', 'real_time'])
def test_a_3_link_arm_under_constant_torque_matches_dop853_over_ros(ros, launch, mode):
    q0, tau = [-0.4, 1.2, 0.3], [40.0, 10.0, 1.2]  # near gravity's 42.5, 10.9, 1.3 N m
    launch('simulator', params=_chain_params(timing_mode=mode, initial_positions=q0))
    states = ros.collect(JointState, 'joint_states')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: states, what='first joint state')
    answered: set[float] = set()

    def drive() -> float:  # a lockstep controller: one answer per new state
        t = stamp(states[-1])
        if t not in answered:
            answered.add(t)
            pub.publish(Float64MultiArray(data=tau))
        return t
    ros.wait_for(lambda: drive() >= 1.0 - 1e-9, timeout=60, what='1 s of simulated time')
    first = {stamp(m): m for m in states}
    times = np.array(sorted(first))
    assert list(states[0].name) == ['joint1', 'joint2', 'joint3']
    q = np.array([first[t].position for t in times])
    arm = PlanarChain(**CHAINS['n3'])
    ref = solve_ivp(lambda _t, x: np.concatenate([x[3:], arm.forward_dynamics(
        x[:3], x[3:], tau)]), (0, times[-1]), [*q0, 0, 0, 0], method='DOP853', rtol=1e-12,
        atol=1e-12, t_eval=times)
    err = np.abs(q - ref.y[:3].T).max()
    assert err < 1e-6, f'published motion deviates from DOP853 by {err:.2e} rad'
    assert np.ptp(q[:, 0]) > 0.1, 'the torque really moved the arm'


#: Joint-space gains for the 3-link arm (N m/rad, N m s/rad, ...): the third link is light,
#: so its gains are small enough for the 10 ms sampled loop. computed_torque keeps its
#: defaults (1/s^2, 1/s: independent of the inertia).
CHAIN_GAINS = {'gains.kp': [200.0, 100.0, 20.0], 'gains.kd': [30.0, 15.0, 2.0],
               'gains.ki': [200.0, 100.0, 20.0], 'gains.i_clamp': [55.0, 20.0, 5.0]}


@pytest.mark.parametrize('law', ['pd', 'pd_gravity', 'computed_torque', 'pid', 'lqr'])
def test_the_controllers_laws_regulate_a_3_link_arm_to_a_planned_goal(ros, launch, law,
                                                                       tmp_path):
    """Simulator, controller, planner, visualizer and recorder on a 3-link arm: the goal is
    reached to 1e-3 m (pd: it settles where ``Kp e = g(q)``, its steady-state error, to
    1e-3 N m), the markers draw the base and two joints before the tip, and ``analyze``
    reads the bag with end-effector metrics for three joints."""
    bag = tmp_path / 'chain'
    launch('simulator', params=_chain_params(timing_mode='lockstep'))
    launch('controller', params={**THREE, 'law': law,
                                 **(CHAIN_GAINS if law != 'computed_torque' else {})})
    launch('planner', params={**THREE, 'regulation_profile': 'synchronized'})
    launch('visualizer', params=THREE)
    recorder = launch('recorder', params={**THREE, 'output': str(bag)})
    states = ros.collect(JointState, 'joint_states')
    references = ros.collect(JointState, 'arm_controller/reference')
    markers = ros.collect(MarkerArray, 'markers')
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    goals = ros.publisher(PoseStamped, 'goal_pose')
    ros.wait_for(lambda: states and markers, timeout=30, what='states and markers')
    ros.wait_for(lambda: any(s.message.startswith(('ready', 'last'))
                             for s in statuses(diags, '/planner', 'summary')),
                 timeout=30, what='the planner to hold a joint state')
    ros.wait_matched(goals, ['planner'])
    goal = np.array([0.5, 1.2])
    arm = robot_model(resolve_robot(THREE))
    kp = np.array(CHAIN_GAINS['gains.kp'])

    def settled() -> bool:
        state = states[-1]
        if stamp(state) < start + 1.0 or max(abs(v) for v in state.velocity) > 1e-4:
            return False
        q = np.array(state.position)
        if law == 'pd':
            ref = next((r for r in reversed(references) if stamp(r) == stamp(state)), None)
            return ref is not None and bool(np.abs(
                kp * (np.array(ref.position) - q) - arm.gravity_vector(q)).max() < 1e-3)
        return bool(np.hypot(*(arm.forward_kinematics(q) - goal)) < 1e-3)
    start = stamp(states[-1])
    goals.publish(goal_msg(*goal))
    try:
        ros.wait_for(settled, timeout=180, what=f'{law} to settle at the goal')
    except pytest.fail.Exception:
        last = states[-1]
        pytest.fail(f'{law} did not settle: last state at {stamp(last):.2f} s q = '
                    f'{list(last.position)}, qd = {list(last.velocity)}, effort = '
                    f'{list(last.effort)}; tip {arm.forward_kinematics(last.position)}')
    joints = next(m for m in markers[-1].markers if m.ns == 'joints')
    assert len(joints.points) == 3, 'base and two joints drawn as spheres before the tip'
    recorder.stop()
    report = analyze(bag)
    assert not [w for w in report.warnings if 'end-effector' in w], report.warnings
    last = report.segments[-1]
    assert len(last.final_error) == 3 and last.series['xy'].shape[-1] == 2


def test_the_live_views_frames_compose_to_the_chains_joints_and_tip():
    from test_live import compose

    from arm_sim.live import arm_transforms
    arm = PlanarChain(**CHAINS['n5'])
    for q in RNG.uniform(-math.pi, math.pi, (50, 5)):
        tfs = arm_transforms(arm, q)
        frames = ['base_link', 'link1', 'link2', 'link3', 'link4', 'link5', 'tool0']
        assert [(t.parent, t.child) for t in tfs] == list(zip(frames, frames[1:]))
        poses = compose(tfs)
        points = arm.joint_points(q)
        for i, frame in enumerate(frames[1:-1]):
            np.testing.assert_allclose(poses[frame][:2, 3], points[i], atol=1e-12)
        np.testing.assert_allclose(poses['tool0'][:2, 3], points[-1], atol=1e-12)
    with pytest.raises(ValueError, match='q must be 5 finite'):
        arm_transforms(arm, [0.0] * 4)
