"""ament_python package arm_sim: builds with colcon and installs with pip.

colcon (real ROS 2 Jazzy): ``setup.cfg`` puts the node executables in ``lib/arm_sim`` so
``ros2 run arm_sim <exe>`` finds them; data files land in ``share/arm_sim``.
pip (plain venv): the same entry points become console scripts on PATH.
Python dependency versions are pinned in ``constraints.txt`` only.
"""

import os
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'arm_sim'


def interfaces_data() -> list[tuple[str, list[str]]]:
    """interfaces/ (build_interfaces.py and the control_msgs/tf2_msgs definitions) as data
    files in share/arm_sim/interfaces/: `arm-sim interfaces` builds them from an installed
    wheel too (docs/interfaces.md)."""
    by_dir: dict[str, list[str]] = {}
    for path in sorted(glob('interfaces/**', recursive=True)):
        if os.path.isfile(path) and '__pycache__' not in path:
            by_dir.setdefault(os.path.dirname(path), []).append(path)
    return [(f'share/{PACKAGE}/{d}', files) for d, files in by_dir.items()]


setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(include=['arm_dynamics*', 'arm_control*', 'arm_planner*',
                                    'arm_bag*', 'arm_common*', 'arm_sim*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
        ('share/' + PACKAGE + '/config/sweeps', glob('config/sweeps/*.yaml')),
        ('share/' + PACKAGE + '/config/disturbances', glob('config/disturbances/*.yaml')),
        ('share/' + PACKAGE + '/config/checks', glob('config/checks/*.yaml')),
        ('share/' + PACKAGE + '/config/rviz', glob('config/rviz/*.rviz')),
        ('share/' + PACKAGE + '/config/foxglove', glob('config/foxglove/*.json')),
        ('share/' + PACKAGE + '/config/plotjuggler', glob('config/plotjuggler/*.xml')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.py')),
        *interfaces_data(),
    ],
    install_requires=['setuptools'],
    extras_require={
        # Versions live in constraints.txt; these are the names only.
        # catkin-pkg: rosidl_adapter (`arm-sim interfaces`) imports it; its wheel does not
        # declare it.
        'ros': ['ros-jazzy-rclpy', 'ros-jazzy-common-interfaces',
                'ros-jazzy-rmw-fastrtps-cpp', 'ros-jazzy-std-srvs', 'catkin-pkg'],
        'core': ['numpy', 'scipy', 'mcap', 'pyyaml', 'matplotlib', 'zstandard', 'lz4'],
        'test': ['pytest', 'pytest-timeout', 'ruff', 'mypy', 'colcon-common-extensions',
                 'rosbags', 'mcap-ros2-support', 'dask', 'distributed', 'yourdfpy', 'pin',
                 'mujoco',  # test/test_geared_motors.py: the reflected rotor inertia
                 'foxglove-sdk', 'websockets'],  # test/test_live.py: server and client
        'bench': ['pin', 'mujoco'],
        'dask': ['dask', 'distributed'],
        'foxglove': ['foxglove-sdk'],  # arm-sim bringup/demo --foxglove (the live node)
    },
    zip_safe=True,
    maintainer='arm_sim developers',
    maintainer_email='arm-sim@example.com',
    description='Simulated 2-R robot arm: dynamics, control, planning, MCAP recording.',
    license='Apache-2.0',
    python_requires='>=3.10',
    entry_points={
        # Every node starts through arm_sim.node_entry:main (the node is the executable's
        # name): it turns a missing control_msgs or tf2_msgs (pip builds no interfaces) into
        # one line naming `arm-sim interfaces`.
        'console_scripts': [
            'simulator = arm_sim.node_entry:main',
            'controller = arm_sim.node_entry:main',
            'planner = arm_sim.node_entry:main',
            'recorder = arm_sim.node_entry:main',
            'composed = arm_sim.node_entry:main',
            'live = arm_sim.node_entry:main',
            'visualizer = arm_sim.node_entry:main',
            'check_reference = arm_sim.node_entry:main',
            'arm-sim = arm_sim.cli:main',
        ],
        # arm_sim.testing: the arm_check fixture (opt-in; docs/check.md)
        'pytest11': ['arm_sim = arm_sim.testing'],
    },
)
