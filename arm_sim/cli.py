"""``arm-sim``: the terminal front end of arm_sim (works in a plain venv, no ros2 CLI).

Sub-commands: ``demo``, ``bringup``, ``goal``, ``analyze``, ``bag``, ``sweep``, ``identify``,
``urdf``, ``check``. Errors are one line on stderr and a non-zero exit code, never a traceback.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from pathlib import Path

import numpy as np

from arm_common.exits import (
    EXIT_ERROR,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_REFUSED,
    EXIT_TIMEOUT,
    EXIT_USAGE,
)
from arm_dynamics.timing import TIMING_MODES


class CliError(Exception):
    """A user-facing failure: printed as one line, exit code ``code``."""

    def __init__(self, message: str, code: int = EXIT_ERROR) -> None:
        super().__init__(message)
        self.code = code


#: ROS domain ids Fast DDS can map to ports (0..232, as ROS 2 documents).
DOMAIN_RANGE = (0, 232)


def _domain(args: argparse.Namespace, claim: bool = False) -> int:
    """The ROS domain of the command: ``--domain-id``, else $ROS_DOMAIN_ID, else (demo,
    bringup) a free one, claimed. With ``claim`` (a run that starts nodes: demo, bringup)
    an explicit domain is claimed too, and refused (exit 2) if another arm_sim run holds
    it: two suites on one domain see each other's nodes."""
    from arm_sim.demo import default_domain
    from arm_sim.launcher import DomainInUse, claim_explicit_domain

    explicit = args.domain_id is not None or bool(os.environ.get('ROS_DOMAIN_ID'))
    try:
        domain = args.domain_id if args.domain_id is not None else default_domain()
    except ValueError:
        raise CliError(f"ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID')!r} is not a number",
                       EXIT_USAGE) from None
    lo, hi = DOMAIN_RANGE
    if not lo <= domain <= hi:
        raise CliError(f'--domain-id {domain} is out of range: ROS domain ids are {lo}..{hi} '
                       '(the DDS port of a higher one does not exist)', EXIT_USAGE)
    if claim and explicit:
        try:
            claim_explicit_domain(domain)
        except DomainInUse as exc:
            raise CliError(str(exc), EXIT_USAGE) from None
    return domain


def _live_view_available(args: argparse.Namespace) -> None:
    """``--foxglove`` without foxglove-sdk: refused before anything starts (one line)."""
    import importlib.util

    from arm_sim.live import FOXGLOVE_MISSING

    wanted = getattr(args, 'foxglove', None) is not None
    if wanted and importlib.util.find_spec('foxglove') is None:
        raise CliError(f'--foxglove: {FOXGLOVE_MISSING}')


def _clean_shared_memory() -> None:
    """Remove the Fast DDS shared-memory files of processes that are gone (a suite killed
    with SIGKILL leaves its own), before this run adds its own."""
    from arm_sim.launcher import remove_stale_shm

    removed = remove_stale_shm()
    if removed:
        print(f'removed {len(removed)} stale Fast DDS shared-memory file(s) of processes '
              'that are gone')


def cmd_demo(args: argparse.Namespace) -> int:
    """The lecture's tasks, recorded, analysed and drawn."""
    from arm_bag.analysis import analyze
    from arm_bag.plot import plot_report
    from arm_sim.client import SuiteError
    from arm_sim.demo import Demo, summary_table, timing_line

    _live_view_available(args)
    domain = _domain(args, claim=True)
    out = Path(args.out) if args.out else Path('runs') / time.strftime('demo-%Y%m%d-%H%M%S')
    if out.exists():
        raise CliError(f'{out} exists; choose another --out')
    started = time.monotonic()
    print(f'arm-sim demo: regulation and straight-line tracking on the simulated 2-R arm'
          f"{' with config/real_arm.yaml (motors, friction, sensors)' if args.real_arm else ''}"
          f' (output in {out}/)')
    _clean_shared_memory()
    demo = Demo(out, domain, fast=args.fast, slow=args.slow, foxglove=args.foxglove,
                timing_mode=args.timing_mode, real_arm=args.real_arm,
                foxglove_host=args.foxglove_host)
    try:
        bag = demo.run()
    except SuiteError as exc:
        raise CliError(str(exc)) from None
    report = analyze(bag)
    for warning in report.warnings:
        if 'before the first trajectory not analysed' in warning:
            continue  # the demo's own hold at the start, by design
        print(f'warning: {warning}')
    doc = report.to_dict()
    print('\nthe lecture\'s questions, answered (full metrics: arm-sim analyze):')
    print(summary_table(demo.results, doc['segments'], doc['effort_limits']))
    picture = plot_report(report, out / 'report.png')
    print(timing_line(args.timing_mode, demo.timing))
    print(f'\ndone in {time.monotonic() - started:.0f} s.')
    print(f'  bag:     {bag}/  (rosbag2, MCAP: {next(bag.glob("*.mcap")).name})')
    print(f'  picture: {picture}')
    print(f'  table again: arm-sim analyze {bag} [--plot FILE.png] [--json]')
    print('  Foxglove: Open local file -> the .mcap, import config/foxglove/arm_layout.json; '
          'PlotJuggler: Load data -> the .mcap, load config/plotjuggler/arm_layout.xml (or '
          'plot /joint_states/joint1/position against '
          f'/arm_controller/reference/joint1/position); ROS 2: ros2 bag info {bag}')
    return EXIT_OK


def cmd_bringup(args: argparse.Namespace) -> int:
    """Start the suite and keep it running until Ctrl-C."""
    from arm_bag.recorder_node import FIRST_MESSAGE
    from arm_planner.planner_node import FIRST_STATE
    from arm_sim.launcher import NodeProcess, config_file, recorder_gates

    _live_view_available(args)
    domain = _domain(args, claim=True)
    params_file = Path(args.params_file) if args.params_file else config_file()
    if not params_file.is_file():
        raise CliError(f'--params-file {params_file}: no such file')
    _clean_shared_memory()
    out = Path(args.out) if args.out else Path('runs') / time.strftime('bringup-%Y%m%d-%H%M%S')
    (out / 'logs').mkdir(parents=True, exist_ok=True)
    ns = '/' + args.namespace.strip('/') if args.namespace.strip('/') else ''  # absolute
    loop = ['composed'] if args.composed else ['simulator', 'controller']
    # The visualizer publishes markers and robot_description (recorded too).
    nodes = loop + ['planner'] + (['recorder'] if args.record else []) + ['visualizer']
    overrides = {'simulator': {'simulator': {'timing_mode': args.timing_mode}},
                 'recorder': {'recorder': {'output': str(out / 'bag')}}}
    # Composed: the controller answers the first state in the same process at once, so the
    # simulation starts paused at t = 0 and runs once the others have its first state.
    overrides['composed'] = {'simulator': {'timing_mode': args.timing_mode, 'pause_at': 0.0}}
    if args.record and not args.composed:
        # The simulator, controller and visualizer send nothing before the recorder has
        # matched them, so the bag holds their first messages. (Composed starts before
        # the recorder: what it sends then is not the recording's.)
        for name, sections in recorder_gates(params_file).items():
            for node, values in sections.items():
                overrides.setdefault(name, {}).setdefault(node, {}).update(values)
    if args.foxglove is not None:  # the Foxglove bridge first: it sees the suite from the start
        nodes.insert(0, 'live')
        overrides['live'] = {'live': {'port': args.foxglove, 'host': args.foxglove_host}}
    procs: list = []

    def start(name: str) -> None:
        # Each node resolves /clock in its own namespace (arm_common.node).
        procs.append(NodeProcess(name, params_file=params_file,
                                 node_params=overrides.get(name),
                                 namespace=ns or None, domain_id=domain,
                                 log_path=out / 'logs' / f'{name}.log'))

    try:
        # Recorder first, then the simulator, and the rest only once the recorder has the
        # first state: the simulator repeats it until the first command comes, so the bag
        # holds every state from the first on. With two processes the controller (which
        # starts the loop) comes last, once the planner has that state too: a planner that
        # joined later, while the simulation stood paused or held, would have none.
        # Composed, the controller answers at once: that process comes first, paused at
        # t = 0 (what it sends before the recorder starts is not the recording's), and runs
        # once the recorder and the planner have its first state.
        if 'live' in nodes:  # the Foxglove bridge first: it sees the suite from the start
            start('live')
        if args.composed:  # paused at t = 0 until the others have that state (below)
            start('composed')
            # Both nodes made: the controller's first line ('[controller]: ', or
            # '[ns.controller]: ' in a namespace).
            _wait_log(procs[-1], 'controller]: ')
        if args.record:
            start('recorder')
            _wait_log(procs[-1], 'recording to')
        if not args.composed:
            start('simulator')
        if args.record and loop[0] == 'simulator':
            recorder = next(p for p in procs if p.name == 'recorder')
            _wait_log(recorder, f'{FIRST_MESSAGE} {ns or ""}/joint_states'.replace('//', '/'))
        for name in nodes:
            if name not in ('live', 'recorder', 'controller', loop[0]):
                start(name)
        if 'controller' in nodes:
            planner = next(p for p in procs if p.name == 'planner')
            _wait_log(planner, FIRST_STATE)
            start('controller')
        else:  # composed, paused at t = 0: run once the recorder and planner have t = 0
            _start_composed_loop(procs, domain, ns)
        live = [p for p in procs if p.name == 'live']
        if live:
            _wait_log(live[0], 'serving ws://')
    except BaseException:  # a refusal, or Ctrl-C while starting: stop what runs
        for p in procs:
            p.stop(signal.SIGINT)
        raise
    shown = ['simulator + controller (one process)' if n == 'composed' else n for n in nodes]
    print(f'arm-sim bringup: {", ".join(shown)} running on ROS domain {domain} '
          f'(namespace {ns or "/"}, simulator {args.timing_mode}); logs in {out}/logs')
    print(f'  send goals from another terminal: ROS_DOMAIN_ID={domain} arm-sim goal X Y '
          f'[--mode straight_line]{" --namespace " + ns if ns else ""}')
    if args.foxglove is not None:
        print(f'  Foxglove: open connection -> {_served_url(procs)} (localhost), then import '
              'the layout config/foxglove/arm_layout.json')
    print('  stop with Ctrl-C', flush=True)
    try:
        _supervise(procs)
    except KeyboardInterrupt:
        print('\nstopping ...')
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C must not cut cleanup
        # The recorder last, so it has every message the others sent.
        order = sorted(procs, key=lambda p: p.name == 'recorder')
        codes = {p.name: p.stop(signal.SIGINT) for p in order}
        codes = {n: codes[n] for n in nodes if n in codes}
    print('stopped: ' + ', '.join(f'{n} ({c})' for n, c in codes.items()))
    for p in procs:  # how simulated time was paced (the simulator logs it at shutdown)
        for line in p.output().splitlines():
            if 'timing: ' in line:
                print(line[line.index('timing: '):])
    if args.record:
        print(f'bag: {out / "bag"}  (arm-sim analyze {out / "bag"})')
    return EXIT_OK


#: Nodes whose exit leaves the suite running (reported): the live view is an extra.
OPTIONAL_NODES = ('live',)


def _supervise(procs: list) -> None:
    """Watch the node processes until one of the suite's exits (CliError naming it and
    its log); an optional one (the live view) that exits is reported and the rest goes on.
    Returns only by KeyboardInterrupt (Ctrl-C, SIGTERM)."""
    watched = list(procs)
    while True:
        for p in [p for p in watched if not p.alive()]:
            if p.name not in OPTIONAL_NODES:
                raise CliError(f'{p.name} exited with code {p.proc.returncode}; see '
                               f'{p.log_path}')
            watched.remove(p)
            print(f'arm-sim bringup: warning: {p.name} exited with code {p.proc.returncode} '
                  f'(see {p.log_path}); the suite goes on without the live view',
                  file=sys.stderr, flush=True)
        time.sleep(0.2)  # supervising child processes: nothing to spin


def _start_composed_loop(procs: list, domain: int, ns: str, timeout: float = 30.0) -> None:
    """Let the composed simulator, paused at t = 0, run once the recorder (if any) and the
    planner have its first state: DDS delivers a state only to subscriptions already
    matched, and the controller in the same process answers it at once, so a simulation
    that ran from the start would integrate ahead of a recorder still being matched (its
    bag then began seconds in). The paused simulator publishes its first state once; it is
    published again (the ``reset`` service: the initial state at t = 0, time unchanged)
    until both logged it, then ``pause_at`` is cleared."""
    from arm_bag.recorder_node import FIRST_MESSAGE
    from arm_planner.planner_node import FIRST_STATE
    from arm_sim.client import SuiteClient, SuiteError

    wanted = {'planner': FIRST_STATE,
              'recorder': f'{FIRST_MESSAGE} {ns or ""}/joint_states'.replace('//', '/')}
    waiting = [(p, wanted[p.name]) for p in procs if p.name in wanted]

    def alive() -> None:
        for p in procs:
            if not p.alive():
                raise CliError(f'{p.name} exited with code {p.proc.returncode}; see '
                               f'{p.log_path}')

    def received() -> bool:
        return all(text in p.output() for p, text in waiting)

    client = SuiteClient(domain, ns)
    try:
        end = time.monotonic() + timeout
        while not received():
            left = end - time.monotonic()
            if left <= 0:
                missing = [p.name for p, text in waiting if text not in p.output()]
                raise CliError(f"{', '.join(missing)} did not receive the simulator's first "
                               f'state within {timeout:g} s; see {procs[0].log_path.parent}')
            client.call_trigger('simulator', 'reset', timeout=left, alive=alive)
            client.spin_for(0.3, received)  # the logs tell: nothing else to wait on
        client.set_params('simulator', pause_at=-1.0)
    except SuiteError as exc:
        raise CliError(f'{exc}; see {procs[0].log_path.parent}') from None
    finally:
        client.close()


def _served_url(procs: list) -> str:
    """The ``ws://HOST:PORT`` the ``live`` node logged it serves (its actual port)."""
    import re

    for p in procs:
        if p.name == 'live':
            found = re.search(r'serving (ws://\S+)', p.output())
            if found:
                return found.group(1).replace('127.0.0.1', 'localhost')
    return 'ws://localhost'


def _wait_log(proc, text: str, timeout: float = 30.0) -> None:
    """Wait until ``proc``'s log has a line containing ``text`` (evidence, not a delay)."""
    end = time.monotonic() + timeout
    while text not in proc.output():
        if not proc.alive():
            raise CliError(f'{proc.name} exited with code {proc.proc.returncode}; see '
                           f'{proc.log_path}')
        if time.monotonic() > end:
            raise CliError(f'{proc.name} did not log {text!r} within {timeout:g} s; see '
                           f'{proc.log_path}')
        time.sleep(0.05)  # polling a log file: no ROS client in this process


def cmd_goal(args: argparse.Namespace) -> int:
    """Send one goal to a running suite and report what became of it."""
    from arm_sim.client import SuiteClient, SuiteError, goal_refusal, stamp_of
    from arm_sim.demo import start_pose
    from arm_sim.launcher import config_file

    if not (np.isfinite(args.x) and np.isfinite(args.y)):
        raise CliError(f'goal must be finite, got ({args.x}, {args.y})')
    for option in ('timeout', 'tolerance'):
        value = getattr(args, option)
        if not (np.isfinite(value) and value > 0):
            raise CliError(f'--{option} must be a positive number, got {value:g}', EXIT_USAGE)
    domain = _domain(args)
    client = SuiteClient(domain, args.namespace)
    try:
        try:
            client.spin_until(lambda: client.states, args.timeout,
                              f'joint_states on ROS domain {domain} (is the suite running? '
                              'arm-sim bringup)')
            params = {}
            if args.mode:
                params['mode'] = args.mode
            if args.duration is not None:
                params['duration'] = args.duration
            if params:
                client.set_params('planner', **params)
            client.spin_until(lambda: client.subscribed('goal_pose', 'planner'), args.timeout,
                              'the planner to subscribe goal_pose')
        except SuiteError as exc:
            raise CliError(str(exc), EXIT_TIMEOUT) from None
        n_traj, n_events = len(client.trajectories), len(client.events)
        n_status = len(client.trajectory_statuses)
        client.publish_goal(args.x, args.y, args.frame)

        def refusal() -> str | None:
            """Why the goal will not be executed: the planner refused it or could not send
            it, the controller refused its trajectory for good (not a stale one the planner
            plans again), or a time jump interrupted it."""
            return goal_refusal(client.events[n_events:],
                                client.trajectory_statuses[n_status:])

        try:
            client.spin_until(lambda: len(client.trajectories) > n_traj or refusal(),
                              args.timeout, 'the planner to answer')
        except SuiteError as exc:
            raise CliError(str(exc), EXIT_TIMEOUT) from None
        if refusal():
            raise CliError(f'refused: {refusal()}', EXIT_REFUSED)
        traj = client.trajectories[-1]
        end = traj.points[-1].time_from_start
        duration = end.sec + end.nanosec * 1e-9
        print(f'planned: {len(traj.points)} point(s), {duration:.2f} s of motion')
        arm, _ = start_pose(config_file())  # link lengths as config/arm.yaml gives them
        goal = np.array([args.x, args.y])
        t0 = stamp_of(traj) or client.sim_time  # the motion starts at its stamp

        def reached():
            if refusal():
                return True
            state = client.states[-1]
            tip = arm.forward_kinematics(np.array(state.position))
            return (client.sim_time >= t0 + duration
                    and np.hypot(*(tip - goal)) < args.tolerance
                    and np.abs(state.velocity).max() < 1e-2)

        try:
            client.spin_until(reached, args.timeout + duration, 'the arm to reach the goal')
            if refusal():
                raise CliError(f'refused: {refusal()}', EXIT_REFUSED)
        except SuiteError:
            tip = arm.forward_kinematics(np.array(client.states[-1].position))
            raise CliError(f'timed out: the tip is at ({tip[0]:.4f}, {tip[1]:.4f}) m, '
                           f'{np.hypot(*(tip - goal)) * 1e3:.1f} mm from the goal',
                           EXIT_TIMEOUT) from None
        tip = arm.forward_kinematics(np.array(client.states[-1].position))
        print(f'reached: tip at ({tip[0]:.4f}, {tip[1]:.4f}) m, '
              f'{np.hypot(*(tip - goal)) * 1e3:.2f} mm from the goal, at simulated t = '
              f'{client.sim_time:.2f} s')
        return EXIT_OK
    finally:
        client.close()


def build_parser() -> argparse.ArgumentParser:
    from arm_planner.planner import MODES as PLANNER_MODES

    parser = argparse.ArgumentParser(
        prog='arm-sim', description='arm_sim: a simulated 2-R robot arm on ROS 2 Jazzy. '
        'Runs the nodes as processes; no ros2 command line needed.')
    sub = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')

    def foxglove_arg(p):
        from arm_sim.live import DEFAULT_PORT

        p.add_argument('--foxglove', type=int, nargs='?', const=DEFAULT_PORT, default=None,
                       metavar='PORT',
                       help='also serve the topics to Foxglove over WebSocket on '
                       f'ws://localhost:PORT (default {DEFAULT_PORT}; 0 = a free port): '
                       "the live node (setup.py extra 'foxglove'); it refuses bad stamps, "
                       'frame ids and numbers with a reason and keeps serving, and if it '
                       'exits the run goes on without it (reported)')
        p.add_argument('--foxglove-host', default='127.0.0.1', metavar='ADDR',
                       help='address the live view listens on (default 127.0.0.1: this '
                       'machine only; 0.0.0.0: every interface). Clients may offer '
                       'foxglove.sdk.v1 or foxglove.websocket.v1')

    def domain_arg(p):
        p.add_argument('--domain-id', type=int, default=None,
                       help='ROS_DOMAIN_ID (default: $ROS_DOMAIN_ID, else a free one no '
                       'other arm_sim run holds); an explicit domain another arm_sim run '
                       'holds is refused (exit 2)')

    demo = sub.add_parser(
        'demo', help='run the lecture tasks, record them and print the analysis',
        description='Start simulator (lockstep, or real_time with --timing-mode), '
        'controller, planner, recorder and visualizer (markers, robot_description); move the '
        'tip from Ps to Pf (regulation), then along the straight line Pf -> Ps slowly and '
        'fast under computed torque, and fast under plain PD. Prints how much torque, how '
        'much deviation and how long to settle, and writes a report picture. Both timing '
        'modes record the same joint states, bit for bit. The run holds its ROS domain '
        '(another arm_sim run on it is refused, exit 2) and first removes the Fast DDS '
        'shared-memory files of processes that are gone (a killed run leaves them). With '
        '--foxglove, a live view that exits is reported and the demo goes on.')
    demo.add_argument('--out', default=None,
                      help='output directory (default runs/demo-<time>)')
    demo.add_argument('--fast', type=float, default=0.8,
                      help='duration of the fast straight line [s] (default 0.8)')
    foxglove_arg(demo)
    demo.add_argument('--slow', type=float, default=3.0,
                      help='duration of the slow straight line [s] (default 3)')
    demo.add_argument('--timing-mode', default='lockstep', choices=('lockstep', 'real_time'),
                      help='simulator timing: lockstep (default: as fast as the closed loop '
                      'runs) or real_time (the same lockstep at wall-clock pace, to watch it; '
                      'a slow machine lowers the real-time factor, never the results)')
    demo.add_argument('--real-arm', action='store_true',
                      help='the arm of config/real_arm.yaml: geared motors, stick/slip '
                      'friction and noisy, quantised, delayed sensors on both joints (the '
                      'same seed, the same run); compare its table with the ideal arm\'s')
    domain_arg(demo)
    demo.set_defaults(func=cmd_demo)

    bring = sub.add_parser(
        'bringup', help='start the suite and keep it running (Ctrl-C stops it)',
        description='Start simulator, controller, planner, visualizer (markers and '
        'robot_description) and recorder with config/arm.yaml and wait; drive it with '
        'arm-sim goal. The run holds its ROS domain (another arm_sim run on it is refused, '
        'exit 2) and first removes the Fast DDS shared-memory files of processes that are '
        'gone. The recorder holds every state from t = 0 (--composed too: its simulation '
        'starts once the recorder and planner have the first state). A node of the suite '
        'that exits stops the suite (exit 1, naming its log); the live view (--foxglove) '
        'that exits is reported and the suite goes on.')
    bring.add_argument('--timing-mode', default='real_time', choices=TIMING_MODES,
                       help='simulator timing: real_time (default: lockstep at wall-clock '
                       'pace, for watching and driving by hand), lockstep (as fast as the '
                       'closed loop runs) or wall_clock (opt-in: periods integrated on the '
                       "wall clock's schedule with the command held then; results depend on "
                       'the machine). real_time and lockstep give the same results')
    bring.add_argument('--composed', action='store_true',
                       help='run simulator and controller in one process with one executor '
                       '(the composed executable): the loop never leaves the process, which '
                       'holds real time at 1 kHz control (see bench/bench_loop.py); it starts '
                       'paused at t = 0 and runs once the recorder and the planner have that '
                       'state')
    bring.add_argument('--namespace', default='', help='namespace for all nodes and topics')
    bring.add_argument('--no-record', dest='record', action='store_false',
                       help='do not start the recorder')
    foxglove_arg(bring)
    bring.add_argument('--out', default=None,
                       help='output directory (default runs/bringup-<time>)')
    bring.add_argument('--params-file', default=None, metavar='FILE',
                       help='ROS params file for every node (default: the shipped '
                       'config/arm.yaml); --timing-mode still decides the simulator\'s mode')
    domain_arg(bring)
    bring.set_defaults(func=cmd_bringup)

    goal = sub.add_parser(
        'goal', help='send an end-effector goal to a running suite and wait for the outcome',
        description='Publish goal_pose (x, y in the base frame) and report: reached (exit 0), '
        'refused with the reason (exit 3) or timed out (exit 4).')
    goal.add_argument('x', type=float, help='goal x [m]')
    goal.add_argument('y', type=float, help='goal y [m]')
    goal.add_argument('--mode', choices=PLANNER_MODES, default=None,
                      help="set the planner's mode first (default: keep it); chirp: a small "
                      'sine sweep about the goal, for arm-sim analyze --frf (docs/frf.md)')
    goal.add_argument('--duration', type=float, default=None,
                      help='set the motion duration [s] first (0 = from speed limits)')
    goal.add_argument('--frame', default='base_link', help='goal frame_id (default base_link)')
    goal.add_argument('--namespace', default='', help="the suite's namespace")
    goal.add_argument('--tolerance', type=float, default=1e-3,
                      help='tip distance counting as reached [m], > 0 (default 0.001)')
    goal.add_argument('--timeout', type=float, default=20.0,
                      help='wall-clock seconds to wait beyond the motion, > 0 (default 20)')
    goal.add_argument('--domain-id', type=int, default=None,
                      help='ROS_DOMAIN_ID of the suite (default: $ROS_DOMAIN_ID or 0)')
    goal.set_defaults(func=cmd_goal)

    from arm_bag.cli import add_analyze_parser, add_bag_parser

    add_analyze_parser(sub)
    add_bag_parser(sub)
    from arm_sim.identify_cli import add_identify_parser
    from arm_sim.sweep import add_sweep_parser

    add_sweep_parser(sub)
    add_identify_parser(sub)
    from arm_sim.urdf_cli import add_urdf_parser

    add_urdf_parser(sub)
    from arm_sim.interfaces_cli import add_interfaces_parser

    add_interfaces_parser(sub)  # after demo and bringup: it adds their pre-flight check
    from arm_sim.check.cli import PARSER, add_check_arguments

    add_check_arguments(sub.add_parser('check', **PARSER)).set_defaults(func=cmd_check)
    return parser


def cmd_check(args: argparse.Namespace) -> int:
    """Grade a controller over its topics (arm_sim/check, docs/check.md)."""
    from arm_sim.check.cli import CheckUsageError, run_check

    try:
        return run_check(args, lambda: _domain(args, claim=True), _clean_shared_memory)
    except CheckUsageError as exc:
        raise CliError(str(exc), EXIT_USAGE) from None


def _interrupt(*_) -> None:
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    # Ctrl-C and SIGTERM both stop cleanly (the node processes are stopped, not orphaned),
    # also when started from a script that ignores SIGINT for background jobs.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _interrupt)
    if args.command == 'goal' and args.domain_id is None:
        args.domain_id = int(os.environ.get('ROS_DOMAIN_ID', '0'))
    try:
        return args.func(args)
    except CliError as exc:
        print(f'arm-sim {args.command}: {exc}', file=sys.stderr)
        return exc.code
    except KeyboardInterrupt:
        print(f'arm-sim {args.command}: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == '__main__':
    raise SystemExit(main())
