"""``arm-sim sweep``: the sub-command's parser, its help, and the command itself.

Pure: no rclpy. Bad input is one line on stderr and an exit code, never a traceback.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path

from arm_common.exits import EXIT_ERROR, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE
from arm_sim.sweep.output import (
    OutputFile,
    default_plot,
    plot_format,
    plot_sweep,
    summary,
    to_json,
    write_csv,
    write_reason,
)
from arm_sim.sweep.run import Progress, SweepStopped, max_workers, run_sweep
from arm_sim.sweep.spec import (
    MAX_AXIS_VALUES,
    MAX_CURVES,
    MAX_PLOT_PANELS,
    MAX_SAMPLES,
    MAX_SCENARIOS,
    MAX_SPEC_BYTES,
    MAX_STEPS,
    SETTINGS,
    Spec,
    SpecError,
    load_spec,
    plot_problem,
    resolve_spec,
    shipped_specs,
)


def _settings_help() -> str:
    lines = ['scenario settings (in scenario: fixed, in axes: varied; pairs are per joint, '
             'one number = both joints):']
    for p in SETTINGS.values():
        d = (f"[{', '.join(f'{v:.4g}' for v in p.default)}]" if isinstance(p.default, tuple)
             else p.default if p.default != '' else 'none')
        u = f' [{p.unit}]' if p.unit else ''
        r = ('' if p.minimum is None or p.maximum is None else
             f"; range {'(' if p.strict_min else '['}{p.minimum:g}, {p.maximum:g}]")
        lines.append(f'  {p.name}{u}: {p.description} (default {d}{r})')
    return '\n'.join(lines)


EPILOG = """SPEC is a YAML file (or the name of a shipped one: {shipped}):

  name: line_speed
  question: How does line deviation grow with speed under each law?
  sweep: grid                 # grid: every combination | random: `samples` draws, `seed`
  scenario: {{task: straight_line, start: [0.5, 1.2], goal: [1.478, 0.184]}}
  axes:      # grid: [values] | {{linspace: [a, b, n]}} | {{logspace: [a, b, n]}}
             # random: [choices] | {{uniform: [a, b]}} | {{loguniform: [a, b]}}
    duration: {{linspace: [0.4, 3.0, 27]}}
    payload: [0.0, 0.5, 1.0]
    variant:                  # one axis of setting bundles, e.g. a law with its gains
      - {{law: computed_torque, kp: [100, 60], kd: [20, 12]}}
      - {{law: pd, kp: [600, 300], kd: [60, 25]}}
  plot: {{x: duration, y: [torque_peak_1, deviation_max], by: law}}
  margins: false    # true: add phase_margin [deg], gain_margin [dB], bandwidth [Hz] per
                    # joint (the linearised loop at the goal; a few ms per scenario)

{settings}

Each scenario starts at rest at `start`, plans as the planner node does (robot without
payload or model errors), and runs the controller's law and the simulator's RK4 and
sampled-data timing for the motion plus `hold` s. Output: one row per scenario with the
arm-sim analyze metrics (columns: see arm_sim/sweep/__init__.py).

Limits, checked before anything is built or run (over one: one line naming it, exit 2):
  scenarios per sweep (grid: the product of axis lengths; random: samples) {max_scenarios}
  values per axis (a list, a linspace/logspace count)                      {max_axis}
  control samples per scenario: (duration + hold) x control_rate           {max_samples}
  RK4 steps per scenario: (duration + hold) / physics_step                 {max_steps}
    (a plan the planner stretches past these two is a refused row)
  every setting: its range above (gains <= 1e6, as the controller's gains.*)
  spec file size [bytes]; YAML anchors and aliases (&a, *a) are refused    {max_bytes}
  plot: panels (y) / curves (by); x and y: number columns                  {plot_limits}
  --workers: 4 per CPU                                                     {max_workers}

Outputs are checked before the run (each file can be created); the CSV and the plot go to
a temporary file next to them, renamed when complete: a full disk leaves no cut file but
one line naming the file and the error (exit 1). The CSV and JSON are written before the
plot is drawn.

Ctrl-C (SIGINT) or SIGTERM stops a sweep within about a second: no further chunk starts,
the workers are terminated, the finished rows are written (--output, --json; the plot is
not drawn) and one line says how many of how many scenarios finished (exit 130). Another
Ctrl-C while writing abandons the writing (no cut file). The workers die with the main
process, also when it is killed (SIGKILL).

Exit codes: 0 ok, 1 a run or an output failed, 2 bad spec or usage, 130 interrupted."""


def add_sweep_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``sweep`` sub-command to an argparse ``subparsers`` object."""
    try:
        shipped = ', '.join(shipped_specs()) or 'none found'
    except FileNotFoundError:
        shipped = 'none found'
    p = subparsers.add_parser(
        'sweep', help='run a grid or random sample of closed-loop scenarios headless',
        description='Run many closed-loop scenarios of the 2-R arm without ROS (the same '
        'planner, control laws, RK4 and sampled-data timing as the nodes), vectorised and '
        'in parallel, and write one row of metrics per scenario.',
        epilog=EPILOG.format(shipped=shipped, settings=_settings_help(),
                             max_scenarios=MAX_SCENARIOS, max_axis=MAX_AXIS_VALUES,
                             max_samples=MAX_SAMPLES, max_steps=MAX_STEPS,
                             max_bytes=MAX_SPEC_BYTES,
                             plot_limits=f'{MAX_PLOT_PANELS} / {MAX_CURVES}',
                             max_workers=max_workers()),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('spec', metavar='SPEC', help='sweep spec (YAML) or a shipped spec name')
    p.add_argument('--output', metavar='FILE.csv', default=None,
                   help='write the results table (CSV: one row per scenario; whole or not '
                   'at all)')
    p.add_argument('--json', action='store_true', help='print the results as JSON on stdout')
    p.add_argument('--plot', metavar='FILE.png', default=None,
                   help="draw the spec's question (its plot section) into a PNG")
    p.add_argument('--workers', type=int, default=2,
                   help='local worker processes (default 2; 1 = this process; at most 4 '
                   f'per CPU: {max_workers()} here)')
    p.add_argument('--chunk-size', type=int, default=None,
                   help='scenarios stepped together per batch (default: about 4 chunks '
                   'per worker, 32-1024)')
    p.add_argument('--dask', metavar='SCHEDULER_ADDRESS', default=None,
                   help='run the chunks on a Dask distributed cluster (e.g. '
                   'tcp://10.0.0.5:8786; needs the dask extra); results equal the local run')
    p.add_argument('--quiet', action='store_true', help='no progress lines on stderr')
    p.set_defaults(func=run_sweep_command)
    return p


class _Signals:
    """While running: SIGINT and SIGTERM raise KeyboardInterrupt (as ``arm-sim`` makes
    them) and remember which one came, for the message."""

    def __init__(self) -> None:
        self.name = 'SIGINT'
        self.old: dict[int, object] = {}

    def _raise(self, signum: int, _frame) -> None:
        self.name = signal.Signals(signum).name
        raise KeyboardInterrupt

    def __enter__(self) -> _Signals:
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                self.old[sig] = signal.signal(sig, self._raise)
            except ValueError:  # not the main thread: leave them
                pass
        return self

    def __exit__(self, *_) -> None:
        for sig, handler in self.old.items():
            if handler is not None:  # None: not set from Python; nothing to put back
                signal.signal(sig, handler)  # type: ignore[arg-type]


def _print_json(doc: dict) -> None:
    """The JSON document on stdout, flushed: a write error (a full disk, /dev/full) is
    raised here (OSError), not at exit."""
    sys.stdout.write(json.dumps(doc, indent=1, allow_nan=False) + '\n')
    sys.stdout.flush()


def run_sweep_command(args: argparse.Namespace) -> int:
    """Run ``arm-sim sweep``; returns the exit code (bad input is one line, never a
    traceback). Everything that sizes the work and every output is checked before the
    run; a Ctrl-C (or SIGTERM) stops it, writes the finished rows and returns
    :data:`EXIT_INTERRUPTED`."""
    def fail(msg: str, code: int = EXIT_USAGE) -> int:
        print(f'arm-sim sweep: {msg}', file=sys.stderr)
        return code

    path = resolve_spec(args.spec)
    if not 1 <= args.workers <= max_workers():
        return fail(f'--workers must be in [1, {max_workers()}] (4 per CPU, '
                    f'{os.cpu_count() or 1} CPUs), got {args.workers}')
    if args.chunk_size is not None and not 1 <= args.chunk_size <= MAX_SCENARIOS:
        return fail(f'--chunk-size must be in [1, {MAX_SCENARIOS}], got {args.chunk_size}')
    try:
        spec = load_spec(path)
        if args.plot and spec.plot is None:
            reason = plot_problem(default_plot(spec), spec)
            if reason:
                raise SpecError(f'the default plot: {reason}; give a plot section')
    except (SpecError, ValueError) as exc:
        return fail(f'{path}: {exc}')
    outputs = {k: OutputFile(v) for k, v in (('csv', args.output), ('plot', args.plot)) if v}
    if len({o.path.resolve() for o in outputs.values()}) < len(outputs):
        return fail(f'--output and --plot are the same file: {args.output}')
    written: list[str] = []
    with _Signals() as signals:
        try:
            return _run(args, spec, path, outputs, signals, fail, written)
        except KeyboardInterrupt:  # before the run, or again while writing its results
            return fail(f"interrupted by {signals.name} ({', '.join(written) or 'nothing'} "
                        'written)', EXIT_INTERRUPTED)
        finally:
            for out in outputs.values():
                out.discard()


def _run(args: argparse.Namespace, spec: Spec, path: Path, outputs: dict[str, OutputFile],
         signals: _Signals, fail: Callable[[str, int], int], written: list[str]) -> int:
    """The checks of the outputs, the scenarios, the run and the outputs; ``written``
    collects what was written."""
    try:
        if args.plot:
            plot_format(args.plot)
        for out in outputs.values():
            out.prepare()
    except (OSError, ValueError) as exc:
        return fail(str(exc), EXIT_USAGE)
    try:
        scenarios = spec.scenarios()
    except (SpecError, ValueError) as exc:
        return fail(f'{path}: {exc}', EXIT_USAGE)
    started = time.monotonic()
    bar = None if args.quiet else Progress(len(scenarios))
    stopped = None
    try:
        rows = run_sweep(scenarios, workers=args.workers, chunk_size=args.chunk_size,
                         dask=args.dask, progress=bar.add if bar else None,
                         margins=spec.margins)
    except SpecError as exc:
        return fail(str(exc), EXIT_ERROR)
    except SweepStopped as exc:
        rows, stopped = exc.rows, exc
    seconds = time.monotonic() - started
    # The results first: a failure after them (the plot) loses nothing.
    failures = []
    if 'csv' in outputs:
        try:
            write_csv(rows, outputs['csv'], spec.columns)
            written.append(args.output)
        except OSError as exc:
            failures.append(str(exc))
    if args.json:
        note = None
        if stopped is not None:
            note = {'signal': signals.name if stopped.reason is None else None,
                    'error': stopped.reason, 'finished': len(rows), 'total': stopped.total}
        try:
            _print_json(to_json(spec, rows, seconds, note))
            written.append('the JSON (stdout)')
        except OSError as exc:
            failures.append(write_reason(Path('stdout'), exc) + ' (the JSON is incomplete)')
    if 'plot' in outputs and stopped is None:
        try:
            plot_sweep(spec, rows, outputs['plot'])
            written.append(args.plot)
        except Exception as exc:  # the results are written: say why, in one line
            failures.append(str(exc) if isinstance(exc, OSError) else
                            f'cannot draw {args.plot}: {type(exc).__name__}: {exc}')
    if not args.json:
        try:
            print(summary(spec, rows, seconds))
            for name in written:
                print(f'  wrote {name}')  # (no JSON here: --json prints no summary)
            sys.stdout.flush()
        except OSError as exc:
            failures.append(write_reason(Path('stdout'), exc))
    for msg in failures:
        fail(msg, EXIT_ERROR)
    if stopped is not None:
        what = (f'interrupted by {signals.name}' if stopped.reason is None
                else f'stopped: {stopped.reason}')
        kept = f"wrote {', '.join(written)}" if written else 'wrote nothing'
        plot = f'; {args.plot} not drawn' if args.plot else ''
        fail(f'{what}: {len(rows)} of {stopped.total} scenarios finished; {kept}{plot}',
             EXIT_ERROR)
        return EXIT_INTERRUPTED if stopped.reason is None else EXIT_ERROR
    return EXIT_ERROR if failures else EXIT_OK
