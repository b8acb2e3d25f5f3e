"""When simulated time may advance: the simulator's timing modes and the lockstep protocol.

Pure and ROS-free: the ``simulator`` node feeds :class:`Timekeeper` the commands it receives,
the states it publishes and the wall clock, and does what it answers. Tests drive it with a
fake clock.

The rule (docs/time.md): simulated time is the only time that changes the physics, the
control or a reported figure; the wall clock only *paces* simulated time and decides when to
*report* that something is late or missing.

Timing modes (:data:`TIMING_MODES`):

* ``lockstep`` -- the simulator advances one control period only on a valid command for the
  current state. A command from arm_sim's controller names the state it answers (see
  :func:`answer_tag`); an answer to any other state is stale and ignored. An untagged
  command (e.g. ros2_control's ForwardCommandController, or a timer-driven controller)
  counts as the answer to the current state, the latest one published. While no answer
  comes, time stands still: the current state is re-sent every :data:`HEARTBEAT_NS` of wall
  time (so a late, restarted or stalled controller gets it) and a wait longer than
  ``report_after_ns`` is reported with the wall time waited. Nothing that the wall clock
  does changes the recorded states. An untagged controller answers every copy of a state
  it receives, and nothing says which copy an answer is for: a re-sent state it had
  already got would be answered twice, the second answer taken for the next state (the
  run would then depend on the load). So once an untagged controller has answered, a state
  is re-sent only on evidence that someone may have missed it: a subscriber of the states
  or a publisher of commands matched after it went out (a restarted controller), not
  because the answer is slow (:meth:`Timekeeper.heartbeat_due`, ``links``).
* ``real_time`` -- lockstep at wall-clock pace: every rule of lockstep, and in addition a
  period is integrated no earlier than its end is due on the wall clock (simulated time
  never runs ahead of ``wall x real_time_factor`` from the pacing anchor). A late
  controller makes simulated time wait (counted as ``waits``, with the wall time waited:
  a state published before its period was due whose answer came after it); after falling
  more than :data:`MAX_LAG_PERIODS` periods and :data:`MAX_LAG_NS` behind the wall clock,
  for any reason, pacing restarts from now (a ``slip``) instead of rushing to catch up; a
  smaller lag is caught up at the loop's own speed. The results
  are those of lockstep, bit for bit; only the achieved real-time factor depends on the
  machine.
* ``wall_clock`` -- explicit opt-in, the pre-0.4 ``real_time``: each period is integrated
  on the wall clock's schedule with the command held then, answered or not, so **the
  results depend on the machine** (how fast the controller answers). A period waits at
  most :data:`GRACE_PERIODS` period past its due time for its answer; one integrated
  without it is *late* and counted. For studying a machine's timing, never for figures.

``as_fast_as_possible`` was removed: free-running steps outrun any external controller (the
arm diverged with the shipped one); ``lockstep`` runs as fast as the closed loop allows.

Holds: a client (the planner, while it plans a goal) can hold simulated time at the current
state (:attr:`Timekeeper.held`), as ``pause_at`` does at a set time: the state's answer is
kept and applied once the hold is released, so a goal takes effect at a simulated time that
does not depend on how long planning took.
"""

from __future__ import annotations

from dataclasses import dataclass

TIMING_MODES = ('real_time', 'lockstep', 'wall_clock')
#: Modes in which simulated time advances only on the answer to the current state.
ANSWERED_MODES = ('real_time', 'lockstep')
#: Modes that are refused, with the reason.
REMOVED_MODES = {
    'as_fast_as_possible': 'as_fast_as_possible was removed: free-running steps outrun any '
                           'external controller (the arm diverged); use lockstep (as fast as '
                           'the closed loop runs, deterministic) or real_time',
}
HEARTBEAT_NS = 200_000_000  # wall: how often a state nobody answered is re-sent
MAX_CATCH_UP = 20  # wall_clock: periods behind before it counts as an overrun
GRACE_PERIODS = 1  # wall_clock: how long past its due time a period waits for its answer
MAX_LAG_PERIODS = 5  # real_time: periods behind the wall clock before pacing restarts ...
MAX_LAG_NS = 100_000_000  # ... and at least this much wall time (a hiccup is caught up)

#: Lockstep protocol: a command may name the joint state it answers in
#: ``layout.dim[0].label`` as ``joint_states@<sec>.<nanosec>`` (arm_sim's controller does).
ANSWER_TAG = 'joint_states@'


def answer_tag(time_ns: int) -> str:
    """The label naming the state stamped ``time_ns`` [ns] that a command answers."""
    sec, nsec = divmod(time_ns, 1_000_000_000)
    return f'{ANSWER_TAG}{sec}.{nsec:09d}'


def parse_answer_tag(label: str) -> int | None:
    """The stamp [ns] named by :func:`answer_tag`, or None for any other label."""
    if not label.startswith(ANSWER_TAG):
        return None
    sec, _, nsec = label[len(ANSWER_TAG):].partition('.')
    if not (sec.isdigit() and nsec.isdigit() and len(nsec) == 9):
        return None
    return int(sec) * 1_000_000_000 + int(nsec)


#: :meth:`Timekeeper.on_command` verdicts.
ADVANCE = 'advance'  # hold the command; the current state is answered: step when allowed
HOLD = 'hold'  # hold the command; time may not move yet (paused or held)
APPLY = 'apply'  # hold the command; time moves on its own schedule (wall_clock)
STALE = 'stale'  # ignore: it answers another state


@dataclass
class Window:
    """Figures of one reporting window (about 1 s of wall time)."""

    wall_s: float
    sim_s: float
    periods: int
    late: int
    waits: int = 0  # real_time: periods whose answer came after they were due
    waited_s: float = 0.0  # real_time: wall time those answers were overdue, summed

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per wall second."""
        return self.sim_s / self.wall_s if self.wall_s > 0 else 0.0

    @property
    def late_fraction(self) -> float:
        return self.late / self.periods if self.periods else 0.0

    @property
    def answered_rate(self) -> float:
        """Control periods answered in time per wall second [Hz]."""
        return (self.periods - self.late) / self.wall_s if self.wall_s > 0 else 0.0


class Timekeeper:
    """Decides when simulated time advances; counts what was late.

    Parameters
    ----------
    mode : one of :data:`TIMING_MODES`.
    period_ns : int, ns > 0 -- the control period (one published state each).
    real_time_factor : > 0 -- real_time and wall_clock: simulated seconds per wall second.
    hold_until_command : wall_clock: hold the initial state until the first valid command
        (the answered modes always wait for it).
    report_after_ns : int, ns >= 0 -- a wait for an answer longer than this (wall) is
        reported; 0 = never.

    All times are integer nanoseconds; ``wall_ns`` is any monotonic clock.
    """

    def __init__(self, *, mode: str, period_ns: int, real_time_factor: float = 1.0,
                 hold_until_command: bool = True, report_after_ns: int = 500_000_000) -> None:
        if mode not in TIMING_MODES:
            raise ValueError(REMOVED_MODES.get(
                mode, f"timing mode must be one of {', '.join(TIMING_MODES)}; got {mode!r}"))
        if period_ns <= 0:
            raise ValueError(f'period_ns must be > 0, got {period_ns}')
        if not real_time_factor > 0:
            raise ValueError(f'real_time_factor must be > 0, got {real_time_factor}')
        self.mode = mode
        self.period_ns = period_ns
        self.real_time_factor = real_time_factor
        self.hold_until_command = hold_until_command
        self.report_after_ns = report_after_ns
        self.pause_at_ns: int | None = None
        self.held = False  # a client holds time at the current state (e.g. while planning)
        self.started = False  # a valid command has arrived
        self.anchor: tuple[int, int] | None = None  # (wall ns, sim ns) of real-time pacing
        self.anchors = 0  # how often pacing was (re)anchored: the node aligns its timer
        self.last_publish_ns: int | None = None
        self.waiting_since: int | None = None  # wall ns the current state went out
        self.answered = False  # answered modes: the current state has its command
        self.answered_wall: int | None = None  # wall ns that answer came
        self.answered_stamp: int | None = None  # wall_clock: latest state answered [sim ns]
        self.fresh = False  # wall_clock: an untagged command came since the last period
        self.tagged = False  # wall_clock: the controller names the states it answers
        self.untagged = False  # answered modes: the last command named no state
        # answered modes: matched links (state subscribers + command publishers) when the
        # current state went out, lowered to the fewest seen since (None: not counted)
        self.links_low: int | None = None
        self.resends = 0  # states re-sent (heartbeats)
        # counters (since start)
        self.commands = 0
        self.stale = 0
        self.periods = 0
        self.late_periods = 0  # wall_clock
        self.overruns = 0  # wall_clock
        self.behind_s = 0.0  # wall_clock: simulated time given up by overruns
        self.late_waits = 0  # answered modes: waits longer than report_after_ns
        self.longest_wait_s = 0.0
        self.waits = 0  # real_time: periods whose answer came after they were due
        self.waited_s = 0.0  # real_time: wall time those answers were overdue, summed
        self.slips = 0  # real_time: pacing restarted after falling behind the wall clock
        self.paced_wall_ns = 0  # real_time: wall time of paced running (no pause, hold)
        self.paced_sim_ns = 0  # real_time: simulated time advanced over it
        self._last_step_wall: int | None = None  # real_time: wall ns of the previous step
        # (wall ns, sim ns, periods, late, waits, waited) at the reporting window's start
        self._win: tuple[int | None, int, int, int, int, float] = (None, 0, 0, 0, 0, 0.0)

    # ------------------------------------------------------------------ state
    def set_mode(self, mode: str) -> None:
        if mode not in TIMING_MODES:
            raise ValueError(REMOVED_MODES.get(mode, f'unknown timing mode {mode!r}'))
        self.mode = mode
        self.anchor = None
        self._last_step_wall = None

    @property
    def answered_mode(self) -> bool:
        """Does time advance only on the answer to the current state?"""
        return self.mode in ANSWERED_MODES

    def paused(self, sim_ns: int) -> bool:
        """Has simulated time reached ``pause_at``?"""
        return self.pause_at_ns is not None and sim_ns >= self.pause_at_ns

    def stopped(self, sim_ns: int) -> bool:
        """Paused at ``pause_at`` or held by a client: time may not move."""
        return self.held or self.paused(sim_ns)

    def holding(self) -> bool:
        """wall_clock: the initial state is held until the first command."""
        return self.mode == 'wall_clock' and self.hold_until_command and not self.started

    def reanchor(self, wall_ns: int) -> None:
        """Restart real-time pacing, and a wait for an answer, from now (after a pause, a
        hold, a reset or a parameter change): time spent stopped is not late."""
        self.anchor = None
        self._last_step_wall = None
        if self.waiting_since is not None:
            self.waiting_since = wall_ns

    # ------------------------------------------------------------------ events
    @property
    def counts_links(self) -> bool:
        """Should the node pass ``links`` (its matched state subscribers plus command
        publishers) to :meth:`on_published` and :meth:`heartbeat_due`? Only for an
        untagged controller in the answered modes: re-sends to it need evidence."""
        return self.answered_mode and self.untagged

    def on_published(self, sim_ns: int, wall_ns: int, new_state: bool,
                     links: int | None = None) -> None:
        """The node published the state at ``sim_ns`` (``new_state``: time moved or the
        state changed, not a re-send); ``links``: see :attr:`counts_links`."""
        self.last_publish_ns = wall_ns
        self.links_low = links
        if not new_state:
            self.resends += 1
        if new_state:
            self.waiting_since = wall_ns
            self.answered = False
            self.answered_wall = None

    def on_command(self, answers: int | None, sim_ns: int, wall_ns: int) -> str:
        """A valid command arrived, answering the state stamped ``answers`` [ns] (None:
        untagged: the current state). Returns :data:`ADVANCE` (answered: step once
        :meth:`may_step` allows), :data:`HOLD` (answered, but time is stopped),
        :data:`APPLY` (wall_clock) or :data:`STALE` (ignore it)."""
        if self.answered_mode:
            if answers is not None and answers != sim_ns:
                self.stale += 1
                return STALE
            self.commands += 1
            self.started = True
            self.untagged = answers is None
            if not self.answered:  # the first answer to this state
                self.answered_wall = wall_ns
                if self.waiting_since is not None:
                    waited = (wall_ns - self.waiting_since) * 1e-9
                    self.longest_wait_s = max(self.longest_wait_s, waited)
                    if self.report_after_ns and waited * 1e9 > self.report_after_ns:
                        self.late_waits += 1
            self.answered = True
            return HOLD if self.stopped(sim_ns) else ADVANCE
        self.commands += 1
        if answers is not None:
            self.tagged = True
            if answers > sim_ns:
                self.stale += 1  # names a state not published yet: another simulator's
                return STALE
            self.answered_stamp = max(answers, self.answered_stamp or answers)
        self.fresh = True
        if not self.started:
            self.started = True
            self.anchor = None
        return APPLY

    # ------------------------------------------------------------------ answered modes
    def may_step(self, sim_ns: int, wall_ns: int) -> bool:
        """Answered modes: may the period starting at ``sim_ns`` be integrated now? True
        once the current state is answered and time is not stopped (lockstep), and, in
        real_time, once the period's end is due on the wall clock. When it returns True the
        caller integrates the period and publishes the new state. Anchors real-time pacing
        at the first chance (the first period then waits one period of wall time) and
        restarts it after falling more than :data:`MAX_LAG_PERIODS` behind."""
        if not self.answered_mode or not self.answered or self.stopped(sim_ns):
            return False
        if self.mode == 'lockstep':
            self.periods += 1
            return True
        if self.anchor is None:
            self.anchor = (wall_ns, sim_ns)
            self.anchors += 1
            return False
        wall0, sim0 = self.anchor
        # The end of this period, on the wall clock (1 ns of slack for float rounding).
        ahead = (sim_ns + self.period_ns - sim0) / self.real_time_factor - (wall_ns - wall0)
        if ahead > 1.0:
            return False
        lag = -ahead  # [wall ns] this period's end is overdue by
        answered = self.answered_wall if self.answered_wall is not None else wall_ns
        due = wall_ns - lag
        published = self.waiting_since if self.waiting_since is not None else due
        if published <= due < answered:
            # The state went out in time and its answer came after the period was due:
            # the controller made time wait (a state published late, while catching up a
            # backlog, is not the controller's wait).
            self.waits += 1
            self.waited_s += (answered - due) * 1e-9
        if lag > max(MAX_LAG_PERIODS * self.period_ns / self.real_time_factor, MAX_LAG_NS):
            # Far behind (a stalled controller, a loaded machine): go on at the same pace
            # from here rather than rushing through the lost time.
            self.slips += 1
            self.anchor = (wall_ns, sim_ns + self.period_ns)
            self.anchors += 1
        if self._last_step_wall is not None:
            self.paced_wall_ns += wall_ns - self._last_step_wall
            self.paced_sim_ns += self.period_ns
        self._last_step_wall = wall_ns
        self.periods += 1
        return True

    @property
    def paced_real_time_factor(self) -> float:
        """real_time: simulated s per wall s over all paced running (pauses, holds and
        waits before the first command excluded); 0 before any."""
        return self.paced_sim_ns / self.paced_wall_ns if self.paced_wall_ns else 0.0

    # ------------------------------------------------------------------ wall_clock
    def periods_due(self, sim_ns: int, wall_ns: int) -> int:
        """wall_clock: how many control periods to advance now (publishing each); ask
        again after each one (and after each command): the answer may change.

        With a controller that names the states it answers, a period is stepped only once
        the current state is answered, or once the answer is :data:`GRACE_PERIODS` periods
        overdue (then it counts as late): a timer that fires late no longer makes the
        simulator integrate states nobody could answer yet, and an answer that comes while
        the simulator is behind steps it at once."""
        if self.mode != 'wall_clock' or self.holding() or self.stopped(sim_ns):
            return 0
        if self.anchor is None:
            self.anchor = (wall_ns, sim_ns)
            return 0
        target = self.anchor[1] + (wall_ns - self.anchor[0]) * self.real_time_factor
        due = int((target - sim_ns) // self.period_ns)
        if due > MAX_CATCH_UP:
            # Too far behind to catch up: give the lost simulated time up and go on from
            # here, at the same pace.
            self.overruns += 1
            self.behind_s += (due - MAX_CATCH_UP) * self.period_ns * 1e-9
            due = MAX_CATCH_UP
            self.anchor = (wall_ns, sim_ns + due * self.period_ns)
        if due <= 0:
            return 0
        if self.tagged:
            answered = self.answered_stamp is not None and self.answered_stamp >= sim_ns
            overdue = target - (sim_ns + self.period_ns)  # [sim ns] past this period's end
            return 1 if answered or overdue >= GRACE_PERIODS * self.period_ns else 0
        return due

    def before_advance(self, sim_ns: int) -> bool:
        """wall_clock: the period starting at ``sim_ns`` is about to be integrated; returns
        True (and counts it) if the controller did not answer that state in time."""
        if self.tagged:
            late = self.answered_stamp is None or self.answered_stamp < sim_ns
        else:
            late = not self.fresh
        self.fresh = False
        self.periods += 1
        self.late_periods += late
        return late

    # ------------------------------------------------------------------ wall-clock checks
    def heartbeat_due(self, sim_ns: int, wall_ns: int, links: int | None = None) -> bool:
        """Should the current state be re-sent now? (answered modes while unanswered,
        wall_clock while holding the initial state; never while paused or held), at most
        every :data:`HEARTBEAT_NS` of wall time. Once an untagged controller has answered
        (:attr:`counts_links`), only when ``links`` (matched state subscribers plus command
        publishers, as the node counts them now) rose above the fewest seen since the state
        went out: a new subscriber may have missed it, or a new controller's answer may
        have gone out before we matched it. Without that evidence a slow answer is waited
        for, never provoked twice."""
        if self.stopped(sim_ns) or self.last_publish_ns is None:
            return False
        waiting = (self.answered_mode and not self.answered) or self.holding()
        if not waiting:
            return False
        if self.counts_links and links is not None:
            if self.links_low is None or links < self.links_low:
                self.links_low = links  # one left: fewer to compare with
                return False
            if links == self.links_low:
                return False
        return wall_ns - self.last_publish_ns >= HEARTBEAT_NS

    def overdue_s(self, sim_ns: int, wall_ns: int) -> float | None:
        """Answered modes: wall seconds waited for the current state's answer, once that
        exceeds ``report_after_ns`` (None otherwise, while paused or held, and before the
        first command: no controller has come yet)."""
        if (not self.answered_mode or self.answered or self.waiting_since is None
                or not self.report_after_ns or self.stopped(sim_ns) or not self.started):
            return None
        waited = wall_ns - self.waiting_since
        return waited * 1e-9 if waited > self.report_after_ns else None

    def window(self, sim_ns: int, wall_ns: int, length_ns: int = 1_000_000_000) -> Window | None:
        """Close the current reporting window if it is ``length_ns`` (wall) old."""
        w0, s0, p0, l0, n0, d0 = self._win
        now = (wall_ns, sim_ns, self.periods, self.late_periods, self.waits, self.waited_s)
        if w0 is None:
            self._win = now
            return None
        if wall_ns - w0 < length_ns:
            return None
        self._win = now
        return Window((wall_ns - w0) * 1e-9, (sim_ns - s0) * 1e-9, self.periods - p0,
                      self.late_periods - l0, self.waits - n0, self.waited_s - d0)
