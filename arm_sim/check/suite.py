"""A check suite: scenarios and the thresholds each is graded on, read from YAML (pure).

The format is documented in docs/check.md and by example in config/checks/lecture.yaml (the
default suite). Every error names the file, the entry (``scenarios[2] (line_fast)``), the
key and the bad value: :class:`SuiteFileError`. A scenario's ``simulator`` values are checked
against the simulator node's own parameter specs (importing that module, and so rclpy, then).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from arm_common.yamlfile import YamlFileError, read_yaml

#: Bounds on a suite file (read with arm_common.yamlfile: no aliases, bounded nesting).
MAX_SUITE_BYTES = 1_000_000
MAX_SUITE_DEPTH = 16
PERIOD = 0.01  # s: the control period of config/arm.yaml (publish_rate 100 Hz)
N_JOINTS = 2  # the suites drive the 2-R arm of config/arm.yaml


@dataclass(frozen=True)
class GradedMetric:
    """A metric a threshold can be set on: ``name``, its SI ``unit``, how it is shown
    (``scale`` x value in ``shown_unit``), per joint or not, which scenarios have it
    (``when``: ``all``, ``regulation``, ``straight_line`` (the last goal's mode) or
    ``push``) and its meaning. A metric passes when its value <= the threshold.

    ``source`` names the :mod:`arm_bag.metrics` metric it grades (``arm-sim analyze``'s
    figure of the scenario's bag), taken from ``scope``: ``segment`` (the last segment),
    ``run`` (the whole run; a per-joint source graded as one value takes the largest
    joint) or ``push`` (the largest over the pushes). None: the check's own figure
    (``final_tip_error``, which needs the goal). ``undefined`` is what an undefined value
    of a measured source is shown as (it fails)."""

    name: str
    unit: str
    shown_unit: str
    scale: float
    per_joint: bool
    when: str
    meaning: str
    source: str | None = None
    scope: str | None = None
    undefined: str = 'not measured'


METRICS: dict[str, GradedMetric] = {m.name: m for m in (
    GradedMetric('final_tip_error', 'm', 'mm', 1e3, False, 'all',
                 'distance of the tip from the last goal at the end of the scenario (the '
                 "true state when the sensors are noisy); not analyze's per-joint "
                 'final_error [rad]'),
    GradedMetric('line_deviation', 'm', 'mm', 1e3, False, 'straight_line',
                 "largest distance of the tip from the last goal's commanded segment "
                 '(arm-sim analyze deviation_max)', source='deviation_max', scope='segment'),
    GradedMetric('settling_time', 's', 's', 1.0, False, 'regulation',
                 "from the last goal's start until every joint stays within 2% of its step "
                 '(arm-sim analyze settling_time_overall; never settling fails)',
                 source='settling_time_overall', scope='segment', undefined='never settles'),
    GradedMetric('peak_torque', 'N m', 'N m', 1.0, True, 'all',
                 'largest |applied torque| per joint over the scenario', source='torque_peak',
                 scope='run'),
    GradedMetric('saturation', 'fraction', '%', 100.0, False, 'all',
                 'largest fraction of the control periods a joint spent at its effort limit',
                 source='saturated_fraction', scope='run'),
    GradedMetric('push_deviation', 'm', 'mm', 1e3, False, 'push',
                 'largest distance of the tip from where it should be after a push',
                 source='peak_deviation', scope='push'),
    GradedMetric('push_recovery', 's', 's', 1.0, False, 'push',
                 'time from a push until the tip is back within max(1 mm, 5% of its peak '
                 'deviation) and stays (never coming back fails)', source='recovery_time',
                 scope='push', undefined='never back'),
)}
#: Old metric names a suite file may still use: old -> new (read with a one-line note).
RENAMED = {'final_error': 'final_tip_error'}


def graded_metrics_markdown() -> str:
    """The docs' table of :data:`METRICS` (docs/check.md holds it verbatim; a test checks)."""
    when = {'all': 'all', 'regulation': 'last goal a regulation',
            'straight_line': 'last goal a straight line', 'push': 'with pushes'}
    scope = {'segment': 'of the last segment', 'run': 'of the run',
             'push': 'of each push, the largest'}
    rows = ['| metric | unit | for | `arm-sim analyze` metric | meaning |',
            '|---|---|---|---|---|']
    for m in METRICS.values():
        unit = f'{m.unit}, per joint (one value: each)' if m.per_joint else m.unit
        source = '-'
        if m.source and m.scope:
            largest = ', largest joint' if m.scope == 'run' and not m.per_joint else ''
            source = f'`{m.source}` {scope[m.scope]}{largest}'
        meaning = m.meaning.replace('|', '\\|')
        rows.append(f'| `{m.name}` | {unit} | {when[m.when]} | {source} | {meaning} |')
    return '\n'.join(rows) + '\n'


MODES = ('regulation', 'straight_line')
#: Simulator parameters a scenario may set (sensors and actuators: read-only parameters,
#: so each scenario runs on a simulator of its own).
SIMULATOR_KEYS = ('position_noise', 'velocity_noise', 'encoder_resolution', 'sensing_delay',
                  'actuation_delay', 'noise_seed')
DEFAULTS = {'settle': 1.0, 'budget': 60.0, 'start_hold': 0.5}
NAME = re.compile(r'^[A-Za-z0-9_.-]{1,64}$')


class SuiteFileError(ValueError):
    """A suite that cannot be used; the message names the file, entry, key and value."""


@dataclass(frozen=True)
class Goal:
    """One goal of a scenario: the tip position [m], how the planner moves there, and the
    simulated time [s] it is sent at (None: the previous motion's end plus ``settle``)."""

    tip: tuple[float, float]
    mode: str = 'regulation'
    duration: float = 0.0  # s; 0 = the planner's speed limits decide
    at: float | None = None


@dataclass(frozen=True)
class Scenario:
    """One scenario: where the arm starts, the goals, the plant's extras and thresholds."""

    name: str
    description: str
    goals: tuple[Goal, ...]
    thresholds: dict[str, Any]
    start: tuple[float, float] | None = None  # joint angles [rad]; None: config/arm.yaml's
    start_tip: tuple[float, float] | None = None  # or the tip [m], elbow down (q2 > 0)
    settle: float = DEFAULTS['settle']  # s simulated after the last motion
    budget: float = DEFAULTS['budget']  # s wall clock for the whole scenario
    start_hold: float = DEFAULTS['start_hold']  # s simulated before the first goal
    simulator: dict[str, Any] = field(default_factory=dict)
    disturbances: dict[str, Any] | None = None

    @property
    def last_mode(self) -> str:
        return self.goals[-1].mode

    def applies(self, metric: str) -> bool:
        when = METRICS[metric].when
        if when == 'push':
            return bool(self.disturbances and self.disturbances.get('pushes'))
        return when == 'all' or when == self.last_mode


@dataclass(frozen=True)
class Suite:
    """A suite: its name, the file it came from, its scenarios, and ``notes``: one line
    each for what the file should change (an old metric name, :data:`RENAMED`)."""

    name: str
    path: str
    scenarios: tuple[Scenario, ...]
    notes: tuple[str, ...] = ()

    def select(self, names: list[str]) -> Suite:
        """The suite with only the scenarios ``names`` (SuiteFileError naming an unknown)."""
        known = {s.name: s for s in self.scenarios}
        for n in names:
            if n not in known:
                raise SuiteFileError(f'{self.path}: no scenario {n!r} (it has: '
                                     f"{', '.join(known)})")
        return Suite(self.name, self.path, tuple(s for s in self.scenarios if s.name in names),
                     self.notes)


def default_suite_path() -> Path:
    """The shipped default suite, config/checks/lecture.yaml."""
    from arm_sim.launcher import config_file

    return config_file('checks/lecture.yaml')


def load_suite(path: str | Path | None = None) -> Suite:
    """Read and validate the suite file at ``path`` (default: the lecture's)."""
    path = Path(path) if path is not None else default_suite_path()
    try:
        data = read_yaml(path, max_bytes=MAX_SUITE_BYTES, max_depth=MAX_SUITE_DEPTH,
                         what='a suite is a short list of scenarios')
    except YamlFileError as exc:
        raise SuiteFileError(f'{path}: {exc}') from None
    return parse_suite(data, str(path))


def parse_suite(data: object, source: str = '<suite>') -> Suite:
    """Validate a parsed suite (a mapping as the YAML file holds it)."""
    if not isinstance(data, dict):
        raise SuiteFileError(f'{source}: a suite is a mapping with "scenarios", got '
                             f'{type(data).__name__}')
    unknown = [k for k in data if k not in ('name', 'description', 'defaults', 'scenarios')]
    if unknown:
        raise SuiteFileError(f'{source}: unknown key {unknown[0]!r} (a suite has name, '
                             'description, defaults, scenarios)')
    defaults = data.get('defaults') or {}
    if not isinstance(defaults, dict):
        raise SuiteFileError(f'{source}: defaults must be a mapping, got {defaults!r:.60}')
    base: dict[str, Any] = dict(DEFAULTS)
    for key, value in defaults.items():
        if key == 'thresholds':
            continue
        if key not in DEFAULTS:
            raise SuiteFileError(f'{source}: defaults: unknown key {key!r} (one of '
                                 f"{', '.join([*DEFAULTS, 'thresholds'])})")
        base[key] = _positive(value, f'{source}: defaults.{key}', zero=key == 'start_hold')
    notes: list[str] = []
    base_thresholds = _thresholds(defaults.get('thresholds') or {}, f'{source}: defaults',
                                  notes)
    items = data.get('scenarios')
    if not isinstance(items, list) or not items:
        raise SuiteFileError(f'{source}: scenarios must be a non-empty list, got {items!r:.60}')
    scenarios = []
    for k, item in enumerate(items):
        label = f'{source}: scenarios[{k}]'
        if isinstance(item, dict) and isinstance(item.get('name'), str):
            label += f" ({item['name']})"
        scenarios.append(_scenario(item, label, base, base_thresholds, notes))
    names = [s.name for s in scenarios]
    dup = next((n for n in names if names.count(n) > 1), None)
    if dup:
        raise SuiteFileError(f'{source}: two scenarios are named {dup!r}')
    return Suite(str(data.get('name') or Path(source).stem), source, tuple(scenarios),
                 tuple(notes))


SCENARIO_KEYS = ('name', 'description', 'start', 'start_tip', 'goals', 'thresholds',
                 'settle', 'budget', 'start_hold', 'simulator', 'disturbances')


def _scenario(item: object, label: str, base: dict, base_thresholds: dict,
              notes: list[str]) -> Scenario:
    if not isinstance(item, dict):
        raise SuiteFileError(f'{label}: a scenario is a mapping, got {item!r:.60}')
    unknown = [k for k in item if k not in SCENARIO_KEYS]
    if unknown:
        raise SuiteFileError(f'{label}: unknown key {unknown[0]!r} (one of '
                             f"{', '.join(SCENARIO_KEYS)})")
    name = item.get('name')
    if not isinstance(name, str) or not NAME.match(name):
        raise SuiteFileError(f'{label}: name must be 1-64 letters, digits, _ . -, got '
                             f'{name!r:.60}')
    if 'start' in item and 'start_tip' in item:
        raise SuiteFileError(f'{label}: give start (joint angles, rad) or start_tip (m), '
                             'not both')
    start = _pair(item['start'], f'{label}: start', 'rad') if 'start' in item else None
    start_tip = (_pair(item['start_tip'], f'{label}: start_tip', 'm')
                 if 'start_tip' in item else None)
    values = {key: (_positive(item[key], f'{label}: {key}', zero=key == 'start_hold')
                    if key in item else base[key]) for key in DEFAULTS}
    goals = _goals(item.get('goals'), label, values['start_hold'])
    simulator = item.get('simulator') or {}
    if not isinstance(simulator, dict):
        raise SuiteFileError(f'{label}: simulator must be a mapping, got {simulator!r:.60}')
    for key in simulator:
        if key not in SIMULATOR_KEYS:
            raise SuiteFileError(f'{label}: simulator.{key}: not settable here (one of '
                                 f"{', '.join(SIMULATOR_KEYS)})")
    if simulator:
        _simulator_values(simulator, label)
    disturbances = item.get('disturbances')
    if disturbances is not None:
        disturbances = _disturbances(disturbances, label)
    thresholds = {**base_thresholds, **_thresholds(item.get('thresholds') or {}, label, notes)}
    scenario = Scenario(name=name, description=str(item.get('description') or ''),
                        goals=goals, thresholds={}, start=start, start_tip=start_tip,
                        simulator=dict(simulator), disturbances=disturbances, **values)
    # A suite-wide default that does not apply to this scenario is dropped; one the
    # scenario sets itself must apply.
    own = {RENAMED.get(k, k): v for k, v in (item.get('thresholds') or {}).items()}
    for metric in list(thresholds):
        if not scenario.applies(metric):
            if metric in own:
                raise SuiteFileError(
                    f'{label}: thresholds.{metric}: only for '
                    f'{METRICS[metric].when} scenarios (the last goal of this one is '
                    f'{scenario.last_mode}' + (', and it has no pushes)' if
                                               METRICS[metric].when == 'push' else ')'))
            del thresholds[metric]
    if not thresholds:
        raise SuiteFileError(f'{label}: no thresholds: nothing to grade')
    return Scenario(**{**scenario.__dict__, 'thresholds': thresholds})


def _goals(items: object, label: str, start_hold: float) -> tuple[Goal, ...]:
    if not isinstance(items, list) or not items:
        raise SuiteFileError(f'{label}: goals must be a non-empty list, got {items!r:.60}')
    goals = []
    last_at = -math.inf
    for k, g in enumerate(items):
        where = f'{label}: goals[{k}]'
        if not isinstance(g, dict):
            raise SuiteFileError(f'{where}: a goal is a mapping {{tip: [x, y], ...}}, got '
                                 f'{g!r:.60}')
        unknown = [key for key in g if key not in ('tip', 'mode', 'duration', 'at')]
        if unknown:
            raise SuiteFileError(f'{where}: unknown key {unknown[0]!r} (one of tip, mode, '
                                 'duration, at)')
        if 'tip' not in g:
            raise SuiteFileError(f'{where}: tip [x, y] (m) is missing')
        tip = _pair(g['tip'], f'{where}.tip', 'm')
        mode = g.get('mode', 'regulation')
        if mode not in MODES:
            raise SuiteFileError(f'{where}.mode: one of {", ".join(MODES)}, got {mode!r}')
        duration = _positive(g.get('duration', 0.0), f'{where}.duration', zero=True)
        at = None
        if g.get('at') is not None:
            at = _positive(g['at'], f'{where}.at', zero=True)
            if abs(at / PERIOD - round(at / PERIOD)) > 1e-9:
                raise SuiteFileError(f'{where}.at: {at:g} s is not a whole number of control '
                                     f'periods ({PERIOD:g} s)')
            at = round(at / PERIOD) * PERIOD
            if at < start_hold or at <= last_at:
                raise SuiteFileError(f'{where}.at: {at:g} s must be >= start_hold '
                                     f'({start_hold:g} s) and after the previous goal')
            last_at = at
        elif k == 0:
            last_at = start_hold
        goals.append(Goal(tip, mode, duration, at))
    return tuple(goals)


def _thresholds(items: object, label: str, notes: list[str]) -> dict[str, Any]:
    """The thresholds by metric name; an old name (:data:`RENAMED`) is read as the new one,
    with a line in ``notes``."""
    if not isinstance(items, dict):
        raise SuiteFileError(f'{label}: thresholds must be a mapping metric: value, got '
                             f'{items!r:.60}')
    out: dict[str, Any] = {}
    for metric, value in items.items():
        where = f'{label}: thresholds.{metric}'
        if metric in RENAMED:
            new = RENAMED[metric]
            if new in items:
                raise SuiteFileError(f'{where}: the old name of {new}, which is given too: '
                                     'give one')
            notes.append(f'{where}: {metric} is deprecated, now {new} (read as it); '
                         'rename it')
            metric = new
        if metric not in METRICS:
            raise SuiteFileError(f'{where}: unknown metric (one of {", ".join(METRICS)})')
        m = METRICS[metric]
        if m.per_joint and isinstance(value, list):
            if len(value) != N_JOINTS:
                raise SuiteFileError(f'{where}: {len(value)} values for {N_JOINTS} joints')
            out[metric] = [_positive(v, where, unit=m.unit) for v in value]
        else:
            v = _positive(value, where, unit=m.unit)
            out[metric] = [v] * N_JOINTS if m.per_joint else v
        if metric == 'saturation' and max(_as_list(out[metric])) > 1:
            raise SuiteFileError(f'{where}: a fraction in [0, 1], got {value!r}')
    return out


def _as_list(v: Any) -> list:
    return v if isinstance(v, list) else [v]


def _disturbances(data: object, label: str) -> dict:
    """Validated as the simulator will read it (arm_dynamics.disturbance)."""
    from arm_dynamics.disturbance import DisturbanceError, Disturbances

    try:
        Disturbances.from_mapping(data, n=N_JOINTS, joint_names=['joint1', 'joint2'],
                                  physics_step_ns=1_000_000, source=f'{label}: disturbances')
    except DisturbanceError as exc:
        raise SuiteFileError(str(exc)) from None
    assert isinstance(data, dict)
    return data


def _simulator_values(simulator: dict, label: str) -> None:
    """Check a scenario's ``simulator`` values against the simulator's own parameter specs
    (:data:`arm_dynamics.simulator_node.SIM_PARAMS`: type, range, one value per joint of
    the :data:`N_JOINTS`-joint arm, relations), as the node checks them at start-up: a
    value it would refuse is a SuiteFileError naming the scenario, key and value, never a
    failed scenario. Imports the node module (and so rclpy) only when a scenario sets one."""
    from arm_common.params import relation_reasons
    from arm_dynamics.simulator_node import SIM_PARAMS

    specs = {s.name: s for s in SIM_PARAMS if s.name in SIMULATOR_KEYS}
    values = {}
    for key, value in simulator.items():
        spec = specs[key]
        declared = spec.as_declared(value)
        reason = spec.check(declared)
        if reason is None and spec.per_joint:
            reason = spec.joint_count_reason(declared, N_JOINTS)
        if reason:
            raise SuiteFileError(f'{label}: simulator.{key}: {value!r:.60} refused by the '
                                 f'simulator: {reason}')
        values[key] = declared
    resolved = {**{s.name: s.default_for(N_JOINTS) if s.per_joint else s.default
                   for s in specs.values()}, **values}
    for key in values:
        reasons = relation_reasons([specs[key]], resolved)
        if reasons:
            raise SuiteFileError(f'{label}: simulator.{key}: {simulator[key]!r:.60} refused '
                                 f'by the simulator: {reasons[0]}')


def _number(value: object, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SuiteFileError(f'{where}: a number, got {value!r:.60}')
    if not math.isfinite(value):
        raise SuiteFileError(f'{where}: a finite number, got {value!r}')
    return float(value)


def _positive(value: object, where: str, zero: bool = False, unit: str = 's') -> float:
    v = _number(value, where)
    if v < 0 or (v == 0 and not zero):
        raise SuiteFileError(f'{where}: must be {">=" if zero else ">"} 0 {unit}, got '
                             f'{value!r}')
    return v


def _pair(value: object, where: str, unit: str) -> tuple[float, float]:
    if not isinstance(value, list) or len(value) != 2:
        raise SuiteFileError(f'{where}: two numbers [{unit}], got {value!r:.60}')
    a, b = (_number(v, where) for v in value)
    return (a, b)
