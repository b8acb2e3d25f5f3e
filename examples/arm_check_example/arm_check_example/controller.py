"""Computed-torque control of the 2-R arm, over topics only (no arm_sim import).

Subscribes joint_states (sensor_msgs/JointState: position rad, velocity rad/s) and
check/reference (JointState stamped like the state it belongs to: position, velocity,
effort = q, q', q'' of the reference), and for each state answers on
effort_controller/commands (std_msgs/Float64MultiArray, N m, joint_states.name order):

    tau = D(q) (q''_ref + SIGN (Kd (q'_ref - q') + Kp (q_ref - q))) + C(q, q') q' + g(q)

The command is tagged with the state it answers (layout.dim[0].label =
"joint_states@SEC.NANOSEC", optional: it keeps a lockstep run exact when a state is re-sent).

Run: python3 controller.py [--ros-args -p kp:="[100.0, 60.0]" ...], or ros2 run
arm_check_example controller after a colcon build.
"""

import math

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

SIGN = 1.0  # the feedback's sign (test/test_check.py makes a copy with -1: unstable)


class ComputedTorque(Node):
    def __init__(self):
        super().__init__('ct_controller')
        # The arm of arm_sim's config/arm.yaml: SI units.
        p = {'link_lengths': [1.0, 0.8], 'com_distances': [0.5, 0.4],
             'link_masses': [2.0, 1.5], 'link_inertias': [0.1, 0.08], 'gravity': 9.81,
             'kp': [100.0, 60.0], 'kd': [20.0, 12.0]}  # gains: 1/s^2, 1/s
        self.p = {k: self.declare_parameter(k, v).value for k, v in p.items()}
        (l1, _), (c1, c2), (m1, m2), (i1, i2) = (self.p[k] for k in (
            'link_lengths', 'com_distances', 'link_masses', 'link_inertias'))
        self.a = i1 + i2 + m1 * c1 ** 2 + m2 * (l1 ** 2 + c2 ** 2)
        self.b = m2 * l1 * c2
        self.d = i2 + m2 * c2 ** 2
        g = self.p['gravity']
        self.g1, self.g2 = (m1 * c1 + m2 * l1) * g, m2 * c2 * g
        self.state = None  # the latest JointState not yet answered
        self.refs = {}  # stamp (ns) -> reference (q, qd, qdd) by joint name
        self.last = None  # (stamp, command): a re-sent state gets the same command
        self.pub = self.create_publisher(Float64MultiArray, 'effort_controller/commands', 10)
        self.create_subscription(JointState, 'joint_states', self.on_state, 10)
        self.create_subscription(JointState, 'check/reference', self.on_reference, 10)

    def on_state(self, msg):
        stamp = msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec
        if self.last and stamp < self.last[0]:  # time went back: a new simulation
            self.refs.clear()
            self.last = None
        if self.last and stamp == self.last[0]:
            self.pub.publish(self.last[1])
            return
        self.state = (stamp, msg)
        self.answer()

    def on_reference(self, msg):
        stamp = msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec
        self.refs[stamp] = {n: (msg.position[i], msg.velocity[i], msg.effort[i])
                            for i, n in enumerate(msg.name)}
        self.answer()

    def answer(self):
        if self.state is None or self.state[0] not in self.refs:
            return  # the state and its reference: both needed
        stamp, msg = self.state
        ref = self.refs.pop(stamp)
        for old in [s for s in self.refs if s < stamp]:
            del self.refs[old]
        self.state = None
        (q1, q2), (v1, v2) = msg.position, msg.velocity
        r = [ref[n] for n in msg.name]
        kp, kd = self.p['kp'], self.p['kd']
        acc = [r[j][2] + SIGN * (kd[j] * (r[j][1] - (v1, v2)[j])
                                 + kp[j] * (r[j][0] - (q1, q2)[j])) for j in range(2)]
        c2, s2 = math.cos(q2), math.sin(q2)
        d11, d12 = self.a + 2 * self.b * c2, self.d + self.b * c2
        tau = [d11 * acc[0] + d12 * acc[1] - self.b * s2 * v2 * (2 * v1 + v2)
               + self.g1 * math.cos(q1) + self.g2 * math.cos(q1 + q2),
               d12 * acc[0] + self.d * acc[1] + self.b * s2 * v1 ** 2
               + self.g2 * math.cos(q1 + q2)]
        out = Float64MultiArray(data=tau)
        sec, nsec = divmod(stamp, 10 ** 9)
        out.layout.dim = [MultiArrayDimension(label=f'joint_states@{sec}.{nsec:09d}',
                                              size=2, stride=2)]
        self.last = (stamp, out)
        self.pub.publish(out)


def main(args=None):
    rclpy.init(args=args)
    node = ComputedTorque()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
