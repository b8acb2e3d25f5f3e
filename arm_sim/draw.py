"""The arm drawn from recorded joint states: poses along a motion, the tip's trail and the
commanded line (matplotlib, no display, no rclpy).

:func:`draw_arm` draws one motion from arrays; :func:`draw_bag` reads a bag, finds its
straight-line segments (as ``arm-sim analyze`` does) and draws each in its own panel, side
by side, on the same scale, so a fast or badly controlled line shows as a trail leaving
the commanded segment.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from arm_dynamics import TwoLinkArm
from arm_dynamics.models import RobotModel

#: Colours: links, the tip's trail, the commanded line.
LINK_COLOUR = '#1f4e9c'
TRAIL_COLOUR = '#d62728'
LINE_COLOUR = '#2ca02c'


@dataclass(frozen=True)
class Motion:
    """One motion to draw.

    Parameters
    ----------
    q : (N, 2) rad
        Joint positions in time order.
    line : ((2,), (2,)) m, optional
        The commanded segment's start and end in the base frame.
    title : str
        The panel's title.
    """

    q: np.ndarray
    line: tuple[Sequence[float], Sequence[float]] | None = None
    title: str = ''

    def __post_init__(self) -> None:
        q = np.asarray(self.q, dtype=float)
        if q.ndim != 2 or q.shape[1] != 2 or len(q) < 1:
            raise ValueError(f'q must have shape (N, 2) with N >= 1, got {q.shape}')
        q = q[np.isfinite(q).all(axis=1)]
        if not len(q):
            raise ValueError('q has no finite joint state')
        object.__setattr__(self, 'q', q)
        if self.line is not None:
            a, b = (np.asarray(p, dtype=float) for p in self.line)
            if a.shape != (2,) or b.shape != (2,) or not np.isfinite([a, b]).all():
                raise ValueError(f'line must be two finite (x, y) points in m, got '
                                 f'{self.line!r}')
            object.__setattr__(self, 'line', (a, b))


def pose_indices(xy: np.ndarray, n_poses: int) -> np.ndarray:
    """Indices of ``n_poses`` samples spread evenly along the tip's path length (so the
    poses follow the motion, not the time spent at rest), first and last included.

    Parameters
    ----------
    xy : (N, 2) m
        Tip positions in time order.
    n_poses : int, >= 2
    """
    if n_poses < 2:
        raise ValueError(f'n_poses must be >= 2, got {n_poses}')
    travelled = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    if travelled[-1] <= 0.0:
        return np.array([0, len(xy) - 1])
    marks = np.linspace(0.0, travelled[-1], n_poses)
    return np.unique(np.minimum(np.searchsorted(travelled, marks), len(xy) - 1))


def _draw_motion(ax: Any, arm: RobotModel, motion: Motion, n_poses: int) -> None:
    points = arm.joint_points(motion.q)          # (K, n + 1, 2): base, joints, tip
    tip = points[:, -1]
    if motion.line is not None:
        a, b = motion.line
        ax.plot([a[0], b[0]], [a[1], b[1]], '-', color=LINE_COLOUR, lw=5, alpha=0.45,
                label='commanded line', zorder=2, solid_capstyle='round')
    picks = pose_indices(tip, n_poses)
    for k, i in enumerate(picks):
        alpha = 0.25 + 0.75 * k / max(len(picks) - 1, 1)
        xs, ys = points[i, :, 0], points[i, :, 1]
        ax.plot(xs, ys, '-', color=LINK_COLOUR, lw=4, alpha=alpha, solid_capstyle='round',
                label='arm' if k == len(picks) - 1 else None, zorder=3)
        ax.plot(xs[:-1], ys[:-1], 'o', color='k', ms=4, alpha=alpha, zorder=4)
    ax.plot(tip[:, 0], tip[:, 1], '-', color=TRAIL_COLOUR, lw=1.2, label='tip trail',
            zorder=5)
    ax.plot(0.0, 0.0, 's', color='0.3', ms=9, zorder=1)
    ax.set_aspect('equal')
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    if motion.title:
        ax.set_title(motion.title, fontsize=9)


def draw_arm(arm: TwoLinkArm, motions: Motion | Sequence[Motion], out: str | Path, *,
             n_poses: int = 7, title: str = '') -> Path:
    """Draw each motion in its own panel (same scale) and write a PNG.

    Parameters
    ----------
    arm : TwoLinkArm
        Gives the link lengths [m].
    motions : Motion or sequence of Motion
    out : path of the PNG to write (its directory must exist)
    n_poses : int, >= 2
        Arm poses per panel, spread along the tip's path, fading from first to last.
    title : str
        The figure's title.

    Returns
    -------
    Path
        ``out``.
    """
    from matplotlib.figure import Figure

    motions = [motions] if isinstance(motions, Motion) else list(motions)
    if not motions:
        raise ValueError('motions is empty: nothing to draw')
    fig = Figure(figsize=(4.2 * len(motions), 4.6), layout='constrained')
    axes = fig.subplots(1, len(motions), sharex=True, sharey=True, squeeze=False)[0]
    for ax, motion in zip(axes, motions):
        _draw_motion(ax, arm, motion, n_poses)
    reach = sum(arm.link_lengths)
    axes[0].set_xlim(-0.25 * reach, 1.05 * reach)
    axes[0].set_ylim(-0.45 * reach, 1.05 * reach)
    axes[0].legend(loc='lower left', fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    out = Path(out)
    fig.savefig(out, dpi=110)
    return out


def draw_bag(bag: str | Path, out: str | Path, *, n_poses: int = 7) -> Path:
    """Draw every straight-line segment of a bag (a bag directory or ``.mcap``) and write a
    PNG: the arm at ``n_poses`` poses, the tip's trail and the commanded line.

    The link lengths come from the bag's robot record (the defaults if it has none), the
    segments and the lines from :func:`arm_bag.analysis.analyze`.

    Raises
    ------
    ValueError
        The bag has no straight-line segment (its path is named).
    """
    from arm_bag.analysis import analyze

    report = analyze(bag)
    arm = TwoLinkArm(link_lengths=tuple(report.link_lengths))  # type: ignore[arg-type]
    motions = []
    for seg in report.segments:
        if seg.mode != 'straight_line':
            continue
        dev = seg.deviation_max
        off = '' if dev is None else f', at most {dev * 1e3:.1f} mm off the line'
        motions.append(Motion(seg.series['q'], seg.series.get('line'),
                              f'segment {seg.index}: from t = {seg.start:.2f} s{off}'))
    if not motions:
        raise ValueError(f'{bag}: no straight-line segment to draw')
    return draw_arm(arm, motions, out, n_poses=n_poses,
                    title='The arm along each straight line of the run: poses, the tip\'s '
                          'trail and the commanded line')
