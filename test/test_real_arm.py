"""The real arm in the simulator: friction, pushes and faults in :class:`SimulatorCore`, the
simulator node's parameters, topics and events, and the lecture's question they answer
(plain PD and PD + gravity stop inside the friction band).

The physics of each effect is tested against its own independent reference in
test_friction.py (event-located DOP853), test_geared_motors.py (MuJoCo, Pinocchio, the
lecture's geared link) and test_disturbance.py (virtual work, momentum); here: that the
simulator applies them where and when it says, exactly.
"""

from __future__ import annotations

import numpy as np
import pytest

from arm_control.laws import law_torque
from arm_dynamics import TwoLinkArm
from arm_dynamics.disturbance import Disturbances
from arm_dynamics.friction import JointFriction
from arm_dynamics.integrate import rk4_step
from arm_dynamics.robot import resolve_robot
from arm_dynamics.simulation import SimulatorCore

STEP_NS, PERIOD_NS = 1_000_000, 10_000_000
NAMES = ('joint1', 'joint2')
#: config/real_arm.yaml's friction.
COULOMB, STATIC = np.array([1.5, 0.5]), np.array([1.95, 0.65])


def core(arm=None, *, friction=None, disturbances=None, q0=(-0.4, 1.2), **kw):
    return SimulatorCore(arm or TwoLinkArm(), q0=list(q0), qd0=[0.0, 0.0],
                         effort_limits=[60.0, 20.0], physics_step_ns=STEP_NS,
                         control_period_ns=PERIOD_NS, velocity_limit=1000.0,
                         joint_names=NAMES, friction=friction, disturbances=disturbances,
                         **kw)


def schedule(data) -> Disturbances:
    return Disturbances.from_mapping(data, n=2, joint_names=NAMES, physics_step_ns=STEP_NS)


def run(c: SimulatorCore, law, periods: int) -> np.ndarray:
    """Close the loop for ``periods``; the true states (periods + 1, 4)."""
    out = [np.r_[c.q, c.qd]]
    for _ in range(periods):
        c.set_command(law(c))
        c.advance()
        out.append(np.r_[c.q, c.qd])
    return np.array(out)


def pd_gravity(arm, goal, kp, kd):
    """The controller's pd_gravity law (:func:`arm_control.laws.law_torque`) to a fixed
    goal, on the state the core publishes."""
    kp, kd, zero = np.asarray(kp, float), np.asarray(kd, float), np.zeros(2)
    limits = np.array([60.0, 20.0])

    def law(c):
        return law_torque('pd_gravity', kp, kd, zero, zero, limits, arm, zero, c.q, c.qd,
                          np.asarray(goal, float), zero, zero, 0.01)[0]
    return law


# ---------------------------------------------------------------------- friction
@pytest.mark.parametrize('start', [(-0.4, 1.2), (0.6, -0.9), (1.2, 0.3)])
def test_pd_gravity_with_friction_stops_inside_the_static_band_and_stays_there(start):
    """The lecture's steady-state question: with Coulomb/static friction, PD + gravity
    stops short of the goal, each joint within static_i / Kp_i of it (where the spring
    torque Kp e no longer breaks the joint away), at exactly zero velocity, and then
    nothing moves: no creep over 10 s of simulated time."""
    arm = TwoLinkArm()
    kp, kd = np.array([40.0, 20.0]), np.array([12.0, 5.0])
    goal = np.array([0.2, 0.8])
    c = core(arm, friction=JointFriction(coulomb=COULOMB, static=STATIC), q0=start)
    law = pd_gravity(arm, goal, kp, kd)
    run(c, law, 600)  # 6 s: settled and stuck
    error = goal - c.q
    band = STATIC / kp
    assert (np.abs(error) <= band * (1 + 1e-9)).all(), (error, band)
    # A joint stops either by sticking (velocity exactly 0) or, overdamped, by creeping
    # exponentially onto the point where Kp e equals the Coulomb torque (it never crosses
    # zero velocity): either way it is at rest to the last digits, inside the band.
    assert (c.stuck | (np.abs(c.qd) < 1e-9)).all(), (c.qd, c.stuck)
    q_rest, stuck = c.q.copy(), c.stuck.copy()
    states = run(c, law, 1000)  # 10 s more
    assert np.abs(states[:, :2] - q_rest).max() < 1e-9, 'no drift (1e-9 rad)'
    for j in np.flatnonzero(stuck):
        assert (states[:, j] == q_rest[j]).all() and (states[:, 2 + j] == 0.0).all(), \
            f'joint {j + 1} stuck: no creep, no chatter, bit for bit'
    assert c.friction_work > 0.0


def test_without_friction_the_same_loop_reaches_the_goal():
    """The contrast: the ideal arm under the same PD + gravity has no steady-state error."""
    arm = TwoLinkArm()
    c = core(arm)
    run(c, pd_gravity(arm, [0.2, 0.8], [40.0, 20.0], [12.0, 5.0]), 1500)
    assert np.abs(c.q - [0.2, 0.8]).max() < 1e-6


def test_friction_work_is_what_the_energy_balance_leaves():
    """Input work of the held torques = change in mechanical energy + friction work (no
    viscous damping), to the integrator's error (stated: 1e-6 J over 3 s)."""
    arm = TwoLinkArm()
    c = core(arm, friction=JointFriction(coulomb=COULOMB, static=STATIC))
    law = pd_gravity(arm, [0.4, 0.4], [60.0, 30.0], [3.0, 1.0])  # lightly damped: slips
    energy0 = sum(arm.energy(c.q, c.qd))
    work_in = 0.0
    for _ in range(300):
        q_before = c.q.copy()
        c.set_command(law(c))
        c.advance()
        work_in += float(c.applied @ (c.q - q_before))
    energy1 = sum(arm.energy(c.q, c.qd))
    assert work_in == pytest.approx(energy1 - energy0 + c.friction_work, abs=1e-6)
    assert c.friction_work > 0.1


def test_the_real_path_with_nothing_active_is_the_ideal_path_bit_for_bit():
    """A schedule whose only fault starts at 1000 s makes the core take each physics step
    on its own (friction_step, no friction): 200 periods equal the ideal core's."""
    arm = TwoLinkArm()
    law = pd_gravity(arm, [0.5, 0.5], [100.0, 60.0], [20.0, 12.0])
    ideal = run(core(arm), law, 200)
    late = schedule({'faults': [{'at': 1000.0, 'brake': {'joint': 1}}]})
    real = run(core(arm, disturbances=late), law, 200)
    assert np.array_equal(ideal, real)


# ---------------------------------------------------------------------- pushes
def test_a_pulse_adds_exactly_jacobian_transpose_force_over_its_physics_steps():
    """A 30 N tip pulse from 0.105 s for 0.05 s (mid control period, on the step grid):
    the core's states equal a hand loop of RK4 steps whose right-hand side adds J(q)^T F
    (at each stage's q) over exactly the steps in [0.105, 0.155) s, to 1e-12; the true
    effort is the motor's plus the mean push torque of the period (J^T F at each step's
    start)."""
    arm = TwoLinkArm()
    force = np.array([0.0, -30.0])
    dist = schedule({'pushes': [{'at': 0.105, 'tip_force': force.tolist(), 'shape': 'pulse',
                                 'duration': 0.05}]})
    c = core(arm, disturbances=dist)
    command = np.array([15.0, 4.0])
    q, qd = c.q.copy(), c.qd.copy()
    for k in range(30):
        c.set_command(command)
        c.advance()
        load_sum = np.zeros(2)
        for j in range(10):
            t = k * PERIOD_NS + j * STEP_NS
            on = 105_000_000 <= t < 155_000_000
            load_sum += arm.jacobian(q).T @ force if on else 0 * force

            def fd(q_, qd_, tau_, on=on):
                return arm.forward_dynamics(q_, qd_, tau_ + (arm.jacobian(q_).T @ force
                                                             if on else 0.0))
            q, qd = rk4_step(fd, q, qd, command, 1e-3)
        np.testing.assert_allclose(c.q, q, rtol=0, atol=1e-12)
        np.testing.assert_allclose(c.qd, qd, rtol=0, atol=1e-12)
        assert c.true_view().effort == pytest.approx(command + load_sum / 10, abs=1e-12)
        assert c.joint_view().effort == pytest.approx(command, abs=0)


def test_events_come_in_the_period_they_happen_in_with_their_exact_time():
    dist = schedule({'pushes': [{'at': 0.105, 'tip_force': [0.0, -30.0], 'shape': 'pulse',
                                 'duration': 0.05}],
                     'faults': [{'at': 0.2, 'until': 0.3, 'commands_dropped': {}}]})
    c = core(disturbances=dist)
    seen = []
    for _ in range(40):
        c.set_command([0.0, 0.0])
        c.advance()
        seen += [(c.time_ns, e.time_ns, e.kind, e.edge) for e in c.events]
    assert seen == [(110_000_000, 105_000_000, 'tip_force', 'start'),
                    (160_000_000, 155_000_000, 'tip_force', 'end'),
                    (210_000_000, 200_000_000, 'commands_dropped', 'start'),
                    (310_000_000, 300_000_000, 'commands_dropped', 'end')]


def test_a_live_push_starts_at_the_next_period_and_lasts_its_duration():
    arm = TwoLinkArm()
    c = core(arm)
    for _ in range(5):
        c.set_command([0.0, 0.0])
        c.advance()
    push = c.push([10.0, 0.0], 20_000_000)
    assert (push.start_ns, push.end_ns) == (50_000_000, 70_000_000)
    efforts = []
    for _ in range(4):
        q = c.q.copy()
        c.set_command([0.0, 0.0])
        c.advance()
        efforts.append(c.true_view().effort)
        assert [e.edge for e in c.events] in (['start'], ['end'], [])
        del q
    assert np.abs(efforts[0]).max() > 0 and np.abs(efforts[1]).max() > 0
    assert efforts[2] == [0.0, 0.0] and efforts[3] == [0.0, 0.0]
    with pytest.raises(ValueError, match='2 components'):
        c.push([1.0, 2.0, 3.0], 10_000_000)


# ---------------------------------------------------------------------- faults
def test_dropped_commands_never_reach_the_drive():
    dist = schedule({'faults': [{'at': 0.05, 'until': 0.08, 'commands_dropped': {}}]})
    c = core(disturbances=dist)
    applied = []
    for k in range(10):
        if c.accepts_command():
            c.set_command([float(k), 0.0])
        c.advance()
        applied.append(c.joint_view().effort[0])
    assert applied == [0.0, 1.0, 2.0, 3.0, 4.0, 4.0, 4.0, 4.0, 8.0, 9.0], \
        'the commands answering t = 0.05, 0.06, 0.07 s are lost; the drive keeps 4 N m'


def test_torque_loss_scales_what_the_joint_delivers_and_the_effort_says_so():
    dist = schedule({'faults': [{'at': 0.02, 'until': 0.04,
                                 'torque_loss': {'joint': 2, 'fraction': 0.25}}]})
    c = core(disturbances=dist)
    efforts = []
    for _ in range(5):
        c.set_command([10.0, 8.0])
        c.advance()
        efforts.append(c.joint_view().effort)
    assert efforts == [[10.0, 8.0], [10.0, 8.0], [10.0, 2.0], [10.0, 2.0], [10.0, 8.0]]


def test_a_brake_holds_its_joint_exactly_under_any_torque():
    dist = schedule({'faults': [{'at': 0.1, 'until': 0.5, 'brake': {'joint': 1}}]})
    c = core(disturbances=dist)
    for _ in range(10):
        c.set_command([30.0, 5.0])
        c.advance()
    c.set_command([30.0, 5.0])
    c.advance()
    held = c.q[0]
    for _ in range(38):
        c.set_command([60.0, -20.0])
        c.advance()
        assert c.q[0] == held and c.qd[0] == 0.0
    c.set_command([60.0, -20.0])
    c.advance()  # t = 0.5 s: released over the next period
    c.set_command([60.0, -20.0])
    c.advance()
    assert c.q[0] != held


def test_a_frozen_encoder_and_a_bias_show_in_the_measurement_only():
    dist = schedule({'faults': [{'at': 0.05, 'until': 0.1, 'encoder_frozen': {'joint': 2}},
                                {'at': 0.08, 'encoder_bias': {'joint': 1, 'bias': 0.05}}]})
    c = core(disturbances=dist)
    rows = []
    for _ in range(12):
        c.set_command([20.0, 6.0])
        c.advance()
        rows.append((c.time_ns, c.joint_view(), c.true_view()))
    frozen = {t: m.position[1] for t, m, _ in rows if 50_000_000 <= t < 100_000_000}
    assert len(set(frozen.values())) == 1, 'joint 2 reads one value while frozen'
    assert all(m.velocity[1] == 0.0 for t, m, _ in rows if t in frozen)
    for t, m, true in rows:
        bias = 0.05 if t >= 80_000_000 else 0.0
        assert m.position[0] == pytest.approx(true.position[0] + bias, abs=1e-15)
        if t not in frozen:
            assert m.position[1] == true.position[1]


# ---------------------------------------------------------------------- parameters
def test_friction_parameters_are_robot_parameters_with_a_checked_band():
    robot = resolve_robot({'coulomb_friction': [1.5, 0.5], 'static_friction': [1.95, 0.0]})
    assert robot['static_friction'] == [1.95, 0.0]
    with pytest.raises(ValueError, match=r'static_friction\[0\] = 1 N m is below '
                                         r'coulomb_friction\[0\] = 1.5'):
        resolve_robot({'coulomb_friction': [1.5, 0.5], 'static_friction': [1.0, 0.0]})
    with pytest.raises(ValueError, match='coulomb_friction'):
        resolve_robot({'coulomb_friction': [-1.0, 0.0]})


def test_the_real_arm_config_loads_as_robot_and_simulator_parameters():
    import yaml

    from arm_sim.launcher import config_file

    doc = yaml.safe_load(config_file('real_arm.yaml').read_text())
    robot = resolve_robot(doc['/**']['ros__parameters'])
    assert robot['gear_ratios'] == [100.0, 80.0] and robot['coulomb_friction'] == [1.5, 0.5]
    arm = TwoLinkArm.from_params(robot)
    assert arm.armature == pytest.approx((0.12, 0.0384))
    sim = doc['/**/simulator']['ros__parameters']
    assert sim['sensing_delay'] == 1 and sim['noise_seed'] == 1


# ---------------------------------------------------------------------- the node
SCENARIO = '''
pushes:
  - {at: 0.105, tip_force: [0.0, -30.0], shape: pulse, duration: 0.05}
faults:
  - {at: 0.2, until: 0.3, torque_loss: {joint: 2, fraction: 0.5}}
  - {at: 0.25, until: 0.28, commands_dropped: {}}
'''
REAL = {'coulomb_friction': [1.5, 0.5], 'static_friction': [1.95, 0.65],
        'gear_ratios': [100.0, 80.0], 'motor_inertias': [1.2e-5, 6.0e-6],
        'motor_damping': [1.0e-5, 1.0e-5]}


def ns_of(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def answer_states(ros, states, pub, law, periods: int) -> None:
    """Be the controller: answer each new state once with ``law(q, qd)`` until the state
    at ``periods`` control periods came."""
    from std_msgs.msg import Float64MultiArray

    from arm_sim.client import stamp_of

    answered: set[float] = set()

    def answer() -> float:
        m = states[-1]
        t = stamp_of(m)
        if t not in answered:
            answered.add(t)
            tau = law(np.array(m.position), np.array(m.velocity))
            pub.publish(Float64MultiArray(data=[float(v) for v in tau]))
        return t

    ros.wait_for(lambda: states and answer() >= periods * 0.01 - 1e-9, timeout=60,
                 what=f'{periods} control periods answered')


def test_the_node_runs_the_real_arm_bit_for_bit_as_the_core_and_publishes_its_events(
        ros, launch, tmp_path):
    """A lockstep simulator with motors, friction and a scenario (a tip pulse, a torque
    loss, dropped commands), answered by a PD + gravity controller in the test: its true
    states are the pure core's for the same answers, bit for bit; each start and end is on
    simulator/events with its exact simulated time; the true effort is the motor's plus
    the push."""
    from diagnostic_msgs.msg import DiagnosticStatus
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    from arm_sim.client import stamp_of

    scenario = tmp_path / 'scenario.yaml'
    scenario.write_text(SCENARIO)
    launch('simulator', params={'timing_mode': 'lockstep', 'disturbance_file': str(scenario),
                                **REAL})
    meas = ros.collect(JointState, 'joint_states')
    true = ros.collect(JointState, 'simulator/true_joint_states')
    events = ros.collect(DiagnosticStatus, 'simulator/events')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: meas and true, timeout=30, what='first states on both topics')
    arm = TwoLinkArm.from_params(REAL)
    kp, kd, goal = np.array([60.0, 30.0]), np.array([10.0, 4.0]), np.array([0.3, 0.9])

    def law(q, qd):
        return kp * (goal - q) - kd * qd + arm.gravity_vector(q)

    periods = 40
    answer_states(ros, meas, pub, law, periods)
    ros.wait_for(lambda: len(events) >= 6
                 and any(stamp_of(m) >= periods * 0.01 - 1e-9 for m in true), timeout=20,
                 what='six events and the true state of the last period')
    by_stamp = {ns_of(m): m for m in reversed(true)}
    # The pure core, the same answers.
    c = core(arm, friction=JointFriction(coulomb=COULOMB, static=STATIC),
             disturbances=schedule(__import__('yaml').safe_load(SCENARIO)))
    for k in range(periods):
        got = by_stamp[k * PERIOD_NS]
        assert list(got.position) == c.q.tolist() and list(got.velocity) == c.qd.tolist(), \
            f'true state at t = {k * 0.01:.2f} s: bit for bit'
        assert list(got.effort) == c.true_view().effort
        if c.accepts_command():
            c.set_command(law(c.q, c.qd))
        c.advance()
    want = [(e.time_ns, e.kind, e.edge) for e in
            c.disturbances.events(0, periods * PERIOD_NS)]  # type: ignore[union-attr]
    got_events = [(int(dict((kv.key, kv.value) for kv in m.values)['time_ns']),
                   dict((kv.key, kv.value) for kv in m.values)['kind'],
                   dict((kv.key, kv.value) for kv in m.values)['edge']) for m in events]
    assert got_events[:len(want)] == want and len(want) == 6
    assert [m.level for m in events[:2]] == [DiagnosticStatus.OK] * 2
    assert events[2].level == DiagnosticStatus.WARN and events[2].name == 'simulator: fault'


def test_a_live_push_on_the_topic_acts_from_the_next_period_as_j_transpose_f(ros, launch):
    """geometry_msgs/WrenchStamped on simulator/push: a tip force held push_duration from
    the next control period; the true effort exceeds the motor's by J(q)^T F."""
    from diagnostic_msgs.msg import DiagnosticStatus
    from geometry_msgs.msg import WrenchStamped
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    from arm_sim.client import stamp_of

    proc = launch('simulator', params={'timing_mode': 'lockstep', 'push_duration': 0.05})
    meas = ros.collect(JointState, 'joint_states')
    true = ros.collect(JointState, 'simulator/true_joint_states')
    events = ros.collect(DiagnosticStatus, 'simulator/events')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    push = ros.publisher(WrenchStamped, 'simulator/push')
    ros.wait_for(lambda: meas, timeout=30, what='the first state')
    ros.wait_matched(push, ['simulator'])
    arm = TwoLinkArm()

    def law(q, qd):
        return arm.gravity_vector(q) - 5.0 * qd

    answer_states(ros, meas, pub, law, 5)
    msg = WrenchStamped()
    msg.wrench.force.x, msg.wrench.force.y = 8.0, -20.0
    push.publish(msg)
    # Time stands still (lockstep, nobody answers) until the push is in: the log says so.
    ros.wait_for(lambda: 'live push' in proc.output(), timeout=20, what='the push taken')
    answer_states(ros, meas, pub, law, 15)
    ros.wait_for(lambda: len(events) >= 2, timeout=20, what='the push start and end events')
    values = {kv.key: kv.value for kv in events[0].values}
    assert values['label'] == 'live' and values['edge'] == 'start'
    start = int(values['time_ns'])
    assert start % PERIOD_NS == 0 and start >= 50_000_000, 'from the start of a period'
    assert {kv.key: kv.value for kv in events[1].values}['time_ns'] == str(start + 50_000_000)
    ros.wait_for(lambda: any(stamp_of(m) >= start * 1e-9 + 0.05 for m in true), timeout=20,
                 what='true states over the push')
    by_stamp = {ns_of(m): m for m in true}
    meas_at = {ns_of(m): m for m in meas}
    # The period from `start`: the effort published with the state at its end.
    t_end = start + PERIOD_NS
    extra = np.array(by_stamp[t_end].effort) - np.array(meas_at[t_end].effort)
    assert np.abs(extra).max() > 1.0
    # J^T F varies with q inside the period: the mean over its steps, near J(q_start)^T F.
    q0 = np.array(meas_at[start].position)  # no sensors: the true position
    np.testing.assert_allclose(extra, arm.jacobian(q0).T @ [8.0, -20.0], atol=0.05)


def test_an_untagged_controller_that_stalls_answers_each_state_once(ros, launch):
    """A naive untagged controller (it answers every state message it receives, in order)
    stalls 0.7 s (wall) at t = 0.2 s, as a loaded machine or SIGSTOP does. The simulator
    waits without re-sending the state (a copy would be answered too, and that answer
    taken for the next state), so the run is the pure core's, bit for bit, and each state
    was sent once."""
    import time

    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    launch('simulator', params={'timing_mode': 'lockstep'})
    inbox = ros.collect(JointState, 'joint_states', qos=1000)
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    arm = TwoLinkArm()
    kp, kd, goal = np.array([60.0, 30.0]), np.array([10.0, 4.0]), np.array([0.3, 0.9])

    def law(q, qd):
        return kp * (goal - q) - kd * qd + arm.gravity_vector(q)

    periods, stall_at = 40, 20 * PERIOD_NS
    done = {'n': 0, 'stall_until': None}

    def answer_inbox() -> bool:
        """Answer every message not answered yet, in order, unless stalled."""
        while done['n'] < len(inbox):
            m = inbox[done['n']]
            if ns_of(m) == stall_at and done['stall_until'] is None:
                done['stall_until'] = time.monotonic() + 0.7
            if done['stall_until'] is not None and time.monotonic() < done['stall_until']:
                return False
            done['n'] += 1
            pub.publish(Float64MultiArray(data=[float(v) for v in law(
                np.array(m.position), np.array(m.velocity))]))
        return bool(inbox) and ns_of(inbox[-1]) >= periods * PERIOD_NS

    ros.wait_for(lambda: inbox, timeout=30, what='the first state')
    ros.wait_for(answer_inbox, timeout=60, what=f'{periods} periods answered')
    stamps = [ns_of(m) for m in inbox]
    # The first state may go out again before the controller is known (discovery).
    assert stamps.count(stall_at) == 1, 'the stalled state was not re-sent'
    by_stamp = {ns_of(m): m for m in inbox}
    c = core(arm)
    for k in range(periods):
        got = by_stamp[k * PERIOD_NS]
        assert list(got.position) == c.q.tolist() and list(got.velocity) == c.qd.tolist(), \
            f'state at t = {k * 0.01:.2f} s: bit for bit'
        c.set_command(law(c.q, c.qd))
        c.advance()
