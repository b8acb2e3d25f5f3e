"""``arm-sim interfaces``: build control_msgs and tf2_msgs into this Python environment.

No PyPI wheel ships them. ``./run.sh setup`` builds them into its venv; a ``pip install
'arm_sim[ros,core]'`` does not (pip runs no build step of ours), so after it this command
runs the same build, ``interfaces/build_interfaces.py``, with the running interpreter into
its prefix (``sys.prefix``). The script and the Jazzy definitions are shipped with the
package (setup.py ``data_files``: ``<prefix>/share/arm_sim/interfaces``); from a source
tree they are taken from ``interfaces/``. Once is enough: it is a no-op (about 0.2 s) when
they are up to date or provided by a real ROS 2 install (docs/interfaces.md).

:func:`add_interfaces_parser` also makes ``arm-sim demo`` and ``bringup`` check the
packages before they start anything: one line naming this command, exit 1.
"""

from __future__ import annotations

import argparse
import importlib
import os
import shutil
import subprocess
import sys
import sysconfig
from collections.abc import Callable
from pathlib import Path

from arm_common.exits import EXIT_ERROR, EXIT_OK, EXIT_USAGE
from arm_common.interfaces import PACKAGES, missing, not_built

SCRIPT = 'build_interfaces.py'
#: The rosidl modules the build runs (rosidl_cli drops one that fails to import with a
#: warning, then stops with "No translate extensions found"): checked first.
GENERATOR_MODULES = ('rosidl_adapter.cli', 'rosidl_generator_type_description.cli',
                     'rosidl_generator_c.cli', 'rosidl_generator_py.cli',
                     'rosidl_typesupport_c.cli', 'rosidl_typesupport_fastrtps_c.cli',
                     'rosidl_typesupport_introspection_c.cli')
#: The commands that start nodes needing the packages: checked before they start any.
CHECKED_COMMANDS = ('demo', 'bringup')


def build_script() -> Path | None:
    """``build_interfaces.py`` next to the definitions: the source tree's ``interfaces/``
    (a checkout, an editable install), else the installed copy in ``share/arm_sim``."""
    candidates = [Path(__file__).resolve().parents[1] / 'interfaces' / SCRIPT,
                  Path(sys.prefix) / 'share' / 'arm_sim' / 'interfaces' / SCRIPT]
    candidates += [Path(p) / 'share' / 'arm_sim' / 'interfaces' / SCRIPT
                   for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    return next((c for c in candidates if c.is_file()), None)


def toolchain_problem() -> str | None:
    """What the build lacks (a C or C++ compiler, an importable rosidl generator,
    ``Python.h``), in one line, or None."""
    for var, default, language in (('CC', 'cc', 'C'), ('CXX', 'c++', 'C++')):
        compiler = os.environ.get(var, default)
        if shutil.which(compiler) is None:
            return (f'no {language} compiler {compiler!r} on PATH (install gcc and g++, or '
                    f'set {var})')
    for module in GENERATOR_MODULES:  # their load errors reach the build as "no extensions"
        try:
            importlib.import_module(module)
        except ImportError as exc:
            return (f'the rosidl generator {module} cannot be imported ({exc}): install '
                    f"the missing package, or reinstall arm_sim with the 'ros' extra")
    header = Path(sysconfig.get_paths()['include']) / 'Python.h'
    if not header.is_file():
        version = f'{sys.version_info[0]}.{sys.version_info[1]}'
        return f'no {header}: install the Python development headers (python{version}-dev)'
    return None


def cmd_interfaces(args: argparse.Namespace) -> int:
    """Run the build into ``sys.prefix``; 0 when both packages import afterwards."""
    script = build_script()
    if script is None:
        print(f'arm-sim interfaces: {SCRIPT} and the definitions are not installed (looked in '
              f'{Path(sys.prefix) / "share" / "arm_sim" / "interfaces"}); reinstall arm_sim',
              file=sys.stderr)
        return EXIT_ERROR
    cmd = [sys.executable, str(script), '--prefix', sys.prefix]
    cmd += ['--force'] * args.force
    if args.jobs is not None:
        if args.jobs < 1:
            print(f'arm-sim interfaces: --jobs must be at least 1, got {args.jobs}',
                  file=sys.stderr)
            return EXIT_USAGE
        cmd += ['--jobs', str(args.jobs)]
    if args.check:
        if subprocess.run([*cmd, '--check']).returncode == 0:
            print(f'arm-sim interfaces: {" and ".join(PACKAGES)} are up to date')
            return EXIT_OK
        print('arm-sim interfaces: a build is due: run `arm-sim interfaces`', file=sys.stderr)
        return EXIT_ERROR
    if subprocess.run([*cmd, '--check'], capture_output=True).returncode != 0:
        problem = toolchain_problem()  # only when something is to be built
        if problem:
            print(f'arm-sim interfaces: cannot build: {problem}', file=sys.stderr)
            return EXIT_ERROR
        print(f'arm-sim interfaces: building {" and ".join(PACKAGES)} into {sys.prefix} '
              '(about a minute the first time)', flush=True)
    result = subprocess.run(cmd)
    if result.returncode != 0:
        print(f'arm-sim interfaces: the build failed (exit code {result.returncode}; the lines '
              'above say why)', file=sys.stderr)
        return EXIT_ERROR
    absent = missing()
    if absent:
        print(f'arm-sim interfaces: built, but {" and ".join(absent)} still cannot be '
              f'imported by {sys.executable}', file=sys.stderr)
        return EXIT_ERROR
    print(f'arm-sim interfaces: {" and ".join(PACKAGES)} are ready in {sys.prefix}')
    return EXIT_OK


def checked(func: Callable[[argparse.Namespace], int]
            ) -> Callable[[argparse.Namespace], int]:
    """``func`` (a command that starts nodes) preceded by the interface packages' check:
    missing ones are one line and exit 1, before anything starts."""

    def run(args: argparse.Namespace) -> int:
        absent = missing()
        if absent:
            print(f'arm-sim {args.command}: {not_built(absent)}', file=sys.stderr)
            return EXIT_ERROR
        return func(args)

    run.__doc__ = func.__doc__
    return run


def add_interfaces_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``arm-sim interfaces``, and the pre-flight check to ``demo`` and ``bringup``
    (call it after those are added)."""
    p = sub.add_parser(
        'interfaces', help='build control_msgs and tf2_msgs into this Python environment '
        '(once, after pip install)',
        description='Build the ROS 2 Jazzy interface packages control_msgs and tf2_msgs, '
        'which no PyPI wheel ships, into this Python environment '
        f'({sys.prefix}) with its rosidl generators and the system C/C++ compiler: about a '
        'minute the first time; nothing to do when they are up to date or a real ROS 2 '
        'install provides them. ./run.sh setup runs the same build. Needed once after '
        "pip install 'arm_sim[ros,core]': the demo, bringup and the controller and "
        'visualizer nodes refuse to start without them.')
    p.add_argument('--force', action='store_true', help='rebuild even if up to date')
    p.add_argument('--check', action='store_true',
                   help='only report whether a build is due (exit 1 if so)')
    p.add_argument('--jobs', '-j', type=int, default=None,
                   help='parallel compile jobs (default: the number of CPUs)')
    p.set_defaults(func=cmd_interfaces)
    for name in CHECKED_COMMANDS:
        parser = sub.choices.get(name)
        if parser is not None:
            parser.set_defaults(func=checked(parser.get_default('func')))
