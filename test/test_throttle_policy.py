"""arm_common.throttle.GrowingIntervals: a condition that goes on (the simulator's "time
waited for the controller", once a second under load) is said once, then summarised at
growing intervals with the totals, instead of a log line a second. Pure: the times are
given, as the simulator's reporting windows (1 s of wall time each) would give them."""

from __future__ import annotations

import pytest

from arm_common.throttle import SUMMARY_INTERVALS, GrowingIntervals, Summary, Throttle

WAITS_PER_WINDOW = 7  # waits for the controller in each 1 s window under load
WAITED_PER_WINDOW = 0.043  # s (wall) waited in each window


def waiting(policy: GrowingIntervals, start: float, seconds: int,
            waits: int = WAITS_PER_WINDOW) -> list[tuple[float, Summary]]:
    """One reporting window a second (wall) for ``seconds`` s from ``start``, each with
    ``waits`` waits (0: a window without); the lines the policy gives, with their times."""
    lines = []
    for i in range(seconds):
        now = start + i + 1.0
        line = policy.note(now, waits, waits and WAITED_PER_WINDOW)
        if line is not None:
            lines.append((now, line))
    return lines


def test_sixty_seconds_of_waiting_give_three_lines_not_sixty():
    policy = GrowingIntervals()
    lines = waiting(policy, 0.0, 60)
    # Before: Diagnostics.problem logged it once a period (1 s): a line per window.
    before = Throttle(1.0, clock=iter(float(t + 1) for t in range(60)).__next__)
    assert sum(before.ready('real_time_waits') for _ in range(60)) == 60
    # Now: at once, 5 s later, 30 s after that.
    assert [t for t, _ in lines] == [1.0, 6.0, 36.0]
    assert [s.first for _, s in lines] == [True, False, False]
    assert policy.lines == 3


def test_each_summary_carries_what_happened_since_the_previous_line_and_the_total():
    policy = GrowingIntervals()
    lines = waiting(policy, 0.0, 60)
    first, five, thirty = (s for _, s in lines)
    assert (first.count, first.span, first.total_count) == (WAITS_PER_WINDOW, 0.0,
                                                            WAITS_PER_WINDOW)
    assert first.amount == pytest.approx(WAITED_PER_WINDOW, abs=1e-12)
    assert (five.count, five.span) == (5 * WAITS_PER_WINDOW, 5.0)
    assert five.amount == pytest.approx(5 * WAITED_PER_WINDOW, abs=1e-12)
    assert (thirty.count, thirty.span) == (30 * WAITS_PER_WINDOW, 30.0)
    # The total: every wait up to the line (36 windows), in count and seconds waited.
    assert thirty.total_count == 36 * WAITS_PER_WINDOW
    assert thirty.total_amount == pytest.approx(36 * WAITED_PER_WINDOW, abs=1e-12)
    assert thirty.total_count == first.count + five.count + thirty.count
    # Nothing is lost: what the lines said plus what waits for the next one is the total.
    assert policy.total_count == 60 * WAITS_PER_WINDOW
    assert policy.total_amount == pytest.approx(60 * WAITED_PER_WINDOW, abs=1e-12)


def test_the_intervals_grow_then_repeat_the_last():
    policy = GrowingIntervals()
    times = [t for t, _ in waiting(policy, 0.0, 600)]
    gaps = [b - a for a, b in zip(times, times[1:])]
    assert gaps[:2] == list(SUMMARY_INTERVALS)
    assert set(gaps[1:]) == {SUMMARY_INTERVALS[-1]}
    assert len(times) == 2 + (600 - 6) // 30  # ten minutes: 21 lines, not 600


def test_waits_that_stop_are_summarised_when_due_and_a_later_episode_is_said_again():
    policy = GrowingIntervals()
    lines = waiting(policy, 0.0, 3)  # 3 s of waiting, then none
    assert [(t, s.first) for t, s in lines] == [(1.0, True)]
    quiet = waiting(policy, 3.0, 40, waits=0)
    # The 2 windows after the first line come out when their 5 s are over (t = 6 s).
    assert [(t, s.first, s.count, s.total_count) for t, s in quiet] == [
        (6.0, False, 2 * WAITS_PER_WINDOW, 3 * WAITS_PER_WINDOW)]
    assert policy.note(100.0, 0) is None, 'nothing more to say'
    # Waiting again after a quiet spell longer than the last interval: said at once.
    again = policy.note(101.0, 2, 0.01)
    assert again is not None and again.first and again.count == 2
    assert again.total_count == 3 * WAITS_PER_WINDOW + 2
    assert policy.note(102.0, 2, 0.01) is None, 'the new episode is summarised in 5 s'


def test_a_short_pause_does_not_start_a_new_episode():
    policy = GrowingIntervals()
    waiting(policy, 0.0, 10)  # lines at 1 and 6 s; the next is due at 36 s
    assert policy.note(20.0, 1, 0.01) is None, 'a pause of 10 s < 30 s: same episode'
    line = policy.note(36.0, 1, 0.01)
    assert line is not None and not line.first and line.count == 4 * WAITS_PER_WINDOW + 2


@pytest.mark.parametrize('intervals', [(), (0.0,), (5.0, -1.0)])
def test_intervals_must_be_positive(intervals):
    with pytest.raises(ValueError, match='positive seconds'):
        GrowingIntervals(intervals)


def test_a_negative_count_is_refused():
    with pytest.raises(ValueError, match='count must be >= 0'):
        GrowingIntervals().note(1.0, -1)
