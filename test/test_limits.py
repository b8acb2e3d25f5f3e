"""Joint limits as everyone uses them, without ROS: the limits themselves, the simulator's
runaway envelope and end stops, the controller's refusal and the planner's goals, lines and
speeds."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from arm_control.core import ControllerCore
from arm_control.laws import ControlLaw, Gains
from arm_control.trajectory import TrajectoryError, TrajectoryPoint
from arm_dynamics import JointLimits, TwoLinkArm
from arm_dynamics.simulation import SimulatorCore
from arm_planner import PlannerSettings, PlanningError, plan_goal

ARM = TwoLinkArm()
LIMITS = JointLimits()  # the defaults: shoulder +-2 pi, elbow +-pi, 8 rad/s
EFFORT = np.array([60.0, 20.0])
Q0 = np.array([-0.4, 1.2])


def test_the_defaults_are_one_shoulder_turn_either_way_elbow_to_folded_and_8_rad_s():
    assert LIMITS.lower == (-2 * math.pi, -math.pi) and LIMITS.upper == (2 * math.pi, math.pi)
    assert LIMITS.velocity == (8.0, 8.0)


@pytest.mark.parametrize('lower, upper, velocity, words', [
    ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0), 'joint 2 position limits must satisfy lower < upper'),
    ((math.inf, 0.0), (math.inf, 1.0), (1.0, 1.0), 'joint 1 position limits'),
    ((0.0, 0.0), (1.0, 1.0), (1.0, 0.0), 'velocity limits must be > 0 rad/s'),
    ((0.0,), (1.0, 1.0), (1.0, 1.0), 'one value per joint'),
])
def test_inconsistent_limits_are_refused_naming_them(lower, upper, velocity, words):
    with pytest.raises(ValueError, match=words):
        JointLimits(lower, upper, velocity)


def test_infinite_limits_mean_none():
    free = JointLimits((-math.inf,) * 2, (math.inf,) * 2, (math.inf,) * 2)
    assert free.violation([1e300, -1e300], [1e300, 0.0]) is None
    assert free.position_violation([math.nan, 0.0]) is not None  # NaN is never inside


def test_violations_name_the_joint_the_value_and_the_limit():
    assert LIMITS.violation(Q0, [0.0, 0.0]) is None and LIMITS.contains(Q0, [0.0, 0.0])
    assert LIMITS.position_violation([[0.0, 0.0], [0.0, 1e300]]) == (
        'joint 2 position 1e+300 rad > upper limit 3.14159 rad (point 1)')
    assert LIMITS.violation([-7.0, 0.0], [0.0, 0.0]) == (
        'joint 1 position -7 rad < lower limit -6.28319 rad')
    assert LIMITS.violation(Q0, [0.0, -9.5]) == 'joint 2 speed 9.5 rad/s > limit 8 rad/s'
    assert not LIMITS.contains(Q0, [0.0, -9.5])


def test_the_envelope_widens_positions_by_the_margin_and_speeds_by_the_factor():
    env = LIMITS.envelope(0.5, 2.0)
    assert env.upper == (2 * math.pi + 0.5, math.pi + 0.5) and env.velocity == (16.0, 16.0)


def test_a_hard_stop_puts_the_joint_on_its_limit_and_removes_its_outward_speed():
    q, qd = LIMITS.hard_stop(np.array([0.0, 3.3]), np.array([1.0, 2.0]))
    assert q.tolist() == [0.0, math.pi] and qd.tolist() == [1.0, 0.0]
    q, qd = LIMITS.hard_stop(np.array([0.0, 3.3]), np.array([1.0, -2.0]))  # moving back in
    assert qd.tolist() == [1.0, -2.0]


# ---------------------------------------------------------------------- simulator
def core(torque, **kw) -> SimulatorCore:
    sim = SimulatorCore(ARM, q0=Q0, qd0=[0.0, 0.0], effort_limits=EFFORT,
                        physics_step_ns=1_000_000, control_period_ns=10_000_000,
                        velocity_limit=1000.0, joint_names=('joint1', 'joint2'),
                        joint_limits=LIMITS, **kw)
    sim.set_command(torque)
    return sim


def test_a_runaway_is_a_fault_that_holds_the_last_good_state_until_reset():
    sim = core([0.0, 20.0], envelope=LIMITS.envelope(0.5, 2.0))  # saturated elbow spins up
    outside_seen = False
    for _ in range(1000):
        sim.advance()
        outside_seen |= sim.outside_limits is not None
        if sim.diverged:
            break
    assert outside_seen, 'the state left the limits before the envelope'
    assert sim.diverged.startswith('runaway at t=') and 'joint 2' in sim.diverged
    held = (sim.q.copy(), sim.qd.copy())
    assert LIMITS.envelope(0.5, 2.0).contains(*held), 'the last good state is inside'
    assert held[1].tolist() == [0.0, 0.0], 'the last good position, held at rest'
    sim.advance()
    assert np.array_equal(sim.q, held[0]) and sim.applied.tolist() == [0.0, 0.0]
    assert sim.qd.tolist() == [0.0, 0.0] and sim.joint_view().velocity == [0.0, 0.0]
    sim.reset()
    assert sim.diverged is None and sim.q.tolist() == Q0.tolist()
    sim.advance()
    assert sim.diverged is None


def test_hard_stops_keep_every_state_within_the_position_limits():
    sim = core([0.0, 20.0], hard_stops=True)
    reached = []
    for _ in range(300):
        sim.advance()
        assert LIMITS.position_violation(sim.q) is None
        reached.append(sim.q[1])
    assert max(reached) == pytest.approx(math.pi), 'pushed against the elbow stop'


def test_a_state_going_non_finite_within_a_period_against_the_stops_is_a_fault_not_a_crash():
    # An absurd speed (limits opened wide) overflows within the period: the end-stop path
    # steps one physics step at a time, and the step after the overflow refuses its input.
    sim = SimulatorCore(ARM, q0=[0.0, 0.5], qd0=[1e150, 0.0], effort_limits=EFFORT,
                        physics_step_ns=1_000_000, control_period_ns=10_000_000,
                        velocity_limit=1e300, joint_names=('joint1', 'joint2'),
                        joint_limits=JointLimits(velocity=(1e300, 1e300)), hard_stops=True)
    sim.advance()
    assert sim.diverged and 'integration diverged' in sim.diverged
    assert sim.q.tolist() == [0.0, 0.5], 'the last good state is held'


# ---------------------------------------------------------------------- controller
def controller() -> ControllerCore:
    law = ControlLaw('pd', Gains(kp=(100.0, 60.0), kd=(20.0, 12.0)), ARM, tuple(EFFORT))
    return ControllerCore(('joint1', 'joint2'), law, limits=LIMITS)


@pytest.mark.parametrize('point, words', [
    (TrajectoryPoint(0.0, (1e300, 0.0)), 'joint 1 position 1e+300 rad > upper limit'),
    (TrajectoryPoint(0.0, (0.0, -100.0)), 'joint 2 position -100 rad < lower limit'),
    (TrajectoryPoint(1.0, (0.0, 0.0), (9.0, 0.0)), 'joint 1 speed 9 rad/s > limit 8'),
])
def test_the_controller_refuses_a_trajectory_leaving_the_limits_and_keeps_its_reference(
        point, words):
    ctl = controller()
    ctl.update(0.0, Q0, np.zeros(2))
    before = ctl.trajectory
    with pytest.raises(TrajectoryError,
                       match=re.escape(f'trajectory leaves the joint limits: {words}')):
        ctl.set_trajectory(('joint1', 'joint2'), [point], 0.0, Q0, np.zeros(2))
    assert ctl.trajectory is before


# ---------------------------------------------------------------------- planner
def plan(goal, q=Q0, **settings):
    return plan_goal(ARM, EFFORT, np.asarray(q, float), np.asarray(goal, float),
                     PlannerSettings(**settings), LIMITS)


def test_a_goal_is_planned_at_the_turn_of_the_shoulder_inside_its_limits():
    # From the shoulder at 6.0 rad, the nearest turn of the goal's 0.15 rad would be 6.43 rad,
    # past 2 pi: the goal is planned at 0.15 rad instead (going back within the limits).
    p = plan((1.0, 1.2), q=(6.0, 1.0), regulation_profile='synchronized')
    assert LIMITS.position_violation(p.q) is None
    assert abs(p.q[-1, 0] - 6.0) > math.pi, 'the long way round, inside the limits'
    assert np.hypot(*(ARM.forward_kinematics(p.q[-1]) - (1.0, 1.2))) < 1e-9


def test_a_goal_no_turn_of_which_fits_the_limits_is_refused_with_the_numbers():
    narrow = JointLimits((-1.0, -math.pi), (1.0, math.pi), (8.0, 8.0))
    with pytest.raises(PlanningError, match=r'needs joint 1 at .* outside its limits \[-1, 1\]'):
        plan_goal(ARM, EFFORT, Q0, np.array([-1.0, -0.5]), PlannerSettings(), narrow)


def test_a_line_that_would_leave_the_limits_is_refused_where_a_joint_move_is_not():
    # The line to (0.5, 1.0) m bends the elbow to 1.854 rad on the way; it ends at 1.817.
    narrow = JointLimits(LIMITS.lower, (2 * math.pi, 1.835), LIMITS.velocity)
    with pytest.raises(PlanningError, match=r'the motion leaves the joint limits: joint 2 '
                                            r'would reach 1\.85\d* rad > upper limit 1\.835 rad'):
        plan_goal(ARM, EFFORT, Q0, np.array([0.5, 1.0]),
                  PlannerSettings(mode='straight_line'), narrow)
    p = plan_goal(ARM, EFFORT, Q0, np.array([0.5, 1.0]),
                  PlannerSettings(regulation_profile='synchronized'), narrow)
    assert p.q[:, 1].max() <= 1.835


@pytest.mark.parametrize('mode', ['straight_line', 'regulation'])
def test_a_motion_too_fast_for_the_speed_limits_is_stretched_or_refused(mode):
    slow = JointLimits(LIMITS.lower, LIMITS.upper, (0.3, 0.3))
    settings = dict(mode=mode, regulation_profile='synchronized', duration=0.5)
    p = plan_goal(ARM, EFFORT, Q0, np.array([0.5, 1.0]), PlannerSettings(**settings), slow)
    assert p.stretched_from == 0.5 and p.duration > 0.5
    assert np.abs(p.qd).max() <= 0.3 + 1e-9
    assert any('exceed its speed limit' in m for m in p.messages)
    with pytest.raises(PlanningError, match='fastest duration within them is'):
        plan_goal(ARM, EFFORT, Q0, np.array([0.5, 1.0]),
                  PlannerSettings(**settings, feasibility='refuse'), slow)


# ---------------------------------------------------------------------- property
def log_uniform(rng, lo: float, hi: float) -> float:
    return float(10 ** rng.uniform(math.log10(lo), math.log10(hi)))


def test_random_goals_settings_and_trajectories_never_escape_the_limits_or_raise():
    """1200 seeded random cases: goals anywhere (inside, outside and on the edge of the
    workspace), from rest or moving at up to 3 rad/s, every mode/profile/scaling/policy,
    limits from 1e-300 up and durations up to 1e4 s are either planned within the joint
    and effort limits or refused with a
    PlanningError; random trajectories are accepted only within the limits, and every
    command the controller then gives is finite and within the effort limits."""
    rng = np.random.default_rng(10)
    planned = refused = 0
    for case in range(1000):
        q = rng.uniform([-6.0, -3.0], [6.0, 3.0])
        goal = rng.uniform(-2.2, 2.2, 2)
        settings = PlannerSettings(
            mode=str(rng.choice(['regulation', 'straight_line'])),
            elbow=str(rng.choice(['up', 'down', 'keep'])),
            time_scaling=str(rng.choice(['quintic', 'trapezoidal'])),
            duration=float(rng.choice([0.0, log_uniform(rng, 1e-3, 1e4)])),
            max_speed=log_uniform(rng, 1e-300, 100.0),
            max_acceleration=log_uniform(rng, 1e-300, 1000.0),
            joint_max_velocity=log_uniform(rng, 1e-300, 1000.0),
            joint_max_acceleration=log_uniform(rng, 1e-300, 1e5),
            regulation_profile=str(rng.choice(['set_point', 'synchronized'])),
            feasibility=str(rng.choice(['stretch', 'refuse'])))
        qd = rng.uniform(-3.0, 3.0, 2) if rng.random() < 0.5 else None  # moving or not
        try:
            p = plan_goal(ARM, EFFORT, q, goal, settings, LIMITS, qd_current=qd)
        except PlanningError:
            refused += 1
            continue
        planned += 1
        assert np.isfinite(p.q).all() and np.isfinite(p.qd).all(), case
        assert LIMITS.position_violation(p.q[1:]) is None, (case, settings)
        assert LIMITS.velocity_violation(p.qd) is None, (case, settings)
        assert (p.peak_torque <= EFFORT + 1e-9).all() or p.profile == 'set_point', case
        assert p.duration <= 3600.0, case
    assert planned > 100 and refused > 100, (planned, refused)  # both paths exercised
    ctl = controller()
    ctl.update(0.0, Q0, np.zeros(2))
    for case in range(200):
        k = int(rng.integers(1, 4))
        scale = log_uniform(rng, 1e-3, 1e300)
        points = [TrajectoryPoint(float(t), tuple(rng.uniform(-1, 1, 2) * scale),
                                  tuple(rng.uniform(-1, 1, 2) * min(scale, 1e3)))
                  for t in np.cumsum(rng.uniform(0.01, 2.0, k))]
        try:
            traj = ctl.set_trajectory(('joint1', 'joint2'), points, 0.0, Q0, np.zeros(2))
        except TrajectoryError:
            continue
        assert LIMITS.position_violation(traj.positions[1:]) is None
        for t in np.linspace(0.0, traj.times[-1] + 0.5, 7):
            tau = ctl.update(float(t), Q0, np.zeros(2)).command.tau
            assert np.isfinite(tau).all() and (np.abs(tau) <= EFFORT).all(), (case, tau)
        ctl.hold(float(traj.times[-1]) + 1.0, Q0, np.zeros(2))
        ctl.last = None


def test_an_initial_state_the_first_step_would_fault_on_is_named_with_its_bound():
    from arm_dynamics.robot import ROBOT_DEFAULTS
    from arm_dynamics.simulation import initial_position_reason, initial_velocity_reason

    sim = {**ROBOT_DEFAULTS, 'fault_position_margin': 0.5, 'fault_velocity_factor': 2.0,
           'velocity_limit': 1000.0, 'initial_positions': [-0.4, 1.2],
           'initial_velocities': [0.0, 0.0], 'geared.gear_ratio': 50.0}
    assert initial_position_reason(sim) is None and initial_velocity_reason(sim) is None
    at_edge = {**sim, 'initial_positions': [2 * np.pi + 0.5, 0.0],
               'initial_velocities': [-16.0, 16.0]}  # on the envelope: allowed
    assert initial_position_reason(at_edge) is None and initial_velocity_reason(at_edge) is None
    assert initial_velocity_reason({**sim, 'initial_velocities': [990.0, -990.0]}) == (
        'initial_velocities: joint 1 initial speed 990 rad/s > limit 16 rad/s, beyond the '
        'runaway envelope (velocity_limits times fault_velocity_factor 2): the first step '
        'would be a runaway fault')
    assert initial_position_reason({**sim, 'initial_positions': [0.0, -3.7]}).startswith(
        'initial_positions: joint 2 initial position -3.7 rad < lower limit -3.64159 rad')
    slow_limit = {**sim, 'velocity_limit': 10.0, 'initial_velocities': [0.0, 12.0]}
    assert 'joint 2 initial speed 12 rad/s > velocity_limit 10 rad/s' in (
        initial_velocity_reason(slow_limit))
    # The geared link has no joint limits; its motor turns gear_ratio times the link.
    geared = {**sim, 'model': 'single_link_geared', 'initial_positions': [50.0, 0.0]}
    assert initial_position_reason(geared) is None
    assert initial_velocity_reason({**geared, 'initial_velocities': [19.0, 0.0]}) is None
    assert 'motor initial speed (link x gear_ratio 50) 1050 rad/s > velocity_limit' in (
        initial_velocity_reason({**geared, 'initial_velocities': [21.0, 0.0]}))
