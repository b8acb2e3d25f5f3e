"""The controller's FollowJointTrajectory action server and controller_state.

Pure tests of goal validation, tolerances and result codes (arm_control.follow), then
process tests: simulator (lockstep) + controller as real processes, driven from an rclpy
ActionClient in the test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from arm_control import follow
from arm_control.core import ControllerCore
from arm_control.follow import GoalError, GoalMonitor, JointTolerance
from arm_control.laws import ControlLaw, Gains
from arm_control.trajectory import TrajectoryPoint
from arm_dynamics import TwoLinkArm

JOINTS = ('joint1', 'joint2')
Q0 = np.array([-0.4, 1.2])


def core() -> ControllerCore:
    law = ControlLaw('computed_torque', Gains(kp=(100.0, 60.0), kd=(20.0, 12.0)),
                     TwoLinkArm(), (60.0, 20.0))
    c = ControllerCore(JOINTS, law)
    c.update(10.0, Q0, np.zeros(2))  # the controller at t = 10 s, holding Q0
    return c


DEFAULTS = follow.default_tolerances([0.0, 0.0], [0.0, 0.0], 0.0, 0.01)


def accept(c: ControllerCore, names=JOINTS, points=None, stamp=0.0, **kw):
    points = [TrajectoryPoint(1.0, [0.3, 0.6])] if points is None else points
    return follow.accept_goal(c, list(names), points, stamp, 10.0, Q0, np.zeros(2),
                              DEFAULTS, **kw)


def refused(c: ControllerCore, **kw) -> GoalError:
    before = (c.trajectory, c.next)
    with pytest.raises(GoalError) as info:
        accept(c, **kw)
    assert (c.trajectory, c.next) == before, 'a refused goal keeps the reference'
    return info.value


def test_result_codes_are_control_msgs_ones():
    from control_msgs.action import FollowJointTrajectory
    r = FollowJointTrajectory.Result
    assert (follow.SUCCESSFUL, follow.INVALID_GOAL, follow.INVALID_JOINTS,
            follow.OLD_HEADER_TIMESTAMP, follow.PATH_TOLERANCE_VIOLATED,
            follow.GOAL_TOLERANCE_VIOLATED) == (
        r.SUCCESSFUL, r.INVALID_GOAL, r.INVALID_JOINTS, r.OLD_HEADER_TIMESTAMP,
        r.PATH_TOLERANCE_VIOLATED, r.GOAL_TOLERANCE_VIOLATED)


def test_a_goal_in_any_joint_order_is_mapped_and_a_zero_stamp_starts_now():
    c = core()
    got = accept(c, names=('joint2', 'joint1'), points=[TrajectoryPoint(1.0, [0.6, 0.3])])
    assert got.start == 10.0 and got.trajectory.duration == 1.0
    assert got.trajectory.positions[-1].tolist() == [0.3, 0.6]
    assert c.next == (got.trajectory, 10.0), 'takes over from the next state'


@pytest.mark.parametrize('kw, code, words', [
    ({'names': ('joint1', 'wrist')}, follow.INVALID_JOINTS, "unknown joint names ['wrist']"),
    ({'names': ('joint1',), 'points': [TrajectoryPoint(1.0, [0.3])]}, follow.INVALID_JOINTS,
     "joints ['joint2'] missing"),
    ({'names': ()}, follow.INVALID_JOINTS, 'missing from joint_names []'),
    ({'points': []}, follow.INVALID_GOAL, 'no points'),
    ({'points': [TrajectoryPoint(1.0, [0.3, 0.6, 0.0])]}, follow.INVALID_GOAL,
     'point 0 has 3 positions for 2 joints'),
    ({'points': [TrajectoryPoint(1.0, [0.3, 0.6], [0.0])]}, follow.INVALID_GOAL,
     'point 0 has 1 velocities'),
    ({'points': [TrajectoryPoint(1.0, [math.nan, 0.6])]}, follow.INVALID_GOAL, 'nan'),
    ({'stamp': 8.0}, follow.OLD_HEADER_TIMESTAMP,
     'starts at t=8.000 s and ends at t=9.000 s, but the state is at t=10.000 s'),
    ({'multi_dof_joints': ['base']}, follow.INVALID_GOAL, "multi_dof_trajectory names "
     "joints ['base']"),
    ({'path': [JointTolerance('wrist', 0.1)]}, follow.INVALID_GOAL,
     "path_tolerance names joint 'wrist'"),
    ({'goal': [JointTolerance('joint2', -2.0)]}, follow.INVALID_GOAL,
     'goal_tolerance position of joint2 [rad] must be > 0, 0 (the default) or -1 (no '
     'check), got -2.0'),
    ({'goal_time': -0.5}, follow.INVALID_GOAL, 'goal_time_tolerance [s] must be > 0'),
])
def test_a_bad_goal_is_refused_with_its_code_and_the_bad_value(kw, code, words):
    err = refused(core(), **kw)
    assert err.code == code, (follow.CODE_NAMES[err.code], str(err))
    assert words in str(err)


@pytest.mark.parametrize('kw, code', [
    ({'names': ('joint1', 'wrist')}, follow.INVALID_JOINTS),
    ({'names': ('joint1', 'joint1')}, follow.INVALID_JOINTS),
    ({'points': []}, follow.INVALID_GOAL),
    ({'points': [TrajectoryPoint(1.0, [9.0, 0.6])]}, follow.INVALID_GOAL),
    ({'path': [JointTolerance('wrist', 0.1)]}, follow.INVALID_GOAL),
])
def test_a_goal_gets_the_same_code_before_the_first_state_as_after_it(kw, code):
    from arm_dynamics.limits import JointLimits
    limits = JointLimits.from_params({
                                      'position_limits_lower': [-3.0, -3.0],
                                      'position_limits_upper': [3.0, 3.0],
                                      'velocity_limits': [10.0, 10.0]})
    law = ControlLaw('pd', Gains(kp=(100.0, 60.0), kd=(20.0, 12.0)), TwoLinkArm(),
                     (60.0, 20.0))
    fresh = ControllerCore(JOINTS, law, limits=limits)  # no state yet
    names = kw.pop('names', JOINTS)
    points = kw.pop('points', [TrajectoryPoint(1.0, [0.3, 0.6])])
    with pytest.raises(GoalError) as before:
        follow.check_goal(fresh, list(names), points, DEFAULTS, **kw)
    assert fresh.trajectory is None and fresh.trajectories_accepted == 0
    running = ControllerCore(JOINTS, law, limits=limits)
    running.update(10.0, Q0, np.zeros(2))
    with pytest.raises(GoalError) as after:
        follow.accept_goal(running, list(names), points, 0.0, 10.0, Q0, np.zeros(2),
                           DEFAULTS, **kw)
    assert before.value.code == after.value.code == code
    assert str(before.value) == str(after.value)


def test_a_goal_that_started_in_the_past_but_has_not_ended_is_joined():
    got = accept(core(), stamp=9.5)  # ends at 10.5 s, the state is at 10 s
    assert got.start == 9.5


def test_goal_tolerances_keep_replace_or_erase_the_defaults():
    defaults = follow.default_tolerances([0.1, 0.2], [0.01, 0.02], 1.5, 0.05)
    assert defaults.goal.velocity.tolist() == [0.05, 0.05], 'stopped velocity at the goal'
    tol = follow.goal_tolerances(
        defaults, JOINTS, path=[JointTolerance('joint2', 0.5, 2.0)],
        goal=[JointTolerance('joint1', -1.0, -1.0), JointTolerance('joint2', 0.0, 0.3)],
        goal_time=0.0)
    assert tol.path.position.tolist() == [0.1, 0.5]
    assert tol.path.velocity.tolist() == [0.0, 2.0]
    assert tol.goal.position.tolist() == [0.0, 0.02], '-1 erases, 0 keeps the default'
    assert tol.goal.velocity.tolist() == [0.0, 0.3]
    assert tol.goal_time == 1.5, 'goal_time_tolerance 0: the parameter'
    assert follow.goal_tolerances(defaults, JOINTS, goal_time=-1.0).goal_time == 0.0


def monitor(path=(0.0, 0.0), goal=(0.0, 0.0), goal_time=0.0, stopped=0.01) -> GoalMonitor:
    return GoalMonitor(JOINTS, follow.default_tolerances(path, goal, goal_time, stopped),
                       start=10.0, duration=1.0)


def test_the_path_tolerance_is_checked_while_the_trajectory_runs():
    m = monitor(path=(0.01, 0.0))
    q_des = np.array([0.1, 0.2])
    assert m.check(10.5, q_des - 0.009, np.zeros(2), q_des, np.zeros(2)) is None
    out = m.check(10.5, q_des - [0.02, 5.0], np.zeros(2), q_des, np.zeros(2))
    assert out is not None and out.code == follow.PATH_TOLERANCE_VIOLATED
    assert out.text == ('path tolerance violated at t=10.500 s (0.500 s into the '
                        'trajectory): joint1 position error 0.02 rad (tolerance 0.01 rad)')


def test_the_goal_succeeds_inside_the_goal_tolerance_at_rest():
    m = monitor(path=(1e-9, 1e-9), goal=(0.01, 0.01))
    q = np.array([0.3, 0.6])
    moving = m.check(11.0, q, np.array([0.02, 0.0]), q, np.zeros(2))
    assert moving is None, 'not at rest yet (stopped_velocity_tolerance 0.01 rad/s)'
    out = m.check(11.2, q + 0.005, np.zeros(2), q, np.zeros(2))
    assert out is not None and out.succeeded, 'the path tolerance no longer applies'
    assert 'goal reached at t=11.200 s (0.200 s after the trajectory ended)' in out.text


def test_the_goal_time_tolerance_bounds_the_wait_and_zero_waits_without_limit():
    q = np.array([0.3, 0.6])
    m = monitor(goal=(0.001, 0.001), goal_time=0.5)
    assert m.check(11.5, q + 0.01, np.zeros(2), q, np.zeros(2)) is None
    out = m.check(11.51, q + [0.0, 0.01], np.zeros(2), q, np.zeros(2))
    assert out is not None and out.code == follow.GOAL_TOLERANCE_VIOLATED
    assert ('0.510 s after the trajectory ended (goal_time_tolerance 0.5 s): joint2 '
            'position error -0.01 rad (tolerance 0.001 rad)') in out.text
    forever = monitor(goal=(0.001, 0.001), goal_time=0.0)
    assert forever.check(1e6, q + 0.01, np.zeros(2), q, np.zeros(2)) is None


# ---------------------------------------------------------------------------- processes

CTRL_PARAMS = {'constraints.goal': [1e-12, 1e-12], 'constraints.goal_time': 0.05}


@pytest.fixture
def arm(ros, launch):
    """Simulator (lockstep) + controller from config/arm.yaml, with goal-tolerance
    defaults no motion meets (1e-12 rad within 0.05 s); the test's ActionClient."""
    from control_msgs.action import FollowJointTrajectory
    from control_msgs.msg import JointTrajectoryControllerState
    from rclpy.action import ActionClient
    from sensor_msgs.msg import JointState

    from arm_sim.client import stamp_of
    from arm_sim.launcher import config_file

    launch('simulator', params_file=config_file(), params={'timing_mode': 'lockstep'})
    launch('controller', params_file=config_file(), params=CTRL_PARAMS)
    states = ros.collect(JointState, 'joint_states', qos=1000)
    ctrl = ros.collect(JointTrajectoryControllerState, 'arm_controller/controller_state',
                       qos=1000)
    client = ActionClient(ros.node, FollowJointTrajectory,
                          'arm_controller/follow_joint_trajectory')
    try:
        ros.wait_for(lambda: states and stamp_of(states[-1]) > 1.0, timeout=30,
                     what='the closed loop to run')
        ros.wait_for(client.server_is_ready, what='the action server')
        yield states, ctrl, client
    finally:
        client.destroy()


def goal_msg(points, names=JOINTS, stamp=0.0, **tolerances):
    """A FollowJointTrajectory goal: points (t, positions[, velocities, accelerations])."""
    from builtin_interfaces.msg import Duration, Time
    from control_msgs.action import FollowJointTrajectory
    from control_msgs.msg import JointTolerance as Tol
    from trajectory_msgs.msg import JointTrajectoryPoint

    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = list(names)
    sec = math.floor(stamp)
    goal.trajectory.header.stamp = Time(sec=sec, nanosec=round((stamp - sec) * 1e9))
    for t, pos, *rest in points:
        pt = JointTrajectoryPoint(positions=[float(x) for x in pos])
        pt.time_from_start = Duration(sec=math.floor(t),
                                      nanosec=round((t - math.floor(t)) * 1e9))
        if rest:
            pt.velocities = [float(x) for x in rest[0]]
            pt.accelerations = [float(x) for x in rest[1]]
        goal.trajectory.points.append(pt)
    for field in ('path_tolerance', 'goal_tolerance'):
        setattr(goal, field, [Tol(name=n, position=p) for n, p in
                              tolerances.get(field, {}).items()])
    if 'goal_time' in tolerances:
        g = tolerances['goal_time']
        goal.goal_time_tolerance = Duration(sec=math.floor(g),
                                            nanosec=round((g - math.floor(g)) * 1e9))
    return goal


class Sent:
    """A goal sent: its handle, result future and the feedback received."""

    def __init__(self, ros, client, goal) -> None:
        self.feedback: list = []
        # A reply can be lost while the server has not matched this client's reader yet
        # (conftest: Ros.RESEND): send again; a first goal that did run is preempted.
        for _ in range(5):
            future = client.send_goal_async(goal, feedback_callback=self.feedback.append)
            try:
                ros.wait_for(future.done, timeout=ros.RESEND, what='the goal response')
                break
            except pytest.fail.Exception:
                continue
        else:
            pytest.fail('the action server never answered the goal')
        self.ros, self.handle = ros, future.result()
        assert self.handle.accepted, 'every goal is accepted, then answered'
        self.result_future = self.handle.get_result_async()

    def result(self, timeout: float = 30.0):
        self.ros.wait_for(self.result_future.done, timeout=timeout, what='the goal result')
        return self.result_future.result()


def outcome(sent: Sent) -> tuple[int, int, str]:
    r = sent.result()
    return r.status, r.result.error_code, r.result.error_string


def test_goals_succeed_or_fail_with_the_result_codes(ros, arm):
    from action_msgs.msg import GoalStatus

    from arm_sim.client import stamp_of
    states, ctrl, client = arm
    # Success, joints in the other order; its own tolerances over the (tight) parameters.
    target = [0.3, 0.6]
    ok = Sent(ros, client, goal_msg([(1.0, target[::-1], [0, 0], [0, 0])],
                                    names=JOINTS[::-1], goal_tolerance=dict(
                                        zip(JOINTS, (1e-3, 1e-3))), goal_time=2.0))
    status, code, text = outcome(ok)
    assert (status, code) == (GoalStatus.STATUS_SUCCEEDED, follow.SUCCESSFUL), text
    assert text.startswith('goal reached at t='), text
    # The state the controller judged it on (its stamp and errors are in the text) is
    # within 1e-3 rad: checked on that state when this test's queue kept it (lockstep can
    # run more than 1000 states ahead of the test), and on the errors the result reports.
    t_reached = float(text.split('goal reached at t=')[1].split(' s')[0])
    errors = [float(v) for v in text.split('position errors [')[1].split(']')[0].split(',')]
    assert max(abs(e) for e in errors) <= 1e-3, text
    judged = [m for m in states if abs(stamp_of(m) - t_reached) < 5e-4]
    if judged:
        assert np.abs(np.array(judged[-1].position) - target).max() <= 1e-3
    # Feedback: one a command (depth 10: a busy reader may miss some), desired - actual.
    ros.wait_for(lambda: ok.feedback, what='feedback')
    for fb in (m.feedback for m in ok.feedback):
        assert list(fb.joint_names) == list(JOINTS) and stamp_of(fb) > 1.0
        assert list(fb.error.positions) == list(np.subtract(fb.desired.positions,
                                                            fb.actual.positions))
    # controller_state: reference, feedback, error, output per joint, stamped as the state
    ros.wait_for(lambda: ctrl, what='controller_state')
    s = ctrl[-1]
    assert list(s.joint_names) == list(JOINTS) and len(s.output.effort) == 2
    assert list(s.error.positions) == list(np.subtract(s.reference.positions,
                                                        s.feedback.positions))
    assert stamp_of(s) in {stamp_of(m) for m in states}
    # Refused goals: the code and the bad value.
    for goal, want, words in [
            (goal_msg([(1.0, [0, 0])], names=('joint1', 'wrist')), follow.INVALID_JOINTS,
             "unknown joint names ['wrist']"),
            (goal_msg([(1.0, [0, 0, 0])]), follow.INVALID_GOAL, '3 positions for 2 joints'),
            (goal_msg([(0.2, [0, 0])], stamp=0.1), follow.OLD_HEADER_TIMESTAMP,
             'trajectory ends in the past: it starts at t=0.100 s and ends at t=0.300 s')]:
        status, code, text = outcome(Sent(ros, client, goal))
        assert (status, code) == (GoalStatus.STATUS_ABORTED, want), text
        assert words in text
    # GOAL_TOLERANCE_VIOLATED: the parameters' 1e-12 rad within 0.05 s.
    status, code, text = outcome(Sent(ros, client, goal_msg([(0.5, [0.1, 0.9])])))
    assert (status, code) == (GoalStatus.STATUS_ABORTED, follow.GOAL_TOLERANCE_VIOLATED), text
    assert '(goal_time_tolerance 0.05 s)' in text and 'tolerance 1e-12 rad' in text
    # PATH_TOLERANCE_VIOLATED: 1e-7 rad along a fast move; then the arm holds.
    status, code, text = outcome(Sent(ros, client, goal_msg(
        [(0.3, [0.6, 0.2])], path_tolerance={'joint1': 1e-7, 'joint2': 1e-7})))
    assert (status, code) == (GoalStatus.STATUS_ABORTED,
                              follow.PATH_TOLERANCE_VIOLATED), text
    assert 'path tolerance violated at t=' in text and 'tolerance 1e-07 rad' in text


def held_after(ros, states, ctrl, t0: float) -> None:
    """From simulated time ``t0`` on, for 1 s: the reference is one measured position at
    rest and the arm stays there."""
    from arm_sim.client import stamp_of
    ros.wait_for(lambda: ctrl and stamp_of(ctrl[-1]) >= t0 + 1.0, timeout=30,
                 what='1 s of holding')
    refs = [s for s in ctrl if stamp_of(s) > t0 + 0.01]
    held = {tuple(s.reference.positions) for s in refs}
    assert len(held) == 1, f'one reference while held, got {len(held)}'
    assert all(list(s.reference.velocities) == [0.0, 0.0] for s in refs), 'at rest'
    assert held.pop() in {tuple(m.position) for m in states}, 'a measured position'
    last = ctrl[-1]
    assert np.abs(last.feedback.velocities).max() < 1e-3, 'the arm has stopped'
    assert np.abs(np.array(last.error.positions)).max() < 1e-3, 'where it was held'


def test_a_canceled_goal_holds_the_arm_where_it_is(ros, arm):
    from action_msgs.msg import GoalStatus

    from arm_sim.client import stamp_of
    states, ctrl, client = arm
    # 1000 s of motion: the cancel comes mid-motion however fast lockstep runs meanwhile.
    slow = Sent(ros, client, goal_msg([(1000.0, [0.3, 0.6], [0, 0], [0, 0])]))
    ros.wait_for(lambda: len(slow.feedback) > 50, what='the goal to run')
    cancel = slow.handle.cancel_goal_async()
    ros.wait_for(cancel.done, what='the cancel response')
    assert len(cancel.result().goals_canceling) == 1
    status, code, text = outcome(slow)
    assert (status, code) == (GoalStatus.STATUS_CANCELED, follow.SUCCESSFUL), text
    t_cancel = float(text.split('canceled at t=')[1].split(' s')[0])
    assert t_cancel < 1000.0, 'canceled mid-motion'
    held_after(ros, states, ctrl, t_cancel)
    assert stamp_of(states[-1]) > t_cancel


def test_goals_and_topic_trajectories_preempt_each_other(ros, arm):
    from action_msgs.msg import GoalStatus
    from diagnostic_msgs.msg import DiagnosticStatus
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    from arm_sim.client import stamp_of
    states, ctrl, client = arm
    first = Sent(ros, client, goal_msg([(1000.0, [0.3, 0.6], [0, 0], [0, 0])]))
    ros.wait_for(lambda: first.feedback, what='the first goal to run')
    second = Sent(ros, client, goal_msg([(0.5, [0.1, 0.9])], goal_tolerance={
        'joint1': 1e-3, 'joint2': 1e-3}, goal_time=2.0))
    status, code, text = outcome(first)
    assert (status, code) == (GoalStatus.STATUS_ABORTED, follow.INVALID_GOAL), text
    assert text.startswith('preempted by goal '), text
    status, code, text = outcome(second)
    assert (status, code) == (GoalStatus.STATUS_SUCCEEDED, follow.SUCCESSFUL), text
    # A trajectory on the topic preempts a goal (1000 s long: still running when it comes,
    # however fast lockstep runs) ...
    third = Sent(ros, client, goal_msg([(1000.0, [0.3, 0.6], [0, 0], [0, 0])]))
    ros.wait_for(lambda: third.feedback, what='the third goal to run')
    pub = ros.publisher(JointTrajectory, 'arm_controller/joint_trajectory')
    topic = JointTrajectory(joint_names=list(JOINTS), points=[JointTrajectoryPoint(
        positions=[-0.2, 1.0])])
    ros.wait_for(lambda: third.result_future.done() or pub.publish(topic), timeout=30,
                 what='the topic trajectory to preempt the goal')
    status, code, text = outcome(third)
    assert (status, code) == (GoalStatus.STATUS_ABORTED, follow.INVALID_GOAL), text
    assert text.startswith('preempted by a trajectory on arm_controller/joint_trajectory'), (
        text)
    # ... and a goal replaces the topic's trajectory (a slow one, then a set point goal).
    verdicts = ros.collect(DiagnosticStatus, 'arm_controller/trajectory_status')
    topic.points = [JointTrajectoryPoint(positions=[0.3, 0.6])]
    topic.points[0].time_from_start.sec = 1000
    ros.wait_for(lambda: any('over 1000.000 s' in v.message for v in verdicts)
                 or pub.publish(topic), what='the slow topic trajectory to be accepted')
    last = Sent(ros, client, goal_msg([(0.0, [0.0, 1.1])], goal_tolerance={
        'joint1': 1e-4, 'joint2': 1e-4}, goal_time=3.0))
    status, code, text = outcome(last)
    assert (status, code) == (GoalStatus.STATUS_SUCCEEDED, follow.SUCCESSFUL), text
    # A state 1 s (simulated) after the goal was reached: this test's subscription may be
    # far behind lockstep's states, so "100 more states received" can still be older.
    reached = float(text.split('goal reached at t=')[1].split()[0])
    ros.wait_for(lambda: states and stamp_of(states[-1]) >= reached + 1.0,
                 what='a state 1 s after the goal was reached')
    assert np.abs(np.array(states[-1].position) - [0.0, 1.1]).max() < 1e-4, (
        'the goal, not the slow topic trajectory, is followed')


def test_a_goal_before_the_first_state_is_answered_or_held_until_it(ros, launch):
    """Goals sent as soon as the server is ready, before any joint state: an unknown joint
    is INVALID_JOINTS at once; a valid goal waits (the simulator starts only once it was
    accepted) and then runs from the first state to success; a canceled waiting goal ends
    canceled with nothing moved."""
    from action_msgs.msg import GoalStatus
    from control_msgs.action import FollowJointTrajectory
    from rclpy.action import ActionClient
    from sensor_msgs.msg import JointState

    from arm_sim.client import stamp_of
    from arm_sim.launcher import config_file

    launch('controller', params_file=config_file())
    client = ActionClient(ros.node, FollowJointTrajectory,
                          'arm_controller/follow_joint_trajectory')
    try:
        ros.wait_for(client.server_is_ready, timeout=30, what='the action server')
        status, code, text = outcome(Sent(ros, client, goal_msg(
            [(1.0, [0, 0])], names=('joint1', 'wrist'))))
        assert (status, code) == (GoalStatus.STATUS_ABORTED, follow.INVALID_JOINTS), text
        assert "unknown joint names ['wrist']" in text
        canceled = Sent(ros, client, goal_msg([(1.0, [0.2, 0.9])]))
        cancel = canceled.handle.cancel_goal_async()
        ros.wait_for(cancel.done, what='the cancel response')
        status, code, text = outcome(canceled)
        assert (status, code) == (GoalStatus.STATUS_CANCELED, follow.SUCCESSFUL), text
        assert 'before the first joint state' in text
        target = [0.3, 0.6]
        held = Sent(ros, client, goal_msg([(1.0, target, [0, 0], [0, 0])],
                                          goal_tolerance=dict(zip(JOINTS, (1e-3, 1e-3))),
                                          goal_time=5.0))
        assert not held.result_future.done(), 'no state yet: the goal waits'
        states = ros.collect(JointState, 'joint_states', qos=1000)
        launch('simulator', params_file=config_file(), params={'timing_mode': 'lockstep'})
        status, code, text = outcome(held)
        assert (status, code) == (GoalStatus.STATUS_SUCCEEDED, follow.SUCCESSFUL), text
        t_reached = float(text.split('goal reached at t=')[1].split(' s')[0])
        # It ran from the first state: reached 1 s (its duration) after it, within the
        # goal_time_tolerance, not after a refusal and a hold.
        assert 1.0 <= t_reached <= 1.0 + 5.0, text
        ros.wait_for(lambda: states and stamp_of(states[-1]) >= t_reached, timeout=30,
                     what='the state the goal was reached at')
    finally:
        client.destroy()


def test_feedback_says_how_far_into_its_trajectory_the_reference_is(ros, arm):
    from arm_sim.client import stamp_of
    _, _, client = arm
    slow = Sent(ros, client, goal_msg([(1000.0, [0.3, 0.6], [0, 0], [0, 0])]))
    ros.wait_for(lambda: len(slow.feedback) > 20, what='feedback')
    fbs = [m.feedback for m in slow.feedback]
    into = [f.desired.time_from_start.sec + f.desired.time_from_start.nanosec * 1e-9
            for f in fbs]
    assert into[-1] > 0.0, 'time_from_start moves with the trajectory'
    # Consecutive feedback: time_from_start advances exactly as the states' stamps.
    steps = np.diff(into[-10:])
    stamps = np.diff([stamp_of(f) for f in fbs[-10:]])
    assert np.allclose(steps, stamps, atol=2e-9), (steps, stamps)
    assert all(f.error.time_from_start == f.desired.time_from_start for f in fbs)
    slow.handle.cancel_goal_async()
    outcome(slow)
