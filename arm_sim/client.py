"""A small rclpy client for a running arm_sim suite: what ``arm-sim`` talks through.

Watches ``joint_states``, the planner's trajectories and ``/diagnostics``, publishes
goals and sets parameters through the standard parameter services.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rcl_interfaces.srv import SetParameters
from rclpy.client import Client
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from arm_common.node import SUMMARY_TASK, parse_status_name, set_parameters_request


@dataclass(frozen=True)
class Event:
    """An immediate /diagnostics report of a suite node: its kind (key ``event``, also the
    status's task), level (0 OK, 1 WARN, 2 ERROR), message and key-values."""

    node: str
    kind: str
    level: int
    message: str
    values: dict[str, str]


class SuiteError(Exception):
    """Something the suite did not do; the message is for the user."""


def stamp_of(msg) -> float:
    """A message's header stamp [s]."""
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def _level(status) -> int:
    level = status.level
    return level if isinstance(level, int) else level[0]


def goal_refusal(events: Sequence[Event], statuses: Sequence) -> str | None:
    """Why a goal will not be executed, from the suite's reports since it was sent (None:
    nothing says so): the planner refused it (its ``goal_*`` reports: unreachable, wrong
    frame, not sent, refused by the controller ...), or the controller refused its
    trajectory for good (a ``refused`` status on ``arm_controller/trajectory_status``, the
    DiagnosticStatuses ``statuses``). A refusal marked ``stale`` (the trajectory was planned
    from a state simulated time has since left: "ends in the past") is not the goal's
    refusal: the planner plans it again from the latest state, and reports
    ``goal_refused_by_controller`` if it gives up."""
    for e in events:
        if e.node == 'planner' and e.kind.startswith('goal_'):
            return e.message.removeprefix('goal_pose refused: ')
    for s in statuses:
        values = {kv.key: kv.value for kv in s.values}
        if _level(s) != 0 and values.get('stale') != 'true':
            return f'the controller {s.message}'
    return None


class SuiteClient:
    """Client of the suite in ``namespace`` on ROS domain ``domain_id``."""

    def __init__(self, domain_id: int, namespace: str = '') -> None:
        self.ns = namespace.rstrip('/')
        if self.ns and not self.ns.startswith('/'):
            self.ns = '/' + self.ns
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node('arm_sim_cli', namespace=self.ns or '/',
                                      context=self.context)
        self.states: list[JointState] = []
        self.trajectories: list[JointTrajectory] = []
        # The controller's word on each trajectory (accepted, or refused and whether stale).
        self.trajectory_statuses: list[DiagnosticStatus] = []
        self.reference_time = -math.inf  # stamp of the controller's latest answer [s]
        # The suite's /diagnostics (statuses '<ns>/<node>: <task>', arm_common.node.Diagnostics):
        self.diagnostics: list[tuple[str, int, str]] = []  # summaries: (node, level, message)
        self.diagnostic_values: list[tuple[str, dict[str, str]]] = []  # summaries: (node, k: v)
        self.events: list[Event] = []  # immediate reports (those with an 'event' key)
        self.counts: dict[tuple[str, str], int] = {}  # (node, kind): occurrences reported
        n = self.node
        n.create_subscription(JointState, 'joint_states', self._keep_state, 1000)
        n.create_subscription(JointTrajectory, 'arm_controller/joint_trajectory',
                              self.trajectories.append, 10)
        n.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 100)
        n.create_subscription(DiagnosticStatus, 'arm_controller/trajectory_status',
                              self.trajectory_statuses.append, 10)
        n.create_subscription(JointState, 'arm_controller/reference', self._on_reference,
                              1000)
        self.goal_pub = n.create_publisher(PoseStamped, 'goal_pose', 10)
        self._clients: dict[str, Client] = {}

    def _keep_state(self, msg: JointState) -> None:
        self.states.append(msg)
        if len(self.states) > 20000:
            del self.states[:10000]

    def follow_reference(self, topic: str) -> None:
        """Also take :attr:`reference_time` from ``topic`` (JointState; e.g. ``arm-sim
        check``'s own reference stream)."""
        self.node.create_subscription(JointState, topic, self._on_reference, 1000)

    def _on_reference(self, msg: JointState) -> None:
        self.reference_time = max(self.reference_time, stamp_of(msg))

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for s in msg.status:
            parsed = parse_status_name(s.name)
            if parsed is None:
                continue
            ns, _, node = parsed[0].rpartition('/')
            if ns != self.ns:
                continue
            task = parsed[1]
            level = _level(s)
            values = {kv.key: kv.value for kv in s.values}
            if task == SUMMARY_TASK:
                self.diagnostics.append((node, level, s.message))
                self.diagnostic_values.append((node, values))
                continue
            if values.get('count', '').isdigit():
                key = (node, task)
                self.counts[key] = max(self.counts.get(key, 0), int(values['count']))
            if 'event' in values:
                self.events.append(Event(node, values['event'], level, s.message, values))

    def events_of(self, node: str, *kinds: str, since: int = 0) -> list[Event]:
        """Immediate reports of ``node`` (of these ``kinds``, if given) from index
        ``since`` of :attr:`events` on."""
        return [e for e in self.events[since:]
                if e.node == node and (not kinds or e.kind in kinds)]

    def latest_values(self, node: str) -> dict[str, str]:
        """The key-values of ``node``'s latest summary (empty if none came)."""
        return next((v for n, v in reversed(self.diagnostic_values) if n == node), {})

    def count(self, node: str, kind: str) -> int:
        """How often ``node`` reported the problem or event ``kind`` happened (its
        status's ``count``; 0 if it never did)."""
        return self.counts.get((node, kind), 0)

    def node_name(self, name: str) -> str:
        return f'{self.ns}/{name}'

    def spin_until(self, condition: Callable[[], object], timeout: float, what: str,
                   alive: Callable[[], None] | None = None) -> object:
        """Spin until ``condition()`` is truthy; SuiteError after ``timeout`` s (wall).
        ``alive`` may raise if a process the wait depends on died."""
        end = time.monotonic() + timeout
        while True:
            value = condition()
            if value:
                return value
            if alive:
                alive()
            if time.monotonic() > end:
                raise SuiteError(f'timed out after {timeout:g} s waiting for {what}')
            self._spin_once()

    def spin_for(self, seconds: float, until: Callable[[], object] | None = None) -> None:
        """Spin for ``seconds`` (wall), or until ``until()`` is truthy; never raises."""
        end = time.monotonic() + seconds
        while time.monotonic() < end and not (until and until()):
            self._spin_once()

    def _spin_once(self) -> None:
        executor = getattr(self, '_executor', None)
        if executor is None:
            from rclpy.executors import SingleThreadedExecutor
            executor = self._executor = SingleThreadedExecutor(context=self.context)
            executor.add_node(self.node)
        executor.spin_once(timeout_sec=0.02)

    @property
    def sim_time(self) -> float:
        return stamp_of(self.states[-1]) if self.states else -math.inf

    def set_params(self, node: str, timeout: float = 10.0, **values) -> None:
        """Set parameters of ``node`` (e.g. 'planner'); SuiteError with the node's reason
        if refused."""
        name = self.node_name(node)
        client = self._clients.get(name)
        if client is None:
            client = self._clients[name] = self.node.create_client(
                SetParameters, f'{name}/set_parameters')
        self.spin_until(client.service_is_ready, timeout, f'the {name} parameter service')
        future = client.call_async(set_parameters_request(values))
        self.spin_until(future.done, timeout, f'{name} to set {sorted(values)}')
        for key, result in zip(values, future.result().results):
            if not result.successful:
                raise SuiteError(f'{name} refused {key}={values[key]!r}: {result.reason}')

    def call_trigger(self, node: str, service: str, timeout: float = 10.0,
                     alive: Callable[[], None] | None = None) -> str:
        """Call ``node``'s std_srvs/Trigger service ``service`` (e.g. 'simulator', 'reset');
        returns its message; SuiteError if it is not there, does not answer in ``timeout``
        s or fails."""
        from std_srvs.srv import Trigger

        name = f'{self.node_name(node)}/{service}'
        client = self._clients.get(name)
        if client is None:
            client = self._clients[name] = self.node.create_client(Trigger, name)
        self.spin_until(client.service_is_ready, timeout, f'the {name} service', alive)
        future = client.call_async(Trigger.Request())
        self.spin_until(future.done, timeout, f'{name} to answer', alive)
        reply = future.result()
        if reply is None or not reply.success:
            raise SuiteError(f'{name} failed: {getattr(reply, "message", "no reply")}')
        return str(reply.message)

    def publish_goal(self, x: float, y: float, frame: str = 'base_link') -> None:
        msg = PoseStamped()
        msg.header.frame_id = frame
        msg.pose.position.x, msg.pose.position.y = float(x), float(y)
        msg.pose.orientation.w = 1.0
        self.goal_pub.publish(msg)

    def subscribed(self, topic: str, node: str) -> bool:
        """Is ``node`` subscribed to ``topic`` (relative to the namespace)?"""
        full = topic if topic.startswith('/') else f'{self.ns}/{topic}'
        return any(i.node_name == node for i in
                   self.node.get_subscriptions_info_by_topic(full))

    def close(self) -> None:
        executor = getattr(self, '_executor', None)
        if executor is not None:
            executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
