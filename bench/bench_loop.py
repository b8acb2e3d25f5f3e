"""Closed-loop benchmark over ROS: the ``simulator`` and ``controller`` node processes.

Starts both nodes as processes (``arm_sim.launcher.NodeProcess``, the shipped
``config/arm.yaml`` plus per-run overrides) on a private ROS domain with localhost-only
discovery, with the controller's computed-torque law holding the arm (``update_on:
joint_states``, so every state gets one command), and measures from the bench's own rclpy
node:

1. lockstep -- simulated seconds per wall second at 1 kHz and 250 Hz control, from the
   simulator's own ``achieved_real_time_factor`` on /diagnostics (the bench subscribes
   nothing else, so it adds no load to the loop), and as a fraction of the middleware
   floor (two bare processes bouncing a message) measured in the same run;
2. real time, side by side per control rate: ``real_time`` (lockstep at wall-clock pace:
   exact results, time waits for a late controller) and ``wall_clock`` (the old
   real_time: periods integrated on the wall clock's schedule, answered or not) -- the
   achieved real-time factor, the wall-clock jitter of state publication, waits and slips,
   late cycles and the state-to-command latency, from ``joint_states`` and
   ``effort_controller/commands`` as the bench receives them (DDS reception and
   publication timestamps from the message info, all on one host clock; commands name the
   state they answer in ``layout.dim[0].label``) and from the simulator's /diagnostics;
3. executors (optional, ``--executors``) -- the same loops with the nodes' executor
   replaced at start-up through ``arm_common.node.EXECUTOR`` (no file is edited):
   ``stock`` is what ships (rclpy.experimental.EventsExecutor in ``spin_once`` loops),
   ``single`` is SingleThreadedExecutor and ``multi`` MultiThreadedExecutor, both in the
   same ``spin_once`` loops.

``--busy N`` runs N busy-loop processes for the whole measurement, to see what a loaded
machine does to each mode.

Run ``python bench/bench_loop.py --help`` for the options; bench/README.md explains every
figure. The programs it runs in subprocesses (the floor's ping-pong, the busy loops, the
executor wrapper) are the files in ``bench/loop_programs/``.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import statistics
import struct
import sys
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from unittest import mock

DEFAULT_DOMAIN = 211
LOCKSTEP_RATES = (1000.0, 250.0)
REALTIME_RATES = (100.0, 250.0, 500.0, 1000.0)
QUICK_REALTIME_RATES = (250.0, 1000.0)
# stock = as shipped: two processes spinning EventsExecutor; composed = both nodes in one
# process with one EventsExecutor (arm_sim.composed, ``arm-sim bringup --composed``)
VARIANTS = ('stock', 'composed', 'single', 'multi')
# Simulator timing modes the bench watches on the wire (states and commands), and their
# labels: real_time is lockstep at wall-clock pace (new), wall_clock the old real_time.
PACED_MODES = ('real_time', 'wall_clock')
LABELS = {'lockstep': 'lockstep', 'real_time': 'real_time (new)',
          'wall_clock': 'wall_clock (old real_time)'}
LATE_LIMIT = 0.01  # a wall_clock rate is "held" with fewer late cycles than this
LOCKSTEP_TARGET = 1.0  # x real time at 1 kHz
RTF_TARGET = 0.99  # real_time: achieved x real time at 250 Hz on a quiet machine
FLOOR_TARGET = 0.60  # two-process lockstep round trips / the floor's, at 1 kHz
TWO_PROCESS = ('stock', 'single', 'multi')  # variants with the floor's process layout
# The programs the bench runs as subprocesses (python FILE ARGS), next to this file so
# that the bench runs from any working directory; each file's docstring says what it does.
PROGRAMS = Path(__file__).resolve().parent / 'loop_programs'
# A busy loop (--busy): PR_SET_PDEATHSIG first, so that it dies with the bench even if the
# bench is killed outright; the bench also kills it at the end.
BUSY_LOOP = PROGRAMS / 'busy_loop.py'
# Run a node with its executor replaced: python EXECUTOR_NODE VARIANT MODULE [--ros-args ...].
# run_node() looks arm_common.node.EXECUTOR up at call time (EventsExecutor as shipped).
EXECUTOR_NODE = PROGRAMS / 'executor_node.py'


def say(text: str) -> None:
    print(f'[bench] {text}', flush=True)


def pct(values: list[float], q: float) -> float:
    """The q-quantile (0..1) of ``values`` by nearest rank; nan when empty."""
    if not values:
        return float('nan')
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, round(q * (len(ordered) - 1))))]


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of process ``pid`` (all its threads) from /proc."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except OSError:
        return float('nan')
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def machine_busy() -> tuple[float, float]:
    """(busy, total) CPU seconds of the whole machine so far: total = CPUs x uptime, busy =
    total - idle, from /proc/uptime. (Not the user/system ticks of /proc/stat: they are
    sampled at the timer tick, and a loop of short wake-ups, as a 1 kHz ROS loop is, mostly
    sleeps at the tick: /proc/stat then counted up to ~70% of a core less than the node
    processes' own CPU time (precise, from /proc/PID/stat). The idle time is precise.)"""
    uptime, idle = (float(x) for x in Path('/proc/uptime').read_text().split()[:2])
    total = (os.cpu_count() or 1) * uptime
    return total - idle, total


# ---------------------------------------------------------------------- raw CDR decoding
# Both messages arrive as raw CDR (little endian, 4-byte encapsulation header): decoding
# only the few fields needed keeps the bench's own CPU use low.
def state_stamp_ns(raw: bytes) -> int:
    """header.stamp of a sensor_msgs/JointState in ns."""
    sec, nsec = struct.unpack_from('<iI', raw, 4)
    return sec * 1_000_000_000 + nsec


def command_answers_ns(raw: bytes) -> int | None:
    """The state stamp [ns] named by a command's layout.dim[0].label, or None."""
    from arm_dynamics.timing import parse_answer_tag

    (n_dims,) = struct.unpack_from('<I', raw, 4)
    if n_dims == 0:
        return None
    (length,) = struct.unpack_from('<I', raw, 8)
    return parse_answer_tag(raw[12:12 + length - 1].decode('ascii', 'replace'))


# The middleware floor: two processes bouncing one small message back and forth with the
# nodes' executor and QoS, callbacks doing nothing else: python PING_PONG ROLE SECONDS.
# The pinger prints its round trips per wall second; no lockstep over ROS can beat it.
PING_PONG = PROGRAMS / 'ping_pong.py'


def ping_pong_floor(seconds: float) -> float:
    """Round trips per wall second of :data:`PING_PONG` between two processes on the
    bench's domain (measured over the second half of ``seconds``); NaN if it failed."""
    import subprocess

    echo = subprocess.Popen([sys.executable, str(PING_PONG), 'echo', str(seconds + 5.0)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        pinger = subprocess.run([sys.executable, str(PING_PONG), 'pinger', str(seconds)],
                                capture_output=True, text=True, timeout=seconds + 30.0)
        return float(pinger.stdout.strip() or 'nan')
    except (subprocess.TimeoutExpired, ValueError):
        return math.nan
    finally:
        echo.terminate()
        echo.wait(10)


@contextmanager
def busy_loops(n: int):
    """N busy-loop processes (:data:`BUSY_LOOP`) for the duration of the ``with``: they
    are killed when it ends, however it ends (an exception, Ctrl-C; SIGTERM is turned into
    SystemExit meanwhile so that it unwinds too; and each loop dies with the bench)."""
    import subprocess

    def on_term(signum, _frame):
        raise SystemExit(128 + signum)

    previous = signal.signal(signal.SIGTERM, on_term)
    procs: list[subprocess.Popen] = []
    try:
        for _ in range(n):
            procs.append(subprocess.Popen([sys.executable, str(BUSY_LOOP)],
                                          stdin=subprocess.DEVNULL,
                                          stdout=subprocess.DEVNULL,
                                          stderr=subprocess.DEVNULL))
        yield procs
    finally:
        for proc in procs:
            proc.kill()
        for proc in procs:
            proc.wait()
        signal.signal(signal.SIGTERM, previous)


# ---------------------------------------------------------------------- processes
@dataclass
class Loop:
    """A simulator + controller pair on the bench's domain."""

    mode: str
    rate: float
    variant: str
    domain: int
    log_dir: Path
    procs: list = field(default_factory=list)
    bad_exits: list = field(default_factory=list)

    def start(self) -> None:
        from arm_sim import launcher

        sim_params = {'timing_mode': self.mode, 'publish_rate': self.rate,
                      'physics_step': 0.001}
        ctl_params = {'law': 'computed_torque', 'update_on': 'joint_states'}
        tag = f'{self.mode}-{self.rate:g}-{self.variant}'
        if self.variant == 'composed':
            self.procs.append(launcher.NodeProcess(
                'composed', params_file=launcher.config_file(),
                node_params={'simulator': sim_params, 'controller': ctl_params},
                domain_id=self.domain, log_path=self.log_dir / f'{tag}-composed.log'))
            return
        with self._executable(launcher):
            for name, params in (('simulator', sim_params), ('controller', ctl_params)):
                self.procs.append(launcher.NodeProcess(
                    name, params_file=launcher.config_file(), params=params,
                    domain_id=self.domain, log_path=self.log_dir / f'{tag}-{name}.log'))

    @contextmanager
    def _executable(self, launcher):
        if self.variant in ('stock', 'composed'):
            yield
            return
        with mock.patch.object(launcher, 'executable', lambda name: [
                sys.executable, str(EXECUTOR_NODE), self.variant, launcher.MODULES[name]]):
            yield

    def alive(self) -> bool:
        return all(p.alive() for p in self.procs)

    def cpu(self) -> list[float]:
        return [cpu_seconds(p.proc.pid) for p in self.procs]

    def stop(self) -> None:
        """SIGINT both (then SIGKILL after 5 s); abnormal exits land in ``bad_exits``."""
        for p in reversed(self.procs):
            code = p.stop(signal.SIGINT, timeout=5.0)
            if code not in (0, -signal.SIGINT):
                last = (p.output().strip().splitlines() or [''])[-1][:200]
                self.bad_exits.append(f'{p.name} exited {code} ({last})')
        self.procs.clear()

    def logs(self) -> str:
        return '\n'.join(f'--- {p.name} log:\n{p.output()[-1500:]}' for p in self.procs)


class Observer:
    """The bench's own rclpy side.

    /diagnostics goes through an EventsExecutor (cheap per message). States and commands
    (``watch_loop``) are subscribed raw on a second node that no executor spins: ``drain``
    takes them straight from the DDS history with their message info (publication and
    reception timestamps), so the bench's own scheduling delays do not enter the figures
    and its CPU use stays low. (EventsExecutor cannot deliver message info here: callbacks
    taking it fail with "SystemError: null argument to internal routine".)
    """

    def __init__(self, domain: int) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray

        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node('bench_loop', context=self.context)
        self.tap = rclpy.create_node('bench_loop_tap', context=self.context)
        try:
            from rclpy.experimental import EventsExecutor
            self.executor = EventsExecutor(context=self.context)
        except ImportError:
            from rclpy.executors import SingleThreadedExecutor
            self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.diag: list[tuple[float, dict]] = []
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 50)
        self.states: list = []
        self.commands: list = []
        self._subs: list = []

    def _on_diag(self, msg) -> None:
        for status in msg.status:
            if status.name == 'simulator: summary':  # arm_common.node.status_name
                values = {kv.key: kv.value for kv in status.values}
                values['message'] = status.message
                self.diag.append((time.monotonic(), values))

    def watch_loop(self) -> None:
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray

        self.unwatch()
        for msg_type, topic, sink in ((JointState, 'joint_states', self.states),
                                      (Float64MultiArray, 'effort_controller/commands',
                                       self.commands)):
            sub = self.tap.create_subscription(msg_type, topic, lambda _msg: None, 10000,
                                               raw=True)
            self._subs.append((sub, sink))

    def drain(self) -> None:
        for sub, sink in self._subs:
            with sub.handle:
                while True:
                    taken = sub.handle.take_message(sub.msg_type, True)
                    if taken is None:
                        break
                    raw, info = taken
                    sink.append((raw, info['source_timestamp'], info['received_timestamp']))

    def unwatch(self) -> None:
        for sub, _sink in self._subs:
            self.tap.destroy_subscription(sub)
        self._subs.clear()

    def clear(self) -> None:
        self.diag.clear()
        self.states.clear()
        self.commands.clear()

    def spin_for(self, seconds: float, until=None) -> bool:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if until is not None and until():
                return True
            self.executor.spin_once(timeout_sec=0.01)
            self.drain()
        return until() if until is not None else True

    def shutdown(self) -> None:
        self.unwatch()
        self.tap.destroy_node()
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


# ---------------------------------------------------------------------- measurements
@dataclass
class Result:
    mode: str
    rate: float
    variant: str
    ok: bool = True
    error: str = ''
    rtf: float = float('nan')  # mean of the simulator's achieved_real_time_factor windows
    rtf_min: float = float('nan')
    rtf_max: float = float('nan')
    windows: int = 0
    paced: float = float('nan')  # real_time: the simulator's paced_real_time_factor
    rtf_seen: float = float('nan')  # paced modes: state stamps / their publication times
    states: int = 0
    late: int = 0  # answered after the next state was due, or never
    skipped: int = 0  # control periods with no state at all (simulator overran)
    unanswered: int = 0  # states followed by the next before their answer was published
    lat_p50: float = float('nan')  # ms, observer: command received - state received
    lat_p99: float = float('nan')
    react_p50: float = float('nan')  # ms, command published - state published
    react_p99: float = float('nan')
    tick_p99: float = float('nan')  # ms, interval between state publications
    jit_p50: float = float('nan')  # ms, interval between new states' receptions
    jit_p99: float = float('nan')
    jit_max: float = float('nan')
    overruns: str = ''
    runs: int = 1
    samples: dict = field(default_factory=dict)  # raw per-run values, for merging repeats
    cpu: list = field(default_factory=list)  # % of one core: simulator, controller, bench
    sim_periods: int = 0  # paced modes: control periods the simulator integrated ...
    sim_late: int = 0  # ... wall_clock: those it integrated before the controller answered
    waits: int = 0  # real_time: periods whose answer came after they were due ...
    waited: float = 0.0  # ... and the wall seconds those answers were overdue, summed
    slips: int = 0  # real_time: pacing restarted after falling behind the wall clock
    other: float = float('nan')  # % of one core used by everything else on the machine

    @property
    def label(self) -> str:
        return LABELS.get(self.mode, self.mode)

    @property
    def periods(self) -> int:
        return self.states + self.skipped

    @property
    def sim_late_fraction(self) -> float:
        return self.sim_late / self.sim_periods if self.sim_periods else float('nan')

    @property
    def wait_fraction(self) -> float:
        return self.waits / self.sim_periods if self.sim_periods else float('nan')

    @property
    def late_fraction(self) -> float:
        return (self.late + self.skipped) / self.periods if self.periods else float('nan')


def sim_values(obs: Observer, since: float) -> list[dict]:
    return [v for t, v in obs.diag if t >= since]


def run_one(obs: Observer, loop: Loop, duration: float, warmup: float) -> Result:
    res = Result(loop.mode, loop.rate, loop.variant)
    obs.clear()
    if loop.mode in PACED_MODES:
        obs.watch_loop()
    loop.start()
    head = f'{LABELS.get(loop.mode, loop.mode)} {loop.rate:g} Hz [{loop.variant}]'
    try:
        if loop.mode == 'lockstep':
            started = obs.spin_for(20.0, lambda: any(
                int(v.get('commands_received', 0)) > 0 for _, v in obs.diag))
        else:
            # both subscriptions matched: discovery can take the bench's state subscription
            # seconds longer than its command subscription, and the window would miss states
            started = obs.spin_for(20.0, lambda: len(obs.commands) > 10
                                   and len(obs.states) > 10)
        if not started or not loop.alive():
            res.ok, res.error = False, 'loop did not start'
            say(f'{head}: loop did not start\n' + loop.logs())
            return res
        obs.spin_for(warmup)
        t0, wall0, cpu0, own0 = time.monotonic(), time.time_ns(), loop.cpu(), time.process_time()
        busy0 = machine_busy()
        obs.spin_for(duration)
        t1, wall1, cpu1, own1 = time.monotonic(), time.time_ns(), loop.cpu(), time.process_time()
        busy1 = machine_busy()
        obs.spin_for(0.2)  # commands answering the last states
        res.cpu = [100 * (b - a) / (t1 - t0) for a, b in zip(cpu0, cpu1)]
        res.cpu.append(100 * (own1 - own0) / (t1 - t0))
        # /proc/stat counts every CPU: busy seconds per wall second = cores in use
        res.other = 100 * (busy1[0] - busy0[0]) / (t1 - t0) - sum(res.cpu)
        if not loop.alive():
            res.ok, res.error = False, 'a node died'
            say(f'{head}: a node died\n' + loop.logs())
            return res
        values = sim_values(obs, t0)
        last = values[-1] if values else {}
        res.overruns = last.get('overruns', '0')
        if loop.mode == 'lockstep':
            window_factors(res, values, required=True)
        else:
            realtime_figures(res, obs, wall0, wall1)
            window_factors(res, values, required=False)
            simulator_counts(res, values)
            if loop.mode == 'real_time' and last.get('paced_real_time_factor'):
                res.paced = float(last['paced_real_time_factor'])
                res.samples['paced'] = [res.paced]
    finally:
        obs.unwatch()
        loop.stop()
    return res


def window_factors(res: Result, values: list[dict], required: bool) -> None:
    """Mean of the simulator's 1 s achieved_real_time_factor windows (each distinct window
    once: its summary may be published twice); the first may straddle the warm-up and is
    dropped. ``required``: no windows fails the run."""
    windows, seen = [], set()
    for v in values:
        key = v.get('window')
        if key in (None, '0') or key in seen or 'achieved_real_time_factor' not in v:
            continue
        seen.add(key)
        windows.append(float(v['achieved_real_time_factor']))
    windows = windows[1:]
    if not windows:
        if required:
            res.ok, res.error = False, 'no diagnostics windows'
        return
    res.samples['rtf'] = [statistics.fmean(windows)]
    res.samples['rtf_windows'] = windows
    res.windows = len(windows)
    res.rtf = statistics.fmean(windows)
    res.rtf_min, res.rtf_max = min(windows), max(windows)


def realtime_figures(res: Result, obs: Observer, wall0: int, wall1: int) -> None:
    """The paced modes as the bench sees them: every state published in [wall0, wall1)
    (system time ns), re-sent states (the same stamp again) left out, and the commands
    answering them."""
    period_ns = round(1e9 / res.rate)
    states, seen = [], set()
    for raw, src, rcv in obs.states:
        stamp = state_stamp_ns(raw)
        if stamp in seen:
            continue  # a re-send of a state nobody answered yet (heartbeat)
        seen.add(stamp)
        if wall0 <= src < wall1:
            states.append((stamp, src, rcv))
    answers: dict[int, tuple[int, int]] = {}
    for raw, src, rcv in obs.commands:
        named = command_answers_ns(raw)
        if named is not None and named not in answers:
            answers[named] = (src, rcv)
    if len(states) < 2:
        res.ok, res.error = False, 'too few states'
        return
    latency, react, ticks, jitter = [], [], [], []
    prev = None
    for stamp, src, rcv in states:
        if prev is not None:
            gap = stamp - prev[0]
            res.skipped += max(0, round(gap / period_ns) - 1)
            ticks.append((src - prev[1]) * 1e-6)
            jitter.append((rcv - prev[2]) * 1e-6)
            before = answers.get(prev[0])
            # the simulator went on before the answer to the previous state was even sent
            res.unanswered += int(before is None or before[0] > src)
        prev = (stamp, src, rcv)
        res.states += 1
        answer = answers.get(stamp)
        if answer is None:
            res.late += 1
            continue
        c_src, c_rcv = answer
        latency.append((c_rcv - rcv) * 1e-6)
        react.append((c_src - src) * 1e-6)
        if c_rcv > src + period_ns:
            res.late += 1
    (first, src0, _), (last, src1, _) = states[0], states[-1]
    res.rtf_seen = (last - first) / (src1 - src0) if src1 > src0 else float('nan')
    res.samples.update({'latency': latency, 'react': react, 'ticks': ticks,
                        'jitter': jitter, 'late%': [100 * res.late_fraction],
                        'seen': [res.rtf_seen]})
    res.lat_p50, res.lat_p99 = pct(latency, 0.5), pct(latency, 0.99)
    res.react_p50, res.react_p99 = pct(react, 0.5), pct(react, 0.99)
    res.tick_p99 = pct(ticks, 0.99)
    res.jit_p50, res.jit_p99 = pct(jitter, 0.5), pct(jitter, 0.99)
    res.jit_max = max(jitter)


def simulator_counts(res: Result, values: list[dict]) -> None:
    """The simulator's own counts over the window, from its cumulative summaries (first and
    last in the window): ``control_periods``, ``late_periods`` (wall_clock: integrated
    before the answer), ``real_time_waits``, ``real_time_waited_wall`` and
    ``real_time_slips`` (real_time)."""
    keys = ('control_periods', 'late_periods', 'real_time_waits', 'real_time_waited_wall',
            'real_time_slips')
    rows = [[float(v.get(k) or 0) for k in keys] for v in values if 'control_periods' in v]
    if len(rows) < 2:
        return
    periods, late, waits, waited, slips = (b - a for a, b in zip(rows[0], rows[-1]))
    res.sim_periods, res.sim_late = int(periods), int(late)
    res.waits, res.waited, res.slips = int(waits), waited, int(slips)
    res.samples['sim%'] = [100 * res.sim_late_fraction]


def merge(results: list[Result]) -> Result:
    """One result from repeats of the same configuration: real-time factors are the median
    of the repeats (min-max across them), counts and latency/jitter samples are pooled."""
    first = results[0]
    good = [r for r in results if r.ok]
    if len(results) == 1 or not good:
        return first
    out = Result(first.mode, first.rate, first.variant, runs=len(good))
    out.cpu = [statistics.median(c) for c in zip(*(r.cpu for r in good))]
    out.other = statistics.median(r.other for r in good)
    rtfs = [x for r in good for x in r.samples.get('rtf', [])]
    if rtfs:
        out.rtf, out.rtf_min, out.rtf_max = statistics.median(rtfs), min(rtfs), max(rtfs)
    out.windows = sum(r.windows for r in good)
    out.samples = {'rtf': rtfs}
    if first.mode == 'lockstep':
        return out
    pooled = {k: [x for r in good for x in r.samples.get(k, [])]
              for k in ('latency', 'react', 'ticks', 'jitter', 'late%', 'seen', 'paced')}
    for name in ('states', 'sim_periods', 'sim_late', 'late', 'skipped', 'unanswered',
                 'waits', 'waited', 'slips'):
        setattr(out, name, sum(getattr(r, name) for r in good))
    out.lat_p50, out.lat_p99 = pct(pooled['latency'], 0.5), pct(pooled['latency'], 0.99)
    out.react_p50, out.react_p99 = pct(pooled['react'], 0.5), pct(pooled['react'], 0.99)
    out.tick_p99 = pct(pooled['ticks'], 0.99)
    out.jit_p50, out.jit_p99 = pct(pooled['jitter'], 0.5), pct(pooled['jitter'], 0.99)
    out.jit_max = max(pooled['jitter'], default=float('nan'))
    if pooled['seen']:
        out.rtf_seen = statistics.median(pooled['seen'])
    if pooled['paced']:
        out.paced = statistics.median(pooled['paced'])
    out.samples.update(pooled)
    return out


def cpu_label(res: Result) -> str:
    return 'sim+ctl/bench' if res.variant == 'composed' else 'sim/ctl/bench'


def describe(res: Result) -> str:
    head = f'{res.label} {res.rate:g} Hz [{res.variant}]'
    cpu = '/'.join(f'{c:.0f}' for c in res.cpu)
    if not res.ok:
        return f'{head}: FAILED ({res.error})'
    if res.mode == 'lockstep':
        return (f'{head}: {res.rtf:.2f} sim-s per wall-s = {res.rtf:.2f}x real time '
                f'({res.rtf * res.rate:.0f} control steps/s, {1e6 / (res.rtf * res.rate):.0f}'
                f' us per state->command->state round; {res.windows} windows '
                f'{res.rtf_min:.2f}-{res.rtf_max:.2f}x; CPU % {cpu_label(res)} {cpu}, other '
                f'processes {res.other:.0f})')
    pace = (f'{res.rtf:.3f}x real time (simulator windows {res.rtf_min:.2f}-'
            f'{res.rtf_max:.2f}; bench {res.rtf_seen:.4f}'
            + (f'; paced {res.paced:.3f}' if res.mode == 'real_time' else '') + ')')
    jitter = (f'state interval p50 {res.jit_p50:.3f} ms p99 {res.jit_p99:.3f} ms max '
              f'{res.jit_max:.2f} ms (period {1e3 / res.rate:.2f} ms)')
    common = (f'latency p50 {res.lat_p50:.2f} ms p99 {res.lat_p99:.2f} ms, publish-to-publish '
              f'p50 {res.react_p50:.2f} ms p99 {res.react_p99:.2f} ms; CPU % '
              f'{cpu_label(res)} {cpu}, other processes {res.other:.0f}')
    if res.mode == 'real_time':
        return (f'{head}: {pace}; {jitter}; {res.waits} waits ({res.waited * 1e3:.1f} ms) '
                f'and {res.slips} slips in {res.sim_periods} periods; {res.unanswered} '
                f'states left before their answer was sent (must be 0); '
                f'{100 * res.late_fraction:.2f}% answered after a period; {common}')
    return (f'{head}: {pace}; {jitter}; {100 * res.late_fraction:.2f}% late cycles '
            f'({res.late} late or unanswered of {res.states} states + {res.skipped} skipped '
            f'periods); the simulator counted {res.sim_late} late of {res.sim_periods} '
            f'periods ({100 * res.sim_late_fraction:.2f}%), overrun reports {res.overruns}; '
            f'{common}')


# ---------------------------------------------------------------------- report
def no_ros_peer(rate: float, seconds: float) -> float:
    """x real time of the same lockstep loop in one process without ROS: SimulatorCore and
    ControllerCore (config/arm.yaml, computed torque holding the first position, physics
    step 1 ms) stepped directly, each tick as the nodes do it (state -> arrays -> update ->
    command list -> set_command -> advance, the limits check), no messages, no middleware.
    """
    import numpy as np
    import yaml

    from arm_control.core import ControllerCore
    from arm_control.laws import ControlLaw, Gains
    from arm_dynamics.limits import JointLimits
    from arm_dynamics.simulation import SimulatorCore
    from arm_dynamics.two_link import TwoLinkArm
    from arm_sim import launcher

    doc = yaml.safe_load(Path(launcher.config_file()).read_text())
    p = {**doc['/**']['ros__parameters'], **doc['/**/simulator']['ros__parameters'],
         **doc['/**/controller']['ros__parameters']}
    arm = TwoLinkArm.from_params({k: p[k] for k in TwoLinkArm.PARAMETERS if k in p})
    limits = JointLimits.from_params(p)
    period = int(round(1e9 / rate))
    sim = SimulatorCore(arm, q0=p['initial_positions'], qd0=p['initial_velocities'],
                        effort_limits=p['effort_limits'], physics_step_ns=1_000_000,
                        control_period_ns=period, velocity_limit=1e3,
                        joint_names=p['joint_names'], joint_limits=limits,
                        envelope=limits.envelope(p['fault_position_margin'],
                                                 p['fault_velocity_factor']))
    gains = Gains(p['gains.kp'], p['gains.kd'], p['gains.ki'], p['gains.i_clamp'])
    ctl = ControllerCore(p['joint_names'], ControlLaw(p['law'], gains, arm,
                                                      tuple(p['effort_limits'])),
                         limits=limits)
    ticks, begun = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - begun) < seconds:
        for _ in range(1000):
            view = sim.joint_view()
            sec, nsec = divmod(sim.time_ns, 1_000_000_000)
            step = ctl.update(sec + nsec * 1e-9, np.array(view.position),
                              np.array(view.velocity))
            sim.set_command(step.command.tau.tolist())
            sim.advance()
            sim.outside_limits  # noqa: B018 -- the simulator node checks it every period
        ticks += 1000
    return ticks * period * 1e-9 / elapsed


def table(results: list[Result], repeats: int = 1,
          peer: dict[float, float] | None = None, floor: float = math.nan,
          busy: int = 0) -> str:
    def num(x: float, fmt: str) -> str:
        return '-' if x != x else format(x, fmt)

    lines = ['', '== Lockstep: simulated seconds per wall second (target >= 1x at 1 kHz; '
             f'two processes >= {100 * FLOOR_TARGET:.0f}% of the floor) ==',
             f"{'control':>8} {'executor':>9} {'x real time':>11} {'min-max':>11} "
             f"{'steps/s':>8} {'us/round':>8} {'% floor':>7} {'CPU% sim/ctl':>13} "
             f"{'other':>5}"]
    for r in results:
        if r.mode != 'lockstep':
            continue
        if not r.ok:
            lines.append(f'{r.rate:>6g}Hz {r.variant:>9} FAILED: {r.error}')
            continue
        nodes_cpu = '/'.join(f'{c:.0f}' for c in r.cpu[:-1])
        lines.append(f'{r.rate:>6g}Hz {r.variant:>9} {r.rtf:>10.2f}x '
                     f'{r.rtf_min:>5.2f}-{r.rtf_max:<5.2f} {r.rtf * r.rate:>8.0f} '
                     f'{1e6 / (r.rtf * r.rate):>8.0f} '
                     f'{num(100 * r.rtf * r.rate / floor, "6.0f")}% {nodes_cpu:>13} '
                     f'{r.other:>5.0f}')
    for rate, rtf in (peer or {}).items():
        lines.append(f'{rate:>6g}Hz {"no ROS":>9} {rtf:>10.2f}x {"":>11} {rtf * rate:>8.0f} '
                     f'{1e6 / (rtf * rate):>8.1f}')
    for rate in (peer or {}) if floor == floor else ():
        lines.append(f'{rate:>6g}Hz {"floor":>9} {floor / rate:>10.2f}x {"":>11} '
                     f'{floor:>8.0f} {1e6 / floor:>8.1f} {100:>6.0f}%')
    if peer:
        lines.append('(no ROS = SimulatorCore + ControllerCore stepped directly in this '
                     'process, best of 3: the loop\n without middleware or messages; floor = '
                     'two rclpy processes bouncing a 2-double message\n with the nodes\' '
                     'executor and QoS and empty callbacks, best of the repeats: no lockstep '
                     'over\n ROS here can beat it; % floor = lockstep rounds per second / '
                     'the floor\'s round trips per second)')
    paced = sorted((r for r in results if r.mode in PACED_MODES),
                   key=lambda r: (r.rate, VARIANTS.index(r.variant), r.mode))
    mode_w = max((len(r.label) for r in paced), default=4)
    lines += ['', '== Real time, side by side: achieved pace and state publication jitter '
              f'(target >= {RTF_TARGET}x at 250 Hz, quiet machine) ==',
              f"{'control':>8} {'executor':>9} {'mode':<{mode_w}} {'x RT':>6} {'min-max':>9} "
              f"{'bench':>6} {'paced':>6} {'jit p50':>7} {'jit p99':>7} {'period':>6} "
              f"{'waits':>6} {'waited':>6} {'slips':>5} {'inexact':>7}"]
    for r in paced:
        if not r.ok:
            lines.append(f'{r.rate:>6g}Hz {r.variant:>9} {r.label:<{mode_w}} FAILED: '
                         f'{r.error}')
            continue
        rt = r.mode == 'real_time'
        # real_time integrates only answered periods: exact by construction (and the bench
        # saw every answer sent before the next state); wall_clock: the simulator's count
        inexact = (f'{r.unanswered:>6}!' if r.unanswered else '     0') if rt else (
            num(100 * r.sim_late_fraction, '5.2f') + '%')
        lines.append(f'{r.rate:>6g}Hz {r.variant:>9} {r.label:<{mode_w}} '
                     f'{num(r.rtf, "6.3f")} {num(r.rtf_min, "4.2f"):>4}-'
                     f'{num(r.rtf_max, "4.2f"):<4} {num(r.rtf_seen, "6.3f")} '
                     f'{num(r.paced, "6.3f") if rt else "":>6} {num(r.jit_p50, "7.3f")} '
                     f'{num(r.jit_p99, "7.3f")} {1e3 / r.rate:>6.2f} '
                     f'{r.waits if rt else "":>6} '
                     f'{num(r.waited, "6.3f") if rt else "":>6} {r.slips if rt else "":>5} '
                     f'{inexact:>7}')
    lines.append('(x RT = mean of the simulator\'s ~1 s achieved_real_time_factor windows, '
                 'min-max across them; bench = state\n stamps advanced / their publication '
                 'times, as the bench sees them; paced = the simulator\'s paced_real_time_'
                 'factor\n over its whole run; jit = ms between the receptions of successive '
                 'new states (re-sends left out); waits =\n periods whose answer came after '
                 'they were due (waited: s, summed), slips = pacing restarts after falling\n '
                 '> 5 periods and 100 ms behind; inexact: real_time\'s results are exact by '
                 'construction '
                 '(lockstep\'s, bit for bit: a period\n is integrated only once its answer '
                 'is in; the bench checks that every answer was sent before the next\n '
                 'state: 0), wall_clock = % of periods integrated before their answer came '
                 '(the simulator\'s count))')
    lines += ['', '== Real time: late cycles and state->command latency '
              '(wall_clock target < 1% late or skipped at 1 kHz) ==',
              f"{'control':>8} {'executor':>9} {'mode':<{mode_w}} {'late %':>7} {'sim %':>6} "
              f"{'late':>5} {'skip':>5} {'states':>6} {'lat p50':>7} {'lat p99':>7} "
              f"{'pub p50':>7} {'pub p99':>7} {'tick p99':>8} "
              f"{'CPU% sim/ctl/bench':>18} {'other':>5}"]
    for r in paced:
        if not r.ok:
            continue
        cpu = '/'.join(f'{c:.0f}' for c in r.cpu)
        sim = num(100 * r.sim_late_fraction, '5.2f') + '%' if r.mode == 'wall_clock' else '-'
        lines.append(f'{r.rate:>6g}Hz {r.variant:>9} {r.label:<{mode_w}} '
                     f'{100 * r.late_fraction:>6.2f}% {sim:>6} {r.late:>5} {r.skipped:>5} '
                     f'{r.states:>6} {num(r.lat_p50, "7.2f")} '
                     f'{num(r.lat_p99, "7.2f")} {num(r.react_p50, "7.2f")} '
                     f'{num(r.react_p99, "7.2f")} '
                     f'{num(r.tick_p99, "8.2f")} {cpu:>18} {r.other:>5.0f}')
    lines.append('(late % = answered after a period or never, or skipped, as the bench sees '
                 'them (real_time: time\n waited instead); sim % = wall_clock periods the '
                 'simulator integrated before the controller had answered\n their state, its '
                 'own count; ms; lat = command received - state received, as the bench '
                 'receives them;\n pub = command published - state published, from the '
                 'publishers\' timestamps; tick = interval between\n states as published; '
                 'CPU in % of one core (composed: sim+ctl in one process), "other" = every '
                 'other\n process on the machine' + (f', the {busy} busy loops included)'
                                                     if busy else ')'))
    lines += ['', '== Summary ==' + (f' ({repeats} interleaved repeats per configuration: '
                                     'real-time factors = median, the rest pooled)'
                                     if repeats > 1 else '')]
    if busy:
        lines.append(f'(with {busy} busy loops running all along: the machine is loaded on '
                     'purpose)')
    others = [r.other for r in results if r.ok and r.other == r.other]
    if others:
        lines.append(f'other processes used {statistics.fmean(others):.0f}% of a core on '
                     f'average during the runs ({min(others):.0f}-{max(others):.0f}; '
                     f'{100 * (os.cpu_count() or 1)}% = every core)')
    for variant in dict.fromkeys(r.variant for r in results):
        mine = [r for r in results if r.variant == variant and r.ok]
        lock = sorted((r for r in mine if r.mode == 'lockstep'), key=lambda r: -r.rate)
        for r in lock:
            line = f'[{variant}] lockstep {r.rate:g} Hz: {r.rtf:.2f}x real time'
            if r.rate == 1000.0:
                verdict = 'meets' if r.rtf >= LOCKSTEP_TARGET else 'MISSES'
                line += f' ({verdict} the >= 1x target)'
                if peer and 1000.0 in peer:
                    line += f'; {peer[1000.0] / r.rtf:.1f}x slower than without ROS'
            if floor == floor:
                ratio = r.rtf * r.rate / floor
                line += (f'; {r.rtf * r.rate:.0f} rounds/s = {100 * ratio:.0f}% of the floor '
                         f'({floor:.0f} round trips/s, this run)')
                if variant in TWO_PROCESS and r.rate == max(x.rate for x in lock):
                    verdict = 'meets' if ratio >= FLOOR_TARGET else 'MISSES'
                    line += f' ({verdict} the >= {100 * FLOOR_TARGET:.0f}% target)'
            lines.append(line)
        for r in sorted((r for r in mine if r.mode == 'real_time'), key=lambda r: r.rate):
            verdict = ''
            if r.rate == 250.0 and not busy:
                verdict = (' (meets' if r.rtf >= RTF_TARGET else ' (MISSES') + (
                    f' the >= {RTF_TARGET}x target)')
            elif r.rate == 250.0:
                verdict = (f' ({"at least" if r.rtf >= RTF_TARGET else "below"} {RTF_TARGET}x '
                           f'under {busy} busy loops; the target is for a quiet machine)')
            lines.append(f'[{variant}] real_time (new) {r.rate:g} Hz: {r.rtf:.3f}x real time'
                         f'{verdict} (bench {r.rtf_seen:.3f}); state interval p50/p99 '
                         f'{r.jit_p50:.2f}/{r.jit_p99:.2f} ms of {1e3 / r.rate:.2f}; '
                         f'{r.waits} waits ({100 * r.wait_fraction:.2f}% of periods), '
                         f'{r.slips} slips; results exact'
                         + ('' if not r.unanswered else
                            f' -- BUT {r.unanswered} states were followed by the next before '
                            'their answer was sent'))
        wc = sorted((r for r in mine if r.mode == 'wall_clock'), key=lambda r: r.rate)
        if wc:
            held = [r for r in wc if r.late_fraction < LATE_LIMIT]
            best = (f'{held[-1].rate:g} Hz ({100 * held[-1].late_fraction:.2f}% late)'
                    if held else 'none of the rates tried')
            lines.append(f'[{variant}] wall_clock (old real_time): highest rate with < 1% '
                         f'late cycles: {best}; tried ' + ', '.join(
                             f'{r.rate:g} Hz {100 * r.late_fraction:.1f}%' + (
                                 ' (runs ' + '/'.join(f'{x:.1f}' for x in r.samples['late%'])
                                 + ')' if r.runs > 1 else '') for r in wc))
            for r in (r for r in wc if r.rate in (250.0, 1000.0)):
                verdict = 'meets' if r.late_fraction < LATE_LIMIT else 'MISSES'
                lines.append(f'[{variant}] wall_clock {r.rate:g} Hz: {r.rtf:.3f}x real time; '
                             f'{100 * r.late_fraction:.2f}% late or skipped as the bench sees '
                             f'them ({verdict} the < 1% target); the simulator counted '
                             f'{100 * r.sim_late_fraction:.2f}% of periods integrated before '
                             'their answer' + (' (results inexact)' if r.sim_late else
                                               ' (exact this time, by luck: not guaranteed)'))
    return '\n'.join(lines)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(
        prog='bench_loop.py',
        description='Closed-loop benchmark over ROS between the simulator and controller '
                    'node processes: lockstep speed (and its ratio to the middleware floor), '
                    'and real_time (new: paced lockstep) side by side with wall_clock (the '
                    'old real_time): pace, jitter, waits, late cycles and latency.',
        epilog='Every process runs on ROS_DOMAIN_ID=--domain with '
               'ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and is stopped at the end.')
    ap.add_argument('--quick', action='store_true',
                    help='smoke run (~100 s): 4 s windows, real time at 250 and 1000 Hz '
                         'only, stock and composed only')
    ap.add_argument('--duration', type=float, default=None,
                    help='measurement window per run in wall seconds (default 10, quick 4)')
    ap.add_argument('--warmup', type=float, default=None,
                    help='wall seconds after the loop starts before measuring '
                         '(default 1.5, quick 1)')
    ap.add_argument('--rates', type=str, default=None,
                    help='real-time control rates in Hz, comma separated, for every mode of '
                         '--modes (default 100,250,500,1000; quick 250,1000)')
    ap.add_argument('--modes', type=str, default=','.join(PACED_MODES),
                    help='paced timing modes to run at --rates, comma separated: real_time '
                         '(new: lockstep at wall-clock pace), wall_clock (the old real_time) '
                         f'(default {",".join(PACED_MODES)})')
    ap.add_argument('--lockstep-rates', type=str, default='1000,250',
                    help='lockstep control rates in Hz (default 1000,250)')
    ap.add_argument('--executors', type=str, default=None,
                    help='node executor variants, comma separated, from '
                         f'{",".join(VARIANTS)}; stock = the nodes as shipped, composed = '
                         'both in one process (default stock,composed,single; quick: '
                         'stock,composed); '
                         'non-stock variants run lockstep at the highest lockstep rate '
                         'and real time at the two highest rates')
    ap.add_argument('--repeats', type=int, default=1,
                    help='run every configuration this many times, interleaved; the table '
                         'gives median real-time factors and pooled counts and samples')
    ap.add_argument('--busy', type=int, default=0, metavar='N',
                    help='run N busy-loop processes (bench/loop_programs/busy_loop.py: '
                         '"while True: pass") during every measurement, floor and no-ROS '
                         'peer included (default 0)')
    ap.add_argument('--domain', type=int, default=None,
                    help=f'ROS_DOMAIN_ID for every process (default: {DEFAULT_DOMAIN} or the '
                    'next one no other arm_sim process on this machine holds)')
    ap.add_argument('--log-dir', type=Path, default=None,
                    help='where node logs go (default: a temporary directory)')
    args = ap.parse_args(argv)
    if args.busy < 0:
        ap.error('--busy must be >= 0')
    args.duration = args.duration or (4.0 if args.quick else 10.0)
    args.warmup = args.warmup if args.warmup is not None else (1.0 if args.quick else 1.5)
    rates = args.rates or ','.join(f'{r:g}' for r in (
        QUICK_REALTIME_RATES if args.quick else REALTIME_RATES))
    args.rt_rates = [float(r) for r in rates.split(',') if r]
    args.ls_rates = [float(r) for r in args.lockstep_rates.split(',') if r]
    args.paced_modes = [m for m in args.modes.split(',') if m]
    bad = [m for m in args.paced_modes if m not in PACED_MODES]
    if bad:
        ap.error(f'unknown mode(s) {bad}; choose from {PACED_MODES}')
    executors = args.executors or ('stock,composed' if args.quick else
                                   'stock,composed,single')
    args.variants = [v for v in executors.split(',') if v]
    bad = [v for v in args.variants if v not in VARIANTS]
    if bad:
        ap.error(f'unknown executor variant(s) {bad}; choose from {VARIANTS}')
    return args


def plan(args: argparse.Namespace) -> list[tuple[str, float, str]]:
    """Every configuration once per repeat; the paced modes side by side at each rate, and
    variants interleaved within a configuration so that background load hits them alike.
    Non-stock variants run only lockstep at the highest lockstep rate and the paced modes
    at the two highest real-time rates."""
    configs = [('lockstep', r) for r in args.ls_rates] + [
        (m, r) for r in args.rt_rates for m in args.paced_modes]
    compare = {('lockstep', max(args.ls_rates, default=0.0))}
    compare |= {(m, r) for r in sorted(args.rt_rates)[-2:] for m in args.paced_modes}
    runs = []
    for _ in range(args.repeats):
        for config in configs:
            runs += [(*config, v) for v in args.variants if v == 'stock' or config in compare]
    return runs


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.domain is None:
        from arm_common.process import claim_domain

        args.domain = claim_domain(DEFAULT_DOMAIN)
    os.environ['ROS_DOMAIN_ID'] = str(args.domain)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    runs = plan(args)
    per_run = args.duration + args.warmup + 3.0
    with busy_loops(args.busy) as loops:
        say(f'{len(runs)} runs of {args.duration:g} s (+{args.warmup:g} s warm-up, ~3 s start/'
            f'stop): ~{len(runs) * per_run:.0f} s; domain {args.domain}, '
            f'{os.cpu_count()} CPUs, load average '
            + ' '.join(f'{x:.2f}' for x in os.getloadavg())
            + (f'; {len(loops)} busy loops running (pids '
               + ' '.join(str(p.pid) for p in loops) + ')' if loops else ''))
        return measure(args, runs)


def measure(args: argparse.Namespace, runs: list[tuple[str, float, str]]) -> int:
    log_ctx = (tempfile.TemporaryDirectory(prefix='bench_loop-') if args.log_dir is None
               else None)
    log_dir = Path(log_ctx.name) if log_ctx else args.log_dir
    log_dir.mkdir(parents=True, exist_ok=True)
    obs = Observer(args.domain)
    results: list[Result] = []
    begun = time.monotonic()
    try:
        for i, (mode, rate, variant) in enumerate(runs, 1):
            loop = Loop(mode, rate, variant, args.domain, log_dir)
            try:
                res = run_one(obs, loop, args.duration, args.warmup)
            finally:
                loop.stop()
            results.append(res)
            say(f'({i}/{len(runs)}, {time.monotonic() - begun:.0f} s) {describe(res)}')
            if loop.bad_exits:
                say('  on SIGINT: ' + '; '.join(loop.bad_exits)
                    + ('' if log_ctx else f' (logs in {log_dir})'))
    except KeyboardInterrupt:
        say('interrupted: partial results')
    finally:
        obs.shutdown()
        if log_ctx:
            log_ctx.cleanup()
    say(f'done in {time.monotonic() - begun:.0f} s; load average now '
        + ' '.join(f'{x:.2f}' for x in os.getloadavg()))
    groups: dict[tuple, list[Result]] = {}
    for r in results:
        groups.setdefault((r.mode, r.rate, r.variant), []).append(r)
    peer = {rate: max(no_ros_peer(rate, 1.0) for _ in range(3)) for rate in args.ls_rates}
    say('measuring the middleware floor (rclpy ping-pong between two processes) ...')
    floors = [ping_pong_floor(args.duration) for _ in range(args.repeats)]
    floor = max((f for f in floors if f == f), default=math.nan)
    say('  round trips/s: ' + ', '.join(f'{f:.0f}' for f in floors))
    print(table([merge(g) for g in groups.values()], args.repeats, peer, floor, args.busy))
    return 0 if results and all(r.ok for r in results) else 1


if __name__ == '__main__':
    raise SystemExit(main())
