"""ROS-free dynamics of the arm_sim robots: models, derivations and integration."""

from arm_dynamics.geared_link import SingleLinkGeared
from arm_dynamics.integrate import SimResult, rk4_step, simulate
from arm_dynamics.two_link import TwoLinkArm

__all__ = ['SimResult', 'SingleLinkGeared', 'TwoLinkArm', 'rk4_step', 'simulate']
