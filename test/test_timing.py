"""The timing modes and the lockstep protocol (:mod:`arm_dynamics.timing`) on a fake clock."""

from __future__ import annotations

import pytest

from arm_dynamics.timing import (
    ADVANCE,
    APPLY,
    HEARTBEAT_NS,
    HOLD,
    MAX_CATCH_UP,
    STALE,
    Timekeeper,
    answer_tag,
    parse_answer_tag,
)

MS = 1_000_000
P = 10 * MS  # control period


def lockstep(**kw) -> Timekeeper:
    return Timekeeper(mode='lockstep', period_ns=P, report_after_ns=500 * MS, **kw)


def test_answer_tags_round_trip_and_other_labels_are_untagged():
    for t in (0, 10 * MS, 123_456_789_012):
        assert parse_answer_tag(answer_tag(t)) == t
    for label in ('', 'x', 'joint_states@1.5', 'joint_states@a.000000000'):
        assert parse_answer_tag(label) is None


def test_lockstep_advances_only_on_an_answer_to_the_current_state():
    k = lockstep()
    k.on_published(0, wall_ns=0, new_state=True)
    assert k.on_command(answers=0, sim_ns=0, wall_ns=MS) == ADVANCE
    k.on_published(P, wall_ns=2 * MS, new_state=True)
    assert k.on_command(answers=0, sim_ns=P, wall_ns=3 * MS) == STALE, 'an old answer'
    assert k.on_command(answers=2 * P, sim_ns=P, wall_ns=3 * MS) == STALE, 'a future one'
    assert k.on_command(answers=None, sim_ns=P, wall_ns=3 * MS) == ADVANCE, 'untagged'
    assert k.stale == 2 and k.commands == 2


def test_lockstep_holds_an_answer_while_paused():
    k = lockstep()
    k.pause_at_ns = P
    k.on_published(P, wall_ns=0, new_state=True)
    assert k.on_command(answers=P, sim_ns=P, wall_ns=MS) == HOLD
    assert not k.heartbeat_due(P, wall_ns=10 * HEARTBEAT_NS), 'no re-sends while paused'


def test_lockstep_wait_is_reported_after_the_threshold_and_never_moves_time():
    k = lockstep()
    k.on_published(0, wall_ns=0, new_state=True)
    k.on_command(answers=0, sim_ns=0, wall_ns=MS)  # the controller is there
    k.on_published(P, wall_ns=2 * MS, new_state=True)
    assert k.overdue_s(P, wall_ns=400 * MS) is None
    assert not k.heartbeat_due(P, wall_ns=100 * MS)
    assert k.heartbeat_due(P, wall_ns=2 * MS + HEARTBEAT_NS), 're-send the unanswered state'
    k.on_published(P, wall_ns=2 * MS + HEARTBEAT_NS, new_state=False)
    assert not k.heartbeat_due(P, wall_ns=2 * MS + HEARTBEAT_NS + MS)
    assert k.overdue_s(P, wall_ns=802 * MS) == pytest.approx(0.8)
    assert k.periods_due(P, wall_ns=10_000 * MS) == 0, 'lockstep never paces on the wall'
    assert k.on_command(answers=P, sim_ns=P, wall_ns=2002 * MS) == ADVANCE
    assert k.late_waits == 1 and k.longest_wait_s == pytest.approx(2.0)
    assert k.overdue_s(P, wall_ns=3000 * MS) is None, 'answered'


def test_a_slow_untagged_answer_is_waited_for_not_provoked_twice():
    """An untagged controller answers every copy of a state: once it has answered, a state
    is re-sent only when a link (state subscriber or command publisher) matched after it
    went out, never because the answer is slow (a second answer would be taken for the
    next state)."""
    k = lockstep()
    k.on_published(0, wall_ns=0, new_state=True)
    assert k.heartbeat_due(0, wall_ns=HEARTBEAT_NS), 'before any answer: discovery'
    k.on_published(0, wall_ns=HEARTBEAT_NS, new_state=False)
    assert k.on_command(answers=None, sim_ns=0, wall_ns=HEARTBEAT_NS + MS) == ADVANCE
    assert k.counts_links, 'the controller tags nothing'
    k.on_published(P, wall_ns=2 * HEARTBEAT_NS, new_state=True, links=3)
    assert not k.heartbeat_due(P, wall_ns=20 * HEARTBEAT_NS, links=3), 'only slow'
    assert not k.heartbeat_due(P, wall_ns=21 * HEARTBEAT_NS, links=2), 'one left'
    assert k.heartbeat_due(P, wall_ns=22 * HEARTBEAT_NS, links=3), 'a new one came'
    k.on_published(P, wall_ns=22 * HEARTBEAT_NS, new_state=False, links=3)
    assert not k.heartbeat_due(P, wall_ns=40 * HEARTBEAT_NS, links=3)
    assert k.resends == 2
    # A tagged controller ignores copies of a state it answered: the timer goes on.
    assert k.on_command(answers=P, sim_ns=P, wall_ns=40 * HEARTBEAT_NS) == ADVANCE
    assert not k.counts_links
    k.on_published(2 * P, wall_ns=41 * HEARTBEAT_NS, new_state=True)
    assert k.heartbeat_due(2 * P, wall_ns=42 * HEARTBEAT_NS)


def test_lockstep_wait_before_the_first_command_is_not_late():
    k = lockstep()
    k.on_published(0, wall_ns=0, new_state=True)
    assert k.overdue_s(0, wall_ns=5000 * MS) is None
    assert k.heartbeat_due(0, wall_ns=HEARTBEAT_NS)


def test_time_spent_paused_is_not_a_late_wait():
    k = lockstep()
    k.on_published(0, wall_ns=0, new_state=True)
    k.on_command(answers=0, sim_ns=0, wall_ns=MS)
    k.pause_at_ns = P
    k.on_published(P, wall_ns=2 * MS, new_state=True)
    assert k.overdue_s(P, wall_ns=5000 * MS) is None
    k.pause_at_ns = None
    k.reanchor(wall_ns=5000 * MS)
    assert k.overdue_s(P, wall_ns=5100 * MS) is None


def real_time(**kw) -> Timekeeper:
    return Timekeeper(mode='real_time', period_ns=P, report_after_ns=500 * MS, **kw)


def test_real_time_waits_for_the_answer_like_lockstep_however_late_the_wall_clock_is():
    k = real_time()
    k.on_published(0, wall_ns=0, new_state=True)
    assert not k.may_step(0, wall_ns=10_000 * MS), 'no answer, no step: time stands'
    assert k.heartbeat_due(0, wall_ns=HEARTBEAT_NS), 'the unanswered state is re-sent'
    assert k.on_command(answers=P, sim_ns=0, wall_ns=10_000 * MS) == STALE
    assert k.on_command(answers=0, sim_ns=0, wall_ns=10_000 * MS) == ADVANCE
    assert not k.may_step(0, wall_ns=10_000 * MS), 'anchors pacing: due one period later'
    assert not k.may_step(0, wall_ns=10_009 * MS), 'not due yet'
    assert k.may_step(0, wall_ns=10_010 * MS), 'due and answered'
    k.on_published(P, wall_ns=10_010 * MS, new_state=True)
    assert not k.may_step(P, wall_ns=10_030 * MS), 'due long ago, but not answered'
    assert k.periods == 1 and k.waits == 0


def test_real_time_never_runs_ahead_of_the_wall_clock_times_the_factor():
    for factor in (1.0, 2.0, 0.3, 20.0):
        k = real_time(real_time_factor=factor)
        wall, sim = 0, 0
        k.on_published(sim, wall, True)
        k.on_command(sim, sim, wall)
        assert not k.may_step(sim, wall)  # anchor at (0, 0)
        for _ in range(200):  # an instant controller: answers at once; poll every 0.1 ms
            k.on_command(sim, sim, wall)
            while not k.may_step(sim, wall):
                wall += 100_000
            sim += P
            assert sim <= wall * factor + 1, f'sim {sim} ns ahead of wall {wall} ns x {factor}'
            assert sim > (wall - 100_000) * factor - 1, 'and it steps as soon as it is due'
            k.on_published(sim, wall, True)
        assert k.waits == 0 and k.slips == 0
        assert k.paced_real_time_factor == pytest.approx(factor, rel=1e-2)


def test_real_time_counts_a_late_answer_as_a_wait_and_catches_up_a_small_lag():
    k = real_time()
    k.on_published(0, 0, True)
    k.on_command(0, 0, 0)
    k.may_step(0, 0)  # anchor (0, 0)
    assert k.may_step(0, 10 * MS)
    k.on_published(P, 10 * MS, True)
    # the answer to P comes 25 ms late (due at 20 ms): time waited for it
    assert not k.may_step(P, 45 * MS)
    k.on_command(P, P, 45 * MS)
    assert k.may_step(P, 45 * MS), 'overdue: steps at once'
    assert k.waits == 1 and k.waited_s == pytest.approx(0.025)
    k.on_published(2 * P, 45 * MS, True)
    k.on_command(2 * P, 2 * P, 46 * MS)
    assert k.may_step(2 * P, 46 * MS), 'still behind the anchor (due at 30 ms): catches up'
    assert k.slips == 0
    assert k.waits == 1, 'a state published late (catching up) is not a wait for the controller'


def test_real_time_catches_up_a_hiccup_shorter_than_the_lag_limit_at_1_khz():
    k = Timekeeper(mode='real_time', period_ns=MS)
    k.on_published(0, 0, True)
    k.on_command(0, 0, 0)
    k.may_step(0, 0)  # anchor
    sim, wall = 0, 50 * MS  # a 50 ms hiccup: 49 periods behind, under MAX_LAG_NS
    for _ in range(49):
        k.on_command(sim, sim, wall)
        assert k.may_step(sim, wall), 'overdue: stepped at once'
        sim += MS
        k.on_published(sim, wall, True)
    assert k.slips == 0 and k.waits == 0, 'caught up, not given up'
    assert sim == 49 * MS


def test_real_time_restarts_pacing_after_a_long_stall_instead_of_rushing():
    k = real_time()
    k.on_published(0, 0, True)
    k.on_command(0, 0, 0)
    k.may_step(0, 0)
    stall = 1500 * MS  # the controller SIGSTOPped for 1.5 s
    k.on_command(0, 0, stall)
    assert k.may_step(0, stall)
    assert k.slips == 1 and k.waits == 0, 'answered at once, so no wait; a slip'
    k.on_published(P, stall, True)
    k.on_command(P, P, stall + MS)
    assert not k.may_step(P, stall + MS), 'paced from the new anchor: not due yet'
    assert k.may_step(P, stall + P)


def test_real_time_keeps_an_answer_while_held_and_steps_it_when_released():
    k = real_time()
    k.on_published(0, 0, True)
    k.held = True
    assert k.on_command(0, 0, MS) == HOLD
    assert not k.may_step(0, 100 * MS)
    assert not k.heartbeat_due(0, 10 * HEARTBEAT_NS), 'no re-sends while held'
    assert k.overdue_s(0, 10_000 * MS) is None, 'a hold is not a late controller'
    k.held = False
    k.reanchor(5000 * MS)
    assert not k.may_step(0, 5000 * MS)
    assert k.may_step(0, 5010 * MS), 'the kept answer steps once released and due'
    assert k.waits == 0


def test_untagged_commands_answer_the_current_state_in_real_time():
    k = real_time()
    k.on_published(0, 0, True)
    assert k.on_command(None, 0, 0) == ADVANCE
    k.may_step(0, 0)
    assert k.may_step(0, P)
    k.on_published(P, P, True)
    assert not k.may_step(P, 2 * P), 'one command, one period'
    assert k.on_command(None, P, 2 * P) == ADVANCE
    assert k.may_step(P, 2 * P)


def test_wall_clock_opt_in_holds_until_the_first_command_then_integrates_on_schedule():
    k = Timekeeper(mode='wall_clock', period_ns=P)
    assert k.holding() and k.periods_due(0, wall_ns=10_000 * MS) == 0
    k.on_published(0, wall_ns=0, new_state=True)
    assert k.heartbeat_due(0, wall_ns=HEARTBEAT_NS), 'the held state is re-sent'
    assert k.on_command(answers=None, sim_ns=0, wall_ns=1000 * MS) == APPLY
    assert not k.holding()
    assert k.periods_due(0, wall_ns=1000 * MS) == 0  # anchors here
    assert k.periods_due(0, wall_ns=1035 * MS) == 3
    fast = Timekeeper(mode='wall_clock', period_ns=P, real_time_factor=2.0,
                      hold_until_command=False)
    fast.periods_due(0, wall_ns=0)
    assert fast.periods_due(0, wall_ns=50 * MS) == 10


def test_wall_clock_overrun_gives_up_time_beyond_the_catch_up_limit():
    k = Timekeeper(mode='wall_clock', period_ns=P, hold_until_command=False)
    k.periods_due(0, wall_ns=0)
    assert k.periods_due(0, wall_ns=1000 * MS) == MAX_CATCH_UP
    assert k.overruns == 1
    assert k.behind_s == pytest.approx((100 - MAX_CATCH_UP) * 0.01)
    sim = MAX_CATCH_UP * P
    assert k.periods_due(sim, wall_ns=1010 * MS) == 1, 'same pace from the new anchor'


def test_wall_clock_late_periods_with_tagged_answers():
    k = Timekeeper(mode='wall_clock', period_ns=P)
    k.on_command(answers=0, sim_ns=0, wall_ns=0)
    assert not k.before_advance(0), 'state 0 was answered'
    assert k.before_advance(P), 'state P was not answered before its period ended'
    k.on_command(answers=P, sim_ns=2 * P, wall_ns=30 * MS)  # an answer to an older state
    assert k.before_advance(2 * P)
    k.on_command(answers=3 * P, sim_ns=3 * P, wall_ns=40 * MS)
    assert not k.before_advance(3 * P)
    assert (k.periods, k.late_periods) == (4, 2)
    assert k.window(4 * P, wall_ns=0) is None  # opens the window
    w = k.window(4 * P, wall_ns=1000 * MS)
    assert w is not None and w.periods == 0 and w.wall_s == pytest.approx(1.0)


def test_wall_clock_waits_up_to_one_period_for_the_answer_then_steps_late():
    k = Timekeeper(mode='wall_clock', period_ns=P)
    k.on_command(answers=0, sim_ns=0, wall_ns=0)
    k.periods_due(0, wall_ns=0)  # anchors
    assert k.periods_due(0, wall_ns=10 * MS) == 1, 'state 0 answered: step'
    k.before_advance(0)
    assert k.periods_due(P, wall_ns=25 * MS) == 0, 'due, but its answer may still come'
    k.on_command(answers=P, sim_ns=P, wall_ns=26 * MS)
    assert k.periods_due(P, wall_ns=26 * MS) == 1, 'the answer steps it at once'
    assert not k.before_advance(P)
    assert k.periods_due(2 * P, wall_ns=29 * MS) == 0, 'not due yet'
    assert k.periods_due(2 * P, wall_ns=39 * MS) == 0, 'due, within the grace period'
    assert k.periods_due(2 * P, wall_ns=40 * MS) == 1, 'a period overdue: step anyway'
    assert k.before_advance(2 * P), '... and count it late'
    assert (k.periods, k.late_periods) == (3, 1)


def test_wall_clock_late_periods_with_untagged_commands():
    k = Timekeeper(mode='wall_clock', period_ns=P)
    k.on_command(answers=None, sim_ns=0, wall_ns=0)
    assert not k.before_advance(0)
    assert k.before_advance(P), 'no command since the last period'
    k.on_command(answers=None, sim_ns=2 * P, wall_ns=0)
    assert not k.before_advance(2 * P)


def test_removed_and_unknown_modes_are_refused_with_the_reason():
    with pytest.raises(ValueError, match='as_fast_as_possible was removed.*lockstep'):
        Timekeeper(mode='as_fast_as_possible', period_ns=P)
    with pytest.raises(ValueError, match="got 'warp'"):
        Timekeeper(mode='warp', period_ns=P)
    with pytest.raises(ValueError, match='period_ns'):
        Timekeeper(mode='lockstep', period_ns=0)
