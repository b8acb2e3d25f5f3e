"""``arm-sim check``: suites, grading output, the CLI's usage errors, the pytest plugin's
light import, and (process tier) the check run against the example controller (passes),
a sign-flipped copy of it (fails: runaway), arm_sim's own controller (passes), the bad
controllers of test/check_controllers/bad.py (each scenario fails with its reason, the
next still runs, nothing is left running) and the example's own plugin test."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from xml.etree import ElementTree as ET

import pytest

from arm_sim.check.grade import MetricResult, ScenarioResult
from arm_sim.check.output import junit, markdown, table
from arm_sim.check.suite import SuiteFileError, load_suite, parse_suite
from arm_sim.cli import main

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / 'examples' / 'arm_check_example' / 'arm_check_example' / 'controller.py'
BAD = ROOT / 'test' / 'check_controllers' / 'bad.py'
TOPIC_ONLY = ROOT / 'test' / 'check_controllers' / 'topic_only.py'
LINE = {'name': 'l', 'start_tip': [0.5, 1.2],
        'goals': [{'tip': [1.4, 0.2], 'mode': 'straight_line', 'duration': 0.8}],
        'thresholds': {'line_deviation': 0.01}}


def test_the_shipped_suite_is_the_lectures():
    suite = load_suite()
    assert [s.name for s in suite.scenarios] == [
        'regulation', 'line_slow', 'line_fast', 'goal_while_moving', 'push', 'noisy_arm']
    fast = suite.select(['line_fast']).scenarios[0]
    assert fast.thresholds == {'final_tip_error': 0.003, 'peak_torque': [57.0, 19.0],
                               'saturation': 0.01, 'line_deviation': 0.0105}
    assert 'settling_time' in suite.scenarios[0].thresholds
    assert suite.scenarios[4].disturbances['pushes'][0]['tip_force'] == [0.0, -30.0]


@pytest.mark.parametrize('change, words', [
    ({'thresholds': {'line_dev': 1}}, "scenarios[0] (l): thresholds.line_dev: unknown metric"),
    ({'thresholds': {'line_deviation': -1}}, 'thresholds.line_deviation: must be > 0 m, got -1'),
    ({'thresholds': {'settling_time': 2}}, 'thresholds.settling_time: only for regulation'),
    ({'thresholds': {'peak_torque': [1, 2, 3]}}, 'peak_torque: 3 values for 2 joints'),
    ({'goals': [{'tip': [1, 'a']}]}, "goals[0].tip: a number, got 'a'"),
    ({'goals': [{'tip': [1, 1], 'mode': 'fly'}]}, "goals[0].mode: one of regulation, "
                                                   "straight_line, got 'fly'"),
    ({'goals': [{'tip': [1, 1], 'at': 0.123}]}, 'goals[0].at: 0.123 s is not a whole number'),
    ({'simulator': {'timing_mode': 'wall_clock'}}, 'simulator.timing_mode: not settable'),
    ({'speed': 1}, "unknown key 'speed'"),
    ({'disturbances': {'pushes': [{'at': 1.0, 'tip_force': [1, 2], 'shape': 'kick'}]}},
     "'kick'"),
])
def test_a_bad_suite_is_refused_naming_the_entry_and_value(change, words):
    with pytest.raises(SuiteFileError) as err:
        parse_suite({'scenarios': [{**LINE, **change}]}, 'my.yaml')
    assert str(err.value).startswith('my.yaml: ')
    assert words in str(err.value)


def test_usage_errors_are_one_line_and_exit_2(tmp_path, capsys):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('scenarios: [{name: x, goals: [{tip: [1, 1]}], thresholds: '
                   '{final_error: oops}}]\n')
    for argv, words in [
        (['check', '--suite', str(bad), '--', 'true'],
         "scenarios[0] (x): thresholds.final_error: a number, got 'oops'"),
        (['check', 'python3', 'ctl.py'], 'put your controller after "--"'),
        (['check', '--budget', '-1', '--', 'true'], '--budget must be a positive number'),
        (['check', '--scenario', 'nope', '--', 'true'], "no scenario 'nope'"),
        (['check', '--', 'no-such-controller-here'], 'no-such-controller-here: command not'),
    ]:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count('\n') == 1 and err.startswith('arm-sim check: ') and words in err
    assert main(['check', '--list']) == 0
    assert 'line_fast: straight line' in capsys.readouterr().out


def _results() -> list[ScenarioResult]:
    ok = ScenarioResult('line_fast', 'fast', [MetricResult('line_deviation', 0.0035, 0.0105,
                                                           True)], sim_time=2.3)
    bad = ScenarioResult('regulation', 'reg', [
        MetricResult('final_tip_error', 0.075, 0.003, False),
        MetricResult('settling_time', None, 3.45, False, 'never settles'),
        MetricResult('peak_torque', [51.5, 10.6], [57.0, 19.0], True)], sim_time=4.33)
    crashed = ScenarioResult('push', '', reason='the controller exited with code 1')
    return [ok, bad, crashed]


def test_junit_has_one_testcase_per_scenario_with_the_failing_metrics(tmp_path):
    suite = load_suite()
    root = ET.fromstring(junit(_results(), suite))
    ts = root.find('testsuite')
    assert ts is not None and (ts.get('tests'), ts.get('failures')) == ('3', '2')
    cases = {c.get('name'): c for c in ts.iter('testcase')}
    assert cases['line_fast'].find('failure') is None
    fail = cases['regulation'].find('failure')
    assert fail is not None
    assert fail.get('message') == ('final_tip_error 75.0 mm > 3.0 mm; settling_time: never '
                                   'settles')
    assert cases['push'].find('failure').get('message') == \
        'the controller exited with code 1'
    text = table(_results())
    assert 'regulation  peak_torque' in text and '1 of 3 scenarios passed' in text
    assert '## regulation: FAIL' in markdown(_results(), suite, tmp_path)


def test_the_docs_graded_metric_table_is_the_suites():
    from arm_sim.check.suite import graded_metrics_markdown

    text = (ROOT / 'docs' / 'check.md').read_text()
    marker = '<!-- generated: arm_sim.check.suite.graded_metrics_markdown -->\n'
    assert marker in text, 'docs/check.md lacks the generated metric table'
    block = text.split(marker, 1)[1].split('<!-- end generated -->', 1)[0]
    assert block == graded_metrics_markdown(), (
        f'docs/check.md is out of date; replace its block with:\n{graded_metrics_markdown()}')


def test_each_graded_metric_is_an_analyze_metric_by_name_and_no_name_means_two_things():
    from arm_bag.metrics import DISTURBANCE_METRICS
    from arm_bag.metrics import METRICS as ANALYZE
    from arm_sim.check.suite import METRICS

    analyze = {m.name: m for m in (*ANALYZE, *DISTURBANCE_METRICS)}
    assert [m.name for m in METRICS.values() if m.source is None] == ['final_tip_error']
    for m in METRICS.values():
        if m.source is None:
            continue
        src = analyze[m.source]
        assert (m.when, m.unit) == (src.when, 'fraction' if src.fmt == 'pct' else src.unit)
        assert m.per_joint == src.per_joint or (m.scope == 'run' and src.per_joint)
    # A name both have is one quantity: the same unit (final_error was m here, rad there).
    for name in set(METRICS) & set(analyze):
        assert METRICS[name].unit == analyze[name].unit, name


def test_grade_takes_each_metric_by_its_analyze_name_and_the_tip_from_the_last_sample():
    from types import SimpleNamespace

    import numpy as np

    from arm_dynamics import TwoLinkArm
    from arm_sim.check.grade import grade

    arm = TwoLinkArm()
    q_end = [-0.4, 1.2]
    tip = arm.forward_kinematics(np.array(q_end))
    goal = [float(tip[0]) + 0.003, float(tip[1]) - 0.004]   # 5 mm from the tip
    seg = SimpleNamespace(values={'deviation_max': 0.002, 'settling_time_overall': None},
                          series={'q': [[0.0, 0.0], q_end]})
    report = SimpleNamespace(segments=[seg], run={'torque_peak': [40.0, 9.0],
                                                  'saturated_fraction': [0.0, 0.02]},
                             pushes=[{'peak_deviation': 0.1, 'recovery_time': 0.5},
                                     {'peak_deviation': 0.3, 'recovery_time': 0.4}])
    scenario = parse_suite({'scenarios': [{
        'name': 's', 'goals': [{'tip': goal, 'mode': 'straight_line'}],
        'disturbances': {'pushes': [{'at': 1.0, 'tip_force': [0.0, -30.0],
                                     'shape': 'pulse', 'duration': 0.1}]},
        'thresholds': {'final_tip_error': 0.006, 'line_deviation': 0.001,
                       'peak_torque': [57.0, 19.0], 'saturation': 0.01,
                       'push_deviation': 0.5, 'push_recovery': 1.0}}]}).scenarios[0]
    got = {m.name: (m.value, m.passed) for m in grade(report, scenario, arm)}
    assert got['final_tip_error'][0] == pytest.approx(0.005, abs=1e-12)
    assert got['final_tip_error'][1]
    assert got['line_deviation'] == (0.002, False)
    assert got['peak_torque'] == ([40.0, 9.0], True)
    assert got['saturation'] == (0.02, False)      # the largest joint
    assert got['push_deviation'] == (0.3, True)    # the largest push
    assert got['push_recovery'] == (0.5, True)
    # An undefined source value says why; a report without segments measured nothing.
    regulation = parse_suite({'scenarios': [{'name': 'r', 'goals': [{'tip': goal}],
                                             'thresholds': {'settling_time': 1.0}}]})
    result = grade(report, regulation.scenarios[0], arm)[0]
    assert (result.value, result.passed, result.note) == (None, False, 'never settles')
    empty = SimpleNamespace(segments=[], run={}, pushes=[])
    notes = {m.name: m.note for m in grade(empty, scenario, arm)}
    assert notes['final_tip_error'] == notes['line_deviation'] == 'not measured'


def test_a_suite_with_the_old_name_final_error_is_read_with_one_warning(tmp_path, capsys):
    old = {'defaults': {'thresholds': {'final_error': 0.003}}, 'scenarios': [LINE]}
    suite = parse_suite(old, 'old.yaml')
    assert suite.scenarios[0].thresholds == {'final_tip_error': 0.003,
                                             'line_deviation': 0.01}
    assert suite.notes == ('old.yaml: defaults: thresholds.final_error: final_error is '
                           'deprecated, now final_tip_error (read as it); rename it',)
    assert parse_suite({'scenarios': [LINE]}).notes == ()
    with pytest.raises(SuiteFileError, match=r'thresholds\.final_error: the old name of '
                       'final_tip_error, which is given too'):
        parse_suite({'scenarios': [{**LINE, 'thresholds': {'final_error': 0.003,
                                                           'final_tip_error': 0.003}}]})
    path = tmp_path / 'old.yaml'
    path.write_text('scenarios: [{name: x, goals: [{tip: [1, 1]}], thresholds: '
                    '{final_error: 0.003}}]\n')
    assert main(['check', '--suite', str(path), '--list']) == 0
    out = capsys.readouterr()
    assert out.err == (f'warning: {path}: scenarios[0] (x): thresholds.final_error: '
                       'final_error is deprecated, now final_tip_error (read as it); '
                       'rename it\n')
    assert 'final_tip_error <= 0.003' in out.out


def test_the_pytest_plugin_is_registered_and_imports_light():
    from importlib.metadata import entry_points

    assert [e.value for e in entry_points(group='pytest11') if e.name == 'arm_sim'] == \
        ['arm_sim.testing']
    code = ('import sys, arm_sim.testing; '
            'print(sorted(m for m in ("rclpy", "numpy", "arm_sim.check.harness") '
            'if m in sys.modules))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=60)
    assert out.stdout.strip() == '[]', out.stderr


def test_a_controller_that_exits_has_what_it_left_in_its_group_stopped(tmp_path):
    """A script that starts its controller in the background and exits (or a controller
    that crashes leaving a child): stopping it stops the whole process group, SIGKILL
    for what ignores SIGINT (a background job of sh does)."""
    from arm_sim.check.harness import ControllerProcess, group_running

    log = tmp_path / 'ctl.log'
    ctl = ControllerProcess(['sh', '-c', f'"{sys.executable}" "{BAD}" orphan & echo $!; '
                             'exit 3'], 0, log, 'x')
    assert ctl.proc.wait(30) == 3
    assert group_running(ctl.proc.pid)  # the orphan, in the group
    assert int(log.read_text()) in _ours_running(str(BAD))  # (the check below can see it)
    assert ctl.stop(timeout=1.0) == 3
    assert not group_running(ctl.proc.pid)
    assert ctl.stop() == 3  # once only


def _check(tmp_path: Path, name: str, *args: str) -> tuple[subprocess.CompletedProcess,
                                                            dict, ET.Element]:
    report, xml = tmp_path / name, tmp_path / f'{name}.xml'
    res = subprocess.run([sys.executable, '-m', 'arm_sim.cli', 'check', '--report',
                          str(report), '--junit', str(xml), *args], capture_output=True,
                         text=True, timeout=400)
    assert xml.is_file(), res.stdout + res.stderr
    return res, json.loads((report / 'results.json').read_text()), ET.parse(xml).getroot()


@pytest.mark.process
@pytest.mark.timeout(600)
def test_check_grades_the_example_and_its_sign_flipped_copy(tmp_path):
    # The example controller (topics only): the whole lecture suite passes.
    ok, doc, xml = _check(tmp_path, 'example', '--', sys.executable, str(EXAMPLE))
    assert ok.returncode == 0, ok.stdout + ok.stderr
    assert doc['passed'] and len(doc['scenarios']) == 6
    assert len(xml.findall('.//testcase')) == 6 and not xml.findall('.//failure')
    assert (tmp_path / 'example' / 'line_fast' / 'report.png').is_file()
    assert (tmp_path / 'example' / 'push' / 'bag' / 'metadata.yaml').is_file()
    fast = next(s for s in doc['scenarios'] if s['name'] == 'line_fast')
    dev = next(m for m in fast['metrics'] if m['name'] == 'line_deviation')
    assert dev['value'] < dev['threshold'] / 2  # margin: 3.5 of 10.5 mm

    # The same controller again: the same report, bit for bit.
    again, doc2, _ = _check(tmp_path, 'again', '--scenario', 'line_fast', '--',
                            sys.executable, str(EXAMPLE))
    assert again.returncode == 0, again.stdout + again.stderr
    assert doc2['scenarios'][0] == fast

    # A sign-flipped copy: every scenario fails with the runaway, the next one still runs.
    flipped = tmp_path / 'flipped.py'
    text = EXAMPLE.read_text()
    assert text.count('\nSIGN = 1.0 ') == 1
    flipped.write_text(text.replace('\nSIGN = 1.0 ', '\nSIGN = -1.0 '))
    bad, doc, xml = _check(tmp_path, 'flipped', '--scenario', 'regulation', '--scenario',
                           'line_fast', '--', sys.executable, str(flipped))
    assert bad.returncode == 1, bad.stdout + bad.stderr
    assert [s['name'] for s in doc['scenarios']] == ['regulation', 'line_fast']
    for s, fail in zip(doc['scenarios'], xml.findall('.//failure')):
        assert not s['passed'] and 'unstable: the simulator reports runaway' in s['reason']
        assert 'runaway' in fail.get('message', '')



@pytest.mark.process
@pytest.mark.timeout(600)
def test_a_topic_only_controller_gets_every_trajectory_and_passes(tmp_path):
    """A third party's controller that takes arm_controller/joint_trajectory itself, gives
    no verdicts and tags no command (test/check_controllers/topic_only.py) gets every
    goal's trajectory (the planner waits for its subscription, and the harness sends it
    once more when its own publisher has matched it): the lecture suite passes. (Which
    state it first answers with a new trajectory depends on its own executor's order of
    the trajectory and the next state: its figures may differ between runs in the 4th
    significant digit, docs/limitations.md.)"""
    res, doc, xml = _check(tmp_path, 'topic_only', '--', sys.executable, str(TOPIC_ONLY))
    assert res.returncode == 0, res.stdout + res.stderr
    assert doc['passed'] and len(doc['scenarios']) == 6
    assert not xml.findall('.//failure')


#: A scenario per behaviour of bad.py (``bad.py scenario`` takes its behaviour from the
#: scenario's name, $ARM_SIM_CHECK_SCENARIO): a short move, budgets short where the
#: behaviour waits for one, and the reason each must fail with.
BAD_SUITE = {
    'name': 'bad_controllers',
    'defaults': {'settle': 0.3, 'budget': 30.0, 'thresholds': {'final_tip_error': 0.003}},
    'scenarios': [{'name': name, 'start_tip': [0.5, 1.2], 'goals': [{'tip': [0.55, 1.15]}],
                   **extra} for name, extra in [
        ('silent', {'budget': 2.0}), ('nan', {}), ('wrong_length', {}), ('crash', {}),
        ('slow', {'budget': 3.0}), ('good', {})]]}
BAD_REASONS = {
    'silent': ['no commands on effort_controller/commands within the wall-clock budget '
               'of 2 s'],
    'nan': ['bad command: at simulated t = 0.00 s: effort command has non-finite values '
            'at index [0, 1]: [nan, nan]'],
    'wrong_length': ['bad command: at simulated t = 0.00 s: effort command must have 2 '
                     'values, got 3'],
    'crash': ['the controller exited with code 1 at simulated t = 0.00 s', 'on purpose'],
    'slow': ['too slow: simulated time reached t = ', 'within the wall-clock budget of 3 s'],
}


def _ours_running(words: str) -> list[int]:
    """PIDs of processes of this test session whose command line holds ``words``."""
    from conftest import ours, proc_dirs

    found = []
    for proc in proc_dirs():
        try:
            line = (proc / 'cmdline').read_bytes().replace(b'\0', b' ').decode(
                errors='replace')
        except OSError:
            continue
        if words in line and ours(proc):
            found.append(int(proc.name))
    return found


@pytest.mark.process
@pytest.mark.timeout(400)
def test_bad_controllers_fail_their_scenario_with_the_reason_and_leave_nothing(tmp_path):
    import yaml
    from conftest import node_processes

    suite = tmp_path / 'bad.yaml'
    suite.write_text(yaml.safe_dump(BAD_SUITE, sort_keys=False))
    before = node_processes()
    res, doc, xml = _check(tmp_path, 'bad', '--suite', str(suite), '--', sys.executable,
                           str(BAD), 'scenario')
    out = res.stdout + res.stderr
    assert res.returncode == 1, out
    # Every scenario ran, in order, each on its own: a failure never stops the next one.
    assert [s['name'] for s in doc['scenarios']] == [s['name'] for s in BAD_SUITE['scenarios']]
    for s in doc['scenarios'][:-1]:
        assert not s['passed'] and not s['metrics'], s
        for words in BAD_REASONS[s['name']]:
            assert words in s['reason'], (s['name'], s['reason'])
    failures = {c.get('name'): c.find('failure') for c in xml.iter('testcase')}
    assert all(failures[n] is not None and failures[n].get('message') ==
               next(s['reason'] for s in doc['scenarios'] if s['name'] == n)
               for n in BAD_REASONS)
    # After them all, the example controller passes: the plant and the suite were reset.
    good = doc['scenarios'][-1]
    assert good['passed'] and good['reason'] is None and failures['good'] is None, good
    assert 'nodes did not stop cleanly' not in out, out
    # Nothing is left running: the suite's nodes, the bad controllers, and the child the
    # crashing one left in its process group (killed with the group at the scenario's end).
    assert node_processes() - before == set()
    assert _ours_running(str(BAD)) == []
    log = (tmp_path / 'bad' / 'crash' / 'logs' / 'your_controller.log').read_text()
    pid = int(log.split('left a child running, pid ')[1].split()[0])
    assert pid not in _ours_running('orphan')


@pytest.mark.process
@pytest.mark.timeout(300)
def test_the_examples_plugin_test_passes(tmp_path):
    """The example package's own test (the ``arm_check`` fixture), as its user runs it
    from the package's directory: the cheapest of its tests, the fast line."""
    example = ROOT / 'examples' / 'arm_check_example'
    res = subprocess.run([sys.executable, '-m', 'pytest', 'test', '-k', 'fast_line', '-q',
                          '-p', 'no:cacheprovider', '--basetemp', str(tmp_path / 'pytest')],
                         cwd=example, capture_output=True, text=True, timeout=240)
    assert res.returncode == 0, res.stdout + res.stderr
    assert '1 passed, 1 deselected' in res.stdout, res.stdout


@pytest.mark.process
@pytest.mark.timeout(600)
def test_check_grades_arm_sims_own_controller_and_plain_pd(tmp_path):
    # arm_sim's own controller, as a user's command.
    own, doc, _ = _check(tmp_path, 'own', '--scenario', 'line_fast', '--scenario', 'push',
                         '--', sys.executable, '-m', 'arm_control.controller_node',
                         '--ros-args', '--params-file', str(ROOT / 'config' / 'arm.yaml'))
    assert own.returncode == 0, own.stdout + own.stderr
    assert '2 of 2 scenarios passed' in own.stdout

    # The same controller with plain PD (the demo's gains): the fast line fails, and the
    # report says why (the tip leaves the line by far more than the threshold).
    pd, doc, xml = _check(tmp_path, 'pd', '--scenario', 'line_fast', '--',
                          sys.executable, '-m', 'arm_control.controller_node',
                          '--ros-args', '--params-file', str(ROOT / 'config' / 'arm.yaml'),
                          '-p', 'law:=pd')
    assert pd.returncode == 1, pd.stdout + pd.stderr
    fast = doc['scenarios'][0]
    dev = next(m for m in fast['metrics'] if m['name'] == 'line_deviation')
    assert not fast['passed'] and not dev['passed'] and dev['value'] > 5 * dev['threshold']
    assert 'line_deviation' in xml.find('.//failure').get('message')


#: A controller that first starts a grandchild which escapes its process group and
#: session (fork, setsid, fork again: orphaned, it ignores SIGINT, as a daemon would) and
#: writes the grandchild's pid to the file argv[1], then becomes the example controller
#: (bad.py's 'good').
ESCAPING = f'''import os, signal, sys
if os.fork() == 0:
    os.setsid()
    if os.fork() == 0:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        with open(sys.argv[1] + '.tmp', 'w') as f:
            f.write(str(os.getpid()))
        os.rename(sys.argv[1] + '.tmp', sys.argv[1])
        while True:
            signal.pause()
    os._exit(0)
os.wait()
os.execv(sys.executable, [sys.executable, {str(EXAMPLE)!r}])
'''


def _escaping_suite(tmp_path: Path, name: str, settle: float = 2.0) -> tuple[Path, Path]:
    """A one-scenario suite (a short regulation) named ``name``, and the controller above."""
    import yaml

    suite = tmp_path / f'{name}.yaml'
    suite.write_text(yaml.safe_dump({'name': name, 'scenarios': [{
        'name': name, 'start_tip': [0.5, 1.2], 'settle': settle, 'budget': 60.0,
        'goals': [{'tip': [0.55, 1.15]}], 'thresholds': {'settling_time': 5.0}}]}))
    ctl = tmp_path / 'escaping_controller.py'
    ctl.write_text(ESCAPING)
    return suite, ctl


def _scenario_processes(scenario: str) -> list[int]:
    """Live processes of this session started for ``scenario`` (its keeper, the controller,
    whatever they started: ARM_SIM_CHECK_SCENARIO=<scenario> in their environment)."""
    from conftest import ours, proc_dirs

    mark = f'ARM_SIM_CHECK_SCENARIO={scenario}'.encode()
    found = []
    for proc in proc_dirs():
        try:
            if (mark in (proc / 'environ').read_bytes().split(b'\0') and ours(proc)
                    and (proc / 'stat').read_text().rsplit(')', 1)[1].split()[0] != 'Z'):
                found.append(int(proc.name))
        except (OSError, IndexError):
            continue
    return found


def _alive(pid: int) -> bool:
    try:
        return Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0] != 'Z'
    except (OSError, IndexError):
        return False


def _poll(condition, timeout: float, what: str):
    """Poll ``condition()`` (every 50 ms) until truthy; fail after ``timeout`` s."""
    import time

    end = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > end:
            pytest.fail(f'timed out after {timeout:g} s waiting for {what}')
        time.sleep(0.05)


@pytest.mark.process
@pytest.mark.timeout(300)
def test_what_a_controller_starts_in_a_session_of_its_own_ends_with_its_scenario(tmp_path):
    """A grandchild the controller started with setsid() (out of its process group, its
    parent gone, SIGINT ignored) is stopped with the scenario: it cannot answer a later
    scenario or check on the domain."""
    from conftest import node_processes

    suite, ctl = _escaping_suite(tmp_path, 'keeper_escape')
    pid_file = tmp_path / 'grandchild.pid'
    before = node_processes()
    res, doc, _ = _check(tmp_path, 'escape', '--suite', str(suite), '--', sys.executable,
                         str(ctl), str(pid_file))
    assert res.returncode == 0, res.stdout + res.stderr
    assert doc['passed'], doc
    grandchild = int(pid_file.read_text())  # it did start, in a session of its own
    assert not _alive(grandchild)
    assert _scenario_processes('keeper_escape') == []
    assert node_processes() - before == set()
    assert 'warning: ROS domain' not in res.stdout, res.stdout


@pytest.mark.process
@pytest.mark.timeout(300)
def test_a_sigkilled_check_leaves_no_process_and_no_shared_memory_behind(tmp_path):
    """SIGKILL of ``arm-sim check`` mid-scenario: the controller, its setsid'ed grandchild
    (the keeper stops them) and the suite's nodes (the kernel tells them their parent
    died) all exit within seconds, and no new Fast DDS file stays in /dev/shm once they
    are gone (the keeper removes what the killed check could not)."""
    import signal

    from conftest import node_processes, own_shm_files, shm_files, shm_holders

    suite, ctl = _escaping_suite(tmp_path, 'keeper_sigkill', settle=20.0)
    pid_file = tmp_path / 'grandchild.pid'
    before = node_processes()
    check = subprocess.Popen([sys.executable, '-m', 'arm_sim.cli', 'check', '--report',
                              str(tmp_path / 'killed'), '--suite', str(suite), '--',
                              sys.executable, str(ctl), str(pid_file)],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        # Mid-scenario: the suite's nodes up, the controller and its grandchild running,
        # the first goal sent (its progress line).
        lines: list[str] = []
        while not any('goal 1:' in line for line in lines):
            line = check.stdout.readline()  # type: ignore[union-attr]
            assert line, 'the check ended early:\n' + ''.join(lines)
            lines.append(line)
        assert pid_file.is_file(), ''.join(lines)
        nodes = node_processes() - before
        controller = _scenario_processes('keeper_sigkill')
        grandchild = int(pid_file.read_text())
        assert len(nodes) >= 4 and len(controller) >= 2 and _alive(grandchild), \
            (nodes, controller)
        held = shm_holders(session_only=True) - own_shm_files()
        assert held, 'the check holds no Fast DDS files?'
    finally:
        check.send_signal(signal.SIGKILL)
        check.wait(30)
        check.stdout.close()  # type: ignore[union-attr]
    _poll(lambda: not _alive(grandchild), 15.0, f'the setsid grandchild {grandchild} to exit')
    _poll(lambda: not _scenario_processes('keeper_sigkill'), 15.0,
          'the controller and its keeper to exit')
    _poll(lambda: not (node_processes() - before), 15.0, "the suite's nodes to exit")

    # The check's own files: those its processes held just before the kill (other test
    # sessions on the machine come and go meanwhile). Each must go once they are gone.
    def stale() -> set[str]:
        return (held & shm_files()) - shm_holders()

    try:
        _poll(lambda: not stale(), 10.0, 'no new stale Fast DDS file in /dev/shm')
    except BaseException:
        print('STALE', sorted(stale()), sorted(held))
        raise


@pytest.mark.process
@pytest.mark.timeout(120)
def test_a_leftover_commands_publisher_on_the_domain_is_named_and_fails_the_scenario(
        tmp_path):
    """A node of another run still publishing effort_controller/commands on the domain
    (it would drive the arm): one warning line names it, and the scenario fails with that
    reason before starting anything."""
    import signal

    leftover = tmp_path / 'leftover.py'
    leftover.write_text(
        'import ctypes, signal, rclpy\n'
        'from std_msgs.msg import Float64MultiArray\n'
        'ctypes.CDLL(None).prctl(1, signal.SIGTERM, 0, 0, 0)\n'
        'rclpy.init()\n'
        "node = rclpy.create_node('ct_controller')\n"
        "node.create_publisher(Float64MultiArray, 'effort_controller/commands', 10)\n"
        "print('up', flush=True)\n"
        'try:\n    rclpy.spin(node)\nexcept Exception:\n    pass\n')
    suite, _ = _escaping_suite(tmp_path, 'keeper_leftover')
    other = subprocess.Popen([sys.executable, str(leftover)], stdout=subprocess.PIPE,
                             text=True)
    try:
        assert other.stdout.readline() == 'up\n'  # type: ignore[union-attr]
        res, doc, xml = _check(tmp_path, 'leftover', '--suite', str(suite), '--', 'true')
    finally:
        other.send_signal(signal.SIGINT)
        other.wait(30)
        other.stdout.close()  # type: ignore[union-attr]
    assert res.returncode == 1, res.stdout + res.stderr
    warnings = [line.strip() for line in res.stdout.splitlines() if 'warning:' in line]
    assert len(warnings) == 1, res.stdout
    assert warnings[0].startswith('warning: ROS domain ') and \
        ' already has /ct_controller publishing effort_controller/commands' in warnings[0]
    assert "Its commands would drive this check's arm" in warnings[0]
    reason = doc['scenarios'][0]['reason']
    assert reason.endswith('already has /ct_controller publishing effort_controller/commands'
                           " (left over from another run?): its commands would drive this "
                           "check's arm; stop it"), reason
    assert xml.find('.//failure') is not None


def test_a_port_left_without_its_lock_by_a_killed_check_is_removed_once_unused(tmp_path):
    """What a SIGKILLed check leaves in /dev/shm: ports whose listener closed (removing
    its lock file) while the killed process still counted as a user. Removed when old
    and unused; a fresh one (being created) and a mapped one are kept."""
    import mmap
    import os
    import time

    from arm_sim.launcher import LOCKLESS_AGE, remove_stale_shm

    shm = tmp_path.resolve()
    old, fresh, mapped = 'fastrtps_port7411', 'fastrtps_port7413', 'fastrtps_port7415'
    for name in (old, fresh, mapped, 'fastrtps_port7417', 'fastrtps_port7417_el'):
        (shm / name).write_bytes(b'\0' * 64)
    then = time.time() - 2 * LOCKLESS_AGE
    for name in (old, mapped):
        os.utime(shm / name, (then, then))
    with open(shm / mapped, 'r+b') as f:  # a live process still maps this port
        view = mmap.mmap(f.fileno(), 64)
    try:
        removed = remove_stale_shm(shm)
    finally:
        view.close()
    assert old in removed and fresh not in removed and mapped not in removed
    assert (shm / fresh).exists() and (shm / mapped).exists()
