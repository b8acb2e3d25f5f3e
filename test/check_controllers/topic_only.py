"""A third party's controller for ``arm-sim check``: topics only, as a plain ros2 node.

It subscribes ``joint_states`` and ``arm_controller/joint_trajectory`` (no arm_sim import,
no ``check/reference``), samples each trajectory itself (quintic Hermite between points,
from the state it was received at, header.stamp = start, 0 = on arrival, as
joint_trajectory_controller does) and answers every state it receives with a computed-torque
command on ``effort_controller/commands``. It gives no verdicts on
``arm_controller/trajectory_status`` and does not tag its commands: nothing tells the
harness or the simulator whether it got a trajectory or which state a command answers.
``test/test_check.py`` checks that such a controller passes the lecture suite, with the same
report each time, under load.
"""

import math
import sys

import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import JointTrajectory

JOINTS = ('joint1', 'joint2')
# The arm of arm_sim's config/arm.yaml (SI units) and the gains (1/s^2, 1/s).
L1, C1, C2, M1, M2, I1, I2, G = 1.0, 0.5, 0.4, 2.0, 1.5, 0.1, 0.08, 9.81
KP, KD = np.array([100.0, 60.0]), np.array([20.0, 12.0])


def torque(q, qd, qdd_ref):
    """tau = D(q) qdd_ref + C(q, qd) qd + g(q) of the 2-R arm [N m]."""
    a = I1 + I2 + M1 * C1 ** 2 + M2 * (L1 ** 2 + C2 ** 2)
    b, d = M2 * L1 * C2, I2 + M2 * C2 ** 2
    c2, s2 = math.cos(q[1]), math.sin(q[1])
    mass = np.array([[a + 2 * b * c2, d + b * c2], [d + b * c2, d]])
    h = -b * s2
    cor = np.array([[h * qd[1], h * (qd[0] + qd[1])], [-h * qd[0], 0.0]])
    g1 = (M1 * C1 + M2 * L1) * G * math.cos(q[0]) + M2 * C2 * G * math.cos(q[0] + q[1])
    grav = np.array([g1, M2 * C2 * G * math.cos(q[0] + q[1])])
    return mass @ qdd_ref + cor @ qd + grav


def hermite(t, t0, t1, p0, v0, a0, p1, v1, a1):
    """Quintic Hermite between (p0, v0, a0) at t0 and (p1, v1, a1) at t1: (p, v, a) at t."""
    h = t1 - t0
    s = (t - t0) / h
    coeffs = np.linalg.solve(np.array([
        [1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0], [0, 0, 2, 0, 0, 0],
        [1, 1, 1, 1, 1, 1], [0, 1, 2, 3, 4, 5], [0, 0, 2, 6, 12, 20]], dtype=float),
        np.array([p0, v0 * h, a0 * h * h, p1, v1 * h, a1 * h * h]))
    powers = np.array([s ** k for k in range(6)])
    dpow = np.array([k * s ** (k - 1) if k else 0.0 for k in range(6)])
    ddpow = np.array([k * (k - 1) * s ** (k - 2) if k > 1 else 0.0 for k in range(6)])
    return powers @ coeffs, dpow @ coeffs / h, ddpow @ coeffs / (h * h)


class TopicOnly(Node):
    def __init__(self):
        super().__init__('topic_only_controller')
        self.latest = None  # (t [s], q, qd)
        self.traj = None  # (start s or None = on arrival, times, pos, vel, acc)
        self.pub = self.create_publisher(Float64MultiArray, 'effort_controller/commands', 10)
        self.create_subscription(JointState, 'joint_states', self.on_state, 10)
        self.create_subscription(JointTrajectory, 'arm_controller/joint_trajectory',
                                 self.on_trajectory, 10)

    def on_trajectory(self, msg):
        order = [list(msg.joint_names).index(j) for j in JOINTS]
        times = [p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in msg.points]
        pos = [[p.positions[i] for i in order] for p in msg.points]
        vel = [[p.velocities[i] for i in order] if p.velocities else [0.0, 0.0]
               for p in msg.points]
        acc = [[p.accelerations[i] for i in order] if p.accelerations else [0.0, 0.0]
               for p in msg.points]
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        t, q, qd = self.latest if self.latest else (0.0, np.array(pos[0]), np.zeros(2))
        # The state it was received at is its point at time 0 (unless a point is there).
        if times[0] > 0.0:
            times, pos, vel, acc = [0.0] + times, [q] + pos, [qd] + vel, [np.zeros(2)] + acc
        self.traj = (stamp or None, np.array(times), np.array(pos, dtype=float),
                     np.array(vel, dtype=float), np.array(acc, dtype=float))

    def reference(self, t, q):
        if self.traj is None:
            return q, np.zeros(2), np.zeros(2)
        start, times, pos, vel, acc = self.traj
        if start is None:  # on arrival: from this state on
            start = t
            self.traj = (start, times, pos, vel, acc)
        tau = t - start
        if tau <= times[0]:
            return pos[0], vel[0], acc[0]
        if tau >= times[-1]:
            return pos[-1], np.zeros(2), np.zeros(2)
        k = int(np.searchsorted(times, tau, side='right')) - 1
        return hermite(tau, times[k], times[k + 1], pos[k], vel[k], acc[k], pos[k + 1],
                       vel[k + 1], acc[k + 1])

    def on_state(self, msg):
        order = [list(msg.name).index(j) for j in JOINTS]
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        q = np.array([msg.position[i] for i in order])
        qd = np.array([msg.velocity[i] for i in order])
        if self.latest is not None and t < self.latest[0]:  # a new simulation
            self.traj = None
        self.latest = (t, q, qd)
        q_ref, qd_ref, qdd_ref = self.reference(t, q)
        u = qdd_ref + KD * (qd_ref - qd) + KP * (q_ref - q)
        self.pub.publish(Float64MultiArray(data=torque(q, qd, u).tolist()))


def main():
    rclpy.init()
    node = TopicOnly()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
