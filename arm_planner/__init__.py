"""ROS-free motion planning for the 2-R arm: inverse kinematics, time scalings, regulation
and straight-line plans with torque feasibility (see :mod:`arm_planner.planner`)."""

from arm_planner.kinematics import PlanningError, check_point, elbow_of, inverse_kinematics
from arm_planner.planner import (
    Plan,
    PlannerSettings,
    make_arm,
    plan_goal,
    plan_regulation,
    plan_stop,
    plan_straight_line,
)
from arm_planner.time_scaling import TimeScaling, from_limits

__all__ = ['Plan', 'PlannerSettings', 'PlanningError', 'TimeScaling', 'check_point',
           'elbow_of', 'from_limits', 'inverse_kinematics', 'make_arm', 'plan_goal',
           'plan_regulation', 'plan_stop', 'plan_straight_line']
