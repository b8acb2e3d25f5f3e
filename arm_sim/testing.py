"""pytest plugin of arm_sim (entry point ``pytest11``: loaded by every pytest in an
environment where arm_sim is installed): grade your controller in your own tests.

Opt-in: nothing here runs unless a test asks for the ``arm_check`` fixture, and importing
this module imports only pytest and the standard library.

    def test_my_controller(arm_check):
        result = arm_check(['python3', 'my_controller.py'])    # the lecture's suite
        assert result.passed, result.summary()

    def test_the_fast_line(arm_check):
        line = arm_check(['ros2', 'run', 'my_pkg', 'ctl'], scenarios=['line_fast'])['line_fast']
        assert line.value('line_deviation') < 0.005            # m

``arm_check(command, suite=None, scenarios=None, budget=None)`` runs ``arm-sim check``'s
harness in the test's process: ``command`` is the controller (any command; None: one you
start yourself), ``suite`` a suite file or a mapping as a suite file holds it (default:
the lecture's), ``scenarios`` the names to run, ``budget`` the wall-clock seconds per
scenario. It returns a :class:`CheckRun`: ``passed``, ``results`` (one
:class:`arm_sim.check.grade.ScenarioResult` per scenario, also ``run['name']``: ``passed``,
``reason``, ``failures()``, ``value(metric)`` in SI units), ``summary()`` (the terminal
table) and ``report_dir`` (bags, pictures, summary.md under the test's ``tmp_path``).
The ROS domain is ``$ROS_DOMAIN_ID`` if set, else a free one the session claims.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pytest


class CheckRun:
    """The outcome of one ``arm_check`` call."""

    def __init__(self, results: list, report_dir: Path) -> None:
        self.results = results
        self.report_dir = report_dir

    @property
    def passed(self) -> bool:
        return all(r.passed for r in self.results)

    def __getitem__(self, name: str):
        for r in self.results:
            if r.name == name:
                return r
        raise KeyError(f'no scenario {name!r} in this run '
                       f'({", ".join(r.name for r in self.results)})')

    def summary(self) -> str:
        from arm_sim.check.output import table

        return table(self.results) + f'\nreport: {self.report_dir / "summary.md"}'


_domain: list[int] = []


def _session_domain() -> int:
    if os.environ.get('ROS_DOMAIN_ID'):
        return int(os.environ['ROS_DOMAIN_ID'])
    if not _domain:
        from arm_common.process import claim_domain

        _domain.append(claim_domain(150 + os.getpid() % 80))
    return _domain[0]


@pytest.fixture
def arm_check(tmp_path: Path) -> Callable[..., CheckRun]:
    """Grade a controller on a check suite (see the module docstring)."""
    calls = []

    def run(command: Sequence[str] | None, suite: str | Path | dict[str, Any] | None = None,
            scenarios: Sequence[str] | None = None, budget: float | None = None) -> CheckRun:
        from dataclasses import replace

        from arm_sim.check.harness import run_suite
        from arm_sim.check.output import write_report
        from arm_sim.check.suite import load_suite, parse_suite

        loaded = parse_suite(suite, '<arm_check suite>') if isinstance(suite, dict) \
            else load_suite(suite)
        if scenarios:
            loaded = loaded.select(list(scenarios))
        if budget is not None:
            loaded = replace(loaded, scenarios=tuple(replace(s, budget=float(budget))
                                                     for s in loaded.scenarios))
        calls.append(1)
        out = tmp_path / f'arm_check-{len(calls)}'
        results = run_suite(loaded, out, _session_domain(), command, echo=lambda s: None)
        write_report(results, loaded, out, out / 'junit.xml')
        return CheckRun(results, out)

    return run
