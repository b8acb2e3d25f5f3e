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


def plot_frf(rep, path: str | Path) -> Path:
    """Write the Bode diagram of an :class:`arm_bag.frf.FrfReport`: per excited joint (a
    column) the closed-loop gain [dB] and phase [deg] of ``q / q_des`` against frequency
    [Hz, log], measured (points, their shade the coherence: dark 1, pale 0) over the
    prediction of the linearised sampled-data loop (line); the checked band shaded grey
    outside; the predicted margins in the title."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from arm_bag.frf import gain_db

    cols = max(1, len(rep.joints))
    fig, axes = plt.subplots(2, cols, figsize=(6.5 * cols, 7), sharex=True, squeeze=False)
    lo, hi = rep.band
    for c, jf in enumerate(rep.joints):
        ax_g, ax_p = axes[0, c], axes[1, c]
        f = jf.freqs
        show = (f >= lo / 2) & (f <= rep.loop.nyquist) & jf.excited
        meas_ph = np.degrees(np.unwrap(np.angle(jf.measured[show])))
        pred_ph = np.degrees(np.unwrap(np.angle(jf.predicted[show])))
        # the measured points: about 60 log-spaced bins (every bin would hide the line)
        fs = f[show]
        pick = np.unique(np.searchsorted(fs, np.geomspace(fs[0], fs[-1], 60))
                         .clip(0, len(fs) - 1)) if len(fs) else np.zeros(0, int)
        colour = plt.get_cmap('Blues')(0.3 + 0.7 * np.clip(jf.coherence[show][pick], 0, 1))
        ax_g.plot(fs, gain_db(jf.predicted[show]), 'C3', lw=1.4,
                  label='predicted (linearised sampled-data loop)', zorder=2)
        ax_g.scatter(fs[pick], gain_db(jf.measured[show])[pick], s=14, c=colour,
                     edgecolors='none', label='measured (shade: coherence, dark = 1)',
                     zorder=3)
        ax_p.plot(fs, pred_ph, 'C3', lw=1.4, zorder=2)
        ax_p.scatter(fs[pick], meas_ph[pick], s=14, c=colour, edgecolors='none', zorder=3)
        m = jf.margins
        gm = 'inf' if not np.isfinite(m.gain_db) else f'{m.gain_db:.1f} dB'
        pm = 'none' if not np.isfinite(m.phase_deg) else f'{m.phase_deg:.1f} deg'
        ax_g.set_title(f'{jf.name}: q / q_des ({rep.law}, amplitude {jf.amplitude:.3g} rad)'
                       f'\nworst {jf.worst_db:.2f} dB / {jf.worst_deg:.2f} deg in '
                       f'{lo:g}..{hi:.3g} Hz; loop GM {gm}, PM {pm}', fontsize='medium')
        for ax in (ax_g, ax_p):
            ax.set_xscale('log')
            ax.axvspan(f[show].min() if show.any() else lo / 2, lo, color='0.9', zorder=0)
            ax.axvspan(hi, rep.loop.nyquist, color='0.9', zorder=0)
            ax.grid(True, which='both', alpha=0.3)
        ax_g.set_ylabel('gain [dB]')
        ax_p.set_ylabel('phase [deg]')
        ax_p.set_xlabel('frequency [Hz] (grey: outside the checked band)')
        ax_g.legend(fontsize='small', loc='lower left')
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out
