"""``arm-sim``: the terminal front end of arm_sim (works in a plain venv, no ros2 CLI).

Sub-commands print one line and exit non-zero on error, never a traceback.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from arm_sim.launcher import NodeProcess, config_file

EXIT_ERROR = 1


class CliError(Exception):
    """A user-facing failure: printed as one line, exit code 1."""


def _domain(args: argparse.Namespace) -> int:
    return args.domain_id if args.domain_id is not None else int(
        os.environ.get('ROS_DOMAIN_ID', '0'))


def cmd_demo(args: argparse.Namespace) -> int:
    """Release the arm under gravity in the simulator and report what it did."""
    import rclpy
    from sensor_msgs.msg import JointState
    from std_srvs.srv import Trigger

    from arm_dynamics import TwoLinkArm

    domain = _domain(args)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    log_dir = args.log_dir
    os.makedirs(log_dir, exist_ok=True)
    print(f'arm-sim demo: starting the simulator (ROS domain {domain}, localhost only; '
          f'logs in {log_dir}/)')
    sim = NodeProcess('simulator', params_file=config_file(), domain_id=domain,
                      params={'timing_mode': 'real_time', 'command_timeout': 0.0,
                              'real_time_factor': args.real_time_factor},
                      log_path=os.path.join(log_dir, 'simulator.log'))
    rclpy.init(domain_id=domain)
    node = rclpy.create_node('arm_sim_demo')
    states: list = []
    node.create_subscription(JointState, 'joint_states', states.append, 1000)
    try:
        deadline = time.monotonic() + 30.0
        while not states:
            if not sim.alive():
                raise CliError(f'the simulator exited: {sim.output().strip()[-500:]}')
            if time.monotonic() > deadline:
                raise CliError('no joint_states from the simulator within 30 s')
            rclpy.spin_once(node, timeout_sec=0.1)
        # The simulator started before we listened: reset it so we watch the whole release.
        client = node.create_client(Trigger, 'simulator/reset')
        if not client.wait_for_service(timeout_sec=10.0):
            raise CliError('the simulator offers no reset service')
        future = client.call_async(Trigger.Request())
        rclpy.spin_until_future_complete(node, future, timeout_sec=10.0)
        if not (future.done() and future.result().success):
            raise CliError('the simulator did not reset')
        t0 = _stamp(states[-1])
        start = len(states) - 1
        print('  the arm is released from rest under gravity, no torque applied')
        shown, progress = t0, (time.monotonic(), t0)
        while _stamp(states[-1]) < t0 + args.duration:
            rclpy.spin_once(node, timeout_sec=0.1)
            if not sim.alive():
                raise CliError('the simulator exited unexpectedly; see its log')
            t = _stamp(states[-1])
            if t > progress[1]:
                progress = (time.monotonic(), t)
            elif time.monotonic() - progress[0] > 10.0:
                raise CliError(f'simulated time stopped at {t:.2f} s; see {sim.log_path}')
            if t >= shown + 0.5:
                shown = t
                q = states[-1].position
                print(f'  t = {t - t0:4.1f} s   q1 = {q[0]:+.3f} rad   q2 = {q[1]:+.3f} rad')
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        code = sim.stop()
    _report_release(states[start:], TwoLinkArm())
    if code not in (0, -2):
        raise CliError(f'the simulator exited with code {code}; see {sim.log_path}')
    return 0


def _stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def _report_release(states: list, arm) -> None:
    t = np.array([_stamp(m) for m in states])
    q = np.array([m.position for m in states])
    qd = np.array([m.velocity for m in states])
    kinetic, potential = arm.energy(q, qd)
    total = kinetic + potential
    tip = arm.forward_kinematics(q)
    print(f'\nwhat the arm did over {t[-1] - t[0]:.2f} s of simulated time '
          f'({len(states)} joint states):')
    print(f'  shoulder q1 swung between {q[:, 0].min():+.3f} and {q[:, 0].max():+.3f} rad; '
          f'elbow q2 between {q[:, 1].min():+.3f} and {q[:, 1].max():+.3f} rad')
    print(f'  fastest joint speed {np.abs(qd).max():.2f} rad/s; the tip fell to '
          f'y = {tip[:, 1].min():+.3f} m (started at y = {tip[0, 1]:+.3f} m)')
    drift = np.abs(total - total[0]).max()
    print(f'  total energy {total[0]:.4f} J at the start, drift {drift:.2e} J '
          f'({drift / max(abs(total[0]), kinetic.max()):.1e} relative: energy is conserved '
          'with no damping and no torque)')


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='arm-sim', description='arm_sim: a simulated 2-R robot arm on ROS 2 Jazzy. '
        'Runs the nodes as processes; no ros2 command line needed.')
    sub = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    demo = sub.add_parser(
        'demo', help='run the demo and print what happened',
        description='Start the simulator, release the arm under gravity, print its motion '
        'and check that energy is conserved.')
    demo.add_argument('--duration', type=float, default=3.0,
                      help='simulated time to run [s] (default 3)')
    demo.add_argument('--real-time-factor', type=float, default=1.0,
                      help='simulated seconds per wall second (default 1)')
    demo.add_argument('--domain-id', type=int, default=None,
                      help='ROS_DOMAIN_ID to use (default: $ROS_DOMAIN_ID or 0)')
    demo.add_argument('--log-dir', default='runs/logs',
                      help='where node logs go (default runs/logs)')
    demo.set_defaults(func=cmd_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except CliError as exc:
        print(f'arm-sim {args.command}: {exc}', file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f'arm-sim {args.command}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    raise SystemExit(main())
