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
    if not _prctl(PR_SET_PDEATHSIG, signal.SIGTERM):
        return
    if str(os.getppid()) != parent:
        os.kill(os.getpid(), signal.SIGTERM)


PR_SET_PDEATHSIG = 1
PR_SET_CHILD_SUBREAPER = 36


def _prctl(option: int, value: int) -> bool:
    """``prctl(option, value)``; False where it is not available or fails (not Linux)."""
    if not sys.platform.startswith('linux'):
        return False
    try:
        return ctypes.CDLL(None, use_errno=True).prctl(option, value, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def die_with_parent(sig: int, parent: int) -> bool:
    """Ask the kernel for signal ``sig`` when the parent dies (``PR_SET_PDEATHSIG``; it
    fires when the parent *thread* that started this process exits, SIGKILL included);
    False if the parent ``parent`` is already gone (re-parented before the request: the
    signal would never come) or the request failed."""
    return _prctl(PR_SET_PDEATHSIG, sig) and os.getppid() == parent


def become_subreaper() -> bool:
    """Make this process a child subreaper (``PR_SET_CHILD_SUBREAPER``): a descendant
    orphaned by its parent (a double fork, a ``setsid`` daemon) is re-parented to this
    process instead of init, so it stays among :func:`descendants`. False if unavailable."""
    return _prctl(PR_SET_CHILD_SUBREAPER, 1)


def _process_table() -> dict[int, tuple[int, str]]:
    """pid: (parent pid, state letter) of every process /proc lists."""
    table = {}
    for name in os.listdir('/proc'):
        if not name.isdigit():
            continue
        try:
            with open(f'/proc/{name}/stat') as f:
                fields = f.read().rsplit(')', 1)[1].split()
            table[int(name)] = (int(fields[1]), fields[0])
        except (OSError, IndexError, ValueError):
            continue  # gone meanwhile
    return table


def descendants(pid: int | None = None, zombies: bool = False) -> list[int]:
    """The children of ``pid`` (default: this process), theirs and so on, by the parent
    links of /proc/<pid>/stat, whatever their session or process group; zombies (exited,
    not yet reaped) only with ``zombies``. Empty where there is no /proc."""
    root = os.getpid() if pid is None else pid
    try:
        table = _process_table()
    except OSError:
        return []
    children: dict[int, list[int]] = {}
    for p, (ppid, _) in table.items():
        children.setdefault(ppid, []).append(p)
    found: list[int] = []
    todo = list(children.get(root, ()))
    while todo:
        p = todo.pop()
        if p in found:
            continue
        found.append(p)
        todo.extend(children.get(p, ()))
    return [p for p in found if zombies or table[p][1] != 'Z']


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
