"""rclpy helpers shared by the arm_sim nodes: parameters from specs, diagnostics, main().

Only node modules import this; the maths stays in the ROS-free packages.
"""

from __future__ import annotations

import inspect
import math
import os
import signal
import sys
import traceback
import weakref
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    ParameterValue,
    SetParametersResult,
)
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.srv import SetParameters
from rclpy._rclpy_pybind11 import RCLError
from rclpy.clock import Clock, ClockType
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.subscription import Subscription
from rclpy.time_source import TimeSource

from arm_common.exits import EXIT_OK, EXIT_USAGE
from arm_common.params import (
    ParamSpec,
    command_line_parameters,
    rcl_params_file,
    rcl_rule_value,
    relation_reasons,
    resolve,
    walk_ros_args,
)
from arm_common.process import watch_parent
from arm_common.stamps import NS_PER_S, stamp_refusal
from arm_common.throttle import Throttle

LEVELS = {'OK': DiagnosticStatus.OK, 'WARN': DiagnosticStatus.WARN,
          'ERROR': DiagnosticStatus.ERROR, 'STALE': DiagnosticStatus.STALE}


class ConfigError(Exception):
    """A node's start-up parameters are refused; the message gives every reason."""


_user_args: list[str] = []  # the command line run_node was given


def clock_in_namespace() -> list[str]:
    """Node arguments every arm_sim node is created with: ``/clock`` resolves to ``clock`` in
    the node's namespace, so a suite started with ``-r __ns:=/arm2`` runs on its own
    simulator's clock (``/arm2/clock``) with no remapping by the user; in the root namespace
    it is the usual ``/clock``. Node-local remaps beat the command line's, so when the user
    remaps ``/clock`` themselves (``-r /clock:=...``) none is added and theirs applies."""
    if any(a.startswith('/clock:=') or a.startswith('clock:=') for a in _user_args):
        return []
    return ['--ros-args', '-r', '/clock:=clock']


def steady_clock() -> Clock:
    """A wall clock for timers that must run whatever ``use_sim_time`` says."""
    return Clock(clock_type=ClockType.STEADY_TIME)


#: History depth of the streams the recorder takes (states, clock, commands, references):
#: a reliable writer keeps this many unacknowledged messages, so a recorder that falls
#: behind a fast lockstep loop for a while (1 s at 1 kHz, 10 s at 100 Hz) still gets every
#: one; with depth 10 a busy machine lost hundreds of states of a composed lockstep run.
STREAM_DEPTH = 1000


def latched_qos() -> QoSProfile:
    """QoS of a state-like topic, published once per change (a plan's path, the verdict on
    the latest trajectory): reliable, transient local, keep last 1, as robot_state_publisher
    publishes ``robot_description``. A subscriber that asks for transient local (RViz with
    Durability "Transient Local", ``ros2 topic echo``, the recorder) gets the last message
    even if it came up later; a volatile one matches too and gets the new ones."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def declare_parameters(node: Node, specs: Iterable[ParamSpec],
                       joints: Callable[[dict[str, Any]], int] | None = None
                       ) -> dict[str, Any]:
    """Declare ``specs`` on ``node`` and return their values; raise :class:`ConfigError`
    listing every refused value.

    Start-up values come from params files and ``--ros-args -p``, with ``-p`` winning for
    every parameter (rclpy alone lets a file entry naming the node beat a ``-p``). They
    are validated by :func:`arm_common.params.resolve`, the code ``arm-sim urdf`` runs too:
    integers given for doubles taken as doubles, an empty list (which a params file loads
    as unset) as the empty default, each value checked, the per-joint parameters sized
    by ``joints`` (the start-up values by name -> the robot's joint count, raising
    ValueError with the reason; those not given are declared with their default for that
    many joints, so parameter tools show the values the node uses), then each spec's
    relation to the others. Every parameter is declared with its type and, numeric, its
    range (:func:`descriptor`), as ``ros2 param describe`` shows them.
    """
    specs = tuple(specs)
    # rclpy keeps the start-up values (params files, then -p) in this dict and reads it in
    # declare_parameter; it is what the public ``parameter_overrides`` argument extends.
    overrides: dict[str, Parameter] = node._parameter_overrides  # private: see above
    from_command_line = command_line_parameters(_user_args, node.get_name(),
                                                node.get_fully_qualified_name())
    own = {spec.name for spec in specs}
    for name, value in from_command_line.items():  # rclpy's own, e.g. use_sim_time
        if name not in own and node.has_parameter(name) and (
                node.get_parameter(name).value != value):
            node.set_parameters([Parameter(name, value=value)])
    given = {spec.name: overrides[spec.name].value for spec in specs
             if spec.name in overrides}
    given.update({k: v for k, v in from_command_line.items() if k in own})
    try:
        values = resolve(specs, given, joints)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    for spec in specs:  # valid now: rclpy may hold them (a mixed list it could not)
        if spec.name in given:
            overrides[spec.name] = Parameter(spec.name, value=values[spec.name])
    for spec in specs:
        _declare(node, spec, values[spec.name])
    return values


#: The ROS type of each ParamSpec kind: what an empty list is declared as.
_TYPES = {'double': Parameter.Type.DOUBLE, 'doubles': Parameter.Type.DOUBLE_ARRAY,
          'string': Parameter.Type.STRING, 'strings': Parameter.Type.STRING_ARRAY,
          'int': Parameter.Type.INTEGER, 'bool': Parameter.Type.BOOL}


def _declare(node: Node, spec: ParamSpec, value: Any) -> None:
    """Declare one parameter with its (valid) start-up ``value`` and :func:`descriptor`.

    Dynamically typed, as the nodes' own checks refuse wrong types in their words; the
    type follows the value, so every value declares its real type, except an empty list,
    which rclpy would take for a byte array (``ros2 param describe`` said "byte array" for
    ``control_model.*``). That one is declared writable, its empty value of the spec's
    type put in place through :meth:`Node.set_descriptor`, and only then read-only as
    its spec says."""
    desc = descriptor(spec)
    if not (isinstance(value, list) and not value):
        node.declare_parameter(spec.name, value, desc)
        return
    kind = _TYPES[spec.kind]
    writable = descriptor(spec)
    writable.read_only = False
    node.declare_parameter(spec.name, value, writable)
    empty = ParameterValue(type=kind.value, **{
        'double_array_value' if kind == Parameter.Type.DOUBLE_ARRAY
        else 'string_array_value': []})
    static = descriptor(spec)
    static.dynamic_typing, static.type = False, kind.value
    node.set_descriptor(spec.name, static, alternative_value=empty)


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """The ROS descriptor of a parameter: its doc, read-only flag, type and numeric range."""
    desc = ParameterDescriptor(name=spec.name, description=spec.doc(),
                               read_only=spec.read_only, dynamic_typing=True,
                               type=_TYPES[spec.kind].value)
    if spec.minimum is None and spec.maximum is None:
        return desc
    lo = -math.inf if spec.minimum is None else spec.minimum
    hi = math.inf if spec.maximum is None else spec.maximum
    if spec.kind == 'int':
        desc.integer_range = [IntegerRange(from_value=int(max(lo, -2**63)),
                                           to_value=int(min(hi, 2**63 - 1)), step=0)]
    elif spec.kind in ('double', 'doubles'):
        desc.floating_point_range = [FloatingPointRange(from_value=float(lo),
                                                        to_value=float(hi), step=0.0)]
    return desc


def on_parameter_changes(node: Node, specs: Iterable[ParamSpec],
                         validate: Callable[[dict[str, Any]], str | None],
                         apply: Callable[[dict[str, Any]], None],
                         values: dict[str, Any] | None = None) -> None:
    """Validate run-time parameter changes against ``specs`` (then ``validate``, which sees
    the changed values and may refuse with a reason, then, given the node's current
    ``values`` by name, each spec's relation to the others, as at start:
    :func:`arm_common.params.relation_reasons`), and ``apply`` accepted ones (``apply``
    keeps ``values`` up to date)."""
    specs = tuple(specs)
    table = {s.name: s for s in specs}

    def check(params: list[Parameter]) -> SetParametersResult:
        changed = {}
        for p in params:
            spec = table.get(p.name)
            if spec is None:
                continue
            reason = spec.check(p.value)
            if reason:
                return SetParametersResult(successful=False, reason=reason)
            changed[p.name] = p.value
        reason = validate(changed) if changed else None
        if reason is None and changed and values is not None:
            reason = '; '.join(relation_reasons(specs, {**values, **changed})) or None
        return SetParametersResult(successful=reason is None, reason=reason or '')

    def after(params: list[Parameter]) -> None:
        changed = {p.name: p.value for p in params if p.name in table}
        if changed:
            apply(changed)

    def as_declared(params: list[Parameter]) -> list[Parameter]:
        return [Parameter(p.name, value=table[p.name].as_declared(p.value))
                if p.name in table else p for p in params]

    node.add_pre_set_parameters_callback(as_declared)
    node.add_on_set_parameters_callback(check)
    node.add_post_set_parameters_callback(after)


def parameter_value(value: Any) -> ParameterValue:
    """A Python value as an rcl_interfaces ParameterValue (bool, int, float, str, lists)."""
    T = ParameterType
    if isinstance(value, bool):
        return ParameterValue(type=T.PARAMETER_BOOL, bool_value=value)
    if isinstance(value, int):
        return ParameterValue(type=T.PARAMETER_INTEGER, integer_value=value)
    if isinstance(value, float):
        return ParameterValue(type=T.PARAMETER_DOUBLE, double_value=value)
    if isinstance(value, str):
        return ParameterValue(type=T.PARAMETER_STRING, string_value=value)
    items = list(value)
    if all(isinstance(v, str) for v in items) and items:
        return ParameterValue(type=T.PARAMETER_STRING_ARRAY, string_array_value=items)
    return ParameterValue(type=T.PARAMETER_DOUBLE_ARRAY,
                          double_array_value=[float(v) for v in items])


def set_parameters_request(values: dict[str, Any]) -> SetParameters.Request:
    """A request for a node's ``set_parameters`` service."""
    return SetParameters.Request(parameters=[
        ParameterMsg(name=k, value=parameter_value(v)) for k, v in values.items()])


#: The task of a node's own state in its /diagnostics (its other tasks are problem and
#: event kinds).
SUMMARY_TASK = 'summary'


def status_name(node_fqn: str, task: str) -> str:
    """The /diagnostics status name of ``task`` of the node ``node_fqn`` (its fully
    qualified name): ``<node>: <task>`` as diagnostic_updater names statuses
    (``get_name() + ": " + task``), the node written as its fully qualified name without
    the leading slash, so ``simulator: summary`` in the root namespace (exactly
    diagnostic_updater's name) and ``arm2/simulator: summary`` in ``/arm2``: two arms in
    one ROS graph never publish the same status name."""
    return f"{node_fqn.lstrip('/')}: {task}"


def parse_status_name(name: str) -> tuple[str, str] | None:
    """(node's fully qualified name, task) of a status named by :func:`status_name`, e.g.
    ``('/arm2/simulator', 'summary')``; None for a name without ``': '``."""
    node, sep, task = name.partition(': ')
    if not sep or not node or not task:
        return None
    return '/' + node, task


class _Task:
    """A problem or event kind of a node: its last occurrence and how often it happened."""

    def __init__(self) -> None:
        self.level, self.message = 'OK', ''
        self.values: dict[str, Any] = {}  # of the last occurrence, sim_time first
        self.count = 0
        self.fresh = False  # occurred since the last periodic report


class Diagnostics:
    """A node's ``/diagnostics`` as diagnostic_updater publishes them: one
    DiagnosticStatus per task, named ``<node>: <task>`` (:func:`status_name`: the node's
    name, with its namespace if it has one, e.g. ``simulator: summary``,
    ``arm2/controller: time_jump``), hardware_id ``arm_sim``, the figures as key-values,
    and every status of the node in one DiagnosticArray every ``period`` s (wall clock).

    Tasks:

    * ``summary``: the node's state, as :meth:`set` last gave it (level, message, figures).
      Problems and events never change it.
    * one task per kind of problem (:meth:`problem`: rejected input, a fault, something
      late) and per kind of event (:meth:`event`, level OK: e.g. ``trajectory_accepted``),
      there from its first occurrence on. An occurrence is reported at once, alone in its
      own array, with the key ``event`` = the kind (a problem is logged and reported at
      most once per ``period`` per kind; every occurrence is counted). The periodic array
      repeats it without ``event``: at the occurrence's level and message while the kind
      occurred since the previous periodic report, then decayed to OK (message ``none since
      the last report (N in total); last: ...``, key ``last_level``). So a problem that
      goes on stays WARN/ERROR, one that stopped reads OK with its count, and a monitor
      that missed the immediate report still sees it. Counting reports that carry
      ``event`` counts what was reported at once; the key ``count`` is every occurrence.

    Every array is stamped with the wall clock (system time), whatever ``use_sim_time``
    says: diagnostics report *when* something happened to the person or tool watching.
    The simulated time is the key ``sim_time`` [s] (from ``sim_time()``, when it returns a
    value): in the summary the time its figures are of (``sim_time()`` when :meth:`set`
    last gave them, however much later the periodic report goes out; before any
    :meth:`set`, the time of the report), in a kind's status the time of its last
    occurrence, whose further key-values it carries too. So every figure in a status is of
    the simulated time the status says.
    """

    def __init__(self, node: Node, period: float = 1.0,
                 sim_time: Callable[[], float | None] | None = None) -> None:
        self.node = node
        self.pub = node.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.node_fqn = node.get_fully_qualified_name()
        self.level = 'OK'
        self.message = 'starting'
        self.values: dict[str, Any] = {}
        self._summary_time: dict[str, str] | None = None  # sim_time of the last set()
        self.tasks: dict[str, _Task] = {}
        self.throttle = Throttle(period)
        self.sim_time = sim_time
        self.wall = Clock(clock_type=ClockType.SYSTEM_TIME)
        node.create_timer(period, self.publish, clock=steady_clock())
        _DIAGNOSTICS[node] = self  # where guard_messages reports a dropped message

    @property
    def counts(self) -> dict[str, int]:
        """How often each problem or event kind occurred."""
        return {kind: task.count for kind, task in self.tasks.items()}

    def set(self, level: str, message: str, **values: Any) -> None:
        """Set the summary (published with the next periodic report), its figures of the
        simulated time now: the report carries this ``sim_time``, not the one at publish."""
        self.level, self.message = level, message
        self.values.update(values)
        self._summary_time = self._sim_time()

    def problem(self, kind: str, reason: str, level: str = 'WARN', *, log: bool = True,
                **values: Any) -> None:
        """Report rejected input or a fault now: log + /diagnostics (task ``kind``), at most
        once a period per ``kind``; every occurrence is counted. ``log=False``: on
        /diagnostics only (the caller logs a summary of its own)."""
        task = self._occurred(kind, level, reason, values)
        if self.throttle.ready(kind):
            held = self.throttle.take_suppressed(kind)
            more = f' ({held} more since last report)' if held else ''
            logger = self.node.get_logger()
            # Two call sites: rclpy refuses a severity change at one call site.
            if not log:
                pass
            elif level == 'ERROR':
                logger.error(f'{reason}{more}')
            else:
                logger.warning(f'{reason}{more}')
            self._send([self._task_status(kind, task, event=True)])

    def event(self, kind: str, message: str, **values: Any) -> None:
        """Publish a notable event now (task ``kind``, level OK, counted), e.g. an accepted
        trajectory."""
        task = self._occurred(kind, 'OK', message, values)
        self._send([self._task_status(kind, task, event=True)])

    def publish(self) -> None:
        """The periodic report: the summary and every kind's status in one array."""
        at = self._sim_time() if self._summary_time is None else self._summary_time
        statuses = [self._status(SUMMARY_TASK, self.level, self.message,
                                 {**at, **self.values})]
        for kind, task in self.tasks.items():
            statuses.append(self._task_status(kind, task))
            task.fresh = False
        self._send(statuses)

    def _sim_time(self) -> dict[str, str]:
        sim = self.sim_time() if self.sim_time else None
        return {} if sim is None else {'sim_time': f'{sim:.9f}'}

    def _occurred(self, kind: str, level: str, message: str,
                  values: dict[str, Any]) -> _Task:
        task = self.tasks.setdefault(kind, _Task())
        task.count += 1
        task.level, task.message = level, message
        task.values = {**self._sim_time(), **values}
        task.fresh = True
        return task

    def _task_status(self, kind: str, task: _Task, event: bool = False) -> DiagnosticStatus:
        head: dict[str, Any] = {'event': kind} if event else {}
        level, message = task.level, task.message
        if not event and not task.fresh and level != 'OK':
            head['last_level'] = level
            level, message = 'OK', (f'none since the last report ({task.count} in total); '
                                    f'last: {message}')
        return self._status(kind, level, message, {**head, 'count': task.count,
                                                    **task.values})

    def _status(self, task: str, level: str, message: str,
                values: dict[str, Any]) -> DiagnosticStatus:
        return DiagnosticStatus(level=LEVELS[level], name=status_name(self.node_fqn, task),
                                message=message, hardware_id='arm_sim',
                                values=[KeyValue(key=k, value=str(v))
                                        for k, v in values.items()])

    def _send(self, statuses: list[DiagnosticStatus]) -> None:
        msg = DiagnosticArray(status=statuses)
        msg.header.stamp = self.wall.now().to_msg()
        self.pub.publish(msg)


#: Each node's :class:`Diagnostics`, where :func:`guard_messages` reports what it drops.
_DIAGNOSTICS: weakref.WeakKeyDictionary[Node, Diagnostics] = weakref.WeakKeyDictionary()
_GUARDED: weakref.WeakSet[Node] = weakref.WeakSet()

#: /diagnostics kinds of :func:`guard_messages`: a clock message that is no valid time, and
#: a message whose callback raised (the planner's and live view's name for the latter).
REJECTED_CLOCK = 'rejected_clock'
INTERNAL_ERROR = 'internal_error'



def clock_refusal(sec: int, nanosec: int) -> str | None:
    """Why the time of a rosgraph_msgs/Clock message (``sec`` [s], ``nanosec`` [ns]) is no
    valid simulated time (rclpy's TimeSource raises ValueError on a negative one), or None:
    :func:`arm_common.stamps.stamp_refusal`, the one rule."""
    return stamp_refusal(sec, nanosec, 'clock')


def guard_messages(node: Node) -> None:
    """No single message stops ``node``: every subscription callback of ``node`` (those it
    has, and those it creates later, rclpy's own ``clock`` subscription included when
    ``use_sim_time`` is switched on at run time) is wrapped so that

    * a ``clock`` message for the node's time source (``use_sim_time``) that
      :func:`clock_refusal` refuses, or that rclpy's TimeSource raises on, is dropped: the
      node keeps its last good time (``kept_time`` [s]) and goes on; reported (WARN,
      throttled) in the log and on /diagnostics as ``rejected_clock`` with ``sec`` and
      ``nanosec``;
    * a message whose callback raises is dropped and reported (ERROR, throttled) as
      ``internal_error`` with the topic, the exception and where it was raised; the node
      goes on. (Without this a callback's exception leaves ``spin_once`` and ends the node
      with exit code 1.)

    :func:`run_node` guards every node its factory makes; reports go to the node's
    :class:`Diagnostics` (to its log alone if it has none)."""
    if node in _GUARDED:
        return
    _GUARDED.add(node)
    for sub in list(node.subscriptions):
        _guard(node, sub)
    create = node.create_subscription

    def create_guarded(*args: Any, **kwargs: Any) -> Subscription:
        sub = create(*args, **kwargs)
        _guard(node, sub)
        return sub

    # An instance attribute: rclpy's TimeSource subscribes through node.create_subscription.
    node.create_subscription = create_guarded  # type: ignore[method-assign]


def _report(node: Node, kind: str, reason: str, level: str, **values: Any) -> None:
    diag = _DIAGNOSTICS.get(node)
    if diag is not None:
        diag.problem(kind, reason, level, **values)
    elif level == 'ERROR':  # two call sites: rclpy refuses a severity change at one
        node.get_logger().error(reason, throttle_duration_sec=1.0)
    else:
        node.get_logger().warning(reason, throttle_duration_sec=1.0)


def _guard(node: Node, sub: Subscription) -> None:
    """Wrap ``sub``'s callback as :func:`guard_messages` says."""
    callback = sub.callback
    topic = sub.topic_name
    # private: the TimeSource that rclpy.node.Node makes and subscribes to clock with
    time_source = getattr(node, '_time_source', None)
    is_clock = (getattr(callback, '__self__', None) is time_source is not None
                and getattr(callback, '__func__', None) is TimeSource.clock_callback)

    def take_clock(msg: Any) -> None:
        sec, nanosec = msg.clock.sec, msg.clock.nanosec
        reason = clock_refusal(sec, nanosec)
        if reason is None:
            try:
                callback(msg)
                return
            except (ValueError, OverflowError, TypeError) as exc:  # TimeSource refused it
                reason = f'rclpy refused it: {exc}'
        kept = node.get_clock().now().nanoseconds / NS_PER_S
        _report(node, REJECTED_CLOCK, f'{topic} refused: {reason}; the node keeps its time '
                f'at {kept:.9f} s', 'WARN', topic=topic, sec=sec, nanosec=nanosec,
                kept_time=f'{kept:.9f}')

    def handle(*args: Any) -> None:
        try:
            if is_clock:
                take_clock(args[0])
            else:
                callback(*args)
        except ExternalShutdownException:
            raise
        except Exception as exc:  # no message may stop the node
            frame = traceback.extract_tb(exc.__traceback__)[-1]
            where = f'{os.path.basename(frame.filename)}:{frame.lineno} in {frame.name}'
            _report(node, INTERNAL_ERROR, f'{topic}: message dropped, handling it failed: '
                    f'{exc!r} (at {where}); the node goes on', 'ERROR', topic=topic,
                    error=repr(exc), where=where)

    try:  # the callback's arity, as rclpy tells the two kinds apart
        inspect.signature(callback).bind(object())
        sub.callback = lambda msg: handle(msg)
    except TypeError:
        sub.callback = lambda msg, info: handle(msg, info)


def print_help(prog: str, summary: str, specs: Iterable[ParamSpec]) -> None:
    """``--help`` for a node executable: what it does and every parameter with its unit."""
    print(f'usage: {prog} [--ros-args -p NAME:=VALUE ... --params-file FILE -r FROM:=TO]\n')
    print(summary.strip() + '\n\nparameters:')
    for s in specs:
        print(f'  {s.name} (default {s.default!r})\n      {s.doc()}')


#: The executor every node spins (bench/bench_loop.py swaps it to compare).
EXECUTOR: Callable[[], Executor] = EventsExecutor

Spin = Callable[[Executor, Node, Callable[[], bool]], None]


def spin_until_stopped(executor: Executor, _node: Node,
                       running: Callable[[], bool]) -> None:
    """The default spin: ``spin_once`` until SIGINT/SIGTERM or shutdown."""
    while running():
        executor.spin_once(timeout_sec=0.1)


_rewritten: list[int] = []  # memfds of params files rewritten for rcl (live as long as we)


def rcl_arguments(argv: Sequence[str], specs: Iterable[ParamSpec] = ()) -> list[str]:
    """``argv`` as rcl can parse it, so that a value the nodes accept never crashes rcl's
    start-up (it refuses a list mixing integers and doubles, ``-p link_lengths:=[1,0.8]``,
    with a traceback, while ``arm-sim urdf`` takes it):

    * a ``-p`` rule whose list mixes integers and doubles is given to rcl as doubles; one
      mixing other types (``[a, 1]``) is left out for rcl: the node reads every ``-p``
      rule itself (:func:`declare_parameters`) and refuses it with the reason the others
      give;
    * a ``--params-file`` with such lists is given to rcl as a rewritten copy (in memory:
      nothing on disk); a list mixing other types raises :class:`ConfigError` naming the
      parameter and, for one of ``specs``, the reason :meth:`ParamSpec.check` gives.
    """
    table = {spec.name: spec for spec in specs}
    out: list[str] = []
    for arg, value, flag in walk_ros_args(argv):
        if not flag or value is None:
            out.append(arg)
        elif arg == '--params-file':
            out += [arg, _rcl_params_file(value, table)]
        elif ':=' not in value:
            out += [arg, value]
        else:
            target, text = value.split(':=', 1)
            rule = rcl_rule_value(text)
            if rule is not None:
                out += [arg, f'{target}:={rule}']
    return out


def _rcl_params_file(path: str, table: dict[str, ParamSpec]) -> str:
    try:
        with open(path, encoding='utf-8') as f:
            text = f.read()
    except (OSError, UnicodeDecodeError):
        return path  # rcl's to refuse
    fixed, mixed = rcl_params_file(text)
    if mixed:
        reasons = []
        for name, value in mixed:
            spec = table.get(name)
            reason = spec.check(spec.as_declared(value)) if spec is not None else None
            reasons.append(reason or f'{name} must hold values of one type, got {value!r}')
        raise ConfigError(f'params file {path!r}: ' + '; '.join(reasons))
    if fixed is None:
        return path
    fd = os.memfd_create('params.yaml')
    os.write(fd, fixed.encode())
    _rewritten.append(fd)
    return f'/proc/self/fd/{fd}'


def run_node(factory: Callable[[], Node | list[Node]], *, prog: str, summary: str,
             specs: Iterable[ParamSpec], args: list[str] | None = None,
             spin: Spin | None = None,
             executor_type: Callable[[], Executor] | None = None) -> int:
    """Jazzy-style main: init, spin until Ctrl-C / SIGTERM / shutdown, destroy, shutdown.

    The executor is rclpy's EventsExecutor, spun with ``spin_once``: measured in
    bench/bench_loop.py it halves the CPU per message and doubles the lockstep rate
    against SingleThreadedExecutor (its ``spin()`` hangs with these wheels, so ``spin``
    functions loop on ``spin_once``). SIGINT and SIGTERM set a flag the loop checks: with
    rclpy's own handlers a busy ``spin_once(0)`` loop never saw the shutdown, and a
    shutdown racing a callback made rclpy raise from ``take_message`` (exit code 1).
    ``executor_type`` overrides the executor (the recorder keeps SingleThreadedExecutor:
    its raw subscriptions and message-lost events misbehave under EventsExecutor).
    Refused start-up parameters print one line and return 2. ``factory`` may return several
    nodes: they are composed in this one process and spun by one executor. Every node is
    guarded (:func:`guard_messages`): a bad ``clock`` or a message its callback fails on is
    dropped and reported, never the end of the node.
    """
    argv = sys.argv[1:] if args is None else args
    own = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    if '-h' in own or '--help' in own:
        try:
            print_help(prog, summary, specs)
        except BrokenPipeError:  # e.g. piped into head
            sys.stdout = None
        return EXIT_OK
    stop = []
    _user_args[:] = argv
    try:
        rcl_args = rcl_arguments(argv, specs)
        rclpy.init(args=[prog, *rcl_args], signal_handler_options=SignalHandlerOptions.NO)
    except (ConfigError, RCLError) as exc:
        reason = ' '.join(str(exc).split()).split(', at /')[0]  # one line, no C sources
        print(f'{prog}: refused parameters: {reason}', file=sys.stderr)
        return EXIT_USAGE
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.append(True))
    watch_parent()

    def running() -> bool:
        return not stop and rclpy.ok()

    nodes: list[Node] = []
    code = EXIT_OK
    try:
        made = factory()
        nodes = made if isinstance(made, list) else [made]
        executor = (executor_type or EXECUTOR)()
        for node in nodes:
            guard_messages(node)  # no single message stops it
            executor.add_node(node)
        (spin or spin_until_stopped)(executor, nodes[0], running)
    except ConfigError as exc:
        print(f'{prog}: refused parameters: {exc}', file=sys.stderr)
        code = EXIT_USAGE
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    return code
