"""Start and stop arm_sim node processes (no rclpy): used by ``arm-sim`` and the tests.

An executable is found the way ``ros2 run`` finds it (``<prefix>/lib/arm_sim/<exe>`` via
the ament index) when arm_sim is installed in a ROS workspace, else as the console script
next to this Python (a pip venv), else as ``python -m <module>``.

Also what a run does before it starts its nodes: hold its explicit ROS domain
(:func:`claim_explicit_domain`) and remove the Fast DDS shared-memory files of processes
that are gone (:func:`remove_stale_shm`).
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from arm_common.process import PARENT_ENV, stop_child

MODULES = {
    'simulator': 'arm_dynamics.simulator_node',
    'controller': 'arm_control.controller_node',
    'planner': 'arm_planner.planner_node',
    'recorder': 'arm_bag.recorder_node',
    'composed': 'arm_sim.composed',  # simulator + controller in one process
    'live': 'arm_sim.live_node',  # the Foxglove WebSocket bridge (--foxglove)
    'visualizer': 'arm_sim.visualizer_node',  # markers and robot_description
    # arm-sim check: the reference stream for the user's controller (check/reference)
    'check_reference': 'arm_sim.check.reference_node',
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


def config_file(name: str = 'arm.yaml') -> Path:
    """A shipped file of ``config/`` (default ``arm.yaml``; ``real_arm.yaml`` the real-arm
    set): from the install's share/ or the source tree."""
    candidates = [Path(p) / 'share' / 'arm_sim' / 'config' / name
                  for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    candidates += [Path(sys.prefix) / 'share' / 'arm_sim' / 'config' / name,
                   Path(__file__).resolve().parents[1] / 'config' / name]
    for c in candidates:
        if c.is_file():
            return c
    raise FileNotFoundError(f'config/{name} not found; looked in: '
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


#: The nodes whose first messages wait for the recorder in a recorded run (``wait_for_nodes:
#: [recorder]``, :mod:`arm_common.gate`) and the topics each gates.
GATED = {'simulator': ('joint_states', 'clock'),
         'controller': ('effort_controller/commands', 'arm_controller/reference'),
         'visualizer': ('markers', 'tf')}


def recorder_gates(params_file: str | Path | None) -> dict[str, dict]:
    """Per-node parameter overrides that make the simulator, controller and visualizer of a
    recorded run send nothing until the recorder has matched them, so the bag holds their
    first messages (a node started after the recorder may otherwise publish before the
    recorder's subscription reaches it; those messages are counted lost). Only nodes all
    of whose gated topics the recorder records: when ``params_file`` sets the recorder's
    ``topics``, a node it leaves out is not gated (it would wait for nothing)."""
    import yaml

    from arm_bag.topics import DEFAULT_TOPICS

    topics = set(DEFAULT_TOPICS)
    if params_file:
        try:
            data = yaml.safe_load(Path(params_file).read_text()) or {}
        except (OSError, yaml.YAMLError):
            data = {}
        for key, section in (data.items() if isinstance(data, dict) else ()):
            values = section.get('ros__parameters') if isinstance(section, dict) else None
            if (str(key).rstrip('/').endswith(('recorder', '/**')) or key == '/**') \
                    and isinstance(values, dict) and isinstance(values.get('topics'), list):
                topics = {str(t).lstrip('/') for t in values['topics']}
    return {node: {node: {'wait_for_nodes': ['recorder']}} for node, gated in GATED.items()
            if all(t in topics for t in gated)}


class NodeProcess:
    """One node as a child process, its output in ``log_path``."""

    def __init__(self, name: str, *, params: dict | None = None,
                 params_file: str | Path | Sequence[str | Path] | None = None,
                 namespace: str | None = None,
                 remaps: dict[str, str] | None = None, domain_id: int | None = None,
                 log_path: str | Path | None = None, extra_args: list[str] | None = None,
                 node_params: dict[str, dict] | None = None):
        self.name = name
        ros_args = []
        files = [params_file] if isinstance(params_file, (str, Path)) else params_file or []
        for f in files:  # a later file's value wins (rcl reads them in order)
            ros_args += ['--params-file', str(f)]
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
        return stop_child(self.proc, sig, timeout)

    def output(self) -> str:
        return self.log_path.read_text(errors='replace') if self.log_path else ''



# ---------------------------------------------------------------------- the ROS domain
class DomainInUse(Exception):
    """The explicit ROS domain is held by another arm_sim run; the message says which."""


#: The abstract Unix socket :func:`arm_common.process.claim_domain` binds to hold a domain
#: (test_process.py checks both claims exclude each other).
DOMAIN_CLAIM = '\0arm_sim_ros_domain_{}'
_explicit: list[socket.socket] = []  # held for the life of the process


def _parent(pid: int) -> int | None:
    try:
        return int(Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[1])
    except (OSError, IndexError, ValueError):
        return None


def ancestors(pid: int | None = None) -> list[int]:
    """``pid`` (default: this process) and its parent, grandparent ... up to init."""
    chain: list[int] = []
    current: int | None = os.getpid() if pid is None else pid
    while current and current not in chain:
        chain.append(current)
        current = _parent(current)
    return chain


def domain_holder(domain: int) -> int | None:
    """The pid of a process holding ``domain``'s claim (an arm_sim run, a test session);
    None if none is found (not held, or held by a process this user cannot see)."""
    name = '@' + DOMAIN_CLAIM.format(domain)[1:]
    try:
        lines = Path('/proc/net/unix').read_text().splitlines()[1:]
    except OSError:
        return None
    inodes = {f'socket:[{fields[6]}]' for fields in (line.split() for line in lines)
              if len(fields) >= 8 and fields[7] == name}
    if not inodes:
        return None
    for proc in Path('/proc').iterdir():
        if not proc.name.isdigit():
            continue
        try:
            if any(os.readlink(fd) in inodes for fd in (proc / 'fd').iterdir()):
                return int(proc.name)
        except OSError:
            continue
    return None


def _describe(pid: int) -> str:
    try:
        argv = Path(f'/proc/{pid}/cmdline').read_bytes().split(b'\0')
    except OSError:
        return f'pid {pid}'
    words = [a.decode(errors='replace') for a in argv if a]
    if words and Path(words[0]).name.startswith('python'):
        words = words[1:]
    return f"pid {pid}: {' '.join(' '.join(words).split())[:120]}"  # one line


def claim_explicit_domain(domain: int) -> None:
    """Hold ROS domain ``domain`` (one the user chose) for this process, as
    :func:`arm_common.process.claim_domain` holds the automatic ones, so no second arm_sim
    run (demo, bringup, bench, test session) starts on it: two suites on one domain see
    each other's simulator and fail with misleading reasons. A claim held by this process
    or one of its ancestors (a test session that claimed the domain and runs demos on it,
    a script that did) is this run's own.

    Raises
    ------
    DomainInUse
        Another run holds it; the message names that process.
    """
    for _ in range(3):  # a holder that exits meanwhile frees the id: try again
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            sock.bind(DOMAIN_CLAIM.format(domain))
        except OSError:
            sock.close()
        else:
            _explicit.append(sock)
            return
        holder = domain_holder(domain)
        if holder is None:
            continue
        if holder in ancestors():
            return
        raise DomainInUse(f'ROS domain {domain} is in use by another arm_sim run '
                          f'({_describe(holder)}); stop it, choose another --domain-id or '
                          'leave it out for a free one')
    raise DomainInUse(f'ROS domain {domain} is in use by another arm_sim run (a process '
                      'this user cannot see); choose another --domain-id or leave it out '
                      'for a free one')


# ---------------------------------------------------------------------- shared memory
SHM_DIR = Path('/dev/shm')
#: Fast DDS's lock files in /dev/shm: a participant's segment ``fastrtps_<16 hex>`` (Fast
#: DDS 2; ``fastdds_`` in 3) and a port ``fastrtps_port<N>`` each have an ``_el`` (or
#: ``_sl``) file that its live owner keeps locked (flock), as ``fastdds shm clean`` reads it.
_SHM_LOCK = re.compile(r'^(fastrtps|fastdds)_(port\d{1,5}|[0-9a-f]{16})_(el|sl)$')
#: A port's named mutex (a POSIX semaphore) without its port.
_SHM_MUTEX = re.compile(r'^sem\.(fastrtps|fastdds)_port(\d{1,5})_mutex$')
#: How old an orphaned port mutex must be to be removed: a port being created has one
#: for a moment before its files.
MUTEX_AGE = 60.0  # s
#: A port segment ``fastrtps_port<N>`` without any lock file: its listener closed (and
#: removed its lock) while a process that had opened the port to write to it was killed,
#: so Fast DDS's count of the port's users never reaches 0 and nobody removes it (what a
#: SIGKILLed ``arm-sim check`` leaves). Removed once unmapped, unopened and this old
#: (its mtime: the segment's creation; mapped writes do not change it): a port being
#: created is mapped by its creator at once.
_SHM_PORT = re.compile(r'^(fastrtps|fastdds)_port\d{1,5}$')
LOCKLESS_AGE = 5.0  # s


def shm_in_use(shm_dir: Path = SHM_DIR) -> set[str]:
    """Names of the files in ``shm_dir`` some live process maps or has open (as far as
    /proc shows this user)."""
    prefix = str(shm_dir).rstrip('/') + '/'
    used: set[str] = set()
    for proc in Path('/proc').iterdir():
        if not proc.name.isdigit():
            continue
        try:
            for line in (proc / 'maps').read_text().splitlines():
                path = line.split(maxsplit=5)[5:]
                if path and path[0].startswith(prefix):
                    used.add(path[0][len(prefix):].removesuffix(' (deleted)'))
            for fd in (proc / 'fd').iterdir():
                target = os.readlink(fd)
                if target.startswith(prefix):
                    used.add(target[len(prefix):])
        except OSError:  # gone meanwhile, or not ours to read
            continue
    return used


def _locked(path: Path) -> tuple[int | None, bool]:
    """Open ``path`` and try to lock it as its owner does: (fd holding our lock, False) if
    nobody holds it, (None, True) if a live owner does, (None, False) if it is gone."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except FileNotFoundError:
        return None, False
    except OSError:
        return None, True  # not ours to judge
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return None, True
    return fd, False


def remove_stale_shm(shm_dir: Path = SHM_DIR) -> list[str]:
    """Remove the Fast DDS shared-memory files whose owners are gone (a suite killed with
    SIGKILL cannot remove its own) and return their names.

    A segment or port is stale when no live process holds the lock of its ``_el``/``_sl``
    file (Fast DDS's own rule, as ``fastdds shm clean`` applies it) and none maps or has
    open any of its files (/proc/*/maps and fd; a process that still talks to a dead port
    maps it, and keeps it). Its files go together: the segment or port, its lock files and
    a port's mutex ``sem.fastrtps_port<N>_mutex``, the locks held by us while they are
    removed. A port left without any lock file goes once it is :data:`LOCKLESS_AGE` s old
    and unused. A port mutex left without its port goes once it is :data:`MUTEX_AGE` s old
    and unmapped. Files of other users and anything not Fast DDS's are left alone."""
    try:
        names = set(os.listdir(shm_dir))
    except OSError:
        return []
    locks = sorted(n for n in names if _SHM_LOCK.match(n))
    mutexes = [n for n in names if _SHM_MUTEX.match(n)]
    ports = sorted(n for n in names if _SHM_PORT.match(n))
    if not locks and not mutexes and not ports:
        return []
    used = shm_in_use(shm_dir)
    removed: list[str] = []
    seen: set[str] = set()
    for lock in locks:
        base = lock[:-3]
        if base in seen:
            continue
        seen.add(base)
        family = [base, f'{base}_el', f'{base}_sl']
        if '_port' in base:
            family.append(f'sem.{base}_mutex')
        if any(f in used for f in family):
            continue
        fds: list[int] = []
        try:
            for f in family[1:3]:
                fd, busy = _locked(shm_dir / f)
                if busy:
                    break
                if fd is not None:
                    fds.append(fd)
            else:
                for f in family:
                    try:
                        (shm_dir / f).unlink()
                        removed.append(f)
                    except FileNotFoundError:
                        pass
                    except OSError:
                        break  # not ours to remove
        finally:
            for fd in fds:
                os.close(fd)
    now = time.time()
    for base in ports:
        if (f'{base}_el' in names or f'{base}_sl' in names or base in used
                or base in removed):
            continue
        try:
            if now - (shm_dir / base).stat().st_mtime < LOCKLESS_AGE:
                continue
            (shm_dir / base).unlink()
            removed.append(base)
        except OSError:
            continue
        names.discard(base)  # its mutex, unused, goes below once old enough
    for mutex in mutexes:
        port = mutex[len('sem.'):-len('_mutex')]
        path = shm_dir / mutex
        try:
            if (port in names or mutex in used
                    or now - path.stat().st_mtime < MUTEX_AGE or mutex in removed):
                continue
            path.unlink()
            removed.append(mutex)
        except OSError:
            continue
    return removed
