"""Rate limiting for repeated error reports (no rclpy): :class:`Throttle` (one report per
key and period) and :class:`GrowingIntervals` (a condition that goes on: said once, then
summarised at growing intervals)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass


class Throttle:
    """Allows one report per ``key`` every ``period`` seconds and counts the rest."""

    def __init__(self, period: float = 1.0, clock: Callable[[], float] = time.monotonic):
        self.period = period
        self.clock = clock
        self._last: dict[str, float] = {}
        self.suppressed: dict[str, int] = {}

    def ready(self, key: str) -> bool:
        """True if a report for ``key`` may go out now (and marks it as sent)."""
        now = self.clock()
        last = self._last.get(key)
        if last is not None and now - last < self.period:
            self.suppressed[key] = self.suppressed.get(key, 0) + 1
            return False
        self._last[key] = now
        return True

    def take_suppressed(self, key: str) -> int:
        """How many reports for ``key`` were held back since the last call."""
        return self.suppressed.pop(key, 0)


#: Wall-clock seconds between the log lines about a condition that goes on
#: (:class:`GrowingIntervals`): the first line at once, a summary 5 s later, then one
#: every 30 s.
SUMMARY_INTERVALS: tuple[float, ...] = (5.0, 30.0)


@dataclass(frozen=True)
class Summary:
    """What one log line about a recurring condition says (:meth:`GrowingIntervals.note`).

    ``first``: the first occurrence of an episode (say it plainly); otherwise a summary.
    ``count`` occurrences and ``amount`` (e.g. seconds waited) since the previous line, this
    one's included, over ``span`` s (wall; 0 for a first line); ``total_count`` and
    ``total_amount`` since the start."""

    first: bool
    count: int
    amount: float
    span: float
    total_count: int
    total_amount: float


class GrowingIntervals:
    """When a condition that recurs (e.g. "time waited for the controller", once a second
    under load) is worth a log line, for a person reading the log.

    The first occurrence is said at once; after it, what happened since the previous line
    is summarised once ``intervals[0]`` s have passed, then ``intervals[1]`` s after that
    line, and so on, the last interval repeating. A summary goes out at the first
    :meth:`note` (with occurrences or without) that finds its interval over and something
    to say. After ``reset_after`` s without an occurrence (default: the last interval) the
    episode is over: the next occurrence is a first line again. Times are the caller's [s],
    on one monotonic clock; nothing here reads a clock."""

    def __init__(self, intervals: tuple[float, ...] = SUMMARY_INTERVALS,
                 reset_after: float | None = None) -> None:
        if not intervals or any(not i > 0 for i in intervals):
            raise ValueError(f'intervals must be positive seconds, got {intervals}')
        self.intervals = tuple(float(i) for i in intervals)
        self.reset_after = self.intervals[-1] if reset_after is None else float(reset_after)
        self.total_count = 0
        self.total_amount = 0.0
        self.lines = 0  # log lines given so far
        self._count, self._amount = 0, 0.0  # since the previous line
        self._line_at: float | None = None  # time of the episode's previous line
        self._step = 0  # the episode's lines after its first
        self._seen_at: float | None = None  # time of the latest occurrence

    def note(self, now: float, count: int = 1, amount: float = 0.0) -> Summary | None:
        """Record ``count`` occurrences (0: none, a check only) with ``amount`` at ``now``
        [s]; the line to log now, if any."""
        if count < 0:
            raise ValueError(f'count must be >= 0, got {count}')
        quiet = self._seen_at is None or now - self._seen_at >= self.reset_after
        if count:
            if quiet:
                self._line_at, self._step = None, 0  # a new episode
            self._seen_at = now
            self._count += count
            self._amount += amount
            self.total_count += count
            self.total_amount += amount
            if self._line_at is None:
                return self._line(now, first=True)
        elif quiet and not self._count:
            self._line_at, self._step = None, 0
            return None
        if not self._count or self._line_at is None:
            return None
        if now - self._line_at < self.intervals[min(self._step, len(self.intervals) - 1)]:
            return None
        self._step += 1
        return self._line(now, first=False)

    def _line(self, now: float, first: bool) -> Summary:
        span = 0.0 if self._line_at is None else now - self._line_at
        out = Summary(first, self._count, self._amount, span, self.total_count,
                      self.total_amount)
        self._count, self._amount = 0, 0.0
        self._line_at = now
        self.lines += 1
        return out
