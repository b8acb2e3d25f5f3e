"""The exit codes of every arm_sim command and node: the one table of them (pure).

Every ``arm-sim`` sub-command (``arm_sim/cli.py``, ``arm_bag/cli.py``,
``arm_sim/sweep/cli.py``, ``arm_sim/identify_cli.py``, ``arm_sim/urdf_cli.py``,
``arm_sim/check/cli.py``) and every node's ``main`` (``arm_common.node.run_node``) returns
one of the constants below, imported from here; no other module declares an exit code
(``test/test_exit_codes.py`` walks the sources and checks it). :data:`EXIT_CODES` says what
each means and which commands return it; the README's exit-code table is
:func:`exit_codes_markdown` verbatim (the same test compares them and prints the block
to paste when they differ).

A number may stand for different things in different commands (3 is a refused goal for
``goal``, nothing usable in the input for ``analyze`` and ``identify``): the names tell
them apart, and no command returns two names of one number.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ExitCode:
    """One exit code: its constant's ``name``, the ``code`` (0-255), the ``commands`` that
    return it and what it ``meaning``\\ s there."""

    name: str
    code: int
    commands: str
    meaning: str


EXIT_OK = 0
EXIT_ERROR = 1
EXIT_USAGE = 2
EXIT_REFUSED = 3
EXIT_NOTHING = 3
EXIT_TIMEOUT = 4
EXIT_UNREADABLE = 4
EXIT_INTERRUPTED = 130

#: Every exit code, by number (then name).
EXIT_CODES: tuple[ExitCode, ...] = (
    ExitCode('EXIT_OK', EXIT_OK, 'every command and node',
             'done: the demo ran, the goal was reached, every bag analysed, every sweep '
             'scenario ran, every check scenario passed; a node stopped by Ctrl-C or '
             'SIGTERM'),
    ExitCode('EXIT_ERROR', EXIT_ERROR,
             'demo, bringup, goal, sweep, check, interfaces, recorder, every node',
             'failed, the one line on stderr says why: a node of the suite exited or did '
             'not start, an output directory exists, a sweep run or output failed, a check '
             'scenario failed, the recorder could not write its bag, the interface '
             'packages are not built (pip install: run `arm-sim interfaces`) or could not '
             'be built'),
    ExitCode('EXIT_USAGE', EXIT_USAGE, 'every command and node',
             'usage: a bad option, argument, spec, suite or parameters file, an output '
             'path that cannot be used, a ROS domain out of range or held by another run; '
             "a node's refused start-up parameters"),
    ExitCode('EXIT_REFUSED', EXIT_REFUSED, 'goal',
             'the planner or the controller refused the goal'),
    ExitCode('EXIT_NOTHING', EXIT_NOTHING, 'analyze, identify',
             'the input was read but holds nothing to use: a bag without joint states '
             '(--frf: no reference or no broadband excitation), data that cannot identify '
             'the arm'),
    ExitCode('EXIT_TIMEOUT', EXIT_TIMEOUT, 'goal',
             'timed out: the tip did not reach the goal in time'),
    ExitCode('EXIT_UNREADABLE', EXIT_UNREADABLE, 'analyze, bag recover, identify',
             'a path is not a bag, not a regular file, unreadable or damaged; nothing '
             'recoverable; a plot that cannot be written'),
    ExitCode('EXIT_INTERRUPTED', EXIT_INTERRUPTED, 'every arm-sim command',
             'interrupted by Ctrl-C or SIGTERM (a sweep writes the finished rows first)'),
)

#: The codes by constant name.
BY_NAME: dict[str, int] = {e.name: e.code for e in EXIT_CODES}


def exit_codes_markdown() -> str:
    """The docs' table of :data:`EXIT_CODES` (the README holds it verbatim; a test checks)."""
    rows = ['| exit code | name | returned by | meaning |', '|---|---|---|---|']
    rows += [f'| {e.code} | `{e.name}` | {e.commands} | {e.meaning} |' for e in EXIT_CODES]
    return '\n'.join(rows) + '\n'
