"""arm_sim.draw: the arm drawn from joint states writes a PNG, from arrays and from a bag.

The drawing functions return only the PNG's path; the ``saved_figures`` fixture records
the matplotlib figure each one saves, so that the tests can check what was drawn on it.
"""

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


@pytest.fixture
def saved_figures(monkeypatch):
    """Every matplotlib figure saved during the test, in order: what the PNGs show."""
    from matplotlib.figure import Figure

    saved = []
    savefig = Figure.savefig

    def record(self, *args, **kwargs):
        saved.append(self)
        return savefig(self, *args, **kwargs)

    monkeypatch.setattr(Figure, 'savefig', record)
    return saved


def lines_by_label(ax) -> dict:
    """The axes' lines by legend label (unlabelled lines are left out)."""
    return {ln.get_label(): ln for ln in ax.get_lines() if not ln.get_label().startswith('_')}


def test_draw_arm_writes_a_png_with_one_panel_per_motion(tmp_path, saved_figures):
    q, line = line_motion()
    q_off, _ = line_motion(off=0.05)
    out = draw_arm(ARM, [Motion(q, line, 'on the line'), Motion(q_off, line, '5 cm off')],
                   tmp_path / 'arm.png', n_poses=5, title='two lines')
    assert out == tmp_path / 'arm.png' and is_png(out)
    single = draw_arm(ARM, Motion(q), tmp_path / 'one.png')
    assert is_png(single) and single.stat().st_size < out.stat().st_size
    two_panels, one_panel = saved_figures
    assert [ax.get_title() for ax in two_panels.axes] == ['on the line', '5 cm off']
    assert len(one_panel.axes) == 1


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
    ({'q': np.zeros((2, 2)), 'line': ((0, 0), (1, np.inf))},
     'line must be two finite (x, y) points in m, got ((0, 0), (1, inf))'),
])
def test_bad_motions_are_refused_saying_what_is_wrong(kwargs, words):
    with pytest.raises(ValueError) as info:
        Motion(**kwargs)
    assert words in str(info.value)


def test_draw_bag_draws_the_straight_line_segments_of_a_bag(tmp_path, saved_figures):
    """A bag of three segments, a straight line, a hold (regulation) and another straight
    line, is drawn as two panels: each straight-line segment's commanded line (the planner
    path's first to last pose) and its tip trail (the recorded joint states' forward
    kinematics), inside the panel's view; the hold is not drawn."""
    w, ch = open_bag(tmp_path / 'bag')

    def straight_line(log: int, a, b, off: float, stamp0: int):
        """Write a straight line from a to b; return the next receive time, the joint
        positions written and the commanded line (the path's first and last pose)."""
        q, (a, b) = line_motion(a, b, off=off)
        n = len(q)
        path_xy = a + np.linspace(0, 1, 5)[:, None] * (b - a)
        waypoints = np.unwrap(ARM.inverse_kinematics(path_xy, 'down'), axis=0)
        log = write_run(w, ch, log, np.arange(n) * 0.01, q, np.zeros((n, 2)),
                        np.zeros((n, 2)), q, (waypoints, np.linspace(0.0, 0.4, 5)), path_xy,
                        stamp0=stamp0)
        return log, q, path_xy[[0, -1]]

    log, q0, line0 = straight_line(1_000_000, (1.2, 0.3), (0.6, 0.9), 0.01, 1_000_000_000)
    hold = np.tile(q0[-1], (20, 1))
    log = write_run(w, ch, log, np.arange(20) * 0.01, hold, np.zeros((20, 2)),
                    np.zeros((20, 2)), hold, (hold[-1:], np.array([0.0])),
                    stamp0=3_000_000_000)
    _, q2, line2 = straight_line(log, (0.6, 0.9), (0.2, 1.1), 0.02, 4_000_000_000)
    w.close()

    out = draw_bag(tmp_path / 'bag', tmp_path / 'drawn.png', n_poses=4)
    assert is_png(out)
    (fig,) = saved_figures
    assert len(fig.axes) == 2, 'one panel per straight-line segment, the hold left out'
    for ax, index, q, (a, b) in zip(fig.axes, (0, 2), (q0, q2), (line0, line2)):
        assert ax.get_title().startswith(f'segment {index}: ')
        drawn = lines_by_label(ax)
        np.testing.assert_allclose(drawn['commanded line'].get_xydata(), [a, b], atol=1e-12)
        np.testing.assert_allclose(drawn['tip trail'].get_xydata(),
                                   ARM.forward_kinematics(q), atol=1e-9)
        (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
        for x, y in (a, b):
            assert x0 < x < x1 and y0 < y < y1, f'line end ({x}, {y}) outside the view'


def test_a_bag_without_a_straight_line_is_refused_naming_the_bag_and_no_png_written(
        tmp_path):
    w, ch = open_bag(tmp_path / 'bag')
    t = np.arange(5) * 0.01
    q = np.tile([0.1, 0.5], (5, 1))
    write_run(w, ch, 1000, t, q, np.zeros((5, 2)), np.zeros((5, 2)), q,
              (np.array([[0.1, 0.5]]), np.array([0.0])), stamp0=1_000_000)
    w.close()
    with pytest.raises(ValueError) as info:
        draw_bag(tmp_path / 'bag', tmp_path / 'x.png')
    assert str(info.value) == f'{tmp_path / "bag"}: no straight-line segment to draw'
    assert not (tmp_path / 'x.png').exists()
