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
