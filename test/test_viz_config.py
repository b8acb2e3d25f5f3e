"""The shipped viewer configurations (RViz, Foxglove, PlotJuggler) parse, are installed, and
show only topics and frames the suite has."""

from __future__ import annotations

import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import yaml

from arm_bag.recorder_node import KNOWN_TOPICS
from arm_dynamics.robot import JOINT_NAMES, ROBOT_DEFAULTS
from arm_dynamics.urdf import BASE_FRAME

ROOT = Path(__file__).resolve().parents[1]
RVIZ = ROOT / 'config' / 'rviz' / 'arm.rviz'
FOXGLOVE = ROOT / 'config' / 'foxglove' / 'arm_layout.json'
PLOTJUGGLER = ROOT / 'config' / 'plotjuggler' / 'arm_layout.xml'
#: Relative names, as the nodes use them.
SUITE_TOPICS = {t.lstrip('/') for t in KNOWN_TOPICS}
#: Topics of the ROS tools the launch file adds (robot_state_publisher).
TOOL_TOPICS = {'robot_description', 'tf', 'tf_static'}
#: Shown before any node publishes it, with the reason.
PENDING: dict[str, str] = {}
#: Foxglove's own output: the layout's user script.
SCRIPT_OUTPUT = '/studio_script/arm_tip'


def rviz_topics(node, found: list[str]) -> list[str]:
    """Every ``Topic``/``Description Topic`` value in an RViz config."""
    if isinstance(node, dict):
        for key, value in node.items():
            if key in ('Topic', 'Description Topic') and isinstance(value, dict):
                found.append(value['Value'])
            else:
                rviz_topics(value, found)
    elif isinstance(node, list):
        for item in node:
            rviz_topics(item, found)
    return found


def test_rviz_config_shows_the_robot_in_base_link_and_sends_goal_pose():
    config = yaml.safe_load(RVIZ.read_text())
    manager = config['Visualization Manager']
    assert manager['Global Options']['Fixed Frame'] == BASE_FRAME
    displays = {d['Class']: d for d in manager['Displays']}
    robot = displays['rviz_default_plugins/RobotModel']
    assert robot['Description Source'] == 'Topic'
    assert robot['Description Topic']['Value'] == 'robot_description'
    assert robot['Description Topic']['Durability Policy'] == 'Transient Local'
    assert displays['rviz_default_plugins/MarkerArray']['Topic']['Value'] == 'markers'
    path = displays['rviz_default_plugins/Path']['Topic']
    assert path['Value'] == 'planner/path' and path['Durability Policy'] == 'Transient Local'
    tools = {t['Class']: t for t in manager['Tools']}
    assert tools['rviz_default_plugins/SetGoal']['Topic']['Value'] == 'goal_pose'
    topics = rviz_topics(config, [])
    assert all(not t.startswith('/') for t in topics), f'relative names only: {topics}'
    unknown = set(topics) - SUITE_TOPICS - TOOL_TOPICS - set(PENDING)
    assert not unknown, f'topics nobody publishes: {unknown}'


def test_foxglove_layout_plots_angles_against_the_reference_torques_and_the_tip():
    layout = json.loads(FOXGLOVE.read_text())
    panels = layout['configById']
    used: list[str] = []

    def walk(node):
        if isinstance(node, str):
            used.append(node)
        else:
            walk(node['first'])
            walk(node['second'])

    walk(layout['layout'])
    assert sorted(used) == sorted(panels), 'every panel is in the layout, and only those'
    assert any(p.startswith('3D!') for p in panels)
    paths = [p['value'] for k, c in panels.items() if k.startswith('Plot!')
             for p in c['paths']]
    for j in range(len(JOINT_NAMES)):
        assert f'/joint_states.position[{j}]' in paths
        assert f'/arm_controller/reference.position[{j}]' in paths
        assert f'/joint_states.effort[{j}]' in paths
    assert f'{SCRIPT_OUTPUT}.deviation' in paths
    suite = {'/' + t for t in SUITE_TOPICS}
    for path in paths:
        topic = path.split('.')[0]
        assert topic in suite | {SCRIPT_OUTPUT}, f'{path}: no such topic'
    three_d = next(c for k, c in panels.items() if k.startswith('3D!'))
    assert three_d['followTf'] == BASE_FRAME
    assert set(three_d['topics']) - suite - {'/' + t for t in PENDING} == set()
    assert three_d['publish']['poseTopic'] == '/goal_pose'
    (script,) = layout['userNodes'].values()
    source = script['sourceCode']
    inputs = json.loads(re.search(r'inputs = (\[.*?\]);', source).group(1))
    assert set(inputs) <= suite
    assert f'output = "{SCRIPT_OUTPUT}"' in source
    lengths = [float(re.search(rf'const L{i} = ([0-9.]+);', source).group(1)) for i in (1, 2)]
    assert lengths == ROBOT_DEFAULTS['link_lengths'], 'the script draws the default arm'


def test_plotjuggler_layout_plots_angles_against_the_reference_and_torques():
    root = ET.parse(PLOTJUGGLER).getroot()
    curves = [c.get('name') for c in root.iter('curve')]
    # PlotJuggler names a JointState's series by joint name, not by index.
    for joint in JOINT_NAMES:
        assert f'/joint_states/{joint}/position' in curves
        assert f'/arm_controller/reference/{joint}/position' in curves
        assert f'/joint_states/{joint}/effort' in curves
    for name in curves:
        topic, joint, field = name.rsplit('/', 2)
        assert topic.lstrip('/') in SUITE_TOPICS and joint in JOINT_NAMES
        assert field in ('position', 'velocity', 'effort')


def test_setup_installs_the_viewer_configurations():
    setup = (ROOT / 'setup.py').read_text()
    for pattern in ('config/rviz/*.rviz', 'config/foxglove/*.json',
                    'config/plotjuggler/*.xml'):
        assert f"glob('{pattern}')" in setup, pattern
    for path in (RVIZ, FOXGLOVE, PLOTJUGGLER):
        assert path.is_file()
