"""One exit-code table for every command (arm_common/exits.py): its constants are the only
exit codes the sources declare, every command module returns them and no number of its
own, the commands' --help states codes the table gives them, and the README's table is the
table's (the block to paste is printed when it differs). Pure."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from arm_common import exits
from arm_common.exits import EXIT_CODES, exit_codes_markdown

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ('arm_common', 'arm_dynamics', 'arm_control', 'arm_planner', 'arm_bag', 'arm_sim')
#: The modules that run a command and return its exit code (and the function of
#: arm_common/node.py every node's main returns through).
COMMAND_MODULES = ('arm_sim/cli.py', 'arm_bag/cli.py', 'arm_sim/sweep/cli.py',
                   'arm_sim/identify_cli.py', 'arm_sim/urdf_cli.py', 'arm_sim/check/cli.py')
EXIT_NAME = re.compile(r'^EXIT_[A-Z_]+$')
#: Commands that state their exit codes in --help (the parser's path under arm-sim).
HELP_STATES_CODES = (('analyze',), ('bag', 'recover'), ('sweep',), ('identify',), ('check',))


def _sources() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).glob('**/*.py'))


def test_the_table_and_its_constants_agree():
    names = [e.name for e in EXIT_CODES]
    assert len(set(names)) == len(names), names
    declared = {k: v for k, v in vars(exits).items()
                if EXIT_NAME.match(k) and isinstance(v, int)}
    assert declared == {e.name: e.code for e in EXIT_CODES}
    assert all(0 <= e.code <= 255 and e.commands and e.meaning for e in EXIT_CODES)
    assert [e.code for e in EXIT_CODES] == sorted(e.code for e in EXIT_CODES)


def test_no_module_but_the_table_declares_an_exit_code():
    """An ``EXIT_*`` name bound to anything but an import from arm_common.exits, anywhere
    in the packages, is a second table."""
    found = []
    for path in _sources():
        if path == ROOT / 'arm_common' / 'exits.py':
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            targets: list[ast.expr] = []
            if isinstance(node, ast.Assign):
                targets = node.targets
            elif isinstance(node, (ast.AnnAssign, ast.AugAssign)):
                targets = [node.target]
            for t in targets:
                for name in ast.walk(t):
                    if isinstance(name, ast.Name) and EXIT_NAME.match(name.id):
                        found.append(f'{path.relative_to(ROOT)}:{node.lineno}: {name.id}')
            if isinstance(node, ast.ImportFrom):
                for alias in node.names:
                    if (EXIT_NAME.match(alias.asname or alias.name)
                            and node.module not in ('arm_common.exits', 'arm_sim.sweep.cli')):
                        found.append(f'{path.relative_to(ROOT)}:{node.lineno}: '
                                     f'{alias.name} from {node.module}')
    assert not found, 'exit codes declared outside arm_common/exits.py:\n' + '\n'.join(found)


def _literal_codes(tree: ast.AST) -> list[int]:
    """Line numbers of ``return <int>``, ``code = <int>`` and ``SystemExit(<int>)``."""
    lines = []
    for node in ast.walk(tree):
        value = None
        if isinstance(node, ast.Return):
            value = node.value
        elif isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == 'code' for t in node.targets):
            value = node.value
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
              and node.func.id == 'SystemExit' and node.args):
            value = node.args[0]
        if (isinstance(value, ast.Constant) and isinstance(value.value, int)
                and not isinstance(value.value, bool)):
            lines.append(node.lineno)
    return lines


def test_every_command_returns_the_tables_constants_not_numbers():
    found = []
    for rel in COMMAND_MODULES:
        tree = ast.parse((ROOT / rel).read_text())
        found += [f'{rel}:{line}' for line in _literal_codes(tree)]
    node = ast.parse((ROOT / 'arm_common' / 'node.py').read_text())
    run_node = next(f for f in ast.walk(node)
                    if isinstance(f, ast.FunctionDef) and f.name == 'run_node')
    found += [f'arm_common/node.py:{line}' for line in _literal_codes(run_node)]
    assert not found, 'exit codes as bare numbers (use arm_common.exits):\n' + '\n'.join(found)


def _returned_by(code: int, command: str) -> bool:
    for e in EXIT_CODES:
        if e.code != code:
            continue
        if e.commands.startswith('every') or command in e.commands.split(', '):
            return True
    return False


@pytest.mark.parametrize('path', HELP_STATES_CODES, ids=' '.join)
def test_the_codes_a_commands_help_states_are_the_tables_for_it(path):
    from arm_sim.cli import build_parser

    parser = build_parser()
    for word in path:
        sub = next(a for a in parser._actions if a.dest in ('command', 'bag_command'))
        parser = sub.choices[word]
    text = ' '.join(parser.format_help().split())
    m = re.search(r'Exit(?: codes?)?:?(.*?\.)(?: |$)', text)
    assert m, f'{" ".join(path)} --help states no exit codes'
    stated = {int(n) for n in re.findall(r'(?:^|[\s,;])(\d+)(?=[\s:])', ' ' + m.group(1))}
    assert stated, m.group(0)
    command = ' '.join(path)
    wrong = sorted(c for c in stated if not _returned_by(c, command))
    assert not wrong, f'{command} --help states exit codes {wrong} the table does not give it'


def test_the_readmes_exit_code_table_is_the_tables():
    text = (ROOT / 'README.md').read_text()
    marker = '<!-- generated: arm_common.exits.exit_codes_markdown -->\n'
    assert marker in text, 'README.md lacks the generated exit-code table'
    block = text.split(marker, 1)[1].split('<!-- end generated -->', 1)[0]
    assert block == exit_codes_markdown(), (
        f'README.md is out of date; replace the block after {marker.strip()} with:\n'
        f'{exit_codes_markdown()}')
