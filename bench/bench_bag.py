"""Benchmark: reading a 1 M-message arm_sim bag with arm_bag vs rosbags vs mcap-ros2-support.

Writes a synthetic bag with arm_bag's own writer (no ROS): N/2 joint_states and N/2
arm_controller/reference JointState messages at 100 Hz plus one trajectory and path per 10 s,
then times ``arm_bag.analysis.analyze`` end to end (open, read, decode, all metrics) on the
whole bag, and the two libraries reading + deserialising the first ``--compare`` messages
(extrapolated as a rate: they are 10-50x slower). Run: ``python bench/bench_bag.py``.
"""

from __future__ import annotations

import argparse
import shutil
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
    args = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix='bench_bag-'))
    rows = []
    try:
        for compression in ('none', 'zstd'):
            path = tmp / f'bag_{compression}'
            wt = make_bag(path, args.messages, compression)
            size = sum(f.stat().st_size for f in path.iterdir()) / 1e6
            print(f'[bench] wrote {args.messages} messages ({compression}, {size:.0f} MB) in '
                  f'{wt:.1f} s', file=sys.stderr)
            best = min(time_ours(path)[0] for _ in range(args.repeats))
            ours = args.messages / best
            rb = time_rosbags(path, args.compare)
            mr = time_mcap_ros2(path, args.compare)
            rows.append((compression, size, best, ours, rb, mr))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f'{"chunks":<7} {"MB":>5} {"ours s":>7} {"ours msg/s":>11} {"rosbags msg/s":>14} '
          f'{"x":>6} {"mcap-ros2 msg/s":>16} {"x":>6}')
    for comp, size, best, ours, rb, mr in rows:
        print(f'{comp:<7} {size:5.0f} {best:7.2f} {ours:11,.0f} {rb:14,.0f} {ours / rb:6.1f} '
              f'{mr:16,.0f} {ours / mr:6.1f}')
    print('ours = arm_bag.analysis.analyze end to end (open, read, decode, metrics) on all '
          f'{args.messages} JointState messages; others read+deserialise the first '
          f'{args.compare}.')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
