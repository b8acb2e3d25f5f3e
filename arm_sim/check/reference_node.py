"""``check_reference`` node: the per-state reference stream ``arm-sim check`` publishes.

arm_sim's controller without its torque: it takes ``arm_controller/joint_trajectory`` as the
controller does (the same sampling, start rule, time jumps, verdicts on
``arm_controller/trajectory_status``, which the planner waits for) and, for every
``joint_states`` it receives, publishes ``check/reference`` (sensor_msgs/JointState, the
state's stamp and joint order): position = q_des [rad], velocity = q'_des [rad/s],
effort = q''_des [rad/s^2] of the reference at that stamp. Until the first trajectory the
reference holds the first measured position. A state that comes again (lockstep re-sends
an unanswered one) gets its reference again, the very same message. It never publishes a
command: the user's controller answers the simulator.

Started by the harness as ``controller`` code with ``-r __node:=check_reference -r
arm_controller/reference:=check/reference -r effort_controller/commands:=check/unused``.
"""

from __future__ import annotations

from sensor_msgs.msg import JointState

from arm_common.node import run_node
from arm_control.controller_node import CONTROL_PARAMS, ControllerNode
from arm_dynamics.robot import ROBOT_PARAMS

SUMMARY = __doc__.split('\n\n')[1]


class ReferenceNode(ControllerNode):
    """See the module docstring."""

    def __init__(self) -> None:
        super().__init__()
        unused, self.cmd_pub = self.cmd_pub, self.ref_pub  # a re-sent state: the reference
        self.destroy_publisher(unused)

    def _control(self, stamp_ns: int | None) -> None:
        assert self.latest is not None
        t, q, qd = self.latest
        step = self.core.update(t, q, qd)
        if step.jump:
            self.diag.problem('time_jump', f'{step.jump}: trajectory dropped, holding the '
                              f'measured position {q.round(4).tolist()} rad')
        ref = JointState(name=list(self.core.joint_names), position=step.q_des.tolist(),
                         velocity=step.qd_des.tolist(), effort=step.qdd_des.tolist())
        if stamp_ns is None:
            stamp_ns = int(round(t * 1e9))
        ref.header.stamp.sec, ref.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        self.answer = (stamp_ns, q, ref, True)
        self.ref_pub.publish(ref)


def main(args: list[str] | None = None) -> int:
    return run_node(ReferenceNode, prog='check_reference', summary=SUMMARY,
                    specs=ROBOT_PARAMS + CONTROL_PARAMS, args=args)


if __name__ == '__main__':
    raise SystemExit(main())
