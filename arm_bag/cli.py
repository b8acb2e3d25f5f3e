"""``arm-sim analyze BAG...``: metrics of recorded runs (thin CLI over arm_bag.analysis);
``arm-sim analyze BAG --frf``: the frequency response of a chirp run (arm_bag.frf);
``arm-sim bag recover BAG``: make a damaged or unfinished bag complete (arm_bag.recover).

Exit codes: 0 every bag analysed / a complete bag written; 2 usage error; 3 a bag holds
nothing analysable (no joint states; ``--frf``: no reference or no broadband excitation);
4 a path is not a bag, is not a regular file (a FIFO, device or socket: refused naming its
kind, never opened), is unreadable or damaged
(``analyze``), or holds nothing recoverable (``bag recover``). Errors are one line on stderr;
warnings (truncated bag, no metadata, default robot parameters, ...) are printed as
``warning: ...`` lines on stderr and never change the exit code.
"""

from __future__ import annotations

import argparse
import json
import sys

from arm_common.exits import EXIT_NOTHING, EXIT_OK, EXIT_UNREADABLE, EXIT_USAGE


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
        'torque, energy; friction loss, and each push\'s peak deviation and recovery time '
        'and each fault, when the bag has them); several bags are compared side by side; '
        'with --frf the frequency '
        'response of a chirp run against the linearised loop. Exit codes: 0 ok, '
        '2 usage, 3 nothing analysable, 4 not a bag / unreadable.')
    p.add_argument('bags', nargs='+', metavar='BAG', help='bag directory or .mcap file')
    p.add_argument('--json', action='store_true',
                   help='print JSON (keys documented in arm_bag.analysis) instead of a table')
    p.add_argument('--plot', metavar='FILE.png', default=None,
                   help='also write a PNG: joint angles vs reference, torques, end-effector '
                   'path vs line, deviation over time (with --frf: the Bode diagram)')
    frf = p.add_argument_group(
        'frequency response (--frf)',
        'Estimate the closed-loop frequency response q / q_des of each excited joint '
        'from a chirp or multi-sine run (planner mode chirp; docs/frf.md), with '
        'coherence and the loop return ratio from the command, and compare it with the '
        'linearised sampled-data loop (the control period\'s hold, --delay). Bags do not '
        'record the controller\'s law and gains: give them here (defaults: the '
        'controller\'s defaults). One bag; --plot writes the Bode diagram.')
    frf.add_argument('--frf', action='store_true',
                     help='frequency response instead of the metrics table')
    frf.add_argument('--law', default='computed_torque', metavar='LAW',
                     help='the controller\'s law during the run: ' + ', '.join(_frf_laws())
                     + ' (default computed_torque, the controller\'s default)')
    frf.add_argument('--kp', type=float, nargs='+', default=None, metavar='KP',
                     help='gains.kp per joint [N m/rad; computed_torque 1/s^2] (default: '
                     'the controller\'s, 100 60)')
    frf.add_argument('--kd', type=float, nargs='+', default=None, metavar='KD',
                     help='gains.kd per joint [N m s/rad; computed_torque 1/s] (default: '
                     'the controller\'s, 20 12)')
    frf.add_argument('--ki', type=float, nargs='+', default=None, metavar='KI',
                     help='gains.ki per joint [N m/(rad s)], pid only (default 50 30)')
    frf.add_argument('--delay', type=int, default=0, metavar='PERIODS',
                     help='control periods between a state and the torque answering it '
                     '(default 0: lockstep)')
    frf.add_argument('--f-min', type=float, default=0.1, metavar='HZ',
                     help='lowest frequency checked against the prediction [Hz] (default '
                     '0.1)')
    frf.add_argument('--f-max', type=float, default=None, metavar='HZ',
                     help='highest frequency checked [Hz] (default: a third of the Nyquist '
                     'rate, 16.7 Hz at 100 Hz)')
    p.add_argument('--dask', metavar='SCHEDULER_ADDRESS', default=None,
                   help='analyse the bags on a Dask distributed cluster (e.g. '
                   'tcp://10.0.0.5:8786; needs the dask extra; every worker must see the '
                   'bag paths); the reports equal a local run')
    p.set_defaults(func=run_analyze)
    return p


def with_recover_advice(message: str, path: str) -> str:
    """``message`` (a damage error ending in the in-place ``arm-sim bag recover PATH``
    hint) with the recovery that works for ``path`` instead
    (:func:`arm_bag.recover.recover_advice`: ``--output DIR`` when the bag's directory
    cannot be written, e.g. on read-only storage)."""
    from arm_bag.bagfile import recover_hint
    from arm_bag.recover import recover_advice

    in_place = recover_hint(path)
    if in_place not in message:
        return message
    return message.replace(in_place, recover_advice(path))


def analyze_one(path: str) -> tuple[str, object]:
    """``('ok', report)`` or ``(kind, message)`` for one bag, kind ``unreadable`` or
    ``nothing``: the exceptions as values, so a Dask worker can return them too."""
    from arm_bag.analysis import NothingToAnalyse, analyze
    from arm_bag.reader import BagError

    try:
        return 'ok', analyze(path)
    except BagError as exc:
        return 'unreadable', with_recover_advice(reason(exc), path)
    except NothingToAnalyse as exc:
        return 'nothing', f'nothing to analyse: {reason(exc)}'
    except (OSError, MemoryError) as exc:
        return 'unreadable', f'{path}: cannot read: {reason(exc)}'


def _frf_laws() -> tuple[str, ...]:
    from arm_control.closed_loop import LINEAR_LAWS

    return LINEAR_LAWS


def run_frf(args: argparse.Namespace) -> int:
    """``analyze --frf``: one bag's frequency response; returns the exit code."""
    from arm_bag.frf import FrfError, format_frf, frf_analysis
    from arm_bag.reader import BagError
    from arm_control.laws import Gains

    def fail(message: str, code: int) -> int:
        print(f'arm-sim analyze --frf: {message}', file=sys.stderr)
        return code

    if len(args.bags) != 1:
        return fail(f'give one bag, got {len(args.bags)}', EXIT_USAGE)
    if args.json or args.dask:
        return fail('--json and --dask do not apply to --frf', EXIT_USAGE)
    if args.law not in _frf_laws():
        return fail(f"--law must be one of {', '.join(_frf_laws())}; got {args.law!r}",
                    EXIT_USAGE)
    if args.delay < 0:
        return fail(f'--delay must be >= 0 periods, got {args.delay}', EXIT_USAGE)
    given = {k: tuple(getattr(args, k)) for k in ('kp', 'kd', 'ki')
             if getattr(args, k) is not None}
    try:
        gains = Gains(**given) if given else Gains()
    except ValueError as exc:
        return fail(f'gains: {reason(exc)}', EXIT_USAGE)
    try:
        rep = frf_analysis(args.bags[0], law=args.law, gains=gains, delay=args.delay,
                           f_min=args.f_min, f_max=args.f_max)
    except BagError as exc:
        return fail(reason(exc), EXIT_UNREADABLE)
    except (OSError, MemoryError) as exc:
        return fail(f'{args.bags[0]}: cannot read: {reason(exc)}', EXIT_UNREADABLE)
    except FrfError as exc:
        return fail(reason(exc), EXIT_NOTHING)
    for w in rep.warnings:
        print(f'warning: {w}', file=sys.stderr)
    print(format_frf(rep))
    if args.plot:
        from arm_bag.plot import plot_frf

        try:
            plot_frf(rep, args.plot)
        except (OSError, ValueError) as exc:
            return fail(f'cannot write plot {args.plot}: {reason(exc)}', EXIT_UNREADABLE)
    return EXIT_OK


def run_analyze(args: argparse.Namespace) -> int:
    """Run ``analyze``; returns the exit code (never raises for bad input)."""
    if getattr(args, 'frf', False):
        return run_frf(args)
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
            from arm_bag.report import format_events, format_table

            print(format_table(reports))
            events = format_events(reports)  # pushes and faults: only bags that have them
            if events:
                print(f'\n{events}')
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
        from arm_bag.bagfile import recover_hint
        from arm_bag.recover import recover_advice

        advice = recover_advice(args.bag) if args.output is None else ''
        hint = f'; {advice}' if advice and advice != recover_hint(args.bag) else ''
        print(f'arm-sim bag recover: {args.bag}: {reason(exc)}{hint}', file=sys.stderr)
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
