"""Grade one scenario: its analysed bag against the suite's thresholds (pure).

Every value comes from :func:`arm_bag.analysis.analyze` of the scenario's bag, so on
simulated time only: the same joint states give the same grades, bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from arm_sim.check.suite import METRICS, GradedMetric, Scenario


@dataclass
class MetricResult:
    """One graded metric: value (SI, per joint a list; None: undefined, which fails),
    threshold (SI), and whether value <= threshold."""

    name: str
    value: Any
    threshold: Any
    passed: bool
    note: str = ''

    def shown(self, which: str = 'value') -> str:
        m = METRICS[self.name]
        v = getattr(self, which)
        if v is None:
            return self.note or 'none'
        values = v if isinstance(v, list) else [v]
        fmt = '.1f' if m.scale != 1.0 or m.name == 'peak_torque' else '.3f'
        text = ' / '.join(f'{x * m.scale:{fmt}}' for x in values)
        return f'{text} {m.shown_unit}'


@dataclass
class ScenarioResult:
    """A scenario's outcome: its metrics, or the reason it could not be graded (a
    controller that sent nothing, crashed, ran away ...). ``sim_time``: the simulated time
    it reached [s]; ``wall``: wall-clock seconds it took (terminal only: never written to
    the report files, which repeat bit for bit)."""

    name: str
    description: str
    metrics: list[MetricResult] = field(default_factory=list)
    reason: str | None = None
    sim_time: float = 0.0
    wall: float = 0.0
    warnings: list[str] = field(default_factory=list)
    picture: str | None = None
    bag: str | None = None

    @property
    def passed(self) -> bool:
        return self.reason is None and all(m.passed for m in self.metrics)

    def failures(self) -> list[str]:
        """One line per failed metric (or the reason), for the JUnit failure message."""
        out = [self.reason] if self.reason else []
        out += [f'{m.name} {m.shown()} > {m.shown("threshold")}' if m.value is not None
                else f'{m.name}: {m.shown()}' for m in self.metrics if not m.passed]
        return out

    def value(self, metric: str) -> Any:
        """The value of ``metric`` (SI; KeyError if it was not graded)."""
        for m in self.metrics:
            if m.name == metric:
                return m.value
        raise KeyError(f'{self.name}: {metric} was not graded')

    def to_dict(self) -> dict:
        return {'name': self.name, 'passed': self.passed, 'reason': self.reason,
                'sim_time': round(self.sim_time, 9),
                'metrics': [{'name': m.name, 'value': m.value, 'threshold': m.threshold,
                             'unit': METRICS[m.name].unit, 'passed': m.passed}
                            for m in self.metrics],
                'warnings': self.warnings}


def measured(report, metric: GradedMetric) -> tuple[Any, bool]:
    """(value, found) of a graded metric's :mod:`arm_bag.metrics` ``source`` in
    ``report`` (SI; per joint a list, else a float; None: undefined). ``found``: the
    report has where it comes from (a segment, pushes), so an undefined value is the
    metric's ``undefined`` rather than 'not measured'."""
    name = metric.source
    if metric.scope == 'segment':
        seg = report.segments[-1] if report.segments else None
        return (None, False) if seg is None else (seg.values.get(name), True)
    if metric.scope == 'push':
        values = [p.get(name) for p in report.pushes or []]
        if not values:
            return None, False
        return (None if None in values else max(values)), True
    value = report.run.get(name)  # scope 'run': (J,) per joint
    if not value:
        return None, True
    values = [float(v) for v in value]
    return (values if metric.per_joint else max(values)), True


def grade(report, scenario: Scenario, arm) -> list[MetricResult]:
    """The scenario's thresholds applied to ``report`` (an :class:`arm_bag.analysis.
    Report` of its bag): each metric's :mod:`arm_bag.metrics` source by name
    (:func:`measured`), and ``final_tip_error``, the distance [m] of the tip at the last
    sample (``arm`` gives it by forward kinematics) from the last goal."""
    out = []
    for name, threshold in scenario.thresholds.items():
        metric = METRICS[name]
        found = True
        v: Any
        if metric.source is None:  # final_tip_error
            v = _final_tip_error(report, scenario, arm)
        else:
            v, found = measured(report, metric)
        if v is None:
            out.append(MetricResult(name, None, threshold, False,
                                    metric.undefined if found else 'not measured'))
            continue
        if isinstance(threshold, list):
            ok = all(math.isfinite(a) and a <= b for a, b in zip(v, threshold))
        else:
            ok = math.isfinite(v) and v <= threshold
        out.append(MetricResult(name, v, threshold, ok))
    return out


def _final_tip_error(report, scenario: Scenario, arm) -> float | None:
    """Distance [m] of the tip at the last sample of the last segment from the last goal;
    None without a sample or with a non-finite tip."""
    seg = report.segments[-1] if report.segments else None
    if seg is None or not len(seg.series.get('q', ())):
        return None
    tip = arm.forward_kinematics(np.asarray(seg.series['q'][-1], dtype=float))
    goal = np.array(scenario.goals[-1].tip)
    return float(np.hypot(*(tip - goal))) if np.isfinite(tip).all() else None
