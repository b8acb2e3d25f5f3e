"""Counting messages lost before the recorder, from publication sequence numbers (pure).

rclpy gives each received message its publisher's sequence number (1, 2, 3, ... per
publisher) but not which publisher sent it, so a gap means loss only while the topic has
exactly one publisher. :class:`GapCounter` is careful about the moments that look like loss
and are not:

* several publishers (the graph says so): their numbers interleave, so nothing is counted;
* a publisher that appears between two looks at the graph: its first number is
  unrelated to the other's, so a jump is held *pending* and confirmed only when the numbers
  go on from there (the next message is one more) or at the end of the recording; a number
  that goes down (another publisher, or a restarted one that begins again at 1) drops
  what is pending and stops counting until the graph shows one publisher again.

So a reported loss is a real one; what can go uncounted is loss in the moments just after
a publisher comes or goes (DDS "message lost" events cover those where DDS sees them).

A publisher that appears while the recorder records (a late topic, or a node started
later) publishes from number 1 on, and what it sends before the recorder's subscription
is matched to it never arrives (a volatile publisher does not keep it): the number of the
first message received from it says how many that was (:func:`missed_before_first`).
"""

from __future__ import annotations


class GapCounter:
    """Loss of one topic, from the sequence numbers of the messages received.

    Feed every received message's number to :meth:`message` and the graph's publisher
    count to :meth:`graph`; :attr:`lost` is the confirmed count; :meth:`close` confirms
    what is still pending if the topic still has one publisher.
    """

    def __init__(self) -> None:
        self.publishers = 0
        self.lost = 0
        self.pending = 0
        self.last: int | None = None
        self.suspended = False

    def graph(self, publishers: int) -> None:
        """The number of publishers (of the recorded type) the graph shows now."""
        if publishers != self.publishers:
            self.last, self.pending = None, 0
        self.publishers = publishers
        if publishers == 1:
            self.suspended = False

    def message(self, seq: int) -> int:
        """A message with publication sequence number ``seq`` (0 = unknown) arrived;
        returns the messages newly confirmed lost."""
        if seq <= 0 or self.publishers > 1 or self.suspended:
            return 0
        last, self.last = self.last, seq
        if last is None:
            return 0
        if seq == last + 1:
            return self._confirm()
        if seq > last + 1:
            self.pending += seq - last - 1
            return 0
        # Down (or repeated): another publisher, or a restart. Trust nothing until the
        # graph shows a single publisher again.
        self.last, self.pending, self.suspended = None, 0, True
        return 0

    def close(self) -> int:
        """The recording ends: confirm what is pending if the topic still has one
        publisher; returns the messages newly confirmed lost."""
        return self._confirm() if self.publishers == 1 and not self.suspended else 0

    def _confirm(self) -> int:
        n, self.pending = self.pending, 0
        self.lost += n
        return n


def missed_before_first(seq: int, publishers: int, appeared_while_recording: bool) -> int:
    """Messages a publisher sent before the first one the recorder received from it.

    ``seq``: that first message's publication sequence number (0 = unknown);
    ``publishers``: how many publishers (of the recorded type) the topic has;
    ``appeared_while_recording``: the recorder saw the publisher appear after it had
    itself been up long enough to see every publisher that existed when it started.

    Returns ``seq - 1`` when the topic has one publisher (so the message is its) that
    appeared while the recording ran (so it sent all of them while the recorder was
    recording, and they never reached it), else 0: with several publishers it is not
    known whose number it is, and a publisher that may have existed before the recorder
    sent its first messages before there was anything to record them.
    """
    if seq <= 1 or publishers != 1 or not appeared_while_recording:
        return 0
    return seq - 1
