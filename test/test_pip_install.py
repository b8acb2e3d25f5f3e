"""arm_sim installed the way Python tools are: ``pip install '<repo>[ros,core]'`` into a
fresh venv (a normal, not editable, install), then used from another folder.

pip builds no interface packages, so before ``arm-sim interfaces`` the nodes that need
control_msgs/tf2_msgs and ``arm-sim demo`` say so in one line (naming that command) and
exit 1, starting nothing; after it, built from the definitions the wheel ships
(``share/arm_sim/interfaces``), the controller node starts and runs. Slow (pip about a
minute with pip's cache, the build about a minute more): one test, process tier.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.process

ROOT = Path(__file__).resolve().parents[1]
#: What a source checkout holds besides the package (not copied to the install source).
NOT_SOURCE = ('.venv', '.git', 'build', 'install', 'log', 'runs', '*.egg-info', '__pycache__',
              '.pytest_cache', '.mypy_cache', '.ruff_cache')


def other_venv_env() -> dict[str, str]:
    """This environment, for another venv's Python: without the ROS wheels' bootstrap guard
    and its LD_LIBRARY_PATH (they name this venv's libraries; see launcher.node_env)."""
    env = dict(os.environ)
    env.pop('_ROS_WHEELS_BOOTSTRAP_COMPLETE', None)
    env.pop('LD_LIBRARY_PATH', None)
    env.pop('AMENT_PREFIX_PATH', None)
    env.pop('PYTHONPATH', None)
    env['PYTHONUNBUFFERED'] = '1'
    return env


def run(cmd: list[str], cwd: Path, timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=cwd, env=other_venv_env(), capture_output=True, text=True,
                          timeout=timeout)


def one_line(result: subprocess.CompletedProcess) -> str:
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, f'expected one line on stderr, got:\n{result.stderr}'
    return lines[0]


@pytest.mark.timeout(1200)
def test_pip_installed_package_builds_its_interfaces_and_runs_a_node(tmp_path):
    src = tmp_path / 'src'  # a copy: pip builds in the source folder (build/, egg-info)
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(*NOT_SOURCE))
    venv = tmp_path / 'venv'
    subprocess.run([sys.executable, '-m', 'venv', str(venv)], check=True, timeout=120,
                   env=other_venv_env())
    bin_ = venv / 'bin'
    pip = run([str(bin_ / 'python'), '-m', 'pip', 'install', '--quiet',
               '--disable-pip-version-check', '-c', str(src / 'constraints.txt'),
               f'{src}[ros,core]'], tmp_path, timeout=900)
    assert pip.returncode == 0, pip.stdout + pip.stderr
    elsewhere = tmp_path / 'elsewhere'  # neither the source tree nor the venv
    elsewhere.mkdir()

    # Before the build: one line naming the command, exit 1, no traceback, nothing started.
    for node, pkg in (('visualizer', 'tf2_msgs'), ('controller', 'control_msgs')):
        r = run([str(bin_ / node), '--help'], elsewhere, timeout=120)
        line = one_line(r)
        assert r.returncode == 1, (node, r.returncode, r.stderr)
        assert line.startswith(f'{node}: ') and pkg in line, line
        assert 'not built into this Python environment' in line, line
        assert line.endswith('run `arm-sim interfaces` once'), line
    demo_out = elsewhere / 'demo-out'
    r = run([str(bin_ / 'arm-sim'), 'demo', '--out', str(demo_out)], elsewhere, timeout=120)
    line = one_line(r)
    assert r.returncode == 1, (r.returncode, r.stdout, r.stderr)
    assert line.startswith('arm-sim demo: control_msgs and tf2_msgs are not built'), line
    assert line.endswith('run `arm-sim interfaces` once'), line
    assert r.stdout == '' and not demo_out.exists(), r.stdout  # it started nothing

    # The one command: built from the definitions the wheel installed, into the venv.
    shipped = venv / 'share' / 'arm_sim' / 'interfaces'
    assert (shipped / 'build_interfaces.py').is_file()
    assert (shipped / 'control_msgs' / 'action' / 'FollowJointTrajectory.action').is_file()
    r = run([str(bin_ / 'arm-sim'), 'interfaces'], elsewhere, timeout=900)
    assert r.returncode == 0, r.stdout + r.stderr
    assert f'control_msgs and tf2_msgs are ready in {venv}' in r.stdout, r.stdout
    assert (venv / 'share' / 'control_msgs' / 'arm_sim_interfaces.stamp').is_file()
    r = run([str(bin_ / 'arm-sim'), 'interfaces', '--check'], elsewhere, timeout=120)
    assert r.returncode == 0 and 'up to date' in r.stdout, r.stdout + r.stderr
    r = run([str(bin_ / 'visualizer'), '--help'], elsewhere, timeout=120)
    assert r.returncode == 0 and 'visualizer' in r.stdout, r.stdout + r.stderr

    # A node of the installed package now starts and runs (control_msgs' action server).
    log = tmp_path / 'controller.log'
    with log.open('w') as out:
        proc = subprocess.Popen([str(bin_ / 'controller')], cwd=elsewhere,
                                env=other_venv_env(), stdout=out, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 120
        while 'control, updating on' not in log.read_text():
            assert proc.poll() is None, f'controller exited:\n{log.read_text()}'
            assert time.monotonic() < deadline, f'no start line:\n{log.read_text()}'
            time.sleep(0.1)
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            code = proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            raise
    assert code == 0, log.read_text()
    assert 'Traceback' not in log.read_text(), log.read_text()
