"""The robot parameters every node shares (``/**`` in config/arm.yaml), as one table (no rclpy).

The defaults come from where the facts live: the model's constructor defaults
(:class:`~arm_dynamics.two_link.TwoLinkArm`), the joint limits' defaults
(:mod:`arm_dynamics.limits`) and :data:`JOINT_NAMES`; this module adds only what a
parameter tool shows (unit, range, description). The simulator, controller, planner,
recorder, analysis and synthetic bags all read them from here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from typing import Any

from arm_common.params import ParamSpec, resolve
from arm_dynamics.friction import STATIC_FRICTION_RULE, static_friction_problem
from arm_dynamics.limits import (
    DEFAULT_EFFORT,
    DEFAULT_POSITION_LOWER,
    DEFAULT_POSITION_UPPER,
    DEFAULT_VELOCITY,
    JointLimits,
)
from arm_dynamics.models import MODELS, joint_count, robot_model
from arm_dynamics.two_link import TwoLinkArm

#: Joint names, shoulder then elbow.
JOINT_NAMES = ('joint1', 'joint2')

#: TwoLinkArm's constructor defaults by parameter name.
MODEL_DEFAULTS = {f.name: f.default for f in fields(TwoLinkArm) if f.init}


def _pair(name: str, default: tuple, description: str, unit: str, **kw) -> ParamSpec:
    return ParamSpec(name, 'doubles', list(default), description, unit, per_joint=True,
                     read_only=True, **kw)


def _model(name: str, description: str, unit: str, **kw) -> ParamSpec:
    default = MODEL_DEFAULTS[name]
    if isinstance(default, tuple):
        return _pair(name, default, description, unit, **kw)
    return ParamSpec(name, 'double', default, description, unit, read_only=True, **kw)


def _buildable(robot: Mapping[str, Any]) -> str | None:
    """Why the model cannot be built from the robot parameters (what its constructor
    refuses: e.g. a centre of gravity beyond its link), or None."""
    try:
        robot_model(robot)
    except ValueError as exc:
        return str(exc)
    return None


def _limits_order(robot: Mapping[str, Any]) -> str | None:
    """Why the joint limits do not hold together (a lower limit not below the upper)."""
    try:
        JointLimits.from_params(robot)
    except ValueError as exc:
        return str(exc)
    return None


def urdf_names(n: int) -> set[str]:
    """The names in the URDF of an ``n``-joint robot besides its joints' (the frames
    base_link, link1..link<n> and tool0, and tool0's fixed joint), as
    :mod:`arm_dynamics.urdf` makes them (it imports this module, so they are written out
    here; test_parameter_truth checks they agree): no joint may take one."""
    return {'base_link', 'tool0', 'tool0_joint', *(f'link{i + 1}' for i in range(n))}


def _frame_names(robot: Mapping[str, Any]) -> str | None:
    """Why the joint names would clash with the other names of the robot's URDF
    (:func:`urdf_names`): robot_state_publisher could not take it."""
    names = tuple(robot['joint_names'])
    taken = urdf_names(len(names))
    if taken & set(names):
        return (f'joint_names must not name a frame of the robot (any of {sorted(taken)}); '
                f'got {names!r}')
    return None


def _static_band(robot: Mapping[str, Any]) -> str | None:
    """Why ``static_friction`` is below ``coulomb_friction`` on a joint (0 = the Coulomb
    value: allowed): :func:`~arm_dynamics.friction.static_friction_problem`."""
    return static_friction_problem(robot['static_friction'], robot['coulomb_friction'])


#: Robot description shared by every node; read-only. The per-joint ones have one value
#: per joint of the model (:func:`~arm_dynamics.models.joint_count`); not given, the
#: default for the first two joints, the last value repeated beyond (joint names
#: ``joint<i>``).
ROBOT_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec('model', 'string', 'two_link',
              'Robot model: ' + '; '.join(f'{k.name}: {k.summary}' for k in MODELS.values()),
              choices=tuple(MODELS), read_only=True, relation=_buildable),
    ParamSpec('joint_names', 'strings', list(JOINT_NAMES),
              'Joint names, base to tip, all different', per_joint=True,
              fill=lambda i: f'joint{i + 1}', read_only=True, unique=True,
              relation=_frame_names),
    _model('link_lengths', 'Link lengths, joint axis to next axis / tip', 'm',
           minimum=0.0, strict_min=True, maximum=100.0),
    _model('com_distances', 'Joint axis to link centre of gravity', 'm',
           minimum=0.0, maximum=100.0),
    _model('link_masses', 'Link masses', 'kg', minimum=0.0, strict_min=True, maximum=1e4),
    _model('link_inertias', 'Link inertias about the CG, normal to the plane', 'kg m^2',
           minimum=0.0, maximum=1e4),
    _model('gravity', 'Gravity magnitude, acting along -y', 'm/s^2',
           minimum=0.0, maximum=100.0),
    _model('joint_damping', 'Viscous joint friction', 'N m s/rad', minimum=0.0,
           maximum=1e4),
    _model('gear_ratios', "Gear reduction of each joint's motor: motor turns per joint turn "
           '(commands stay joint-side torques)', '', minimum=0.0, strict_min=True,
           maximum=1e4),
    _model('motor_inertias', 'Rotor inertia of each joint motor, motor side; the joint sees '
           'gear_ratio^2 times it added to the diagonal of D(q) (reflected inertia, '
           'armature)', 'kg m^2', minimum=0.0, maximum=1e4),
    _model('motor_damping', 'Viscous friction of each joint motor, motor side; the joint '
           'sees gear_ratio^2 times it added to joint_damping', 'N m s/rad', minimum=0.0,
           maximum=1e4),
    _pair('coulomb_friction', (0.0, 0.0), 'Coulomb (sliding) friction of each joint, '
          'link side: -c sign(qd) while it slips, stick/slip exact (arm_dynamics.friction)',
          'N m', minimum=0.0, maximum=1e4),
    _pair('static_friction', (0.0, 0.0), 'Break-away (static) friction of each joint: a '
          'joint at rest stays stuck while the torque needed to hold it is within it; '
          + STATIC_FRICTION_RULE, 'N m', minimum=0.0, maximum=1e4,
          relation=_static_band),
    _pair('effort_limits', DEFAULT_EFFORT, 'Joint torque limits (applied torque is clipped)',
          'N m', minimum=0.0, strict_min=True, maximum=1e6),
    _pair('position_limits_lower', DEFAULT_POSITION_LOWER,
          'Joint position lower limits (-.inf: none); default shoulder one turn, elbow not '
          'past folded', 'rad', allow_inf=True),
    _pair('position_limits_upper', DEFAULT_POSITION_UPPER,
          'Joint position upper limits (.inf: none); must exceed the lower', 'rad',
          allow_inf=True, relation=_limits_order),
    _pair('velocity_limits', DEFAULT_VELOCITY,
          'Joint speed limits (.inf: none); default about 3x the demo\'s fastest motion',
          'rad/s', minimum=0.0, strict_min=True, allow_inf=True),
)

#: The defaults by name, as a bag's ``arm_sim_robot`` record would hold them.
ROBOT_DEFAULTS = {s.name: s.default for s in ROBOT_PARAMS}


def resolve_robot(given: dict) -> dict:
    """The robot parameters for ``given`` values (name -> value; others take their
    defaults, per-joint ones sized to the model's joints): the pure twin of what every
    node's start-up does, through the same code (:func:`arm_common.params.resolve`, the
    checks of :data:`ROBOT_PARAMS` and their relations). Raises ValueError naming each
    refused value."""
    known = {s.name for s in ROBOT_PARAMS}
    unknown = sorted(set(given) - known)
    if unknown:
        raise ValueError('; '.join(f'unknown robot parameter {name!r}' for name in unknown))
    return resolve(ROBOT_PARAMS, given, joint_count)
