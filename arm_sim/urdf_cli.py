"""``arm-sim urdf``: print the arm's URDF, made from the robot parameters (no rclpy).

The parameters come as the nodes take them: a params file's ``/**`` section (where
config/arm.yaml keeps the robot description; other keys there are ignored), then
``-p name:=value`` rules, which win. The launch file gives robot_state_publisher the same
text through :func:`urdf_for_params_file`. The values are validated by the code every
node's start runs (:func:`arm_dynamics.robot.resolve_robot`, i.e.
:func:`arm_common.params.resolve`): a value a node refuses is refused here in the same
words (``-p joint_names:=[a,a]``), one it takes is taken (``-p link_lengths:=[1,0.8]``).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from arm_common.exits import EXIT_OK, EXIT_USAGE
from arm_common.params import command_line_parameters
from arm_dynamics.robot import ROBOT_PARAMS
from arm_dynamics.urdf import urdf_from_params


def robot_params_from_file(path: str | Path) -> dict[str, Any]:
    """The robot parameters in a ROS 2 params file: its ``/**`` section's
    ``ros__parameters`` whose names are robot parameters.

    Raises
    ------
    ValueError
        The file cannot be read or is not a params file (the path and the reason named).
    """
    try:
        data = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f'params file {str(path)!r}: cannot read: {exc}') from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ValueError(f'params file {str(path)!r} is not a ROS 2 params file (its top '
                         f'level is a {type(data).__name__}, not a mapping)')
    section = data.get('/**') or {}
    params = section.get('ros__parameters') if isinstance(section, dict) else None
    if not isinstance(params, dict):
        return {}
    names = {s.name for s in ROBOT_PARAMS}
    return {k: v for k, v in params.items() if k in names}


def robot_params(params_file: str | Path | None = None,
                 rules: Sequence[str] = ()) -> dict[str, Any]:
    """Robot parameters from ``params_file`` (``/**`` section) and then ``rules``
    (``name:=value``, values read as YAML as ``ros2 run -p`` reads them), the later
    winning.

    Raises
    ------
    ValueError
        A rule without ``:=``, or a bad params file (named).
    """
    params = robot_params_from_file(params_file) if params_file else {}
    argv = ['--ros-args']
    for rule in rules:
        if ':=' not in rule:
            raise ValueError(f'-p {rule!r}: expected name:=value')
        argv += ['-p', rule]
    params.update(command_line_parameters(argv, 'urdf', '/urdf'))
    return params


def urdf_for_params_file(params_file: str | Path | None = None,
                         rules: Sequence[str] = ()) -> str:
    """The URDF of the arm ``params_file`` and ``rules`` describe (see
    :func:`robot_params`); raises ValueError naming a bad parameter or file."""
    return urdf_from_params(robot_params(params_file, rules))


def add_urdf_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``urdf`` sub-command to an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        'urdf', help="print the arm's URDF, made from the robot parameters",
        description="Print the URDF of the simulated arm (base_link, link1, link2, tool0; "
        "the suite's joint names, limits, masses, CG positions and inertias) made from the "
        "robot parameters: the defaults, a params file's /** section, then -p rules. "
        'robot_state_publisher takes it as robot_description.')
    p.add_argument('-p', '--param', dest='params', action='append', default=[],
                   metavar='NAME:=VALUE',
                   help='a robot parameter, as ros2 run takes it (e.g. -p '
                   'link_lengths:=[1.2,0.6]); repeatable, wins over --params-file')
    p.add_argument('--params-file', default=None, metavar='FILE',
                   help='ROS 2 params file whose /** section holds robot parameters (e.g. '
                   'config/arm.yaml)')
    p.add_argument('--output', '-o', default=None, metavar='FILE.urdf',
                   help='write the URDF to FILE instead of stdout')
    p.set_defaults(func=run_urdf)
    return p


def run_urdf(args: argparse.Namespace) -> int:
    """Run ``urdf``; returns the exit code (bad parameters: one line, exit 2)."""
    try:
        text = urdf_for_params_file(args.params_file, args.params)
    except ValueError as exc:
        print(f'arm-sim urdf: {exc}', file=sys.stderr)
        return EXIT_USAGE
    if args.output:
        try:
            Path(args.output).write_text(text)
        except OSError as exc:
            print(f'arm-sim urdf: cannot write {args.output}: {exc}', file=sys.stderr)
            return EXIT_USAGE
    else:
        sys.stdout.write(text)
    return EXIT_OK
