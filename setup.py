"""ament_python package arm_sim: builds with colcon and installs with pip.

colcon (real ROS 2 Jazzy): ``setup.cfg`` puts the node executables in ``lib/arm_sim`` so
``ros2 run arm_sim <exe>`` finds them; data files land in ``share/arm_sim``.
pip (plain venv): the same entry points become console scripts on PATH.
Python dependency versions are pinned in ``constraints.txt`` only.
"""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'arm_sim'

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
    ],
    install_requires=['setuptools'],
    extras_require={
        # Versions live in constraints.txt; these are the names only.
        'ros': ['ros-jazzy-rclpy', 'ros-jazzy-common-interfaces',
                'ros-jazzy-rmw-fastrtps-cpp', 'ros-jazzy-std-srvs'],
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
        'console_scripts': [
            'simulator = arm_dynamics.simulator_node:main',
            'controller = arm_control.controller_node:main',
            'planner = arm_planner.planner_node:main',
            'recorder = arm_bag.recorder_node:main',
            'composed = arm_sim.composed:main',
            'live = arm_sim.live_node:main',
            'visualizer = arm_sim.visualizer_node:main',
            'check_reference = arm_sim.check.reference_node:main',
            'arm-sim = arm_sim.cli:main',
        ],
        # arm_sim.testing: the arm_check fixture (opt-in; docs/check.md)
        'pytest11': ['arm_sim = arm_sim.testing'],
    },
)
