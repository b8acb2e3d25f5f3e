"""A bad controller for ``arm-sim check``'s tests: topics only (rclpy), no arm_sim import.

    python3 bad.py BEHAVIOUR

BEHAVIOUR is one of
  silent        subscribes joint_states, never publishes
  nan           answers each state with [nan, nan]
  wrong_length  answers each state with 3 values (the arm has 2 joints)
  crash         at the first state starts a child in its process group (``orphan``,
                which waits for a signal) and dies of an uncaught exception (exit code 1)
  slow          answers each state with zero torque after 0.2 s (wall)
  good          runs the example controller (examples/arm_check_example)
  scenario      the behaviour named by $ARM_SIM_CHECK_SCENARIO (set by the harness):
                one check run with scenarios named after behaviours tries them all
"""

import ctypes
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

BEHAVIOURS = ('silent', 'nan', 'wrong_length', 'crash', 'slow', 'good')
EXAMPLE = (Path(__file__).resolve().parents[2] / 'examples' / 'arm_check_example'
           / 'arm_check_example' / 'controller.py')
SLOW = 0.2  # s (wall) per answer


def main(behaviour: str) -> int:
    if behaviour == 'scenario':
        behaviour = os.environ.get('ARM_SIM_CHECK_SCENARIO', '')
    if behaviour == 'orphan':  # the crash's child: waits until it is signalled
        signal.pause()
        return 0
    if behaviour not in BEHAVIOURS:
        print(f'bad.py: unknown behaviour {behaviour!r} (one of {", ".join(BEHAVIOURS)})',
              file=sys.stderr)
        return 2
    if behaviour == 'good':
        os.execv(sys.executable, [sys.executable, str(EXAMPLE)])
    # Die with the harness if it is killed (a failed test must not leave this running).
    ctypes.CDLL(None).prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG

    import rclpy
    from rclpy.executors import ExternalShutdownException
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    rclpy.init()
    node = rclpy.create_node(f'bad_controller_{behaviour}')
    pub = node.create_publisher(Float64MultiArray, 'effort_controller/commands', 10)
    answer = {'nan': [math.nan, math.nan], 'wrong_length': [0.0, 0.0, 0.0],
              'slow': [0.0, 0.0]}.get(behaviour)

    def on_state(msg: JointState) -> None:
        if behaviour == 'crash':
            child = subprocess.Popen([sys.executable, __file__, 'orphan'])
            print(f'bad.py: left a child running, pid {child.pid}', flush=True)
            raise RuntimeError('bad.py crashes on purpose at the first state')
        if behaviour == 'slow':
            time.sleep(SLOW)
        if answer is not None:
            pub.publish(Float64MultiArray(data=answer))

    node.create_subscription(JointState, 'joint_states', on_state, 10)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else ''))
