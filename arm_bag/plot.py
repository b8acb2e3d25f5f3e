"""Plots of analysis reports (matplotlib, Agg backend; pure)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from arm_bag.analysis import Report


def plot_report(reports: Report | list[Report], path: str | Path) -> Path:
    """Write a PNG with four panels: joint angles against the reference [rad], applied
    torques [N m], the end-effector XY path against the commanded line [m], and the
    deviation from that line over time [m]. Several reports are overlaid (labelled by bag).
    """
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    reports = [reports] if isinstance(reports, Report) else list(reports)
    fig, axes = plt.subplots(2, 2, figsize=(12, 8))
    ax_q, ax_tau, ax_xy, ax_dev = axes.ravel()
    for r_i, rep in enumerate(reports):
        tag = Path(rep.bag).name if len(reports) > 1 else ''
        offset = 0.0
        for seg in rep.segments:
            s = seg.series
            t = s['t'] + seg.start
            for j, name in enumerate(rep.joint_names):
                first = seg.index == rep.segments[0].index
                lbl = f'{tag} {name}'.strip() if first else None
                line, = ax_q.plot(t, s['q'][:, j], label=lbl,
                                  color=f'C{(2 * r_i + j) % 10}')
                if 'ref' in s:
                    ax_q.plot(t, s['ref'][:, j], '--', color=line.get_color(), lw=0.8)
                ax_tau.plot(t, s['effort'][:, j], color=line.get_color(), label=lbl)
            if 'xy' in s and len(s['xy']):
                ax_xy.plot(s['xy'][:, 0], s['xy'][:, 1], color=f'C{r_i}', lw=1)
            if 'line' in s:
                a, b = np.asarray(s['line'][0]), np.asarray(s['line'][1])
                ax_xy.plot([a[0], b[0]], [a[1], b[1]], 'k--', lw=0.8)
                n = min(len(t), len(s['deviation']))
                ax_dev.plot(t[:n], s['deviation'][:n], color=f'C{r_i}')
            offset = max(offset, float(t[-1]))
    ax_q.set(title='joint angles (dashed: reference)', xlabel='t [s]', ylabel='q [rad]')
    ax_tau.set(title='applied torque', xlabel='t [s]', ylabel='tau [N m]')
    ax_xy.set(title='end effector (dashed: commanded line)', xlabel='x [m]', ylabel='y [m]')
    ax_xy.set_aspect('equal', adjustable='datalim')
    ax_dev.set(title='distance from the commanded segment', xlabel='t [s]', ylabel='[m]')
    for ax in (ax_q, ax_tau):
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize='small')
    for ax in axes.ravel():
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out
