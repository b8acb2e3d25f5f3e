"""arm_common.node.Diagnostics on a real rclpy node in this process (test domain): status
names as diagnostic_updater gives them, one status per task, immediate reports that do not
overwrite the summary, and a problem's status that persists and decays to OK."""

from __future__ import annotations

import time

import pytest
from conftest import values
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

from arm_common.node import SUMMARY_TASK, Diagnostics, parse_status_name, status_name

PERIOD = 0.3  # s: the periodic report, and the throttle of immediate problem reports


def test_status_names_follow_diagnostic_updater_with_the_namespace():
    assert status_name('/simulator', 'summary') == 'simulator: summary'
    assert status_name('/arm2/simulator', 'time_jump') == 'arm2/simulator: time_jump'
    assert parse_status_name('arm2/simulator: time_jump') == ('/arm2/simulator', 'time_jump')
    assert parse_status_name('simulator: summary') == ('/simulator', 'summary')
    assert parse_status_name('/simulator') is None  # the old naming: no task


@pytest.fixture
def probe(ros):
    """A node ``/diag_test/probe`` with Diagnostics, spun by the test's executor."""
    node = ros.rclpy.create_node('probe', namespace='/diag_test', context=ros.context)
    ros.executor.add_node(node)
    sim = {'t': 1.5}
    diag = Diagnostics(node, period=PERIOD, sim_time=lambda: sim['t'])
    yield diag, sim
    ros.executor.remove_node(node)
    node.destroy_node()


def named(array: DiagnosticArray, task: str) -> DiagnosticStatus | None:
    name = f'diag_test/probe: {task}'
    return next((s for s in array.status if s.name == name), None)


def periodic(arrays: list) -> list:
    """The periodic arrays (those with the summary)."""
    return [a for a in arrays if named(a, SUMMARY_TASK)]


def test_problems_and_events_get_their_own_persistent_status(ros, probe):
    diag, sim = probe
    arrays = ros.collect(DiagnosticArray, '/diagnostics')
    diag.set('OK', 'all fine', widgets=3)
    ros.wait_for(lambda: periodic(arrays), what='a periodic report')
    first = periodic(arrays)[0]
    summary = named(first, SUMMARY_TASK)
    assert [s.name for s in first.status] == ['diag_test/probe: summary'], 'no kinds yet'
    assert summary.hardware_id == 'arm_sim' and summary.message == 'all fine'
    assert values(summary) == {'sim_time': '1.500000000', 'widgets': '3'}
    stamp = first.header.stamp.sec + first.header.stamp.nanosec * 1e-9
    assert abs(stamp - time.time()) < 10, 'stamped with the wall clock'

    # A problem: reported at once, alone, with its kind as task and key 'event'; two more
    # right after it are counted but throttled.
    n = len(arrays)
    sim['t'] = 2.25
    diag.problem('bad_input', 'input refused: 7 is odd', value=7)
    sim['t'] = 2.5
    diag.problem('bad_input', 'input refused: 9 is odd', value=9)
    diag.problem('bad_input', 'input refused: 11 is odd', value=11)
    ros.wait_for(lambda: [a for a in arrays[n:] if named(a, 'bad_input')],
                 what='the immediate report')
    now = [a for a in arrays[n:] if not named(a, SUMMARY_TASK)]
    assert len(now) == 1 and len(now[0].status) == 1, 'one immediate report, throttled'
    report = now[0].status[0]
    assert report.level == DiagnosticStatus.WARN and report.hardware_id == 'arm_sim'
    assert report.message == 'input refused: 7 is odd'
    assert values(report) == {'event': 'bad_input', 'count': '1', 'sim_time': '2.250000000',
                              'value': '7'}

    # The next periodic report: the summary untouched, the problem's own status at its
    # level with the last occurrence and every one counted, without 'event'.
    ros.wait_for(lambda: periodic(arrays[n:]), what='the next periodic report')
    after = periodic(arrays[n:])[0]
    assert [s.name for s in after.status] == ['diag_test/probe: summary',
                                               'diag_test/probe: bad_input']
    summary, kind = named(after, SUMMARY_TASK), named(after, 'bad_input')
    assert summary.level == DiagnosticStatus.OK and summary.message == 'all fine'
    assert kind.level == DiagnosticStatus.WARN and kind.message == 'input refused: 11 is odd'
    assert values(kind) == {'count': '3', 'sim_time': '2.500000000', 'value': '11'}

    # No occurrence since: it decays to OK and keeps its count.
    ros.wait_for(lambda: len(periodic(arrays[n:])) >= 2, what='one more periodic report')
    kind = named(periodic(arrays[n:])[1], 'bad_input')
    assert kind.level == DiagnosticStatus.OK
    assert kind.message == ('none since the last report (3 in total); last: input refused: '
                            '11 is odd')
    assert values(kind) == {'last_level': 'WARN', 'count': '3', 'sim_time': '2.500000000',
                            'value': '11'}

    # An event: its own task too, level OK, reported at once (never throttled).
    m = len(arrays)
    diag.event('thing_done', 'did it', items=2)
    diag.event('thing_done', 'did it again', items=4)
    ros.wait_for(lambda: len([a for a in arrays[m:] if named(a, 'thing_done')
                              and not named(a, SUMMARY_TASK)]) >= 2, what='both events')
    done = [named(a, 'thing_done') for a in arrays[m:] if not named(a, SUMMARY_TASK)]
    assert [(s.level, s.message, values(s)['count'], values(s)['event']) for s in done] == [
        (DiagnosticStatus.OK, 'did it', '1', 'thing_done'),
        (DiagnosticStatus.OK, 'did it again', '2', 'thing_done')]
    ros.wait_for(lambda: periodic(arrays[m:]), what='a periodic report with the event')
    assert [s.name for s in periodic(arrays[m:])[0].status] == [
        'diag_test/probe: summary', 'diag_test/probe: bad_input',
        'diag_test/probe: thing_done'], 'one status per task, all in one array'
