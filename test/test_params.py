"""Parameter specs: command-line rules and the values a node declares (pure, no ROS)."""

from __future__ import annotations

import math

import pytest
import yaml

from arm_common.params import ParamSpec, command_line_parameters

RATE = ParamSpec('publish_rate', 'double', 100.0, 'rate', 'Hz', minimum=0.0, strict_min=True)
GAINS = ParamSpec('gains.kp', 'doubles', [100.0, 50.0], 'gains', 'N m/rad', length=2)
MODEL = ParamSpec('model.link_lengths', 'doubles', [], 'model', 'm')
LAW = ParamSpec('law', 'string', 'pd', 'law', choices=('pd', 'pid'))


def rules(*args: str, node: str = 'controller', fqn: str = '/controller') -> dict:
    return command_line_parameters(list(args), node, fqn)


def test_bare_and_node_prefixed_rules_apply_to_the_named_node_only():
    argv = ['--ros-args', '-p', 'law:=pid', '--param', 'controller:gains.kp:=[1, 2]',
            '-p', 'planner:law:=pd', '-p', '/controller:publish_rate:=5']
    assert rules(*argv) == {'law': 'pid', 'gains.kp': [1, 2], 'publish_rate': 5}
    assert rules(*argv, node='planner', fqn='/planner') == {'law': 'pd'}


def test_the_later_rule_wins_and_only_ros_args_sections_count():
    argv = ['-p', 'law:=ignored', '--ros-args', '-p', 'law:=pd', '--params-file', 'f.yaml',
            '-p', 'law:=pid', '--', '-p', 'law:=after_the_section']
    assert rules(*argv) == {'law': 'pid'}


def test_values_are_read_as_yaml_as_rcl_reads_them():
    got = rules('--ros-args', '-p', 'a:=1e3', '-p', 'b:=true', '-p', 'c:=[0.2, 1e-3]',
                '-p', 'd:="5"', '-p', 'e:=[unclosed', '-p', 'f:=nan', '-p', 'g:=')
    assert got['a'] == 1000.0 and got['b'] is True and got['c'] == [0.2, 0.001]
    assert got['d'] == '5'  # quoted: a string, as rcl reads it
    assert got['e'] == '[unclosed' and math.isnan(got['f']) and got['g'] is None


def test_a_rule_without_assignment_is_left_to_rcl():
    assert rules('--ros-args', '-p', 'law', '-p') == {}


def test_integers_given_for_doubles_are_declared_as_doubles():
    assert RATE.as_declared(5) == 5.0 and isinstance(RATE.as_declared(5), float)
    assert GAINS.as_declared([200, 100]) == [200.0, 100.0]
    assert all(isinstance(v, float) for v in GAINS.as_declared([200, 1.5]))


def test_values_of_the_wrong_type_are_left_for_check_to_refuse():
    assert RATE.as_declared(True) is True
    assert RATE.check(True) == 'publish_rate must be a number, got True'
    assert GAINS.as_declared(['a', 1]) == ['a', 1]
    assert GAINS.check(['a', 1]) == "gains.kp must be a number, got 'a'"
    assert LAW.as_declared(3) == 3 and LAW.check(3) == 'law must be a string, got 3'


def test_an_unset_value_is_the_empty_default_as_an_empty_list_in_a_file_loads():
    assert MODEL.as_declared(None) == [] and MODEL.check([]) is None
    assert GAINS.as_declared(None) is None
    assert GAINS.check(None) == 'gains.kp must be a list, got None'


def test_a_unique_list_refuses_a_repeated_value_and_a_free_string_may_allow_empty():
    names = ParamSpec('joint_names', 'strings', ['a', 'b'], 'names', unique=True)
    assert names.check(['a', 'b']) is None
    assert names.check(['a', 'a']) == "joint_names must not repeat a value, got ('a', 'a')"
    free = ParamSpec('hold_service', 'string', 'x', 'service', allow_empty=True)
    assert free.check('') is None and LAW.check('') is not None


def test_resolve_declares_checks_sizes_then_relates_and_names_every_refusal():
    from arm_common.params import resolve

    def lower_below_upper(v):
        return None if v['lo'] < v['hi'] else f"lo {v['lo']:g} must be below hi {v['hi']:g}"

    specs = (ParamSpec('lo', 'double', 0.0, 'lo'),
             ParamSpec('hi', 'double', 1.0, 'hi', relation=lower_below_upper),
             ParamSpec('gains', 'doubles', [1.0, 2.0], 'g', per_joint=True), RATE)
    got = resolve(specs, {'lo': 0, 'gains': [3, 4.5]}, joints=lambda v: 2)
    assert got == {'lo': 0.0, 'hi': 1.0, 'gains': [3.0, 4.5], 'publish_rate': 100.0}
    assert isinstance(got['lo'], float), 'integers given for doubles are doubles'
    assert resolve(specs, {}, joints=lambda v: 3)['gains'] == [1.0, 2.0, 2.0]
    with pytest.raises(ValueError, match='lo 2 must be below hi 1'):
        resolve(specs, {'lo': 2})
    with pytest.raises(ValueError) as info:  # every value's refusal, before relations
        resolve(specs, {'lo': 'x', 'publish_rate': 0, 'hi': -5.0})
    assert str(info.value) == ("lo must be a number, got 'x'; publish_rate must be > 0 Hz, "
                               'got 0.0')
    with pytest.raises(ValueError, match='gains has 2 values but the robot has 3 joints'):
        resolve(specs, {'gains': [1.0, 2.0]}, joints=lambda v: 3)


def test_rules_and_params_files_rcl_cannot_parse_are_made_so_or_left_to_our_checks():
    from arm_common.params import rcl_params_file, rcl_rule_value

    assert rcl_rule_value('[1,0.8]') == '[1.0, 0.8]'
    assert rcl_rule_value('[1, 2]') == '[1, 2]' and rcl_rule_value('5') == '5'
    assert rcl_rule_value('[.inf, 2]') == '[.inf, 2.0]'
    for text in ('[a, 1]', '[true, 1]', '["1", 2]', '[1, 0.8'):
        assert rcl_rule_value(text) is None, text
    text = ('/**:\n  ros__parameters:\n    link_lengths: [1, 0.8]  # m\n    frame: yes\n'
            '    joint_names: [a, 1]\n/**/simulator:\n  ros__parameters:\n'
            '    initial_positions:\n      - 0\n      - 1.5\n')
    fixed, mixed = rcl_params_file(text)
    assert mixed == [('joint_names', ['a', 1])]
    assert fixed is not None and 'link_lengths: [1.0, 0.8]' in fixed
    assert 'frame: yes' in fixed, 'everything else as written'
    assert yaml.safe_load(fixed)['/**/simulator']['ros__parameters'] == {
        'initial_positions': [0.0, 1.5]}
    assert rcl_params_file('/**:\n  ros__parameters:\n    a: [1, 2]\n') == (None, [])
