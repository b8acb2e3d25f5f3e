"""Geared motors on every joint: the reflected rotor inertia and motor damping.

Each robot model (:class:`~arm_dynamics.two_link.TwoLinkArm`,
:class:`~arm_dynamics.planar_chain.PlanarChain`) takes ``gear_ratios`` ``n``,
``motor_inertias`` ``Jm`` and ``motor_damping`` ``Bm`` per joint (motor side); torques stay
joint-side. Joint ``i`` then sees ``n_i^2 Jm_i`` on the diagonal of ``D(q)`` (MuJoCo's joint
``armature``, Pinocchio's ``model.armature``) and ``n_i^2 Bm_i`` added to its viscous
damping (Spong, Hutchinson, Vidyasagar, *Robot Modeling and Control*, Dynamics and
Independent Joint Control chapters). Checked here against independent references: MuJoCo
on an MJCF written in this file, Pinocchio on the URDF arm_sim generates, the lecture's
geared single link (:class:`~arm_dynamics.geared_link.SingleLinkGeared`, its own closed form
on the motor side), energy balance; plus: the defaults change no bit, the controller's model
may differ in its motors, bad values are refused by name. Pure: no ROS.
"""

from __future__ import annotations

import math
import pickle

import numpy as np
import pinocchio as pin
import pytest

from arm_common.params import resolve
from arm_control.model_params import CONTROL_MODEL_PARAMS, controller_model
from arm_dynamics.geared_link import SingleLinkGeared
from arm_dynamics.identify import IdentificationError, base_parameters, identified_arm
from arm_dynamics.integrate import rk4_step
from arm_dynamics.models import joint_count, robot_model
from arm_dynamics.planar_chain import PlanarChain
from arm_dynamics.robot import ROBOT_PARAMS, resolve_robot
from arm_dynamics.two_link import TwoLinkArm, TwoLinkBatch
from arm_dynamics.urdf import urdf_from_params

RNG = np.random.default_rng(20270114)
#: Motors of the 2-R arm: reflected inertias n^2 Jm = (0.075, 0.018) kg m^2, comparable to
#: the links' own (0.1, 0.08 about the CG), and reflected damping n^2 Bm = (0.25, 0.18).
MOTORS2 = {'gear_ratios': (50.0, 30.0), 'motor_inertias': (3e-5, 2e-5),
           'motor_damping': (1e-4, 2e-4)}
ARM = TwoLinkArm(joint_damping=(0.3, 0.2), **MOTORS2)
#: A 3-link chain with motors: n^2 Jm = (0.2, 0.025, 0.002), n^2 Bm = (0.1, 0.05, 0.004).
THREE = {'link_lengths': (1.0, 0.8, 0.6), 'com_distances': (0.5, 0.4, 0.3),
         'link_masses': (2.0, 1.5, 1.0), 'link_inertias': (0.1, 0.08, 0.05),
         'joint_damping': (0.1, 0.2, 0.05)}
MOTORS3 = {'gear_ratios': (100.0, 50.0, 20.0), 'motor_inertias': (2e-5, 1e-5, 5e-6),
           'motor_damping': (1e-5, 2e-5, 1e-5)}
MODELS = {
    'two_link': ('two_link', TwoLinkArm(**MOTORS2)),
    'chain_n2': ('planar_chain', PlanarChain(joint_damping=(0.3, 0.2), **MOTORS2)),
    'chain_n3': ('planar_chain', PlanarChain(**THREE, **MOTORS3)),
}


def reflected(model) -> tuple[np.ndarray, np.ndarray]:
    """``(n^2 Jm, b + n^2 Bm)`` computed here from the parameters (not the model's own
    properties)."""
    n = np.asarray(model.gear_ratios)
    return (n * n * np.asarray(model.motor_inertias),
            np.asarray(model.joint_damping) + n * n * np.asarray(model.motor_damping))


def random_states(n: int, count: int) -> tuple[np.ndarray, ...]:
    """q [rad], qd [rad/s], tau [N m], qdd [rad/s^2], each (count, n)."""
    return (RNG.uniform(-math.pi, math.pi, (count, n)), RNG.uniform(-5.0, 5.0, (count, n)),
            RNG.uniform(-30.0, 30.0, (count, n)), RNG.uniform(-20.0, 20.0, (count, n)))


# ------------------------------------------------------------------------ 1. MuJoCo
def mjcf(arm: TwoLinkArm) -> str:
    """The 2-R arm in MJCF: hinge joints about z, gravity (0, -g, 0), no contacts, each
    joint's ``armature = n^2 Jm`` and ``damping = b + n^2 Bm``. Inertia about the CG:
    ``diaginertia="1e-6 I I"`` (a rod along x; only the z entry enters planar motion, and
    MuJoCo refuses principal inertias breaking ``A + B >= C``)."""
    (l1, _), (lc1, lc2) = arm.link_lengths, arm.com_distances
    (m1, m2), (i1, i2) = arm.link_masses, arm.link_inertias
    armature, damping = reflected(arm)

    def joint(i: int) -> str:
        return (f'<joint name="joint{i + 1}" type="hinge" axis="0 0 1" pos="0 0 0" '
                f'damping="{float(damping[i])!r}" armature="{float(armature[i])!r}" '
                'frictionloss="0"/>')

    return f"""<mujoco model="geared_two_link">
  <compiler angle="radian"/>
  <option timestep="0.001" gravity="0 {-arm.gravity!r} 0" integrator="RK4">
    <flag contact="disable"/>
  </option>
  <worldbody>
    <body name="link1" pos="0 0 0">
      {joint(0)}
      <inertial pos="{lc1!r} 0 0" mass="{m1!r}" diaginertia="1e-06 {i1!r} {i1!r}"/>
      <body name="link2" pos="{l1!r} 0 0">
        {joint(1)}
        <inertial pos="{lc2!r} 0 0" mass="{m2!r}" diaginertia="1e-06 {i2!r} {i2!r}"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def test_mujoco_with_joint_armature_gives_the_two_link_arms_mass_matrix_and_dynamics_to_1e_9():
    """At 50 random states: ``mj_fullM`` against ``mass_matrix``, ``mj_forward``'s qacc
    (``qfrc_applied = tau``) against ``forward_dynamics`` (the single-state hot path and the
    batch path), ``mj_inverse``'s ``qfrc_inverse`` against ``inverse_dynamics``; 1e-9
    relative to the largest entry (measured: 1.3e-15)."""
    mujoco = pytest.importorskip('mujoco')
    model = mujoco.MjModel.from_xml_string(mjcf(ARM))
    data = mujoco.MjData(model)
    q, qd, tau, qdd = random_states(2, 50)
    full = np.zeros((2, 2))
    qacc, inverse, mass = [], [], []
    for k in range(len(q)):
        data.qpos[:], data.qvel[:], data.qfrc_applied[:] = q[k], qd[k], tau[k]
        mujoco.mj_forward(model, data)
        qacc.append(data.qacc.copy())
        mujoco.mj_fullM(model, data, full)
        mass.append(full.copy())
        data.qacc[:] = qdd[k]
        mujoco.mj_inverse(model, data)
        inverse.append(data.qfrc_inverse.copy())
    qacc, inverse, mass = np.array(qacc), np.array(inverse), np.array(mass)
    single = np.array([ARM.forward_dynamics(*x) for x in zip(q, qd, tau)])
    for ours, theirs in ((ARM.mass_matrix(q), mass), (single, qacc),
                         (ARM.forward_dynamics(q, qd, tau), qacc),
                         (ARM.inverse_dynamics(q, qd, qdd), inverse)):
        np.testing.assert_allclose(ours, theirs, rtol=1e-9, atol=1e-9 * np.abs(theirs).max())
    # The armature is what makes the difference: without motors MuJoCo's D differs by it.
    assert np.abs(mass - TwoLinkArm(joint_damping=(0.3, 0.2)).mass_matrix(q)).max() > 0.01


# ---------------------------------------------------------------------- 2. Pinocchio
@pytest.mark.parametrize('name', sorted(MODELS))
def test_pinocchio_with_model_armature_gives_the_models_dynamics_to_1e_9(name):
    """Pinocchio on the URDF arm_sim generates for the same robot parameters, with
    ``model.armature = n^2 Jm`` (what ``crba``, ``aba`` and ``rnea`` of Pinocchio 4 add to
    the diagonal; its ``rotorInertia``/``rotorGearRatio`` fields enter none of the three).
    Pinocchio knows no damping: ``b + n^2 Bm`` is added here. ``crba`` against
    ``mass_matrix``, ``aba`` against ``forward_dynamics``, ``rnea`` against
    ``inverse_dynamics`` at 50 random states, 1e-9 relative to the largest entry."""
    kind, arm = MODELS[name]
    n = arm.n_dof
    params = {'model': kind, **{k: list(getattr(arm, k)) for k in (
        'link_lengths', 'com_distances', 'link_masses', 'link_inertias', 'joint_damping',
        *MOTORS2)}}
    assert robot_model(resolve_robot(params)) == arm
    model = pin.buildModelFromXML(urdf_from_params(params))
    model.gravity.linear = np.array([0.0, -arm.gravity, 0.0])
    armature, damping = reflected(arm)
    model.armature = armature
    data = model.createData()
    q, qd, tau, qdd = random_states(n, 50)
    theirs = np.array([pin.aba(model, data, *x, t - damping * x[1]) for *x, t in zip(q, qd, tau)])
    for ours in (arm.forward_dynamics(q, qd, tau),
                 np.array([arm.forward_dynamics(*x) for x in zip(q, qd, tau)])):
        np.testing.assert_allclose(ours, theirs, rtol=1e-9, atol=1e-9 * np.abs(theirs).max())
    theirs = np.array([pin.rnea(model, data, *x) + damping * x[1] for x in zip(q, qd, qdd)])
    for ours in (arm.inverse_dynamics(q, qd, qdd),
                 np.array([arm.inverse_dynamics(*x) for x in zip(q, qd, qdd)])):
        np.testing.assert_allclose(ours, theirs, rtol=1e-9, atol=1e-9 * np.abs(theirs).max())
    for k in range(10):
        d = pin.crba(model, data, q[k])
        d = np.triu(d) + np.triu(d, 1).T
        np.testing.assert_allclose(arm.mass_matrix(q[k]), d, rtol=1e-9, atol=1e-12)


# ------------------------------------------------------------ 3. the lecture's geared link
def test_a_one_link_chain_with_a_motor_moves_as_the_lectures_geared_link_to_1e_12():
    """``SingleLinkGeared`` (motor side: ``J th'' + B th' + C sin(th/n) = u``, its default
    numbers, those of ``single_link_geared``) and a one-link ``PlanarChain`` with
    ``gear_ratios=[n]``, ``motor_inertias=[Jm]``, ``motor_damping=[Bm]`` and the link's
    mass ``M``, CG distance ``l``, inertia about the CG ``Jl - M l^2`` and damping ``Bl``,
    integrated 5 s with the same RK4 and step under the same piecewise-constant motor torque
    ``u`` (the chain gets ``tau = n u``). Link side ``q = th/n - pi/2`` (the chain measures
    from +x, the geared link from hanging down). The two ODEs are the same up to that affine
    change of variables, which RK4 preserves stage by stage, so the trajectories differ by
    rounding only: ``|q - (th/n - pi/2)| <= 1e-12`` rad and ``|qd - th'/n| <= 1e-12`` rad/s
    (measured 4e-15 and 1.4e-15 over a swing of 1.2 rad: 5000 steps of rounding at ~1e-16
    each). The chain's inverse dynamics along the way is ``n`` times the motor's (``tau = n
    u``), its kinetic energy the same and its potential energy the same less ``M g l``, to
    1e-12 relative (measured 4e-14: ``tau`` is a difference of terms ~10x larger)."""
    geared = SingleLinkGeared()
    n, m, ll = geared.gear_ratio, geared.mass, geared.length
    chain = PlanarChain(link_lengths=(ll,), com_distances=(ll,), link_masses=(m,),
                        link_inertias=(geared.load_inertia - m * ll * ll,),
                        gravity=geared.gravity, joint_damping=(geared.load_damping,),
                        gear_ratios=(n,), motor_inertias=(geared.motor_inertia,),
                        motor_damping=(geared.motor_damping,))
    dt, per_period = 1e-3, 10
    th, thd = np.array([0.2 * n]), np.array([-0.5 * n])           # link at 0.2 rad, -0.5 rad/s
    q, qd = th / n - math.pi / 2, thd / n
    worst_q = worst_qd = worst_tau = worst_energy = 0.0
    lowest = highest = 0.2
    for period in range(500):                                      # 5 s of 10 ms periods
        u = np.array([0.4 * math.sin(0.013 * period) + 0.1 * math.cos(0.07 * period)])
        thdd = geared.forward_dynamics(th, thd, u)
        qdd = chain.forward_dynamics(q, qd, n * u)
        np.testing.assert_allclose(qdd, thdd / n, rtol=1e-12, atol=1e-12)
        tau = chain.inverse_dynamics(q, qd, thdd / n)
        worst_tau = max(worst_tau, float(np.abs(tau - n * u).max()) / abs(n * float(u[0])))
        (ke_c, pe_c), (ke_g, pe_g) = (tuple(float(np.squeeze(e)) for e in energy) for energy in
                                      (chain.energy(q, qd), geared.energy(th, thd)))
        worst_energy = max(worst_energy, abs(ke_c - ke_g) / max(ke_g, 1e-3),
                           abs(pe_c + m * geared.gravity * ll - pe_g) / (m * geared.gravity * ll))
        for _ in range(per_period):
            th, thd = rk4_step(geared.forward_dynamics, th, thd, u, dt)
        q, qd = chain.step(q, qd, n * u, dt, per_period)
        worst_q = max(worst_q, float(np.abs(q - (th / n - math.pi / 2)).max()))
        worst_qd = max(worst_qd, float(np.abs(qd - thd / n).max()))
        lowest, highest = min(lowest, float(th[0]) / n), max(highest, float(th[0]) / n)
    assert worst_q <= 1e-12 and worst_qd <= 1e-12, (worst_q, worst_qd)
    assert worst_tau <= 1e-12 and worst_energy <= 1e-12, (worst_tau, worst_energy)
    assert highest - lowest > 1.0, ('the link must swing', lowest, highest)


# ------------------------------------------------------------- 4. defaults change nothing
#: Outputs of TwoLinkArm(joint_damping=(0.3, 0.2)) and of the 3-link chain THREE as the
#: implementation before the motors (commit 472ccf1) gave them, bit for bit (repr).
BEFORE = {
    'fd': [-4.973773077861028, -9.373639677794156],
    'fd_batch': [[-4.973773077861028, -9.373639677794156],
                 [-6.318652836840829, -8.450567363779005]],
    'id': [30.404580896856856, 5.016787219662974],
    'id_batch': [[44.03393286458534, 8.128189531619885],
                 [5.319701765900768, 2.509547606070977]],
    'mass_matrix': [[3.337810624741387, 0.7789053123706933],
                    [0.7789053123706933, 0.32000000000000006]],
    'damping_torque': [0.33, -0.08000000000000002],
    'step': [[0.3864557724013352, -0.7918039131313627],
             [0.6328619810026679, -1.4576797161078698]],
    'step_batch': [[[0.3864557724013352, -0.7918039131313627],
                    [-1.2159210058793855, 2.7614073389692844]],
                   [[0.6328619810026679, -1.4576797161078698],
                    [-0.5465765154407245, 2.2604703668699035]]],
    'energy': [1.7022570905254344, 4.955516705540636],
    'batch_step': [[[0.3864557724013352, -0.7918039131313627],
                    [-1.2142625998590437, 2.7710957834866816]],
                   [[0.6328619810026679, -1.4576797161078698],
                    [-0.5124471180426325, 2.4515049723054]]],
    'linearize_b': [[0.0, 0.0], [0.0, 0.0], [0.6935325059730987, -1.6881129787631437],
                    [-1.6881129787631437, 7.234000522001648]],
    'chain_fd': [-6.120970315775009, -2.345036572556417, 15.492460528085745],
    'chain_id': [77.10936837052994, 24.153589170166235, 4.501318538690542],
    'chain_step': [[0.3207955889419769, -0.7085278612831967, 1.2151701889183222],
                   [0.9804994441914633, -0.45553483567404657, 0.9202796204284125]],
    'chain_energy': [3.509121730521354, 6.909593757967383],
}


@pytest.mark.parametrize('explicit', [False, True], ids=['omitted', 'given'])
def test_default_motors_change_no_bit_of_any_output(explicit):
    """With ``gear_ratios`` 1 and ``motor_inertias``/``motor_damping`` 0 (omitted, or given
    explicitly) every output equals :data:`BEFORE` exactly (``==`` on floats)."""
    extra2 = ({'gear_ratios': (1.0, 1.0), 'motor_inertias': (0.0, 0.0),
               'motor_damping': (0.0, 0.0)} if explicit else {})
    arm = TwoLinkArm(joint_damping=(0.3, 0.2), **extra2)
    q, qd, tau, qdd = (np.array(x) for x in ([0.3, -0.7], [1.1, -0.4], [5.0, -2.0],
                                             [0.8, -1.5]))
    qs, qds, taus = (np.array(x) for x in ([[0.3, -0.7], [-1.2, 2.5]], [[1.1, -0.4], [0.2, 3.0]],
                                           [[5.0, -2.0], [-1.0, 0.5]]))
    got = {
        'fd': arm.forward_dynamics(q, qd, tau).tolist(),
        'fd_batch': arm.forward_dynamics(qs, qds, taus).tolist(),
        'id': arm.inverse_dynamics(q, qd, qdd).tolist(),
        'id_batch': arm.inverse_dynamics(qs, qds, taus).tolist(),
        'mass_matrix': arm.mass_matrix(q).tolist(),
        'damping_torque': arm.damping_torque(qd).tolist(),
        'step': [x.tolist() for x in arm.step(q, qd, tau, 1e-3, 100)],
        'step_batch': [x.tolist() for x in arm.step(qs, qds, taus, 1e-3, 100)],
        'energy': [float(x) for x in arm.energy(q, qd)],
        'batch_step': [x.tolist() for x in TwoLinkBatch([arm, TwoLinkArm(**extra2)]).step(
            qs, qds, taus, 1e-3, 100)],
        'linearize_b': arm.linearize(q, qd, tau)[1].tolist(),
    }
    step = BEFORE['step']
    assert list(arm.step_floats(*q, *qd, *tau, 1e-3, 100)) == [*step[0], *step[1]]
    extra3 = ({'gear_ratios': (1.0,) * 3, 'motor_inertias': (0.0,) * 3,
               'motor_damping': (0.0,) * 3} if explicit else {})
    chain = PlanarChain(**THREE, **extra3)
    q3, qd3, t3 = (np.array(x) for x in ([0.3, -0.7, 1.2], [1.1, -0.4, 0.6], [5.0, -2.0, 1.0]))
    got |= {
        'chain_fd': chain.forward_dynamics(q3, qd3, t3).tolist(),
        'chain_id': chain.inverse_dynamics(q3, qd3, t3).tolist(),
        'chain_step': [x.tolist() for x in chain.step(q3, qd3, t3, 1e-3, 20)],
        'chain_energy': [float(x) for x in chain.energy(q3, qd3)],
    }
    assert {k: v for k, v in got.items() if v != BEFORE[k]} == {}
    assert arm == TwoLinkArm(joint_damping=(0.3, 0.2)) and chain == PlanarChain(**THREE)


# ------------------------------------------------------------------------- 5. energy
@pytest.mark.parametrize('name', sorted(MODELS))
def test_without_damping_or_torque_the_energy_with_the_rotors_is_conserved_to_1e_6_j(name):
    """Motors on (inertia), every damping zero, zero torque: kinetic (rotors included) plus
    potential energy of :meth:`energy` over 2 s of RK4 steps of 1 ms stays within 1e-6 J of
    its start (RK4's error, O(dt^4); measured 3.8e-9 J for the 2-R arm, 2.2e-7 J for the
    3-link chain of ~23 J whose light outer link turns fastest); and the rotors' share
    ``sum n^2 Jm qd^2 / 2`` is really in it (the kinetic energy exceeds the links' by it)."""
    _, arm = MODELS[name]
    n = arm.n_dof
    arm = type(arm)(**{k: getattr(arm, k) for k in arm.PARAMETERS
                       if k not in ('joint_damping', 'motor_damping')})
    q, qd, zero = np.linspace(0.3, -0.5, n), np.linspace(2.0, -3.0, n), np.zeros(n)
    e0 = sum(arm.energy(q, qd))
    worst = 0.0
    for _ in range(200):
        q, qd = arm.step(q, qd, zero, 1e-3, 10)
        worst = max(worst, abs(float(sum(arm.energy(q, qd)) - e0)))
    assert worst <= 1e-6, worst
    links = type(arm)(**{k: getattr(arm, k) for k in arm.PARAMETERS if k != 'motor_inertias'})
    rotors = 0.5 * float(np.sum(reflected(arm)[0] * qd * qd))
    assert rotors > 0.01
    assert arm.energy(q, qd)[0] - links.energy(q, qd)[0] == pytest.approx(rotors, rel=1e-12)


@pytest.mark.parametrize('name', sorted(MODELS))
def test_the_energy_motor_damping_takes_is_the_integral_of_n2_bm_qd2_to_1e_6_j(name):
    """Motors with damping only (``joint_damping`` 0), zero torque, 2 s of RK4 steps of
    1 ms: the drop of :meth:`energy` equals ``int sum_i n_i^2 Bm_i qd_i^2 dt`` (Simpson's
    rule on the 1 ms samples, error O(dt^4)) to 1e-6 J (measured 1.3e-9 J of 7.6 J for the
    2-R arm, 1.8e-7 J of 5.0 J for the 3-link chain: RK4's own energy error)."""
    _, arm = MODELS[name]
    n = arm.n_dof
    arm = type(arm)(**{k: getattr(arm, k) for k in arm.PARAMETERS if k != 'joint_damping'})
    bm = reflected(arm)[1]
    q, qd, zero = np.linspace(0.3, -0.5, n), np.linspace(2.0, -3.0, n), np.zeros(n)
    e0 = float(sum(arm.energy(q, qd)))
    power = [float(bm @ (qd * qd))]
    for _ in range(2000):
        q, qd = arm.step(q, qd, zero, 1e-3, 1)
        power.append(float(bm @ (qd * qd)))
    p = np.array(power)
    dissipated = 1e-3 / 3.0 * (p[0] + p[-1] + 4.0 * p[1:-1:2].sum() + 2.0 * p[2:-1:2].sum())
    loss = e0 - float(sum(arm.energy(q, qd)))
    assert dissipated > 0.5, dissipated
    assert abs(loss - dissipated) <= 1e-6, (loss, dissipated)


# ------------------------------------------------------ 6. the controller's model of them
def test_the_controllers_model_of_the_motors_may_differ_from_the_arm_by_its_armature():
    """``control_model.motor_inertias`` set, the rest the robot's: the controller's
    ``D(q)`` is the robot's plus ``diag(n^2 (Jm_controller - Jm_robot))`` (to 1e-14: only
    the rounding of the lumped constants differs); unset, the controller's model is the
    robot's (gear ratios and motor damping carried from the robot parameters)."""
    given = {'gear_ratios': [50.0, 30.0], 'motor_inertias': [3e-5, 2e-5],
             'motor_damping': [1e-4, 2e-4]}
    specs = ROBOT_PARAMS + CONTROL_MODEL_PARAMS
    robot = robot_model(resolve(specs, given, joint_count))
    assert controller_model(resolve(specs, given, joint_count)) == robot
    p = resolve(specs, {**given, 'control_model.motor_inertias': [5e-5, 1e-5]}, joint_count)
    model = controller_model(p)
    assert model.gear_ratios == robot.gear_ratios == (50.0, 30.0)
    assert model.motor_damping == robot.motor_damping
    q = RNG.uniform(-math.pi, math.pi, (20, 2))
    expected = np.diag([2500.0 * (5e-5 - 3e-5), 900.0 * (1e-5 - 2e-5)])
    np.testing.assert_allclose(model.mass_matrix(q) - robot.mass_matrix(q),
                               np.broadcast_to(expected, (20, 2, 2)), rtol=0, atol=1e-14)


# -------------------------------------------------------------------- 7. validation
@pytest.mark.parametrize('cls', [TwoLinkArm, PlanarChain])
@pytest.mark.parametrize('name, value, words', [
    ('gear_ratios', (0.0, 30.0), 'gear_ratios[0] must be > 0, got 0.0'),
    ('gear_ratios', (50.0, -2.0), 'gear_ratios[1] must be > 0, got -2.0'),
    ('gear_ratios', (float('nan'), 1.0), 'gear_ratios[0] must be finite, got nan'),
    ('motor_inertias', (-1e-4, 0.0), 'motor_inertias[0] must be >= 0, got -0.0001'),
    ('motor_inertias', (0.0, float('inf')), 'motor_inertias[1] must be finite, got inf'),
    ('motor_damping', (0.0, float('nan')), 'motor_damping[1] must be finite, got nan'),
    ('motor_damping', (-1.0, 0.0), 'motor_damping[0] must be >= 0, got -1.0'),
    ('gear_ratios', (50.0,), 'gear_ratios must have 2 elements, got 1'),
])
def test_a_bad_motor_value_is_refused_naming_the_parameter_and_the_value(cls, name, value,
                                                                           words):
    with pytest.raises(ValueError, match=r'^' + words.replace('[', r'\[').replace(']', r'\]')):
        cls(**{name: value})


def test_the_robot_parameters_take_the_motors_and_refuse_a_bad_one_by_name():
    robot = resolve_robot({'gear_ratios': [10, 5], 'motor_inertias': [1e-4, 5e-5]})
    assert robot['gear_ratios'] == [10.0, 5.0] and robot['motor_damping'] == [0.0, 0.0]
    arm = robot_model(robot)
    assert arm.armature == pytest.approx((1e-2, 1.25e-3), rel=1e-15)
    three = resolve_robot({'model': 'planar_chain', 'link_lengths': [1.0, 0.8, 0.6]})
    assert three['gear_ratios'] == [1.0] * 3 and three['motor_inertias'] == [0.0] * 3
    with pytest.raises(ValueError, match='gear_ratios'):
        resolve_robot({'gear_ratios': [0.0, 5.0]})
    with pytest.raises(ValueError, match='motor_inertias'):
        resolve_robot({'motor_inertias': [1e-4, -1.0]})


# ----------------------------------------------------- every path carries the motors
@pytest.mark.parametrize('name', sorted(MODELS))
def test_every_path_of_a_model_with_motors_agrees_with_its_mass_matrix_and_damping(name):
    """Single and batch forward dynamics solve ``D qdd = tau - h`` with ``D`` the
    :meth:`mass_matrix` (rotors included) and ``h = ID(q, qd, 0)``; inverse dynamics
    (single, batch, complex) is ``D qdd + h``; :meth:`damping_torque` is ``(b + n^2 Bm) qd``;
    :meth:`step` is RK4 of the forward dynamics; ``linearize``'s ``B`` is ``[0; D^-1]``;
    pickling keeps the motors. All to 1e-12 relative (one formula against another)."""
    _, arm = MODELS[name]
    n = arm.n_dof
    armature, damping = reflected(arm)
    q, qd, tau, qdd = random_states(n, 20)
    d = arm.mass_matrix(q)
    assert np.abs(d - PlanarChain(**{k: getattr(arm, k) for k in arm.PARAMETERS
                                     if k != 'motor_inertias'}).mass_matrix(q)
                  - np.diag(armature)).max() < 1e-12
    h = arm.inverse_dynamics(q, qd, np.zeros_like(qdd))
    expected = np.linalg.solve(d, (tau - h)[..., None])[..., 0]
    for got in (arm.forward_dynamics(q, qd, tau),
                np.array([arm.forward_dynamics(*x) for x in zip(q, qd, tau)])):
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    expected = np.einsum('kij,kj->ki', d, qdd) + h
    for got in (arm.inverse_dynamics(q, qd, qdd),
                np.array([arm.inverse_dynamics(*x) for x in zip(q, qd, qdd)]),
                np.array([arm.inverse_dynamics_complex(*x).real for x in zip(q, qd, qdd)])):
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    np.testing.assert_allclose(arm.damping_torque(qd), damping * qd, rtol=1e-15)
    q1, qd1 = rk4_step(arm.forward_dynamics, q[0], qd[0], tau[0], 1e-3)
    for got, want in zip(arm.step(q[0], qd[0], tau[0], 1e-3), (q1, qd1)):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    _, b = arm.linearize(q[0], qd[0], tau[0])
    np.testing.assert_allclose(b[n:], np.linalg.inv(d[0]), rtol=1e-12, atol=1e-12)
    again = pickle.loads(pickle.dumps(arm))
    assert again == arm and again.armature == arm.armature
    np.testing.assert_array_equal(again.forward_dynamics(q, qd, tau),
                                  arm.forward_dynamics(q, qd, tau))


def test_the_2r_arm_with_motors_is_the_two_link_chain_with_them_in_batch_too():
    """The closed form (single, its batch class mixing arms with and without motors,
    ``step_floats``) against the Newton-Euler chain of the same parameters, to 1e-12."""
    chain = MODELS['chain_n2'][1]
    arm = TwoLinkArm(joint_damping=(0.3, 0.2), **MOTORS2)
    plain = TwoLinkArm()
    q, qd, tau, _ = random_states(2, 2)
    batch = TwoLinkBatch([arm, plain])
    want = np.stack([chain.forward_dynamics(q[0], qd[0], tau[0]),
                     plain.forward_dynamics(q[1], qd[1], tau[1])])
    np.testing.assert_allclose(batch.forward_dynamics(q, qd, tau), want, rtol=1e-12)
    bq, bqd = batch.step(q, qd, tau, 1e-3, 50)
    cq, cqd = chain.step(q[0], qd[0], tau[0], 1e-3, 50)
    np.testing.assert_allclose(np.r_[bq[0], bqd[0]], np.r_[cq, cqd], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(arm.step_floats(*q[0], *qd[0], *tau[0], 1e-3, 50),
                               np.r_[cq, cqd], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(arm.energy(q, qd), chain.energy(q, qd), rtol=1e-12)


def test_a_payload_or_model_errors_keep_the_motors():
    """:meth:`TwoLinkArm.with_payload` and :meth:`~TwoLinkArm.with_errors` change the links
    only: the motors stay, so ``D`` gains ``p J^T J`` (payload) and the armature is not
    scaled by the errors."""
    arm = ARM
    payload = arm.with_payload(1.5)
    wrong = arm.with_errors(0.2, -0.1)
    for other in (payload, wrong):
        assert (other.gear_ratios, other.motor_inertias, other.motor_damping,
                other.joint_damping) == (arm.gear_ratios, arm.motor_inertias,
                                         arm.motor_damping, arm.joint_damping)
    q = RNG.uniform(-math.pi, math.pi, (10, 2))
    jac = arm.jacobian(q)
    np.testing.assert_allclose(payload.mass_matrix(q),
                               arm.mass_matrix(q) + 1.5 * np.swapaxes(jac, -1, -2) @ jac,
                               rtol=1e-12)
    links = np.diag(reflected(arm)[0])
    np.testing.assert_allclose(wrong.mass_matrix(q) - links,
                               1.2 * 0.81 * (arm.mass_matrix(q) - links), rtol=1e-12)


def test_identification_refuses_an_arm_with_motors_naming_them():
    """Its regressor has no column for joint 2's rotor inertia: it refuses rather than
    returning biased parameters; gear ratios alone (no rotor inertia or damping) are fine
    and carried over to the identified arm."""
    with pytest.raises(IdentificationError, match=r'motor_inertias=\[3e-05, 2e-05\]'):
        base_parameters(ARM)
    with pytest.raises(IdentificationError, match='nominal arm has geared motors'):
        identified_arm(np.zeros(6), ARM)
    geared_only = TwoLinkArm(gear_ratios=(50.0, 30.0))
    values = base_parameters(geared_only)
    assert identified_arm(values, geared_only).gear_ratios == (50.0, 30.0)
