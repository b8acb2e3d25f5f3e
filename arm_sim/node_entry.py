"""The node executables' one entry point (setup.py ``console_scripts``: every node is
``<name> = arm_sim.node_entry:main``).

:func:`main` starts the node the executable is named after (``sys.argv[0]``, e.g.
``.venv/bin/controller`` or colcon's ``lib/arm_sim/controller``): it imports its module
(:data:`arm_sim.launcher.MODULES`) and returns that module's ``main()``. A node module
imports its message packages at the top, so in a Python environment without the built
interface packages (``control_msgs``, ``tf2_msgs``: ``pip install`` does not build them)
it would stop with a ``ModuleNotFoundError`` traceback before its ``main`` runs; here that
is the one line ``<node>: control_msgs is not built into this Python environment (...):
run `arm-sim interfaces` once`` and exit code ``EXIT_ERROR`` (1). Any other missing module
is raised as it is.
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

from arm_common.exits import EXIT_ERROR, EXIT_USAGE
from arm_common.interfaces import missing, missing_interface, not_built
from arm_sim.launcher import MODULES


def start(name: str, args: list[str] | None = None) -> int:
    """Run node executable ``name`` (a key of MODULES); its exit code."""
    try:
        node = importlib.import_module(MODULES[name])
    except ModuleNotFoundError as exc:
        pkg = missing_interface(exc)
        if pkg is None:
            raise
        print(f'{name}: {not_built(missing() or [pkg])}', file=sys.stderr)
        return EXIT_ERROR
    return node.main(args)


def main() -> int:
    """The console script's entry: the node named by the executable's file name."""
    name = Path(sys.argv[0]).name.removesuffix('.exe')
    if name not in MODULES:
        print(f'{name}: not a node executable of arm_sim (known: {", ".join(MODULES)})',
              file=sys.stderr)
        return EXIT_USAGE
    return start(name)
