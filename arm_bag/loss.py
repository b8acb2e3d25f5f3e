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
has matched it never arrives. DDS matches each side on its own: the publisher's side can
match the recorder's subscription (so it sends, and a publisher waiting for the match goes
ahead) before the recorder's side has matched the publisher, and the subscription drops
data from a writer it does not know yet. Once it matches, the reliable protocol sends again
only what the publisher still keeps (its history depth: 10 by default, 10 ms at 1 kHz), so
a window of milliseconds to seconds (measured up to 1.5 s under load) loses the rest. The
number of the first message received says exactly how many messages the publisher sent
before it (:func:`before_first`): lost, if the publisher appeared while the recorder
recorded; else an *unrecorded start* (it may have sent them before the recording began).
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


def before_first(seq: int, publishers: int, appeared_while_recording: bool
                 ) -> tuple[int, int]:
    """The messages a topic's publisher sent before the first one the recorder received
    from it, as ``(lost, unrecorded_start)``; at most one of the two is not 0.

    ``seq``, ``publishers`` and ``appeared_while_recording`` as for
    :func:`missed_before_first`. All ``seq - 1`` messages are missing from the bag: they
    are ``lost`` when the publisher appeared while the recorder recorded, else an
    ``unrecorded_start`` (sent before the first recorded one, before or during the
    recording: which, the recorder cannot tell). With several publishers (whose number is
    it?) or none left in the graph, both are 0.
    """
    if seq <= 1 or publishers != 1:
        return 0, 0
    return (seq - 1, 0) if appeared_while_recording else (0, seq - 1)
