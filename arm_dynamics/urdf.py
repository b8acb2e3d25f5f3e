"""A URDF of the arm (the 2-R arm or any planar chain), generated from the robot parameters
(no rclpy).

The model a viewer shows is the model the simulator integrates: every number comes from
the same parameters (:data:`arm_dynamics.robot.ROBOT_PARAMS`) through the same
constructors (:meth:`TwoLinkArm.from_params <arm_dynamics.two_link.TwoLinkArm.from_params>`,
:meth:`JointLimits.from_params <arm_dynamics.limits.JointLimits.from_params>`), so a
parameter set the nodes refuse is refused here too, with the same reason.

Frames (the suite's convention, :mod:`arm_dynamics.two_link`): the arm moves in the x-y
plane of ``base_link``, gravity along -y, angles counter-clockwise about +z::

    base_link --joint1 (revolute, z, at the origin)--> link1
    link1     --joint2 (revolute, z, at (l1, 0, 0))--> link2
    link2     --tool0_joint (fixed, at (l2, 0, 0))---> tool0

(a planar chain of n links continues the same way: ``link<i>`` --``joint<i+1>`` at
``(l_i, 0, 0)``--> ``link<i+1>``, and ``tool0`` at ``(l_n, 0, 0)`` of ``link<n>``)

Each link frame has its x axis along the link, so ``q1`` is link 1's angle from +x and
``q2`` link 2's angle relative to link 1, and the origin of ``tool0`` is the tip of
:meth:`TwoLinkArm.forward_kinematics <arm_dynamics.two_link.TwoLinkArm.forward_kinematics>`.

Inertials: mass ``m_i`` at ``(lc_i, 0, 0)`` in ``link_i``; inertia about the CG with
``izz = I_i`` (the planar inertia, the only entry the planar motion sees), ``ixx =``
:data:`AXIAL_INERTIA` (small and positive, as for a thin rod about its own axis) and
``iyy = I_i +`` :data:`AXIAL_INERTIA` (a rod about a transverse axis), so the tensor is
positive definite (semi-definite for ``I_i = 0``, the model's point mass) and meets the
triangle inequality that physics engines check (Gazebo, MuJoCo) for every ``I_i >= 0``.

Joint damping goes to ``<dynamics damping>``, effort and speed limits to ``<limit>``; a
joint with an infinite position limit (``-.inf`` or ``.inf``) is ``continuous`` (URDF has
no one-sided limit). Nor has URDF "no speed limit": an infinite one is written as
:data:`UNLIMITED_VELOCITY`. Gravity is not part of a URDF: a simulator given this model
sets it to ``(0, -gravity, 0)`` in ``base_link``.

The geared motors (``gear_ratios``, ``motor_inertias``, ``motor_damping``) are not written:
URDF has no rotor inertia (a ``<transmission>``'s ``mechanicalReduction`` is read by
ros2_control, not by dynamics engines, and would say nothing about ``Jm``), and
``<dynamics damping>`` stays the link-side ``joint_damping``. A dynamics engine loading this
URDF for an arm with motors must add the reflected inertia ``n^2 Jm`` itself (Pinocchio's
``model.armature``, MuJoCo's joint ``armature``) and ``n^2 Bm`` to the damping.

Visuals (they carry no physics): a cylinder along each link, a disc at each joint, a
small sphere at the tip and a base plate behind the plane, sized from the link lengths.

References: the URDF specification, ROS wiki ``urdf/XML`` (link, joint, inertial,
limit and dynamics elements).
"""

from __future__ import annotations

import math
import sys
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from arm_dynamics.limits import JointLimits
from arm_dynamics.models import RobotModel, robot_model
from arm_dynamics.robot import JOINT_NAMES, ROBOT_PARAMS, resolve_robot

#: kg m^2: the inertia of each link about its own (x) axis, and what is added to ``iyy``:
#: small and positive, so the inertia tensor is valid for any planar inertia ``I >= 0``.
AXIAL_INERTIA = 1e-6
#: rad/s: what an infinite ``velocity_limits`` entry becomes (URDF requires a number).
UNLIMITED_VELOCITY = sys.float_info.max
#: Frame names: the root, the links (``link<i>``, i = 1..n; the 2-R arm's two below) and
#: the tip.
BASE_FRAME = 'base_link'
LINK_FRAMES = ('link1', 'link2')
TIP_FRAME = 'tool0'


def link_frames(n: int) -> tuple[str, ...]:
    """The link frames of an n-joint arm: ``link1`` .. ``link<n>``."""
    return tuple(f'link{i + 1}' for i in range(n))
#: RGBA colours of the visuals.
COLOURS = {'base': (0.3, 0.3, 0.3, 1.0), 'link1': (0.2, 0.45, 0.8, 1.0),
           'link2': (0.95, 0.55, 0.1, 1.0), 'joint': (0.15, 0.15, 0.15, 1.0),
           'tip': (0.8, 0.1, 0.1, 1.0)}


@dataclass(frozen=True)
class RobotDescription:
    """Everything the URDF is made from, checked.

    Parameters
    ----------
    arm : a RobotModel of n joints (:mod:`arm_dynamics.models`)
        Lengths [m], CG distances [m], masses [kg], inertias about the CG [kg m^2],
        damping [N m s/rad] (gravity [m/s^2] is not part of a URDF).
    limits : JointLimits
        Position limits [rad] and speed limits [rad/s].
    effort_limits : (n,) N m, each > 0
    joint_names : (n,) str
        Base to tip.
    name : str
        The ``<robot name>``.
    """

    arm: RobotModel
    limits: JointLimits
    effort_limits: tuple[float, ...]
    joint_names: tuple[str, ...] = JOINT_NAMES
    name: str = 'arm_sim_two_link'

    def __post_init__(self) -> None:
        n = self.arm.n_dof
        count = 'two' if n == 2 else str(n)
        if len(self.limits.lower) != n:
            raise ValueError(f'limits must be for {n} joints, got {len(self.limits.lower)}')
        effort = tuple(float(e) for e in self.effort_limits)
        if len(effort) != n or not all(math.isfinite(e) and e > 0 for e in effort):
            raise ValueError(f'effort_limits must be {count} finite values > 0 N m, got '
                             f'{self.effort_limits!r}')
        names = tuple(self.joint_names)
        taken = {BASE_FRAME, TIP_FRAME, 'tool0_joint', *link_frames(n)}
        if (len(names) != n or not all(isinstance(x, str) and x for x in names)
                or len(set(names)) != n or taken & set(names)):
            raise ValueError(f'joint_names must be {count} different non-empty names, none '
                             f'of {sorted(taken)}; got {self.joint_names!r}')
        if not self.name:
            raise ValueError(f'name must not be empty, got {self.name!r}')
        object.__setattr__(self, 'effort_limits', effort)
        object.__setattr__(self, 'joint_names', names)

    @classmethod
    def from_params(cls, params: Mapping[str, Any] | None = None,
                    name: str | None = None) -> RobotDescription:
        """From robot parameters by name (missing ones take the defaults of
        :data:`~arm_dynamics.robot.ROBOT_DEFAULTS`, per-joint ones sized to the model; the
        name defaults to ``arm_sim_<model>``).

        Raises
        ------
        ValueError
            An unknown parameter name, or a value the nodes would refuse (named, with the
            value).
        """
        given = dict(params or {})
        unknown = sorted(set(given) - {s.name for s in ROBOT_PARAMS})
        if unknown:
            raise ValueError(f'unknown robot parameter(s) {unknown}; known: '
                             f'{", ".join(s.name for s in ROBOT_PARAMS)}')
        values = resolve_robot(given)
        return cls(arm=robot_model(values), limits=JointLimits.from_params(values),
                   effort_limits=tuple(values['effort_limits']),
                   joint_names=tuple(values['joint_names']),
                   name=name or f"arm_sim_{values['model']}")

    def to_urdf(self) -> str:
        """The URDF document (XML text with declaration, ending in a newline)."""
        return robot_urdf(self)


def _num(x: float) -> str:
    """A float as the shortest text that reads back to the same double."""
    return repr(float(x))


def _vec(*xs: float) -> str:
    return ' '.join(_num(x) for x in xs)


def _size(*xs: float) -> str:
    """Visual dimensions [m]: 4 decimals are plenty for a picture."""
    return _vec(*(round(x, 4) for x in xs))


def _sub(parent: ET.Element, tag: str, **attrib: str) -> ET.Element:
    return ET.SubElement(parent, tag, attrib)


def _visual(link: ET.Element, name: str, geometry: tuple[str, dict[str, str]],
            xyz: tuple[float, float, float], colour: str,
            rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
    visual = _sub(link, 'visual', name=name)
    _sub(visual, 'origin', xyz=_vec(*xyz), rpy=_vec(*rpy))
    _sub(_sub(visual, 'geometry'), geometry[0], **geometry[1])
    _sub(visual, 'material', name=colour)


def _cylinder(radius: float, length: float) -> tuple[str, dict[str, str]]:
    return 'cylinder', {'radius': _size(radius), 'length': _size(length)}


def robot_urdf(robot: RobotDescription) -> str:
    """The URDF of ``robot``: see the module docstring for frames and conventions.

    Parameters
    ----------
    robot : RobotDescription

    Returns
    -------
    str
        XML text: ``base_link`` root, links ``link1`` .. ``link<n>``, ``tool0``, revolute
        (or continuous) joints named ``robot.joint_names``, fixed ``tool0_joint``.
    """
    arm, limits = robot.arm, robot.limits
    frames = link_frames(arm.n_dof)
    lengths, cgs = arm.link_lengths, arm.com_distances
    reach = sum(lengths)
    radius = 0.02 * reach  # m: link cylinders; joint discs are twice as wide
    root = ET.Element('robot', name=robot.name)
    for colour, rgba in COLOURS.items():
        _sub(_sub(root, 'material', name=colour), 'color', rgba=_vec(*rgba))

    base = _sub(root, 'link', name=BASE_FRAME)
    _visual(base, 'base_plate', ('box', {'size': _size(4 * radius, 4 * radius, radius)}),
            (0.0, 0.0, -1.5 * radius), 'base')

    for i, frame in enumerate(frames):
        length, cg = lengths[i], cgs[i]
        link = _sub(root, 'link', name=frame)
        _visual(link, f'{frame}_body', _cylinder(radius, length), (length / 2, 0.0, 0.0),
                'link1' if i == 0 else 'link2', rpy=(0.0, math.pi / 2, 0.0))
        _visual(link, f'{frame}_joint_disc', _cylinder(2 * radius, 1.5 * radius),
                (0.0, 0.0, 0.0), 'joint')
        inertial = _sub(link, 'inertial')
        _sub(inertial, 'origin', xyz=_vec(cg, 0.0, 0.0), rpy=_vec(0.0, 0.0, 0.0))
        _sub(inertial, 'mass', value=_num(arm.link_masses[i]))
        izz = arm.link_inertias[i]
        _sub(inertial, 'inertia', ixx=_num(AXIAL_INERTIA), ixy='0.0', ixz='0.0',
             iyy=_num(izz + AXIAL_INERTIA), iyz='0.0', izz=_num(izz))

    tip = _sub(root, 'link', name=TIP_FRAME)
    _visual(tip, 'tip', ('sphere', {'radius': _size(1.5 * radius)}), (0.0, 0.0, 0.0), 'tip')

    parents = (BASE_FRAME,) + frames[:-1]
    origins = ((0.0, 0.0, 0.0),) + tuple((length, 0.0, 0.0) for length in lengths[:-1])
    for i, name in enumerate(robot.joint_names):
        bounded = math.isfinite(limits.lower[i]) and math.isfinite(limits.upper[i])
        joint = _sub(root, 'joint', name=name, type='revolute' if bounded else 'continuous')
        _sub(joint, 'parent', link=parents[i])
        _sub(joint, 'child', link=frames[i])
        _sub(joint, 'origin', xyz=_vec(*origins[i]), rpy=_vec(0.0, 0.0, 0.0))
        _sub(joint, 'axis', xyz=_vec(0.0, 0.0, 1.0))
        speed = limits.velocity[i] if math.isfinite(limits.velocity[i]) else UNLIMITED_VELOCITY
        bounds = ({'lower': _num(limits.lower[i]), 'upper': _num(limits.upper[i])}
                  if bounded else {})
        _sub(joint, 'limit', effort=_num(robot.effort_limits[i]), velocity=_num(speed),
             **bounds)
        _sub(joint, 'dynamics', damping=_num(arm.joint_damping[i]), friction='0.0')

    fixed = _sub(root, 'joint', name='tool0_joint', type='fixed')
    _sub(fixed, 'parent', link=frames[-1])
    _sub(fixed, 'child', link=TIP_FRAME)
    _sub(fixed, 'origin', xyz=_vec(lengths[-1], 0.0, 0.0), rpy=_vec(0.0, 0.0, 0.0))

    ET.indent(root, space='  ')
    comment = (f'<!-- generated by arm_sim (arm_dynamics.urdf) from the robot parameters; '
               f'gravity {_num(arm.gravity)} m/s^2 along -y of {BASE_FRAME} -->\n')
    return ('<?xml version="1.0"?>\n' + comment
            + ET.tostring(root, encoding='unicode') + '\n')


def urdf_from_params(params: Mapping[str, Any] | None = None,
                     name: str | None = None) -> str:
    """The URDF of the arm the robot parameters ``params`` describe (missing ones: the
    defaults). Raises ValueError naming a bad or unknown parameter."""
    return RobotDescription.from_params(params, name=name).to_urdf()
