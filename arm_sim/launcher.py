"""Start and stop arm_sim node processes (no rclpy): used by ``arm-sim`` and the tests.

An executable is found the way ``ros2 run`` finds it (``<prefix>/lib/arm_sim/<exe>`` via
the ament index) when arm_sim is installed in a ROS workspace, else as the console script
next to this Python (a pip venv), else as ``python -m <module>``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

from arm_common.process import PARENT_ENV

MODULES = {
    'simulator': 'arm_dynamics.simulator_node',
    'controller': 'arm_control.controller_node',
    'planner': 'arm_planner.planner_node',
    'recorder': 'arm_bag.recorder_node',
    'composed': 'arm_sim.composed',  # simulator + controller in one process
    'live': 'arm_sim.live_node',  # the Foxglove WebSocket bridge (--foxglove)
    'visualizer': 'arm_sim.visualizer_node',  # markers and robot_description
}


def executable(name: str) -> list[str]:
    """Command line that starts node executable ``name``."""
    for prefix in filter(None, os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep)):
        exe = Path(prefix) / 'lib' / 'arm_sim' / name
        if exe.is_file() and os.access(exe, os.X_OK):
            return [str(exe)]
    exe = Path(sys.executable).parent / name
    if exe.is_file() and os.access(exe, os.X_OK):
        return [str(exe)]
    return [sys.executable, '-m', MODULES[name]]


def config_file() -> Path:
    """The shipped ``config/arm.yaml``: from the install's share/ or the source tree."""
    candidates = [Path(p) / 'share' / 'arm_sim' / 'config' / 'arm.yaml'
                  for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    candidates += [Path(sys.prefix) / 'share' / 'arm_sim' / 'config' / 'arm.yaml',
                   Path(__file__).resolve().parents[1] / 'config' / 'arm.yaml']
    for c in candidates:
        if c.is_file():
            return c
    raise FileNotFoundError('config/arm.yaml not found; looked in: '
                            + ', '.join(str(c) for c in candidates))


def node_env(domain_id: int | None = None, localhost: bool = True) -> dict[str, str]:
    """Environment for a node process.

    Drops the ROS wheels' bootstrap guard so a child of another venv's process re-resolves
    its own libraries (docs/ros.md: ROS 2 from PyPI wheels), and pins the DDS domain.
    """
    env = dict(os.environ)
    if env.pop('_ROS_WHEELS_BOOTSTRAP_COMPLETE', None) is not None:
        env.pop('LD_LIBRARY_PATH', None)
    if domain_id is not None:
        env['ROS_DOMAIN_ID'] = str(domain_id)
    if localhost:
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.setdefault('PYTHONUNBUFFERED', '1')
    return env


class NodeProcess:
    """One node as a child process, its output in ``log_path``."""

    def __init__(self, name: str, *, params: dict | None = None,
                 params_file: str | Path | None = None, namespace: str | None = None,
                 remaps: dict[str, str] | None = None, domain_id: int | None = None,
                 log_path: str | Path | None = None, extra_args: list[str] | None = None,
                 node_params: dict[str, dict] | None = None):
        self.name = name
        ros_args = []
        if params_file:
            ros_args += ['--params-file', str(params_file)]
        sections = {**({name: params} if params else {}), **(node_params or {})}
        pass_fds: tuple[int, ...] = ()
        if sections:
            # '-p' overrides count as '/**' entries, which a params file's '/**/<node>'
            # section beats; a second file keyed by node name overrides both. A process
            # of several nodes (composed) gets a section per node (``node_params``). The
            # file lives in memory (memfd) and is handed to the child as an open file, so
            # nothing is left on disk whatever happens to either process.
            fd = os.memfd_create(f'{name}.params.yaml')
            os.write(fd, json.dumps({f'/**/{node}': {'ros__parameters': values}
                                     for node, values in sections.items()}).encode())
            pass_fds = (fd,)
            ros_args += ['--params-file', f'/proc/self/fd/{fd}']  # JSON is YAML
        if namespace:
            ros_args += ['-r', f'__ns:={namespace}']
        for src, dst in (remaps or {}).items():
            ros_args += ['-r', f'{src}:={dst}']
        self.cmd = executable(name) + (extra_args or []) + (
            ['--ros-args', *ros_args] if ros_args else [])
        self.log_path = Path(log_path) if log_path else None
        env = node_env(domain_id)
        env[PARENT_ENV] = str(os.getpid())  # the node exits when this process dies
        try:
            with open(self.log_path or os.devnull, 'wb') as out:
                self.proc = subprocess.Popen(self.cmd, env=env, stdout=out,
                                             stderr=subprocess.STDOUT,
                                             stdin=subprocess.DEVNULL, pass_fds=pass_fds)
        finally:
            for fd in pass_fds:
                os.close(fd)

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, sig: int = signal.SIGINT, timeout: float = 10.0) -> int:
        """Send ``sig``, wait up to ``timeout`` s, then kill; returns the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode

    def output(self) -> str:
        return self.log_path.read_text(errors='replace') if self.log_path else ''

