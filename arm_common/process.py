"""Process manners shared by the nodes and their launcher (no rclpy)."""

from __future__ import annotations

import ctypes
import os
import signal
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
