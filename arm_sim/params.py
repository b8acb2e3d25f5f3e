"""Parameter specifications shared by the nodes, and their validation (no rclpy).

Each :class:`ParamSpec` knows its default, unit, valid range and whether it may change at
run time; :meth:`ParamSpec.check` returns the reason a value is refused, or None.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class ParamSpec:
    """One node parameter.

    ``kind`` is one of ``'double'``, ``'doubles'`` (array), ``'string'``, ``'strings'``,
    ``'int'``, ``'bool'``. ``length`` fixes an array's length; ``minimum``/``maximum``
    bound every number (``strict_min`` makes the minimum exclusive); ``choices`` lists the
    allowed strings; ``hints`` gives the reason for known refused strings (e.g. a removed
    mode).
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
        if not math.isfinite(item):
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


def _pair(name: str, default: tuple, description: str, unit: str, **kw) -> ParamSpec:
    return ParamSpec(name, 'doubles', list(default), description, unit, length=2,
                     read_only=True, **kw)


#: Robot description shared by every node (``/**`` in config/arm.yaml); read-only.
ROBOT_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec('joint_names', 'strings', ['joint1', 'joint2'],
              'Joint names, shoulder then elbow', length=2, read_only=True),
    _pair('link_lengths', (1.0, 0.8), 'Link lengths, joint axis to next axis / tip', 'm',
          minimum=0.0, strict_min=True, maximum=100.0),
    _pair('com_distances', (0.5, 0.4), 'Joint axis to link centre of gravity', 'm',
          minimum=0.0, maximum=100.0),
    _pair('link_masses', (2.0, 1.5), 'Link masses', 'kg', minimum=0.0, strict_min=True,
          maximum=1e4),
    _pair('link_inertias', (0.1, 0.08), 'Link inertias about the CG, normal to the plane',
          'kg m^2', minimum=0.0, maximum=1e4),
    ParamSpec('gravity', 'double', 9.81, 'Gravity magnitude, acting along -y', 'm/s^2',
              minimum=0.0, maximum=100.0, read_only=True),
    _pair('joint_damping', (0.0, 0.0), 'Viscous joint friction', 'N m s/rad', minimum=0.0,
          maximum=1e4),
    _pair('effort_limits', (60.0, 20.0), 'Joint torque limits (applied torque is clipped)',
          'N m', minimum=0.0, strict_min=True, maximum=1e6),
)


def by_name(specs: tuple[ParamSpec, ...]) -> dict[str, ParamSpec]:
    """Index specs by parameter name."""
    return {s.name: s for s in specs}
