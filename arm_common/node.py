"""rclpy helpers shared by the arm_sim nodes: parameters from specs, diagnostics, main().

Only node modules import this; the maths stays in the ROS-free packages.
"""

from __future__ import annotations

import math
import signal
import sys
from collections.abc import Callable, Iterable
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
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from arm_common.params import ParamSpec, command_line_parameters
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


def declare_parameters(node: Node, specs: Iterable[ParamSpec]) -> dict[str, Any]:
    """Declare ``specs`` on ``node`` and return their values; raise :class:`ConfigError`
    listing every refused value.

    Start-up values come from params files and ``--ros-args -p``, with ``-p`` winning for
    every parameter (rclpy alone lets a file entry naming the node beat a ``-p``), integers
    given for doubles taken as doubles, and an empty list (which a params file loads as
    unset) as the empty default. Numeric parameters carry their range
    (``FloatingPointRange`` / ``IntegerRange``) for ``ros2 param describe``.
    """
    specs = tuple(specs)
    # rclpy keeps the start-up values (params files, then -p) in this dict and reads it in
    # declare_parameter; it is what the public ``parameter_overrides`` argument extends.
    overrides: dict[str, Parameter] = node._parameter_overrides  # noqa: SLF001
    from_command_line = command_line_parameters(_user_args, node.get_name(),
                                                node.get_fully_qualified_name())
    for spec in specs:
        if spec.name in from_command_line:
            overrides[spec.name] = Parameter(spec.name, value=from_command_line[spec.name])
        if spec.name in overrides:
            value = spec.as_declared(overrides[spec.name].value)
            overrides[spec.name] = Parameter(spec.name, value=value)
    own = {spec.name for spec in specs}
    for name, value in from_command_line.items():  # rclpy's own, e.g. use_sim_time
        if name not in own and node.has_parameter(name) and (
                node.get_parameter(name).value != value):
            node.set_parameters([Parameter(name, value=value)])
    values, reasons = {}, []
    for spec in specs:
        reason = spec.check(overrides[spec.name].value) if spec.name in overrides else None
        if reason:  # refused before rclpy's own range check can raise on it
            reasons.append(reason)
            continue
        value = node.declare_parameter(spec.name, spec.default, descriptor(spec)).value
        values[spec.name] = spec.as_declared(value)
    if reasons:
        raise ConfigError('; '.join(reasons))
    return values


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """The ROS descriptor of a parameter: its doc, read-only flag and numeric range."""
    desc = ParameterDescriptor(name=spec.name, description=spec.doc(),
                               read_only=spec.read_only, dynamic_typing=True)
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
                         apply: Callable[[dict[str, Any]], None]) -> None:
    """Validate run-time parameter changes against ``specs`` (then ``validate``, which sees
    the changed values and may refuse with a reason), and ``apply`` accepted ones."""
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


class Diagnostics:
    """One DiagnosticStatus for a node on ``/diagnostics``: a summary published every
    second, and rejected input, faults and notable events at once (problems throttled per
    kind, every occurrence counted).

    Every status is stamped with the wall clock (system time), whatever ``use_sim_time``
    says: diagnostics report *when* something happened to the person or tool watching.
    The simulated time it happened at is the key ``sim_time`` [s] (from ``sim_time()``,
    when it returns a value). Immediate reports carry the key ``event`` = their kind, and
    any further key-values given, so tools read them without parsing the message.
    """

    def __init__(self, node: Node, period: float = 1.0,
                 sim_time: Callable[[], float | None] | None = None) -> None:
        self.node = node
        self.pub = node.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.name = node.get_fully_qualified_name()
        self.level = 'OK'
        self.message = 'starting'
        self.values: dict[str, Any] = {}
        self.counts: dict[str, int] = {}
        self.last_problem: dict[str, str] = {}
        self.throttle = Throttle(period)
        self.sim_time = sim_time
        self.wall = Clock(clock_type=ClockType.SYSTEM_TIME)
        node.create_timer(period, self.publish, clock=steady_clock())

    def set(self, level: str, message: str, **values: Any) -> None:
        """Set the summary (published with the next periodic report)."""
        self.level, self.message = level, message
        self.values.update(values)

    def problem(self, kind: str, reason: str, level: str = 'WARN', **values: Any) -> None:
        """Report rejected input or a fault now: log + /diagnostics, at most once a second
        per ``kind``; every occurrence is counted."""
        self.counts[kind] = self.counts.get(kind, 0) + 1
        self.last_problem[kind] = reason
        if self.throttle.ready(kind):
            held = self.throttle.take_suppressed(kind)
            more = f' ({held} more since last report)' if held else ''
            log = self.node.get_logger()
            # Two call sites: rclpy refuses a severity change at one call site.
            if level == 'ERROR':
                log.error(f'{reason}{more}')
            else:
                log.warning(f'{reason}{more}')
            self.publish(extra=(level, f'{kind}: {reason}', {'event': kind, **values}))

    def event(self, kind: str, message: str, **values: Any) -> None:
        """Publish a notable event now (level OK, counted), e.g. an accepted trajectory."""
        self.counts[kind] = self.counts.get(kind, 0) + 1
        self.publish(extra=('OK', f'{kind}: {message}', {'event': kind, **values}))

    def publish(self, extra: tuple[str, str, dict[str, Any]] | None = None) -> None:
        level, message, own = extra or (self.level, self.message, {})
        sim = self.sim_time() if self.sim_time else None
        values = {**({} if sim is None else {'sim_time': f'{sim:.9f}'}), **self.values,
                  **own}
        kv = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        kv += [KeyValue(key=f'{k}_count', value=str(v)) for k, v in self.counts.items()]
        kv += [KeyValue(key=f'{k}_last', value=v) for k, v in self.last_problem.items()]
        status = DiagnosticStatus(level=LEVELS[level], name=self.name, message=message,
                                  hardware_id='arm_sim', values=kv)
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.wall.now().to_msg()
        self.pub.publish(msg)


def print_help(prog: str, summary: str, specs: Iterable[ParamSpec]) -> None:
    """``--help`` for a node executable: what it does and every parameter with its unit."""
    print(f'usage: {prog} [--ros-args -p NAME:=VALUE ... --params-file FILE -r FROM:=TO]\n')
    print(summary.strip() + '\n\nparameters:')
    for s in specs:
        print(f'  {s.name} (default {s.default!r})\n      {s.doc()}')


#: The executor every node spins (bench/bench_loop.py swaps it to compare).
EXECUTOR: Callable[[], object] = EventsExecutor

Spin = Callable[[EventsExecutor, Node, Callable[[], bool]], None]


def spin_until_stopped(executor: EventsExecutor, _node: Node,
                       running: Callable[[], bool]) -> None:
    """The default spin: ``spin_once`` until SIGINT/SIGTERM or shutdown."""
    while running():
        executor.spin_once(timeout_sec=0.1)


def run_node(factory: Callable[[], Node | list[Node]], *, prog: str, summary: str,
             specs: Iterable[ParamSpec], args: list[str] | None = None,
             spin: Spin | None = None,
             executor_type: Callable[[], object] | None = None) -> int:
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
    nodes: they are composed in this one process and spun by one executor.
    """
    argv = sys.argv[1:] if args is None else args
    own = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    if '-h' in own or '--help' in own:
        try:
            print_help(prog, summary, specs)
        except BrokenPipeError:  # e.g. piped into head
            sys.stdout = None
        return 0
    stop = []
    _user_args[:] = argv
    rclpy.init(args=[prog, *argv], signal_handler_options=SignalHandlerOptions.NO)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.append(True))

    def running() -> bool:
        return not stop and rclpy.ok()

    nodes: list[Node] = []
    code = 0
    try:
        made = factory()
        nodes = made if isinstance(made, list) else [made]
        executor = (executor_type or EXECUTOR)()
        for node in nodes:
            executor.add_node(node)
        (spin or spin_until_stopped)(executor, nodes[0], running)
    except ConfigError as exc:
        print(f'{prog}: refused parameters: {exc}', file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    return code
