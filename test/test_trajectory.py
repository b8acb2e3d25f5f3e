"""Trajectory validation and sampling, as joint_trajectory_controller does them."""

from __future__ import annotations

import numpy as np
import pytest

from arm_control.trajectory import Trajectory, validate_trajectory
from arm_control.trajectory import TrajectoryPoint as P

JOINTS = ('joint1', 'joint2')


@pytest.mark.parametrize('names, points, reason', [
    (['joint1', 'elbow'], [P(1, [0, 0])], 'unknown joint names'),
    (['joint1'], [P(1, [0])], 'missing'),
    (['joint1', 'joint2', 'joint1'], [P(1, [0, 0, 0])], 'unknown|repeats'),
    (JOINTS, [], 'no points'),
    (JOINTS, [P(1, [0, 0]), P(1, [1, 1])], 'strictly increasing'),
    (JOINTS, [P(-1, [0, 0])], 'strictly increasing'),
    (JOINTS, [P(1, [0, 0, 0])], '3 positions for 2 joints'),
    (JOINTS, [P(1, [0, 0], [1]), ], '1 velocities'),
    (JOINTS, [P(1, [0, 0], [1, 1]), P(2, [0, 0])], 'for every point or for none'),
    (JOINTS, [P(1, [0, 0], [], [1, 1])], 'accelerations given without velocities'),
    (JOINTS, [P(1, [float('nan'), 0])], 'non-finite'),
    (JOINTS, [P(float('inf'), [0, 0])], 'non-finite'),
])
def test_invalid_trajectories_are_refused_with_the_reason(names, points, reason):
    with pytest.raises(ValueError, match=reason):
        validate_trajectory(names, points, JOINTS)


def test_joint_order_follows_joint_names():
    _, pos, vel, acc = validate_trajectory(['joint2', 'joint1'], [P(1, [2, 1], [4, 3])],
                                           JOINTS)
    assert pos.tolist() == [[1, 2]] and vel.tolist() == [[3, 4]] and acc is None


def make(points, q0=(0.0, 0.0), qd0=(0.0, 0.0)):
    return Trajectory(q0, qd0, *validate_trajectory(JOINTS, points, JOINTS))


def test_quintic_segments_meet_position_velocity_and_acceleration_at_waypoints():
    tr = make([P(0, [0, 0], [0, 0], [0, 0]), P(1, [1, -1], [0.5, 0.2], [0.1, -0.3]),
               P(2.5, [2, 0], [0, 0], [0, 0])])
    assert tr.order == 5
    for t, pos, vel, acc in [(1.0, [1, -1], [0.5, 0.2], [0.1, -0.3]),
                             (2.5, [2, 0], [0, 0], [0, 0])]:
        for side in (-1e-9, 1e-9):
            q, qd, qdd = tr.sample(t + side)
            assert np.allclose(q, pos, atol=1e-7) and np.allclose(qd, vel, atol=1e-6)
            assert np.allclose(qdd, acc, atol=1e-5)
    # Velocity is the derivative of position inside a segment.
    t = np.array([0.3, 1.7])
    h = 1e-6
    qp, _, _ = tr.sample_many(t + h)
    qm, _, _ = tr.sample_many(t - h)
    _, qd, _ = tr.sample_many(t)
    assert np.allclose((qp - qm) / (2 * h), qd, atol=1e-6)


def test_cubic_with_velocities_and_linear_with_positions_only():
    cubic = make([P(0, [0, 0], [0, 0]), P(2, [2, 4], [0, 0])])
    assert cubic.order == 3
    q, qd, _ = cubic.sample(1.0)
    assert np.allclose(q, [1, 2]) and np.allclose(qd, [1.5, 3.0])  # cubic midpoint speed
    linear = make([P(0, [0, 0]), P(2, [2, 4])])
    q, qd, qdd = linear.sample(0.5)
    assert linear.order == 1 and np.allclose(q, [0.5, 1]) and np.allclose(qd, [1, 2])


def test_the_last_point_is_held_and_a_late_first_point_starts_from_the_given_state():
    tr = make([P(1.0, [1, 2], [0, 0], [0, 0])], q0=(0.5, 0.5), qd0=(0.0, 0.0))
    q, _, _ = tr.sample(0.0)
    assert q.tolist() == [0.5, 0.5], 'starts at the measured state'
    q, qd, qdd = tr.sample(5.0)
    assert q.tolist() == [1, 2] and qd.tolist() == [0, 0] and qdd.tolist() == [0, 0]


def test_one_point_at_time_zero_is_a_set_point():
    tr = make([P(0, [1, 2])], q0=(0, 0))
    assert tr.set_point
    for t in (0.0, 0.5, 10.0):
        q, qd, _ = tr.sample(t)
        assert q.tolist() == [1, 2] and qd.tolist() == [0, 0]
