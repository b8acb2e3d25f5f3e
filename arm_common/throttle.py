"""Rate limiting for repeated error reports (no rclpy)."""

from __future__ import annotations

import time
from collections.abc import Callable


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
