"""Grade one scenario: its analysed bag against the suite's thresholds (pure).

Every value comes from :func:`arm_bag.analysis.analyze` of the scenario's bag, so on
simulated time only: the same joint states give the same grades, bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from arm_sim.check.suite import METRICS, Scenario


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


def grade(report, scenario: Scenario, arm) -> list[MetricResult]:
    """The scenario's thresholds applied to ``report`` (an :class:`arm_bag.analysis.
    Report` of its bag); ``arm`` gives the tip (forward kinematics)."""
    seg = report.segments[-1] if report.segments else None
    values: dict[str, Any] = {}
    notes: dict[str, str] = {}
    if seg is not None and len(seg.series.get('q', ())):
        q = np.asarray(seg.series['q'][-1], dtype=float)
        tip = arm.forward_kinematics(q)
        goal = np.array(scenario.goals[-1].tip)
        values['final_error'] = (float(np.hypot(*(tip - goal))) if np.isfinite(tip).all()
                                 else None)
    if seg is not None:
        values['line_deviation'] = seg.values.get('deviation_max')
        values['settling_time'] = seg.values.get('settling_time_overall')
        notes['settling_time'] = 'never settles'
    run = report.run
    peak = run.get('torque_peak')
    values['peak_torque'] = [float(v) for v in peak] if peak else None
    sat = run.get('saturated_fraction')
    values['saturation'] = max(float(v) for v in sat) if sat else None
    pushes = report.pushes or []
    if pushes:
        dev = [p.get('peak_deviation') for p in pushes]
        rec = [p.get('recovery_time') for p in pushes]
        values['push_deviation'] = None if None in dev else max(dev)
        values['push_recovery'] = None if None in rec else max(rec)
        notes['push_recovery'] = 'never back'
    out = []
    for name, threshold in scenario.thresholds.items():
        v = values.get(name)
        if v is None:
            out.append(MetricResult(name, None, threshold, False,
                                    notes.get(name, 'not measured')))
            continue
        if isinstance(threshold, list):
            ok = all(math.isfinite(a) and a <= b for a, b in zip(v, threshold))
        else:
            ok = math.isfinite(v) and v <= threshold
        out.append(MetricResult(name, v, threshold, ok))
    return out
