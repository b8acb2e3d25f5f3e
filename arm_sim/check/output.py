"""What ``arm-sim check`` writes: the terminal table, JUnit XML, the Markdown summary and
``results.json`` (pure).

The files hold only simulated-time figures (no wall-clock time, no absolute path), so the
same controller gives the same files bit for bit; the JUnit ``time`` of a testcase is the
simulated time the scenario reached [s].
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from xml.etree import ElementTree as ET

from arm_sim.check.grade import ScenarioResult
from arm_sim.check.suite import METRICS, Suite


def rows(results: list[ScenarioResult]) -> list[tuple[str, str, str, str, str]]:
    """(scenario, metric, value, threshold, pass/FAIL) per graded metric; a scenario that
    could not be graded has one row with its reason."""
    out = []
    for r in results:
        if r.reason is not None:
            out.append((r.name, '-', 'not graded: ' + r.reason, '-', 'FAIL'))
        for m in r.metrics:
            out.append((r.name, m.name, m.shown(), f'<= {m.shown("threshold")}',
                        'pass' if m.passed else 'FAIL'))
    return out


def table(results: list[ScenarioResult], width: int = 100) -> str:
    head = ('scenario', 'metric', 'value', 'threshold', 'result')
    body = rows(results)
    limit = max(20, width - 60)
    body = [(a, b, c if len(c) <= limit else c[:limit - 11] + '... (below)', d, e)
            for a, b, c, d, e in body]
    widths = [max(len(r[i]) for r in [head, *body]) for i in range(len(head))]
    fmt = '  '.join(f'{{:<{w}}}' for w in widths)
    lines = [fmt.format(*head), '  '.join('-' * w for w in widths)]
    lines += [fmt.format(*r).rstrip() for r in body]
    lines += [f'{r.name}: not graded: {r.reason}' for r in results if r.reason]
    passed = sum(r.passed for r in results)
    lines.append(f'{passed} of {len(results)} scenarios passed')
    return '\n'.join(lines)


def junit(results: list[ScenarioResult], suite: Suite) -> str:
    """JUnit XML: one testcase per scenario, the failing metrics (or the reason) in the
    failure message, every metric in its system-out."""
    root = ET.Element('testsuites')
    ts = ET.SubElement(root, 'testsuite', name=f'arm-sim check {suite.name}',
                       tests=str(len(results)),
                       failures=str(sum(not r.passed for r in results)), errors='0',
                       time=f'{sum(r.sim_time for r in results):.3f}')
    for r in results:
        case = ET.SubElement(ts, 'testcase', classname=f'arm_sim_check.{suite.name}',
                             name=r.name, time=f'{r.sim_time:.3f}')
        if not r.passed:
            fail = ET.SubElement(case, 'failure', message='; '.join(r.failures()),
                                 type='failed' if r.reason is None else 'aborted')
            fail.text = '\n'.join(r.failures())
        out = ET.SubElement(case, 'system-out')
        out.text = '\n'.join(f'{m.name}: {m.shown()} (threshold {m.shown("threshold")}): '
                             f'{"pass" if m.passed else "FAIL"}' for m in r.metrics) or \
            (r.reason or '')
    ET.indent(root)
    return ET.tostring(root, encoding='unicode', xml_declaration=True) + '\n'


def markdown(results: list[ScenarioResult], suite: Suite, report_dir: Path) -> str:
    """The report directory's summary.md: verdict, the table, then per scenario its
    description, metrics and picture (paths relative to ``report_dir``)."""
    passed = sum(r.passed for r in results)
    lines = [f'# arm-sim check: {suite.name}', '',
             f'**{passed} of {len(results)} scenarios passed.** Suite: '
             f'`{Path(suite.path).name}`. Every figure is on simulated time, from the '
             'scenario\'s bag (`arm-sim analyze <scenario>/bag` gives all its metrics).', '',
             '| scenario | metric | value | threshold | result |', '|---|---|---|---|---|']
    lines += [f'| {a} | {b} | {c.replace("|", "/")} | {d} | {e} |' for a, b, c, d, e in
              rows(results)]
    for r in results:
        lines += ['', f'## {r.name}: {"pass" if r.passed else "FAIL"}', '']
        if r.description:
            lines += [r.description, '']
        if r.reason:
            lines += [f'Not graded: {r.reason}', '']
        for m in r.metrics:
            lines.append(f'- `{m.name}` {m.shown()} (threshold {m.shown("threshold")}): '
                         f'{"pass" if m.passed else "**FAIL**"}; {METRICS[m.name].meaning}')
        if r.picture:
            rel = os.path.relpath(r.picture, report_dir)
            lines += ['', f'![{r.name}]({rel})']
        if r.bag:
            lines += ['', f'Bag: `{os.path.relpath(r.bag, report_dir)}/`']
    return '\n'.join(lines) + '\n'


def write_report(results: list[ScenarioResult], suite: Suite, report_dir: Path,
                 junit_path: Path | None) -> None:
    report_dir.mkdir(parents=True, exist_ok=True)
    (report_dir / 'summary.md').write_text(markdown(results, suite, report_dir))
    (report_dir / 'results.json').write_text(json.dumps(
        {'suite': suite.name, 'passed': all(r.passed for r in results),
         'scenarios': [r.to_dict() for r in results]}, indent=1) + '\n')
    if junit_path is not None:
        junit_path.parent.mkdir(parents=True, exist_ok=True)
        junit_path.write_text(junit(results, suite))
