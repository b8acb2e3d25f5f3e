"""arm_sim.draw: the arm drawn from joint states writes a PNG, from arrays and from a bag."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from arm_bag.synthetic import open_bag, write_run
from arm_dynamics import TwoLinkArm
from arm_sim.draw import Motion, draw_arm, draw_bag, pose_indices

ARM = TwoLinkArm()
PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'


def line_motion(a=(1.2, 0.3), b=(0.6, 0.9), n: int = 41, off: float = 0.0):
    """Joint angles moving the tip from a to b (``off`` m to one side at mid-way), then
    resting at b for as long again."""
    a, b = np.array(a), np.array(b)
    s = 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, n))
    normal = np.array([-(b - a)[1], (b - a)[0]]) / np.hypot(*(b - a))
    xy = a + s[:, None] * (b - a) + (off * np.sin(np.pi * s))[:, None] * normal
    xy = np.vstack([xy, np.repeat(xy[-1:], n, axis=0)])
    return np.unwrap(ARM.inverse_kinematics(xy, 'down'), axis=0), (a, b)


def is_png(path: Path) -> bool:
    return path.is_file() and path.read_bytes()[:8] == PNG_SIGNATURE


def test_draw_arm_writes_a_png_with_one_panel_per_motion(tmp_path):
    q, line = line_motion()
    q_off, _ = line_motion(off=0.05)
    out = draw_arm(ARM, [Motion(q, line, 'on the line'), Motion(q_off, line, '5 cm off')],
                   tmp_path / 'arm.png', n_poses=5, title='two lines')
    assert out == tmp_path / 'arm.png' and is_png(out)
    single = draw_arm(ARM, Motion(q), tmp_path / 'one.png')
    assert is_png(single) and single.stat().st_size < out.stat().st_size


def test_poses_are_spread_along_the_tips_path_not_over_the_rest():
    q, _ = line_motion(n=41)
    tip = ARM.forward_kinematics(q)
    picks = pose_indices(tip, 5)
    assert picks[0] == 0 and len(picks) == 5
    assert picks[-1] <= 40, 'the last pose is where the tip arrives, not the end of the rest'
    travelled = np.concatenate([[0], np.cumsum(np.hypot(*np.diff(tip, axis=0).T))])
    steps = np.diff(travelled[picks])
    assert steps.max() - steps.min() < 0.1 * steps.mean() + 2 * np.diff(travelled).max()
    assert list(pose_indices(np.zeros((10, 2)), 5)) == [0, 9], 'no motion: first and last'
    with pytest.raises(ValueError, match='n_poses must be >= 2, got 1'):
        pose_indices(tip, 1)


@pytest.mark.parametrize('kwargs, words', [
    ({'q': np.zeros((3, 3))}, 'q must have shape (N, 2) with N >= 1, got (3, 3)'),
    ({'q': np.full((2, 2), np.nan)}, 'q has no finite joint state'),
    ({'q': np.zeros((2, 2)), 'line': ((0, 0), (1, np.inf))}, 'line must be two finite'),
])
def test_bad_motions_are_refused_naming_the_value(kwargs, words):
    with pytest.raises(ValueError) as info:
        Motion(**kwargs)
    assert words in str(info.value)


def test_draw_bag_draws_the_straight_line_segments_of_a_bag(tmp_path):
    w, ch = open_bag(tmp_path / 'bag')
    q, (a, b) = line_motion(off=0.01)
    n = len(q)
    path_xy = a + np.linspace(0, 1, 5)[:, None] * (b - a)
    waypoints = np.unwrap(ARM.inverse_kinematics(path_xy, 'down'), axis=0)
    write_run(w, ch, 1_000_000, np.arange(n) * 0.01, q, np.zeros((n, 2)), np.zeros((n, 2)),
              q, (waypoints, np.linspace(0.0, 0.4, 5)), path_xy, stamp0=1_000_000_000)
    w.close()
    out = draw_bag(tmp_path / 'bag', tmp_path / 'drawn.png', n_poses=4)
    assert is_png(out)


def test_a_bag_without_a_straight_line_is_refused_by_name(tmp_path):
    w, ch = open_bag(tmp_path / 'bag')
    t = np.arange(5) * 0.01
    q = np.tile([0.1, 0.5], (5, 1))
    write_run(w, ch, 1000, t, q, np.zeros((5, 2)), np.zeros((5, 2)), q,
              (np.array([[0.1, 0.5]]), np.array([0.0])), stamp0=1_000_000)
    w.close()
    with pytest.raises(ValueError, match='no straight-line segment to draw'):
        draw_bag(tmp_path / 'bag', tmp_path / 'x.png')
    assert not (tmp_path / 'x.png').exists()
