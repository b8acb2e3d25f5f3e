"""Process manners shared by the nodes and their launcher (no rclpy)."""

from __future__ import annotations

import ctypes
import os
import signal
import socket
import sys

#: Set by the launcher (arm_sim.launcher.NodeProcess) to its pid; see :func:`watch_parent`.
PARENT_ENV = 'ARM_SIM_PARENT_PID'


def watch_parent() -> None:
    """A node started by arm_sim's launcher (``ARM_SIM_PARENT_PID`` set) asks the kernel
    for SIGTERM when that parent dies (``prctl(PR_SET_PDEATHSIG)``), so a killed ``arm-sim``
    (SIGKILL included) takes its nodes with it and each still closes cleanly (the recorder
    its bag). A parent that is already gone means stop now. Linux only; elsewhere a no-op.
    """
    parent = os.environ.get(PARENT_ENV)
    if not parent or not sys.platform.startswith('linux'):
        return
    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM, 0, 0, 0)  # 1: PDEATHSIG
    except (OSError, AttributeError):
        return
    if str(os.getppid()) != parent:
        os.kill(os.getpid(), signal.SIGTERM)


_claimed: list[socket.socket] = []  # held for the life of the process


def claim_domain(start: int, first: int = 1, last: int = 232) -> int:
    """A ROS domain id that no other arm_sim process on this machine holds, trying ``start``
    first, then the next ones (wrapping within ``first``..``last``).

    The claim is an abstract Unix socket named after the id (Linux): no file, and the kernel
    frees it when the process exits, however it exits. Two test sessions, a demo and a
    benchmark started side by side therefore never share a domain (sharing one made each
    see the other's simulator). Elsewhere, or if every id is held, ``start`` is returned.
    """
    span = last - first + 1
    for k in range(span):
        domain = first + (start - first + k) % span
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            sock.bind(f'\0arm_sim_ros_domain_{domain}')
        except OSError:
            sock.close()
            continue
        _claimed.append(sock)
        return domain
    return start


def stop_child(proc, sig: int = signal.SIGINT, timeout: float = 10.0) -> int:
    """Stop the child ``proc`` (a :class:`subprocess.Popen`): send ``sig`` if it still
    runs, wait up to ``timeout`` s, then kill it; returns its exit code."""
    import subprocess

    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    return proc.returncode
