"""Bag reading and recovery that are bounded and tidy (issue "Reliability"): only regular
files are opened, recovery streams chunk by chunk, nothing of arm_sim's own is left in a
bag directory, a killed bag is recovered whether its directory or its file is named, and
a bag holding messages the nodes refused is analysed without a traceback."""

from __future__ import annotations

import json
import os
import resource
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml

from arm_bag import bagfile, cli
from arm_bag.analysis import analyze
from arm_bag.bagfile import RECORDING_KEY, RESERVE_NAME, BagError, open_regular
from arm_bag.cdr import encode_joint_trajectory, encode_path
from arm_bag.reader import read_bag
from arm_bag.recover import recover_bag
from arm_bag.synthetic import open_bag, write_run

ROOT = Path(__file__).resolve().parents[1]
MEMORY_LIMIT = 3 << 30  # bytes of address space for a CLI child: a runaway read fails fast


def _limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def arm_sim(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    """``arm-sim ARGS`` in a child with bounded memory and time (a blocked open or an
    unbounded read fails the test instead of hanging it or filling the machine)."""
    return subprocess.run([sys.executable, '-m', 'arm_sim.cli', *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout,
                          preexec_fn=_limit_memory)


def names(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir())


# A BagWriter killed with SIGKILL (as a recorder dies): flushed chunks on disk, the last
# states only in memory, the bag marked open, its reserve file left behind.
KILLED_WRITER = '''
import os, signal, sys
import numpy as np
from arm_bag.synthetic import open_bag, write_run
path, segments, chunk = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
w, ch = open_bag(path, chunk_size=chunk)
rng = np.random.default_rng(5)
log = 1_000_000_000
t = np.arange(1000) * 0.01
for seg in range(segments):
    goal = rng.uniform(-1, 1, 2)
    q = goal + 0.5 * np.exp(-t / 0.5)[:, None] * np.cos(4 * t)[:, None]
    log = write_run(w, ch, log, t, q, q, q, q + 0 * goal,
                    (np.array([q[0], goal]), np.array([0.0, 2.0])),
                    stamp0=(seg + 1) * 10_000_000_000)
w.flush()
write_run(w, ch, log, t[:50], q[:50], q[:50], q[:50], None)  # in memory only: lost
print(w.message_count, flush=True)
os.kill(os.getpid(), signal.SIGKILL)
'''


def killed_bag(path: Path, segments: int = 3, chunk_size: int = 8192) -> int:
    """Make ``path`` a bag whose writer was SIGKILLed; returns the messages it flushed."""
    proc = subprocess.run([sys.executable, '-c', KILLED_WRITER, str(path), str(segments),
                           str(chunk_size)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == -9, proc.stderr
    assert (path / RESERVE_NAME).exists(), 'the reserve of a writer that died'
    meta = yaml.safe_load((path / 'metadata.yaml').read_text())
    assert meta['rosbag2_bagfile_information']['custom_data'][RECORDING_KEY] == 'open'
    return int(proc.stdout)


def good_bag(path: Path) -> Path:
    w, ch = open_bag(path, chunk_size=4096)
    t = np.arange(100) * 0.01
    q = np.c_[np.sin(t), np.cos(t)]
    write_run(w, ch, 1000, t, q, q, q, q, (np.array([q[0], [0.5, 0.5]]), np.array([0.0, 1.0])),
              stamp0=1)
    w.close()
    return path


# ---------------------------------------------------------------------- 1: regular files
def special(kind: str, at: Path) -> str:
    """Make ``at`` a FIFO, a character device (a symlink to /dev/zero: read without end)
    or a socket; returns the words naming its kind."""
    if kind == 'fifo':
        os.mkfifo(at)
        return 'a FIFO (named pipe)'
    if kind == 'device':
        at.symlink_to('/dev/zero')
        return 'a character device'
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(at))
    sock.close()  # the socket file stays
    return 'a socket'


@pytest.mark.parametrize('command', [['analyze'], ['bag', 'recover']])
@pytest.mark.parametrize('place', ['file', 'in_directory', 'listed'])
@pytest.mark.parametrize('kind', ['fifo', 'device', 'socket'])
def test_a_fifo_device_or_socket_as_a_bag_is_refused_naming_it_and_its_kind(
        tmp_path, kind, place, command):
    """Named as the bag, found in a bag directory, or listed by its metadata.yaml: one line
    naming the path and its kind, exit 4, at once (a FIFO opened for reading would block
    the child until the timeout; /dev/zero read would run into the memory limit)."""
    if place == 'file':
        target = tmp_path / 'x.mcap'
        arg = target
    else:
        bag = tmp_path / 'b'
        bag.mkdir()
        target = bag / 'b_0.mcap'
        arg = bag
        if place == 'listed':
            (bag / 'metadata.yaml').write_text(yaml.safe_dump({
                'rosbag2_bagfile_information': {'version': 9, 'storage_identifier': 'mcap',
                                                'relative_file_paths': ['b_0.mcap']}}))
    words = special(kind, target)
    out = arm_sim(*command, str(arg))
    prog = 'arm-sim ' + ' '.join(command)
    assert out.returncode == 4, out.stderr
    assert out.stderr.splitlines() == [f'{prog}: {target}: {words}, not a regular file (only '
                                       'regular files are read)'], out.stderr


@pytest.fixture
def opened(monkeypatch):
    """Paths opened through ``os.open``, ``open`` or ``io.open`` (each call still made)."""
    import builtins
    import io

    seen: list[str] = []
    real_os_open, real_open = os.open, builtins.open

    def spy_os_open(path, *args, **kwargs):
        seen.append(os.fspath(path))
        return real_os_open(path, *args, **kwargs)

    def spy_open(file, *args, **kwargs):
        if isinstance(file, (str, bytes, os.PathLike)):
            seen.append(os.fsdecode(file))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(os, 'open', spy_os_open)
    monkeypatch.setattr(builtins, 'open', spy_open)
    monkeypatch.setattr(io, 'open', spy_open)
    return seen


@pytest.mark.parametrize('call', ['read_bag', 'analyze', 'recover_bag'])
@pytest.mark.parametrize('kind', ['device', 'socket', 'fifo_in_bag'])
def test_a_file_that_is_not_regular_is_never_opened(tmp_path, opened, kind, call):
    """stat first: what is not a regular file is refused before any open (a device can act
    on being opened). A FIFO is only tried inside a bag directory here: in this process an
    open that blocked would hang the test (the CLI test above bounds that case)."""
    bag = tmp_path / 'b'
    bag.mkdir()
    target = bag / 'b_0.mcap'
    words = special('fifo' if kind == 'fifo_in_bag' else kind, target)
    fn = {'read_bag': read_bag, 'analyze': analyze, 'recover_bag': recover_bag}[call]
    for arg in ([bag] if kind == 'fifo_in_bag' else [bag, target]):
        with pytest.raises(BagError) as exc:
            fn(arg)
        assert str(exc.value) == (f'{target}: {words}, not a regular file (only regular '
                                  'files are read)')
    assert str(target) not in opened


def test_a_metadata_yaml_that_is_a_fifo_is_ignored_with_a_warning_not_opened(tmp_path):
    bag = good_bag(tmp_path / 'bag')
    (bag / 'metadata.yaml').unlink()
    os.mkfifo(bag / 'metadata.yaml')
    out = arm_sim('analyze', str(bag))
    assert out.returncode == 0, out.stderr
    assert (f'warning: {bag / "metadata.yaml"}: unreadable ({bag / "metadata.yaml"}: a FIFO '
            '(named pipe), not a regular file (only regular files are read)); ignoring it'
            in out.stderr.splitlines()), out.stderr


def test_a_fifo_put_in_place_after_the_check_cannot_block_the_open(tmp_path, monkeypatch):
    """The stat before the open is raced (the check is skipped here): the open itself does
    not block (O_NONBLOCK) and fstat refuses what it opened."""
    fifo = tmp_path / 'x.mcap'
    os.mkfifo(fifo)
    monkeypatch.setattr(bagfile, 'regular_file', lambda path, error=BagError: None)
    result: list = []

    def run() -> None:
        try:
            os.close(open_regular(fifo))
            result.append('opened')
        except BagError as exc:
            result.append(str(exc))

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(10)
    if thread.is_alive():  # blocked in open(): give it a writer so the thread can end
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        thread.join(10)
        pytest.fail('opening the FIFO blocked')
    assert result == [f'{fifo}: a FIFO (named pipe), not a regular file (only regular files '
                      'are read)']


def test_errors_without_a_message_still_give_a_reason(tmp_path, monkeypatch, capsys):
    import arm_bag.analysis
    import arm_bag.recover

    def out_of_memory(*_args, **_kw):
        raise MemoryError()

    monkeypatch.setattr(arm_bag.analysis, 'analyze', out_of_memory)
    assert cli.analyze_one('some/bag') == ('unreadable', 'some/bag: cannot read: out of '
                                           'memory')
    monkeypatch.setattr(arm_bag.recover, 'recover_bag', out_of_memory)
    assert cli.main(['bag', 'recover', 'some/bag']) == 4
    assert capsys.readouterr().err == 'arm-sim bag recover: some/bag: out of memory\n'
    assert cli.reason(BagError()) == 'BagError' and cli.reason(OSError(5, '')) == '[Errno 5]'


# ---------------------------------------------------------------------- 2: bounded memory
PEAK = '''
import sys
from arm_bag.recover import recover_bag

def peak():  # this process's own high-water mark of resident memory [bytes]
    with open('/proc/self/status') as f:
        return next(int(l.split()[1]) for l in f if l.startswith('VmHWM:')) * 1024

before = peak()
report = recover_bag(sys.argv[1])
print(before, peak(), report.messages)
'''


def test_recovery_streams_a_killed_bag_with_peak_memory_under_half_its_size(tmp_path):
    """A 50 MB bag of a killed writer recovered in place, in a fresh process: its peak
    resident memory grows by less than 0.5 x the bag (it was 3.4 x when the file and every
    message were held at once). The bag is uncompressed: its bytes are its messages."""
    bag = tmp_path / 'big'
    flushed = killed_bag(bag, segments=165, chunk_size=1 << 20)
    size = (bag / 'big_0.mcap').stat().st_size
    assert size > 45e6
    out = subprocess.run([sys.executable, '-c', PEAK, str(bag)], capture_output=True,
                         text=True, timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    before, peak, messages = map(int, out.stdout.split())
    print(f'recovery: {(peak - before) / 1e6:.1f} MB over imports, bag {size / 1e6:.1f} MB')
    assert messages == flushed, 'every flushed message kept'
    assert peak - before < 0.5 * size, (
        f'recovery took {(peak - before) / 1e6:.0f} MB over its imports for a '
        f'{size / 1e6:.0f} MB bag ({(peak - before) / size:.2f} x)')
    assert read_bag(bag).message_count == flushed


# ---------------------------------------------------------------------- 3: tidy
def test_a_closed_bag_directory_holds_only_the_bag(tmp_path):
    w, ch = open_bag(tmp_path / 'bag', chunk_size=4096)
    assert RESERVE_NAME in names(tmp_path / 'bag'), 'the reserve while recording'
    t = np.arange(50) * 0.01
    write_run(w, ch, 1000, t, np.zeros((50, 2)), np.zeros((50, 2)), np.zeros((50, 2)), None)
    w.flush()
    w.close()
    assert names(tmp_path / 'bag') == ['bag_0.mcap', 'metadata.yaml']


@pytest.mark.parametrize('how', ['recover_dir', 'recover_file', 'read_bag', 'cli_recover'])
def test_recovering_a_killed_writers_bag_leaves_only_the_bag(tmp_path, how):
    """The dead writer's reserve and half-written metadata.yaml, and the temporary files
    of a recovery killed before, are gone after the recovery, whichever way it ran."""
    bag = tmp_path / 'bag'
    flushed = killed_bag(bag)
    (bag / '.metadata.yaml.tmp').write_text('half written')
    (bag / '.bag_0.mcap.recover.tmp').write_bytes(b'a recovery killed mid-write')
    if how == 'recover_dir':
        assert recover_bag(bag).messages == flushed
    elif how == 'recover_file':
        assert recover_bag(bag / 'bag_0.mcap').messages == flushed
    elif how == 'read_bag':
        assert read_bag(bag).message_count == flushed
    else:
        out = arm_sim('bag', 'recover', str(bag))
        assert out.returncode == 0 and f'kept {flushed} messages' in out.stdout, out.stderr
    assert names(bag) == ['bag_0.mcap', 'metadata.yaml']
    assert read_bag(bag).warnings == [], 'complete'


def test_recovering_into_another_directory_writes_only_the_bag_there(tmp_path):
    bag = tmp_path / 'bag'
    killed_bag(bag)
    before = names(bag)
    recover_bag(bag, tmp_path / 'out')
    assert names(tmp_path / 'out') == ['bag_0.mcap', 'metadata.yaml']
    assert names(bag) == before, 'the original is left as it was'


# ---------------------------------------------------------------------- 4: named by file
def test_a_killed_bag_is_recovered_when_its_mcap_file_is_named(tmp_path):
    bag = tmp_path / 'bag'
    flushed = killed_bag(bag)
    out = arm_sim('analyze', '--json', str(bag / 'bag_0.mcap'))
    assert out.returncode == 0, out.stderr
    recovered = [w for w in out.stderr.splitlines() if 'recovered unfinished recording' in w]
    assert len(recovered) == 1 and recovered[0].startswith(
        f'warning: {bag / "bag_0.mcap"}: recovered unfinished recording: kept {flushed} '
        'messages'), out.stderr
    report = json.loads(out.stdout)
    assert sum(report['message_counts'].values()) == flushed
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['custom_data'][RECORDING_KEY] == 'closed' and meta['message_count'] == flushed
    assert names(bag) == ['bag_0.mcap', 'metadata.yaml']


def test_a_bag_being_recorded_named_by_its_file_is_read_live_and_left_alone(tmp_path):
    import fcntl

    bag = tmp_path / 'bag'
    killed_bag(bag)
    mcap = bag / 'bag_0.mcap'
    before = mcap.read_bytes()
    with open(mcap, 'rb') as lock:  # as a live recorder holds it
        fcntl.flock(lock.fileno(), fcntl.LOCK_EX)
        data = read_bag(mcap)
        assert any('still being recorded' in w for w in data.warnings), data.warnings
    assert mcap.read_bytes() == before and RESERVE_NAME in names(bag)


def test_an_mcap_file_not_listed_by_the_directory_metadata_is_not_taken_for_the_bag(
        tmp_path):
    """A killed bag's file copied beside another bag's metadata: not that bag's recording,
    so its damage is an error as for any bare file (nothing is rewritten)."""
    bag = tmp_path / 'bag'
    killed_bag(bag)
    other = tmp_path / 'other.mcap'
    other.write_bytes((bag / 'bag_0.mcap').read_bytes())
    (tmp_path / 'metadata.yaml').write_bytes((bag / 'metadata.yaml').read_bytes())
    with pytest.raises(BagError, match='no MCAP magic at the end'):
        read_bag(other)


# ---------------------------------------------------------------------- 6: refused messages
def refused_bag(path: Path, with_refused: bool) -> Path:
    """Three regulation segments; ``with_refused`` adds between them what the nodes refuse:
    a trajectory with a NaN position (its end-effector path, with no path of its own, is
    the forward kinematics of its points: "q must be finite" once), one with infinite
    velocities, one whose times go back, joint states with NaN, and paths with a NaN
    pose."""
    w, ch = open_bag(path, chunk_size=4096)
    rng = np.random.default_rng(3)
    t = np.arange(200) * 0.01
    log = 1_000_000_000
    names2 = ('joint1', 'joint2')
    for seg in range(3):
        goal = rng.uniform(-1, 1, 2)
        q = goal + 0.5 * np.exp(-t / 0.3)[:, None]
        stamp0 = (seg + 1) * 10_000_000_000
        if with_refused and seg == 2:
            q[[50, 120]] = np.nan  # the controller rejects these states
        log = write_run(w, ch, log, t[:100], q[:100], q[:100], q[:100], q[:100] * 0 + goal,
                        (np.array([q[0], goal]), np.array([0.0, 1.0])), stamp0=stamp0)
        if with_refused:
            mid = stamp0 + 500_000_000
            bad = [encode_joint_trajectory(mid, names2, [q[0], [np.nan, 0.1]], [0.0, 1.0]),
                   encode_joint_trajectory(mid, names2, [q[0], goal], [0.0, 1.0],
                                           velocities=[[0.0, 0.0], [np.inf, 0.0]]),
                   encode_joint_trajectory(mid, names2, [q[0], goal], [1.0, 0.5])]
            w.write(ch['/arm_controller/joint_trajectory'], bad[seg], log)
            # a path of no trajectory of the run (its stamp is no trajectory's)
            w.write(ch['/planner/path'], encode_path(mid + 1, [[0.5, 1.0], [np.nan, 0.5],
                                                               [1.2, 0.3]]), log + 1000)
        log += 2000
        log = write_run(w, ch, log, t[100:], q[100:], q[100:], q[100:],
                        q[100:] * 0 + goal, stamp0=stamp0)
    w.close()
    return path


def test_trajectories_the_controller_refused_are_listed_and_start_no_segment(tmp_path):
    bad = refused_bag(tmp_path / 'bad', True)
    clean = analyze(refused_bag(tmp_path / 'clean', False)).to_dict()
    out = arm_sim('analyze', '--json', str(bad))
    assert out.returncode == 0 and 'Traceback' not in out.stderr, out.stderr
    report = json.loads(out.stdout)
    refused = [w for w in report['warnings'] if 'refused as the controller refuses it' in w]
    assert len(refused) == 3, report['warnings']
    assert 'positions has non-finite values' in refused[0]
    assert 'velocities has non-finite values' in refused[1]
    assert 'time_from_start must be >= 0 and strictly increasing' in refused[2]
    assert all(w.endswith(': not a segment') for w in refused)
    assert len(report['segments']) == len(clean['segments']) == 3
    # The refused trajectories change nothing but the samples NaN states leave out.
    for got, want in zip(report['segments'][:2], clean['segments'][:2], strict=True):
        assert got == want
    assert report['segments'][2]['samples'] == clean['segments'][2]['samples']
