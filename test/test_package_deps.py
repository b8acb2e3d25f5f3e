"""package.xml names every run dependency by its rosdep key, and nothing nobody uses.

Walks every ``import`` (``ast``, function-level ones included) of the installed packages
and the launch files, maps each third-party top-level module to its rosdep key with the one
table below, and checks the keys against package.xml's ``exec_depend`` (and ``depend``).
A new import that is not in the table fails, so it forces a decision about its key.
Standard library modules (``sys.stdlib_module_names``) and the packages' own are skipped.
The recorder also imports message modules by name at run time (``importlib``) for whatever
topics it is asked to record; the suite's own topics are all covered here by static imports.

The tests are held to the same rule: every third-party module a test imports (statically,
or by name through ``pytest.importorskip`` / ``importlib.import_module``) is a run
dependency or a ``test_depend`` of package.xml, or an optional one without a rosdep key
(:data:`OPTIONAL`, the test skips without it); and every ``test_depend`` is imported by a
test.
"""

from __future__ import annotations

import ast
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: What setup.py installs as Python packages.
PACKAGES = ('arm_common', 'arm_dynamics', 'arm_control', 'arm_planner', 'arm_bag', 'arm_sim')

#: Third-party top-level module -> its rosdep key (rosdistro ``rosdep/*.yaml``; a ROS
#: package's key is its name).
ROSDEP_KEYS = {
    # ROS packages (message, client library and launch packages)
    'rclpy': 'rclpy',
    'builtin_interfaces': 'builtin_interfaces',
    'diagnostic_msgs': 'diagnostic_msgs',
    'geometry_msgs': 'geometry_msgs',
    'nav_msgs': 'nav_msgs',
    'rcl_interfaces': 'rcl_interfaces',
    'rosgraph_msgs': 'rosgraph_msgs',
    'sensor_msgs': 'sensor_msgs',
    'std_msgs': 'std_msgs',
    'std_srvs': 'std_srvs',
    'trajectory_msgs': 'trajectory_msgs',
    'tf2_msgs': 'tf2_msgs',
    'control_msgs': 'control_msgs',
    'visualization_msgs': 'visualization_msgs',
    'ament_index_python': 'ament_index_python',
    'launch': 'launch',
    'launch_ros': 'launch_ros',
    # Python libraries (rosdep/python.yaml)
    'numpy': 'python3-numpy',
    'scipy': 'python3-scipy',
    'yaml': 'python3-yaml',
    'matplotlib': 'python3-matplotlib',  # arm_bag.plot: arm-sim analyze --plot, the demo
    # The mcap library and its own pip requirements zstandard and lz4 have no rosdep keys
    # (python3-mcap, python3-zstandard and python3-lz4 resolve to nothing, so `rosdep
    # install` stopped); mcap-ros2-support's pip key installs all three.
    'zstandard': 'mcap-ros2-support',  # arm_bag.reader/writer: zstd-compressed MCAP chunks
    'lz4': 'mcap-ros2-support',  # arm_bag.reader/writer: lz4-compressed MCAP chunks
    'mcap': 'mcap-ros2-support',  # arm_bag.writer/recover: the mcap library (pip: mcap)
}

#: The rosdep keys package.xml may use, as ros/rosdistro defines them at commit 8468e88
#: (2026-08-22): rosdep/python.yaml and rosdep/base.yaml keys, and Jazzy packages
#: (jazzy/distribution.yaml). A key not here would leave `rosdep install` unresolved.
ROSDISTRO_KEYS = {
    'python3-numpy', 'python3-scipy', 'python3-yaml', 'python3-matplotlib',
    'mcap-ros2-support', 'python3-pytest', 'python3-hypothesis', 'python3-rosbags-pip',
    'python3-yourdfpy-pip', 'python3-mujoco-pip', 'python3-websockets',
    # Jazzy packages
    'rclpy', 'builtin_interfaces', 'std_msgs', 'std_srvs', 'sensor_msgs', 'geometry_msgs',
    'trajectory_msgs', 'visualization_msgs', 'nav_msgs', 'diagnostic_msgs',
    'rosgraph_msgs', 'rcl_interfaces', 'ament_index_python', 'launch', 'launch_ros',
    'robot_state_publisher', 'rviz2', 'pinocchio', 'tf2_msgs', 'control_msgs',
    'action_msgs',
}

#: Optional imports (a setup.py extra, imported only when asked for): no run dependency.
OPTIONAL = {
    'distributed': "arm-sim sweep --dask only (setup.py extra 'dask')",
    'foxglove': "arm-sim bringup/demo --foxglove only (setup.py extra 'foxglove')",
    'pytest': 'arm_sim.testing only: the pytest plugin, which pytest itself loads',
}

#: Third-party top-level module a test imports -> its rosdep key, for what the packages do
#: not import themselves (those are in :data:`ROSDEP_KEYS`, run dependencies the tests have
#: too). ``foxglove`` and ``distributed`` are :data:`OPTIONAL` (no rosdep key; the tests
#: skip without them).
TEST_ROSDEP_KEYS = {
    'pytest': 'python3-pytest',  # the runner (an OPTIONAL import of the packages)
    'rosbags': 'python3-rosbags-pip',  # bags read by an independent reader
    'yourdfpy': 'python3-yourdfpy-pip',  # the URDF read by an independent parser
    'mujoco': 'python3-mujoco-pip',  # the reflected rotor inertia
    'pinocchio': 'pinocchio',  # the dynamics against an independent library
    'websockets': 'python3-websockets',  # test_live*.py: the Foxglove WebSocket client
    'action_msgs': 'action_msgs',  # test_follow_joint_trajectory.py: goal status codes
    'mcap_ros2': 'mcap-ros2-support',  # recovered bags decoded by mcap_ros2
}

#: exec_depends no module imports, with the reason they are there anyway.
NOT_IMPORTED: dict[str, str] = {
    'robot_state_publisher': 'launch/arm.launch.py starts it (robot_state_publisher:=true)',
    'rviz2': 'launch/arm.launch.py starts it with config/rviz/arm.rviz (rviz:=true)',
}


def sources() -> list[Path]:
    files = [p for pkg in PACKAGES for p in sorted((ROOT / pkg).glob('**/*.py'))]
    return files + sorted((ROOT / 'launch').glob('*.py'))


def third_party_imports() -> dict[str, set[str]]:
    """Top-level third-party module -> the files (relative) importing it."""
    found: dict[str, set[str]] = {}
    for path in sources():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split('.')[0]
                if (top in sys.stdlib_module_names or top in PACKAGES or top in OPTIONAL
                        or top == '__future__'):
                    continue
                found.setdefault(top, set()).add(str(path.relative_to(ROOT)))
    return found


def exec_depends(tags: tuple[str, ...] = ('exec_depend', 'depend')) -> set[str]:
    root = ET.parse(ROOT / 'package.xml').getroot()
    return {e.text.strip() for e in root if e.tag in tags and e.text}


def test_every_key_in_package_xml_is_one_rosdep_resolves():
    keys = exec_depends(('exec_depend', 'depend', 'test_depend', 'build_depend'))
    unknown = keys - ROSDISTRO_KEYS
    assert not unknown, f'package.xml keys rosdistro does not define: {sorted(unknown)}'


def test_every_package_is_walked():
    found = {p.parent.name for p in ROOT.glob('*/__init__.py')}
    assert found == set(PACKAGES), f'packages not walked (add them to PACKAGES): {found}'


def test_every_third_party_import_has_its_rosdep_key_in_package_xml():
    imports = third_party_imports()
    unmapped = {m: sorted(files) for m, files in imports.items() if m not in ROSDEP_KEYS}
    assert not unmapped, (f'imports without a rosdep key in ROSDEP_KEYS (decide their key, '
                          f'add it here and to package.xml): {unmapped}')
    declared = exec_depends()
    missing = {ROSDEP_KEYS[m]: sorted(files) for m, files in imports.items()
               if ROSDEP_KEYS[m] not in declared}
    assert not missing, f'package.xml lacks <exec_depend> for: {missing}'


def test_every_exec_depend_is_imported_or_justified():
    used = {ROSDEP_KEYS[m] for m in third_party_imports() if m in ROSDEP_KEYS}
    unused = exec_depends() - used - set(NOT_IMPORTED)
    assert not unused, (f'package.xml exec_depends nothing imports (drop them, or say why '
                        f'in NOT_IMPORTED): {sorted(unused)}')


def test_the_table_holds_no_stale_entries():
    stale = set(ROSDEP_KEYS) - set(third_party_imports())
    assert not stale, f'ROSDEP_KEYS entries nothing imports any more: {sorted(stale)}'


def local_test_modules() -> set[str]:
    """Modules of test/ one test imports from another (``conftest``, ``test_launch_file``):
    the tests' own, no dependency."""
    return {p.stem for p in (ROOT / 'test').glob('*.py')}


def files_of_tests() -> list[Path]:
    """Every Python file under test/ (npm's node_modules left out)."""
    return sorted(p for p in (ROOT / 'test').glob('**/*.py') if 'node_modules' not in p.parts)


#: Calls that import the module named by their first (literal) argument.
IMPORTING_CALLS = ('importorskip', 'import_module')


def imports_of_tests() -> dict[str, set[str]]:
    """Top-level third-party module -> the test files (relative) importing it, statically
    or by a literal name given to ``pytest.importorskip`` / ``importlib.import_module``."""
    own = set(PACKAGES) | local_test_modules()
    found: dict[str, set[str]] = {}
    for path in files_of_tests():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
                names = [node.module]
            elif (isinstance(node, ast.Call) and node.args
                  and isinstance(node.args[0], ast.Constant)
                  and isinstance(node.args[0].value, str)
                  and getattr(node.func, 'attr', getattr(node.func, 'id', None))
                  in IMPORTING_CALLS):
                names = [node.args[0].value]
            else:
                continue
            for name in names:
                top = name.split('.')[0]
                if top in sys.stdlib_module_names or top in own or top == '__future__':
                    continue
                found.setdefault(top, set()).add(str(path.relative_to(ROOT)))
    return found


def test_the_walk_of_the_tests_sees_imports_by_name():
    imports = imports_of_tests()
    # test_live.py has no import statement for websockets: pytest.importorskip('websockets').
    assert 'test/test_live.py' in imports['websockets']
    assert 'test/test_follow_joint_trajectory.py' in imports['action_msgs']
    assert 'conftest' not in imports and 'arm_sim' not in imports


def test_every_module_a_test_imports_is_a_declared_dependency():
    imports = imports_of_tests()
    keys = {**ROSDEP_KEYS, **TEST_ROSDEP_KEYS}
    unmapped = {m: sorted(files) for m, files in imports.items()
                if m not in keys and m not in OPTIONAL}
    assert not unmapped, (f'modules tests import without a rosdep key (decide it: add it to '
                          f'TEST_ROSDEP_KEYS and to package.xml, or to OPTIONAL with why): '
                          f'{unmapped}')
    declared = exec_depends(('exec_depend', 'depend', 'test_depend'))
    missing = {keys[m]: sorted(files) for m, files in imports.items()
               if m in keys and keys[m] not in declared}
    assert not missing, f'package.xml lacks <test_depend> for: {missing}'


def test_every_test_depend_is_imported_by_a_test():
    used = {TEST_ROSDEP_KEYS[m] for m in imports_of_tests() if m in TEST_ROSDEP_KEYS}
    unused = exec_depends(('test_depend',)) - used
    assert not unused, (f'package.xml test_depends no test imports (drop them): '
                        f'{sorted(unused)}')
    stale = set(TEST_ROSDEP_KEYS) - set(imports_of_tests())
    assert not stale, f'TEST_ROSDEP_KEYS entries no test imports any more: {sorted(stale)}'
