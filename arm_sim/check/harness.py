"""Run a check suite around a user's controller: every scenario on a fresh suite.

Each scenario starts its own recorder, visualizer, simulator (lockstep, paused at
``start_hold``, the scenario's start pose, sensors and pushes), planner and reference node
(:mod:`arm_sim.check.reference_node`) on the run's ROS domain, then the user's controller
(``command``; or, without one, waits for a controller started by hand), sends the goals at
exact simulated times, runs to the end, stops everything and grades the bag. A fresh
simulator per scenario is the reset: the plant, the planner and the user's controller all
start from scratch, so a crash, a runaway or a hang in one scenario cannot leak into the
next, and the sensors and pushes (read-only simulator parameters) differ per scenario.

A controller that does not do its job never hangs the check: no command, a command with
NaN or the wrong number of joints, a controller that exits, a runaway (the simulator's
``runaway``/``diverged`` fault on /diagnostics) or a scenario over its wall-clock
``budget`` ends the scenario at once with that reason. At the scenario's end everything
the controller started is stopped, in any session or process group (its keeper,
:mod:`arm_sim.check.keeper`, does it, also when this process is killed), also when the
command itself has exited (a child it left must not answer the next scenario); the
command sees the scenario's name in ``ARM_SIM_CHECK_SCENARIO``. Before the first scenario
the domain is looked at for nodes of another run (:func:`leftover_nodes`; again before
each next one while there are some): one warning line names them, and a publisher of
commands fails the scenario (it would drive the arm).

Built from the demo's pieces (:class:`arm_sim.demo.Demo`: starting the nodes behind the
recorder's gate, the recorder drain, the pause and refusal checks) and
:class:`arm_sim.client.SuiteClient`.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import select
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import yaml

from arm_bag.topics import DEFAULT_TOPICS
from arm_dynamics.simulation import CommandError, validate_command
from arm_sim.check.grade import ScenarioResult, grade
from arm_sim.check.suite import PERIOD, Scenario, Suite
from arm_sim.client import SuiteClient, SuiteError, goal_refusal
from arm_sim.demo import Demo
from arm_sim.launcher import NodeProcess, node_env, remove_stale_shm

REFERENCE_TOPIC = 'check/reference'
REFERENCE_REMAPS = {'__node': 'check_reference',
                    'arm_controller/reference': REFERENCE_TOPIC,
                    'effort_controller/commands': 'check/unused'}
START_WAIT = 60.0  # s (wall): the suite's own nodes to start and match
#: A controller that gives verdicts (arm_sim's own, or yours if it publishes on the topic
#: below) but has none on a goal's trajectory this long (wall) after the reference node
#: took it is sent the very same trajectory again, time still paused, up to VERDICT_SENDS
#: times: the planner stops re-sending once the verdict givers *it* knows have answered,
#: and under load it may not know of a controller the harness already sees.
VERDICT_WAIT = 1.0
VERDICT_SENDS = 3
STATUS_TOPIC = '/arm_controller/trajectory_status'
#: The nodes the harness runs (and its own client's): any other node is the controller's.
SUITE_NODES = frozenset({'simulator', 'planner', 'recorder', 'visualizer', 'check_reference',
                         'arm_sim_cli'})
FAULTS = ('runaway', 'diverged')
#: The scenario's name, in the environment of the controller the harness starts.
SCENARIO_ENV = 'ARM_SIM_CHECK_SCENARIO'


class ScenarioFailed(Exception):
    """The controller failed the scenario before it could be graded; the reason."""


class ControllerProcess:
    """The user's controller: any command, run by a keeper (:mod:`arm_sim.check.keeper`,
    in a session of its own) with the run's ROS domain, localhost-only discovery and the
    scenario's name (``ARM_SIM_CHECK_SCENARIO``) in its environment, its output in
    ``log_path``. Everything the command starts, in any session or process group, stays
    the keeper's descendant and is stopped with it: by :meth:`stop`, and by the keeper
    itself when this process dies (SIGKILL included; the kernel's parent-death signal
    comes when the *thread* that started it ends: start it from the one that outlives
    it). ``proc`` is the command (its pid, also its process group, and exit code),
    ``keeper`` the keeper's process."""

    name = 'your controller'
    #: s (wall) for the keeper to start the command and say so.
    START_WAIT = 30.0
    #: s (wall) the keeper gets beyond a stop's timeout before it is killed itself.
    KEEPER_GRACE = 10.0

    def __init__(self, command: Sequence[str], domain_id: int, log_path: Path,
                 scenario: str = '') -> None:
        self.log_path = log_path
        env = node_env(domain_id)
        env[SCENARIO_ENV] = scenario
        read, write = os.pipe()
        keeper = [sys.executable, '-m', 'arm_sim.check.keeper', '--parent', str(os.getpid()),
                  '--status-fd', str(write), '--lifeline', '--', *command]
        try:
            with open(log_path, 'wb') as out:
                self.keeper = subprocess.Popen(keeper, env=env, stdout=out,
                                               stderr=subprocess.STDOUT,
                                               stdin=subprocess.PIPE, pass_fds=(write,),
                                               start_new_session=True)
        except BaseException:
            os.close(read)
            raise
        finally:
            os.close(write)
        self.proc = KeptCommand(self.keeper, read, self.START_WAIT)
        self.stopped = False

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, timeout: float = 5.0) -> int:
        """Stop the command and everything it started, in any session or process group,
        also when the command itself has exited already (it crashed, or a script started
        its controller in the background and returned: what it left running must not
        answer the next scenario's simulator): SIGINT, then SIGKILL after ``timeout`` s
        (the keeper does it and reaps them). Returns the command's exit code. Once only."""
        if self.stopped:
            return self.proc.wait()
        try:
            assert self.keeper.stdin is not None
            self.keeper.stdin.write(f'stop {timeout:g}\n'.encode())
            self.keeper.stdin.close()  # the lifeline: its end alone says stop
        except OSError:  # the keeper is gone already
            pass
        try:
            self.keeper.wait(timeout + self.KEEPER_GRACE)
        except subprocess.TimeoutExpired:  # never seen: the keeper's own process group
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.keeper.pid, signal.SIGKILL)
            self.keeper.wait()
        code = self.proc.wait()
        self.stopped = True
        return code

    def output(self) -> str:
        return self.log_path.read_text(errors='replace')


class KeptCommand:
    """The command a keeper runs, as far as its status pipe ``fd`` tells (``started
    <pid>``, ``exited <code>``): ``pid`` (its process group too), ``returncode`` (None
    while it runs; ``-N``: killed by signal N), ``poll()`` and ``wait()`` as
    :class:`subprocess.Popen` has them."""

    def __init__(self, keeper: subprocess.Popen, fd: int, start_wait: float) -> None:
        self.keeper = keeper
        self._fd: int | None = fd
        self._buf = b''
        self._pid: int | None = None
        self._start_wait = start_wait
        self.returncode: int | None = None

    @property
    def pid(self) -> int:
        """The command's pid (the keeper's if it could not start it)."""
        end = time.monotonic() + self._start_wait
        while self._pid is None and self._fd is not None and time.monotonic() < end:
            self._read(0.05)
        return self._pid if self._pid is not None else self.keeper.pid

    def _read(self, timeout: float) -> None:
        """Take what the pipe holds, waiting up to ``timeout`` s for something."""
        if self._fd is None:
            return
        ready, _, _ = select.select([self._fd], [], [], timeout)
        if not ready:
            return
        data = os.read(self._fd, 4096)
        if not data:  # the keeper has exited: the pipe says no more
            os.close(self._fd)
            self._fd = None
            if self.returncode is None:  # it died before the command's end: its code
                self.returncode = self.keeper.wait()
            return
        self._buf += data
        while b'\n' in self._buf:
            line, self._buf = self._buf.split(b'\n', 1)
            word, _, value = line.decode(errors='replace').partition(' ')
            if word == 'started':
                self._pid = int(value)
            elif word == 'exited':
                self.returncode = int(value)

    def poll(self) -> int | None:
        if self.returncode is None:
            self._read(0.0)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        end = math.inf if timeout is None else time.monotonic() + timeout
        while self.returncode is None:
            left = end - time.monotonic()
            if left < 0:
                raise subprocess.TimeoutExpired(self.keeper.args, timeout or 0.0)
            self._read(min(left, 1.0))
        return self.returncode


def group_running(pgid: int) -> bool:
    """Whether a process of the process group ``pgid`` still runs (a zombie does not: an
    orphan's is reaped by whoever adopted it, maybe late)."""
    try:
        os.killpg(pgid, 0)
    except (ProcessLookupError, PermissionError):
        return False
    try:
        procs = [p for p in os.listdir('/proc') if p.isdigit()]
    except OSError:  # no /proc: the signal's answer
        return True
    for pid in procs:
        try:
            with open(f'/proc/{pid}/stat') as f:
                fields = f.read().rsplit(')', 1)[1].split()
        except (OSError, IndexError):
            continue
        if fields[2] == str(pgid) and fields[0] != 'Z':  # state, ppid, pgrp
            return True
    return False


#: s (wall) a fresh node listens to the domain before the first scenario for nodes left
#: over from another run: discovery on localhost mostly takes 0.1 s, but when the first
#: exchange is lost (under load) a participant is seen at its next announcement, which
#: Fast DDS sends every 3 s.
LEFTOVER_WINDOW = 4.0
COMMANDS_TOPIC = 'effort_controller/commands'


def leftover_nodes(domain_id: int, controller_started: bool = True,
                   window: float = LEFTOVER_WINDOW) -> dict[str, list[str]]:
    """Nodes already on ROS domain ``domain_id`` that publish ``effort_controller/commands``
    or ``joint_states`` or subscribe ``joint_states``, looked for during ``window`` s (wall)
    before a scenario starts its nodes (:data:`LEFTOVER_WINDOW`): at that moment the check
    runs none, so any is left over from another run (a controller killed with its check
    before keepers existed, one started by hand ...) and would take part in the scenario.
    Keyed by what they do (``'publishing effort_controller/commands'`` ...), node names as
    ``/namespace/name``.
    Without ``controller_started`` (a controller started by hand, which stays across
    scenarios) only ``joint_states`` publishers count."""
    what = [('publishing', COMMANDS_TOPIC), ('publishing', 'joint_states'),
            ('subscribing', 'joint_states')]
    if not controller_started:
        what = what[1:2]
    c = SuiteClient(domain_id)
    try:
        c.spin_for(window)
        own = c.node.get_fully_qualified_name()
        found: dict[str, list[str]] = {}
        for verb, topic in what:
            info = (c.node.get_publishers_info_by_topic if verb == 'publishing' else
                    c.node.get_subscriptions_info_by_topic)(f'/{topic}')
            names = sorted({f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in info}
                           - {own})
            if names:
                found[f'{verb} {topic}'] = names
        return found
    finally:
        c.close()


def leftover_warning(domain_id: int, found: dict[str, list[str]]) -> str:
    """The one line that names the nodes :func:`leftover_nodes` found."""
    listed = '; '.join(f'{", ".join(names)} {what}' for what, names in found.items())
    harm = ("Its commands would drive this check's arm" if f'publishing {COMMANDS_TOPIC}'
            in found else "It would take part in this check's scenarios")
    return (f'warning: ROS domain {domain_id} already has {listed}: left over from another '
            f'run? {harm}; stop it')


def tail(text: str, chars: int = 300) -> str:
    """The end of a log, on one line."""
    return ' | '.join(line.strip() for line in text.strip()[-chars:].splitlines()
                      if line.strip()) or '(no output)'


class ScenarioRun(Demo):
    """One scenario of a suite, in ``out`` (``bag/``, ``logs/``)."""

    def __init__(self, scenario: Scenario, out: Path, domain_id: int,
                 command: Sequence[str] | None, echo: Callable[[str], None] = print) -> None:
        super().__init__(out, domain_id, fast=0.8, slow=3.0, echo=echo)
        self.scenario = scenario
        self.command = list(command) if command else None
        if scenario.start is not None:
            self.q0 = np.array(scenario.start, dtype=float)
        elif scenario.start_tip is not None:
            self.q0 = self.arm.inverse_kinematics(np.array(scenario.start_tip), 'down')
        self.controller: ControllerProcess | None = None
        self.client: SuiteClient | None = None
        self.deadline = math.inf  # wall (monotonic) end of the scenario's budget
        self.waiting_for = 'the suite to start'  # what the current wait waits for
        self.commands = 0
        self.bad_command: str | None = None
        self.t_end = math.nan

    # ------------------------------------------------------------------ evidence
    def _on_command(self, msg) -> None:
        self.commands += 1
        if self.bad_command is not None:
            return
        t = max(self.client.sim_time, 0.0) if self.client else 0.0
        try:
            validate_command(msg.data, len(self.q0))
        except CommandError as exc:  # the simulator's own check: the same words
            self.bad_command = f'at simulated t = {t:.2f} s: {exc}'

    def _watch(self) -> None:
        """The alive check of every wait: a suite node that exited is the harness's
        problem (SuiteError); the controller's failures end the scenario (ScenarioFailed)."""
        Demo._alive(self)
        c = self.client
        assert c is not None
        t = max(c.sim_time, 0.0)
        if self.bad_command:
            raise ScenarioFailed(f'bad command: {self.bad_command}')
        for e in c.events_of('simulator', *FAULTS):
            raise ScenarioFailed(f'unstable: the simulator reports {e.kind} at simulated '
                                 f"t = {float(e.values.get('sim_time', t)):.2f} s and holds "
                                 f'the arm: {e.message}')
        for e in c.events_of('simulator', 'rejected_command'):
            # The simulator's account of the same check: whichever reaches the harness
            # first gives the reason (the command may reach the simulator only).
            reason = e.values.get('refused', e.message)
            raise ScenarioFailed(f"bad command: at simulated t = "
                                 f"{float(e.values.get('sim_time', t)):.2f} s: {reason}")
        if self.controller is not None and not self.controller.alive():
            raise ScenarioFailed(f'the controller exited with code '
                                 f'{self.controller.proc.returncode} at simulated t = '
                                 f'{t:.2f} s; its last output: '
                                 f'{tail(self.controller.output())}')
        if time.monotonic() > self.deadline:
            budget = self.scenario.budget
            if not self.commands and t < PERIOD / 2:  # time never left the start
                raise ScenarioFailed(f'no commands on effort_controller/commands within the '
                                     f'wall-clock budget of {budget:g} s (simulated time '
                                     f'stood at t = {t:.2f} s)')
            goal = '' if math.isnan(self.t_end) else f' of {self.t_end:.2f} s'
            raise ScenarioFailed(f'too slow: simulated time reached t = {t:.2f} s{goal} '
                                 f'within the wall-clock budget of {budget:g} s '
                                 f'({self.commands} commands received; waiting for '
                                 f'{self.waiting_for})')

    def _wait(self, condition: Callable[[], object], what: str) -> None:
        assert self.client is not None
        self.waiting_for = what
        timeout = START_WAIT if math.isinf(self.deadline) else \
            max(self.deadline - time.monotonic(), 0.0) + 5.0
        self.client.spin_until(condition, timeout, what, self._watch)

    # ------------------------------------------------------------------ running
    def run(self) -> ScenarioResult:  # type: ignore[override]
        sc = self.scenario
        result = ScenarioResult(sc.name, sc.description)
        started = time.monotonic()
        (self.out / 'logs').mkdir(parents=True, exist_ok=True)
        bag = self.out / 'bag'
        sim = {'timing_mode': 'lockstep', 'pause_at': sc.start_hold,
               'initial_positions': [float(v) for v in self.q0],
               'initial_velocities': [0.0] * len(self.q0), **sc.simulator}
        if sc.disturbances:
            file = self.out / 'disturbances.yaml'
            file.write_text(yaml.safe_dump(sc.disturbances, sort_keys=False))
            sim['disturbance_file'] = str(file.resolve())
        self._start('recorder', output=str(bag))
        self._start('visualizer')
        # The first state waits until the recorder, the planner and the reference node
        # have matched joint_states: a node matched later may get no state while time
        # stands paused (the reference node then refuses the trajectory, as it cannot
        # know where the motion starts).
        self._start('simulator', wait_for_nodes=['recorder', 'planner', 'check_reference'],
                    **sim)
        # The planner starts in _drive, once the controller under test is up.
        self.procs.append(NodeProcess(
            'check_reference', params_file=self.params_files,
            node_params={'check_reference': {'use_sim_time': True}},
            remaps=REFERENCE_REMAPS, domain_id=self.domain,
            log_path=self.out / 'logs' / 'check_reference.log'))
        from std_msgs.msg import Float64MultiArray

        c = self.client = SuiteClient(self.domain)
        c.follow_reference(REFERENCE_TOPIC)
        c.node.create_subscription(Float64MultiArray, 'effort_controller/commands',
                                   self._on_command, 1000)
        from trajectory_msgs.msg import JointTrajectory

        self.traj_pub = c.node.create_publisher(JointTrajectory,
                                                'arm_controller/joint_trajectory', 10)
        codes: dict[str, int] = {}
        try:
            try:
                self._drive(c)
            except ScenarioFailed as exc:
                result.reason = str(exc)
            except SuiteError as exc:
                result.reason = f'the harness: {exc} (logs: {self.out / "logs"})'
            result.sim_time = max(c.sim_time, 0.0)
            self._stop_controller()
            codes.update({p.name: p.stop(signal.SIGINT) for p in self.procs
                          if p.name != 'recorder'})
            self._drain_recorder(c, topics=('joint_states',))
        finally:
            c.close()
            self._stop_controller()
            codes.update({p.name: p.stop(signal.SIGINT) for p in self.procs
                          if p.name not in codes})
        bad = {n: code for n, code in codes.items() if code not in (0, -signal.SIGINT)}
        if bad:
            self.warnings.append(f'nodes did not stop cleanly: {bad} (logs: '
                                 f'{self.out / "logs"})')
        result.warnings = self.warnings
        self._grade(result, bag)
        result.wall = time.monotonic() - started
        return result

    def _stop_controller(self) -> None:
        if self.controller is not None:
            self.controller.stop()

    def _grade(self, result: ScenarioResult, bag: Path) -> None:
        from arm_bag.analysis import NothingToAnalyse, analyze
        from arm_bag.plot import plot_report
        from arm_bag.reader import BagError

        try:
            report = analyze(bag)
        except (NothingToAnalyse, BagError, OSError) as exc:
            if result.reason is None:
                result.reason = f'the harness: the bag cannot be analysed: {exc}'
            return
        result.bag = str(bag)
        if result.reason is None:
            result.metrics = grade(report, self.scenario, self.arm)
        try:
            result.picture = str(plot_report(report, self.out / 'report.png'))
        except Exception as exc:  # a picture is a bonus: never fail the grade for it
            self.warnings.append(f'no picture: {exc}')

    def _start_controller(self, c: SuiteClient) -> None:
        if self.command:
            self.controller = ControllerProcess(self.command, self.domain,
                                                self.out / 'logs' / 'your_controller.log',
                                                self.scenario.name)
        else:
            def publisher() -> bool:
                return bool(c.node.get_publishers_info_by_topic('/effort_controller/commands'))

            if not publisher():
                self.echo(f'    waiting for your controller on ROS domain {self.domain} '
                          '(ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST): it subscribes '
                          f'joint_states and {REFERENCE_TOPIC} or '
                          'arm_controller/joint_trajectory, publishes '
                          'effort_controller/commands (Ctrl-C stops)')
                c.spin_until(publisher, math.inf, 'your controller', Demo._alive.__get__(self))

    def _drive(self, c: SuiteClient) -> None:
        sc = self.scenario
        needed = [('recorder', t) for t in DEFAULT_TOPICS] + [
            ('planner', 'joint_states'), ('planner', 'goal_pose'),
            ('visualizer', 'joint_states'), ('check_reference', 'joint_states'),
            ('check_reference', 'arm_controller/joint_trajectory')]
        # The controller starts with the suite: the simulator holds t = 0 until the
        # recorder has matched it, and lockstep makes the run independent of who came first.
        self._start_controller(c)
        # Trajectories go out once the reference node (it grades them) and every node of
        # the controller under test that takes them on the topic have matched them: a
        # volatile trajectory published before a subscription is matched never reaches it,
        # and a controller that gives no verdicts cannot say it missed one.
        takers = self._trajectory_takers(c)
        # ... and the recorder: the bag must hold the trajectory (it marks the segments);
        # the planner now starts after the recorder's start-up window.
        self._start('planner', wait_for_nodes=['recorder', 'check_reference', *takers])
        for node, topic in needed:
            self._wait(functools.partial(c.subscribed, topic, node),
                       f'the {node} to subscribe {topic}')
        self._wait(lambda: self._recorded(c, 'joint_states'),
                   'the recorder to record the first joint state')
        # The budget runs from here: the suite is up, its first state out.
        self.deadline = time.monotonic() + sc.budget
        t_next = sc.start_hold
        self._run_to_time(c, t_next)
        for k, goal in enumerate(sc.goals, 1):
            at = goal.at if goal.at is not None else t_next
            self._run_to_time(c, at)
            c.set_params('planner', mode=goal.mode, duration=goal.duration,
                         time_scaling='quintic')
            n_traj, n_events = len(c.trajectories), len(c.events)
            n_status = len(c.trajectory_statuses)
            accepted = len(c.events_of('check_reference', 'trajectory_accepted'))
            c.publish_goal(*goal.tip)

            def refusal(n: int = n_events, s: int = n_status) -> str | None:
                return goal_refusal(c.events[n:], c.trajectory_statuses[s:])

            self._wait(lambda: len(c.trajectories) > n_traj or refusal(),  # noqa: B023
                       f'the plan of goal {k}')
            if refusal():
                raise ScenarioFailed(f'goal {k} {list(goal.tip)} m refused: {refusal()}')
            self._wait(lambda: len(c.events_of('check_reference', 'trajectory_accepted'))
                       > accepted, f'the trajectory of goal {k} to be accepted')  # noqa: B023
            self._every_verdict(c, c.trajectories[-1], k)
            self._reach_silent_takers(c, c.trajectories[-1], k)
            end = c.trajectories[-1].points[-1].time_from_start
            duration = end.sec + end.nanosec * 1e-9
            t_next = round((at + duration + sc.settle) / PERIOD) * PERIOD
            self.t_end = t_next
            self.echo(f'    t = {at:5.2f} s  goal {k}: {goal.mode} to '
                      f'({goal.tip[0]:g}, {goal.tip[1]:g}) m, {duration:.2f} s of motion')
        self._run_to_time(c, t_next)

    def _trajectory_takers(self, c: SuiteClient) -> list[str]:
        """The nodes of the controller under test that subscribe
        ``arm_controller/joint_trajectory`` (as ``/namespace/name``), read from the graph
        once it lists a node of the controller subscribing ``joint_states`` (every
        controller does, and creates its subscriptions before it can get a state)."""
        def others(topic: str) -> set[str]:
            return {f"{i.node_namespace.rstrip('/')}/{i.node_name}"
                    for i in c.node.get_subscriptions_info_by_topic(f'{c.ns}/{topic}')
                    if i.node_name not in SUITE_NODES}

        try:
            self._wait(lambda: others('joint_states'),
                       'your controller to subscribe joint_states')
        except SuiteError:
            raise ScenarioFailed(f'no node of your controller subscribed joint_states within '
                                 f'{START_WAIT:g} s (wall) of its start (ROS domain '
                                 f'{self.domain}, localhost discovery)') from None
        return sorted(others('arm_controller/joint_trajectory'))

    def _every_verdict(self, c: SuiteClient, msg, k: int) -> None:
        """Every node publishing trajectory_status (but the reference node, already
        waited for) has a verdict on the trajectory ``msg`` of goal ``k``: one without is
        sent ``msg`` again (see :data:`VERDICT_WAIT`); after :data:`VERDICT_SENDS` sends
        the scenario goes on with a warning (a controller may publish statuses of its own
        kind). Time stands paused at the goal meanwhile, so nothing of the run changes."""
        stamp = str(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)

        def missing() -> list[str]:
            givers = {f"{i.node_namespace.rstrip('/')}/{i.node_name}"
                      for i in c.node.get_publishers_info_by_topic(STATUS_TOPIC)}
            said = {s.name for s in c.trajectory_statuses
                    if any(kv.key == 'stamp_ns' and kv.value == stamp for kv in s.values)}
            return sorted(givers - said - {'/check_reference'})

        for _ in range(VERDICT_SENDS):
            end = time.monotonic() + VERDICT_WAIT
            self._wait(lambda: not missing() or time.monotonic() > end,  # noqa: B023
                       f'the verdicts on the trajectory of goal {k}')
            if not missing():
                return
            listed = len(c.node.get_subscriptions_info_by_topic(self.traj_pub.topic_name))
            self._wait(lambda: self.traj_pub.get_subscription_count() >= listed,  # noqa: B023
                       'the controllers to match the trajectory sent again')
            self.echo(f'    goal {k}: no verdict from {", ".join(missing())} in '
                      f'{VERDICT_WAIT:g} s: its trajectory sent again (time stands paused)')
            self.traj_pub.publish(msg)
        end = time.monotonic() + VERDICT_WAIT
        self._wait(lambda: not missing() or time.monotonic() > end,
                   f'the verdicts on the trajectory of goal {k}')
        if missing():
            self.warnings.append(f'no verdict from {", ".join(missing())} on the trajectory '
                                 f'of goal {k} in {VERDICT_SENDS + 1} sends')

    def _reach_silent_takers(self, c: SuiteClient, msg, k: int) -> None:
        """A node of the controller under test that takes trajectories on the topic but
        gives no verdicts cannot say it missed one (its subscription matched the planner
        too late): once the harness's own publisher has matched every subscription its
        graph lists, it sends ``msg`` once more, time standing paused at the goal, so each
        of them has it at least once (the same trajectory again changes nothing for a
        controller that had it: same stamp, same held state). Sent for every goal when
        there are such nodes, so every run's bag is alike."""
        def silent() -> list[str]:
            givers = {i.node_name for i in c.node.get_publishers_info_by_topic(STATUS_TOPIC)}
            return sorted({i.node_name for i in c.node.get_subscriptions_info_by_topic(
                self.traj_pub.topic_name)} - givers - SUITE_NODES)

        if not silent():
            return
        listed = len(c.node.get_subscriptions_info_by_topic(self.traj_pub.topic_name))
        self._wait(lambda: self.traj_pub.get_subscription_count() >= listed,
                   f'the trajectory of goal {k} to reach {", ".join(silent())}')
        self.traj_pub.publish(msg)

    def _run_to_time(self, c: SuiteClient, t: float) -> None:
        """Let simulated time run to ``t`` (the simulator pauses there) and wait for it."""
        if c.sim_time >= t - 1e-9 or self._paused_at(c, t):
            return
        c.set_params('simulator', pause_at=t)
        self._wait(lambda: c.sim_time >= t - 1e-9 or self._paused_at(c, t),
                   f'simulated time {t:.2f} s')


def run_suite(suite: Suite, out: Path, domain_id: int, command: Sequence[str] | None,
              echo: Callable[[str], None] = print) -> list[ScenarioResult]:
    """Run every scenario of ``suite`` (each in ``out/<name>/``); progress to ``echo``."""
    results = []
    n = len(suite.scenarios)
    found: dict[str, list[str]] = {}
    for k, sc in enumerate(suite.scenarios, 1):
        echo(f'[{k}/{n}] {sc.name}: {sc.description}' if sc.description else
             f'[{k}/{n}] {sc.name}')
        # Fast DDS files of processes a scenario had to kill would be found by the next
        # scenario's on the same domain (stale ports leave a new participant deaf).
        removed = remove_stale_shm()
        if removed:
            echo(f'    removed {len(removed)} stale Fast DDS shared-memory file(s)')
        # Nodes of another run on this domain would drive or disturb the scenarios: looked
        # for before the first, and before each next one while there are some (within a
        # check, what a scenario started is gone when it ends: ControllerProcess).
        if k == 1 or found:
            found = leftover_nodes(domain_id, controller_started=command is not None)
            if found:
                echo(f'    {leftover_warning(domain_id, found)}')
        if command and f'publishing {COMMANDS_TOPIC}' in found:
            res = ScenarioResult(sc.name, sc.description, reason=(
                f"ROS domain {domain_id} already has "
                f"{', '.join(found[f'publishing {COMMANDS_TOPIC}'])} publishing "
                f"{COMMANDS_TOPIC} (left over from another run?): its commands would "
                f"drive this check's arm; stop it"))
        else:
            res = ScenarioRun(sc, out / sc.name, domain_id, command, echo).run()
        verdict = 'pass' if res.passed else 'FAIL: ' + '; '.join(res.failures())
        echo(f'    {verdict}  ({res.wall:.1f} s wall, {res.sim_time:.2f} s simulated)')
        for w in res.warnings:
            echo(f'    warning: {w}')
        results.append(res)
    return results
