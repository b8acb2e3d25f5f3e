"""``recorder`` node: records topics as serialized messages into a rosbag2 bag (MCAP).

Thin ROS shell around :class:`arm_bag.writer.BagWriter` (the ``mcap`` library's Writer,
chunk and data CRCs on). What it does about loss, in the order a message meets it:

* **Subscribed before the publishers exist.** The suite's topics have known types, so they
  are subscribed when the recorder starts, with the QoS their publishers offer (reliable;
  ``planner/path`` and ``arm_controller/trajectory_status`` transient local). A publisher
  appearing later is seen at once: each subscription's "matched" event makes the recorder
  look at the graph then, besides a 0.1 s poll as rosbag2 has. Topics of unknown type
  (``topics: ['*']`` or your own) are subscribed when their first publisher appears, with
  its type and QoS; a subscription whose QoS no longer matches every publisher (a
  best-effort or volatile publisher joined) is made again with the QoS they all offer, as
  ``ros2 bag record`` does.
* **Wrong type.** A publisher of another type on a recorded topic is reported
  (``recorder: wrong_type`` on /diagnostics) and the topic goes on being recorded from
  the publishers of its type.
* **Deep queue, drained in a tight loop.** Each subscription keeps the last
  ``queue_depth`` messages; its callback takes every message waiting (raw bytes, with the
  message info) in one loop instead of one executor round per message.
* **Counted loss.** Each message carries its publisher's sequence number; on a topic with
  one publisher a gap is an exact count of messages that never reached the recorder (a
  restarted publisher starts again at 1 and is not a loss). DDS "message lost" events
  count the rest. Losses are reported per topic on /diagnostics (``recorder: lost``), in
  ``metadata.yaml`` (``custom_data: arm_sim.lost``) and by ``arm-sim analyze``.
* **A publisher that appears while recording** (a late topic, or a node started later)
  can have its first messages miss the bag even when it waits for the match: its side of
  DDS matches the recorder's subscription (so it sends) before the recorder's side has
  matched it, which drops what comes from a writer it does not know; the reliable protocol
  then sends again only what the publisher still keeps (its history depth). No subscription
  is made fast enough to prevent it. The number of the first message received says how
  many were sent before it (:func:`arm_bag.loss.before_first`, while the publisher is its
  topic's only one): counted lost for a publisher first seen :data:`DISCOVERY_SETTLE` s
  after the recorder started (it cannot have been there before the recording), else
  counted apart as an *unrecorded start* (``custom_data: arm_sim.unrecorded_start``,
  ``unrecorded_start <topic>`` on /diagnostics): it may have sent them before the
  recording. So recorded + lost + unrecorded start = published.

Log time = the recorder's clock at receive (wall-clock system time by default; simulated
time, the latest ``clock`` received, with ``use_sim_time: true``, as ``ros2 bag record
--use-sim-time`` does); publish time = the publisher's source timestamp; the MCAP sequence
= the publication sequence number. The robot parameters are stored as the MCAP metadata
record ``arm_sim_robot`` (JSON values).

Durability: the open chunk is written and ``metadata.yaml`` rewritten every
``flush_period`` (wall clock) and whenever the chunk reaches ``chunk_size`` bytes, so a
SIGKILL loses at most the messages received in the last ``flush_period`` seconds; the bag
is marked open and locked while recording, so arm_sim completes it the next time it opens
it (or ``arm-sim bag recover DIR``). SIGINT/SIGTERM take what is still queued and close
the bag (exit 0). A full disk spends the bag's reserve on a complete bag, stops recording
with one error line, reports it on /diagnostics and exits 1. An existing ``output``
directory is refused (exit 2), and so is a start without ``output`` (it is required).
"""

from __future__ import annotations

import functools
import importlib
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.subscription import Subscription

from arm_bag.loss import GapCounter, before_first
from arm_bag.msgdefs import MessageDefinitionError, QosProfile, qos_yaml, schema_text, type_hash
from arm_bag.topics import DEFAULT_TOPICS, KNOWN_TOPICS, LATCHED
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
from arm_dynamics.models import joint_count
from arm_dynamics.robot import ROBOT_PARAMS

InvalidHandle = _rclpy.InvalidHandle

SUMMARY = '''
Records topics into a rosbag2 bag directory (metadata.yaml + <name>_0.mcap, MCAP profile
ros2, CDR messages, ros2msg schemas, chunk CRCs) without deserialising them; output is
required. The suite's topics are subscribed at start with their publishers' QoS; others
when a publisher appears (graph events); what a publisher sent before the first message
received from it is counted: lost if it appeared after the first 5 s, else as an
unrecorded start (metadata.yaml custom_data arm_sim.unrecorded_start). Log time = receive time
on the recorder's clock: wall-clock system time, or simulated time (the latest clock
message) with use_sim_time:=true. Messages lost before
the recorder (publisher sequence gaps, DDS loss events) are counted per topic on
/diagnostics ("recorder: lost"), in metadata.yaml (custom_data arm_sim.lost) and by
arm-sim analyze. SIGINT/SIGTERM close the bag (exit 0); a SIGKILL loses at most the last
flush_period of messages and the bag is completed the next time arm_sim opens it. The robot
parameters are stored in the MCAP metadata record arm_sim_robot.
'''
DISCOVERY_PERIOD = 0.1  # s, wall clock: the fallback poll (rosbag2's default)
#: s, wall clock from the recorder's start: by then it has seen every publisher that
#: existed when it started, so one it first sees later appeared while it recorded and its
#: messages before the first one received are counted lost (:func:`arm_bag.loss.
#: missed_before_first`). A participant that was there before the recorder is seen when
#: it next announces itself, which Fast DDS does every 3 s (its default announcement
#: period; measured here: up to 3.1 s), while a new one announces itself at once.
DISCOVERY_SETTLE = 5.0
SETTLED = 'discovery settled'  # logged once DISCOVERY_SETTLE has passed
DRAIN_MAX = 5000  # messages taken in one callback before other callbacks get a turn
LINGER = 1.0  # s (wall) the node stays up after a write failure, to report it
FIRST_MESSAGE = 'first message on'  # logged once per topic (arm-sim bringup waits on it)

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
    ParamSpec('queue_depth', 'int', 10000, 'Messages each subscription keeps while the '
              'recorder is busy (more than this in a burst are lost, and counted)',
              'messages', minimum=1, maximum=1_000_000, read_only=True),
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


def adapted_qos(profiles: list, latched_default: bool) -> tuple[bool, bool]:
    """(reliable, transient_local) a subscription needs to match every publisher in
    ``profiles`` and get what they keep (rosbag2's rule); with no publisher known yet,
    reliable and ``latched_default``."""
    if not profiles:
        return True, latched_default
    reliable = all(q.reliability == ReliabilityPolicy.RELIABLE for q in profiles)
    latched = all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in profiles)
    return reliable, latched


@dataclass
class _Topic:
    """One recorded topic: its subscription and counts."""

    name: str
    type_name: str
    cls: Any
    qos: tuple[bool, bool]            # (reliable, transient_local) subscribed with
    sub: Subscription | None = None
    channel: int | None = None        # MCAP channel, made at the first message
    received: int = 0
    gap_lost: int = 0                 # from publisher sequence gaps
    event_lost: int = 0               # from DDS message-lost events
    first_seq: int = 0                # publication number of the first message received
    start_note: str = ''              # what became of the messages before it (logged)
    unrecorded_start: int = 0         # sent before it, perhaps before the recording
    publishers: int = 0               # of the right type, at the last graph look
    gaps: GapCounter = field(default_factory=GapCounter)
    wrong: set[str] = field(default_factory=set)

    @property
    def lost(self) -> int:
        # DDS's events count some of the same messages as the numbers do, the unrecorded
        # start among them (its publisher's first messages never arrived): never twice.
        return max(self.gap_lost, self.event_lost - self.unrecorded_start)


class RecorderNode(Node):
    """See the module docstring."""

    def __init__(self) -> None:
        self.started = time.monotonic()
        super().__init__('recorder', cli_args=clock_in_namespace())
        p = declare_parameters(self, ROBOT_PARAMS + RECORDER_PARAMS, joints=joint_count)
        if not str(p['output']).strip():
            raise ConfigError('output is required: the bag directory to create (-p '
                              'output:=DIR; it must not exist)')
        out = Path(p['output']).expanduser()
        if os.path.lexists(out):
            raise ConfigError(f'output {str(out)!r} already exists; refusing to overwrite it')
        try:
            self.writer = BagWriter(out, chunk_size=p['chunk_size'])
        except (OSError, ValueError) as exc:
            raise ConfigError(f'output {str(out)!r}: {exc}') from None
        try:
            self.writer.add_metadata('arm_sim_robot', {s.name: json.dumps(list(p[s.name])
                                     if isinstance(p[s.name], (list, tuple)) else p[s.name])
                                     for s in ROBOT_PARAMS})
            self.writer.write_metadata_yaml()
        except (OSError, ValueError) as exc:
            try:  # a complete (empty) bag, its reserve freed: nothing half-made is left
                self.writer.close()
            except OSError:
                pass
            raise ConfigError(f'output {str(out)!r}: {exc}') from None
        self.sim_clock = bool(self.get_parameter('use_sim_time').value)
        self.depth = int(p['queue_depth'])
        self.wanted = list(p['topics'])
        self.all_topics = '*' in self.wanted
        self.known = {self.resolve_topic_name(t): ty for t, ty in KNOWN_TOPICS.items()}
        self.latched = {self.resolve_topic_name(t) for t in LATCHED}
        self.resolved = {self.resolve_topic_name(t) for t in self.wanted if t != '*'}
        self.topics: dict[str, _Topic] = {}
        self.skipped: set[str] = set()
        self.first_seen: dict[bytes, float] = {}  # publisher GID -> when seen (monotonic)
        self.settled = False
        self.received = 0
        self.failed: str | None = None
        self.stopped = False
        self.diag = Diagnostics(self)
        for name in sorted(self.resolved):
            if name in self.known:  # subscribed now: nothing its publishers send is missed
                self._subscribe(name, self.known[name], [])
        self.create_timer(DISCOVERY_PERIOD, self.discover, clock=steady_clock())
        self.create_timer(p['flush_period'], self.flush, clock=steady_clock())
        self.discover()
        self.get_logger().info(
            f"recording to {out} (flush every {p['flush_period']:g} s, chunk "
            f"{p['chunk_size']} bytes): {'every topic' if self.all_topics else self.wanted}")

    # ------------------------------------------------------------------ topics
    def discover(self) -> None:
        """Look at the graph: subscribe new topics, adapt QoS, report wrong types."""
        if self.stopped:
            return
        now = time.monotonic()
        for name, _types in self.get_topic_names_and_types():
            if name in self.skipped or (not self.all_topics and name not in self.resolved):
                continue
            infos = self.get_publishers_info_by_topic(name)
            if not infos:
                continue
            for i in infos:
                self.first_seen.setdefault(bytes(i.endpoint_gid), now)
            rec = self.topics.get(name)
            type_name = rec.type_name if rec else self._choose_type(name, infos)
            if type_name is None:
                continue
            right = [i for i in infos if i.topic_type == type_name]
            if rec is None:
                self._subscribe(name, type_name, [i.qos_profile for i in right])
                rec = self.topics.get(name)
                if rec is None:
                    continue
            self._check_publishers(rec, infos, right)
        if not self.settled and now - self.started >= DISCOVERY_SETTLE:
            self.settled = True
            self.get_logger().info(
                f'{SETTLED}: a publisher that appears from now on is counted from its '
                'first message (what it sent before the recorder got it is lost)')

    def _before_first(self, rec: _Topic, seq: int) -> tuple[int, int]:
        """(lost, unrecorded start): the messages the one publisher of ``rec`` sent before
        the first one the recorder received (``seq``), lost if it appeared while the
        recorder recorded (:func:`arm_bag.loss.before_first`)."""
        if seq <= 1:
            return 0, 0
        right = [i for i in self.get_publishers_info_by_topic(rec.name)
                 if i.topic_type == rec.type_name]
        if len(right) != 1:
            return 0, 0
        seen = self.first_seen.setdefault(bytes(right[0].endpoint_gid), time.monotonic())
        return before_first(seq, len(right), seen - self.started >= DISCOVERY_SETTLE)

    def _choose_type(self, name: str, infos) -> str | None:
        types = sorted({i.topic_type for i in infos},
                       key=lambda t: (-sum(i.topic_type == t for i in infos), t))
        return types[0] if types else None

    def _check_publishers(self, rec: _Topic, infos, right) -> None:
        rec.publishers = len(right)
        for i in infos:
            if i.topic_type != rec.type_name and i.topic_type not in rec.wrong:
                rec.wrong.add(i.topic_type)
                self.diag.problem('wrong_type', f'{rec.name}: a publisher of '
                                  f'{i.topic_type} (node {i.node_namespace.rstrip("/")}/'
                                  f'{i.node_name}) is not recorded; recording the '
                                  f'{rec.type_name} publishers', topic=rec.name,
                                  type=i.topic_type)
        need = adapted_qos([i.qos_profile for i in right], rec.name in self.latched)
        if right and need != rec.qos:
            # A publisher this subscription cannot match (best effort, volatile) or one
            # whose kept messages it would not get: subscribe again with what all offer.
            old = rec.sub
            rec.qos = need
            rec.sub = self._create(rec)
            if old is not None:  # what reached only the old one (the overlap may repeat a
                self._drain_sub(rec, old)  # few messages, as two subscriptions would)
                self.destroy_subscription(old)
            self.get_logger().info(
                f"{rec.name}: subscribed again as {'reliable' if need[0] else 'best effort'}"
                f", {'transient local' if need[1] else 'volatile'} to match its publishers")

    def _skip(self, name: str, reason: str) -> None:
        self.skipped.add(name)
        self.diag.problem('skipped_topic', f'not recording {name}: {reason}')

    def _subscribe(self, name: str, type_name: str, profiles: list) -> None:
        try:
            cls = message_class(type_name)
            schema_text(type_name)
        except (ImportError, AttributeError, ValueError, MessageDefinitionError) as exc:
            self._skip(name, f'type {type_name} unavailable: {exc}')
            return
        rec = _Topic(name, type_name, cls, adapted_qos(profiles, name in self.latched))
        rec.sub = self._create(rec)
        self.topics[name] = rec
        self.get_logger().info(f'recording {name} [{type_name}]')

    def _create(self, rec: _Topic) -> Subscription:
        reliable, latched = rec.qos
        qos = QoSProfile(depth=self.depth,
                         reliability=(ReliabilityPolicy.RELIABLE if reliable
                                      else ReliabilityPolicy.BEST_EFFORT),
                         durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched
                                     else DurabilityPolicy.VOLATILE))
        kwargs: dict[str, Any] = {}
        try:
            from rclpy.event_handler import SubscriptionEventCallbacks

            kwargs['event_callbacks'] = SubscriptionEventCallbacks(
                message_lost=functools.partial(self._lost, rec=rec),
                matched=lambda _info: self.discover())  # a publisher came or went
        except ImportError:
            pass
        return self.create_subscription(rec.cls, rec.name,
                                        functools.partial(self._on_message, rec=rec), qos,
                                        raw=True, **kwargs)

    def _channel(self, rec: _Topic) -> int:
        """The topic's MCAP channel, made at its first message: by then its publishers are
        known, so their offered QoS is written with it."""
        infos = [i for i in self.get_publishers_info_by_topic(rec.name)
                 if i.topic_type == rec.type_name]
        thash = type_hash(rec.type_name)
        if not thash and infos:
            thash = str(getattr(infos[0], 'topic_type_hash', '') or '')
        rec.channel = self.writer.add_topic(
            rec.name, rec.type_name, schema_text(rec.type_name),
            qos_yaml(offered_qos([i.qos_profile for i in infos])), thash)
        self.get_logger().info(f'{FIRST_MESSAGE} {rec.name}{rec.start_note}')
        return rec.channel

    # ------------------------------------------------------------------ data
    def _on_message(self, data: bytes, info: dict, *, rec: _Topic) -> None:
        if rec.sub is not None:
            self._take(rec, rec.sub, data, info)
        self._drain(rec)

    def _drain(self, rec: _Topic, limit: int = DRAIN_MAX) -> None:
        """Take what is waiting on ``rec``'s subscription, up to ``limit`` messages."""
        if rec.sub is not None:
            self._drain_sub(rec, rec.sub, limit)

    def _drain_sub(self, rec: _Topic, sub: Subscription, limit: int = 10**9) -> None:
        try:
            with sub.handle:
                for _ in range(limit):
                    got = sub.handle.take_message(rec.cls, True)
                    if got is None:
                        return
                    self._take(rec, sub, got[0], got[1])
        except InvalidHandle:
            pass  # destroyed while we took: nothing left to take

    def _take(self, rec: _Topic, sub: Subscription, data: bytes, info: dict) -> None:
        now = self.get_clock().now().nanoseconds if self.sim_clock else time.time_ns()
        self.received += 1
        rec.received += 1
        seq = int(info.get('publication_sequence_number') or 0)
        if rec.received == 1:  # its first message: what its publisher sent before it?
            rec.first_seq = seq
            missed, unrecorded = self._before_first(rec, seq)
            if unrecorded:
                self.writer.count_unrecorded_start(rec.name, unrecorded)
                self._count_lost(rec, unrecorded=unrecorded)
            if missed:
                self._count_lost(rec, gap=missed)
            if missed or unrecorded:
                rec.start_note = (
                    f' (number {seq} of its publisher; the {missed or unrecorded} before it '
                    + ('never arrived: counted lost)' if missed else
                       'are an unrecorded start: it was there in the first '
                       f'{DISCOVERY_SETTLE:g} s, so they may precede the recording)'))
        if seq and seq != (rec.gaps.last or -1) + 1:
            # Not the next number: first tell the counter how many publishers DDS has
            # matched right now (a publisher is matched before any of its data arrives).
            rec.gaps.graph(sub.handle.get_publisher_count())
        gap = rec.gaps.message(seq)
        if gap:
            self._count_lost(rec, gap=gap)
        if self.stopped:
            return
        try:
            channel = rec.channel if rec.channel is not None else self._channel(rec)
            self.writer.write(channel, data, now, int(info.get('source_timestamp') or now),
                              seq)
        except BagWriteError as exc:
            self._fail(exc)

    def _lost(self, info, *, rec: _Topic) -> None:
        self._count_lost(rec, event=int(getattr(info, 'total_count_change', 1)))

    def _count_lost(self, rec: _Topic, gap: int = 0, event: int = 0,
                    unrecorded: int = 0) -> None:
        """Count ``gap`` messages lost by the numbers, ``event`` by DDS events, and
        ``unrecorded`` sent before the first one received, not known to be loss (DDS
        events of those are then not loss either)."""
        before = rec.lost
        rec.gap_lost += gap
        rec.event_lost += event
        rec.unrecorded_start += unrecorded
        n = rec.lost - before
        if n != 0:
            self.writer.set_lost(rec.name, rec.lost)
        if n <= 0:
            return
        self.diag.problem('lost', f'{rec.name}: {n} messages lost before reaching the '
                          f'recorder ({rec.lost} on this topic so far)', topic=rec.name,
                          lost=rec.lost, lost_total=self.lost)

    @property
    def lost(self) -> int:
        return sum(r.lost for r in self.topics.values())

    def flush(self) -> None:
        if self.stopped:
            return
        try:
            self.writer.flush()
        except BagWriteError as exc:
            self._fail(exc)
            return
        lost = self.lost
        self.diag.set('OK' if not lost else 'WARN', f'recording {len(self.topics)} topics',
                      received=self.received, written=self.writer.message_count,
                      buffered=self.writer.pending, lost=lost, dropped=lost,
                      topics=sorted(self.topics),
                      **{f'received {t}': r.received for t, r in self.topics.items()},
                      **{f'lost {t}': r.lost for t, r in self.topics.items() if r.lost},
                      **{f'unrecorded_start {t}': r.unrecorded_start
                         for t, r in self.topics.items() if r.unrecorded_start})

    def _fail(self, exc: Exception) -> None:
        if self.stopped:
            return
        self.stopped = True
        self.failed = str(exc.strerror if isinstance(exc, OSError) and exc.strerror
                          else exc)
        self.failed_at = time.monotonic()
        for rec in self.topics.values():
            if rec.sub is not None:
                self.destroy_subscription(rec.sub)
                rec.sub = None
        try:
            self.writer.close()
        except BagWriteError:
            pass
        self.diag.set('ERROR', self.failed, received=self.received,
                      written=self.writer.message_count, lost=self.lost)
        # Not diag.problem(): rclpy refuses one logging call site used with two severities
        # (problem() logs both warnings and errors from the same line).
        self.get_logger().error(self.failed)
        self.diag.publish()

    def close(self) -> None:
        """Take what is still queued, write everything and close the bag (idempotent)."""
        if self.stopped:
            return
        for rec in self.topics.values():
            self._drain(rec, limit=10**9)
            gap = rec.gaps.close()
            if gap:
                self._count_lost(rec, gap=gap)
        self.stopped = True
        try:
            self.writer.close()
        except BagWriteError as exc:
            self.failed = str(exc.strerror or exc)
            self.get_logger().error(self.failed)
            return
        lost = {t: r.lost for t, r in self.topics.items() if r.lost}
        start = {t: r.unrecorded_start for t, r in self.topics.items() if r.unrecorded_start}
        self.get_logger().info(
            f'bag closed: {self.writer.message_count} messages written of '
            f'{self.received} received ({self.lost} lost before the recorder'
            f'{": " + json.dumps(lost) if lost else ""}'
            f'{"; unrecorded start: " + json.dumps(start) if start else ""}) in '
            f'{self.writer.directory}')

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
