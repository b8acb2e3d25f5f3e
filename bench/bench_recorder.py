"""Benchmark: the recorder's highest zero-loss rate, beside a plain rclpy subscriber.

A publisher process sends the suite's message mix (per tick: ``joint_states`` and
``arm_controller/reference`` JointState, ``effort_controller/commands``
Float64MultiArray, ``clock``) with the suite's QoS (reliable, depth 10) at a given total
rate for ``--seconds``. At each rate two subscribers take it in turn, in the same run:

* the ``recorder`` node (a real process, as ``ros2 run arm_sim recorder`` starts it),
  counted from its bag and its own loss count;
* a plain rclpy subscriber process: one deserialising ``create_subscription`` per topic
  (depth 1000) spun by SingleThreadedExecutor, counting messages.

Printed per rate: messages sent, kept, lost, for each. The highest rate with zero loss is
the figure docs/benchmarks.md (Recorder) quotes. Each trial uses its own private ROS
domain, localhost only.
Run: ``python bench/bench_recorder.py [--rates 5000,10000,20000,30000] [--seconds 3]``.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

TOPICS = ('joint_states', 'arm_controller/reference', 'effort_controller/commands',
          'clock')


def publisher(rate: float, seconds: float) -> int:
    """Publish the mix at ``rate`` messages/s once every topic has a subscriber."""
    import rclpy
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    rclpy.init()
    node = rclpy.create_node('bench_publisher')
    kinds = (JointState, JointState, Float64MultiArray, Clock)
    pubs = [node.create_publisher(k, t, 10) for k, t in zip(kinds, TOPICS)]
    ticks = int(rate * seconds / len(TOPICS))
    end = time.monotonic() + 60
    while any(p.get_subscription_count() < 1 for p in pubs):
        if time.monotonic() > end:
            return 1
        time.sleep(0.05)
    time.sleep(0.5)  # the subscriber matched every publisher: let discovery settle

    def messages(i: int) -> list[bytes]:
        js = JointState(name=['joint1', 'joint2'], position=[0.001 * i, 0.5],
                        velocity=[0.1, 0.2], effort=[1.0, 2.0])
        js.header.stamp.sec, js.header.stamp.nanosec = divmod(i * 1_000_000, 1_000_000_000)
        clock = Clock()
        clock.clock = js.header.stamp
        return [serialize_message(js), serialize_message(js),
                serialize_message(Float64MultiArray(data=[1.0, 2.0])),
                serialize_message(clock)]

    data = [messages(i) for i in range(ticks)]
    batch = max(1, int(rate / len(TOPICS) / 1000))  # ticks per ms
    start = time.perf_counter()
    for k in range(0, ticks, batch):
        for tick in data[k:k + batch]:
            for pub, raw in zip(pubs, tick):
                pub.publish(raw)
        ahead = start + (k + batch) * len(TOPICS) / rate - time.perf_counter()
        if ahead > 0:
            time.sleep(ahead)
    took = time.perf_counter() - start
    print(f'sent {ticks * len(TOPICS)} {took:.3f}', flush=True)
    time.sleep(1.0)  # reliable: stay to answer the subscribers' acknowledgements
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def baseline() -> int:
    """Count messages per topic with plain deserialising subscriptions until SIGINT."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    stop = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node('bench_baseline')
    counts = dict.fromkeys(TOPICS, 0)
    kinds = (JointState, JointState, Float64MultiArray, Clock)
    for kind, topic in zip(kinds, TOPICS):
        def count(_msg, t=topic):
            counts[t] += 1
        node.create_subscription(kind, topic, count, 1000)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    while not stop:
        ex.spin_once(timeout_sec=0.05)
    while True:  # take what is still queued: until 0.2 s pass with nothing
        before = sum(counts.values())
        ex.spin_once(timeout_sec=0.2)
        if sum(counts.values()) == before:
            break
    print('received', sum(counts.values()), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def env_for(domain: int) -> dict[str, str]:
    from arm_sim.launcher import node_env

    return node_env(domain)


def trial(kind: str, rate: float, seconds: float, domain: int, work: Path) -> dict:
    """One subscriber (``recorder`` or ``baseline``) against the publisher at ``rate``."""
    from arm_bag.reader import read_bag
    from arm_sim.launcher import NodeProcess

    env = env_for(domain)
    if kind == 'recorder':
        bag = work / f'bag-{int(rate)}'
        sub = NodeProcess('recorder', params={'output': str(bag), 'topics': list(TOPICS)},
                          domain_id=domain, log_path=work / f'recorder-{int(rate)}.log')
        popen = sub.proc
    else:
        popen = subprocess.Popen([sys.executable, __file__, '--role', 'baseline'], env=env,
                                 stdout=subprocess.PIPE, text=True)
    pub = subprocess.Popen([sys.executable, __file__, '--role', 'publisher', '--rate',
                            str(rate), '--seconds', str(seconds)], env=env,
                           stdout=subprocess.PIPE, text=True)
    out, _ = pub.communicate(timeout=seconds * 10 + 120)
    sent_line = [x for x in out.splitlines() if x.startswith('sent')]
    if not sent_line:
        popen.send_signal(signal.SIGINT)
        popen.wait(30)
        raise SystemExit(f'publisher failed at {rate:g} msg/s: {out.strip()}')
    sent, took = int(sent_line[0].split()[1]), float(sent_line[0].split()[2])
    popen.send_signal(signal.SIGINT)
    if kind == 'recorder':
        popen.wait(60)
        data = read_bag(bag)
        kept = sum(n for t, (_, n) in data.topics.items() if t.lstrip('/') in TOPICS)
        meta = yaml.safe_load((bag / 'metadata.yaml').read_text())
        lost_counted = sum(json.loads((meta['rosbag2_bagfile_information']['custom_data']
                                       or {}).get('arm_sim.lost', '{}')).values())
    else:
        text, _ = popen.communicate(timeout=60)
        kept = int(text.split('received')[-1].split()[0])
        lost_counted = None
    return {'sent': sent, 'kept': kept, 'lost': sent - kept, 'counted': lost_counted,
            'achieved': sent / took}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--role', choices=('bench', 'publisher', 'baseline'), default='bench',
                    help=argparse.SUPPRESS)
    ap.add_argument('--rate', type=float, default=10000.0, help=argparse.SUPPRESS)
    ap.add_argument('--rates', default='5000,10000,20000,30000',
                    help='total message rates to try [msg/s], comma-separated')
    ap.add_argument('--seconds', type=float, default=3.0,
                    help='publishing time per trial [s] (default 3)')
    args = ap.parse_args()
    if args.role == 'publisher':
        return publisher(args.rate, args.seconds)
    if args.role == 'baseline':
        return baseline()
    rates = [float(r) for r in args.rates.split(',')]
    from arm_common.process import claim_domain

    domain = claim_domain(150 + os.getpid() % 50)  # no other arm_sim process uses it
    best = {'recorder': 0.0, 'baseline': 0.0}
    print(f'{"rate msg/s":>10} {"achieved":>9}  {"recorder kept/sent (lost, counted)":>36}  '
          f'{"plain rclpy kept/sent (lost)":>30}')
    with tempfile.TemporaryDirectory(prefix='bench_recorder_') as tmp:
        for rate in rates:
            row = {}
            for kind in ('recorder', 'baseline'):
                print(f'[bench] {kind} at {rate:g} msg/s ...', file=sys.stderr, flush=True)
                row[kind] = trial(kind, rate, args.seconds, domain, Path(tmp))
                if row[kind]['lost'] == 0:
                    best[kind] = max(best[kind], rate)
            r, b = row['recorder'], row['baseline']
            print(f'{rate:>10.0f} {r["achieved"]:>9.0f}  '
                  f'{r["kept"]:>12}/{r["sent"]:<8} ({r["lost"]}, {r["counted"]}){"":>6}  '
                  f'{b["kept"]:>12}/{b["sent"]:<8} ({b["lost"]})', flush=True)
    print(f'highest zero-loss rate tried: recorder {best["recorder"]:.0f} msg/s, plain rclpy '
          f'subscriber {best["baseline"]:.0f} msg/s')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
