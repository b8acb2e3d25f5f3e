"""Streaming bag reading (issue 14): the same report, to the last bit, as before.

``test/data/analysis_reference.json`` holds ``analyze(bag).to_dict()`` for the bags
:func:`write_bag` makes, computed by the reader that held the whole file in memory (before
it read chunk by chunk). JSON floats round-trip exactly, so equality is bit equality.
Speed and peak memory are measured in bench/bench_bag.py, never here.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from arm_bag import reader
from arm_bag.analysis import analyze
from arm_bag.synthetic import open_bag, write_run

REF = Path(__file__).parent / 'data' / 'analysis_reference.json'
#: name -> write_bag keyword arguments
CASES: dict[str, dict] = {
    'none': dict(compression='none'),
    'zstd': dict(compression='zstd'),
    'lz4': dict(compression='lz4'),
    'big_chunks': dict(compression='none', chunk_size=1 << 20),
    'resent': dict(compression='zstd', resend=True),
}


def write_bag(path: Path, compression: str = 'none', chunk_size: int = 1 << 13,
              segments: int = 12, per_segment: int = 300, resend: bool = False) -> None:
    """A synthetic run (as bench/bench_bag.py writes, smaller): ``segments`` regulation
    segments of ``per_segment`` states and references at 100 Hz, every third one with a
    straight-line path; ``resend`` repeats every 7th state (lockstep re-sends)."""
    w, ch = open_bag(path, compression=compression, chunk_size=chunk_size)
    rng = np.random.default_rng(14)
    log = 1_000_000_000
    for seg in range(segments):
        t = np.arange(per_segment) * 0.01
        goal = rng.uniform(-1, 1, 2)
        q = goal + 0.5 * np.exp(-t / 0.5)[:, None] * np.cos(4 * t)[:, None]
        qd = np.gradient(q, t, axis=0)
        tau = 10 * (goal - q)
        if resend:
            idx = np.sort(np.r_[np.arange(per_segment), np.arange(0, per_segment, 7)])
            t, q, qd, tau = t[idx], q[idx], qd[idx], tau[idx]
        traj = (np.array([q[0], goal]), np.array([0.0, 2.0]))
        path_xy = (np.linspace([0.5, 1.0], [1.2, 0.3], 5) if seg % 3 == 2 else None)
        log = write_run(w, ch, log, t, q, qd, tau, q * 0 + goal, traj, path_xy=path_xy,
                        stamp0=seg * 10_000_000_000)
    w.close()


def _reference() -> dict:
    return json.loads(REF.read_text())


@pytest.mark.parametrize('mapped', [False, True], ids=['read', 'mmap'])
@pytest.mark.parametrize('name', sorted(CASES))
def test_report_is_bit_identical_to_the_in_memory_reader(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, name: str, mapped: bool) -> None:
    """Both ways of getting at the file: read into memory (small files) and memory-mapped
    with its pages released chunk by chunk (large files; forced here)."""
    if mapped:
        monkeypatch.setattr(reader, 'MMAP_MIN_BYTES', 0)
    write_bag(tmp_path / name, **CASES[name])
    got = analyze(tmp_path / name).to_dict()
    got['bag'] = None
    assert json.loads(json.dumps(got, sort_keys=True)) == _reference()[name]


@pytest.mark.parametrize('mapped', [False, True], ids=['read', 'mmap'])
def test_lean_reading_keeps_what_analysis_uses(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                               mapped: bool) -> None:
    """``read_bag(lean=True)`` (what analyze uses) gives the same joint states and reference
    stamps, receive times and positions as a full read; only the reference's velocity and
    effort become NaN views that take no memory."""
    if mapped:
        monkeypatch.setattr(reader, 'MMAP_MIN_BYTES', 0)
    write_bag(tmp_path / 'bag', compression='zstd', resend=True)
    full = reader.read_bag(tmp_path / 'bag')
    lean = reader.read_bag(tmp_path / 'bag', lean=True)
    assert full.joint_states is not None and lean.joint_states is not None
    assert full.reference is not None and lean.reference is not None
    for key in ('stamp', 'log_time', 'position', 'velocity', 'effort'):
        np.testing.assert_array_equal(getattr(full.joint_states, key),
                                      getattr(lean.joint_states, key))
    for key in ('stamp', 'log_time', 'position'):
        np.testing.assert_array_equal(getattr(full.reference, key),
                                      getattr(lean.reference, key))
    for key in ('velocity', 'effort'):
        kept, dropped = getattr(full.reference, key), getattr(lean.reference, key)
        assert np.isfinite(kept).all() and dropped.shape == kept.shape
        assert np.isnan(dropped).all() and dropped.strides == (0, 0)
    assert full.topics == lean.topics and full.warnings == lean.warnings


def test_many_small_chunks_give_every_state_in_order(tmp_path: Path) -> None:
    """A bare .mcap from the mcap library with chunks of a few messages each (decoded one
    chunk at a time into growing arrays, no statistics-based preallocation needed)."""
    from mcap.writer import CompressionType, Writer

    from arm_bag.msgdefs import schema_text
    from arm_bag.synthetic import joint_state_block

    t = np.arange(50) * 0.01
    q = np.c_[np.sin(t), np.cos(t)]
    msgs = joint_state_block((t * 1e9).astype(np.int64), q, q, q)
    path = tmp_path / 'late.mcap'
    with open(path, 'wb') as fh:
        w = Writer(fh, chunk_size=400, compression=CompressionType.NONE,
                   use_statistics=False)
        w.start(profile='ros2', library='test')
        sid = w.register_schema('sensor_msgs/msg/JointState', 'ros2msg',
                                schema_text('sensor_msgs/msg/JointState').encode())
        ch = w.register_channel('/joint_states', 'cdr', sid)
        for i, m in enumerate(msgs):
            w.add_message(ch, log_time=1000 + i, data=m, publish_time=1000 + i)
        w.finish()
    bag = reader.read_bag(path)
    assert bag.joint_states is not None
    np.testing.assert_array_equal(bag.joint_states.position, q)
    np.testing.assert_array_equal(bag.joint_states.log_time, 1000 + np.arange(50))
