"""The controller's own model of the arm: its ``control_model.*`` parameters and the model
they make (pure: no rclpy). One source for the controller node, the sweeps'
``control_model`` setting and ``arm-sim identify``'s params file.

``control_model.<key>`` (each robot parameter ``<key>`` of the model, per joint; empty =
the robot's) and ``control_model.gravity`` (negative = the robot's) let the controller's
model differ from the simulated arm: an unmodelled payload, an identified model.
"""

from __future__ import annotations

from typing import Any

from arm_common.params import ParamSpec
from arm_dynamics.models import RobotModel, robot_model
from arm_dynamics.robot import ROBOT_PARAMS
from arm_dynamics.two_link import TwoLinkArm

#: The robot parameters the controller's model may set (``control_model.<key>``); every
#: model of :data:`arm_dynamics.models.MODELS` takes these names.
MODEL_KEYS = tuple(k for k in TwoLinkArm.PARAMETERS if k != 'gravity')

#: The ``control_model.*`` parameters (unit and range of each from the robot's).
CONTROL_MODEL_PARAMS: tuple[ParamSpec, ...] = tuple(
    ParamSpec(f'control_model.{k}', 'doubles', [], f'Controller model {k.replace("_", " ")}; '
              'empty = the robot parameter (set to study model mismatch)',
              next(s.unit for s in ROBOT_PARAMS if s.name == k), minimum=0.0,
              maximum=1e4, read_only=True, per_joint=True)
    for k in MODEL_KEYS
) + (ParamSpec('control_model.gravity', 'double', -1.0, 'Controller model gravity; negative = '
               'the robot parameter', 'm/s^2', maximum=100.0, read_only=True),)


def controller_model(p: dict[str, Any]) -> RobotModel:
    """The controller's model from resolved parameters ``p`` (the robot's and
    ``control_model.*``): ``control_model.<key>`` where set, else the robot's ``<key>``.
    Raises ValueError as :func:`arm_dynamics.models.robot_model` does."""
    args: dict[str, Any] = {k: (p[f'control_model.{k}'] or p[k]) for k in MODEL_KEYS}
    gravity = p['control_model.gravity']
    args['gravity'] = p['gravity'] if gravity < 0 else gravity
    args['model'] = p['model']
    return robot_model(args)
