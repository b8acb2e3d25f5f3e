"""The URDF made from the robot parameters is the arm the simulator integrates: read by two
real URDF libraries (yourdfpy, Pinocchio's urdfdom parser), its kinematics equal
``TwoLinkArm.forward_kinematics`` and its rigid-body dynamics ``forward_dynamics`` /
``inverse_dynamics``; and ``arm-sim urdf`` prints it from the parameters as the nodes take
them."""

from __future__ import annotations

import io
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yourdfpy

from arm_dynamics import JointLimits, TwoLinkArm
from arm_dynamics.robot import JOINT_NAMES, ROBOT_DEFAULTS
from arm_dynamics.urdf import (
    AXIAL_INERTIA,
    UNLIMITED_VELOCITY,
    RobotDescription,
    urdf_from_params,
)
from arm_sim.cli import main
from arm_sim.urdf_cli import robot_params, urdf_for_params_file

ROOT = Path(__file__).resolve().parents[1]
RNG_SEED = 12


def parsed(text: str) -> yourdfpy.URDF:
    return yourdfpy.URDF.load(io.StringIO(text), load_meshes=False,
                              build_collision_scene_graph=False)


def random_params(rng: np.random.Generator) -> dict:
    """A random valid parameter set (the defaults' orders of magnitude, with damping)."""
    lengths = rng.uniform(0.3, 2.0, 2)
    return {'link_lengths': lengths.tolist(),
            'com_distances': (lengths * rng.uniform(0.1, 0.9, 2)).tolist(),
            'link_masses': rng.uniform(0.5, 5.0, 2).tolist(),
            'link_inertias': rng.uniform(0.01, 0.5, 2).tolist(),
            'gravity': float(rng.uniform(0.0, 20.0)),
            'joint_damping': rng.uniform(0.0, 2.0, 2).tolist()}


PARAM_SETS = [{}, *(random_params(np.random.default_rng(RNG_SEED + i)) for i in range(3))]


def test_yourdfpy_reads_the_frames_joints_limits_and_inertials():
    robot = parsed(urdf_from_params())
    assert robot.base_link == 'base_link'
    assert set(robot.link_map) == {'base_link', 'link1', 'link2', 'tool0'}
    assert tuple(robot.actuated_joint_names) == JOINT_NAMES
    arm = TwoLinkArm.from_params(ROBOT_DEFAULTS)
    limits = JointLimits.from_params(ROBOT_DEFAULTS)
    for i, name in enumerate(JOINT_NAMES):
        joint = robot.joint_map[name]
        assert joint.type == 'revolute'
        np.testing.assert_array_equal(joint.axis, [0.0, 0.0, 1.0])
        assert joint.limit.lower == limits.lower[i] and joint.limit.upper == limits.upper[i]
        assert joint.limit.effort == ROBOT_DEFAULTS['effort_limits'][i]
        assert joint.limit.velocity == limits.velocity[i]
        assert float(joint.dynamics.damping) == arm.joint_damping[i]  # yourdfpy: text
        inertial = robot.link_map[f'link{i + 1}'].inertial
        assert inertial.mass == arm.link_masses[i]
        np.testing.assert_array_equal(inertial.origin[:3, 3], [arm.com_distances[i], 0, 0])
        np.testing.assert_array_equal(inertial.origin[:3, :3], np.eye(3))
        izz = arm.link_inertias[i]
        np.testing.assert_array_equal(inertial.inertia,
                                      np.diag([AXIAL_INERTIA, izz + AXIAL_INERTIA, izz]))
        assert robot.link_map[f'link{i + 1}'].visuals, 'every link is drawn'
    tool = robot.joint_map['tool0_joint']
    assert (tool.type, tool.parent, tool.child) == ('fixed', 'link2', 'tool0')
    assert robot.validate(), robot.errors


@pytest.mark.parametrize('inertia', [0.0, 1e-9, 0.1, 100.0])
def test_the_inertia_tensor_is_physical_for_any_planar_inertia(inertia):
    """Positive definite (semi-definite for the model's point mass, I = 0) and the triangle
    inequality (what Gazebo and MuJoCo check); izz is the model's inertia exactly."""
    params = {'link_inertias': [0.1, inertia]}
    robot = parsed(urdf_from_params(params))
    tensor = robot.link_map['link2'].inertial.inertia
    ixx, iyy, izz = np.diag(tensor)
    assert izz == inertia and np.all(np.linalg.eigvalsh(tensor) >= 0)
    assert (np.linalg.eigvalsh(tensor).min() > 0) == (inertia > 0)
    assert ixx + iyy >= izz and iyy + izz >= ixx and izz + ixx >= iyy


@pytest.mark.parametrize('params', PARAM_SETS, ids=lambda p: 'defaults' if not p else 'random')
def test_the_tip_frame_is_forward_kinematics_to_1e_12(params):
    arm = TwoLinkArm.from_params(params)
    robot = parsed(urdf_from_params(params))
    model = pin.buildModelFromXML(urdf_from_params(params))
    data = model.createData()
    tool = model.getFrameId('tool0')
    rng = np.random.default_rng(RNG_SEED)
    for q in rng.uniform(-math.pi, math.pi, (50, 2)):
        robot.update_cfg(q)
        pose = robot.get_transform('tool0', 'base_link')
        expected = arm.forward_kinematics(q)
        np.testing.assert_allclose(pose[:3, 3], [*expected, 0.0], rtol=0, atol=1e-12)
        angle = q.sum()  # tool0's x axis along link 2
        np.testing.assert_allclose(pose[:3, 0], [math.cos(angle), math.sin(angle), 0],
                                   rtol=0, atol=1e-12)
        pin.framesForwardKinematics(model, data, q)
        np.testing.assert_allclose(data.oMf[tool].translation, [*expected, 0.0], rtol=0,
                                   atol=1e-12)


@pytest.mark.parametrize('params', PARAM_SETS, ids=lambda p: 'defaults' if not p else 'random')
def test_pinocchio_dynamics_of_the_urdf_equal_the_simulated_model(params):
    """``pin.aba`` / ``pin.rnea`` at 200 random states to 1e-9 relative. Pinocchio reads
    the joint damping into ``model.damping`` but its algorithms leave it out, so the
    viscous torque ``B qd`` is added here."""
    arm = TwoLinkArm.from_params(params)
    model = pin.buildModelFromXML(urdf_from_params(params))
    model.gravity.linear = np.array([0.0, -arm.gravity, 0.0])
    data = model.createData()
    damping = np.array(arm.joint_damping)
    np.testing.assert_array_equal(model.damping, damping)
    np.testing.assert_array_equal(model.effortLimit, ROBOT_DEFAULTS['effort_limits'])
    rng = np.random.default_rng(RNG_SEED)
    n = 200
    q = rng.uniform(-math.pi, math.pi, (n, 2))
    qd = rng.uniform(-5.0, 5.0, (n, 2))
    tau = rng.uniform(-60.0, 60.0, (n, 2))
    qdd = rng.uniform(-20.0, 20.0, (n, 2))
    ours_acc = np.array([arm.forward_dynamics(*x) for x in zip(q, qd, tau)])
    pin_acc = np.array([pin.aba(model, data, *x, t - damping * x[1])
                        for *x, t in zip(q, qd, tau)])
    np.testing.assert_allclose(pin_acc, ours_acc, rtol=1e-9,
                               atol=1e-9 * np.abs(ours_acc).max())
    ours_tau = np.array([arm.inverse_dynamics(*x) for x in zip(q, qd, qdd)])
    pin_tau = np.array([pin.rnea(model, data, *x) + damping * x[1]
                        for x in zip(q, qd, qdd)])
    np.testing.assert_allclose(pin_tau, ours_tau, rtol=1e-9,
                               atol=1e-9 * np.abs(ours_tau).max())
    np.testing.assert_allclose(pin.crba(model, data, q[0]), arm.mass_matrix(q[0]),
                               rtol=1e-12, atol=1e-12)  # upper triangle as filled by crba


def test_unbounded_joints_are_continuous_and_an_infinite_speed_is_the_largest_number():
    params = {'position_limits_lower': [-math.inf, -3.0],
              'position_limits_upper': [math.inf, 3.0], 'velocity_limits': [math.inf, 8.0]}
    robot = parsed(urdf_from_params(params))
    joint = robot.joint_map['joint1']
    assert joint.type == 'continuous' and joint.limit.velocity == UNLIMITED_VELOCITY
    assert robot.joint_map['joint2'].type == 'revolute'
    model = pin.buildModelFromXML(urdf_from_params(params))
    assert (model.nq, model.nv) == (3, 2)  # a continuous joint is (cos, sin) in Pinocchio


def test_joint_names_and_the_robot_name_come_from_the_parameters():
    text = RobotDescription.from_params({'joint_names': ['shoulder', 'elbow']},
                                        name='my_arm').to_urdf()
    robot = parsed(text)
    assert robot.robot.name == 'my_arm'
    assert robot.actuated_joint_names == ['shoulder', 'elbow']


@pytest.mark.parametrize('params, words', [
    ({'link_lenghts': [1.0, 1.0]}, "['link_lenghts']"),
    ({'link_masses': [0.0, 1.0]}, 'link_masses must be > 0 kg, got 0.0'),
    ({'link_lengths': [1.0]}, 'link_lengths has 1 values but model two_link has 2 links'),
    ({'joint_names': ['a', 'a']}, "got ('a', 'a')"),
    ({'joint_names': ['tool0', 'b']}, "got ('tool0', 'b')"),
    ({'position_limits_lower': [1.0, 0.0], 'position_limits_upper': [0.5, 1.0]},
     'joint 1 position limits must satisfy lower < upper, got [1, 0.5] rad'),
])
def test_bad_parameters_are_refused_naming_the_value(params, words):
    with pytest.raises(ValueError) as info:
        urdf_from_params(params)
    assert words in str(info.value)


def test_the_document_is_plain_xml_with_exact_numbers():
    root = ET.fromstring(urdf_from_params({'link_lengths': [0.1 + 0.2, 0.7]}))
    joint2 = root.find("joint[@name='joint2']/origin")
    assert joint2 is not None and float(joint2.get('xyz', '').split()[0]) == 0.1 + 0.2


def test_arm_sim_urdf_prints_it_from_the_params_file_and_p_rules(capsys, tmp_path):
    assert main(['urdf']) == 0
    assert capsys.readouterr().out == urdf_from_params()
    assert main(['urdf', '--params-file', str(ROOT / 'config' / 'arm.yaml')]) == 0
    assert capsys.readouterr().out == urdf_from_params(), 'config/arm.yaml = the defaults'
    params = tmp_path / 'p.yaml'
    params.write_text("/**:\n  ros__parameters:\n    link_lengths: [1.5, 0.5]\n"
                      "    use_sim_time: true\n/**/simulator:\n  ros__parameters:\n"
                      "    link_masses: [9.0, 9.0]\n")
    rules = ['link_masses:=[3, 1]', 'gravity:=1']
    assert robot_params(params, rules) == {'link_lengths': [1.5, 0.5],
                                           'link_masses': [3.0, 1.0], 'gravity': 1.0}
    out = tmp_path / 'arm.urdf'
    argv = ['urdf', '--params-file', str(params), '-p', rules[0], '-p', rules[1], '-o', str(out)]
    assert main(argv) == 0
    assert out.read_text() == urdf_for_params_file(params, rules)
    robot = parsed(out.read_text())
    assert robot.joint_map['tool0_joint'].origin[0, 3] == 0.5
    assert robot.link_map['link1'].inertial.mass == 3.0


@pytest.mark.parametrize('argv, words', [
    (['-p', 'link_masses:=[0, 1]'], 'link_masses must be > 0 kg'),
    (['-p', 'gravity'], "-p 'gravity': expected name:=value"),
    (['-p', 'nope:=1'], "unknown robot parameter(s) ['nope']"),
    (['--params-file', '/nonexistent.yaml'], "'/nonexistent.yaml': cannot read"),
])
def test_arm_sim_urdf_refuses_bad_input_in_one_line(capsys, argv, words):
    assert main(['urdf', *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith('arm-sim urdf: ') and words in err and err.count('\n') == 1
