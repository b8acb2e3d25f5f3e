"""A sweep's outputs: the CSV table, the JSON document, the summary lines and the plot.

Pure: no rclpy; matplotlib is imported only to draw. A file is written whole or not at
all (:class:`OutputFile`: a temporary file next to it, renamed over it when complete), and
can be checked before the run.
"""

from __future__ import annotations

import csv
import errno
import math
import os
import stat
import textwrap
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from arm_sim.sweep.columns import COLUMNS, MARGIN_COLUMNS, STATUSES
from arm_sim.sweep.spec import MAX_CURVES, VARIANT, PlotSpec, Spec, plot_problem


class OutputError(OSError):
    """An output that cannot be written; the message (one line) names the file and why."""


def write_reason(path: str | Path, exc: OSError) -> str:
    """``cannot write PATH: <strerror> (<errno name>)``, one line."""
    code = errno.errorcode.get(exc.errno, '') if exc.errno else ''
    return f"cannot write {path}: {exc.strerror or exc}{f' ({code})' if code else ''}"


class OutputFile:
    """An output file, checked before the run (:meth:`prepare`) and written whole or not
    at all (:meth:`write`).

    A regular file (new or existing) is written into a temporary file next to it
    (``.NAME.PID.partial``, created by :meth:`prepare`: the directory must take it),
    flushed to the disk, then renamed over the path: a full disk or a Ctrl-C leaves the
    old file, or none, never a cut one. A device or FIFO (``/dev/null``, ``/dev/full``,
    ``/dev/stdout``) is written in place.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.tmp: Path | None = None
        self.direct = False

    def prepare(self) -> None:
        """Check now that the file can be written; raises :class:`OutputError`."""
        p = self.path
        try:
            st: os.stat_result | None = os.stat(p)
        except FileNotFoundError:
            st = None
        except OSError as exc:
            raise OutputError(write_reason(p, exc)) from None
        if st is not None and stat.S_ISDIR(st.st_mode):
            raise OutputError(f'cannot write {p}: it is a directory')
        if st is not None and not stat.S_ISREG(st.st_mode):
            if not os.access(p, os.W_OK):
                raise OutputError(f'cannot write {p}: Permission denied (EACCES)')
            self.direct = True
            return
        if not p.parent.is_dir():
            raise OutputError(f'cannot write {p}: its directory does not exist')
        if st is not None and not os.access(p, os.W_OK):
            raise OutputError(f'cannot write {p}: Permission denied (EACCES)')
        if self.tmp is None:
            tmp = p.parent / f'.{p.name}.{os.getpid()}.partial'
            try:
                os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            except OSError as exc:
                raise OutputError(write_reason(p, exc)) from None
            self.tmp = tmp

    def write(self, fill: Callable[[IO], object], binary: bool = False) -> Path:
        """Write the file with ``fill(f)`` (``f`` open for text, or bytes if ``binary``);
        raises :class:`OutputError` naming the file and the errno (the temporary file
        removed, the path as it was), or what ``fill`` raised. Returns the path."""
        if not self.direct and self.tmp is None:
            self.prepare()
        target = self.path if self.direct else self.tmp
        assert target is not None
        try:
            f: IO = (open(target, 'wb') if binary
                     else open(target, 'w', newline='', encoding='utf-8'))
            with f:
                fill(f)
                f.flush()
                if not self.direct:
                    os.fsync(f.fileno())
            if not self.direct:
                os.replace(target, self.path)
                self.tmp = None
        except OSError as exc:
            self.discard()
            raise OutputError(write_reason(self.path, exc)) from None
        except BaseException:
            self.discard()
            raise
        return self.path

    def discard(self) -> None:
        """Remove the temporary file, if any (nothing written)."""
        if self.tmp is not None:
            try:
                self.tmp.unlink()
            except OSError:
                pass
            self.tmp = None


def _cell(v: object, infinite: bool = False) -> object:
    """A CSV cell: NaN (undefined) empty; an infinity empty too, or ``inf``/``-inf`` where
    ``infinite`` (a margin column: an infinite gain margin is a value)."""
    if isinstance(v, float) and not math.isfinite(v):
        return str(v) if infinite and not math.isnan(v) else ''
    return v


def _json_value(v: object, infinite: bool = False) -> object:
    """A JSON value: NaN null; an infinity null too, or ``"inf"``/``"-inf"`` where
    ``infinite`` (JSON has no infinity)."""
    if isinstance(v, float) and not math.isfinite(v):
        return str(v) if infinite and not math.isnan(v) else None
    return v


def write_csv(rows: Sequence[dict], path: str | Path | OutputFile,
              columns: Sequence[str] = COLUMNS) -> None:
    """One row per scenario, ``columns`` (default :data:`~arm_sim.sweep.columns.COLUMNS`;
    a spec's: :attr:`Spec.columns <arm_sim.sweep.spec.Spec.columns>`); undefined values
    are empty cells, infinite margins ``inf``. Written whole or not at all
    (:class:`OutputFile`); raises :class:`OutputError`."""
    def fill(f: IO) -> None:
        w = csv.writer(f)
        w.writerow(columns)
        for r in rows:
            w.writerow([_cell(r[c], c in MARGIN_COLUMNS) for c in columns])

    (path if isinstance(path, OutputFile) else OutputFile(path)).write(fill)


def to_json(spec: Spec, rows: Sequence[dict], seconds: float,
            interrupted: dict | None = None) -> dict:
    """``--json``: ``name``, ``question``, ``scenarios``, ``wall_time`` s, ``status``
    counts, ``columns`` (:attr:`Spec.columns <arm_sim.sweep.spec.Spec.columns>`) and
    ``rows`` (objects keyed by the columns; null = undefined, an infinite margin ``"inf"``);
    and ``interrupted`` (e.g. ``{signal, finished, total}``) when given: the rows are the
    finished scenarios only."""
    cols = spec.columns
    counts = {k: sum(r['status'] == k for r in rows) for k in STATUSES}
    doc = {'name': spec.name, 'question': spec.question, 'scenarios': len(rows),
           'wall_time': seconds, 'status': counts, 'columns': list(cols),
           'rows': [{c: _json_value(r[c], c in MARGIN_COLUMNS) for c in cols}
                    for r in rows]}
    if interrupted is not None:
        doc['interrupted'] = interrupted
    return doc


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
    task = spec.scenario.get('task', 'straight_line')
    err = 'deviation_max' if task == 'straight_line' else 'settling_time_overall'
    y = ('torque_peak_1', 'torque_peak_2', err)
    # Curves: the first other axis that makes a few (not a random range, not hundreds).
    others = [n for n in names if n != x and n in COLUMNS
              and plot_problem(PlotSpec(x, y, n), spec) is None]
    if others:
        by = others[0]
    elif VARIANT in names:
        by = 'law'
    return PlotSpec(x=x, y=y, by=by)


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
    if len(groups) > MAX_CURVES:
        raise ValueError(f'plot: by {ps.by!r} has {len(groups)} values, more than '
                         f'{MAX_CURVES} curves')
    fig, axes = plt.subplots(len(ps.y), 1, figsize=(8, 2.6 * len(ps.y) + 0.8), sharex=True,
                             squeeze=False)
    for ax, col in zip(axes[:, 0], ps.y):
        for label, rs in groups.items():
            at: dict[float, list[float]] = {}  # x -> the finite values there, in row order
            for r in rs:
                x, v = float(r[ps.x]), float(r[col])
                if not math.isnan(x):
                    values = at.setdefault(x, [])
                    if math.isfinite(v):
                        values.append(v)
            xs = sorted(at)
            ys = [sum(at[x]) / len(at[x]) if at[x] else math.nan for x in xs]
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


def plot_format(path: str | Path) -> str:
    """The image format of ``path`` (its suffix; none: png); ValueError if matplotlib
    cannot write it."""
    from matplotlib.backend_bases import FigureCanvasBase

    fmt = Path(path).suffix[1:].lower() or 'png'
    known = FigureCanvasBase.get_supported_filetypes()
    if fmt not in known:
        raise ValueError(f'{path}: cannot draw a .{fmt} file (formats: '
                         f"{', '.join(sorted(known))})")
    return fmt


def plot_sweep(spec: Spec, rows: Sequence[dict], path: str | Path | OutputFile) -> Path:
    """Draw :func:`sweep_figure` into an image (PNG, or the format of the suffix) at
    ``path``, whole or not at all (:class:`OutputFile`); returns the path."""
    import matplotlib.pyplot as plt

    out = path if isinstance(path, OutputFile) else OutputFile(path)
    fmt = plot_format(out.path)
    fig = sweep_figure(spec, rows)
    try:
        return out.write(lambda f: fig.savefig(f, format=fmt, dpi=100), binary=True)
    finally:
        plt.close(fig)


_UNITS = {'duration': 's', 'payload': 'kg', 'control_rate': 'Hz', 'deviation': 'm',
          'torque': 'N m', 'settling': 's', 'tracking': 'rad', 'kp': '', 'energy': 'J',
          'overshoot': '%', 'phase_margin': 'deg', 'gain_margin': 'dB', 'bandwidth': 'Hz'}


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
    margins = ('phase_margin_1', 'phase_margin_2') if spec.margins else ()
    for col in ('torque_peak_1', 'torque_peak_2', 'deviation_max', 'settling_time_overall',
                *margins):
        v = np.array([r[col] for r in ok], dtype=float)
        v = v[np.isfinite(v)]
        if len(v):
            lines.append(f'  {_label(col)}: {v.min():.4g} .. {v.max():.4g}')
    return '\n'.join(lines)
