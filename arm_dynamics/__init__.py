"""ROS-free dynamics of the arm_sim robots: models, derivations and integration."""

from arm_dynamics.geared_link import SingleLinkGeared
from arm_dynamics.integrate import SimResult, rk4_step, simulate
from arm_dynamics.lagrange import LagrangianSystem, planar_chain
from arm_dynamics.limits import JointLimits
from arm_dynamics.newton_euler import rnea
from arm_dynamics.two_link import TwoLinkArm

__all__ = ['JointLimits', 'LagrangianSystem', 'SimResult', 'SingleLinkGeared', 'TwoLinkArm',
           'planar_chain', 'rk4_step', 'rnea', 'simulate']
