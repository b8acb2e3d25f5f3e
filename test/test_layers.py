"""The packages form layers: every import runs down (or within a package), none up, and no
module imports itself back through others. Walks every ``import`` of the installed
packages' sources with ``ast``, function-level imports included."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Bottom to top: a package may import only itself and the packages before it.
LAYERS = ('arm_common',    # ROS-glue base: parameter specs, node helpers, diagnostics
          'arm_dynamics',  # the model, integration, timing, joint limits (+ simulator node)
          'arm_control',   # laws, trajectories, controller core (+ controller node)
          'arm_planner',   # kinematics use, time scaling, plans (+ planner node)
          'arm_bag',       # MCAP writing/reading, metrics, analysis (+ recorder node)
          'arm_sim')       # user-facing: CLI, demo, launcher, client, composed executable


def imports_of(source: str, module: str) -> set[str]:
    """The arm_sim modules ``source`` (the text of ``module``) imports, as dotted names."""
    found: set[str] = set()
    package = module.rsplit('.', 1)[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:  # relative: resolve against this module's package
                parts = package.split('.')[:len(package.split('.')) - node.level + 1]
                base = '.'.join(parts + ([base] if base else []))
            names = [base] + [f'{base}.{a.name}' for a in node.names]
        else:
            continue
        found.update(n for n in names if n.split('.')[0] in LAYERS)
    return found


def module_graph() -> dict[str, set[str]]:
    modules = {}
    for pkg in LAYERS:
        for path in sorted((ROOT / pkg).glob('**/*.py')):
            rel = path.relative_to(ROOT).with_suffix('')
            parts = rel.parts[:-1] if rel.name == '__init__' else rel.parts
            modules['.'.join(parts)] = path
    graph = {}
    for name, path in modules.items():
        # ``from pkg import name`` may name a submodule or an attribute: keep what exists.
        graph[name] = {m for m in imports_of(path.read_text(), name)
                       if m in modules and m != name}
    return graph


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    rank = {pkg: i for i, pkg in enumerate(LAYERS)}
    return sorted(f'{a} -> {b}' for a, deps in graph.items() for b in deps
                  if rank[b.split('.')[0]] > rank[a.split('.')[0]])


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Module import cycles (strongly connected components of more than one module),
    ignoring a package ``__init__`` re-exporting its own submodules."""
    def edges(a):
        return {b for b in graph[a]
                if not (b.startswith(a + '.') or a.startswith(b + '.'))}

    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in edges(v):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return found


def test_every_package_is_in_a_layer():
    packages = {p.parent.name for p in ROOT.glob('*/__init__.py')}
    assert packages - {'test', 'bench'} == set(LAYERS)


def test_no_import_runs_up_the_layers():
    graph = module_graph()
    assert 'arm_common.params' in graph['arm_dynamics.robot'], 'the walk sees imports'
    assert upward_imports(graph) == []


def test_no_circular_imports():
    assert cycles(module_graph()) == []


def test_the_import_walk_sees_function_level_and_relative_imports():
    source = ('import numpy\n'
              'def f():\n'
              '    from arm_sim.cli import main\n'
              'from . import core\n')
    found = imports_of(source, 'arm_control.laws')
    assert {'arm_sim.cli', 'arm_sim.cli.main', 'arm_control.core'} <= found
    graph = {'arm_control.laws': {'arm_sim.cli'}, 'arm_sim.cli': {'arm_control.laws'}}
    assert upward_imports(graph) == ['arm_control.laws -> arm_sim.cli']
    assert cycles(graph) == [['arm_control.laws', 'arm_sim.cli']]

