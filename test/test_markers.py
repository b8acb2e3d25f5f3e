"""The arm's markers (arm_sim.markers): every position is the forward kinematics of the
joint state (1e-9 m), trail and path are drawn when there is something to draw and
deleted when not, and the trail depends only on the joint states' stamps."""

from __future__ import annotations

import numpy as np
import pytest

from arm_dynamics import TwoLinkArm
from arm_sim.markers import NAMESPACES, TipTrail, arm_markers, link_points

ARMS = [TwoLinkArm(), TwoLinkArm(link_lengths=(1.2, 0.6)), TwoLinkArm(link_lengths=(0.3, 2.5))]
TOL = 1e-9  # m


def by_ns(shapes) -> dict:
    return {s.ns: s for s in shapes}


def elbow_of(arm: TwoLinkArm, q: np.ndarray) -> np.ndarray:
    """Independent of the module: link 1's end."""
    return arm.link_lengths[0] * np.array([np.cos(q[0]), np.sin(q[0])])


@pytest.mark.parametrize('arm', ARMS)
def test_links_joints_and_tip_are_forward_kinematics_at_random_states(arm):
    rng = np.random.default_rng(12)
    for q in rng.uniform(-2 * np.pi, 2 * np.pi, (200, 2)):
        m = by_ns(arm_markers(arm, q))
        tip = arm.forward_kinematics(q)
        elbow = elbow_of(arm, q)
        base = np.zeros(2)
        links = m['links']
        assert links.shape == 'line_list' and links.visible
        assert np.abs(links.points[:, :2] - [base, elbow, elbow, tip]).max() < TOL
        assert np.abs(m['joints'].points[:, :2] - [base, elbow]).max() < TOL
        assert np.abs(m['tip'].points[0, :2] - tip).max() < TOL
        for s in m.values():
            assert not s.points.size or np.all(s.points[:, 2] == 0.0), 'in the plane z = 0'
        # link lengths are kept
        assert np.linalg.norm(elbow) == pytest.approx(arm.link_lengths[0], abs=TOL)
        assert np.linalg.norm(tip - elbow) == pytest.approx(arm.link_lengths[1], abs=TOL)


def test_link_points_vectorised_match_one_by_one():
    arm = ARMS[1]
    q = np.random.default_rng(3).uniform(-4, 4, (50, 2))
    many = link_points(arm, q)
    assert many.shape == (50, 3, 2)
    for k in range(50):
        assert np.array_equal(many[k], link_points(arm, q[k]))
    assert np.abs(many[:, 2] - arm.forward_kinematics(q)).max() == 0.0, 'the tip is FK itself'


def test_every_namespace_once_in_order_and_nothing_to_show_is_not_visible():
    arm = TwoLinkArm()
    shapes = arm_markers(arm, np.array([0.3, -0.7]))
    assert tuple(s.ns for s in shapes) == NAMESPACES
    m = by_ns(shapes)
    for ns in ('trail', 'goal', 'path'):
        assert not m[ns].visible and m[ns].points.shape == (0, 3)
    for ns in ('links', 'joints', 'tip'):
        assert m[ns].visible
    # Empty arrays and a single point are nothing to draw as a line either.
    m = by_ns(arm_markers(arm, np.zeros(2), trail=np.zeros((0, 2)), path=np.zeros((1, 2))))
    assert not m['trail'].visible and not m['path'].visible


def test_trail_goal_and_path_are_drawn_where_given():
    arm = TwoLinkArm()
    q = np.array([-0.4, 1.2])
    trail = arm.forward_kinematics(np.linspace([-0.6, 1.0], q, 25))
    path = np.linspace([0.5, 1.2], arm.forward_kinematics(q), 9)
    m = by_ns(arm_markers(arm, q, trail=trail, goal=(0.5, 1.2), path=path))
    assert m['trail'].visible and m['trail'].shape == 'line_strip'
    assert np.array_equal(m['trail'].points[:, :2], trail)
    assert m['path'].visible and m['path'].shape == 'line_strip'
    assert np.array_equal(m['path'].points[:, :2], path)
    assert m['goal'].visible and m['goal'].shape == 'sphere'
    assert m['goal'].points.tolist() == [[0.5, 1.2, 0.0]]
    links = m['links']
    assert links.colours is not None and links.colours.shape == (4, 4)
    assert m['links'].scale[0] > m['trail'].scale[0] > 0, 'links wider than the trail'


@pytest.mark.parametrize('kw', [
    {'q': [0.0, np.nan]}, {'q': [0.0, 1.0, 2.0]}, {'goal': (np.inf, 0.0)}, {'goal': (1.0,)},
    {'trail': np.array([[0.0, np.nan], [1.0, 1.0]])}, {'path': np.zeros((3, 3))},
])
def test_bad_inputs_are_refused_with_the_reason(kw):
    args = {'q': [0.1, 0.2], **kw}
    with pytest.raises(ValueError, match='q|goal|trail|path'):
        arm_markers(TwoLinkArm(), np.asarray(args.pop('q'), dtype=float), **args)


def test_tip_trail_keeps_the_window_by_stamp_and_is_forward_kinematics():
    arm = TwoLinkArm()
    trail = TipTrail(window_ns=100_000_000)  # 0.1 s
    assert len(trail) == 0 and trail.points(arm).shape == (0, 2)
    qs = np.column_stack([np.linspace(0, 1, 30), np.linspace(1, 0, 30)])
    for k, q in enumerate(qs):
        trail.add(k * 10_000_000, q)  # every 10 ms
    # 0.1 s window back from 0.29 s: stamps 0.19 ... 0.29 s, 11 states
    assert trail.stamps().tolist() == [k * 10_000_000 for k in range(19, 30)]
    assert np.abs(trail.points(arm) - arm.forward_kinematics(qs[19:])).max() < TOL
    # The same state re-sent (lockstep heartbeat) counts once.
    trail.add(29 * 10_000_000, qs[29])
    assert len(trail) == 11
    # Time going back (a restarted simulator) starts a new trail.
    trail.add(0, qs[0])
    assert trail.stamps().tolist() == [0]
    # Zero window: the latest state alone, so no trail line.
    none = TipTrail(0)
    for k, q in enumerate(qs):
        none.add(k, q)
    assert len(none) == 1
    assert not by_ns(arm_markers(arm, qs[-1], trail=none.points(arm)))['trail'].visible


def test_tip_trail_is_bounded_and_independent_of_when_it_is_read():
    a, b = TipTrail(10**12, max_points=5), TipTrail(10**12, max_points=5)
    qs = np.random.default_rng(1).uniform(-1, 1, (20, 2))
    for k, q in enumerate(qs):
        a.add(k, q)
        a.angles()  # reading changes nothing
    for k, q in enumerate(qs):
        b.add(k, q)
    assert len(a) == 5 and np.array_equal(a.angles(), b.angles())
    assert np.array_equal(a.angles(), qs[-5:])
    with pytest.raises(ValueError):
        TipTrail(-1)
