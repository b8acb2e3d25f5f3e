"""``arm-sim sweep``: the sub-command's parser, its help, and the command itself.

Pure: no rclpy. Bad input is one line on stderr and an exit code, never a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from arm_sim.sweep.output import plot_sweep, summary, to_json, write_csv
from arm_sim.sweep.run import Progress, run_sweep
from arm_sim.sweep.spec import SETTINGS, SpecError, load_spec, resolve_spec, shipped_specs

EXIT_OK, EXIT_ERROR, EXIT_USAGE = 0, 1, 2


def _settings_help() -> str:
    lines = ['scenario settings (in scenario: fixed, in axes: varied; pairs are per joint, '
             'one number = both joints):']
    for p in SETTINGS.values():
        d = (f"[{', '.join(f'{v:.4g}' for v in p.default)}]" if isinstance(p.default, tuple)
             else p.default)
        u = f' [{p.unit}]' if p.unit else ''
        lines.append(f'  {p.name}{u}: {p.description} (default {d})')
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

{settings}

Each scenario starts at rest at `start`, plans as the planner node does (robot without
payload or model errors), and runs the controller's law and the simulator's RK4 and
sampled-data timing for the motion plus `hold` s. Output: one row per scenario with the
arm-sim analyze metrics (columns: see arm_sim/sweep/__init__.py). Exit codes: 0 ok, 1 a
run or an output failed, 2 bad spec or usage."""


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
        epilog=EPILOG.format(shipped=shipped, settings=_settings_help()),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('spec', metavar='SPEC', help='sweep spec (YAML) or a shipped spec name')
    p.add_argument('--output', metavar='FILE.csv', default=None,
                   help='write the results table (CSV: one row per scenario)')
    p.add_argument('--json', action='store_true', help='print the results as JSON on stdout')
    p.add_argument('--plot', metavar='FILE.png', default=None,
                   help="draw the spec's question (its plot section) into a PNG")
    p.add_argument('--workers', type=int, default=2,
                   help='local worker processes (default 2; 1 = this process)')
    p.add_argument('--chunk-size', type=int, default=None,
                   help='scenarios stepped together per batch (default: about 4 chunks '
                   'per worker, 32-1024)')
    p.add_argument('--dask', metavar='SCHEDULER_ADDRESS', default=None,
                   help='run the chunks on a Dask distributed cluster (e.g. '
                   'tcp://10.0.0.5:8786; needs the dask extra); results equal the local run')
    p.add_argument('--quiet', action='store_true', help='no progress lines on stderr')
    p.set_defaults(func=run_sweep_command)
    return p


def run_sweep_command(args: argparse.Namespace) -> int:
    """Run ``arm-sim sweep``; returns the exit code (bad input is one line, never a
    traceback)."""
    def fail(msg: str, code: int = EXIT_USAGE) -> int:
        print(f'arm-sim sweep: {msg}', file=sys.stderr)
        return code

    path = resolve_spec(args.spec)
    if args.workers < 1:
        return fail(f'--workers must be >= 1, got {args.workers}')
    if args.chunk_size is not None and args.chunk_size < 1:
        return fail(f'--chunk-size must be >= 1, got {args.chunk_size}')
    try:
        spec = load_spec(path)
        scenarios = spec.scenarios()
    except (SpecError, ValueError) as exc:
        return fail(f'{path}: {exc}')
    for out in (args.output, args.plot):
        if out and not Path(out).resolve().parent.is_dir():
            return fail(f'{out}: its directory does not exist')
    started = time.monotonic()
    bar = None if args.quiet else Progress(len(scenarios))
    try:
        rows = run_sweep(scenarios, workers=args.workers, chunk_size=args.chunk_size,
                         dask=args.dask, progress=bar.add if bar else None)
    except SpecError as exc:
        return fail(str(exc), EXIT_ERROR)
    seconds = time.monotonic() - started
    try:
        if args.output:
            write_csv(rows, args.output)
        if args.plot:
            plot_sweep(spec, rows, args.plot)
    except OSError as exc:
        return fail(f'cannot write output: {exc}', EXIT_ERROR)
    if args.json:
        json.dump(to_json(spec, rows, seconds), sys.stdout, indent=1, allow_nan=False)
        print()
    else:
        print(summary(spec, rows, seconds))
        for out in (args.output, args.plot):
            if out:
                print(f'  wrote {out}')
    return EXIT_OK
