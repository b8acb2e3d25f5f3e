"""The keeper: runs a command so that nothing it starts outlives it (no rclpy, no numpy).

    python -m arm_sim.check.keeper [--parent PID] [--status-fd FD] [--lifeline]
                                   [--timeout S] -- CMD [ARGS...]

``arm-sim check`` starts the user's controller through it
(:class:`arm_sim.check.harness.ControllerProcess`). The keeper makes itself a child
subreaper (``prctl(PR_SET_CHILD_SUBREAPER)``), so a process the command starts stays its
descendant whatever it does: a double fork, ``setsid``, a new process group; orphans are
re-parented to the keeper, which reaps them. It starts CMD in a process group of its own
(stdin ``/dev/null``, its output the keeper's), then stops **every descendant** (found by
the parent links of /proc: SIGINT, up to ``--timeout`` s (default 5) for them to exit,
then SIGKILL until none is left) when

- it gets SIGTERM, SIGINT or SIGHUP;
- its parent ``--parent`` dies, however it dies (SIGKILL included): the kernel sends it
  SIGTERM (``prctl(PR_SET_PDEATHSIG)``; a parent already gone when that was asked means
  stop at once, without starting CMD);
- with ``--lifeline``: its stdin (a pipe from the parent) reads a line ``stop [S]`` (S:
  this stop's timeout [s]) or ends (the parent closed it, or died);
- without ``--status-fd``: CMD exits (what it left running is stopped with it).

With ``--status-fd FD`` it writes ``started <pid>`` (CMD's pid, also its process group)
and ``exited <code>`` (CMD's exit code; ``-N``: killed by signal N) on that pipe, and
keeps what CMD left running after CMD exits until it is told to stop: the parent decides.
When its parent died, it also waits for the nodes the parent started itself (those with
``ARM_SIM_PARENT_PID`` = its pid: the kernel sends them SIGTERM too) to exit, SIGKILL after
``--timeout`` s. After stopping everything it removes the Fast DDS shared-memory files
left by what had to be killed (or by the parent that died: it could not) and exits with
CMD's code (128 + N for a signal).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import select
import signal
import sys
import time
from collections.abc import Sequence

from arm_common.process import PARENT_ENV, become_subreaper, descendants, die_with_parent

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
DEFAULT_TIMEOUT = 5.0  # s: SIGINT to SIGKILL
KILL_ROUNDS = 200  # SIGKILL passes at most (each ~20 ms): a fork bomb is not our case


class Keeper:
    """One command and everything it starts; see the module's docstring."""

    def __init__(self, command: Sequence[str], status_fd: int | None = None,
                 lifeline: bool = False, timeout: float = DEFAULT_TIMEOUT) -> None:
        self.command = list(command)
        self.status_fd = status_fd
        self.lifeline = lifeline
        self.timeout = timeout
        self.pid = 0  # the command's
        self.code: int | None = None  # its exit code, once reaped
        self.stop_requested = False
        self.killed = False  # something had to be SIGKILLed
        self._wake_r, self._wake_w = os.pipe()
        for fd in (self._wake_r, self._wake_w):
            os.set_blocking(fd, False)
        signal.set_wakeup_fd(self._wake_w)
        for sig in STOP_SIGNALS:
            signal.signal(sig, self._on_stop_signal)
        signal.signal(signal.SIGCHLD, lambda *_: None)  # wakes the loop (wakeup fd)
        self._line = b''

    def _on_stop_signal(self, signum, frame) -> None:
        self.stop_requested = True

    def _say(self, line: str) -> None:
        if self.status_fd is None:
            return
        try:
            os.write(self.status_fd, (line + '\n').encode())
        except OSError:  # the reader is gone: the parent died
            self.stop_requested = True

    def start(self) -> bool:
        """Start the command (False: it cannot be run; exit code 127, said on stderr)."""
        env = dict(os.environ)
        # The keeper, not an arm_sim launcher, is its parent: an arm_sim node started by
        # the command (maybe not as the keeper's child) must not take the keeper's parent
        # for its own and stop at once (arm_common.process.watch_parent).
        env.pop(PARENT_ENV, None)
        devnull = os.open(os.devnull, os.O_RDONLY)
        try:
            # As subprocess does: the signals Python ignores back to their defaults.
            self.pid = os.posix_spawnp(self.command[0], self.command, env, setpgroup=0,
                                       file_actions=[(os.POSIX_SPAWN_DUP2, devnull, 0)],
                                       setsigdef=(signal.SIGPIPE, signal.SIGXFSZ))
        except OSError as exc:
            print(f'arm-sim check: cannot run {self.command[0]}: {exc.strerror or exc}',
                  file=sys.stderr, flush=True)
            self.code = 127
            self._say('exited 127')
            return False
        finally:
            os.close(devnull)
        self._say(f'started {self.pid}')
        return True

    def reap(self) -> None:
        """Collect every child that exited (the command, orphans re-parented to us)."""
        while True:
            try:
                pid, status = os.waitpid(-1, os.WNOHANG)
            except ChildProcessError:
                return
            if pid == 0:
                return
            if pid == self.pid and self.code is None:
                self.code = os.waitstatus_to_exitcode(status)
                self._say(f'exited {self.code}')

    def _wait_event(self, timeout: float) -> None:
        """Sleep until a signal (SIGCHLD included), a lifeline line or ``timeout`` s."""
        fds = [self._wake_r] + ([0] if self.lifeline else [])
        try:
            ready, _, _ = select.select(fds, [], [], timeout)
        except InterruptedError:
            return
        if self._wake_r in ready:
            try:
                while os.read(self._wake_r, 512):
                    pass
            except BlockingIOError:
                pass
        if self.lifeline and 0 in ready:
            self._read_lifeline()

    def _read_lifeline(self) -> None:
        try:
            data = os.read(0, 512)
        except OSError:
            data = b''
        if not data:  # closed: the parent is done with us, or gone
            self.lifeline = False
            self.stop_requested = True
            return
        self._line += data
        while b'\n' in self._line:
            line, self._line = self._line.split(b'\n', 1)
            words = line.decode(errors='replace').split()
            if words[:1] == ['stop']:
                if len(words) > 1:
                    try:
                        self.timeout = max(float(words[1]), 0.0)
                    except ValueError:
                        pass
                self.stop_requested = True

    def run(self) -> int:
        """Run until told to stop (or the command exits, without a status pipe), stop
        everything, clean up; the exit code."""
        if not self.stop_requested and self.start():
            while not self.stop_requested:
                self.reap()
                if self.code is not None and self.status_fd is None:
                    break  # standalone: the command is done, and so is what it left
                self._wait_event(1.0)
        self.stop_all(self.timeout)
        orphaned = os.getppid() != PARENT
        if orphaned:
            self.stop_siblings(self.timeout)
        if self.killed or orphaned:
            from arm_sim.launcher import remove_stale_shm

            remove_stale_shm()
        code = self.code if self.code is not None else 0
        return code if code >= 0 else 128 - code

    def stop_siblings(self, timeout: float) -> None:
        """After the parent's death: wait up to ``timeout`` s for the nodes it started
        itself (``ARM_SIM_PARENT_PID`` = its pid in their environment: the kernel sent
        them SIGTERM as it died, :func:`arm_common.process.watch_parent`) to exit, SIGKILL
        what is left, and wait for that too (up to 5 s), so that the shared-memory files
        are removed after the last of them."""
        end = time.monotonic() + timeout
        while self._siblings() and time.monotonic() < end:
            self._wait_event(0.05)
        left = self._siblings()
        for pid in left:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
                self.killed = True
        end = time.monotonic() + 5.0
        while left and self._siblings() and time.monotonic() < end:
            self._wait_event(0.05)

    @staticmethod
    def _siblings() -> list[int]:
        """Live processes (not zombies) whose environment says :data:`PARENT` started them."""
        mark = f'{PARENT_ENV}={PARENT}'.encode()
        found = []
        for name in os.listdir('/proc'):
            if not name.isdigit() or int(name) == os.getpid():
                continue
            try:
                with open(f'/proc/{name}/environ', 'rb') as f:
                    if mark not in f.read().split(b'\0'):
                        continue
                with open(f'/proc/{name}/stat') as f:
                    if f.read().rsplit(')', 1)[1].split()[0] == 'Z':
                        continue
            except (OSError, IndexError):
                continue
            found.append(int(name))
        return found

    def stop_all(self, timeout: float) -> None:
        """SIGINT to every descendant, up to ``timeout`` s for all to exit, then SIGKILL
        to whatever is left (again, until nothing is: one may fork meanwhile); each reaped."""
        self._signal_all(signal.SIGINT)
        end = time.monotonic() + timeout
        while True:
            self.reap()
            if not descendants() or time.monotonic() > end:
                break
            self._wait_event(0.02)
        for _ in range(KILL_ROUNDS):
            self.reap()
            if not self._signal_all(signal.SIGKILL):
                break
            self.killed = True
            self._wait_event(0.02)
        self.reap()

    @staticmethod
    def _signal_all(sig: int) -> list[int]:
        """Send ``sig`` to every live descendant; the ones it was sent to."""
        sent = []
        for pid in descendants():
            try:
                os.kill(pid, sig)
                sent.append(pid)
            except ProcessLookupError:
                continue
        return sent


PARENT = os.getppid()  # at import, before anything could re-parent us


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog='python -m arm_sim.check.keeper',
                                description=__doc__.split('\n\n', 1)[0])
    p.add_argument('--parent', type=int, default=None, metavar='PID',
                   help='stop everything when this process (our parent) dies')
    p.add_argument('--status-fd', type=int, default=None, metavar='FD')
    p.add_argument('--lifeline', action='store_true')
    p.add_argument('--timeout', type=float, default=DEFAULT_TIMEOUT, metavar='S')
    p.add_argument('cmd', nargs=argparse.REMAINDER)
    args = p.parse_args(argv)
    command = args.cmd[1:] if args.cmd[:1] == ['--'] else args.cmd
    if not command:
        p.error('no command given (after "--")')
    global PARENT
    if args.parent is not None:
        PARENT = args.parent
    if args.status_fd is not None:
        os.set_inheritable(args.status_fd, False)  # the command must not hold it
    keeper = Keeper(command, args.status_fd, args.lifeline, args.timeout)
    become_subreaper()
    # SIGTERM when the parent dies; a parent gone before we asked: stop at once.
    if not die_with_parent(signal.SIGTERM, PARENT) and os.getppid() != PARENT:
        keeper.stop_requested = True
    return keeper.run()


if __name__ == '__main__':
    sys.exit(main())
