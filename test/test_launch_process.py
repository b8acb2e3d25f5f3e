"""The process tree ``ros2 launch arm_sim arm.launch.py`` makes, without ROS's launch
packages (PyPI has none): a parent process loads the launch file (against the stand-ins of
test_launch_file.py) and starts its arm_sim nodes with the environment the file gives them,
as launch does; killing that parent by any signal must take every node with it, and the
recorder must close its bag."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from sensor_msgs.msg import JointState
from test_suite import running

ROOT = Path(__file__).resolve().parents[1]

#: The parent: load the launch file as launch would, start the simulator and the recorder
#: it describes (executable, additional_env) as children, print their pids, wait.
PARENT = r'''
import os, subprocess, sys, time
sys.path.insert(0, sys.argv[1])
import test_launch_file as t
for name, mod in t.stand_ins().items():
    sys.modules[name] = mod
import importlib.util
spec = importlib.util.spec_from_file_location('arm_launch', t.LAUNCH_FILE)
module = importlib.util.module_from_spec(spec)
spec.loader.exec_module(module)
pids = []
for node in t.arm_sim_nodes(module):
    exe = node.kwargs['executable']
    if exe not in ('simulator', 'recorder'):
        continue
    args = [os.path.join(os.path.dirname(sys.executable), exe), '--ros-args',
            '--params-file', str(t.CONFIG), '-p', 'timing_mode:=lockstep']
    if exe == 'recorder':
        args += ['-p', f'output:={sys.argv[2]}']
    env = {**os.environ, **node.kwargs['additional_env']}
    pids.append(subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL,
                                 stderr=subprocess.DEVNULL).pid)
print(' '.join(map(str, pids)), flush=True)
time.sleep(3600)
'''


@pytest.mark.parametrize('sig', [signal.SIGKILL, signal.SIGTERM], ids=lambda s: s.name)
def test_nodes_of_a_launch_die_with_the_launch_process_and_the_bag_is_closed(ros, tmp_path,
                                                                             sig):
    states = ros.collect(JointState, 'joint_states')
    bag = tmp_path / 'bag'
    parent = subprocess.Popen([sys.executable, '-c', PARENT, str(ROOT / 'test'), str(bag)],
                              stdout=subprocess.PIPE, text=True, env=os.environ.copy())
    try:
        assert parent.stdout is not None
        pids = [int(p) for p in parent.stdout.readline().split()]
        assert len(pids) == 2, pids
        ros.wait_for(lambda: states, timeout=60, what="the launched simulator's state")
        ros.wait_for(lambda: (bag / 'metadata.yaml').is_file(), timeout=60,
                     what='the launched recorder to open its bag')
    finally:
        parent.send_signal(sig)
        parent.wait()
    ros.wait_for(lambda: not any(running(p) for p in pids), timeout=30,
                 what=f'every node to exit after its launch process got {sig.name}')
    meta = (bag / 'metadata.yaml').read_text()
    assert 'arm_sim.recording: closed' in meta, 'the recorder closed its bag on SIGTERM'
