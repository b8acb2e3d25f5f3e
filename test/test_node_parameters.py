"""Node parameters as ROS tools use them, on real node processes: ``-p`` beats a params file,
bad values are refused at start whatever their source, ``ros2 param dump`` output loads back,
integers given for doubles are doubles, and numeric parameters describe their range."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import (
    DescribeParameters,
    GetParameters,
    ListParameters,
    SetParameters,
)
from rclpy.parameter import parameter_value_to_python

from arm_sim.launcher import NodeProcess, config_file

CONFIG = config_file()

# node: (parameter, a well-formed but refused value, the reason's words)
REFUSED = {
    'simulator': ('timing_mode', 'foo',
                  "timing_mode must be one of real_time, lockstep, wall_clock; got 'foo'"),
    'controller': ('law', 'foo', "law must be one of pd, pd_gravity, computed_torque, pid"),
    'planner': ('max_speed', '0', 'max_speed must be > 0 m/s, got 0.0'),
    'recorder': ('chunk_size', '1', 'chunk_size must be >= 64 bytes, got 1'),
}


def ros_args(*rules: str) -> list[str]:
    return ['--ros-args', *[a for r in rules for a in ('-p', r)]]


def parameters(ros, node: str) -> dict:
    """What ``ros2 param get`` would print for every parameter of ``node``: name ->
    (ParameterType, Python value)."""
    names = sorted(ros.call(ListParameters, f'/{node}/list_parameters',
                            ListParameters.Request()).result.names)
    values = ros.call(GetParameters, f'/{node}/get_parameters',
                      GetParameters.Request(names=names)).values
    return {n: (v.type, parameter_value_to_python(v)) for n, v in zip(names, values)}


def dump(values: dict, node: str) -> str:
    """``ros2 param dump /<node>``: names split at '.' into nested mappings (as ros2param's
    dump verb builds them), byte arrays as lists, then ``yaml.dump``."""
    tree: dict = {}
    for name, (_, value) in values.items():
        *parents, leaf = name.split('.')
        branch = tree
        for key in parents:
            branch = branch.setdefault(key, {})
        branch[leaf] = list(value) if isinstance(value, bytes) else value
    return yaml.dump({f'/{node}': {'ros__parameters': tree}}, default_flow_style=False)


def wait_ready(ros, node: str) -> None:
    ros.wait_for(lambda: f'/{node}' in [f'{ns.rstrip("/")}/{n}' for n, ns in
                                        ros.node.get_node_names_and_namespaces()],
                 timeout=30, what=f'/{node} to start')


@pytest.mark.parametrize('node', REFUSED)
def test_a_bad_dash_p_value_is_refused_at_start_even_with_a_params_file(node, tmp_path):
    name, value, reason = REFUSED[node]
    for args in ([f'{name}:={value}'], [f'{node}:{name}:={value}']):
        proc = NodeProcess(node, params_file=CONFIG, log_path=tmp_path / f'{node}.log',
                           domain_id=0, extra_args=ros_args(*args))
        assert proc.proc.wait(30) == 2, f'{node} started with {args}'
        lines = proc.output().strip().splitlines()
        assert len(lines) == 1 and reason in lines[0] and lines[0].startswith(node), lines


def test_dash_p_beats_the_params_file_and_integers_are_doubles(ros, launch):
    # config/arm.yaml says computed_torque and gains.kp [100.0, 60.0] for /**/controller.
    launch('controller', params_file=CONFIG,
           extra_args=ros_args('law:=pid', 'controller:gains.kp:=[200, 100]',
                               'state_timeout:=2', 'planner:law:=pd'))
    wait_ready(ros, 'controller')
    got = parameters(ros, 'controller')
    assert got['law'] == (ParameterType.PARAMETER_STRING, 'pid')
    assert got['gains.kp'] == (ParameterType.PARAMETER_DOUBLE_ARRAY, [200.0, 100.0])
    assert got['state_timeout'] == (ParameterType.PARAMETER_DOUBLE, 2.0)
    # And at run time, as `ros2 param set /controller gains.kd "[30, 10]"` sends them.
    T = ParameterType
    request = SetParameters.Request(parameters=[
        Parameter(name='gains.kd', value=ParameterValue(type=T.PARAMETER_INTEGER_ARRAY,
                                                         integer_array_value=[30, 10])),
        Parameter(name='state_timeout', value=ParameterValue(type=T.PARAMETER_INTEGER,
                                                              integer_value=3))])
    results = ros.call(SetParameters, '/controller/set_parameters', request).results
    assert [r.successful for r in results] == [True, True], results
    got = parameters(ros, 'controller')
    assert got['gains.kd'] == (T.PARAMETER_DOUBLE_ARRAY, [30.0, 10.0])
    assert got['state_timeout'] == (T.PARAMETER_DOUBLE, 3.0)


def test_numeric_parameters_describe_their_range(ros, launch):
    launch('simulator', params_file=CONFIG)
    wait_ready(ros, 'simulator')
    names = ['publish_rate', 'link_masses', 'model', 'pause_at']
    got = {d.name: d for d in ros.call(DescribeParameters, '/simulator/describe_parameters',
                                       DescribeParameters.Request(names=names)).descriptors}
    rate = got['publish_rate'].floating_point_range[0]
    assert (rate.from_value, rate.to_value) == (0.1, 10000.0)
    masses = got['link_masses'].floating_point_range[0]
    assert (masses.from_value, masses.to_value) == (0.0, 1e4) and got['link_masses'].read_only
    assert not got['model'].floating_point_range and not got['model'].integer_range
    assert '[Hz]' in got['publish_rate'].description


@pytest.mark.parametrize('node', ['simulator', 'controller', 'planner', 'recorder',
                                  'visualizer'])
def test_ros2_param_dump_output_loads_back_unchanged(node, ros, launch, tmp_path):
    bag = tmp_path / 'bag'
    params = {'output': str(bag)} if node == 'recorder' else None
    first = launch(node, params_file=CONFIG, params=params)
    wait_ready(ros, node)
    before = parameters(ros, node)
    dumped = tmp_path / 'dump.yaml'
    dumped.write_text(dump(before, node))
    assert first.stop() == 0
    if node == 'recorder':  # the bag the first run wrote; output must not exist
        import shutil
        shutil.rmtree(bag)
    # A node that stops says so to its peers at once; if that one message is lost, they
    # drop it when its lease runs out (Fast DDS: 20 s, checked with the 3 s announcements):
    # seen once in 10 runs, 30 s was not enough.
    ros.wait_for(lambda: f'/{node}' not in [f'{ns.rstrip("/")}/{n}' for n, ns in
                                            ros.node.get_node_names_and_namespaces()],
                 timeout=60, what=f'the first /{node} to leave the graph')
    launch(node, params_file=Path(dumped))
    wait_ready(ros, node)
    after = parameters(ros, node)
    assert after == before, {k: (before.get(k), after.get(k)) for k in before.keys() | after
                             if before.get(k) != after.get(k)}


CHAIN = ('model:=planar_chain', 'link_lengths:=[1.0, 0.8, 0.6]')


@pytest.mark.parametrize('node', ['simulator', 'controller', 'planner', 'recorder'])
def test_a_per_joint_parameter_of_the_wrong_length_is_refused_naming_it(node, tmp_path):
    proc = NodeProcess(node, params_file=CONFIG, log_path=tmp_path / f'{node}.log',
                       domain_id=0, extra_args=ros_args(*CHAIN, 'joint_damping:=[0.1, 0.2]'))
    assert proc.proc.wait(30) == 2, f'{node} started with 2 damping values for 3 joints'
    lines = proc.output().strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(node), lines
    assert 'joint_damping has 2 values but the robot has 3 joints' in lines[0], lines


def test_per_joint_parameters_not_given_are_declared_sized_for_the_chain(ros, launch):
    """With config/arm.yaml's two-joint lists replaced only where given: a 3-link chain
    whose other lists are not given shows, to ``ros2 param get``, each joint's default."""
    launch('controller', extra_args=ros_args(*CHAIN))
    wait_ready(ros, 'controller')
    got = parameters(ros, 'controller')
    assert got['joint_names'][1] == ['joint1', 'joint2', 'joint3']
    assert got['joint_damping'][1] == [0.0, 0.0, 0.0]
    assert got['effort_limits'][1] == [60.0, 20.0, 20.0]
    assert got['gains.kp'][1] == [100.0, 60.0, 60.0]
    assert got['control_model.link_masses'][1] == []


def node_specs(node: str) -> tuple:
    """The ParamSpecs ``node`` declares (the robot's and its own)."""
    from importlib import import_module

    from arm_dynamics.robot import ROBOT_PARAMS
    module, table = {'simulator': ('arm_dynamics.simulator_node', 'SIM_PARAMS'),
                     'controller': ('arm_control.controller_node', 'CONTROL_PARAMS'),
                     'planner': ('arm_planner.planner_node', 'PLANNER_PARAMS'),
                     'recorder': ('arm_bag.recorder_node', 'RECORDER_PARAMS'),
                     'visualizer': ('arm_sim.visualizer_node', 'VISUALIZER_PARAMS')}[node]
    return ROBOT_PARAMS + getattr(import_module(module), table)


#: The ROS type each ParamSpec kind must describe and hold as.
ROS_TYPE = {'double': ParameterType.PARAMETER_DOUBLE,
            'doubles': ParameterType.PARAMETER_DOUBLE_ARRAY,
            'string': ParameterType.PARAMETER_STRING,
            'strings': ParameterType.PARAMETER_STRING_ARRAY,
            'int': ParameterType.PARAMETER_INTEGER, 'bool': ParameterType.PARAMETER_BOOL}


@pytest.mark.parametrize('node', ['controller', 'simulator', 'planner', 'recorder',
                                  'visualizer'])
def test_every_parameter_describes_and_holds_its_real_type(node, ros, launch, tmp_path):
    """``ros2 param describe`` and ``ros2 param get`` show each parameter's own type: an
    empty list default (the controller's ``control_model.*``) is a double array, not the
    byte array rclpy makes of an untyped ``[]``; the read-only flag survives."""
    params = {'output': str(tmp_path / 'bag')} if node == 'recorder' else None
    launch(node, params_file=CONFIG, params=params)
    wait_ready(ros, node)
    specs = node_specs(node)
    names = [s.name for s in specs]
    described = ros.call(DescribeParameters, f'/{node}/describe_parameters',
                         DescribeParameters.Request(names=names)).descriptors
    held = parameters(ros, node)
    wrong = {s.name: (d.type, held[s.name][0], ROS_TYPE[s.kind])
             for s, d in zip(specs, described)
             if not d.type == held[s.name][0] == ROS_TYPE[s.kind]}
    assert not wrong, f'(described, held, expected) types: {wrong}'
    assert all(d.read_only == s.read_only for s, d in zip(specs, described))
    if node == 'controller':
        assert held['control_model.link_lengths'] == (
            ParameterType.PARAMETER_DOUBLE_ARRAY, []), 'empty: the robot parameter is used'
