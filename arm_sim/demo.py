"""``arm-sim demo``: the lecture's two tasks on the simulated arm, recorded and analysed.

Starts simulator (lockstep, or real_time: lockstep at wall-clock pace), controller,
planner, recorder and visualizer (markers and robot_description, recorded too) as separate
processes with ``config/arm.yaml``, then drives a fixed scenario. Every goal takes effect
at an exact simulated time: the simulator pauses there (``pause_at``), the goal is planned
from the paused state and the controller accepts it before time moves on, so two runs, in
either timing mode, record the same joint states.
"""

from __future__ import annotations

import functools
import math
import os
import signal
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from arm_bag.recorder_node import DEFAULT_TOPICS
from arm_dynamics import TwoLinkArm
from arm_sim.client import SuiteClient, SuiteError, stamp_of
from arm_sim.launcher import NodeProcess, config_file, recorder_gates

PF = (0.5, 1.2)  # m: the regulation goal
SETTLE = 1.0  # s of simulated time after each planned motion
PERIOD = 0.01  # s, the control period in config/arm.yaml (publish_rate 100 Hz)
PD_GAINS = {'gains.kp': [600.0, 300.0], 'gains.kd': [60.0, 25.0]}  # N m/rad, N m s/rad


@dataclass(frozen=True)
class TaskResult:
    """What one task did: planned motion time [s] and the tip's distance to the goal
    after settling [m]."""

    task: Task
    motion: float
    tip_error: float


@dataclass(frozen=True)
class Task:
    """One step of the scenario: goal [m] and the parameters it runs with."""

    label: str
    goal: tuple[float, float]
    planner: dict = field(default_factory=dict)
    controller: dict = field(default_factory=dict)


def scenario(ps: tuple[float, float], fast: float = 0.8, slow: float = 3.0) -> list[Task]:
    """Regulation Ps -> Pf, then the line Pf -> Ps slow and fast under computed torque,
    and fast under plain PD (regulation moves return to Pf in between)."""
    ct = {'law': 'computed_torque'}
    regulation = {'mode': 'regulation', 'duration': 0.0}  # duration from the speed limits
    back = Task('regulation, back to Pf', PF, regulation, ct)
    line = {'mode': 'straight_line', 'time_scaling': 'quintic'}
    return [
        Task('regulation Ps -> Pf (computed torque)', PF, regulation, ct),
        Task(f'straight line Pf -> Ps, slow ({slow:g} s, computed torque)', ps,
             {**line, 'duration': slow}, ct),
        back,
        Task(f'straight line Pf -> Ps, fast ({fast:g} s, computed torque)', ps,
             {**line, 'duration': fast}, ct),
        back,
        Task(f'straight line Pf -> Ps, fast ({fast:g} s, plain PD)', ps,
             {**line, 'duration': fast}, {'law': 'pd', **PD_GAINS}),
    ]


def start_pose(config: Path) -> tuple[TwoLinkArm, np.ndarray]:
    """The arm and its initial joint positions as config/arm.yaml defines them."""
    data = yaml.safe_load(config.read_text())
    robot = data.get('/**', {}).get('ros__parameters', {})
    sim = data.get('/**/simulator', {}).get('ros__parameters', {})
    arm = TwoLinkArm.from_params(robot)
    return arm, np.array(sim.get('initial_positions', [-0.4, 1.2]), dtype=float)


class Demo:
    """Runs the scenario; ``out`` gets ``bag/``, ``report.png`` and ``logs/``."""

    def __init__(self, out: Path, domain_id: int, fast: float, slow: float,
                 echo=print, foxglove: int | None = None,
                 timing_mode: str = 'lockstep', real_arm: bool = False,
                 foxglove_host: str = '127.0.0.1') -> None:
        self.out = out
        self.timing_mode = timing_mode
        self.timing: dict[str, str] = {}  # the simulator's last summary (its counters)
        self.foxglove = foxglove  # port of the live node (Foxglove WebSocket); None: none
        self.foxglove_host = foxglove_host  # the address it listens on
        self.domain = domain_id
        self.echo = echo
        self.config = config_file()
        # --real-arm: config/real_arm.yaml after it (geared motors, friction, sensors).
        self.params_files = [self.config] + ([config_file('real_arm.yaml')] if real_arm
                                             else [])
        self.gates = recorder_gates(self.config)
        self.arm, self.q0 = start_pose(self.config)
        x, y = (float(v) for v in self.arm.forward_kinematics(self.q0))
        ps = (x, y)
        self.tasks = scenario(ps, fast, slow)
        self.procs: list[NodeProcess] = []
        self.lost: list[NodeProcess] = []  # optional nodes that exited (reported)
        self.results: list[TaskResult] = []
        self.warnings: list[str] = []

    def _start(self, name: str, **params) -> None:
        # The simulator, controller and visualizer send nothing before the recorder has
        # matched them: the bag holds their first messages (arm_sim.launcher.recorder_gates).
        params = {**self.gates.get(name, {}).get(name, {}), **params}
        self.procs.append(NodeProcess(
            name, params_file=self.params_files, params=params, domain_id=self.domain,
            log_path=self.out / 'logs' / f'{name}.log'))

    def _alive(self) -> None:
        """SuiteError if a node of the suite exited; the live view (an extra) that exits is
        reported once and the run goes on without it."""
        for p in self.procs:
            if p.alive() or p in self.lost:
                continue
            if p.name == 'live':
                self.lost.append(p)
                self.echo(f'warning: the live view exited with code {p.proc.returncode} '
                          f'(log: {p.log_path}); the demo goes on without it')
                continue
            raise SuiteError(f'{p.name} exited with code {p.proc.returncode}: '
                             f'{p.output().strip()[-300:]} (log: {p.log_path})')

    def run(self) -> Path:
        """Run everything; returns the bag directory."""
        (self.out / 'logs').mkdir(parents=True, exist_ok=True)
        bag = self.out / 'bag'
        self.echo(f'starting simulator, controller, planner, recorder and visualizer (ROS '
                  f'domain {self.domain}, localhost only; logs in {self.out / "logs"})')
        if self.foxglove is not None:  # first: Foxglove sees the run from its start
            self._start('live', port=self.foxglove, host=self.foxglove_host)
        self._start('recorder', output=str(bag))
        self._start('visualizer')
        self._start('simulator', timing_mode=self.timing_mode, pause_at=0.05)
        self._start('planner')
        client = SuiteClient(self.domain)
        codes = {}
        try:
            self._drive(client)
            self.timing = client.latest_values('simulator')
            # The simulation stands paused at its end: stop everything but the recorder,
            # then let the recorder take what is still on its way to it.
            codes = {p.name: p.stop(signal.SIGINT) for p in self.procs
                     if p.name != 'recorder'}
            self._drain_recorder(client)
            self.warnings += suite_warnings(client)
            for w in self.warnings:
                self.echo(f'warning: {w}')
        finally:
            client.close()
            codes.update({p.name: p.stop(signal.SIGINT) for p in self.procs
                          if p.name not in codes})
        reported = {p.name for p in self.lost}
        bad = {n: c for n, c in codes.items()
               if c not in (0, -signal.SIGINT) and n not in reported}
        if bad:
            raise SuiteError(f'processes did not stop cleanly: {bad}; see {self.out}/logs')
        return bag

    def _drive(self, c: SuiteClient) -> None:
        wait = 30.0
        if self.foxglove is not None:
            live = next(p for p in self.procs if p.name == 'live')
            c.spin_until(lambda: 'serving ws://' in live.output(), wait,
                         'the live node to serve Foxglove', self._alive)
            url = live.output().split('serving ', 1)[1].split()[0]
            self.echo(f'Foxglove: open connection -> {url.replace("127.0.0.1", "localhost")}'
                      ', then import the layout config/foxglove/arm_layout.json')
        needed = [('recorder', t) for t in DEFAULT_TOPICS] + [
            ('planner', 'joint_states'), ('planner', 'goal_pose'),
            ('visualizer', 'joint_states')]
        for node, topic in needed:
            c.spin_until(functools.partial(c.subscribed, topic, node), wait,
                         f'the {node} to subscribe {topic}', self._alive)
        # The simulator re-sends its first state until a command comes: start the controller
        # (and so the loop) only once the recorder has that state, so the bag has every one.
        c.spin_until(lambda: self._recorded(c, 'joint_states'), wait,
                     'the recorder to record a joint state', self._alive)
        self._start('controller')
        # The recorder, and this client, must also be matched with the controller's topics
        # before the first task (discovery of a new process takes a moment, and what is
        # published before the match is not delivered): creep through the initial hold
        # until both have received them (the recorded joint states do not depend on where
        # the simulation pauses).
        def matched() -> bool:
            return c.reference_time > -math.inf and all(self._recorded(c, t) for t in (
                'effort_controller/commands', 'arm_controller/reference'))

        hold = 0.05
        while not matched():
            try:
                self._run_to(c, hold, answered=False)
                c.spin_until(matched, 1.5, 'the recorder and this client', self._alive)
            except SuiteError:
                hold = round(hold + 0.05, 2)
                if hold >= 0.5:
                    raise SuiteError('the recorder receives no commands or references from '
                                     'the controller') from None
        t_next = 0.5
        self.echo(f'the arm starts at rest at q = {self.q0.tolist()} rad, tip Ps = '
                  f'({self.tasks[1].goal[0]:.3f}, {self.tasks[1].goal[1]:.3f}) m, held by '
                  'the controller')
        self._run_to(c, t_next)
        accepted = 0
        for k, task in enumerate(self.tasks, 1):
            c.set_params('planner', **task.planner)
            if task.controller:
                c.set_params('controller', **task.controller)
            n_traj = len(c.trajectories)
            c.publish_goal(*task.goal)
            def planned(n: int = n_traj) -> bool:
                return len(c.trajectories) > n or bool(self._refusal(c))

            c.spin_until(planned, wait, 'the plan', self._alive)
            refusal = self._refusal(c)
            if refusal:
                raise SuiteError(f'task {k} ({task.label}): planner refused: {refusal}')
            accepted += 1
            def confirmed(a: int = accepted) -> bool:
                return self._accepted(c) >= a

            c.spin_until(confirmed, wait,
                         'the controller to accept the trajectory', self._alive)
            pts = c.trajectories[-1].points
            dur = pts[-1].time_from_start.sec + pts[-1].time_from_start.nanosec * 1e-9
            t_start = t_next
            planned_from = stamp_of(c.trajectories[-1])
            if abs(planned_from - t_start) > 1e-9:
                self.warnings.append(f'task {k} was planned from the state at t = '
                                     f'{planned_from:.3f} s, not the paused one at '
                                     f'{t_start:.3f} s: this run may not repeat exactly')
            t_next = round((t_next + dur + SETTLE) / PERIOD) * PERIOD
            self.echo(f'[{k}/{len(self.tasks)}] t = {t_start:5.2f} s  {task.label}: '
                      f'{len(pts)} points over {dur:.2f} s')
            self._run_to(c, t_next)
            tip = self.arm.forward_kinematics(np.array(c.states[-1].position))
            miss = float(np.hypot(*(tip - np.array(task.goal))))
            self.results.append(TaskResult(task, dur, miss))
            self.echo(f'        tip at ({tip[0]:.4f}, {tip[1]:.4f}) m, {miss * 1e3:.2f} mm '
                      'from the goal after settling')

    def _run_to(self, c: SuiteClient, t: float, answered: bool = True) -> None:
        """Run to ``t`` and (``answered``) wait until the controller has answered the
        state at ``t``: a parameter or trajectory change before that answer would make the
        run depend on timing."""
        c.set_params('simulator', pause_at=t)
        c.spin_until(lambda: c.sim_time >= t - 1e-9 or self._paused_at(c, t), 60.0,
                     f'simulated time {t:.2f} s', self._alive)
        if answered:
            try:
                c.spin_until(lambda: c.reference_time >= t - 1e-9, 5.0,
                             f"the controller's answer at {t:.2f} s", self._alive)
            except SuiteError as exc:  # seen once under load: the answer never reached us
                self.warnings.append(f'{exc}; this run may not repeat exactly')

    def _drain_recorder(self, c: SuiteClient, topics=('joint_states',
                                                      'effort_controller/commands',
                                                      'arm_controller/reference')) -> None:
        """Wait until two successive recorder reports show the same counts for the run's
        topics, nothing being published any more: the recorder has every message that
        reached it (its queue is drained)."""
        keys = [f'received /{t}' for t in topics]
        since = len(c.diagnostic_values)

        def settled() -> bool:
            counts = [tuple(v.get(k) for k in keys) for n, v in c.diagnostic_values[since:]
                      if n == 'recorder' and 'received' in v]
            return len(counts) >= 2 and counts[-1] == counts[-2]

        try:
            c.spin_until(settled, 15.0, 'the recorder to take the last messages')
        except SuiteError as exc:
            self.warnings.append(f'{exc}: the bag may lack the last messages')

    @staticmethod
    def _paused_at(c: SuiteClient, t: float) -> bool:
        """The simulator's /diagnostics summary says it is paused at ``t``."""
        return any(node == 'simulator' and v.get('paused_at')
                   and abs(float(v['paused_at']) - t) < 1e-9
                   for node, v in c.diagnostic_values[-20:])

    @staticmethod
    def _refusal(c: SuiteClient) -> str | None:
        refused = [e for e in c.events_of('planner') if e.kind.startswith('goal_')]
        return refused[-1].message if refused else None

    @staticmethod
    def _recorded(c: SuiteClient, topic: str) -> bool:
        key = f'received /{topic}'
        return any(node == 'recorder' and int(values.get(key, 0)) > 0
                   for node, values in c.diagnostic_values)

    @staticmethod
    def _accepted(c: SuiteClient) -> int:
        return len(c.events_of('controller', 'trajectory_accepted'))


#: Reports that are the run's own subject, not something late, refused or lost: torque
#: saturation is in the table (peak torque at the effort limit).
EXPECTED_EVENTS = {'saturation'}


def suite_warnings(c: SuiteClient) -> list[str]:
    """One line per kind of problem the suite's nodes reported on /diagnostics during the
    run (late, refused, re-sent, dropped ...), with how often and the last message."""
    seen: dict[tuple[str, str], list] = {}
    for e in c.events:
        if e.level >= 1 and e.kind not in EXPECTED_EVENTS:
            entry = seen.setdefault((e.node, e.kind), [0, ''])
            entry[0] += 1
            entry[1] = e.message
    lines = []
    for (node, kind), (reports, message) in seen.items():
        total = max(c.count(node, kind), reports)  # occurrences (some reported late or held)
        lines.append(f'{node} reported {kind} {total} time(s); last: {message}')
    return lines


def timing_line(mode: str, values: dict[str, str]) -> str:
    """What the simulator's counters say about pacing: for real_time, the real-time factor
    achieved while running and how often (and how long) time waited for the controller."""
    if mode != 'real_time':
        return (f'timing: lockstep, as fast as the loop runs '
                f"({values.get('control_periods', '?')} control periods)")
    factor = values.get('paced_real_time_factor', '?')
    waits = values.get('real_time_waits', '?')
    waited = values.get('real_time_waited_wall', '?')
    slips = values.get('real_time_slips', '?')
    return (f'timing: real_time achieved {factor}x real time while running; simulated time '
            f'waited for the controller {waits} time(s), {waited} s in all, and restarted '
            f'its pacing {slips} time(s) after falling behind; the results are those of '
            'lockstep')


def default_domain() -> int:
    """$ROS_DOMAIN_ID, else a domain no other arm_sim process here holds (claimed)."""
    env = os.environ.get('ROS_DOMAIN_ID')
    if env:
        return int(env)
    from arm_common.process import claim_domain

    return claim_domain(120 + os.getpid() % 100)


def summary_table(results: list[TaskResult], segments: list[dict],
                  effort_limits: list[float]) -> str:
    """One row per task: the lecture's questions (how much torque, how much deviation, how
    long to settle, does it stay) answered from the analysed bag segments."""
    head = ('task', 'motion s', 'peak |tau| N m', 'line dev. mm', 'past end mm', 'settle s',
            'tip err mm')
    rows = []
    if len(results) != len(segments):
        rows.append((f'(the bag has {len(segments)} segments for {len(results)} tasks: '
                     'rows may not match)', *[''] * (len(head) - 1)))
    for res, seg in zip(results, segments):
        peak = seg.get('torque_peak') or [float('nan')] * 2
        dev = seg.get('deviation_max')
        past = seg.get('line_overshoot_end')
        settle = seg.get('settling_time_overall')
        rows.append((res.task.label, f'{res.motion:.2f}',
                     ' / '.join(f'{p:.1f}' for p in peak),
                     '-' if dev is None else f'{dev * 1e3:.2f}',
                     '-' if past is None else f'{past * 1e3:.2f}',
                     '-' if settle is None else f'{settle:.2f}',
                     f'{res.tip_error * 1e3:.2f}'))
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    fmt = '  '.join(f'{{:{"<" if i == 0 else ">"}{w}}}' for i, w in enumerate(widths))
    lines = [fmt.format(*head), '  '.join('-' * w for w in widths)]
    lines += [fmt.format(*r) for r in rows]
    lines.append(f'(effort limits {effort_limits[0]:g} / {effort_limits[1]:g} N m; line '
                 'dev. = largest distance of the tip from the commanded segment; past end = '
                 'how far the tip went beyond its end, along the line)')
    return '\n'.join(lines)
