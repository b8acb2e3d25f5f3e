"""The interface packages arm_sim builds into the Python environment (pure: no rclpy).

No PyPI wheel ships ``control_msgs`` or ``tf2_msgs``: ``arm-sim interfaces`` (or
``./run.sh setup``) builds them into the running interpreter's prefix
(docs/interfaces.md). A node or command that needs them and finds them missing says so in
one line, :func:`not_built`, naming that command, instead of a ``ModuleNotFoundError``
traceback: the node executables through :mod:`arm_sim.node_entry`, ``arm-sim demo`` and
``bringup`` before they start any node (:mod:`arm_sim.interfaces_cli`).
"""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Iterable

#: The packages built from interfaces/ (the only ones no ROS wheel provides).
PACKAGES = ('control_msgs', 'tf2_msgs')
#: The one command that builds them into the running Python environment.
BUILD_COMMAND = 'arm-sim interfaces'


def missing(packages: Iterable[str] = PACKAGES) -> list[str]:
    """The ``packages`` this interpreter cannot import (a bare folder of that name, e.g.
    ``interfaces/control_msgs`` in the current directory, is no package)."""
    importlib.invalidate_caches()
    absent = []
    for pkg in packages:
        try:
            spec = importlib.util.find_spec(pkg)
        except (ImportError, ValueError):
            spec = None
        if spec is None or spec.origin in (None, 'namespace'):
            absent.append(pkg)
    return absent


def not_built(packages: Iterable[str]) -> str:
    """The one line for missing interface ``packages``: which, where, and the command."""
    names = list(packages)
    verb = 'is' if len(names) == 1 else 'are'
    return (f'{" and ".join(names)} {verb} not built into this Python environment '
            f'({sys.prefix}): run `{BUILD_COMMAND}` once')


def missing_interface(exc: BaseException) -> str | None:
    """The interface package a ``ModuleNotFoundError`` is about, or None (another module)."""
    if not isinstance(exc, ModuleNotFoundError):
        return None
    root = (exc.name or '').split('.')[0]
    return root if root in PACKAGES else None
