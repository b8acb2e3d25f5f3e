"""Parameter specifications and their validation (no rclpy, nothing else of arm_sim).

Each :class:`ParamSpec` knows its default, unit, valid range and whether it may change at
run time; :meth:`ParamSpec.check` returns the reason a value is refused, or None.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
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
    mode); ``allow_inf`` accepts -inf / inf (written ``.inf`` in YAML) as "no limit".
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
            if not self.choices and not item:
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


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


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
    in_ros_args = False
    it = iter(argv)
    for arg in it:
        if arg == '--ros-args':
            in_ros_args = True
        elif arg == '--':
            in_ros_args = False
        elif in_ros_args and arg in ('-p', '--param'):
            rule = next(it, '')
            if ':=' not in rule:
                continue
            target, text = rule.split(':=', 1)
            node, _, name = target.rpartition(':')
            if node and node not in (node_name, fully_qualified_name):
                continue
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
