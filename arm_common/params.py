"""Parameter specifications and their validation (no rclpy, nothing else of arm_sim).

Each :class:`ParamSpec` knows its default, unit, valid range and whether it may change at
run time; :meth:`ParamSpec.check` returns the reason a value is refused, or None.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import yaml


@dataclass(frozen=True)
class ParamSpec:
    """One node parameter.

    ``kind`` is one of ``'double'``, ``'doubles'`` (array), ``'string'``, ``'strings'``,
    ``'int'``, ``'bool'``. ``length`` fixes an array's length; ``minimum``/``maximum``
    bound every number (``strict_min`` makes the minimum exclusive); ``choices`` lists the
    allowed strings; ``hints`` gives the reason for known refused strings (e.g. a removed
    mode); ``allow_inf`` accepts -inf / inf (written ``.inf`` in YAML) as "no limit";
    ``unique`` refuses a list that repeats a value (joint names); ``allow_empty`` accepts
    an empty string (a free string is otherwise refused empty); ``relation`` checks the
    value against the other parameters (:func:`resolve`).
    """

    name: str
    kind: str
    default: Any
    description: str
    unit: str = ''
    minimum: float | None = None
    maximum: float | None = None
    strict_min: bool = False
    choices: tuple[str, ...] | None = None
    length: int | None = None
    read_only: bool = False
    hints: tuple[tuple[str, str], ...] = ()  # (refused value, the reason given for it)
    allow_inf: bool = False
    #: One value per joint of the robot (the model sets how many): not given, the default
    #: for ``n`` joints is :meth:`default_for`; given, it must have ``n`` values (an empty
    #: default, as the controller's ``control_model.*``, also accepts an empty list: "unset").
    per_joint: bool = False
    #: What :meth:`default_for` puts on joints beyond the default's length: a value, or a
    #: function of the 0-based joint index; None repeats the default's last value.
    fill: Any = None
    unique: bool = False
    allow_empty: bool = False
    #: The reason this parameter's value does not fit the others (every parameter's value
    #: by name, as declared and sized to the joints), or None: what no single value shows
    #: (a lower limit above the upper, an initial state beyond the runaway envelope). Run
    #: by :func:`resolve` at start and by the nodes on every run-time change.
    relation: Callable[[Mapping[str, Any]], str | None] | None = None

    def doc(self) -> str:
        """The description with unit, range and mutability, as shown by parameter tools."""
        parts = [self.description]
        if self.unit:
            parts.append(f'[{self.unit}]')
        if self.choices:
            parts.append('one of: ' + ', '.join(self.choices))
        if self.minimum is not None or self.maximum is not None:
            lo = '-inf' if self.minimum is None else f'{self.minimum:g}'
            hi = 'inf' if self.maximum is None else f'{self.maximum:g}'
            parts.append(f"range {'(' if self.strict_min else '['}{lo}, {hi}]")
        if self.length:
            parts.append(f'{self.length} values')
        if self.per_joint:
            parts.append('one value per joint')
        parts.append('read-only' if self.read_only else 'changeable at run time')
        return ' '.join(parts)

    def check(self, value: Any) -> str | None:
        """Reason ``value`` is refused for this parameter, or None if it is valid."""
        if self.kind in ('doubles', 'strings'):
            if isinstance(value, (str, bytes)) or not hasattr(value, '__len__'):
                return f'{self.name} must be a list, got {value!r}'
            if self.length is not None and len(value) != self.length:
                return f'{self.name} must have {self.length} values, got {len(value)}'
            items = list(value)
            kind = 'double' if self.kind == 'doubles' else 'string'
        else:
            items, kind = [value], self.kind
        for item in items:
            reason = self._check_item(kind, item)
            if reason:
                return reason
        if self.unique and len(set(items)) != len(items):
            return f'{self.name} must not repeat a value, got {tuple(items)!r}'
        return None

    def _check_item(self, kind: str, item: Any) -> str | None:
        name = self.name
        if kind == 'string':
            if not isinstance(item, str):
                return f'{name} must be a string, got {item!r}'
            hint = dict(self.hints).get(item)
            if hint:
                return f'{name}: {hint}'
            if self.choices and item not in self.choices:
                return f"{name} must be one of {', '.join(self.choices)}; got {item!r}"
            if not self.choices and not item and not self.allow_empty:
                return f'{name} must not be empty'
            return None
        if kind == 'bool':
            return None if isinstance(item, bool) else f'{name} must be true or false'
        if isinstance(item, bool) or not isinstance(item, (int, float)):
            return f'{name} must be a number, got {item!r}'
        if kind == 'int' and not isinstance(item, int):
            return f'{name} must be an integer, got {item!r}'
        if not math.isfinite(item) and not (self.allow_inf and math.isinf(item)):
            return f'{name} must be finite, got {item!r}'
        unit = f' {self.unit}' if self.unit else ''
        if self.minimum is not None:
            if self.strict_min and not item > self.minimum:
                return f'{name} must be > {self.minimum:g}{unit}, got {item!r}'
            if not self.strict_min and item < self.minimum:
                return f'{name} must be >= {self.minimum:g}{unit}, got {item!r}'
        if self.maximum is not None and item > self.maximum:
            return f'{name} must be <= {self.maximum:g}{unit}, got {item!r}'
        return None

    def default_for(self, n: int) -> Any:
        """The default of a per-joint parameter for a robot of ``n`` joints: the default's
        first ``n`` values, the joints beyond them taking :attr:`fill` (for two joints, the
        default itself). An empty default stays empty ("unset")."""
        default = list(self.default)
        if not self.per_joint or not default or len(default) == n:
            return default
        extra = [self.fill(i) if callable(self.fill)
                 else default[-1] if self.fill is None else self.fill
                 for i in range(len(default), n)]
        return (default + extra)[:n]

    def joint_count_reason(self, value: Any, n: int) -> str | None:
        """Why a given ``value`` of this per-joint parameter does not fit ``n`` joints, or
        None (an empty value of a parameter whose default is empty means unset)."""
        if not self.per_joint or len(value) == n or (not value and self.default == []):
            return None
        return (f'{self.name} has {len(value)} values but the robot has {n} joints '
                f'(give {n} values, or leave it out for the default of each joint)')

    def as_declared(self, value: Any) -> Any:
        """``value`` with integers given for a double (or doubles) parameter made floats, as
        a user typing ``5`` or ``[200, 100]`` means them; anything else unchanged (a wrong
        type is :meth:`check`'s to refuse). An unset value (None, what an empty list in a
        params file loads as) is the default of a parameter whose default is empty."""
        if value is None and self.kind in ('doubles', 'strings') and self.default == []:
            return []
        if self.kind == 'double' and _is_int(value):
            return float(value)
        if (self.kind == 'doubles' and isinstance(value, Sequence)
                and not isinstance(value, str) and any(_is_int(v) for v in value)
                and all(_is_int(v) or isinstance(v, float) for v in value)):
            return [float(v) for v in value]
        return value


def per_joint_defaults(specs: Sequence[ParamSpec], given: dict[str, Any], n: int
                       ) -> tuple[dict[str, Any], list[str]]:
    """The defaults of ``specs`` for a robot of ``n`` joints, and why any ``given`` value
    (name -> value, already :meth:`ParamSpec.check`-ed) of a per-joint parameter does not
    fit ``n`` joints: the one place the rule "a per-joint parameter not given takes its
    per-joint default for every joint; given with the wrong length, it is refused" lives."""
    defaults, reasons = {}, []
    for spec in specs:
        defaults[spec.name] = spec.default_for(n) if spec.per_joint else spec.default
        if spec.name in given:
            reason = spec.joint_count_reason(given[spec.name], n)
            if reason:
                reasons.append(reason)
    return defaults, reasons


def resolve(specs: Sequence[ParamSpec], given: Mapping[str, Any],
            joints: Callable[[dict[str, Any]], int] | None = None) -> dict[str, Any]:
    """Every parameter's value for the ``given`` ones (name -> value, e.g. from a params
    file or ``-p``; the others take their defaults), or ValueError naming every refused
    value: the one place a node's start-up and ``arm-sim urdf`` validate parameters.

    In order: each given value as declared (:meth:`ParamSpec.as_declared`: integers for
    doubles are doubles) and checked (:meth:`ParamSpec.check`); then ``joints`` (the
    values -> the robot's joint count, raising ValueError with the reason) sizes the
    per-joint parameters (:func:`per_joint_defaults`); then each :attr:`ParamSpec.relation`
    sees every value. A stage runs only if the one before refused nothing.
    """
    specs = tuple(specs)
    table = {spec.name: spec for spec in specs}
    values = {name: table[name].as_declared(v) if name in table else v
              for name, v in given.items()}
    reasons = [r for r in (table[name].check(v) for name, v in values.items()
                           if name in table) if r]
    defaults = {spec.name: spec.default for spec in specs}
    if not reasons and joints is not None:
        try:
            n = joints({**defaults, **values})
        except ValueError as exc:
            raise ValueError(str(exc)) from None
        defaults, reasons = per_joint_defaults(specs, values, n)
    if reasons:
        raise ValueError('; '.join(reasons))
    resolved = {**defaults, **values}
    reasons = relation_reasons(specs, resolved)
    if reasons:
        raise ValueError('; '.join(reasons))
    return resolved


def relation_reasons(specs: Sequence[ParamSpec], values: Mapping[str, Any]) -> list[str]:
    """Why ``values`` (every parameter's, by name) do not fit together: the reason of each
    spec's :attr:`~ParamSpec.relation` that refuses. A relation that fails (it should
    not: :meth:`ParamSpec.check` and the joint count run first) refuses, naming why."""
    reasons = []
    for spec in specs:
        if spec.relation is None:
            continue
        try:
            reason = spec.relation(values)
        except Exception as exc:  # a value no check foresaw: refused, never a crash
            reason = f'{spec.name} cannot be checked against the other parameters: {exc!r}'
        if reason:
            reasons.append(reason)
    return reasons


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


#: The ``--ros-args`` flags that take a value (the next argument).
VALUE_FLAGS = ('-p', '--param', '--params-file')


def walk_ros_args(argv: Sequence[str]) -> Iterator[tuple[str, str | None, bool]]:
    """``argv`` one item at a time as ``(arg, value, flag)``: a ``-p``/``--param`` or
    ``--params-file`` inside a ``--ros-args`` section (up to ``--``) comes with the argument
    after it as ``value`` (None if ``argv`` ends there) and ``flag`` True; every other
    argument alone, ``(arg, None, False)``. The one reading of rcl's command line that
    :func:`command_line_parameters` and :func:`arm_common.node.rcl_arguments` share."""
    in_ros_args = False
    it = iter(argv)
    for arg in it:
        if arg == '--ros-args':
            in_ros_args = True
        elif arg == '--':
            in_ros_args = False
        elif in_ros_args and arg in VALUE_FLAGS:
            yield arg, next(it, None), True
            continue
        yield arg, None, False


def command_line_parameters(argv: Sequence[str], node_name: str,
                            fully_qualified_name: str) -> dict[str, Any]:
    """The ``-p [node:]name:=value`` rules in ``argv``'s ``--ros-args`` sections that apply
    to a node, the later winning, with values read as YAML as rcl reads them.

    rcl files a bare ``-p`` rule under the ``/**`` wildcard, and rclpy lets any params-file
    entry naming the node beat a wildcard, so on its own ``-p law:=pid --params-file
    config/arm.yaml`` keeps the file's law. The nodes apply these rules last instead:
    a value typed on the command line is the one the user means.
    """
    rules: dict[str, Any] = {}
    for arg, rule, flag in walk_ros_args(argv):
        if flag and arg != '--params-file' and rule is not None and ':=' in rule:
            target, text = rule.split(':=', 1)
            node, _, name = target.rpartition(':')
            if not node or node in (node_name, fully_qualified_name):
                rules[name] = _yaml_value(text)
    return rules


def _yaml_value(text: str) -> Any:
    """A command-line parameter value as rcl reads it: YAML, where an unquoted ``1e3`` is a
    number (PyYAML alone reads it as a string) and a quoted ``"5"`` a string."""
    try:
        node = yaml.compose(text)
    except yaml.YAMLError:
        return text
    if node is None:
        return None
    items = node.value if isinstance(node, yaml.SequenceNode) else None
    if items is None:
        return _scalar(node)
    return [_scalar(item) for item in items]


def _scalar(node: yaml.Node) -> Any:
    if not isinstance(node, yaml.ScalarNode):
        return yaml.safe_load(yaml.serialize(node))
    value = yaml.safe_load(yaml.serialize(node))
    if isinstance(value, str) and node.style is None:
        try:
            return float(value)
        except ValueError:
            return value
    return value


def _kind(value: Any) -> str:
    """rcl's type of one parsed YAML item: bool, integer, double or string."""
    if isinstance(value, bool):
        return 'bool'
    if isinstance(value, int):
        return 'integer'
    if isinstance(value, float):
        return 'double'
    return 'string' if isinstance(value, str) else type(value).__name__


def _fix_sequence(node: yaml.SequenceNode) -> bool | None:
    """Make a flow or block sequence of scalars rcl can read: integers among doubles
    rewritten as doubles (True: changed), nothing to do (False), or None: it mixes other
    types (``[a, 1]``, ``[true, 1]``), which no rcl parameter can hold."""
    if not node.value or not all(isinstance(i, yaml.ScalarNode) for i in node.value):
        return False
    values = [_scalar(i) for i in node.value]
    kinds = {_kind(v) for v in values}
    if len(kinds) < 2:
        return False
    if kinds != {'integer', 'double'}:
        return None
    for item, value in zip(node.value, values):
        if isinstance(value, int):
            item.value, item.tag, item.style = repr(float(value)), 'tag:yaml.org,2002:float', None
    return True


def rcl_rule_value(text: str) -> str | None:
    """A ``-p name:=value`` rule's value as rcl can parse it: ``text`` itself, a list mixing
    integers and doubles (``[1, 0.8]``, which rcl refuses: "Sequence should be of same
    type") written as doubles (``[1.0, 0.8]``), or None for a list mixing other types
    (``[a, 1]``) or text that is no YAML (``[1, 2``): no rcl parameter holds it, so the
    node's own check must refuse it (:func:`command_line_parameters` reads the rule for
    the nodes, as a string where it is no YAML)."""
    try:
        node = yaml.compose(text)
    except yaml.YAMLError:
        return None
    if not isinstance(node, yaml.SequenceNode):
        return text
    fixed = _fix_sequence(node)
    if fixed is None:
        return None
    if not fixed:
        return text
    return '[' + ', '.join(i.value if i.style is None else repr(i.value)
                           for i in node.value) + ']'


def rcl_params_file(text: str) -> tuple[str | None, list[tuple[str, Any]]]:
    """A params file's ``text`` as rcl can parse it: (the text with every list mixing
    integers and doubles written as doubles, or None when no list needed it; the (name,
    value) of every list mixing other types, which rcl cannot parse at all). Everything
    else is left exactly as written (the YAML is re-emitted from its node graph, scalars
    in their own styles). Text that is not YAML is rcl's to refuse: (None, [])."""
    try:
        root = yaml.compose(text)
    except yaml.YAMLError:
        return None, []
    changed = False
    mixed: list[tuple[str, Any]] = []

    def walk(node: yaml.Node, name: str) -> None:
        nonlocal changed
        if isinstance(node, yaml.MappingNode):
            for key, value in node.value:
                walk(value, str(key.value) if isinstance(key, yaml.ScalarNode) else name)
        elif isinstance(node, yaml.SequenceNode):
            fixed = _fix_sequence(node)
            if fixed is None:
                mixed.append((name, [_scalar(i) for i in node.value]))
            changed = changed or bool(fixed)

    if root is not None:
        walk(root, '')
    return (yaml.serialize(root) if changed else None), mixed
