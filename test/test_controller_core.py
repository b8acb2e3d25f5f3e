"""ControllerCore: reference handling, trajectories ending in the past, time and state jumps."""

from __future__ import annotations

import numpy as np
import pytest

from arm_control.core import ControllerCore
from arm_control.laws import ControlLaw, Gains
from arm_control.trajectory import TrajectoryError, TrajectoryPoint
from arm_dynamics import TwoLinkArm

JOINTS = ('joint1', 'joint2')
Q0 = np.array([-0.4, 1.2])
ZERO = np.zeros(2)


def core(law: str = 'pid') -> ControllerCore:
    gains = Gains(kp=[100.0, 60.0], kd=[20.0, 12.0], ki=[50.0, 30.0], i_clamp=[20.0, 10.0])
    return ControllerCore(JOINTS, ControlLaw(law, gains, TwoLinkArm(), (60.0, 20.0)))


def move(c: ControllerCore, start: float = 0.0) -> None:
    pts = [TrajectoryPoint(1.0, [0.2, 0.8], [0.0, 0.0], [0.0, 0.0])]
    c.set_trajectory(JOINTS, pts, start, Q0, ZERO)


@pytest.mark.parametrize('t_next, label', [(0.5, 'back'), (3.0, 'jumped')])
def test_a_time_jump_drops_the_trajectory_and_holds_the_measured_position(t_next, label):
    c = core()
    c.update(1.0, Q0, ZERO)
    move(c, start=1.0)
    assert not np.allclose(c.update(1.5, Q0, ZERO).q_des, Q0), 'moving along the plan'
    c.law.integral = np.array([1.0, 1.0])
    q = Q0 + 0.3
    step = c.update(t_next, q, ZERO)
    assert step.jump and label in step.jump
    assert np.array_equal(step.q_des, q) and np.array_equal(step.qd_des, ZERO)
    assert np.array_equal(c.law.integral, ZERO), 'PID integral forgotten'
    later = c.update(t_next + 0.01, q, ZERO)
    assert later.jump is None and np.array_equal(later.q_des, q)
    assert c.jumps == 1


def test_a_reset_state_at_the_same_time_is_a_state_jump_but_a_resent_one_is_not():
    c = core()
    c.update(1.0, Q0, ZERO)
    move(c, start=1.0)
    c.update(1.2, Q0 + 0.01, np.array([0.5, 0.5]))
    assert c.update(1.2, Q0 + 0.01, np.array([0.5, 0.5])).jump is None, 'the same state again'
    fast = c.update(1.21, Q0 + 0.01 + 0.005, np.array([0.5, 0.5]))
    assert fast.jump is None, 'motion its velocity explains'
    assert 'state jumped' in c.update(1.21, Q0 - 0.5, ZERO).jump


def test_a_trajectory_that_ends_in_the_past_is_refused_and_the_reference_kept():
    c = core()
    c.update(100.0, Q0, ZERO)
    with pytest.raises(TrajectoryError, match='ends in the past'):
        c.set_trajectory(JOINTS, [TrajectoryPoint(1.0, [0.2, 0.8])], 0.0, Q0, ZERO, now=100.0)
    assert c.trajectories_accepted == 0
    assert np.array_equal(c.update(100.01, Q0, ZERO).q_des, Q0)
    c.set_trajectory(JOINTS, [TrajectoryPoint(1.0, [0.2, 0.8])], 99.5, Q0, ZERO, now=100.0)
    assert c.trajectories_accepted == 1, 'one that started in the past but ends later is fine'


def test_jump_settings_are_validated():
    law = core().law
    with pytest.raises(ValueError, match='jump_threshold'):
        ControllerCore(JOINTS, law, jump_threshold=0.0)
    with pytest.raises(ValueError, match='state_jump_tolerance'):
        ControllerCore(JOINTS, law, state_jump_tolerance=-1.0)


def test_a_trajectory_starting_in_the_future_holds_the_measured_position_until_then():
    c = core('pd')
    c.update(1.0, Q0, ZERO)
    pts = [TrajectoryPoint(1.0, [0.2, 0.8], [0.0, 0.0], [0.0, 0.0])]
    c.set_trajectory(JOINTS, pts, 3.0, Q0, ZERO, now=1.0)  # starts 2 s from now
    for t in (1.01, 2.0, 2.99, 3.0):
        step = c.update(t, Q0, ZERO)
        assert np.array_equal(step.q_des, Q0) and np.array_equal(step.qd_des, ZERO), t
    assert np.allclose(c.update(4.0, Q0, ZERO).q_des, [0.2, 0.8]), 'then the motion'


def test_a_trajectory_takes_over_after_its_start_state_whichever_came_first():
    """The state at a trajectory's stamp is answered with the previous reference, whether
    the trajectory reached the controller before or after that state: the motion never
    depends on how the two messages raced."""
    pts = [TrajectoryPoint(0.5, [0.2, 0.8], [0.0, 0.0], [0.0, 0.0])]
    answers = []
    for trajectory_first in (False, True):
        c = core('computed_torque')
        c.update(0.99, Q0, ZERO)  # holding the start
        if trajectory_first:
            c.set_trajectory(JOINTS, pts, 1.0, Q0, ZERO, now=0.99)
            at_stamp = c.update(1.0, Q0, ZERO)
        else:
            at_stamp = c.update(1.0, Q0, ZERO)
            c.set_trajectory(JOINTS, pts, 1.0, Q0, ZERO, now=1.0)
        after = c.update(1.01, Q0, ZERO)
        answers.append((at_stamp.command.tau, after.q_des, after.command.tau))
        assert np.array_equal(at_stamp.q_des, Q0), 'the old reference at the stamp'
        assert not np.array_equal(after.q_des, Q0), 'the new one from the next state'
    for a, b in zip(*answers):
        assert np.array_equal(a, b), 'bit for bit the same either way'
