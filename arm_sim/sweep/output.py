"""A sweep's outputs: the CSV table, the JSON document, the summary lines and the plot.

Pure: no rclpy; matplotlib is imported only to draw.
"""

from __future__ import annotations

import csv
import math
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from arm_sim.sweep.columns import COLUMNS, STATUSES
from arm_sim.sweep.spec import VARIANT, PlotSpec, Spec


def _cell(v: object) -> object:
    if isinstance(v, float) and not math.isfinite(v):
        return ''
    return v


def write_csv(rows: Sequence[dict], path: str | Path) -> None:
    """One row per scenario, columns :data:`~arm_sim.sweep.columns.COLUMNS`; undefined
    values are empty cells."""
    with open(path, 'w', newline='') as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for r in rows:
            w.writerow([_cell(r[c]) for c in COLUMNS])


def to_json(spec: Spec, rows: Sequence[dict], seconds: float) -> dict:
    """``--json``: ``name``, ``question``, ``scenarios``, ``wall_time`` s, ``status``
    counts, ``columns`` and ``rows`` (objects keyed by the columns; null = undefined)."""
    def clean(v):
        return None if isinstance(v, float) and not math.isfinite(v) else v

    counts = {k: sum(r['status'] == k for r in rows) for k in STATUSES}
    return {'name': spec.name, 'question': spec.question, 'scenarios': len(rows),
            'wall_time': seconds, 'status': counts, 'columns': list(COLUMNS),
            'rows': [{c: clean(r[c]) for c in COLUMNS} for r in rows]}


def default_plot(spec: Spec) -> PlotSpec:
    """Without a ``plot`` section: the first numeric axis across, the first other axis as
    curves, peak torques and the task's main error up."""
    x, by = 'index', None
    names = list(spec.axes)

    def numeric(n):
        values = spec.axes[n] if isinstance(spec.axes[n], list) else spec.axes[n]['arg']
        return all(isinstance(v, float) for v in values)

    nums = [n for n in names if numeric(n) and f'{n}_1' not in COLUMNS]
    if nums:
        x = nums[0]
    others = [n for n in names if n != x and n in COLUMNS]
    if others:
        by = others[0]
    elif VARIANT in names:
        by = 'law'
    task = spec.scenario.get('task', 'straight_line')
    err = 'deviation_max' if task == 'straight_line' else 'settling_time_overall'
    return PlotSpec(x=x, y=('torque_peak_1', 'torque_peak_2', err), by=by)


def sweep_figure(spec: Spec, rows: Sequence[dict]) -> Any:
    """The matplotlib figure of ``spec.plot`` (or :func:`default_plot`): one panel per
    ``y`` column, one curve per ``by`` value (labelled ``<by> = <value>``: the mean of the
    rows at each ``x`` where other settings vary too), the effort limits drawn on torque
    panels; refused and diverged scenarios are left out. Drawn with the Agg backend; the
    caller closes it (``matplotlib.pyplot.close``)."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    ps = spec.plot or default_plot(spec)
    ok = [r for r in rows if r['status'] == 'ok']
    groups: dict[object, list[dict]] = {}
    for r in ok:
        groups.setdefault(r[ps.by] if ps.by else '', []).append(r)
    fig, axes = plt.subplots(len(ps.y), 1, figsize=(8, 2.6 * len(ps.y) + 0.8), sharex=True,
                             squeeze=False)
    for ax, col in zip(axes[:, 0], ps.y):
        for label, rs in groups.items():
            xs = sorted({float(r[ps.x]) for r in rs})
            ys = []
            for x in xs:
                v = [float(r[col]) for r in rs if float(r[ps.x]) == x]
                v = [y for y in v if math.isfinite(y)]
                ys.append(sum(v) / len(v) if v else math.nan)
            ax.plot(xs, ys, marker='.', label=f'{ps.by} = {label}' if ps.by else None)
        if col.startswith(('torque_peak_', 'torque_rms_')):
            j = col[-1]
            for lim in sorted({r[f'effort_limit_{j}'] for r in ok}):
                ax.axhline(lim, color='k', ls='--', lw=1)
                ax.annotate(f'effort limit {lim:g} N m', (0.01, lim), color='k',
                            xycoords=('axes fraction', 'data'), va='bottom', fontsize=8)
        ax.set_ylabel(_label(col))
        ax.grid(alpha=0.3, which='both')
        drawn = [float(r[col]) for r in ok if math.isfinite(float(r[col]))]
        if drawn and min(drawn) > 0 and max(drawn) > 100 * min(drawn):
            ax.set_yscale('log')  # spans decades (e.g. mm under one law, m under another)
    if ps.by and groups:
        axes[0, 0].legend(fontsize=8)
    axes[-1, 0].set_xlabel(_label(ps.x))
    xs_all = [float(r[ps.x]) for r in ok if math.isfinite(float(r[ps.x]))]
    if xs_all and min(xs_all) > 0 and max(xs_all) > 20 * min(xs_all):
        axes[-1, 0].set_xscale('log')  # a wide positive range (e.g. a logspace axis)
    skipped = len(rows) - len(ok)
    title = spec.name + (f': {spec.question}' if spec.question else '')
    fig.suptitle(textwrap.fill(title, 100) + (f'\n({skipped} refused or diverged, not drawn)'
                                              if skipped else ''), fontsize=9)
    fig.tight_layout()
    return fig


def plot_sweep(spec: Spec, rows: Sequence[dict], path: str | Path) -> Path:
    """Draw :func:`sweep_figure` into a PNG at ``path``; returns the path."""
    import matplotlib.pyplot as plt

    fig = sweep_figure(spec, rows)
    try:
        fig.savefig(path, dpi=100)
    finally:
        plt.close(fig)
    return Path(path)


_UNITS = {'duration': 's', 'payload': 'kg', 'control_rate': 'Hz', 'deviation': 'm',
          'torque': 'N m', 'settling': 's', 'tracking': 'rad', 'kp': '', 'energy': 'J',
          'overshoot': '%'}


def _label(col: str) -> str:
    unit = next((u for k, u in _UNITS.items() if col.startswith(k)), '')
    return f'{col} [{unit}]' if unit else col


def summary(spec: Spec, rows: Sequence[dict], seconds: float) -> str:
    """A few lines: counts and the extremes of the main metrics."""
    counts = {k: sum(r['status'] == k for r in rows) for k in STATUSES}
    lines = [f'{spec.name}: {len(rows)} scenarios in {seconds:.1f} s '
             f"({', '.join(f'{v} {k}' for k, v in counts.items())})"]
    if spec.question:
        lines.append(f'question: {spec.question}')
    ok = [r for r in rows if r['status'] == 'ok']
    for col in ('torque_peak_1', 'torque_peak_2', 'deviation_max', 'settling_time_overall'):
        v = np.array([r[col] for r in ok], dtype=float)
        v = v[np.isfinite(v)]
        if len(v):
            lines.append(f'  {_label(col)}: {v.min():.4g} .. {v.max():.4g}')
    return '\n'.join(lines)
