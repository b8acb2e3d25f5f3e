"""``arm-sim analyze BAG...``: metrics of recorded runs (thin CLI over arm_bag.analysis);
``arm-sim bag recover BAG``: make a damaged or unfinished bag complete (arm_bag.recover).

Exit codes: 0 every bag analysed / a complete bag written; 2 usage error; 3 a bag holds
nothing analysable (no joint states); 4 a path is not a bag, is not a regular file (a FIFO,
device or socket: refused naming its kind, never opened), is unreadable or damaged
(``analyze``), or holds nothing recoverable (``bag recover``). Errors are one line on stderr;
warnings (truncated bag, no metadata, default robot parameters, ...) are printed as
``warning: ...`` lines on stderr and never change the exit code.
"""

from __future__ import annotations

import argparse
import json
import sys

EXIT_OK, EXIT_USAGE, EXIT_NOTHING, EXIT_UNREADABLE = 0, 2, 3, 4


def reason(exc: BaseException) -> str:
    """What went wrong, as words: never empty (a bare MemoryError has no message)."""
    if isinstance(exc, MemoryError):
        return f'out of memory ({exc})' if str(exc) else 'out of memory'
    text = str(getattr(exc, 'strerror', None) or exc)
    return ' '.join(text.split()) or type(exc).__name__


def add_analyze_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``analyze`` sub-command to an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        'analyze', help='metrics of recorded runs (bag directories or .mcap files)',
        description='Read rosbag2/MCAP bags recorded from arm_sim and print per-segment '
        'metrics (tracking error, settling time, overshoot, straight-line deviation, '
        'torque, energy); several bags are compared side by side. Exit codes: 0 ok, '
        '2 usage, 3 nothing analysable, 4 not a bag / unreadable.')
    p.add_argument('bags', nargs='+', metavar='BAG', help='bag directory or .mcap file')
    p.add_argument('--json', action='store_true',
                   help='print JSON (keys documented in arm_bag.analysis) instead of a table')
    p.add_argument('--plot', metavar='FILE.png', default=None,
                   help='also write a PNG: joint angles vs reference, torques, end-effector '
                   'path vs line, deviation over time')
    p.add_argument('--dask', metavar='SCHEDULER_ADDRESS', default=None,
                   help='analyse the bags on a Dask distributed cluster (e.g. '
                   'tcp://10.0.0.5:8786; needs the dask extra; every worker must see the '
                   'bag paths); the reports equal a local run')
    p.set_defaults(func=run_analyze)
    return p


def analyze_one(path: str) -> tuple[str, object]:
    """``('ok', report)`` or ``(kind, message)`` for one bag, kind ``unreadable`` or
    ``nothing``: the exceptions as values, so a Dask worker can return them too."""
    from arm_bag.analysis import NothingToAnalyse, analyze
    from arm_bag.reader import BagError

    try:
        return 'ok', analyze(path)
    except BagError as exc:
        return 'unreadable', reason(exc)
    except NothingToAnalyse as exc:
        return 'nothing', f'nothing to analyse: {reason(exc)}'
    except (OSError, MemoryError) as exc:
        return 'unreadable', f'{path}: cannot read: {reason(exc)}'


def run_analyze(args: argparse.Namespace) -> int:
    """Run ``analyze``; returns the exit code (never raises for bad input)."""
    if getattr(args, 'dask', None):
        from arm_common.cluster import ClusterError, dask_map

        try:
            outcomes = dask_map(args.dask, analyze_one, list(args.bags))
        except ClusterError as exc:
            print(f'arm-sim analyze: {exc}', file=sys.stderr)
            return EXIT_USAGE
    else:
        outcomes = [analyze_one(path) for path in args.bags]
    reports, code = [], EXIT_OK
    for kind, value in outcomes:
        if kind == 'ok':
            reports.append(value)
            continue
        print(f'arm-sim analyze: {value}', file=sys.stderr)
        if kind == 'unreadable':
            code = EXIT_UNREADABLE
        elif code != EXIT_UNREADABLE:
            code = max(code, EXIT_NOTHING)
    for rep in reports:
        for w in rep.warnings:
            print(f'warning: {w}', file=sys.stderr)
    if reports:
        if args.json:
            docs = [r.to_dict() for r in reports]
            print(json.dumps(docs[0] if len(docs) == 1 else docs, indent=2))
        else:
            from arm_bag.report import format_table

            print(format_table(reports))
        if args.plot:
            from arm_bag.plot import plot_report

            try:
                plot_report(reports, args.plot)
            except (OSError, ValueError) as exc:
                print(f'arm-sim analyze: cannot write plot {args.plot}: {exc}',
                      file=sys.stderr)
                return max(code, EXIT_UNREADABLE)
    return code


def add_bag_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``bag`` command group (``bag recover``) to an argparse ``subparsers``."""
    p = subparsers.add_parser('bag', help='bag maintenance: recover a damaged or unfinished '
                              'bag', description='Bag maintenance commands.')
    group = p.add_subparsers(dest='bag_command', required=True, metavar='BAG_COMMAND')
    rec = group.add_parser(
        'recover', help='make a damaged or unfinished bag complete again',
        description='Read the MCAP file(s) of a bag record by record, like `mcap recover` '
        'and `ros2 bag reindex`: keep every schema, channel and metadata record and every '
        'chunk whose CRC and decompression check out; drop damaged or incomplete chunks '
        '(a recorder killed mid-chunk, a full disk, flipped bytes) and stop where the file '
        'is cut. Writes a complete MCAP file (CRCs on, the compression found) atomically '
        'over the original (files that are already intact are left alone) or into '
        '--output, and rewrites metadata.yaml (per-topic counts, start and duration [ns], '
        'recording marker closed). Prints one summary line (messages kept, chunks and '
        'messages dropped and why, bytes cut at the end [bytes]) and the messages kept '
        'per topic. Exit codes: 0 a complete bag was written, 4 nothing recoverable (not '
        'MCAP, no intact message) or the bag is still being recorded.')
    rec.add_argument('bag', metavar='DIR_OR_MCAP', help='bag directory or .mcap file')
    rec.add_argument('--output', metavar='DIR', default=None,
                     help='write the recovered bag to this new (or empty) directory instead '
                     'of replacing the damaged files in place')
    rec.set_defaults(func=run_recover)
    return p


def run_recover(args: argparse.Namespace) -> int:
    """Run ``bag recover``; returns the exit code (never raises for bad input)."""
    from arm_bag.bagfile import BagError
    from arm_bag.recover import recover_bag

    try:
        report = recover_bag(args.bag, args.output)
    except BagError as exc:  # RecoveryError, a file that is not a regular file, ...
        print(f'arm-sim bag recover: {reason(exc)}', file=sys.stderr)
        return EXIT_UNREADABLE
    except (OSError, MemoryError) as exc:
        print(f'arm-sim bag recover: {args.bag}: {reason(exc)}', file=sys.stderr)
        return EXIT_UNREADABLE
    written = ', '.join(report.files) or 'nothing rewritten (already intact)'
    print(f'{report.output}: {report.summary()}; written: {written}')
    for topic, n in sorted(report.topics.items()):
        print(f'  {topic}: {n} messages')
    return EXIT_OK


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='arm-sim')
    sub = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    add_analyze_parser(sub)
    add_bag_parser(sub)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == '__main__':
    raise SystemExit(main())
