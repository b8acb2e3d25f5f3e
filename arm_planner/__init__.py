"""ROS-free motion planning for the 2-R arm: goal checks, time scalings, regulation and
straight-line plans with torque feasibility (see :mod:`arm_planner.planner`). The kinematics
(forward, inverse with the elbow choice, Jacobian, J' q') are the model's methods:
:class:`arm_dynamics.TwoLinkArm`."""

from arm_planner.kinematics import PlanningError, check_point
from arm_planner.planner import (
    Plan,
    PlannerSettings,
    make_arm,
    plan_goal,
    plan_path_stop,
    plan_regulation,
    plan_stop,
    plan_straight_line,
)
from arm_planner.time_scaling import TimeScaling, from_limits

__all__ = ['Plan', 'PlannerSettings', 'PlanningError', 'TimeScaling', 'check_point',
           'from_limits', 'make_arm', 'plan_goal', 'plan_path_stop', 'plan_regulation',
           'plan_stop', 'plan_straight_line']
