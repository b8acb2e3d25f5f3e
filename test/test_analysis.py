"""Bag analysis without ROS: metrics against hand-computed values, reader robustness, CLI."""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from arm_bag import metrics
from arm_bag.analysis import Segment, analyze
from arm_bag.cdr import decode_joint_states_bulk, encode_joint_state
from arm_bag.reader import BagError, read_bag
from arm_bag.synthetic import open_bag, write_run
from arm_bag.writer import RECORDING_KEY, RESERVE_NAME, BagWriteError, BagWriter
from arm_dynamics import TwoLinkArm

ROOT = Path(__file__).resolve().parents[1]
ARM = TwoLinkArm()


def ik(xy: np.ndarray) -> np.ndarray:
    """The default arm's joint angles for tip points (elbow 'down', q2 >= 0), (N, 2) m ->
    (N, 2) rad, unwrapped so a path stays continuous."""
    return np.unwrap(ARM.inverse_kinematics(xy, 'down'), axis=0)


# ---------------------------------------------------------------------- metrics
def test_settling_time_and_overshoot_match_hand_values():
    t = np.arange(7.0)
    q = np.array([0.0, 0.5, 1.2, 1.1, 1.01, 1.0, 1.0])
    assert metrics.overshoot(q, 0.0, 1.0) == pytest.approx(20.0)
    # |q - 1| > 0.02 last at t = 3 (1.1), inside from t = 4 on
    assert metrics.settling_time(t, q, 0.0, 1.0) == 4.0
    assert metrics.settling_time(t, np.r_[q[:-1], 1.5], 0.0, 1.0) is None
    assert metrics.overshoot(-q, 0.0, -1.0) == pytest.approx(20.0), 'negative step'
    assert metrics.overshoot(q, 1.0, 1.0) is None, 'zero step'


# A 3-4-5 segment: from A to B is 5 m along U; N is normal to it. Points are built as
# A + s U + h N, so their distances follow by hand (exact to rounding: tolerance 1e-12 m).
SEG_A, SEG_B = np.array([1.0, 1.0]), np.array([4.0, 5.0])
SEG_U, SEG_N = np.array([0.6, 0.8]), np.array([-0.8, 0.6])


def on_seg(s: float, h: float) -> np.ndarray:
    return SEG_A + s * SEG_U + h * SEG_N


def test_segment_deviation_is_perpendicular_alongside_and_to_the_end_point_beyond():
    xy = [on_seg(2.0, 0.5),    # alongside: 0.5 m across
          on_seg(8.0, 4.0),    # 3 m past B, 4 m across: 5 m from B (the line: 4 m)
          on_seg(-0.3, -0.4),  # 0.3 m before A, 0.4 m across: 0.5 m from A
          on_seg(5.0, 0.0),    # B itself
          on_seg(0.0, -2.0)]   # 2 m across at A
    dev = metrics.segment_deviation(xy, SEG_A, SEG_B)
    assert dev == pytest.approx([0.5, 5.0, 0.5, 0.0, 2.0], abs=1e-12)


def test_overshoot_along_line_counts_only_the_distance_beyond_each_end():
    xy = [on_seg(2.0, 0.5), on_seg(8.0, 4.0), on_seg(-0.3, -0.4), on_seg(5.0, 0.0),
          on_seg(5.002, -0.001)]  # 2 mm past B, 1 mm across
    before, past = metrics.overshoot_along_line(xy, SEG_A, SEG_B)
    assert before == pytest.approx([0.0, 0.0, 0.3, 0.0, 0.0], abs=1e-12)
    assert past == pytest.approx([0.0, 3.0, 0.0, 0.0, 0.002], abs=1e-12)
    # the direction matters: the same points on the segment from B to A
    before, past = metrics.overshoot_along_line(xy, SEG_B, SEG_A)
    assert before == pytest.approx([0.0, 3.0, 0.0, 0.0, 0.002], abs=1e-12)
    assert past == pytest.approx([0.0, 0.0, 0.3, 0.0, 0.0], abs=1e-12)


def test_a_zero_length_segment_gives_the_distance_to_its_point_and_no_overshoot():
    xy = [[4.0, 6.0], [1.0, 2.0]]  # 3-4-5 from (1, 2), and the point itself
    with np.errstate(all='raise'):  # a division by zero would raise here
        dev = metrics.segment_deviation(xy, [1.0, 2.0], [1.0, 2.0])
        before, past = metrics.overshoot_along_line(xy, [1.0, 2.0], [1.0, 2.0])
    assert dev == pytest.approx([5.0, 0.0], abs=1e-12)
    assert before.tolist() == [0.0, 0.0] and past.tolist() == [0.0, 0.0]


def test_straight_line_check_energy_and_torque_stats_match_hand_values():
    t = np.linspace(0, 1, 11)
    tau = np.tile([2.0, -1.0], (11, 1))
    q = np.outer(t, [3.0, 4.0])  # constant speeds 3 and 4 rad/s for 1 s
    assert metrics.energy_delivered(tau, q) == pytest.approx(6.0 - 4.0)
    stats = metrics.torque_stats([[60.0, 1.0], [-59.0, -20.0], [0.0, 3.0], [60.0, 0.0]],
                                 [60.0, 20.0])
    assert stats['peak'] == pytest.approx([60.0, 20.0])
    assert stats['saturated_fraction'] == pytest.approx([0.5, 0.25])
    assert stats['rms'] == pytest.approx(np.sqrt([(3600 + 3481 + 3600) / 4,
                                                  (1 + 400 + 9) / 4]))
    assert metrics.is_straight_line([[0, 0], [0.5, 5e-7], [1, 0]])
    assert not metrics.is_straight_line([[0, 0], [0.5, 2e-6], [1, 0]])
    assert not metrics.is_straight_line([[0, 0], [1, 0]]), 'needs >= 3 points'
    with pytest.raises(ValueError, match='effort_limits'):
        metrics.torque_stats([[1.0, 2.0]], [1.0])


# ---------------------------------------------------------------------- synthetic runs
def synthetic_bag(path: Path, robot=True, reference=True) -> dict:
    """A regulation segment (known overshoot, settling) then a straight-line segment
    (known deviation); returns the expected values."""
    w, ch = open_bag(path, **({} if robot else {'robot': None}))
    # regulation: joint 1 steps 0 -> 1 rad with 20 % overshoot, joint 2 stays at 0.5
    t = np.arange(7) * 0.5
    q1 = np.array([0.0, 0.5, 1.2, 1.1, 1.01, 1.0, 1.0])
    q = np.stack([q1, np.full(7, 0.5)], 1)
    qd = np.tile([1.0, 0.0], (7, 1))
    tau = np.tile([60.0, 5.0], (7, 1))
    ref = q - 0.01  # tracking error exactly 0.01 rad
    log = write_run(w, ch, 1_000_000_000, t, q, qd, tau, ref if reference else None,
                    (np.array([[0.0, 0.5], [1.0, 0.5]]), np.array([0.0, 3.0])),
                    stamp0=1_000_000_000)
    # straight line from (1.2, 0.3) to (0.6, 0.9); the tip runs 2 mm off it at mid-way
    a, b = np.array([1.2, 0.3]), np.array([0.6, 0.9])
    s = np.linspace(0, 1, 21)
    normal = np.array([1.0, 1.0]) / np.sqrt(2)
    off = 0.002 * np.sin(np.pi * s)
    xy = a + s[:, None] * (b - a) + off[:, None] * normal
    q_line = ik(xy)
    path_xy = a + np.linspace(0, 1, 5)[:, None] * (b - a)
    n = len(s)
    write_run(w, ch, log + 10_000, np.arange(n) * 0.1, q_line, np.zeros((n, 2)),
              np.zeros((n, 2)), q_line if reference else None,
              (ik(path_xy), np.linspace(0, 2, 5)), path_xy, stamp0=10_000_000_000)
    w.close()
    return {'deviation_max': 0.002, 'deviation_rms': 0.002 * np.sqrt(np.mean(
        np.sin(np.pi * s) ** 2))}


def test_regulation_and_straight_line_segments_match_hand_values(tmp_path):
    expected = synthetic_bag(tmp_path / 'bag')
    rep = analyze(tmp_path / 'bag')
    assert rep.robot_source == 'bag' and rep.warnings == []
    reg, line = rep.segments
    assert (reg.mode, line.mode) == ('regulation', 'straight_line')
    assert reg.duration == pytest.approx(3.0) and reg.samples == 7
    assert reg.overshoot[0] == pytest.approx(20.0)
    assert reg.settling_time[0] == pytest.approx(2.0)  # t[4] - t[0] = 4 * 0.5 s
    assert reg.settling_time[1] is None, 'joint 2 has no step'
    assert reg.settling_time_overall == pytest.approx(2.0)
    assert reg.tracking_rms == pytest.approx([0.01, 0.01], abs=1e-12)
    assert reg.tracking_max == pytest.approx([0.01, 0.01], abs=1e-12)
    assert reg.saturated_fraction == pytest.approx([1.0, 0.0])
    # the work of the held torques: 60 N m while joint 1 goes 0 -> 1 rad, joint 2 does
    # not move, and the line's first period is held at zero torque
    assert reg.energy == pytest.approx(60.0 * 1.0)
    assert line.deviation_max == pytest.approx(expected['deviation_max'], abs=1e-9)
    assert line.deviation_rms == pytest.approx(expected['deviation_rms'], abs=1e-9)
    assert line.line_overshoot_end == pytest.approx(0.0, abs=1e-9), 'stops at its end'
    assert line.line_overshoot_start == pytest.approx(0.0, abs=1e-9)
    assert reg.line_overshoot_end is None and reg.deviation_max is None, 'no line'
    assert line.tracking_rms == pytest.approx([0, 0], abs=1e-12)
    doc = json.loads(json.dumps(rep.to_dict()))
    assert doc['segments'][1]['deviation_max'] == pytest.approx(0.002, abs=1e-9)


def test_segments_depend_on_simulated_time_only_not_on_receive_times_or_resent_states(
        tmp_path):
    """The same joint states give the same table when the recorder received the
    trajectories late (after some of their states) and when states were re-sent."""
    synthetic_bag(tmp_path / 'bag')
    bag = read_bag(tmp_path / 'bag')
    base = analyze(tmp_path / 'bag').to_dict()
    js = bag.joint_states
    for tr in bag.trajectories:  # received 3 states after their start
        tr.log_time = int(js.log_time[np.searchsorted(js.log_time, tr.log_time) + 3])
    dup = np.repeat(np.arange(len(js)), np.where(np.arange(len(js)) % 4 == 0, 3, 1))
    bag.joint_states = type(js)(js.topic, js.names, js.stamp[dup], js.log_time[dup],
                                js.position[dup], js.velocity[dup], js.effort[dup])
    from arm_bag.analysis import analyze_data
    lagged = analyze_data(bag).to_dict()
    assert lagged['segments'] == base['segments']
    assert lagged['run'] == base['run']


def test_a_trajectory_sent_again_unchanged_is_one_segment_and_a_changed_one_replaces_it(
        tmp_path):
    """The planner sends a trajectory again, the very same, until the controller confirms
    it: the table is that of one send. A different one with the same start replaces it."""
    import copy
    from dataclasses import replace

    from arm_bag.analysis import analyze_data
    synthetic_bag(tmp_path / 'bag')
    bag = read_bag(tmp_path / 'bag')
    base = analyze_data(bag).to_dict()
    first = bag.trajectories[0]
    again = copy.deepcopy(first)
    again.log_time += 1_000_000_000   # one second (wall) later: the planner's re-send
    bag.trajectories.insert(1, again)
    resent = analyze_data(bag).to_dict()
    assert resent['segments'] == base['segments'] and resent['warnings'] == base['warnings']
    changed = copy.deepcopy(again)
    changed.trajectory = replace(again.trajectory, positions=again.trajectory.positions + 0.1)
    bag.trajectories[1] = changed
    doc = analyze_data(bag).to_dict()
    # Not a re-send: it replaces the first at its start, which keeps no states of its own.
    assert [seg['index'] for seg in doc['segments']] == [1, 2]
    assert 'segment 0: no joint states after its trajectory' in doc['warnings']


def test_unstamped_trajectories_fall_back_to_receive_time_with_a_warning(tmp_path):
    synthetic_bag(tmp_path / 'bag')
    bag = read_bag(tmp_path / 'bag')
    for tr in bag.trajectories:
        tr.trajectory.stamp = 0
    from arm_bag.analysis import analyze_data
    rep = analyze_data(bag)
    assert [s.mode for s in rep.segments] == ['regulation', 'straight_line']
    assert any('without a header stamp' in w for w in rep.warnings)


def test_without_reference_or_robot_record_the_set_point_and_defaults_are_used(tmp_path):
    synthetic_bag(tmp_path / 'bag', robot=False, reference=False)
    rep = analyze(tmp_path / 'bag')
    assert rep.robot_source == 'defaults'
    assert any('arm_sim_robot' in w for w in rep.warnings)
    reg = rep.segments[0]
    assert reg.reference == 'set_point'
    assert reg.final_error == pytest.approx([0.0, 0.0])
    assert reg.tracking_max[0] == pytest.approx(1.0), 'largest |q - set point| at t = 0'


def test_bulk_decoder_ignores_padding_bytes_and_falls_back_for_odd_messages():
    msgs = [bytearray(encode_joint_state(i * 10, ['joint1', 'joint2'], [i, 2.0],
                                         [0.5, 1.0], [3.0, 4.0])) for i in range(5)]
    msgs[2][35] = 0xAB  # a padding byte (after 'joint1\0' + before the next string)
    msgs.append(bytearray(encode_joint_state(99, ['a'], [1.0], [], [])))
    buf = np.frombuffer(b''.join(msgs), np.uint8)
    lengths = np.array([len(m) for m in msgs])
    offsets = np.r_[0, np.cumsum(lengths)[:-1]]
    groups, bad = decode_joint_states_bulk(buf, offsets, lengths)
    assert bad == 0 and [g.names for g in groups] == [('joint1', 'joint2'), ('a',)]
    assert groups[0].position[:, 0] == pytest.approx(range(5))
    assert groups[0].stamp.tolist() == [0, 10, 20, 30, 40]
    assert np.isnan(groups[1].velocity).all()


# ---------------------------------------------------------------------- damaged bags
def test_a_cut_finished_bag_is_an_error_naming_the_cut_and_the_recover_command(tmp_path):
    """A bare .mcap (no recording marker) that was cut is never read partially: the error
    names the file, the byte where it ends and how to keep what is intact; the bag
    directory without metadata.yaml is still read in full."""
    synthetic_bag(tmp_path / 'bag')
    mcap = tmp_path / 'bag' / 'bag_0.mcap'
    data = mcap.read_bytes()
    bare = tmp_path / 'cut.mcap'
    cut = int(len(data) * 0.8)
    bare.write_bytes(data[:cut])
    with pytest.raises(BagError, match=f'{bare}: byte {cut}: .*arm-sim bag recover {bare}`'):
        read_bag(bare)
    (tmp_path / 'bag' / 'metadata.yaml').unlink()
    assert len(read_bag(tmp_path / 'bag').joint_states) == 28


def test_ros2_control_style_bag_with_only_joint_states_gives_torque_metrics(tmp_path):
    w = BagWriter(tmp_path / 'foreign')
    from arm_bag.msgdefs import schema_text
    ch = w.add_topic('/joint_states', 'sensor_msgs/msg/JointState',
                     schema_text('sensor_msgs/msg/JointState'))
    for i in range(10):
        w.write(ch, encode_joint_state(i * 10_000_000, ['shoulder', 'elbow'], [0.01 * i, 0],
                                       [1.0, 0.0], [2.0, 0.0]), 1000 + i)
    w.close()
    rep = analyze(tmp_path / 'foreign')
    assert rep.joint_names == ['shoulder', 'elbow']
    assert rep.run['energy'] == pytest.approx(2.0 * 0.09)
    assert rep.segments[0].mode is None and rep.segments[0].tracking_rms is None
    assert any('joint_trajectory' in w for w in rep.warnings)



def test_geared_link_energy_counts_the_motor_not_its_output_again(tmp_path):
    """The geared model publishes the motor (u, th_m') and the link (n u', th_m'/n): the
    link's power is the motor's passed through the gear, so energy counts the motor once."""
    n = 50.0
    w = BagWriter(tmp_path / 'geared')
    from arm_bag.msgdefs import schema_text
    ch = w.add_topic('/joint_states', 'sensor_msgs/msg/JointState',
                     schema_text('sensor_msgs/msg/JointState'))
    for i in range(11):  # motor at 2 rad/s under 0.5 N m for 0.1 s: 0.1 J
        w.write(ch, encode_joint_state(i * 10_000_000, ['joint1_motor', 'joint1'],
                                       [0.02 * i, 0.02 * i / n], [2.0, 2.0 / n],
                                       [0.5, 0.5 * n]), 1000 + i)
    w.close()
    rep = analyze(tmp_path / 'geared')
    assert rep.run['energy'] == pytest.approx(0.5 * 2.0 * 0.1, abs=1e-12)
    assert rep.run['torque_peak'] == pytest.approx([0.5, 0.5 * n]), 'both still reported'


class _Failing:
    """A file object whose next ``fails`` writes raise ``err`` (a full disk, an I/O error)."""

    def __init__(self, f, err: int, fails: int = 1) -> None:
        self.f, self.err, self.fails = f, err, fails

    def write(self, data):
        if self.fails:
            self.fails -= 1
            raise OSError(self.err, os.strerror(self.err))
        return self.f.write(data)

    def __getattr__(self, name):
        return getattr(self.f, name)


def test_a_full_disk_spends_the_reserve_on_a_complete_bag_and_refuses_more(tmp_path):
    """The first ENOSPC is absorbed by freeing the reserve file: that write lands, no
    message is accepted after it, and close() writes summary and footer (the real full disk
    is tested with the recorder on a tmpfs in test_recorder.py)."""
    w, ch = open_bag(tmp_path / 'bag', chunk_size=1 << 30)
    t = np.arange(10) * 0.01
    z = np.zeros((10, 2))
    write_run(w, ch, 1000, t, z, z, z, None)
    w.flush()
    assert (tmp_path / 'bag' / RESERVE_NAME).is_file()
    w._file.file = _Failing(w._file.file, errno.ENOSPC)
    write_run(w, ch, 10**9, t, z, z, z, None)
    w.flush_chunk()  # fails once, lands in the reserve's space
    assert not (tmp_path / 'bag' / RESERVE_NAME).exists()
    with pytest.raises(BagWriteError, match='No space left on device; recording stopped, 20'):
        write_run(w, ch, 2 * 10**9, t, z, z, z, None)
    w.close()
    assert sorted(p.name for p in (tmp_path / 'bag').iterdir()) == ['bag_0.mcap',
                                                                     'metadata.yaml']
    bag = read_bag(tmp_path / 'bag')
    assert len(bag.joint_states) == 20 and not bag.truncated and bag.warnings == []
    meta = yaml.safe_load((tmp_path / 'bag' / 'metadata.yaml').read_text())
    assert meta['rosbag2_bagfile_information']['custom_data'] == {RECORDING_KEY: 'closed'}


def test_a_failed_write_cuts_the_file_back_to_its_last_record_and_leaves_it_open(tmp_path):
    w, ch = open_bag(tmp_path / 'bag', chunk_size=1 << 30)
    t = np.arange(10) * 0.01
    z = np.zeros((10, 2))
    write_run(w, ch, 1000, t, z, z, z, None)
    w.flush()
    good = w.path.stat().st_size
    w._file.file = _Failing(w._file.file, errno.EIO)
    write_run(w, ch, 10**9, t, z, z, z, None)
    with pytest.raises(BagWriteError, match=f'{w.path} failed: Input/output error'):
        w.flush_chunk()
    with pytest.raises(BagWriteError, match='recording stopped, 10 messages kept'):
        w.close()
    assert w.path.stat().st_size == good, 'cut back to the end of the last chunk'
    meta = yaml.safe_load((tmp_path / 'bag' / 'metadata.yaml').read_text())
    info = meta['rosbag2_bagfile_information']
    assert info['custom_data'][RECORDING_KEY] == 'open' and info['message_count'] == 10
    assert not (tmp_path / 'bag' / RESERVE_NAME).exists()


# ---------------------------------------------------------------------- CLI
def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'arm_bag.cli', 'analyze', *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)


def test_cli_table_json_plot_and_comparison(tmp_path):
    synthetic_bag(tmp_path / 'a')
    synthetic_bag(tmp_path / 'b', reference=False)
    out = run_cli(str(tmp_path / 'a'), str(tmp_path / 'b'), '--plot', str(tmp_path / 'p.png'))
    assert out.returncode == 0, out.stderr
    header = out.stdout.splitlines()[0]
    assert str(tmp_path / 'a') in header and str(tmp_path / 'b') in header
    assert 'overshoot [%]' in out.stdout and (tmp_path / 'p.png').stat().st_size > 10_000
    doc = json.loads(run_cli(str(tmp_path / 'a'), '--json').stdout)
    assert doc['segments'][0]['overshoot'][0] == pytest.approx(20.0)


@pytest.mark.parametrize('kind, code', [('missing', 4), ('garbage', 4), ('empty_dir', 4),
                                        ('no_messages', 3), ('usage', 2)])
def test_cli_errors_are_one_line_with_a_distinct_exit_code(tmp_path, kind, code):
    target = tmp_path / kind
    if kind == 'garbage':
        target = tmp_path / 'x.mcap'
        target.write_bytes(b'not an mcap file at all')
    elif kind == 'empty_dir':
        target.mkdir()
    elif kind == 'no_messages':
        BagWriter(target).close()
    out = run_cli('--bogus') if kind == 'usage' else run_cli(str(target))
    assert out.returncode == code, out.stderr
    assert 'Traceback' not in out.stderr
    errors = [line for line in out.stderr.splitlines() if not line.startswith('warning:')]
    assert kind == 'usage' or len(errors) == 1, out.stderr


def test_a_tip_that_runs_past_the_line_end_is_measured_to_the_end_with_its_overshoot(
        tmp_path):
    """The tip follows the line, runs 3 mm past its end (1 mm across) and comes back: it is
    hypot(3, 1) mm from the commanded segment (1 mm from the infinite line) and overshoots
    the end by 3 mm along the line; in the report, the table and the JSON."""
    a, b = np.array([1.2, 0.3]), np.array([0.6, 0.9])
    u = (b - a) / np.hypot(*(b - a))
    normal = np.array([-u[1], u[0]])
    line = a + np.linspace(0, 1, 11)[:, None] * (b - a)
    past = b + np.outer([0.002, 0.003, 0.001, 0.0], u) + np.outer([0.0005, 0.001, 0.0, 0.0],
                                                                   normal)
    q = ik(np.vstack([line, past]))
    n = len(q)
    path_xy = a + np.linspace(0, 1, 5)[:, None] * (b - a)
    w, ch = open_bag(tmp_path / 'bag')
    write_run(w, ch, 1_000_000, np.arange(n) * 0.1, q, np.zeros((n, 2)), np.zeros((n, 2)),
              q, (ik(path_xy), np.linspace(0, 1, 5)), path_xy, stamp0=10_000_000_000)
    w.close()
    seg = analyze(tmp_path / 'bag').segments[0]
    assert seg.mode == 'straight_line'
    assert seg.deviation_max == pytest.approx(np.hypot(0.003, 0.001), abs=1e-9)
    assert seg.line_overshoot_end == pytest.approx(0.003, abs=1e-9)
    assert seg.line_overshoot_start == pytest.approx(0.0, abs=1e-9)
    out = run_cli(str(tmp_path / 'bag'))
    assert out.returncode == 0, out.stderr
    row = next(r for r in out.stdout.splitlines() if 'past line end [m]' in r)
    assert float(row.split()[-1]) == pytest.approx(0.003, rel=1e-3), row
    doc = json.loads(run_cli(str(tmp_path / 'bag'), '--json').stdout)
    assert doc['segments'][0]['line_overshoot_end'] == pytest.approx(0.003, abs=1e-9)
    assert doc['segments'][0]['deviation_max'] == pytest.approx(np.hypot(0.003, 0.001),
                                                                abs=1e-9)


def test_a_line_after_a_stop_is_measured_from_where_its_path_starts(tmp_path):
    """The planner brings a moving arm to rest before a line and stamps the path's poses
    with the line's start: the stop, off the line, does not count as line deviation."""
    a, b = np.array([1.2, 0.3]), np.array([0.6, 0.9])
    normal = np.array([1.0, 1.0]) / np.sqrt(2)
    stop = a + np.linspace(0.05, 0.0, 6)[:, None] * normal  # 50 mm off, coming to rest at a
    s = np.linspace(0, 1, 11)
    line = a + s[:, None] * (b - a) + (0.001 * np.sin(np.pi * s))[:, None] * normal
    xy = np.vstack([stop, line[1:]])
    q = ik(xy)
    n = len(xy)
    path_xy = a + np.linspace(0, 1, 5)[:, None] * (b - a)
    for path_start, expected in ((10_500_000_000, 0.001), (None, 0.05)):
        bag = tmp_path / f'bag{path_start}'
        w, ch = open_bag(bag)
        write_run(w, ch, 1_000_000, np.arange(n) * 0.1, q, np.zeros((n, 2)),
                  np.zeros((n, 2)), q, (ik(path_xy), np.linspace(0, 2, 5)), path_xy,
                  stamp0=10_000_000_000, path_start=path_start)
        w.close()
        seg = analyze(bag).segments[0]
        assert seg.mode == 'straight_line'
        assert seg.deviation_max == pytest.approx(expected, abs=1e-9), path_start


def test_energy_is_the_exact_work_of_the_held_torques_change_in_energy_plus_damping_loss():
    """On a run stepped by the simulator's own core (torque held over each 10 ms period, as
    the node publishes it), the energy metric equals the change in mechanical energy plus
    the viscous loss: to 1e-9 J without damping; with damping, the loss comes from an
    independent DOP853 integration of the same held torques (1e-8 J). The trapezoid of
    tau . qd it replaces was off by about 0.1 J on the same run."""
    from scipy.integrate import solve_ivp

    from arm_dynamics.simulation import SimulatorCore

    for damping in ((0.0, 0.0), (0.6, 0.3)):
        arm = TwoLinkArm(joint_damping=damping)
        core = SimulatorCore(arm, q0=[-0.4, 1.2], qd0=[0.0, 0.0], effort_limits=[60.0, 20.0],
                             physics_step_ns=1_000_000, control_period_ns=10_000_000,
                             velocity_limit=1000.0, joint_names=['joint1', 'joint2'])
        qs, qds, taus = [core.q.copy()], [core.qd.copy()], [np.zeros(2)]
        goal = np.array([0.3, 0.6])
        for _ in range(200):  # 2 s of PD plus gravity, saturating at first
            q, qd = core.q.copy(), core.qd.copy()
            core.command = 100 * (goal - q) - 20 * qd + arm.gravity_vector(q)
            core.advance()
            qs.append(core.q.copy())
            qds.append(core.qd.copy())
            taus.append(np.array(core.joint_view().effort))
        q, qd, tau = np.array(qs), np.array(qds), np.array(taus)
        work = metrics.energy_delivered(tau, q)
        change = sum(arm.energy(q[-1], qd[-1])) - sum(arm.energy(q[0], qd[0]))
        if not any(damping):
            assert abs(work - change) < 1e-9, work - change
            t = np.arange(len(q)) * 0.01
            trapezoid = float(np.sum(0.5 * np.diff(t) * (
                np.sum(tau[1:] * qd[1:], 1) + np.sum(tau[:-1] * qd[:-1], 1))))
            assert abs(trapezoid - change) > 1e-3, 'the old figure was measurably off'
            continue
        loss = 0.0
        x = np.r_[q[0], qd[0]]
        b = np.array(damping)
        for k in range(1, len(q)):  # the held torque of each period, integrated apart
            sol = solve_ivp(lambda _t, y, u=tau[k]: np.r_[y[2:4], arm.forward_dynamics(
                y[:2], y[2:4], u), b @ (y[2:4] ** 2)], (0, 0.01), np.r_[x, 0.0],
                method='DOP853', rtol=1e-12, atol=1e-12)
            x, loss = sol.y[:4, -1], loss + sol.y[4, -1]
        assert abs(work - (change + loss)) < 1e-8, (work, change, loss)


def test_the_report_rows_json_fields_and_sweep_columns_all_come_from_the_metric_table():
    """One table, :data:`arm_bag.metrics.METRICS`: each metric is a report row labelled with
    its unit, a JSON field of every segment, and the sweep's column(s), in the table's
    order; the sweep computes them with the same function as ``analyze``."""
    from arm_bag import metrics as m
    from arm_bag.report import _ROWS
    from arm_sim.sweep import METRIC_COLUMNS
    from arm_sim.sweep import metrics as sweep_metrics

    assert [r[1] for r in _ROWS][-len(m.METRICS):] == list(m.METRIC_NAMES)
    assert all(f'[{x.unit}]' in r[0] for x, r in zip(m.METRICS, _ROWS[-len(m.METRICS):]))
    expanded = [c for x in m.METRICS
                for c in ((f'{x.name}_1', f'{x.name}_2') if x.per_joint else (x.name,))]
    assert list(METRIC_COLUMNS) == expanded
    seg = Segment(index=0, mode=None, start=0.0, duration=0.0, samples=0)
    assert list(seg.to_dict())[-len(m.METRICS):] == list(m.METRIC_NAMES)
    assert sweep_metrics.metrics.segment_metrics is m.segment_metrics


def test_the_docs_metric_table_is_the_metric_tables():
    from arm_bag.metrics import metrics_markdown
    text = (Path(__file__).resolve().parents[1] / 'docs' / 'bags.md').read_text()
    marker = '<!-- generated: arm_bag.metrics.metrics_markdown -->\n'
    assert marker in text, 'docs/bags.md lacks the generated metric table'
    block = text.split(marker, 1)[1].split('<!-- end generated -->', 1)[0]
    assert block == metrics_markdown(), ('docs/bags.md is out of date; replace its block '
                                         f'with:\n{metrics_markdown()}')
