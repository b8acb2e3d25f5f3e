"""What the live view's front (:mod:`arm_sim.live_front`) costs: a peer run of the same
client against the SDK's server directly and through the front, alternating.

    python bench/bench_live.py [--rounds 3] [--bursts 10] [--burst 1000] [--sizes 150,65536]

The server (a :class:`arm_sim.live.Bridge` with one channel) runs in this process, the
client (``websockets``, the ``test`` extra) in another, as Foxglove would. Per round and
path it measures

* latency: 2000 messages at 1 kHz, each carrying ``time.monotonic_ns()`` at ``log()``; the
  client takes its own monotonic clock (the same clock: one machine) on receipt: median,
  p99 [us];
* throughput: bursts of ``--burst`` messages of each size (below the SDK's per-client
  backlog of 1024, beyond which it drops the oldest), logged as fast as the server can,
  0.3 s apart; the client times each burst from its first message to its last [msg/s,
  MB/s, median over bursts] and counts what arrived.

Prints one line per measurement and the medians over rounds.
"""

from __future__ import annotations

import argparse
import json
import statistics
import struct
import subprocess
import sys
import time

LATENCY_COUNT = 2000


# ---------------------------------------------------------------------- client process
def client(url: str, subprotocol: str) -> None:
    from websockets.sync.client import connect
    from websockets.typing import Subprotocol

    with connect(url, subprotocols=[Subprotocol(subprotocol)], max_size=None) as ws:
        channel = None
        while channel is None:
            m = ws.recv()
            if isinstance(m, str) and json.loads(m)['op'] == 'advertise':
                channel = next(c['id'] for c in json.loads(m)['channels']
                               if c['topic'] == '/bench')
        ws.send(json.dumps({'op': 'subscribe',
                            'subscriptions': [{'id': 1, 'channelId': channel}]}))
        print('ready', flush=True)
        warm = False
        latency: list[int] = []
        counts: dict[str, list[int]] = {}  # 'size/burst' -> [count, first ns, last ns]
        while True:
            m = ws.recv()
            now = time.monotonic_ns()
            if isinstance(m, str):
                continue
            kind = m[13:14]
            if kind == b'W' and not warm:
                warm = True
                print('warm', flush=True)
            elif kind == b'L':
                latency.append(now - struct.unpack_from('<q', m, 14)[0])
            elif kind == b'T':
                key = f'{len(m) - 13}/{struct.unpack_from("<I", m, 14)[0]}'
                c = counts.setdefault(key, [0, now, now])
                c[0] += 1
                c[2] = now
            elif kind == b'E':
                print(json.dumps({'latency_ns': latency, 'throughput': counts}), flush=True)
                return


# ---------------------------------------------------------------------- server side
def _run(bridge, relay: bool, bursts: int, burst: int, sizes: list[int]) -> dict:
    url = bridge.url if relay else f'ws://127.0.0.1:{bridge.sdk_port}'
    proto = 'foxglove.websocket.v1' if relay else 'foxglove.sdk.v1'
    proc = subprocess.Popen([sys.executable, __file__, '--client', url,
                             '--subprotocol', proto], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    try:
        assert proc.stdout.readline().strip() == 'ready'
        channel = bridge.channels['/bench']
        import select

        while not select.select([proc.stdout], [], [], 0.01)[0]:  # until the first arrives
            channel.log(b'W', log_time=0)
        assert proc.stdout.readline().strip() == 'warm'
        for _ in range(LATENCY_COUNT):
            channel.log(b'L' + struct.pack('<q', time.monotonic_ns()), log_time=0)
            time.sleep(0.001)
        for size in sizes:
            for b in range(bursts):
                body = b'T' + struct.pack('<I', b) + bytes(size - 5)
                for _ in range(burst):
                    channel.log(body, log_time=0)
                time.sleep(0.3)  # the client drains its backlog
        while not select.select([proc.stdout], [], [], 0.05)[0]:
            channel.log(b'E', log_time=0)
        result = json.loads(proc.stdout.readline())
    finally:
        proc.wait(10)
    lat = sorted(result['latency_ns'])
    out: dict = {'path': 'front' if relay else 'direct', 'received_latency': len(lat),
                 'latency_median_us': lat[len(lat) // 2] / 1e3,
                 'latency_p90_us': lat[int(len(lat) * 0.9)] / 1e3,
                 'latency_p99_us': lat[int(len(lat) * 0.99)] / 1e3}
    for size in sizes:
        rates = []
        received = 0
        for b in range(bursts):
            n, first, last = result['throughput'].get(f'{size}/{b}', [0, 0, 0])
            received += n
            if n > 1:
                rates.append((n - 1) / ((last - first) / 1e9))
        rate = statistics.median(rates) if rates else 0.0
        out[f'{size}B'] = {'received': received, 'of': bursts * burst, 'msg_per_s': rate,
                           'MB_per_s': rate * size / 1e6}
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog='python bench/bench_live.py', description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--rounds', type=int, default=3)
    p.add_argument('--bursts', type=int, default=10)
    p.add_argument('--burst', type=int, default=1000)
    p.add_argument('--sizes', default='150,65536')
    p.add_argument('--client', help=argparse.SUPPRESS)
    p.add_argument('--subprotocol', help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.client:
        client(args.client, args.subprotocol)
        return 0
    from arm_sim.live import Bridge

    sizes = [int(s) for s in args.sizes.split(',')]
    bridge = Bridge(port=0)
    bridge.add_ros_channel('/bench', 'std_msgs/msg/String')
    runs: dict[str, list[dict]] = {'direct': [], 'front': []}
    try:
        for _ in range(args.rounds):
            for relay in (False, True):
                r = _run(bridge, relay, args.bursts, args.burst, sizes)
                print(json.dumps(r), flush=True)
                runs[r['path']].append(r)
    finally:
        bridge.stop()
    print('medians over rounds:')
    for path, rs in runs.items():
        med = {k: statistics.median(r[k] for r in rs)
               for k in ('latency_median_us', 'latency_p90_us', 'latency_p99_us')}
        line = (f'  {path:6s} latency median {med["latency_median_us"]:6.1f} us, p90 '
                f'{med["latency_p90_us"]:6.1f} us, p99 {med["latency_p99_us"]:7.1f} us')
        for size in sizes:
            key = f'{size}B'
            line += (f'; {size} B: {statistics.median(r[key]["msg_per_s"] for r in rs):8.0f} '
                     f'msg/s {statistics.median(r[key]["MB_per_s"] for r in rs):7.1f} MB/s '
                     f'({sum(r[key]["received"] for r in rs)}/'
                     f'{sum(r[key]["of"] for r in rs)} received)')
        print(line)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
