"""colcon builds arm_sim as an ament_python package, and ``ros2 run`` would find and run it.

The package files are copied into a temporary workspace ``src/arm_sim`` (colcon's
ament_python build writes ``*.egg-info`` into the source directory, so the repository is
never built in place) and built with the colcon of this test's venv. The installed
``simulator`` is then located exactly as ``ros2 run arm_sim simulator`` locates it (ament
index prefix + ``lib/arm_sim/simulator``) in a shell that sourced ``install/setup.bash``,
started on the test's private ROS domain, and must publish ``joint_states`` and stop cleanly
on SIGINT. No ``ros2`` command line is needed.
"""

from __future__ import annotations

import importlib.util
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import DOMAIN_ID
from sensor_msgs.msg import JointState

from arm_sim.launcher import node_env

REPO = Path(__file__).resolve().parents[1]
PACKAGE = 'arm_sim'
PACKAGE_FILES = ['package.xml', 'setup.py', 'setup.cfg']
PACKAGE_DIRS = ['resource', 'config', 'launch', 'arm_dynamics', 'arm_control', 'arm_planner',
                'arm_sim']
IGNORE = shutil.ignore_patterns('__pycache__', '*.pyc', '*.egg-info', '.pytest_cache',
                                '.ruff_cache')
BUILD_TIMEOUT = 120.0  # s; a build takes about 5 s on a 2-core machine
# Imports checked to come from the install space, not the source tree or the venv's
# editable install (which maps them to the repository).
CHECKED_MODULES = ['arm_sim', 'arm_dynamics', 'arm_dynamics.simulator_node']


def colcon_command() -> list[str]:
    """The colcon of this test's venv (never one found on PATH)."""
    exe = Path(sys.executable).parent / 'colcon'
    if exe.is_file() and os.access(exe, os.X_OK):
        return [str(exe)]
    if importlib.util.find_spec('colcon_core') is not None:
        return [sys.executable, '-c',
                'import sys; from colcon_core.command import main; sys.exit(main())']
    pytest.fail(f'colcon is not installed in the venv of {sys.executable}: '
                "pip install colcon-common-extensions (it is in the 'test' extra)")


def package_sources() -> tuple[list[str], list[str]]:
    """Top-level files and directories that make up the package (no build or VCS state)."""
    files = [f for f in PACKAGE_FILES if (REPO / f).is_file()]
    dirs = [d for d in PACKAGE_DIRS if (REPO / d).is_dir()]
    # Any other top-level Python package (e.g. a future arm_bag).
    dirs += sorted(p.name for p in REPO.iterdir()
                   if p.is_dir() and p.name not in dirs and not p.name.startswith('.')
                   and (p / '__init__.py').is_file())
    return files, dirs


def run(cmd: list[str], cwd: Path, env: dict[str, str], timeout: float,
        what: str) -> subprocess.CompletedProcess:
    try:
        return subprocess.run(cmd, cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                              capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f'{what} did not finish within {timeout:g} s:\n'
                    f'{exc.stdout or ""}\n{exc.stderr or ""}')


def colcon_log(ws: Path) -> str:
    """The package's build log (warnings that colcon only writes to log/)."""
    log = ws / 'log' / 'latest_build' / PACKAGE / 'stdout_stderr.log'
    return log.read_text(errors='replace')[-6000:] if log.is_file() else f'(no {log})'


@pytest.fixture(scope='module')
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A colcon workspace with arm_sim built and installed into ``install/``."""
    ws = tmp_path_factory.mktemp('colcon_ws')
    src = ws / 'src' / PACKAGE
    src.mkdir(parents=True)
    files, dirs = package_sources()
    for name in files:
        shutil.copy2(REPO / name, src / name)
    for name in dirs:
        shutil.copytree(REPO / name, src / name, ignore=IGNORE)

    env = node_env()
    # Ignore the user's colcon defaults (e.g. --symlink-install would install links into
    # the build directory and change the layout under test).
    (ws / 'colcon_home').mkdir()
    env['COLCON_HOME'] = str(ws / 'colcon_home')
    colcon = colcon_command()

    listed = run(colcon + ['list', '--base-paths', 'src'], ws, env, 60, 'colcon list')
    assert listed.returncode == 0, listed.stdout + listed.stderr
    # A package.xml that catkin_pkg rejects (e.g. a bad maintainer email) makes colcon build
    # it as plain Python: no ament hooks, no ament_index lookup after sourcing.
    assert '(ros.ament_python)' in listed.stdout, (
        f'colcon does not identify {PACKAGE} as ament_python:\n{listed.stdout}{listed.stderr}')

    start = time.monotonic()
    build = run(colcon + ['build', '--base-paths', 'src', '--event-handlers', 'console_direct+'],
                ws, env, BUILD_TIMEOUT, 'colcon build')
    if build.returncode != 0:
        pytest.fail(f'colcon build failed ({build.returncode}) after '
                    f'{time.monotonic() - start:.1f} s:\n{build.stdout[-6000:]}\n'
                    f'{build.stderr[-3000:]}\n--- {PACKAGE} build log ---\n{colcon_log(ws)}')
    return ws


def test_colcon_installs_the_ament_python_layout(workspace: Path):
    prefix = workspace / 'install' / PACKAGE
    for name in ('simulator', 'controller', 'planner', 'recorder', 'composed'):
        exe = prefix / 'lib' / PACKAGE / name
        assert exe.is_file() and os.access(exe, os.X_OK), (
            f'{exe} missing or not executable (setup.cfg install_scripts?)\n'
            f'{colcon_log(workspace)}')
    for rel in [f'share/{PACKAGE}/package.xml', f'share/{PACKAGE}/config/arm.yaml',
                f'share/{PACKAGE}/launch/arm.launch.py',
                f'share/{PACKAGE}/config/rviz/arm.rviz',
                f'share/{PACKAGE}/config/foxglove/arm_layout.json',
                f'share/{PACKAGE}/config/plotjuggler/arm_layout.xml',
                f'share/ament_index/resource_index/packages/{PACKAGE}',
                # Written by colcon's ament_python support only, not by setup.py.
                f'share/{PACKAGE}/hook/ament_prefix_path.dsv']:
        assert (prefix / rel).is_file(), f'{rel} not installed\n{colcon_log(workspace)}'
    # Launch files cannot run here (no launch/launch_ros), but they must at least compile.
    for launch_file in (prefix / 'share' / PACKAGE / 'launch').glob('*.launch.py'):
        compile(launch_file.read_text(), str(launch_file), 'exec')
    # The script must run with the Python colcon ran with (this venv, which has rclpy).
    shebang = exe.read_text().splitlines()[0]
    interpreter = Path(shlex.split(shebang.removeprefix('#!'))[0])
    assert interpreter.parent.resolve() == Path(sys.executable).parent.resolve(), (
        f'{exe} runs {shebang!r}, not the Python of {sys.executable}')


# Runs in bash after `source install/setup.bash`: resolves the executable like `ros2 run`,
# reports where the script's interpreter imports the package from, then becomes the node.
RUN_LIKE_ROS2_RUN = r'''
set -e
source install/setup.bash  # not "set -u" safe
set -u
prefix=$("$PY" -c "from ament_index_python.packages import get_package_prefix
print(get_package_prefix('arm_sim'))")
exe="$prefix/lib/arm_sim/simulator"
echo "PREFIX=$prefix"
read -r shebang < "$exe"
${shebang#'#!'} -c "import importlib.metadata as md, importlib.util, sys
dist = md.distribution('arm-sim')
print('DIST=' + str(dist.locate_file('')))
for name in sys.argv[1:]:
    print('MODULE=' + importlib.util.find_spec(name).origin)" $CHECKED_MODULES
exec "$exe" --ros-args -p timing_mode:=real_time
'''


def test_installed_simulator_runs_like_ros2_run(workspace: Path, ros):
    install = (workspace / 'install').resolve()
    env = node_env(DOMAIN_ID)
    env['PY'] = sys.executable
    env['CHECKED_MODULES'] = ' '.join(CHECKED_MODULES)
    log_path = workspace / 'simulator.log'
    states = ros.collect(JointState, 'joint_states')
    with open(log_path, 'wb') as log:
        proc = subprocess.Popen(['bash', '-c', RUN_LIKE_ROS2_RUN], cwd=workspace, env=env,
                                stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
    code: int | None = None
    try:
        ros.wait_for(lambda: len(states) >= 5 or proc.poll() is not None, timeout=30,
                     what='joint_states from the installed simulator')
        assert proc.poll() is None, (
            f'the installed simulator exited {proc.returncode}:\n{log_path.read_text()}')
        os.killpg(proc.pid, signal.SIGINT)  # bash exec'd the node: the group is the node
        try:
            code = proc.wait(15)
        except subprocess.TimeoutExpired:
            pass
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    output = log_path.read_text(errors='replace')
    assert code is not None, f'no exit within 15 s of SIGINT (killed):\n{output[-3000:]}'
    assert code in (0, -signal.SIGINT, 128 + signal.SIGINT), (
        f'exit code {code} on SIGINT:\n{output[-3000:]}')
    assert list(states[0].name) == ['joint1', 'joint2']

    report = dict(line.split('=', 1) for line in output.splitlines()
                  if line.split('=', 1)[0] in ('PREFIX', 'DIST'))
    modules = [line.split('=', 1)[1] for line in output.splitlines()
               if line.startswith('MODULE=')]
    assert Path(report['PREFIX']).resolve() == install / PACKAGE, output
    outside = [p for p in [report['DIST'], *modules]
               if not Path(p).resolve().is_relative_to(install)]
    assert len(modules) == len(CHECKED_MODULES) and not outside, (
        f'the installed simulator imports from outside {install}: {outside}\n{output}')
