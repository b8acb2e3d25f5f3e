"""The middleware floor: two processes bouncing one small message back and forth.

``bench/bench_loop.py`` (``ping_pong_floor()``, after the loop runs) starts two of these
on the bench's ROS domain::

    python bench/loop_programs/ping_pong.py echo   SECONDS+5
    python bench/loop_programs/ping_pong.py pinger SECONDS

with the nodes' executor (rclpy.experimental.EventsExecutor in ``spin_once`` loops) and
QoS (depth 10), the callbacks doing nothing but publish the answer: the ``pinger``
publishes a 2-double ``Float64MultiArray`` on ``ping``, the ``echo`` sends it back on
``pong``. Once both sides are matched and 200 round trips have warmed it up, the pinger
counts round trips over ``SECONDS / 2`` and prints round trips per wall second (one
number) on stdout; the echo prints nothing and runs until ``SECONDS`` (the bench stops it
earlier). No lockstep loop over ROS on the machine can beat that rate.
"""

import argparse
import time

import rclpy
from rclpy.experimental import EventsExecutor
from std_msgs.msg import Float64MultiArray


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('role', choices=('pinger', 'echo'))
    ap.add_argument('seconds', type=float, help='wall seconds to run')
    args = ap.parse_args()
    role, seconds = args.role, args.seconds
    rclpy.init()
    node = rclpy.create_node('bench_loop_' + role)
    out, into = ('ping', 'pong') if role == 'pinger' else ('pong', 'ping')
    pub = node.create_publisher(Float64MultiArray, out, 10)
    msg = Float64MultiArray(data=[0.0, 0.0])
    count = [0]

    def answer(m):
        count[0] += 1
        pub.publish(msg if role == 'pinger' else m)

    node.create_subscription(Float64MultiArray, into, answer, 10)
    executor = EventsExecutor()
    executor.add_node(node)
    end = time.monotonic() + seconds
    if role == 'pinger':
        while time.monotonic() < end and count[0] == 0:
            if pub.get_subscription_count() and node.count_publishers(into):
                pub.publish(msg)
            executor.spin_once(timeout_sec=0.2)
        while time.monotonic() < end and count[0] < 200:
            executor.spin_once(timeout_sec=0.2)
        n0, t0 = count[0], time.perf_counter()
        end = time.monotonic() + seconds / 2
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.1)
    if role == 'pinger':
        print((count[0] - n0) / (time.perf_counter() - t0), flush=True)


if __name__ == '__main__':
    main()
