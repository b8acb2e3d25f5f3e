"""The arm's transform tree from its URDF and joint positions, as robot_state_publisher
computes it (no rclpy).

:class:`FrameTree` reads the joints of a URDF (the text :mod:`arm_dynamics.urdf` makes,
the ``robot_description`` the visualizer publishes, or any URDF) and gives, per joint
(parent link -> child link):

* a movable joint (``revolute``, ``continuous``, ``prismatic``): the joint's
  ``<origin>`` transform times the motion along its ``<axis>`` by the joint position
  (a rotation by ``q`` rad about the axis, or a translation by ``q`` m along it), as
  robot_state_publisher sends on ``/tf`` for each joint state;
* a ``fixed`` joint: its ``<origin>`` transform, once, as robot_state_publisher sends on
  ``/tf_static``.

The names and numbers are the URDF's own (read back from its text), so the frames agree
with the model a viewer loads from ``robot_description``. For the suite's arms:
``base_link --joint1--> link1 --joint2--> link2 ... link<n> --tool0_joint--> tool0``,
each revolute about z, the joint of ``link<i+1>`` at ``(l_i, 0, 0)`` of ``link<i>``.

Conventions (URDF, tf2): translations in m, rotations as unit quaternions
``(x, y, z, w)``; an ``<origin rpy>`` is roll about x, then pitch about y, then yaw about
z, all about the parent's fixed axes (``R = Rz(yaw) Ry(pitch) Rx(roll)``).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

Vector = tuple[float, float, float]
Quaternion = tuple[float, float, float, float]  # (x, y, z, w)

#: URDF joint types that move with a joint position, and the fixed one.
MOVABLE = ('revolute', 'continuous', 'prismatic')
FIXED = 'fixed'
IDENTITY: Quaternion = (0.0, 0.0, 0.0, 1.0)


@dataclass(frozen=True)
class Transform:
    """``child``'s pose in ``parent``: translation [m] and rotation (unit quaternion
    ``(x, y, z, w)``); a point p in ``child`` is ``R p + t`` in ``parent``."""

    parent: str
    child: str
    translation: Vector
    rotation: Quaternion


@dataclass(frozen=True)
class Joint:
    """One ``<joint>`` of a URDF: what the transform tree needs of it."""

    name: str
    kind: str  # revolute, continuous, prismatic or fixed
    parent: str
    child: str
    xyz: Vector  # m: <origin xyz>
    rpy: Vector  # rad: <origin rpy>
    axis: Vector  # <axis xyz>, unit length (movable joints)


# ---------------------------------------------------------------------- quaternions
def quat_multiply(a: Quaternion, b: Quaternion) -> Quaternion:
    """The Hamilton product ``a b`` (the rotation b, then a: as rotation matrices
    ``R(a) R(b)``)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


def quat_from_axis_angle(axis: Vector, angle: float) -> Quaternion:
    """Rotation by ``angle`` rad about the unit vector ``axis``."""
    s, c = math.sin(angle / 2), math.cos(angle / 2)
    return (axis[0] * s, axis[1] * s, axis[2] * s, c)


def quat_from_rpy(roll: float, pitch: float, yaw: float) -> Quaternion:
    """URDF's ``rpy`` [rad] (fixed axes x, y, z: ``Rz(yaw) Ry(pitch) Rx(roll)``)."""
    q = quat_from_axis_angle((1.0, 0.0, 0.0), roll)
    q = quat_multiply(quat_from_axis_angle((0.0, 1.0, 0.0), pitch), q)
    return quat_multiply(quat_from_axis_angle((0.0, 0.0, 1.0), yaw), q)


def rotate(q: Quaternion, v: Vector) -> Vector:
    """``v`` rotated by the unit quaternion ``q``."""
    x, y, z, w = q
    # v + 2 w (u x v) + 2 u x (u x v), u = (x, y, z)
    cx, cy, cz = y * v[2] - z * v[1], z * v[0] - x * v[2], x * v[1] - y * v[0]
    return (v[0] + 2 * (w * cx + y * cz - z * cy),
            v[1] + 2 * (w * cy + z * cx - x * cz),
            v[2] + 2 * (w * cz + x * cy - y * cx))


def compose(a: Transform, b: Transform) -> Transform:
    """``a.parent -> b.child`` from ``a`` (parent -> x) and ``b`` (x -> child)."""
    if a.child != b.parent:
        raise ValueError(f'cannot compose {a.parent}->{a.child} with {b.parent}->{b.child}')
    t = rotate(a.rotation, b.translation)
    return Transform(a.parent, b.child,
                     (a.translation[0] + t[0], a.translation[1] + t[1],
                      a.translation[2] + t[2]),
                     quat_multiply(a.rotation, b.rotation))


def chain(transforms: Iterable[Transform], root: str, frame: str) -> Transform:
    """``root -> frame`` composed from a set of parent -> child transforms (a tree: each
    child has one parent). Raises ValueError when ``frame`` does not lead up to ``root``."""
    by_child = {t.child: t for t in transforms}
    path: list[Transform] = []
    name = frame
    while name != root:
        if name not in by_child or len(path) > len(by_child):
            raise ValueError(f'no transform chain from {root!r} to {frame!r}')
        path.append(by_child[name])
        name = by_child[name].parent
    out = Transform(root, root, (0.0, 0.0, 0.0), IDENTITY)
    for t in reversed(path):
        out = compose(out, t)
    return out


# ---------------------------------------------------------------------- URDF
def _floats(text: str | None, default: Vector, what: str) -> Vector:
    if text is None:
        return default
    try:
        values = tuple(float(v) for v in text.split())
    except ValueError:
        raise ValueError(f'{what}: {text!r} is not three numbers') from None
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise ValueError(f'{what}: {text!r} is not three finite numbers')
    return values[0], values[1], values[2]


def urdf_joints(urdf: str) -> tuple[Joint, ...]:
    """The joints of the URDF text ``urdf``, in document order.

    Raises
    ------
    ValueError
        Not a URDF (XML with a ``<robot>`` root), a joint without parent or child, of a
        type a transform tree cannot follow (``floating``, ``planar``), or with bad
        numbers (named).
    """
    try:
        root = ET.fromstring(urdf)
    except ET.ParseError as exc:
        raise ValueError(f'not a URDF: {exc}') from None
    if root.tag != 'robot':
        raise ValueError(f'not a URDF: the root element is <{root.tag}>, not <robot>')
    joints = []
    for el in root.findall('joint'):
        name, kind = el.get('name', ''), el.get('type', '')
        parent, child = el.find('parent'), el.find('child')
        if parent is None or child is None or not parent.get('link') or not child.get('link'):
            raise ValueError(f'joint {name!r}: needs <parent link> and <child link>')
        if kind not in MOVABLE + (FIXED,):
            raise ValueError(f'joint {name!r}: type {kind!r} is not one of '
                             f'{", ".join(MOVABLE + (FIXED,))}')
        origin = el.find('origin')
        xyz = _floats(origin.get('xyz') if origin is not None else None, (0.0, 0.0, 0.0),
                      f'joint {name!r} origin xyz')
        rpy = _floats(origin.get('rpy') if origin is not None else None, (0.0, 0.0, 0.0),
                      f'joint {name!r} origin rpy')
        axis_el = el.find('axis')
        axis = _floats(axis_el.get('xyz') if axis_el is not None else None, (1.0, 0.0, 0.0),
                       f'joint {name!r} axis')
        norm = math.sqrt(sum(a * a for a in axis))
        if kind != FIXED:
            if norm == 0.0:
                raise ValueError(f'joint {name!r}: axis must not be zero')
            if norm != 1.0:
                axis = (axis[0] / norm, axis[1] / norm, axis[2] / norm)
        joints.append(Joint(name, kind, str(parent.get('link')), str(child.get('link')),
                            xyz, rpy, axis))
    return tuple(joints)


class FrameTree:
    """The transform tree of a URDF (see the module docstring).

    Parameters
    ----------
    urdf : str
        URDF text (e.g. :func:`arm_dynamics.urdf.urdf_from_params`).

    Raises
    ------
    ValueError
        See :func:`urdf_joints`; or a link that is the child of two joints.
    """

    def __init__(self, urdf: str) -> None:
        joints = urdf_joints(urdf)
        children = [j.child for j in joints]
        twice = sorted({c for c in children if children.count(c) > 1})
        if twice:
            raise ValueError(f'links {twice} are the child of more than one joint')
        self.movable = tuple(j for j in joints if j.kind in MOVABLE)
        self.fixed = tuple(j for j in joints if j.kind == FIXED)
        #: The movable joints' names, in URDF order.
        self.joint_names = tuple(j.name for j in self.movable)
        self._origins = {j.name: quat_from_rpy(*j.rpy) for j in joints}

    def static_transforms(self) -> list[Transform]:
        """One transform per fixed joint (robot_state_publisher's ``/tf_static``)."""
        return [Transform(j.parent, j.child, j.xyz, self._origins[j.name])
                for j in self.fixed]

    def transforms(self, positions: Mapping[str, float] | Sequence[float]) -> list[Transform]:
        """One transform per movable joint at ``positions`` (rad, or m for a prismatic
        joint): by joint name, or a sequence in :attr:`joint_names` order.

        Raises
        ------
        ValueError
            A movable joint without a position, or a position that is not finite.
        """
        if isinstance(positions, Mapping):
            missing = [n for n in self.joint_names if n not in positions]
            if missing:
                raise ValueError(f'no position for joints {missing}')
            values = [float(positions[n]) for n in self.joint_names]
        else:
            values = [float(v) for v in positions]
            if len(values) != len(self.joint_names):
                raise ValueError(f'{len(values)} positions for the '
                                 f'{len(self.joint_names)} joints {list(self.joint_names)}')
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f'positions must be finite, got {values}')
        out = []
        for j, q in zip(self.movable, values):
            origin = self._origins[j.name]
            if j.kind == 'prismatic':
                d = rotate(origin, (j.axis[0] * q, j.axis[1] * q, j.axis[2] * q))
                out.append(Transform(j.parent, j.child, (j.xyz[0] + d[0], j.xyz[1] + d[1],
                                                         j.xyz[2] + d[2]), origin))
            else:
                out.append(Transform(j.parent, j.child, j.xyz,
                                     quat_multiply(origin, quat_from_axis_angle(j.axis, q))))
        return out
