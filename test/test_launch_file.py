"""launch/arm.launch.py, checked without ROS's launch packages (PyPI has none): it compiles,
declares its arguments, and, run against stand-ins for ``launch`` / ``launch_ros`` that
record what they are given, starts robot_state_publisher with the generated URDF and RViz
with the shipped config only when asked to, and hands a non-empty ``timing_mode`` to the
simulator as a rule that beats params_file (test_launch_timing.py runs it for real)."""

from __future__ import annotations

import ast
import importlib.util
import re
import sys
import types
from pathlib import Path

import pytest

from arm_sim.urdf_cli import urdf_for_params_file

ROOT = Path(__file__).resolve().parents[1]
LAUNCH_FILE = ROOT / 'launch' / 'arm.launch.py'
CONFIG = ROOT / 'config' / 'arm.yaml'


class Recorded:
    """Any launch class: keeps its arguments."""

    def __init__(self, *args, **kwargs) -> None:
        self.args, self.kwargs = args, kwargs


class LaunchConfiguration(Recorded):
    def perform(self, context: dict) -> str:
        return context[self.args[0]]


class PackageNotFoundError(KeyError):
    """ament_index_python's, for the stand-in."""


#: Packages the stand-in ament index has (arm_sim's share directory is the repository).
INSTALLED = {'arm_sim', 'robot_state_publisher', 'rviz2'}


def share_directory(package: str) -> str:
    if package not in INSTALLED:
        raise PackageNotFoundError(package)
    return str(ROOT)


def stand_ins() -> dict[str, types.ModuleType]:
    mods = {}
    for name, attrs in {
        'ament_index_python': {}, 'launch': {}, 'launch_ros': {},
        'ament_index_python.packages': {'get_package_share_directory': share_directory,
                                        'PackageNotFoundError': PackageNotFoundError},
        'launch.actions': {'DeclareLaunchArgument': type('DeclareLaunchArgument',
                                                         (Recorded,), {}),
                           'OpaqueFunction': type('OpaqueFunction', (Recorded,), {})},
        'launch.conditions': {'IfCondition': type('IfCondition', (Recorded,), {})},
        'launch.launch_context': {'LaunchContext': dict},
        'launch.launch_description': {'LaunchDescription': type('LaunchDescription',
                                                                (Recorded,), {})},
        'launch.substitutions': {'LaunchConfiguration': LaunchConfiguration},
        'launch_ros.actions': {'Node': type('Node', (Recorded,), {})},
        'launch_ros.parameter_descriptions': {
            'ParameterValue': type('ParameterValue', (Recorded,), {}),
            'Parameter': type('Parameter', (Recorded,), {})},
    }.items():
        mod = types.ModuleType(name)
        mod.__dict__.update(attrs)
        mods[name] = mod
    return mods


def load_launch_module(monkeypatch) -> types.ModuleType:
    """launch/arm.launch.py run against the stand-ins (in ``sys.modules`` while the test
    runs)."""
    for name, mod in stand_ins().items():
        monkeypatch.setitem(sys.modules, name, mod)
    spec = importlib.util.spec_from_file_location('arm_launch', LAUNCH_FILE)
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def launch_module(monkeypatch):
    return load_launch_module(monkeypatch)


def declared(module) -> dict[str, dict]:
    description = module.generate_launch_description()
    return {a.args[0]: a.kwargs for a in description.args[0]
            if type(a).__name__ == 'DeclareLaunchArgument'}


def visualization_nodes(module, **given: str) -> list:
    context = {'rviz': 'false', 'robot_state_publisher': 'false', 'params_file': str(CONFIG),
               **given}
    opaque = [a for a in module.generate_launch_description().args[0]
              if type(a).__name__ == 'OpaqueFunction'
              and a.kwargs['function'].__name__ == '_visualization']
    assert len(opaque) == 1
    return opaque[0].kwargs['function'](context)


def loop_nodes(module, **given: str) -> list:
    """The nodes ``_loop`` starts (the simulator's process first) for launch arguments
    ``given`` (default: two processes, timing_mode empty)."""
    context = {'composed': 'false', 'timing_mode': '', 'params_file': str(CONFIG),
               'record': 'true', **given}
    opaque = [a for a in module.generate_launch_description().args[0]
              if type(a).__name__ == 'OpaqueFunction'
              and a.kwargs['function'].__name__ == '_loop']
    assert len(opaque) == 1
    return opaque[0].kwargs['function'](context)


def test_the_launch_file_compiles_and_names_the_new_arguments():
    source = LAUNCH_FILE.read_text()
    compile(source, str(LAUNCH_FILE), 'exec')
    names = {node.args[0].value for node in ast.walk(ast.parse(source))
             if isinstance(node, ast.Call) and getattr(node.func, 'id', '') ==
             'DeclareLaunchArgument' and isinstance(node.args[0], ast.Constant)}
    assert {'rviz', 'robot_state_publisher', 'namespace', 'params_file', 'record',
            'composed', 'timing_mode', 'use_sim_time', 'bag'} <= names


def test_rviz_and_robot_state_publisher_are_optional_booleans_off_by_default(launch_module):
    args = declared(launch_module)
    for name in ('rviz', 'robot_state_publisher'):
        assert args[name]['default_value'] == 'false'
        assert args[name]['choices'] == ['true', 'false']
        assert args[name]['description']
    assert visualization_nodes(launch_module) == []


def test_robot_state_publisher_gets_the_urdf_of_the_params_file(launch_module):
    (rsp,) = visualization_nodes(launch_module, robot_state_publisher='true')
    assert (rsp.kwargs['package'], rsp.kwargs['executable']) == ('robot_state_publisher',
                                                                 'robot_state_publisher')
    description = rsp.kwargs['parameters'][0]['robot_description']
    assert description.args[0] == urdf_for_params_file(CONFIG)
    assert description.kwargs['value_type'] is str  # never read as YAML by launch_ros
    assert ('/tf', 'tf') in rsp.kwargs['remappings']
    assert ('/clock', 'clock') in rsp.kwargs['remappings']


def test_rviz_starts_with_the_shipped_config_and_the_robot_state_publisher(launch_module):
    rsp, rviz = visualization_nodes(launch_module, rviz='true')
    assert rsp.kwargs['executable'] == 'robot_state_publisher'
    assert (rviz.kwargs['package'], rviz.kwargs['executable']) == ('rviz2', 'rviz2')
    flag, config = rviz.kwargs['arguments']
    assert flag == '-d' and Path(config) == ROOT / 'config' / 'rviz' / 'arm.rviz'
    assert Path(config).is_file()
    assert rviz.kwargs['namespace'] is launch_module.namespace
    assert ('/tf', 'tf') in rviz.kwargs['remappings']


def timing_rules(node) -> list[tuple[str, str]]:
    """The launch_ros ``Parameter`` entries of the node's ``parameters`` (name, value):
    launch_ros gives each to the node as a ``-p name:=value`` rule."""
    return [(p.args[0], p.args[1]) for p in node.kwargs.get('parameters', [])
            if type(p).__name__ == 'Parameter']


def timing_in_dicts(node) -> list:
    """The ``timing_mode`` entries of the node's parameter dicts (launch_ros writes them as
    a params file that a params file's ``/**/simulator`` section may beat)."""
    return [p['timing_mode'] for p in node.kwargs.get('parameters', [])
            if isinstance(p, dict) and 'timing_mode' in p]


@pytest.mark.parametrize('composed', ['true', 'false'])
@pytest.mark.parametrize('mode', ['lockstep', 'real_time', ' lockstep '])
def test_timing_mode_reaches_the_simulator_as_a_node_scoped_rule(launch_module, composed,
                                                                  mode):
    nodes = loop_nodes(launch_module, composed=composed, timing_mode=mode)
    sim = nodes[0]
    assert sim.kwargs['executable'] == ('composed' if composed == 'true' else 'simulator')
    # '-p node:param:=value' (after the params files) beats every params file; a '/**'
    # dict would lose to config/arm.yaml's '/**/simulator' section.
    assert timing_rules(sim) == [('simulator:timing_mode', mode.strip())]
    assert sim.kwargs['parameters'][0] is launch_module.params_file
    cmd = launch_ros_command(sim)
    rule = cmd.index(f'simulator:timing_mode:={mode.strip()}\n...\n')
    assert cmd[rule - 1] == '-p' and rule > cmd.index('--params-file'), cmd
    assert not timing_in_dicts(sim) and not sim.kwargs.get('ros_arguments')
    for other in nodes[1:]:  # the controller of two processes
        assert other.kwargs['executable'] == 'controller'
        assert not timing_rules(other) and not timing_in_dicts(other)
    assert len(nodes) == (1 if composed == 'true' else 2)


@pytest.mark.parametrize('composed', ['true', 'false'])
@pytest.mark.parametrize('mode', ['', '  '])
def test_empty_timing_mode_leaves_params_file_to_decide(launch_module, composed, mode):
    for node in loop_nodes(launch_module, composed=composed, timing_mode=mode):
        assert not timing_rules(node), 'no rule overrides params_file'
        assert not node.kwargs.get('ros_arguments') and not timing_in_dicts(node)
        assert node.kwargs['parameters'][0] is launch_module.params_file


def test_timing_mode_choices_are_the_simulators_modes(launch_module):
    from arm_dynamics.timing import TIMING_MODES

    assert declared(launch_module)['timing_mode']['choices'] == ['', *TIMING_MODES]


def arm_sim_nodes(module, **given: str) -> list:
    """Every arm_sim node the description starts (two processes, recorder and visualizer
    on): ``_loop``'s, the planner, the recorder and the visualizer."""
    context = {'composed': 'false', 'timing_mode': '', 'params_file': str(CONFIG),
               'rviz': 'false', 'robot_state_publisher': 'false', 'visualizer': 'true',
               'record': 'true', **given}
    nodes = []
    for action in module.generate_launch_description().args[0]:
        if type(action).__name__ == 'OpaqueFunction':
            nodes += action.kwargs['function'](context)
        elif type(action).__name__ == 'Node':
            nodes.append(action)
    return [n for n in nodes if n.kwargs['package'] == 'arm_sim']


@pytest.mark.parametrize('composed', ['false', 'true'])
def test_every_arm_sim_node_is_told_the_launch_processs_pid_to_die_with_it(launch_module,
                                                                           composed):
    import os

    from arm_common.process import PARENT_ENV
    nodes = arm_sim_nodes(launch_module, composed=composed)
    assert {n.kwargs['executable'] for n in nodes} >= {'planner', 'recorder', 'visualizer'}
    for node in nodes:
        assert node.kwargs['additional_env'] == {PARENT_ENV: str(os.getpid())}, node.kwargs


@pytest.mark.parametrize('given, missing', [
    ({'robot_state_publisher': 'true'}, 'robot_state_publisher'),
    ({'rviz': 'true'}, 'rviz2'),
])
def test_a_missing_optional_package_is_refused_before_any_node_starts(
        launch_module, monkeypatch, given, missing):
    everything = INSTALLED
    monkeypatch.setattr(sys.modules[__name__], 'INSTALLED', everything - {missing})
    actions = launch_module.generate_launch_description().args[0]
    first = next(a for a in actions if type(a).__name__ != 'DeclareLaunchArgument')
    assert first.kwargs['function'].__name__ == '_optional_packages', 'checked first'
    context = {'rviz': 'false', 'robot_state_publisher': 'false', **given}
    with pytest.raises(RuntimeError, match=f'{missing} not installed .* no node was started'):
        first.kwargs['function'](context)
    monkeypatch.setattr(sys.modules[__name__], 'INSTALLED', everything)
    assert first.kwargs['function'](context) == [], 'installed: nothing refused'


def gate_of(node) -> list | None:
    """The ``wait_for_nodes`` a launched node is given (None: not given)."""
    values = [p['wait_for_nodes'] for p in node.kwargs.get('parameters', [])
              if isinstance(p, dict) and 'wait_for_nodes' in p]
    return values[-1] if values else None


@pytest.mark.parametrize('composed', ['false', 'true'])
def test_a_recorded_launch_holds_the_first_messages_until_the_recorder_matched_them(
        launch_module, composed):
    nodes = arm_sim_nodes(launch_module, composed=composed)
    gated = {n.kwargs['executable'] for n in nodes if gate_of(n) == ['recorder']}
    loop = {'composed'} if composed == 'true' else {'simulator', 'controller'}
    assert gated == loop | {'visualizer'}
    unrecorded = arm_sim_nodes(launch_module, composed=composed, record='false')
    assert all(gate_of(n) is None for n in unrecorded), 'nothing to wait for'


def test_a_recorder_that_leaves_a_stream_out_is_not_waited_for(launch_module, tmp_path):
    import yaml
    params = yaml.safe_load(CONFIG.read_text())
    params['/**/recorder'] = {'ros__parameters': {'topics': ['joint_states', 'clock']}}
    custom = tmp_path / 'arm.yaml'
    custom.write_text(yaml.safe_dump(params))
    nodes = arm_sim_nodes(launch_module, params_file=str(custom))
    gated = {n.kwargs['executable'] for n in nodes if gate_of(n) == ['recorder']}
    assert gated == {'simulator'}, 'the controller and visualizer would wait for nothing'


def launch_ros_command(node) -> list[str]:
    """The command line launch_ros (Jazzy, launch_ros/actions/node.py) runs for the
    recorded Node, in its order: the executable, ``arguments``, ``--ros-args`` +
    ``ros_arguments`` when given (even empty), then the ``--ros-args`` section it always
    opens: the node's name and namespace, each entry of ``parameters`` (a params file or
    a dict: ``--params-file``; a ``Parameter``: ``-p name:=<yaml.dump(value)>``), the
    remappings. Substitutions are shown as their names (``<params_file>``)."""
    import yaml

    kw = node.kwargs

    def text(v) -> str:
        return f'<{v.args[0]}>' if isinstance(v, LaunchConfiguration) else str(v)

    cmd = [kw['executable'], *(text(a) for a in kw.get('arguments') or [])]
    if kw.get('ros_arguments') is not None:
        cmd += ['--ros-args', *(text(a) for a in kw['ros_arguments'])]
    cmd.append('--ros-args')
    if kw.get('name') is not None:
        cmd += ['-r', f"__node:={kw['name']}"]
    if kw.get('namespace') is not None:
        cmd += ['-r', f"__ns:={text(kw['namespace'])}"]
    for entry in kw.get('parameters') or []:
        if type(entry).__name__ == 'Parameter':
            cmd += ['-p', f'{entry.args[0]}:={yaml.dump(entry.args[1])}']
        else:
            cmd += ['--params-file', text(entry) if not isinstance(entry, dict)
                    else '<launch_params_file>']
    for src, dst in kw.get('remappings') or []:
        cmd += ['-r', f'{src}:={dst}']
    return cmd


def every_node(module, **given: str) -> list:
    """Every Node the description starts for launch arguments ``given`` (all optional
    nodes on: recorder, visualizer, robot_state_publisher and RViz)."""
    context = {'composed': 'false', 'timing_mode': '', 'params_file': str(CONFIG),
               'rviz': 'true', 'robot_state_publisher': 'true', 'visualizer': 'true',
               'record': 'true', **given}
    nodes = []
    for action in module.generate_launch_description().args[0]:
        if type(action).__name__ == 'OpaqueFunction':
            nodes += action.kwargs['function'](context)
        elif type(action).__name__ == 'Node':
            nodes.append(action)
    return nodes


@pytest.mark.parametrize('composed', ['false', 'true'])
@pytest.mark.parametrize('mode', ['', 'lockstep'])
def test_every_node_gets_one_ros_args_section(launch_module, composed, mode):
    """launch_ros opens a ``--ros-args`` section of its own for every Node; ``ros_arguments``
    (even an empty list) opened a second one before it, so the simulator's command line
    read ``simulator --ros-args --ros-args -r __node:=simulator ...``."""
    nodes = every_node(launch_module, composed=composed, timing_mode=mode)
    assert {n.kwargs['executable'] for n in nodes} >= {'planner', 'rviz2'}
    for node in nodes:
        cmd = launch_ros_command(node)
        assert cmd.count('--ros-args') == 1, cmd


def test_the_use_sim_time_argument_names_every_node_it_sets(launch_module):
    """Every node given the ``use_sim_time`` launch argument is named in its description,
    and so is the simulator, which is pinned to the wall clock."""
    description = declared(launch_module)['use_sim_time']['description']
    followers = set()
    for node in every_node(launch_module):
        for entry in node.kwargs.get('parameters') or []:
            value = entry.get('use_sim_time') if isinstance(entry, dict) else None
            if type(value).__name__ == 'ParameterValue' and (
                    value.args[0] is launch_module.use_sim_time):
                followers.add(node.kwargs['executable'])
    assert followers == {'controller', 'planner', 'recorder', 'visualizer',
                         'robot_state_publisher', 'rviz2'}
    for name in sorted(followers) + ['simulator', 'composed']:
        assert re.search(rf'\b{name}\b', description), (name, description)
    (sim, _) = loop_nodes(launch_module)
    assert {'use_sim_time': False} in sim.kwargs['parameters'], 'the clock source'
