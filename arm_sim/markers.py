"""Visualization markers of the two-link arm, built from arrays (no rclpy).

:func:`arm_markers` describes what the ``visualizer`` node publishes on ``markers``
(visualization_msgs/MarkerArray), one namespace per element:

========  ============  ==========================================================
ns        shape         what
========  ============  ==========================================================
links     LINE_LIST     base -> elbow (link 1's colour), elbow -> tip (link 2's)
joints    SPHERE_LIST   the shoulder (base) and the elbow
tip       SPHERE        the end effector
trail     LINE_STRIP    the tip over the last ``trail_length`` s of simulated time
goal      SPHERE        the current goal (``goal_pose``)
path      LINE_STRIP    the planned path (``planner/path``): the commanded straight
                        line, or the start and goal of a regulation
========  ============  ==========================================================

Every element is always described: one with nothing to show (no goal, a trail or path of
fewer than two points) is marked not visible, so the node sends a DELETE for it and a
display drops what it showed before. All points lie in the plane z = 0 of the base frame.

Positions come from the arm's own kinematics,
:meth:`TwoLinkArm.forward_kinematics <arm_dynamics.two_link.TwoLinkArm.forward_kinematics>`:
the tip is ``forward_kinematics(q)``; the elbow is the stretched arm's tip
``forward_kinematics((q1, 0))`` scaled by ``l1 / (l1 + l2)`` (link 1 points where the
stretched arm points), so no second copy of the kinematics exists and the markers equal
forward kinematics to rounding (about 1e-16 m). Sizes and colours follow the URDF's visuals
(:mod:`arm_dynamics.urdf`): widths proportional to the reach ``l1 + l2``.

:class:`TipTrail` keeps the joint states of the trail window by their stamps: what is shown
depends only on the joint states received, never on when the markers are sent.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from arm_dynamics.models import RobotModel
from arm_dynamics.urdf import COLOURS

#: Marker shapes (visualization_msgs/Marker type names, lower case).
SHAPES = ('line_list', 'line_strip', 'sphere', 'sphere_list')
#: The namespaces, in the order :func:`arm_markers` returns them.
NAMESPACES = ('links', 'joints', 'tip', 'trail', 'goal', 'path')

Colour = tuple[float, float, float, float]
Scale = tuple[float, float, float]

#: RGBA of the elements (links, joints and tip as the URDF's visuals; trail red and
#: commanded path green as in arm_sim.draw's pictures).
MARKER_COLOURS: dict[str, Colour] = {
    'link1': COLOURS['link1'], 'link2': COLOURS['link2'], 'joints': COLOURS['joint'],
    'tip': COLOURS['tip'], 'trail': (0.85, 0.1, 0.1, 0.8), 'goal': (0.1, 0.7, 0.2, 0.6),
    'path': (0.1, 0.7, 0.2, 0.9)}


@dataclass(frozen=True, eq=False)
class MarkerShape:
    """One marker: a namespace's element in the base frame.

    Parameters
    ----------
    ns : str
        Namespace (one of :data:`NAMESPACES`); the marker id is 0.
    shape : str
        One of :data:`SHAPES`.
    points : (N, 3) float, m
        Vertices (line_list: pairs; line_strip: the polyline; sphere_list: centres;
        sphere: its centre, N = 1). Empty when not visible.
    scale : (3,) m
        Lines: width in x; spheres: diameters in x, y, z.
    colour : (4,) RGBA in [0, 1]
        The whole marker's colour.
    colours : (N, 4) RGBA or None
        Per-vertex colours (the links: each link its URDF colour), else None.
    visible : bool
        False: nothing to show (a DELETE of the namespace's marker).
    """

    ns: str
    shape: str
    points: np.ndarray
    scale: Scale
    colour: Colour
    colours: np.ndarray | None = None
    visible: bool = True

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise ValueError(f'shape must be one of {SHAPES}, got {self.shape!r}')
        points = np.asarray(self.points, dtype=float).reshape(-1, 3)
        points.setflags(write=False)
        object.__setattr__(self, 'points', points)


@dataclass(frozen=True)
class MarkerSizes:
    """Marker sizes [m] for an arm of reach ``reach`` = l1 + l2 [m]: link lines as wide as
    the URDF's link cylinders (0.04 reach), joints as its discs (0.08 reach)."""

    link_width: float
    joint_diameter: float
    tip_diameter: float
    goal_diameter: float
    line_width: float  # the trail and the path

    @classmethod
    def for_reach(cls, reach: float) -> MarkerSizes:
        """Sizes proportional to ``reach`` [m]."""
        return cls(link_width=0.04 * reach, joint_diameter=0.08 * reach,
                   tip_diameter=0.05 * reach, goal_diameter=0.06 * reach,
                   line_width=0.01 * reach)


def link_points(arm: RobotModel, q: np.ndarray) -> np.ndarray:
    """Base, each joint after it and the tip [m] of the arm at ``q``: the model's own
    :meth:`~arm_dynamics.models.RobotModel.joint_points`.

    Parameters
    ----------
    arm : any :class:`~arm_dynamics.models.RobotModel` of n joints
    q : (n,) or (K, n), rad

    Returns
    -------
    (n + 1, 2) or (K, n + 1, 2), m
        Rows base (0, 0), the joints (for the 2-R arm the elbow ``l1 (cos q1, sin q1)``)
        and the tip (forward kinematics).
    """
    return arm.joint_points(np.asarray(q, dtype=float))


def _xyz(xy: np.ndarray | None) -> np.ndarray:
    """(N, 2) m -> (N, 3) m in the plane z = 0 (None -> no points)."""
    if xy is None:
        return np.zeros((0, 3))
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    return np.column_stack([xy, np.zeros(len(xy))])


def _strip(ns: str, xy: np.ndarray | None, width: float) -> MarkerShape:
    points = _xyz(xy)
    visible = len(points) >= 2  # a line strip needs two points (RViz warns otherwise)
    return MarkerShape(ns, 'line_strip', points if visible else np.zeros((0, 3)),
                       (width, 0.0, 0.0), MARKER_COLOURS[ns], visible=visible)


def arm_markers(arm: RobotModel, q: np.ndarray, trail: np.ndarray | None = None,
                goal: tuple[float, float] | np.ndarray | None = None,
                path: np.ndarray | None = None) -> tuple[MarkerShape, ...]:
    """The markers of the arm at ``q`` with its tip's trail, goal and planned path.

    Parameters
    ----------
    arm : RobotModel
        The robot (n joints; link lengths [m]).
    q : (n,) rad
        Joint angles, base to tip.
    trail : (N, 2) m or None
        The tip's recent positions, oldest first (e.g. :meth:`TipTrail.points`); fewer
        than 2 or None: no trail.
    goal : (x, y) m or None
        The current goal of the tip; None: none.
    path : (P, 2) m or None
        The planned tip path (the commanded line); fewer than 2 points or None: none.

    Returns
    -------
    tuple of MarkerShape
        One per namespace of :data:`NAMESPACES`, in that order.

    Raises
    ------
    ValueError
        ``q``, ``goal``, ``trail`` or ``path`` of the wrong shape or not finite.
    """
    q = np.asarray(q, dtype=float)
    n = arm.n_dof
    if q.shape != (n,) or not np.isfinite(q).all():
        raise ValueError(f'q must be {n} finite angles [rad], got {q.tolist()}')
    for name, xy in (('trail', trail), ('path', path)):
        if xy is not None:
            a = np.asarray(xy, dtype=float)
            if a.size and (a.ndim != 2 or a.shape[1] != 2 or not np.isfinite(a).all()):
                raise ValueError(f'{name} must be (N, 2) finite positions [m], got shape '
                                 f'{a.shape}')
    goal_xy = None
    if goal is not None:
        goal_xy = np.asarray(goal, dtype=float)
        if goal_xy.shape != (2,) or not np.isfinite(goal_xy).all():
            raise ValueError(f'goal must be a finite (x, y) [m], got {goal_xy.tolist()}')
    sizes = MarkerSizes.for_reach(sum(arm.link_lengths))
    points = _xyz(link_points(arm, q))
    tip = points[-1]
    # Link 1 in its colour, every link after it in link 2's.
    c1, c2 = MARKER_COLOURS['link1'], MARKER_COLOURS['link2']
    ends = np.repeat(points, 2, axis=0)[1:-1]           # p0 p1 p1 p2 ... p_n
    colours = np.array([c1 if k < 2 else c2 for k in range(len(ends))], dtype=float)
    links = MarkerShape('links', 'line_list', ends, (sizes.link_width, 0.0, 0.0), c1,
                        colours=colours)
    d = sizes.joint_diameter
    joints = MarkerShape('joints', 'sphere_list', points[:-1], (d, d, d),
                         MARKER_COLOURS['joints'])
    d = sizes.tip_diameter
    tip_marker = MarkerShape('tip', 'sphere', tip[None], (d, d, d), MARKER_COLOURS['tip'])
    d = sizes.goal_diameter
    goal_marker = MarkerShape('goal', 'sphere', _xyz(goal_xy), (d, d, d),
                              MARKER_COLOURS['goal'], visible=goal_xy is not None)
    return (links, joints, tip_marker, _strip('trail', trail, sizes.line_width),
            goal_marker, _strip('path', path, sizes.line_width))


class TipTrail:
    """The joint states of the last ``window_ns`` of simulated time, by stamp, for the
    tip's trail.

    A state re-sent with the stamp of the latest one replaces it (counted once); a stamp
    earlier than the latest (a restarted simulator, a replayed bag) starts the trail anew;
    states older than ``window_ns`` before the latest are dropped, and at most
    ``max_points`` are kept (the oldest go first). So the trail depends only on the joint
    states received, not on when it is read.

    Parameters
    ----------
    window_ns : int, ns, >= 0
        How far back the trail reaches (0: the latest state only: no trail line).
    max_points : int, >= 1
        Bound on the states kept (memory and marker size).
    """

    def __init__(self, window_ns: int, max_points: int = 10_000) -> None:
        if window_ns < 0 or max_points < 1:
            raise ValueError(f'window_ns must be >= 0 and max_points >= 1, got {window_ns}, '
                             f'{max_points}')
        self.window_ns = int(window_ns)
        self._states: deque[tuple[int, tuple[float, ...]]] = deque(maxlen=int(max_points))

    def __len__(self) -> int:
        return len(self._states)

    def add(self, stamp_ns: int, q: np.ndarray) -> None:
        """Add the joint state ``q`` [rad] (n,) stamped ``stamp_ns`` [ns]."""
        states = self._states
        if states and stamp_ns <= states[-1][0]:
            if stamp_ns < states[-1][0]:
                states.clear()  # time went back: a new run
            else:
                states.pop()  # the same state again
        states.append((int(stamp_ns), tuple(float(v) for v in q)))
        while states[0][0] < stamp_ns - self.window_ns:
            states.popleft()

    def angles(self) -> np.ndarray:
        """(N, n) rad: the joint angles of the trail, oldest first."""
        if not self._states:
            return np.zeros((0, 2))
        return np.array([s[1] for s in self._states], dtype=float)

    def stamps(self) -> np.ndarray:
        """(N,) int64 ns: their stamps."""
        return np.array([s[0] for s in self._states], dtype=np.int64)

    def points(self, arm: RobotModel) -> np.ndarray:
        """(N, 2) m: the tip along the trail, oldest first (forward kinematics)."""
        q = self.angles()
        return arm.forward_kinematics(q) if len(q) else np.zeros((0, 2))
