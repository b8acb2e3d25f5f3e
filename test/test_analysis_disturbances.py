"""Bags of a real arm, without ROS: simulator/events (pushes and faults), the friction loss
and the push response of ``arm-sim analyze`` against hand-computed values.

Tolerances: figures that are sums or maxima of the constructed values are compared to
1e-12 relative (or 1e-9 m where positions went through inverse then forward kinematics);
recovery times to one sample period (the first sample back in the band follows the
crossing by less than one period).
"""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from arm_bag import metrics
from arm_bag.analysis import analyze
from arm_bag.cdr import (
    CdrError,
    DiagnosticStatusMsg,
    decode_diagnostic_status,
    encode_diagnostic_status,
)
from arm_bag.cli import main
from arm_bag.msgdefs import QosProfile, qos_yaml, schema_text, type_hash
from arm_bag.reader import PUSH_KINDS, SimEvent, read_bag, sim_event
from arm_bag.report import format_events, format_table
from arm_bag.synthetic import (
    ROBOT,
    encode_event,
    joint_state_block,
    make_event,
    open_bag,
    write_events,
    write_run,
)
from arm_bag.topics import DEFAULT_TOPICS, KNOWN_TOPICS, LATCHED
from arm_dynamics import TwoLinkArm

ARM = TwoLinkArm()  # the default robot's, as the bag's robot record
STAMP0 = 1_000_000_000  # ns: the run's first state
DT = 0.01  # s: the state period of the synthetic runs


def ik(xy: np.ndarray) -> np.ndarray:
    return np.unwrap(ARM.inverse_kinematics(xy, 'down'), axis=0)


# ---------------------------------------------------------------------- topics and CDR
def test_events_and_live_pushes_are_known_topics_recorded_by_default_not_latched():
    assert KNOWN_TOPICS['simulator/events'] == 'diagnostic_msgs/msg/DiagnosticStatus'
    assert KNOWN_TOPICS['simulator/push'] == 'geometry_msgs/msg/WrenchStamped'
    assert {'simulator/events', 'simulator/push'} <= set(DEFAULT_TOPICS)
    assert not {'simulator/events', 'simulator/push'} & LATCHED


def test_the_readers_push_kinds_are_the_simulators():
    from arm_dynamics.disturbance import FAULT_KINDS
    from arm_dynamics.disturbance import PUSH_KINDS as SIM_PUSH_KINDS

    assert PUSH_KINDS == SIM_PUSH_KINDS and not set(PUSH_KINDS) & set(FAULT_KINDS)


def test_diagnostic_status_round_trips_and_is_the_cdr_rosbags_writes():
    values = [('time_ns', '1500000000'), ('kind', 'tip_force'), ('edge', 'start'),
              ('label', 'pushes[0]')]
    data = encode_diagnostic_status(0, 'simulator: push',
                                    'push: tip force [0, -30] N pulse 0.1 s', '', values)
    msg = decode_diagnostic_status(data)
    assert msg == DiagnosticStatusMsg(0, 'simulator: push',
                                      'push: tip force [0, -30] N pulse 0.1 s', '',
                                      tuple(values))
    assert msg.value('edge') == 'start' and msg.value('nope', 'x') == 'x'
    # the layout by hand: header, byte level, then strings aligned to 4 (length with NUL)
    assert data[:5] == b'\x00\x01\x00\x00\x00' and data[5:8] == b'\x00\x00\x00'
    assert struct.unpack_from('<I', data, 8)[0] == len('simulator: push') + 1
    typesys = pytest.importorskip('rosbags.typesys')
    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    kv = store.types['diagnostic_msgs/msg/KeyValue']
    status = store.types['diagnostic_msgs/msg/DiagnosticStatus'](
        level=0, name=msg.name, message=msg.message, hardware_id='',
        values=[kv(key=k, value=v) for k, v in values])
    theirs = bytes(store.serialize_cdr(status, 'diagnostic_msgs/msg/DiagnosticStatus'))
    assert theirs == data


def test_diagnostic_status_ignores_padding_bytes_and_refuses_malformed_data():
    data = bytearray(encode_diagnostic_status(1, 'simulator: fault', 'fault: x', '',
                                              [('time_ns', '7')]))
    data[5:8] = b'\x7f\x55\x7f'  # padding after the level: rclpy leaves whatever was there
    assert decode_diagnostic_status(bytes(data)).level == 1
    with pytest.raises(CdrError, match='truncated'):
        decode_diagnostic_status(bytes(data[:-3]))
    with pytest.raises(CdrError, match='encapsulation'):
        decode_diagnostic_status(b'\x00\x00\x00\x00' + bytes(data[4:]))
    with pytest.raises(CdrError, match='bytes after the end'):
        decode_diagnostic_status(bytes(data) + b'\x00' * 8)
    with pytest.raises(CdrError, match='truncated'):  # a huge KeyValue count
        decode_diagnostic_status(bytes(data[:-20]) + struct.pack('<I', 0xFFFFFFFF))


def test_a_status_without_an_integer_time_or_a_known_edge_is_no_event():
    good = DiagnosticStatusMsg(1, 'simulator: fault', 'fault: brake', '',
                               (('time_ns', '42'), ('kind', 'brake'), ('edge', 'end'),
                                ('label', 'faults[0]')))
    assert sim_event(good) == SimEvent(42, 'simulator: fault', 'brake', 'end', 'faults[0]',
                                       'fault: brake', 1)
    for values in ((('time_ns', '4.2'), ('edge', 'start')), (('edge', 'start'),),
                   (('time_ns', '42'), ('edge', 'middle'))):
        with pytest.raises(CdrError):
            sim_event(DiagnosticStatusMsg(0, 'simulator: push', '', '', values))


def test_events_are_read_by_simulated_time_and_undecodable_ones_counted(tmp_path):
    w, ch = open_bag(tmp_path / 'bag', events=True)
    log = write_run(w, ch, 1000, np.arange(3) * DT, np.zeros((3, 2)), np.zeros((3, 2)),
                    np.zeros((3, 2)), None, stamp0=STAMP0)
    events = [make_event(STAMP0 + 20_000_000, 'brake', 'end', 'faults[0]'),
              make_event(STAMP0 + 10_000_000, 'tip_force', 'start', 'pushes[0]'),
              make_event(STAMP0 + 10_000_000, 'brake', 'start', 'faults[0]')]
    log = write_events(w, ch, events, log)
    bad = encode_diagnostic_status(0, 'simulator: push', 'push: x', '', [('edge', 'start')])
    w.write(ch['/simulator/events'], bad, log)  # no time_ns
    w.write(ch['/simulator/events'], encode_event(events[0])[:-6], log + 1000)  # truncated
    w.close()
    bag = read_bag(tmp_path / 'bag')
    assert bag.events == [events[1], events[2], events[0]], 'by time, then as received'
    assert bag.events[0].is_push and not bag.events[1].is_push
    assert bag.topics['/simulator/events'][1] == 5
    assert [x for x in bag.warnings if 'simulator/events' in x] == [
        '/simulator/events: 2 messages could not be decoded as simulator events '
        '(DiagnosticStatus with an integer time_ns and an edge)']


# ---------------------------------------------------------------------- friction loss
# Joint 1 goes 0 -> 1 -> -0.5 -> 0.25 rad (reversing at samples), joint 2 0 -> 2 rad: path
# lengths 3.25 and 2 rad; with coulomb_friction (1.5, 0.5) N m the loss is 5.875 J.
KNOTS_1 = [0.0, 1.0, -0.5, 0.25]
COULOMB = [1.5, 0.5]
LOSS = 1.5 * 3.25 + 0.5 * 2.0


def zigzag(n_per_leg: int) -> np.ndarray:
    legs = [np.linspace(a, b, n_per_leg + 1)[:-1] for a, b in zip(KNOTS_1, KNOTS_1[1:])]
    q1 = np.r_[np.concatenate(legs), KNOTS_1[-1]]
    return np.stack([q1, np.linspace(0.0, 2.0, len(q1))], 1)


def test_friction_loss_is_coulomb_times_path_length_exact_when_reversals_are_sampled():
    q = zigzag(7)
    assert metrics.friction_loss(COULOMB, q) == pytest.approx(LOSS, rel=1e-12)
    assert metrics.friction_loss([0.0, 0.0], q) == 0.0
    assert metrics.friction_loss(COULOMB, q[:1]) == 0.0
    q_nan = q.copy()
    q_nan[3, 0] = np.nan  # the two periods touching it are left out
    expected = LOSS - 1.5 * 2 * abs(q[1, 0] - q[0, 0]) - 0.5 * 2 * (q[1, 1] - q[0, 1])
    assert metrics.friction_loss(COULOMB, q_nan) == pytest.approx(expected, rel=1e-12)
    # a reversal inside a period: 0 -> 1.2 -> 1 counts the net 1 rad, not the 1.4 rad run
    assert metrics.friction_loss([2.0], [[0.0], [1.0]]) == 2.0
    with pytest.raises(ValueError, match='coulomb must have 2 values'):
        metrics.friction_loss([1.0], q)


def friction_bag(path, coulomb, segments: int = 2, true_state: bool = True) -> np.ndarray:
    """The zigzag as ``segments`` regulation segments; the measured positions are 0.01 rad
    off the true ones (so the loss shows which it used). Returns the true positions."""
    robot = {**ROBOT, **({} if coulomb is None else {'coulomb_friction': coulomb})}
    w, ch = open_bag(path, robot=robot, true_state=true_state)
    q = zigzag(10)
    n = len(q)
    log = 1000
    for k, part in enumerate(np.array_split(np.arange(n), segments)):
        qs = q[part]
        log = write_run(w, ch, log, np.arange(len(part)) * DT, qs + 0.01 * (k + 1),
                        np.zeros_like(qs), np.zeros_like(qs), None,
                        (np.stack([qs[0], qs[-1]]), np.array([0.0, 1.0])),
                        stamp0=STAMP0 + int(part[0]) * 10_000_000,
                        q_true=qs if true_state else None)
    w.close()
    return q


def test_friction_loss_of_the_run_and_its_segments_on_the_true_positions(tmp_path):
    friction_bag(tmp_path / 'bag', COULOMB)
    rep = analyze(tmp_path / 'bag')
    assert rep.state_source == 'true_joint_states' and rep.warnings == []
    assert rep.run['friction_loss'] == pytest.approx(LOSS, rel=1e-12)
    parts = [seg.friction_loss for seg in rep.segments]
    assert len(parts) == 2 and sum(parts) == pytest.approx(LOSS, rel=1e-12), \
        'segments add up to the run (a segment has the period to the next one)'
    doc = rep.to_dict()
    assert doc['run']['friction_loss'] == rep.run['friction_loss']
    assert [s['friction_loss'] for s in doc['segments']] == parts
    table = format_table([rep])
    run_row = [line.split() for line in table.splitlines()
               if line.startswith('run friction loss [J]')]
    assert run_row == [['run', 'friction', 'loss', '[J]', f'{LOSS:.4g}']]
    assert table.count('\n  friction loss [J]') == 2, 'a row in each segment'


def test_without_coulomb_friction_there_is_no_friction_loss(tmp_path):
    for name, coulomb in (('none', None), ('zero', [0.0, 0.0])):
        friction_bag(tmp_path / name, coulomb)
        rep = analyze(tmp_path / name)
        doc = rep.to_dict()
        assert 'friction_loss' not in doc['run'], name
        assert all('friction_loss' not in s for s in doc['segments']), name
        assert rep.segments[0].friction_loss is None
        assert 'friction loss' not in format_table([rep])
    friction_bag(tmp_path / 'bad', [1.0])
    rep = analyze(tmp_path / 'bad')
    assert 'friction_loss' not in rep.run
    assert any('coulomb_friction=[1.0] unusable' in x for x in rep.warnings)


# ---------------------------------------------------------------------- pushes
PUSH_1 = STAMP0 + 1_000_000_000  # the first push, 1 s into the run
PUSH_2 = STAMP0 + 3_000_000_000  # a held one, 3 s in
N = 401  # states: 4 s at 100 Hz
D, TAU, HELD = 0.05, 0.2, 0.02  # m, s, m


def deviation(t: np.ndarray) -> np.ndarray:
    """The tip's distance [m] from where it should be at ``t`` [s since the first state]:
    after the first push ``D x e^(1 - x)``, x = (t - 1) / TAU (peak D at x = 1), plus
    HELD after the second push (a step push: never recovers)."""
    x = np.maximum(t - 1.0, 0.0) / TAU
    return D * x * np.exp(1.0 - x) + np.where(t > 3.0, HELD, 0.0)


def recovery_expected() -> float:
    """When D x e^(1 - x) falls back to the band, 5% of D (above 1 mm), past the peak."""
    lo, hi = 1.0, 20.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if mid * np.exp(1.0 - mid) > 0.05 else (lo, mid)
    return TAU * lo


def push_bag(path, reference: bool, faults: bool = True, events: bool = True):
    """The tip moves along a line (the reference) or rests, and is pushed off it along
    the unit vector (0.6, 0.8) by :func:`deviation`. The measured positions are 0.02 rad
    off the true ones. Returns (true q (N, 2), its t (N,) s, the intended q)."""
    w, ch = open_bag(path, true_state=True, events=events)
    stamps = STAMP0 + np.arange(N, dtype=np.int64) * 10_000_000
    t = (stamps - STAMP0) * 1e-9
    if reference:
        home = np.array([1.2, 0.3]) + np.outer(t, [-0.05, 0.05])
    else:
        home = np.tile([1.2, 0.3], (N, 1))
    q_home = ik(home)
    q = ik(home + deviation(t)[:, None] * np.array([0.6, 0.8]))
    zero = np.zeros((N, 2))
    log = write_run(w, ch, 1000, t, q + [0.02, 0.0], zero, zero,
                    q_home if reference else None,
                    (np.stack([q_home[0], q_home[-1]]), np.array([0.0, 4.0])),
                    stamp0=STAMP0, q_true=q)
    if events:
        ev = [make_event(PUSH_1, 'tip_force', 'start', 'pushes[0]',
                         'push: tip force [0, -30] N pulse 0.1 s'),
              make_event(PUSH_1 + 100_000_000, 'tip_force', 'end', 'pushes[0]',
                         'push end: tip force [0, -30] N pulse 0.1 s'),
              make_event(PUSH_2, 'tip_force', 'start', 'live',
                         'push: tip force [5, 5] N step (held)')]
        if faults:
            ev += [make_event(STAMP0 + 1_500_000_000, 'torque_loss', 'start', 'faults[0]',
                              'fault: joint 1 (joint1) torque loss: delivers 0.5 x its '
                              'command until 2 s'),
                   make_event(STAMP0 + 2_000_000_000, 'torque_loss', 'end', 'faults[0]',
                              'fault end: joint 1 (joint1) torque loss: delivers 0.5 x '
                              'its command'),
                   make_event(STAMP0 + 2_500_000_000, 'commands_dropped', 'start',
                              'faults[1]', 'fault: effort commands dropped (to the end)')]
        write_events(w, ch, ev, log)
    w.close()
    return q, t, q_home


@pytest.mark.parametrize('reference', [True, False], ids=['reference', 'at_rest'])
def test_a_push_gives_its_peak_deviation_and_recovery_time(tmp_path, reference):
    q, t, q_home = push_bag(tmp_path / 'bag', reference)
    rep = analyze(tmp_path / 'bag')
    assert rep.state_source == 'true_joint_states'
    first, second = rep.pushes
    assert (first['time'], first['end'], first['label'], first['kind']) == (
        pytest.approx(1.0, abs=1e-12), pytest.approx(1.1, abs=1e-12), 'pushes[0]',
        'tip_force')
    assert first['description'] == 'push: tip force [0, -30] N pulse 0.1 s'
    assert first['baseline'] == ('reference' if reference else 'push_start')
    assert first['peak_deviation'] == pytest.approx(D, abs=1e-9)  # at x = 1, a sample
    late = first['recovery_time'] - recovery_expected()
    assert 0.0 <= late <= DT + 1e-9, 'back in the band within one sample of the crossing'
    window = (t >= 1.0) & (t < 3.0)
    assert first['peak_joint_deviation'] == pytest.approx(
        np.abs(q[window] - q_home[window]).max(axis=0), rel=1e-12)
    # the held push: its window runs to the end of the run, and it never recovers
    assert second['label'] == 'live' and second['end'] is None
    at_push = 0.0 if reference else deviation(np.array([3.0]))[0]  # where it should be
    assert second['peak_deviation'] == pytest.approx(
        np.abs(deviation(t[t >= 3.0]) - at_push).max(), abs=1e-9)
    assert second['recovery_time'] is None


def test_push_response_band_is_1_mm_or_5_percent_of_the_peak():
    t = np.arange(6) * 0.1
    # peak 0.1 m: band 5 mm; last outside at 0.2 s, so back from 0.3 s on
    assert metrics.push_response(t, [0.0, 0.1, 0.006, 0.004, 0.0, 0.0], 0.0) == (
        0.1, pytest.approx(0.3))
    # peak 10 mm: band 1 mm (5% would be 0.5 mm)
    assert metrics.push_response(t, [0.0, 0.01, 0.0011, 0.0009, 0.0, 0.0], 0.0) == (
        0.01, pytest.approx(0.3))
    assert metrics.push_response(t, [0.0005] * 6, 0.0) == (0.0005, 0.0), 'never left'
    assert metrics.push_response(t, [0.0, 0.1, 0.0, 0.0, 0.0, 0.1], 0.0)[1] is None
    assert metrics.push_response(t[:0], [], 0.0) == (None, None)
    meaning = {m.name: m.meaning for m in metrics.DISTURBANCE_METRICS}
    assert 'max(1 mm, 5% of peak_deviation)' in meaning['recovery_time']
    assert 'reverses' in meaning['friction_loss']


def test_push_joint_deviation_works_for_any_joint_count_without_a_tip(tmp_path):
    names = ('joint1', 'joint2', 'joint3')
    w, ch = open_bag(tmp_path / 'bag', events=True)
    ty = 'sensor_msgs/msg/JointState'
    js = w.add_topic('/arm3/joint_states', ty, schema_text(ty), qos_yaml([QosProfile()]),
                     type_hash(ty))
    stamps = STAMP0 + np.arange(50, dtype=np.int64) * 10_000_000
    q = np.zeros((50, 3))
    q[21:, 2] = 0.3 * np.exp(-np.arange(29) * 0.1)  # joint 3 pushed at sample 20
    zero = np.zeros((50, 3))
    for i, data in enumerate(joint_state_block(stamps, q, zero, zero, names)):
        w.write(js, data, 1000 + i)
    write_events(w, ch, [make_event(int(stamps[20]), 'joint_torque', 'start',
                                    'pushes[0]')], 10**6)
    w.close()
    rep = analyze(tmp_path / 'bag')
    (push,) = rep.pushes
    assert push['peak_joint_deviation'] == pytest.approx([0.0, 0.0, 0.3], rel=1e-12)
    assert push['peak_deviation'] is None and push['recovery_time'] is None
    assert push['baseline'] == 'push_start'


# ---------------------------------------------------------------------- faults, output
def test_faults_are_listed_with_their_start_and_end(tmp_path):
    push_bag(tmp_path / 'bag', reference=True)
    rep = analyze(tmp_path / 'bag')
    assert [(f['label'], f['kind'], f['time'], f['end']) for f in rep.faults] == [
        ('faults[0]', 'torque_loss', pytest.approx(1.5), pytest.approx(2.0)),
        ('faults[1]', 'commands_dropped', pytest.approx(2.5), None)]
    assert rep.faults[0]['time_ns'] == STAMP0 + 1_500_000_000
    assert rep.faults[0]['end_ns'] == STAMP0 + 2_000_000_000
    assert rep.faults[1]['description'] == 'fault: effort commands dropped (to the end)'


def test_an_end_without_its_start_is_warned_about(tmp_path):
    w, ch = open_bag(tmp_path / 'bag', events=True)
    log = write_run(w, ch, 1000, np.arange(5) * DT, np.zeros((5, 2)), np.zeros((5, 2)),
                    np.zeros((5, 2)), None, stamp0=STAMP0)
    write_events(w, ch, [make_event(STAMP0 + 20_000_000, 'brake', 'end', 'faults[3]')], log)
    w.close()
    rep = analyze(tmp_path / 'bag')
    assert rep.faults == [] and rep.pushes == []
    assert 'fault faults[3] (brake) ends at 0.020 s without a start in the bag' in \
        rep.warnings


def test_analyze_prints_a_pushes_table_and_a_faults_list_and_json_has_them(tmp_path,
                                                                            capsys):
    push_bag(tmp_path / 'bag', reference=True)
    assert main(['analyze', str(tmp_path / 'bag')]) == 0
    out = capsys.readouterr().out
    text = out.split('\n\npushes\n', 1)[1]
    lines = text.splitlines()
    heads = [h for h in lines[0].strip().split('  ') if h]
    assert heads == ['time [s]', 'end [s]', 'label'] + [
        f'{m.label} [{m.unit}]' for m in metrics.PUSH_METRICS] + ['description']
    row = lines[2].split()
    assert row[:4] == ['1.000', '1.100', 'pushes[0]', f'{D:.3g}']
    assert lines[3].split()[:3] == ['3.000', '-', 'live'] and ' - ' in lines[3]
    assert 'faults\n  1.500 s until 2.000 s  faults[0] (torque_loss): fault: joint 1' in text
    assert '  2.500 s to the end  faults[1] (commands_dropped): fault: effort' in text
    assert main(['analyze', str(tmp_path / 'bag'), '--json']) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [p['label'] for p in doc['pushes']] == ['pushes[0]', 'live']
    assert list(doc['pushes'][0]) == ['time', 'time_ns', 'end', 'end_ns', 'kind', 'label',
                                      'description', 'baseline', 'peak_deviation',
                                      'recovery_time', 'peak_joint_deviation']
    assert doc['pushes'][1]['recovery_time'] is None
    assert [f['kind'] for f in doc['faults']] == ['torque_loss', 'commands_dropped']


def test_bags_without_events_report_exactly_as_before(tmp_path, capsys):
    push_bag(tmp_path / 'with', reference=True)
    push_bag(tmp_path / 'without', reference=True, events=False)
    with_events = analyze(tmp_path / 'with').to_dict()
    without = analyze(tmp_path / 'without').to_dict()
    assert 'pushes' not in without and 'faults' not in without
    assert format_events([analyze(tmp_path / 'without')]) == ''
    del with_events['pushes'], with_events['faults']
    for doc in (with_events, without):
        del doc['bag'], doc['message_counts']
    assert with_events == without, 'the events add their lists, nothing else'
    assert main(['analyze', str(tmp_path / 'without')]) == 0
    out = capsys.readouterr().out
    assert 'pushes' not in out and 'faults' not in out
    assert out == format_table([analyze(tmp_path / 'without')]) + '\n'


def test_comparing_bags_names_each_bags_pushes(tmp_path):
    push_bag(tmp_path / 'a', reference=True, faults=False)
    push_bag(tmp_path / 'b', reference=False, events=False)
    text = format_events([analyze(tmp_path / 'a'), analyze(tmp_path / 'b')])
    assert text.startswith(f"pushes ({tmp_path / 'a'})\n") and 'faults' not in text
    assert str(tmp_path / 'b') not in text


def test_the_docs_hold_the_disturbance_metric_table():
    from pathlib import Path

    from arm_bag.metrics import disturbance_metrics_markdown

    text = (Path(__file__).resolve().parents[1] / 'docs' / 'bags.md').read_text()
    marker = '<!-- generated: arm_bag.metrics.disturbance_metrics_markdown -->\n'
    assert marker in text, 'docs/bags.md lacks the generated disturbance metric table'
    block = text.split(marker, 1)[1].split('<!-- end generated -->', 1)[0]
    assert block == disturbance_metrics_markdown(), (
        f'docs/bags.md is out of date; replace its block with:\n'
        f'{disturbance_metrics_markdown()}')
