"""Topic-level tests of the ``simulator`` node (a real process on a private domain)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import count, events, statuses, values
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from scipy.integrate import solve_ivp
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from arm_dynamics import TwoLinkArm
from arm_sim.client import stamp_of as stamp

ARM = TwoLinkArm()  # the node's defaults are the contract's arm


def command(values, answers=None) -> Float64MultiArray:
    """An effort command; ``answers``: the JointState it answers (tagged, as arm_sim's
    controller tags them), None = untagged."""
    msg = Float64MultiArray(data=[float(v) for v in values])
    if answers is not None:
        from std_msgs.msg import MultiArrayDimension

        from arm_dynamics.timing import answer_tag
        ns = answers.header.stamp.sec * 1_000_000_000 + answers.header.stamp.nanosec
        msg.layout.dim = [MultiArrayDimension(label=answer_tag(ns), size=len(msg.data),
                                              stride=len(msg.data))]
    return msg


class Answerer:
    """Plays a lockstep controller: each call answers the latest state with ``tau``, once
    per stamp (the simulator re-sends a state it got no answer to), and returns that
    stamp [s]; ``answered`` holds every stamp answered."""

    def __init__(self, states: list, pub, tau) -> None:
        self.states, self.pub, self.tau = states, pub, tau
        self.answered: set[float] = set()

    def __call__(self) -> float:
        t = stamp(self.states[-1])
        if t not in self.answered:
            self.answered.add(t)
            self.pub.publish(command(self.tau))
        return t


def summaries(diags: list) -> list[str]:
    """The messages of the simulator's periodic summary."""
    return [s.message for s in statuses(diags, '/simulator', 'summary')]


def test_lockstep_motion_under_constant_torque_matches_solve_ivp(ros, launch):
    q0, tau = [-0.4, 1.2], [12.0, -3.0]
    launch('simulator', params={'timing_mode': 'lockstep', 'initial_positions': q0})
    states = ros.collect(JointState, 'joint_states')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: states, what='first joint state')
    drive = Answerer(states, pub, tau)  # lockstep: one command advances one period
    ros.wait_for(lambda: drive() >= 1.5 - 1e-9, timeout=60, what='1.5 s of simulated time')
    first = {stamp(m): m for m in states}
    times = np.array(sorted(first))
    assert times[0] == 0.0 and np.allclose(np.diff(times), 0.01), 'one state per 10 ms period'
    q = np.array([first[t].position for t in times])
    ref = solve_ivp(lambda _t, x: np.concatenate([x[2:], ARM.forward_dynamics(
        x[:2], x[2:], tau)]), (0, times[-1]), [*q0, 0.0, 0.0], method='DOP853',
        rtol=1e-12, atol=1e-12, t_eval=times)
    err = np.abs(q - ref.y[:2].T).max()
    assert err < 1e-6, f'published motion deviates from solve_ivp by {err:.2e} rad'
    assert np.ptp(q[:, 0]) > 0.1, 'the torque really moved the arm'
    assert all(m.effort == pytest.approx(tau) for m in states[1:]), 'effort = applied torque'
    assert list(states[0].name) == ['joint1', 'joint2']


def test_lockstep_advances_only_on_commands(ros, launch):
    launch('simulator', params={'timing_mode': 'lockstep'})
    states = ros.collect(JointState, 'joint_states')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    # Heartbeats re-send t=0 while no command comes: several states, time stands still.
    ros.wait_for(lambda: len(states) >= 3, what='three heartbeat states')
    assert {stamp(m) for m in states} == {0.0}
    for k in range(1, 4):
        pub.publish(command([0.0, 0.0]))
        ros.wait_for(lambda: any(stamp(m) > 0.01 * (k - 0.5) for m in states),
                     what=f'state after command {k}')
        assert max(stamp(m) for m in states) == pytest.approx(0.01 * k, abs=1e-12)


def test_bad_commands_are_refused_and_node_keeps_publishing(ros, launch):
    launch('simulator', params={'timing_mode': 'real_time', 'command_timeout': 0.0})
    states = ros.collect(JointState, 'joint_states')
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: states, what='first joint state')
    good = [5.0, 1.0]
    # Tagged: while time stands still the state is re-sent (to an untagged controller
    # only when a new subscriber or publisher matched: arm_dynamics.timing).
    pub.publish(command(good, answers=states[-1]))
    ros.wait_for(lambda: states[-1].effort == pytest.approx(good), what='good command applied')
    bad_inputs = {'non-finite': [math.nan, 1.0], 'infinite': [math.inf, 0.0],
                  'too short': [1.0], 'too long': [1.0, 2.0, 3.0]}
    for k, (label, data) in enumerate(bad_inputs.items(), start=1):
        pub.publish(Float64MultiArray(data=data))
        # Counted at once; reported at once, or (throttled) with the next periodic report.
        ros.wait_for(lambda: count(diags, '/simulator', 'rejected_command') >= k,
                     what=f'/diagnostics report of the {label} command')
        n = len(states)
        ros.wait_for(lambda: len(states) > n + 3, what='states after the bad command')
        last = states[-1]
        assert last.effort == pytest.approx(good), f'{label}: last good command kept'
        assert np.isfinite(last.position).all() and np.isfinite(last.velocity).all()


def test_effort_is_saturated_at_the_limits(ros, launch):
    launch('simulator', params={'timing_mode': 'lockstep', 'effort_limits': [60.0, 20.0]})
    states = ros.collect(JointState, 'joint_states')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: states, what='first joint state')
    pub.publish(command([500.0, -100.0]))
    ros.wait_for(lambda: stamp(states[-1]) > 0, what='one step')
    assert list(states[-1].effort) == [60.0, -20.0]


def test_wall_clock_opt_in_command_timeout_sets_torque_to_zero_and_reports(ros, launch):
    launch('simulator', params={'timing_mode': 'wall_clock', 'command_timeout': 0.3})
    states = ros.collect(JointState, 'joint_states')
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: states, what='first joint state')
    pub.publish(command([10.0, 2.0]))
    ros.wait_for(lambda: states[-1].effort == pytest.approx([10.0, 2.0]), what='command')
    ros.wait_for(lambda: list(states[-1].effort) == [0.0, 0.0], timeout=5,
                 what='zero torque after the timeout')
    timeout = ros.wait_for(lambda: statuses(diags, '/simulator', 'command_timeout'),
                           what='timeout on /diagnostics')[0]
    assert timeout.level == DiagnosticStatus.WARN and values(timeout)['command_timeout'] == '0.3'
    # The periodic summary says so too, while its own status stays apart.
    ros.wait_for(lambda: 'command timeout: applying zero torque' in summaries(diags),
                 what='the summary of the timeout')


def test_reset_restores_the_initial_state(ros, launch):
    q0 = [0.3, -0.7]
    launch('simulator', params={'timing_mode': 'wall_clock', 'initial_positions': q0,
                                'wait_for_command': False})
    states = ros.collect(JointState, 'joint_states')
    ros.wait_for(lambda: states and abs(states[-1].position[0] - q0[0]) > 0.2,
                 what='the arm to fall away from q0')
    reply = ros.call(Trigger, '/simulator/reset', Trigger.Request())
    assert reply.success, reply.message
    n = len(states)
    ros.wait_for(lambda: len(states) > n, what='a state after reset')
    after_reset = [m for m in states[n - 1:] if m.position == pytest.approx(q0, abs=1e-12)]
    assert after_reset, 'a state at exactly q0 was published after reset'
    assert list(after_reset[0].velocity) == [0.0, 0.0]
    assert stamp(after_reset[0]) > 0, 'simulated time keeps running through a reset'


def test_divergence_stops_integration_and_holds_last_good_state(ros, launch):
    # A feather-light arm with huge effort limits: full torque sends it past velocity_limit.
    launch('simulator', params={'timing_mode': 'lockstep', 'link_masses': [1e-3, 1e-3],
                                'link_inertias': [1e-6, 1e-6], 'effort_limits': [1e6, 1e6],
                                'velocity_limit': 100.0})
    states = ros.collect(JointState, 'joint_states')
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: states, what='first joint state')
    for k in range(1, 4):
        pub.publish(command([1e6, -1e6]))
        ros.wait_for(lambda: stamp(states[-1]) >= 0.01 * k - 1e-9, what=f'step {k}')
    diverged = ros.wait_for(lambda: statuses(diags, '/simulator', 'diverged'),
                            what='divergence reported')[0]
    assert diverged.level == DiagnosticStatus.ERROR
    held = states[-1]
    assert np.isfinite(held.position).all()
    assert list(held.velocity) == [0.0, 0.0], 'the last good position held at rest'
    assert list(held.effort) == [0.0, 0.0], 'no torque applied while diverged'
    assert held.position == states[-2].position, 'last good state is held'
    reply = ros.call(Trigger, '/simulator/reset', Trigger.Request())
    assert reply.success
    ros.wait_for(lambda: states[-1].position == pytest.approx([-0.4, 1.2]),
                 what='reset state published')


def test_a_runaway_is_reported_once_held_and_recovered_by_reset(ros, launch):
    # The contract's arm with its elbow driven at full torque: it spins up past its speed
    # limit (8 rad/s: reported) and on to the runaway envelope (2x: a fault).
    launch('simulator', params={'timing_mode': 'lockstep'})
    states = ros.collect(JointState, 'joint_states')
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: states, what='first joint state')

    def reported(kind: str) -> list:
        return events(diags, '/simulator', kind)

    drive = Answerer(states, pub, [0.0, 20.0])
    fault = ros.wait_for(lambda: drive() is not None and reported('runaway'), timeout=60,
                         what='the runaway fault')[0]
    assert fault.level == DiagnosticStatus.ERROR
    assert 'runaway at t=' in fault.message and 'joint 2 speed' in fault.message
    assert reported('outside_limits'), 'leaving the limits was reported before the fault'
    # Held: further commands advance time but the state stays the last good one.
    n = len(states)
    ros.wait_for(lambda: drive() is not None and len(states) > n + 5,
                 what='states after the fault')
    held = states[n - 1:]
    assert all(m.position == held[0].position for m in held), 'the last good state is held'
    # At rest: a frozen arm does not move, and nobody should plan from a speed it lost.
    assert all(list(m.velocity) == [0.0, 0.0] for m in held[1:]), 'held with zero velocity'
    assert all(list(m.effort) == [0.0, 0.0] for m in held[1:]), 'no torque while faulted'
    assert len(reported('runaway')) == 1, 'reported once'
    # The summary reports the fault (ERROR, its reason) while it lasts.
    ros.wait_for(lambda: [s for s in statuses(diags, '/simulator', 'summary')
                          if s.level == DiagnosticStatus.ERROR
                          and s.message.startswith('runaway at t=')],
                 what='the summary to report the fault')
    n, d0 = len(states), len(diags)
    assert ros.call(Trigger, '/simulator/reset', Trigger.Request()).success
    reset = ros.wait_for(lambda: [m for m in states[n:] if m.position == pytest.approx(
        [-0.4, 1.2], abs=1e-12)], what='the reset state')[0]
    cleared = ros.wait_for(lambda: events(diags[d0:], '/simulator', 'reset'),
                           what='the reset reported at once')[0]
    assert values(cleared)['cleared'].startswith('runaway at t='), 'naming the fault'
    # Time runs on after the reset (an answer sent just before it may advance it once).
    # Holding torque: with none the arm would fall, swing and may run away again.
    run_on = Answerer(states, pub, ARM.gravity_vector(np.array([-0.4, 1.2])).tolist())
    ros.wait_for(lambda: run_on() > stamp(reset) + 0.015,
                 what='the simulation to run again after reset')
    ros.wait_for(lambda: [run_on()] and any(  # driven on: a waiting simulator says WARN
        s.level == DiagnosticStatus.OK for s in statuses(diags[d0:], '/simulator', 'summary')),
        what='the summary back to OK')
    # The fault's own status persists, decayed to OK with its count once it is over.
    ros.wait_for(lambda: [run_on()] and [
        s for s in statuses(diags[d0:], '/simulator', 'runaway')
        if s.level == DiagnosticStatus.OK and values(s).get('last_level') == 'ERROR'
        and values(s)['count'] == '1'], what='the runaway status decayed to OK')


def test_lockstep_pauses_at_pause_at_and_resumes_when_it_moves(ros, launch):
    launch('simulator', params={'timing_mode': 'lockstep', 'pause_at': 0.05})
    states = ros.collect(JointState, 'joint_states')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: states, what='first joint state')
    drive = Answerer(states, pub, [1.0, 0.0])

    def answer(until):
        return lambda: drive() >= until - 1e-9

    diags = ros.collect(DiagnosticArray, '/diagnostics')
    ros.wait_for(answer(0.05), what='time to reach pause_at')
    ros.wait_for(lambda: any('paused at t=0.050' in m for m in summaries(diags)),
                 what='the simulator to report the pause')
    assert max(stamp(m) for m in states) == pytest.approx(0.05), 'time stood at pause_at'
    assert ros.set_params('/simulator', pause_at=-1.0)[0].successful
    # Negative resumes; the command held for the paused state advances the loop again.
    ros.wait_for(answer(0.1), what='time to run on after resuming')
    refused = ros.set_params('/simulator', real_time_factor=-1.0)[0]
    # Refused by the parameter's FloatingPointRange, in rclpy's words.
    assert not refused.successful and refused.reason.startswith(
        'Parameter real_time_factor out of range Min: 0.0, Max: 1000.0, value: -1.0')
    refused = ros.set_params('/simulator', real_time_factor=0.0)[0]  # in range, not > 0
    assert not refused.successful and 'real_time_factor must be > 0' in refused.reason


def test_bad_parameters_are_refused_with_the_reason(tmp_path):
    from arm_sim.launcher import NodeProcess
    proc = NodeProcess('simulator', params={'link_masses': [0.0, 1.0],
                                            'publish_rate': 300.0},
                       log_path=tmp_path / 'sim.log', domain_id=0)
    assert proc.proc.wait(30) == 2
    out = proc.output()
    assert 'link_masses must be > 0 kg' in out and 'Traceback' not in out


def test_single_link_geared_model_follows_the_lectures_equation(ros, launch):
    from arm_dynamics import SingleLinkGeared, simulate
    link = SingleLinkGeared()  # the node's geared.* defaults
    launch('simulator', params={'timing_mode': 'lockstep', 'model': 'single_link_geared',
                                'initial_positions': [0.3, 0.0]})
    states = ros.collect(JointState, 'joint_states')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: states, what='first joint state')
    assert list(states[0].name) == ['joint1_motor', 'joint1']
    drive = Answerer(states, pub, [0.05])
    ros.wait_for(lambda: drive() >= 1.0 - 1e-9, timeout=30, what='1 s of simulated time')
    n = link.gear_ratio
    ref = simulate(model=link, q0=[0.3 * n], qd0=[0.0], torque=[0.05], duration=1.0,
                   dt=1e-3, method='solve_ivp')
    last = {stamp(m): m for m in states}[max(drive.answered)]
    assert last.position[0] == pytest.approx(ref.q[-1, 0], abs=1e-6), 'motor angle'
    assert last.position[1] == pytest.approx(ref.q[-1, 0] / n, abs=1e-8), 'link = motor / n'


def test_wall_clock_reports_when_it_cannot_keep_up(ros, launch):
    # 1000x real time at 1 ms steps needs a million RK4 steps per second: too many.
    launch('simulator', params={'timing_mode': 'wall_clock', 'real_time_factor': 1000.0,
                                'wait_for_command': False})
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    overrun = ros.wait_for(lambda: statuses(diags, '/simulator', 'overrun'),
                           what='the overrun report')[0]
    assert float(values(overrun)['simulated_time_given_up']) > 0


def diag_values(diags: list, node: str = '/simulator') -> list[dict[str, str]]:
    """The key-values of every status of ``node`` (its summary and each kind's)."""
    return [values(s) for s in statuses(diags, node)]


def test_lockstep_stands_still_for_a_silent_controller_and_reports_the_wait(ros, launch):
    launch('simulator', params={'timing_mode': 'lockstep', 'command_timeout': 0.3})
    states = ros.collect(JointState, 'joint_states')
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: states, what='first joint state')
    for k in range(1, 4):  # three periods under a torque, then silence
        # Tagged: a silent tagged controller gets the state again (test_real_arm.py: an
        # untagged one only when a new subscriber or publisher matched).
        pub.publish(command([8.0, 1.0], answers=states[-1]))
        ros.wait_for(lambda: stamp(states[-1]) >= 0.01 * k - 1e-9, what=f'step {k}')
    ros.wait_for(lambda: [v for v in diag_values(diags)
                          if v.get('event') == 'waiting_for_command'
                          and float(v['waited_wall']) > 0.3],
                 what='the wait reported with the wall time waited')
    n = len(states)
    ros.wait_for(lambda: len(states) > n + 2, what='re-sent states while waiting')
    assert {stamp(m) for m in states[n - 1:]} == {stamp(states[n - 1])}, 'time stood still'
    assert stamp(states[-1]) == pytest.approx(0.03)
    assert all(m.effort == pytest.approx([8.0, 1.0]) for m in states[1:]), (
        'never zero torque: the last command stays applied')
    assert len({tuple(m.position) for m in states[n - 1:]}) == 1, 'the state is re-sent as is'
    pub.publish(command([8.0, 1.0], answers=states[-1]))
    ros.wait_for(lambda: stamp(states[-1]) >= 0.04 - 1e-9, what='time to move on again')
    ros.wait_for(lambda: any(v.get('event') == 'controller_back' for v in diag_values(diags)),
                 what='the return reported')


def test_lockstep_ignores_answers_to_other_states(ros, launch):
    from std_msgs.msg import MultiArrayDimension

    from arm_dynamics.timing import answer_tag
    launch('simulator', params={'timing_mode': 'lockstep'})
    states = ros.collect(JointState, 'joint_states')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: states, what='first joint state')

    def tagged(t_ns: int, tau) -> Float64MultiArray:
        msg = command(tau)
        msg.layout.dim = [MultiArrayDimension(label=answer_tag(t_ns), size=2, stride=2)]
        return msg

    pub.publish(tagged(0, [1.0, 0.0]))
    ros.wait_for(lambda: stamp(states[-1]) >= 0.01 - 1e-9, what='the answer to t=0')
    pub.publish(tagged(0, [50.0, 0.0]))  # a late duplicate answer to t=0: stale
    pub.publish(tagged(10_000_000, [2.0, 0.0]))
    ros.wait_for(lambda: stamp(states[-1]) >= 0.02 - 1e-9, what='the answer to t=0.01')
    assert states[-1].effort == pytest.approx([2.0, 0.0])
    assert max(stamp(m) for m in states) == pytest.approx(0.02), 'one period per answer'


def test_real_time_holds_the_initial_state_until_the_first_command(ros, launch):
    q0 = [0.3, -0.7]
    launch('simulator', params={'timing_mode': 'real_time', 'initial_positions': q0})
    states = ros.collect(JointState, 'joint_states')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: len(states) >= 3, what='three states while holding')
    assert {stamp(m) for m in states} == {0.0}, 'time stands at its start'
    assert all(m.position == pytest.approx(q0, abs=0) for m in states), 'no integration'
    tau = ARM.gravity_vector(np.array(q0))  # holds the arm where it is
    drive = Answerer(states, pub, tau)
    ros.wait_for(lambda: drive() > 0.1, what='time to run once commands answer the states')


def test_real_time_is_lockstep_at_wall_clock_pace(ros, launch):
    """Each period waits for its answer, as in lockstep (so the motion is lockstep's to the
    bit), and is never integrated before its end is due on the wall clock."""
    import time

    launch('simulator', params={'timing_mode': 'real_time', 'real_time_factor': 2.0})
    states: list = []
    received: list[float] = []  # wall time each state came [s]

    def keep(msg) -> None:
        states.append(msg)
        received.append(time.monotonic())

    ros.node.create_subscription(JointState, 'joint_states', keep, 1000)
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: states, what='first joint state')
    tau = [8.0, -2.0]
    sent = time.monotonic()
    drive = Answerer(states, pub, tau)
    ros.wait_for(lambda: drive() >= 0.5 - 1e-9, timeout=30, what='0.5 s of simulated time')
    moving = [(stamp(m), w) for m, w in zip(states, received) if stamp(m) > 0]
    for t, wall in moving:  # the simulator paces from an anchor after the first answer
        assert t <= (wall - sent) * 2.0 + 1e-6, f'state at {t} s came {wall - sent:.4f} s ' \
                                                 'after the first command: ahead of 2x'
    # Lockstep's motion: one period per answer, the same physics (DOP853 to 1e-6 rad).
    first = {stamp(m): m for m in states}
    times = np.array(sorted(first))
    assert np.allclose(np.diff(times), 0.01), 'one state per 10 ms period, none skipped'
    q = np.array([first[t].position for t in times])
    ref = solve_ivp(lambda _t, x: np.concatenate([x[2:], ARM.forward_dynamics(
        x[:2], x[2:], tau)]), (0, times[-1]), [-0.4, 1.2, 0.0, 0.0], method='DOP853',
        rtol=1e-12, atol=1e-12, t_eval=times)
    err = np.abs(q - ref.y[:2].T).max()
    assert err < 1e-6, f'published motion deviates from solve_ivp by {err:.2e} rad'


def test_wall_clock_counts_periods_the_controller_did_not_answer(ros, launch):
    launch('simulator', params={'timing_mode': 'wall_clock', 'command_timeout': 0.0})
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    states = ros.collect(JointState, 'joint_states')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: states, what='first joint state')
    pub.publish(command([0.0, 0.0]))  # one command, then nothing: every period is late
    report = ros.wait_for(lambda: [v for v in diag_values(diags)
                                   if v.get('event') == 'late_periods'],
                          what='the late periods reported')[0]
    assert float(report['late_fraction']) > 0.5
    assert float(report['achieved_control_rate']) < 50.0


def test_removed_timing_mode_is_refused_with_the_reason(tmp_path):
    from arm_sim.launcher import NodeProcess
    proc = NodeProcess('simulator', params={'timing_mode': 'as_fast_as_possible'},
                       log_path=tmp_path / 'sim.log', domain_id=0)
    assert proc.proc.wait(30) == 2
    out = proc.output()
    assert 'as_fast_as_possible was removed' in out and 'use lockstep' in out
    assert 'Traceback' not in out
