"""``recorder`` node: records topics as serialized messages into a rosbag2 bag (MCAP).

Thin ROS shell around :class:`arm_bag.writer.BagWriter`: raw (undeserialised) subscriptions,
log time = the recorder's clock at receive (wall-clock system time by default; simulated
time, the latest ``clock`` received, with ``use_sim_time: true``, as ``ros2 bag record
--use-sim-time`` does), the graph polled every 0.5 s (wall) for topics that appear later,
the robot parameters stored as the MCAP metadata record ``arm_sim_robot`` (JSON values).

Durability: the open chunk is written and ``metadata.yaml`` rewritten every
``flush_period`` (wall clock) and whenever the chunk reaches ``chunk_size`` bytes, so a
SIGKILL loses at most the messages received in the last ``flush_period`` seconds (and at
most ``chunk_size`` bytes of them). SIGINT/SIGTERM close the bag (exit 0). A write error
(e.g. disk full) stops recording with one error line, reports it on /diagnostics, leaves a
readable bag and exits 1. An existing ``output`` directory is refused (exit 2).
"""

from __future__ import annotations

import functools
import importlib
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.subscription import Subscription

from arm_bag.msgdefs import MessageDefinitionError, QosProfile, qos_yaml, schema_text, type_hash
from arm_bag.writer import BagWriteError, BagWriter
from arm_common.node import (
    ConfigError,
    Diagnostics,
    clock_in_namespace,
    declare_parameters,
    run_node,
    steady_clock,
)
from arm_common.params import ParamSpec
from arm_dynamics.robot import ROBOT_PARAMS

SUMMARY = '''
Records topics into a rosbag2 bag directory (metadata.yaml + <name>_0.mcap, MCAP profile
ros2, CDR messages, ros2msg schemas) without deserialising them; log time = receive time on
the recorder's clock: wall-clock system time, or simulated time (the latest clock message)
with use_sim_time:=true. Analysis uses the messages' header stamps, never the log time.
Topics that appear later are picked up (graph polled every 0.5 s). SIGINT/SIGTERM close the
bag (exit 0); a SIGKILL loses at most the last flush_period of messages. The robot
parameters are stored in the MCAP metadata record arm_sim_robot. Reports received,
written and dropped message counts on /diagnostics (status "recorder: summary"; lost
messages and skipped topics as "recorder: dropped" and "recorder: skipped_topic").
'''
DEFAULT_TOPICS = ['joint_states', 'effort_controller/commands', 'arm_controller/reference',
                  'arm_controller/joint_trajectory', 'goal_pose', 'planner/path',
                  '/diagnostics']
DISCOVERY_PERIOD = 0.5  # s, wall clock
QUEUE_DEPTH = 1000
LINGER = 1.0  # s (wall) the node stays up after a write failure, to report it

RECORDER_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec('output', 'string', '', 'Bag directory to create (required; must not exist)',
              read_only=True),
    ParamSpec('topics', 'strings', DEFAULT_TOPICS,
              "Topics to record, relative to the node's namespace; ['*'] = every topic "
              'found', read_only=True),
    ParamSpec('chunk_size', 'int', 65536, 'MCAP chunk size: a chunk is written when it '
              'reaches this', 'bytes', minimum=64, maximum=64 * 1024 * 1024, read_only=True),
    ParamSpec('flush_period', 'double', 0.5, 'Wall-clock period of writing the open chunk and '
              'metadata.yaml (bounds the loss on SIGKILL)', 's', minimum=0.01, maximum=60.0,
              read_only=True),
)

_HISTORY = {HistoryPolicy.KEEP_LAST: 'keep_last', HistoryPolicy.KEEP_ALL: 'keep_all'}
_RELIABILITY = {ReliabilityPolicy.RELIABLE: 'reliable',
                ReliabilityPolicy.BEST_EFFORT: 'best_effort'}
_DURABILITY = {DurabilityPolicy.VOLATILE: 'volatile',
               DurabilityPolicy.TRANSIENT_LOCAL: 'transient_local'}


def _duration(d) -> tuple[int, int] | None:
    ns = d.nanoseconds
    return None if ns <= 0 or ns >= 9223372036854775807 else divmod(ns, 1_000_000_000)


def offered_qos(profiles: list) -> list[QosProfile]:
    """rclpy QoS profiles of the publishers -> the records rosbag2 stores."""
    out = []
    for q in profiles:
        out.append(QosProfile(
            history=_HISTORY.get(q.history, 'unknown'), depth=int(q.depth),
            reliability=_RELIABILITY.get(q.reliability, 'unknown'),
            durability=_DURABILITY.get(q.durability, 'unknown'),
            liveliness=str(q.liveliness.name).lower(),
            deadline=_duration(q.deadline), lifespan=_duration(q.lifespan),
            liveliness_lease_duration=_duration(q.liveliness_lease_duration),
            avoid_ros_namespace_conventions=bool(q.avoid_ros_namespace_conventions)))
    return out


def message_class(type_name: str):
    pkg, kind, name = type_name.split('/')
    return getattr(importlib.import_module(f'{pkg}.{kind}'), name)


class RecorderNode(Node):
    """See the module docstring."""

    def __init__(self) -> None:
        super().__init__('recorder', cli_args=clock_in_namespace())
        p = declare_parameters(self, ROBOT_PARAMS + RECORDER_PARAMS)
        out = Path(p['output']).expanduser()
        if out.exists():
            raise ConfigError(f'output {str(out)!r} already exists; refusing to overwrite it')
        try:
            self.writer = BagWriter(out, chunk_size=p['chunk_size'])
            self.writer.add_metadata('arm_sim_robot', {s.name: json.dumps(list(p[s.name])
                                     if isinstance(p[s.name], (list, tuple)) else p[s.name])
                                     for s in ROBOT_PARAMS})
            self.writer.write_metadata_yaml()
        except (OSError, ValueError) as exc:
            raise ConfigError(f'output {str(out)!r}: {exc}') from None
        self.sim_clock = bool(self.get_parameter('use_sim_time').value)
        self.wanted = list(p['topics'])
        self.all_topics = '*' in self.wanted
        self.resolved = {self.resolve_topic_name(t) for t in self.wanted if t != '*'}
        self.subs: dict[str, Subscription] = {}
        self.channels: dict[str, int] = {}
        self.skipped: set[str] = set()
        self.received = 0
        self.per_topic: dict[str, int] = {}  # messages received per topic
        self.dropped = 0
        self.failed: str | None = None
        self.stopped = False
        self.diag = Diagnostics(self)
        self.create_timer(DISCOVERY_PERIOD, self.discover, clock=steady_clock())
        self.create_timer(p['flush_period'], self.flush, clock=steady_clock())
        self.discover()
        self.get_logger().info(
            f"recording to {out} (flush every {p['flush_period']:g} s, chunk "
            f"{p['chunk_size']} bytes): {'every topic' if self.all_topics else self.wanted}")

    # ------------------------------------------------------------------ topics
    def discover(self) -> None:
        if self.stopped:
            return
        for name, types in self.get_topic_names_and_types():
            if name in self.subs or name in self.skipped:
                continue
            if not self.all_topics and name not in self.resolved:
                continue
            if len(types) != 1:
                self._skip(name, f'{len(types)} types advertised ({types})')
                continue
            self._subscribe(name, types[0])

    def _skip(self, name: str, reason: str) -> None:
        self.skipped.add(name)
        self.diag.problem('skipped_topic', f'not recording {name}: {reason}')

    def _subscribe(self, name: str, type_name: str) -> None:
        try:
            cls = message_class(type_name)
            schema = schema_text(type_name)
        except (ImportError, AttributeError, ValueError, MessageDefinitionError) as exc:
            self._skip(name, f'type {type_name} unavailable: {exc}')
            return
        infos = self.get_publishers_info_by_topic(name)
        profiles = [i.qos_profile for i in infos]
        reliable = bool(profiles) and all(
            q.reliability == ReliabilityPolicy.RELIABLE for q in profiles)
        latched = bool(profiles) and all(
            q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in profiles)
        qos = QoSProfile(depth=QUEUE_DEPTH,
                         reliability=(ReliabilityPolicy.RELIABLE if reliable
                                      else ReliabilityPolicy.BEST_EFFORT),
                         durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched
                                     else DurabilityPolicy.VOLATILE))
        thash = type_hash(type_name)
        if not thash and infos:
            thash = str(getattr(infos[0], 'topic_type_hash', '') or '')
        try:
            ch = self.writer.add_topic(name, type_name, schema, qos_yaml(offered_qos(profiles)),
                                       thash)
        except BagWriteError as exc:
            self._fail(exc)
            return
        self.channels[name] = ch
        kwargs: dict[str, Any] = {}
        try:
            from rclpy.event_handler import SubscriptionEventCallbacks

            kwargs['event_callbacks'] = SubscriptionEventCallbacks(message_lost=self._lost)
        except ImportError:
            pass
        self.per_topic[name] = 0
        self.subs[name] = self.create_subscription(
            cls, name, functools.partial(self._on_message, ch, topic=name), qos,
            raw=True, **kwargs)
        self.get_logger().info(f'recording {name} [{type_name}]')

    # ------------------------------------------------------------------ data
    def _on_message(self, channel: int, data: bytes, *, topic: str) -> None:
        now = self.get_clock().now().nanoseconds if self.sim_clock else time.time_ns()
        self.received += 1
        self.per_topic[topic] += 1
        if self.stopped:
            self.dropped += 1
            return
        try:
            self.writer.write(channel, data, now)
        except BagWriteError as exc:
            self.dropped += 1
            self._fail(exc)

    def _lost(self, info) -> None:
        n = int(getattr(info, 'total_count_change', 1))
        self.dropped += n
        self.diag.problem('dropped', f'{n} messages lost before reaching the recorder',
                          lost=n, dropped=self.dropped)

    def flush(self) -> None:
        if self.stopped:
            return
        try:
            self.writer.flush()
        except BagWriteError as exc:
            self._fail(exc)
            return
        written = self.writer.message_count
        self.diag.set('OK' if not self.dropped else 'WARN',
                      f'recording {len(self.subs)} topics', received=self.received,
                      written=written, buffered=self.writer.pending, dropped=self.dropped,
                      topics=sorted(self.subs),
                      **{f'received {t}': n for t, n in self.per_topic.items()})

    def _fail(self, exc: Exception) -> None:
        if self.stopped:
            return
        self.stopped = True
        self.failed = str(exc)
        self.failed_at = time.monotonic()
        for sub in self.subs.values():
            self.destroy_subscription(sub)
        self.subs.clear()
        try:
            self.writer.close()
        except BagWriteError:
            pass
        self.diag.set('ERROR', self.failed, received=self.received,
                      written=self.writer.message_count, dropped=self.dropped)
        # Not diag.problem(): rclpy refuses one logging call site used with two severities
        # (problem() logs both warnings and errors from the same line).
        self.get_logger().error(self.failed)
        self.diag.publish()

    def close(self) -> None:
        """Write everything received and close the bag (idempotent)."""
        if self.stopped:
            return
        self.stopped = True
        try:
            self.writer.close()
        except BagWriteError as exc:
            self.failed = str(exc)
            self.get_logger().error(self.failed)
            return
        self.get_logger().info(
            f'bag closed: {self.writer.message_count} messages written of '
            f'{self.received} received ({self.dropped} dropped) in {self.writer.directory}')

    def destroy_node(self) -> None:
        self.close()
        super().destroy_node()


def _spin(executor: Executor, node: Node, running: Callable[[], bool]) -> None:
    # After a write failure, linger LINGER s so /diagnostics subscribers get the report.
    assert isinstance(node, RecorderNode)
    while running() and (node.failed is None or time.monotonic() < node.failed_at + LINGER):
        executor.spin_once(timeout_sec=0.1)


def main(args: list[str] | None = None) -> int:
    nodes: list[RecorderNode] = []

    def factory() -> RecorderNode:
        nodes.append(RecorderNode())
        return nodes[-1]

    code = run_node(factory, prog='recorder', summary=SUMMARY,
                    specs=ROBOT_PARAMS + RECORDER_PARAMS, args=args, spin=_spin,
                    executor_type=SingleThreadedExecutor)
    if nodes and nodes[0].failed:
        return 1
    return code


if __name__ == '__main__':
    raise SystemExit(main())
