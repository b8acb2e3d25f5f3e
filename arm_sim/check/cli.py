"""``arm-sim check``: grade a controller over its topics (docs/check.md)."""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from arm_common.exits import EXIT_ERROR, EXIT_OK

DESCRIPTION = """\
Grade any controller over its ROS topics. For each scenario of the suite, start the
simulator (lockstep), planner, recorder, visualizer and the harness's reference stream on a
private ROS domain (localhost-only discovery), start your controller with CMD in that
environment (ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST,
ARM_SIM_CHECK_SCENARIO=<scenario>), send the goals at exact simulated times, stop
everything and grade the recorded run: final tip error [mm], line deviation [mm],
settling time [s], peak torque [N m], saturation [%], push response.
Each scenario runs on fresh nodes, your controller restarted too. Without "-- CMD" it
waits for a controller you start by hand (it prints the domain and the topics; it must
then handle simulated time starting again at 0 for each scenario).

Your controller: subscribe joint_states (sensor_msgs/JointState), publish
effort_controller/commands (std_msgs/Float64MultiArray, N m, in joint_states.name order)
once per joint state; take the reference from check/reference (sensor_msgs/JointState
stamped like the state: position, velocity, effort = q, q', q'' of the reference) or from
arm_controller/joint_trajectory (trajectory_msgs/JointTrajectory). See docs/check.md.

A controller that sends nothing, NaN or the wrong number of values, exits, runs away or
exceeds the scenario's wall-clock budget fails that scenario with the reason; the next
one still runs. Exit 0: every scenario passed; 1: one failed; 2: usage error (bad
option, bad suite file: one line naming the entry and value).
"""

EPILOG = """\
examples:
  arm-sim check -- python3 my_controller.py
  arm-sim check --junit results.xml -- ros2 run my_pkg my_controller
  arm-sim check --suite my_suite.yaml --scenario line_fast -- ./build/controller
  arm-sim check                      # then start your controller by hand
"""


HELP = "grade your controller (any language) on the lecture's scenarios, over its topics"
PARSER: dict[str, Any] = {'help': HELP, 'description': DESCRIPTION, 'epilog': EPILOG,
          'formatter_class': argparse.RawDescriptionHelpFormatter}


class CheckUsageError(Exception):
    """A usage error (exit 2): the message is one line naming the bad value."""


def add_check_arguments(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The options of ``arm-sim check`` (``p = sub.add_parser('check', **PARSER)``)."""
    p.add_argument('--suite', default=None, metavar='FILE',
                   help='suite YAML (default: the shipped config/checks/lecture.yaml)')
    p.add_argument('--scenario', action='append', default=[], metavar='NAME',
                   help='run only this scenario (repeatable)')
    p.add_argument('--junit', default=None, metavar='FILE',
                   help='write JUnit XML: one testcase per scenario')
    p.add_argument('--report', default=None, metavar='DIR',
                   help='report directory: per scenario bag/, report.png, logs/; '
                   'summary.md, results.json (default runs/check-<time>)')
    p.add_argument('--budget', type=float, default=None, metavar='S',
                   help="wall-clock budget per scenario [s], > 0 (default: the suite's, "
                   '60 s in the lecture suite)')
    p.add_argument('--list', action='store_true',
                   help="list the suite's scenarios and thresholds, run nothing")
    p.add_argument('--domain-id', type=int, default=None,
                   help='ROS_DOMAIN_ID (default: $ROS_DOMAIN_ID, else a free one no other '
                   'arm_sim run holds); an explicit domain another arm_sim run holds is '
                   'refused (exit 2)')
    p.add_argument('cmd', nargs=argparse.REMAINDER, metavar='-- CMD [ARGS...]',
                   help='your controller: any command (a ros2 run, a Python file, a binary)')
    return p


def run_check(args: argparse.Namespace, domain_of: Callable[[], int],
              clean: Callable[[], None]) -> int:
    """Run the check ``args`` ask for; ``domain_of()`` claims the ROS domain (after the
    usage checks), ``clean()`` removes stale Fast DDS files. CheckUsageError: exit 2."""
    from dataclasses import replace

    from arm_sim.check.suite import SuiteFileError, load_suite

    command = list(args.cmd)
    if command and command[0] == '--':
        command = command[1:]
    elif command:
        raise CheckUsageError(f'unexpected argument {command[0]!r}: put your controller '
                              'after "--" (arm-sim check -- CMD ...)')
    try:
        suite = load_suite(args.suite)
        if args.scenario:
            suite = suite.select(args.scenario)
    except SuiteFileError as exc:
        raise CheckUsageError(str(exc)) from None
    for note in suite.notes:  # e.g. an old metric name: read, said once
        print(f'warning: {note}', file=sys.stderr)
    if args.budget is not None:
        if not args.budget > 0 or args.budget == float('inf'):
            raise CheckUsageError(f'--budget must be a positive number of seconds, got '
                                  f'{args.budget:g}')
        suite = replace(suite, scenarios=tuple(replace(s, budget=args.budget)
                                               for s in suite.scenarios))
    if args.list:
        for s in suite.scenarios:
            limits = ', '.join(f'{k} <= {v}' for k, v in s.thresholds.items())
            print(f'{s.name}: {s.description} [{limits}]')
        return EXIT_OK
    if command:
        import shutil

        if shutil.which(command[0]) is None:
            raise CheckUsageError(f'{command[0]}: command not found')
    report = Path(args.report) if args.report else \
        Path('runs') / time.strftime('check-%Y%m%d-%H%M%S')
    if report.exists() and any(report.iterdir()):
        raise CheckUsageError(f'--report {report} exists and is not empty; choose another')
    domain = domain_of()
    from arm_sim.check.harness import REFERENCE_TOPIC, run_suite
    from arm_sim.check.output import table, write_report

    started = time.monotonic()
    who = shlex.join(command) if command else 'a controller you start by hand'
    print(f'arm-sim check: {len(suite.scenarios)} scenario(s) of {suite.name} '
          f'({suite.path}) against {who}, on ROS domain {domain} (localhost only); report '
          f'in {report}/')
    if not command:
        print(f'  start your controller with ROS_DOMAIN_ID={domain} '
              'ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST: it subscribes joint_states and '
              f'{REFERENCE_TOPIC} (or arm_controller/joint_trajectory) and publishes '
              'effort_controller/commands')
    clean()
    results = run_suite(suite, report, domain, command or None,
                        echo=lambda s: print(s, flush=True))
    junit_path = Path(args.junit) if args.junit else None
    write_report(results, suite, report, junit_path)
    print()
    print(table(results))
    print(f'\ndone in {time.monotonic() - started:.0f} s. report: {report / "summary.md"}'
          + (f'; JUnit: {junit_path}' if junit_path else ''))
    return EXIT_OK if all(r.passed for r in results) else EXIT_ERROR
