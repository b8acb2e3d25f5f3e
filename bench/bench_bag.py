"""Benchmark: reading a 1 M-message arm_sim bag with arm_bag vs rosbags vs mcap-ros2-support.

Writes a synthetic bag with arm_bag's own writer (no ROS): N/2 joint_states and N/2
arm_controller/reference JointState messages at 100 Hz plus one trajectory and path per 10 s,
then times ``arm_bag.analysis.analyze`` end to end (open, read, decode, all metrics) on the
whole bag, and the two libraries reading + deserialising the first ``--compare`` messages
(extrapolated as a rate: they are 10-50x slower). Rates are JointState messages per second.

Peak memory: each measurement of ours runs ``analyze`` once more in a fresh subprocess
(``python -c``), and ``arm_bag.recover.recover_bag`` on the same bag (read, checked and
written anew into another directory: the whole work of ``arm-sim bag recover``) in
another, each reporting its own peak resident set (``VmHWM``; ``ru_maxrss`` counts the
parent's memory at the fork too), and that of a bare interpreter with the same imports,
so the table shows the
peak and the peak over the imports, both also as a fraction of the bag's size on disk.
``--memory-messages N`` (default 5e6, 0 = skip) adds an uncompressed N-message bag
measured for memory alone (the issue-14 target for analyze, and the "Reliability" one for
recovery: peak <= 0.5 x the bag size). ``--no-recover`` skips the recovery rows.
Run: ``python bench/bench_bag.py``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from arm_bag.analysis import analyze
from arm_bag.synthetic import open_bag, write_run


def make_bag(path: Path, n_messages: int, compression: str) -> float:
    """Write the benchmark bag; returns the write time [s]."""
    start = time.perf_counter()
    w, ch = open_bag(path, compression=compression, chunk_size=1 << 20)
    per_seg = 1000  # 10 s at 100 Hz, two messages per sample
    n_samples = n_messages // 2
    log = 1_000_000_000
    rng = np.random.default_rng(0)
    done = 0
    seg = 0
    while done < n_samples:
        n = min(per_seg, n_samples - done)
        t = np.arange(n) * 0.01
        goal = rng.uniform(-1, 1, 2)
        q = goal + 0.5 * np.exp(-t / 0.5)[:, None] * np.cos(4 * t)[:, None]
        qd = np.gradient(q, t, axis=0) if n > 1 else np.zeros_like(q)
        tau = 10 * (goal - q)
        traj = (np.array([q[0], goal]), np.array([0.0, 2.0]))
        log = write_run(w, ch, log, t, q, qd, tau, q * 0 + goal, traj,
                        stamp0=seg * 10_000_000_000)
        done += n
        seg += 1
    w.close()
    return time.perf_counter() - start


def time_ours(path: Path) -> tuple[float, int]:
    start = time.perf_counter()
    rep = analyze(path)
    elapsed = time.perf_counter() - start
    return elapsed, sum(v for k, v in rep.message_counts.items()
                        if k in ('/joint_states', '/arm_controller/reference'))


_PEAK = """
import resource, sys, time
from arm_bag.analysis import analyze
from arm_bag.recover import recover_bag

def peak():
    try:  # this process's own high-water mark
        with open('/proc/self/status') as f:
            return next(int(l.split()[1]) for l in f if l.startswith('VmHWM:')) * 1024
    except (OSError, StopIteration):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024

start = time.perf_counter()
if sys.argv[2] == 'analyze':
    analyze(sys.argv[1])
elif sys.argv[2] == 'recover':
    recover_bag(sys.argv[1], sys.argv[3])
print(peak(), time.perf_counter() - start)
"""


def peak_rss(path: Path, what: str = 'analyze') -> tuple[int, int, float]:
    """(peak RSS [bytes] of a fresh ``python`` that imported arm_bag and ran ``what`` on
    ``path``: ``analyze``, or ``recover`` (``recover_bag`` into a new directory, removed
    after), peak RSS of one that only imported it, the run's time [s]).

    The peak is the child's ``VmHWM`` (/proc/self/status): on Linux the child's
    ``ru_maxrss`` also counts the parent's resident set at the fork (the old memory map's
    high-water mark is carried over at exec), which here is the benchmark holding its own
    data; ``ru_maxrss`` is used only where /proc is missing."""
    root = str(Path(__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [root, *filter(None, [os.environ.get('PYTHONPATH')])]))
    out: dict[str, tuple[int, float]] = {}
    target = path.with_name(path.name + '-recovered')
    try:
        for mode in (what, 'import'):
            res = subprocess.run([sys.executable, '-c', _PEAK, str(path), mode, str(target)],
                                 env=env, capture_output=True, text=True, check=True)
            peak, seconds = res.stdout.split()
            out[mode] = int(peak), float(seconds)
    finally:
        shutil.rmtree(target, ignore_errors=True)
    return out[what][0], out['import'][0], out[what][1]


def bag_bytes(path: Path) -> int:
    return sum(f.stat().st_size for f in path.iterdir())


def time_rosbags(path: Path, limit: int) -> float:
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    start = time.perf_counter()
    n = 0
    with Reader(path) as reader:
        for conn, _t, raw in reader.messages():
            store.deserialize_cdr(raw, conn.msgtype)
            n += 1
            if n >= limit:
                break
    return n / (time.perf_counter() - start)


def time_mcap_ros2(path: Path, limit: int) -> float:
    from mcap_ros2.reader import read_ros2_messages

    start = time.perf_counter()
    n = 0
    for _msg in read_ros2_messages(str(next(path.glob('*.mcap')))):
        n += 1
        if n >= limit:
            break
    return n / (time.perf_counter() - start)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--messages', type=int, default=1_000_000, help='bag size (default 1e6)')
    ap.add_argument('--compare', type=int, default=50_000,
                    help='messages the other libraries read (default 5e4)')
    ap.add_argument('--repeats', type=int, default=3, help='timed runs of ours (best kept)')
    ap.add_argument('--memory-messages', type=int, default=5_000_000,
                    help='size of the extra uncompressed bag measured for peak memory only '
                         '(default 5e6; 0 = skip)')
    ap.add_argument('--no-recover', action='store_true',
                    help='do not measure recover_bag beside analyze')
    args = ap.parse_args(argv)
    whats = ('analyze',) if args.no_recover else ('analyze', 'recover')
    tmp = Path(tempfile.mkdtemp(prefix='bench_bag-'))
    rows = []
    mem_rows = []
    try:
        for compression in ('none', 'zstd'):
            path = tmp / f'bag_{compression}'
            wt = make_bag(path, args.messages, compression)
            size = bag_bytes(path)
            print(f'[bench] wrote {args.messages} messages ({compression}, {size / 1e6:.0f} '
                  f'MB) in {wt:.1f} s', file=sys.stderr)
            best = min(time_ours(path)[0] for _ in range(args.repeats))
            ours = args.messages / best
            rb = time_rosbags(path, args.compare)
            mr = time_mcap_ros2(path, args.compare)
            rows.append((compression, size / 1e6, best, ours, rb, mr))
            for what in whats:
                mem_rows.append((what, compression, args.messages, size,
                                 *peak_rss(path, what)))
        if args.memory_messages:
            path = tmp / 'bag_memory'
            shutil.rmtree(tmp / 'bag_none', ignore_errors=True)
            shutil.rmtree(tmp / 'bag_zstd', ignore_errors=True)
            wt = make_bag(path, args.memory_messages, 'none')
            size = bag_bytes(path)
            print(f'[bench] wrote {args.memory_messages} messages (none, {size / 1e6:.0f} MB) '
                  f'in {wt:.1f} s', file=sys.stderr)
            for what in whats:
                mem_rows.append((what, 'none', args.memory_messages, size,
                                 *peak_rss(path, what)))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f'{"chunks":<7} {"MB":>5} {"ours s":>7} {"ours JS/s":>11} {"rosbags JS/s":>14} '
          f'{"x":>6} {"mcap-ros2 JS/s":>16} {"x":>6}')
    for comp, size_mb, best, ours, rb, mr in rows:
        print(f'{comp:<7} {size_mb:5.0f} {best:7.2f} {ours:11,.0f} {rb:14,.0f} '
              f'{ours / rb:6.1f} {mr:16,.0f} {ours / mr:6.1f}')
    print('ours = arm_bag.analysis.analyze end to end (open, read, decode, metrics) on all '
          f'{args.messages} JointState messages (JS); others read+deserialise the first '
          f'{args.compare}. Target: ours >= 2 M JS/s.')
    print()
    print(f'{"run":<8} {"chunks":<7} {"messages":>9} {"bag MB":>7} {"s":>6} {"peak MB":>8} '
          f'{"x bag":>6} {"imports MB":>11} {"peak-imports MB":>16} {"x bag":>6}')
    for what, comp, n, size, peak, base, seconds in mem_rows:
        print(f'{what:<8} {comp:<7} {n:9d} {size / 1e6:7.0f} {seconds:6.1f} {peak / 1e6:8.0f} '
              f'{peak / size:6.2f} {base / 1e6:11.0f} {(peak - base) / 1e6:16.0f} '
              f'{(peak - base) / size:6.2f}')
    print('peak = VmHWM of a fresh process running analyze, or recover_bag into a new '
          'directory (imports included); imports = the same process doing neither. '
          'Target: peak <= 0.5 x bag (5 M, none), for both.')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
