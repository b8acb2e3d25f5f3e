"""Start the arm_sim suite on a ROS 2 Jazzy install: simulator, controller, planner, recorder,
visualizer.

    ros2 launch arm_sim arm.launch.py
    ros2 launch arm_sim arm.launch.py namespace:=arm2 timing_mode:=lockstep record:=false
    ros2 launch arm_sim arm.launch.py composed:=true     # simulator + controller, one process
    ros2 launch arm_sim arm.launch.py rviz:=true         # + robot_state_publisher and RViz 2
    ros2 launch arm_sim arm.launch.py visualizer:=false  # no markers, no robot_description
    ros2 launch arm_sim arm.launch.py --show-args

The simulator is the clock source: it publishes ``clock`` relative to its namespace, so
every node remaps ``/clock`` to ``clock``, which resolves to ``/<namespace>/clock`` (plain
``/clock`` without a namespace) and keeps two arms in two namespaces on separate clocks. A
remap target is expanded in the node's namespace, so this works whether ``namespace`` is
given as ``arm2`` or ``/arm2``.

``robot_state_publisher:=true`` adds robot_state_publisher with ``robot_description`` made
from params_file's robot parameters (``arm-sim urdf`` prints the same URDF), publishing the
frames base_link, link1, link2 and tool0 from ``joint_states``; ``rviz:=true`` adds it too
and RViz 2 with config/rviz/arm.rviz. Both run in ``namespace`` with ``/tf`` remapped to
``tf`` there, so two arms keep two trees.

Failures and signals: a launch that asks for a package this machine does not have
(``robot_state_publisher:=true`` or ``rviz:=true`` without it) is refused before any node
starts, naming the package. Every arm_sim node is told the launch process's pid
(``ARM_SIM_PARENT_PID``) and asks the kernel for SIGTERM when that process dies, by any
signal (SIGKILL included): no node outlives its ``ros2 launch``, and the recorder closes
its bag.

``visualizer:=true`` (the default) starts the visualizer: ``markers`` (the arm, its trail, the
goal and the planned path) and ``robot_description``; when robot_state_publisher runs, that
publishes ``robot_description`` and the visualizer leaves it out.
"""

from __future__ import annotations

import os
from datetime import datetime

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition
from launch.launch_context import LaunchContext
from launch.launch_description import LaunchDescription
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import Parameter, ParameterValue

from arm_common.process import PARENT_ENV  # nodes die with the process that started them
from arm_dynamics.timing import TIMING_MODES  # the one list of modes
from arm_sim.launcher import recorder_gates  # first messages wait for the recorder
from arm_sim.urdf_cli import urdf_for_params_file  # the URDF arm-sim urdf prints

PACKAGE = 'arm_sim'
# Topic names are relative: '/clock' -> 'clock' lands in the node's namespace.
CLOCK_REMAP = [('/clock', 'clock')]
# The same for the transform tree of robot_state_publisher and RViz.
TF_REMAP = [('/tf', 'tf'), ('/tf_static', 'tf_static')]

#: Given to every arm_sim node: this (the ros2 launch) process's pid; each node asks the
#: kernel for SIGTERM when it dies (arm_common.process.watch_parent).
PARENT = {PARENT_ENV: str(os.getpid())}

namespace = LaunchConfiguration('namespace')
params_file = LaunchConfiguration('params_file')
use_sim_time = LaunchConfiguration('use_sim_time')
timing_mode = LaunchConfiguration('timing_mode')
bag = LaunchConfiguration('bag')
record = LaunchConfiguration('record')
composed = LaunchConfiguration('composed')
rviz = LaunchConfiguration('rviz')
robot_state_publisher = LaunchConfiguration('robot_state_publisher')
visualizer = LaunchConfiguration('visualizer')


def _arguments() -> list[DeclareLaunchArgument]:
    default_params = os.path.join(get_package_share_directory(PACKAGE), 'config', 'arm.yaml')
    default_bag = os.path.join(os.getcwd(),
                               'arm_sim_' + datetime.now().strftime('%Y%m%d_%H%M%S'))
    return [
        DeclareLaunchArgument(
            'namespace', default_value='',
            description='ROS namespace of all the nodes and their topics (e.g. arm2 or '
                        '/arm2); empty: the root namespace.'),
        DeclareLaunchArgument(
            'params_file', default_value=default_params,
            description='ROS 2 params file given to every node (robot description and '
                        'node settings).'),
        DeclareLaunchArgument(
            'use_sim_time', default_value='true', choices=['true', 'false'],
            description='Run controller, planner, recorder, visualizer and, when started, '
                        'robot_state_publisher and rviz2 on simulated time: the clock topic '
                        'the simulator publishes in namespace (false: the wall clock). The '
                        'simulator is the clock source and always runs on the wall clock; '
                        'with composed:=true the controller in its process follows '
                        'params_file instead (config/arm.yaml: simulated time).'),
        DeclareLaunchArgument(
            'timing_mode', default_value='', choices=['', *TIMING_MODES],
            description='Simulator timing mode: real_time (wall-clock speed, the default in '
                        'config/arm.yaml) or lockstep (deterministic, as fast as the closed '
                        'loop runs); empty: the value in params_file.'),
        DeclareLaunchArgument(
            'bag', default_value=default_bag,
            description='Bag directory the recorder creates (parameter "output"); default: '
                        'arm_sim_<timestamp> in the current directory.'),
        DeclareLaunchArgument(
            'record', default_value='true', choices=['true', 'false'],
            description='Start the recorder.'),
        DeclareLaunchArgument(
            'composed', default_value='false', choices=['true', 'false'],
            description='Run simulator and controller in one process with one executor '
                        '(executable "composed"): holds real time at 1 kHz control. Their '
                        'settings then come from params_file (and timing_mode) only.'),
        DeclareLaunchArgument(
            'robot_state_publisher', default_value='false', choices=['true', 'false'],
            description='Start robot_state_publisher with robot_description made from '
                        'params_file\'s robot parameters (the URDF arm-sim urdf prints): '
                        'the frames base_link, link1, link2, tool0 from joint_states.'),
        DeclareLaunchArgument(
            'rviz', default_value='false', choices=['true', 'false'],
            description='Start RViz 2 with config/rviz/arm.rviz (robot model, planned path, '
                        'markers; its 2D Goal Pose tool sends goal_pose), and '
                        'robot_state_publisher, which it needs.'),
        DeclareLaunchArgument(
            'visualizer', default_value='true', choices=['true', 'false'],
            description='Start the visualizer: markers (visualization_msgs/MarkerArray of '
                        'the arm, its tip trail, the goal and the planned path) and '
                        'robot_description (left to robot_state_publisher when it runs).'),
    ]


def _loop(context: LaunchContext) -> list[Node]:
    """The simulator and the controller: two processes, or one (``composed``), with
    ``timing_mode`` overriding params_file only when non-empty.

    A non-empty ``timing_mode`` reaches the node ``simulator`` as a node-scoped command-line
    rule (:func:`timing_mode_parameters`), in either process: a ``parameters`` dict would not
    do for ``composed``, whose Node has no single name, so launch_ros writes the dict as a
    ``/**`` section, which a params file's ``/**/simulator`` section (config/arm.yaml's sets
    ``timing_mode``) beats. The rule is an entry of ``parameters`` (a launch_ros
    ``Parameter``), which launch_ros writes as ``-p`` after the params files in the one
    ``--ros-args`` section it makes; ``ros_arguments`` would open a second one.

    The simulator is the clock source and must run on the wall clock, so its
    ``use_sim_time`` is pinned to false even if params_file sets it for all nodes (composed:
    params_file's per-node sections decide, as config/arm.yaml does).
    """
    modes = timing_mode_parameters(timing_mode.perform(context))
    if composed.perform(context) == 'true':
        return [Node(package=PACKAGE, executable='composed', namespace=namespace,
                     parameters=[params_file, *_gate(context, 'simulator'), *modes],
                     remappings=CLOCK_REMAP, output='screen', additional_env=PARENT)]
    return [Node(package=PACKAGE, executable='simulator', name='simulator',
                 namespace=namespace, parameters=[params_file, {'use_sim_time': False},
                                                  *_gate(context, 'simulator'), *modes],
                 remappings=CLOCK_REMAP, output='screen', additional_env=PARENT),
            _sim_time_node('controller', parameters=_gate(context, 'controller'))]


def _gate(context: LaunchContext, node: str) -> list[dict]:
    """With ``record`` true, ``node`` sends nothing before the recorder has matched it, so
    the bag holds its first messages (:func:`arm_sim.launcher.recorder_gates`)."""
    if record.perform(context) != 'true':
        return []
    values = recorder_gates(params_file.perform(context)).get(node, {}).get(node)
    return [values] if values else []


def timing_mode_parameters(mode: str) -> list[Parameter]:
    """The rule that sets the node ``simulator``'s ``timing_mode`` to ``mode``, or none for
    an empty ``mode`` (params_file decides).

    launch_ros (Jazzy) gives a ``Parameter`` entry of ``parameters`` to the node as
    ``-p simulator:timing_mode:=<mode>`` after the params files, in its one ``--ros-args``
    section. That rule applies to the node named ``simulator`` in any namespace, leaves the
    controller of the composed process alone and wins over every params file: rcl applies
    the later of a file and a rule, and the suite's nodes apply ``-p`` rules last anyway
    (:func:`arm_common.params.command_line_parameters`).
    """
    mode = mode.strip()
    return [Parameter('simulator:timing_mode', mode)] if mode else []


def _visualization(context: LaunchContext) -> list[Node]:
    """robot_state_publisher (``robot_state_publisher`` or ``rviz`` true) with the URDF of
    params_file's robot parameters, and RViz 2 with the shipped config (``rviz`` true).

    Both follow ``use_sim_time`` like the controller: the transforms carry the joint
    states' simulated stamps.
    """
    show = rviz.perform(context) == 'true'
    if not (show or robot_state_publisher.perform(context) == 'true'):
        return []
    sim_time = {'use_sim_time': ParameterValue(use_sim_time, value_type=bool)}
    description = urdf_for_params_file(params_file.perform(context))
    nodes = [Node(package='robot_state_publisher', executable='robot_state_publisher',
                  name='robot_state_publisher', namespace=namespace,
                  parameters=[{'robot_description': ParameterValue(description,
                                                                   value_type=str)},
                              sim_time],
                  remappings=CLOCK_REMAP + TF_REMAP, output='screen')]
    if show:
        config = os.path.join(get_package_share_directory(PACKAGE), 'config', 'rviz',
                              'arm.rviz')
        nodes.append(Node(package='rviz2', executable='rviz2', name='rviz2',
                          namespace=namespace, arguments=['-d', config],
                          parameters=[sim_time], remappings=CLOCK_REMAP + TF_REMAP,
                          output='screen'))
    return nodes


def _visualizer(context: LaunchContext) -> list[Node]:
    """The visualizer (``visualizer`` true); it publishes ``robot_description``, ``tf`` and
    ``tf_static`` unless robot_state_publisher does (``robot_state_publisher`` or ``rviz``
    true), so each topic has one publisher."""
    if visualizer.perform(context) != 'true':
        return []
    rsp = 'true' in (robot_state_publisher.perform(context), rviz.perform(context))
    return [_sim_time_node('visualizer',
                           parameters=[{'publish_robot_description': not rsp,
                                        'publish_tf': not rsp},
                                       *_gate(context, 'visualizer')])]


def _sim_time_node(executable: str, **kwargs) -> Node:
    """A node of the suite that runs on simulated time (when use_sim_time is true)."""
    extra = kwargs.pop('parameters', [])
    return Node(package=PACKAGE, executable=executable, name=executable, namespace=namespace,
                parameters=[params_file,
                            {'use_sim_time': ParameterValue(use_sim_time, value_type=bool)},
                            *extra],
                remappings=CLOCK_REMAP, output='screen', additional_env=PARENT, **kwargs)


def _optional_packages(context: LaunchContext) -> list:
    """Refuse, before any node starts, a launch asking for a package this machine lacks
    (``robot_state_publisher:=true`` or ``rviz:=true``): launch stops with the reason and
    nothing is left running."""
    wanted = []
    if rviz.perform(context) == 'true':
        wanted = ['robot_state_publisher', 'rviz2']
    elif robot_state_publisher.perform(context) == 'true':
        wanted = ['robot_state_publisher']
    missing = []
    for package in wanted:
        try:
            get_package_share_directory(package)
        except PackageNotFoundError:
            missing.append(package)
    if missing:
        raise RuntimeError(
            f"{', '.join(missing)} not installed (apt install "
            f"{' '.join('ros-jazzy-' + m.replace('_', '-') for m in missing)}), which "
            'robot_state_publisher:=true / rviz:=true need; no node was started')
    return []


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        *_arguments(),
        OpaqueFunction(function=_optional_packages),  # first: before any node starts
        OpaqueFunction(function=_loop),
        _sim_time_node('planner'),
        _sim_time_node('recorder',
                       parameters=[{'output': ParameterValue(bag, value_type=str)}],
                       condition=IfCondition(record)),
        OpaqueFunction(function=_visualization),
        OpaqueFunction(function=_visualizer),
    ])
