"""Process manners without ROS: the ROS domain claim (arm_common.process)."""

from __future__ import annotations

import subprocess
import sys

from arm_common.process import claim_domain

CLAIM = 'from arm_common.process import claim_domain; print(claim_domain({start}))'


def claim_in_child(start: int) -> int:
    done = subprocess.run([sys.executable, '-c', CLAIM.format(start=start)],
                          capture_output=True, text=True, timeout=60, check=True)
    return int(done.stdout)


def test_a_claimed_domain_is_not_handed_out_again_until_its_process_exits():
    mine = claim_domain(200)
    again = claim_domain(mine)
    assert again != mine, 'held by this process: the next free one'
    assert claim_in_child(mine) not in (mine, again), 'another process skips both'
    child = claim_in_child(100)
    assert claim_in_child(child) == child, 'freed when the child exited'


def test_the_claim_wraps_within_the_valid_range():
    assert 1 <= claim_domain(232) <= 232


# ---------------------------------------------------------------------- explicit domains
HOLD = ('import sys; from arm_common.process import claim_domain; '
        'print(claim_domain({start}), flush=True); sys.stdin.read()')
EXPLICIT = ('import sys; from arm_sim.launcher import DomainInUse, claim_explicit_domain\n'
            'try:\n    claim_explicit_domain({domain})\nexcept DomainInUse as exc:\n'
            '    print(exc); sys.exit(2)\nprint("claimed", flush=True); sys.stdin.read()')


class Holder:
    """A child process holding a claim until closed (what another arm_sim run does)."""

    def __init__(self, code: str) -> None:
        self.proc = subprocess.Popen([sys.executable, '-c', code], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True)
        self.line = self.proc.stdout.readline().strip()  # type: ignore[union-attr]

    def close(self) -> int:
        self.proc.stdin.close()  # type: ignore[union-attr]
        return self.proc.wait(30)


def explicit_in_child(domain: int) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-c', EXPLICIT.format(domain=domain)],
                          input='', capture_output=True, text=True, timeout=60)


def test_an_explicit_domain_another_run_holds_is_refused_naming_it():
    run = Holder(HOLD.format(start=150))
    try:
        domain = int(run.line)
        refused = explicit_in_child(domain)
        assert refused.returncode == 2, refused.stdout + refused.stderr
        assert (f'ROS domain {domain} is in use by another arm_sim run (pid {run.proc.pid}: '
                in refused.stdout), refused.stdout
        assert refused.stdout.count('\n') == 1, 'one line'
    finally:
        run.close()
    assert explicit_in_child(domain).stdout.strip() == 'claimed', 'free once it exited'


def test_an_explicit_claim_keeps_automatic_claims_off_its_domain():
    free = claim_in_child(170)  # free once that child exited
    run = Holder(EXPLICIT.format(domain=free))
    try:
        assert run.line == 'claimed', run.line
        assert claim_in_child(free) != free, 'an automatic claim skips it'
    finally:
        run.close()
    assert claim_in_child(free) == free, 'free once it exited'


def test_a_run_started_by_the_holder_of_its_domain_may_use_it():
    """A test session (or a script) that claimed a domain and runs arm-sim on it: the run
    is the holder's own (its ancestor holds the claim)."""
    mine = claim_domain(190)
    assert explicit_in_child(mine).stdout.strip() == 'claimed'
    from arm_sim.launcher import claim_explicit_domain
    claim_explicit_domain(mine)  # this process itself: no error


# ---------------------------------------------------------------------- shared memory
def test_stale_fast_dds_files_are_removed_and_those_in_use_kept(tmp_path):
    import fcntl
    import mmap
    import os
    import time

    from arm_sim.launcher import MUTEX_AGE, remove_stale_shm

    shm = tmp_path.resolve()

    def make(*names: str) -> None:
        for name in names:
            (shm / name).write_bytes(b'\0' * 64)

    seg, locked, port, mapped = ('fastrtps_0123456789abcdef', 'fastdds_aaaaaaaaaaaaaaaa',
                                 'fastrtps_port7411', 'fastrtps_port7413')
    make(seg, f'{seg}_el', locked, f'{locked}_el', port, f'{port}_el',
         f'sem.{port}_mutex', mapped, f'{mapped}_sl', f'sem.{mapped}_mutex',
         'sem.fastrtps_port9999_mutex', 'sem.fastrtps_port9998_mutex',
         'fastrtps_port7415', 'something_else')
    old = time.time() - 2 * MUTEX_AGE
    os.utime(shm / 'sem.fastrtps_port9999_mutex', (old, old))
    lock_fd = os.open(shm / f'{locked}_el', os.O_RDONLY)  # a live owner's lock
    fcntl.flock(lock_fd, fcntl.LOCK_EX)
    with open(shm / mapped, 'r+b') as f:  # a live process still maps this port
        view = mmap.mmap(f.fileno(), 64)
    try:
        removed = remove_stale_shm(shm)
    finally:
        view.close()
        os.close(lock_fd)
    assert sorted(removed) == sorted([seg, f'{seg}_el', port, f'{port}_el',
                                      f'sem.{port}_mutex', 'sem.fastrtps_port9999_mutex'])
    assert sorted(p.name for p in shm.iterdir()) == sorted([
        locked, f'{locked}_el', mapped, f'{mapped}_sl', f'sem.{mapped}_mutex',
        'sem.fastrtps_port9998_mutex', 'fastrtps_port7415', 'something_else'])
    assert sorted(remove_stale_shm(shm)) == sorted([locked, f'{locked}_el', mapped,
                                                   f'{mapped}_sl', f'sem.{mapped}_mutex'])
