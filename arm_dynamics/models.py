"""The robot-model seam: one protocol every algorithm takes, one table of the models.

Every node and tool that needs the arm's physics or geometry asks this module for it:
:func:`robot_model` builds the arm from the robot parameters (the ``model`` parameter
names the kind), :func:`joint_count` says how many joints those parameters describe, and
:class:`RobotModel` is what the simulator core, the controller's model-based laws, the
planner, the visualizer and markers, the live view, the URDF and the analysis may call.

To add a model: write a class that satisfies :class:`RobotModel` (one file in
``arm_dynamics/``, ROS-free), add a :class:`ModelKind` to :data:`MODELS`, and test it
against an independent reference (Pinocchio on its URDF, DOP853). docs/architecture.md
("Add a robot model") walks through it with ``planar_chain`` as the example.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from arm_dynamics.geared_link import SingleLinkGeared
from arm_dynamics.planar_chain import PlanarChain
from arm_dynamics.two_link import TwoLinkArm


@runtime_checkable
class RobotModel(Protocol):
    """A rigid arm of ``n_dof`` revolute joints in the plane, gravity along -y.

    Shapes: a state is (n,) or a batch (..., n); angles rad, speeds rad/s, torques N m,
    lengths m. ``D(q) qdd + C(q, qd) qd + g(q) + B qd = tau``.
    """

    @property
    def n_dof(self) -> int: ...

    # The chain's parameters (the robot parameters of the same names), read-only.
    @property
    def link_lengths(self) -> Any:
        """(n,) m."""

    @property
    def com_distances(self) -> Any:
        """(n,) m."""

    @property
    def link_masses(self) -> Any:
        """(n,) kg."""

    @property
    def link_inertias(self) -> Any:
        """(n,) kg m^2."""

    @property
    def gravity(self) -> float:
        """m/s^2, along -y."""

    @property
    def joint_damping(self) -> Any:
        """(n,) N m s/rad."""

    def mass_matrix(self, q) -> np.ndarray:
        """D(q) [kg m^2], (..., n, n)."""

    def coriolis_matrix(self, q, qd) -> np.ndarray:
        """C(q, qd) [N m s/rad], Christoffel form, (..., n, n)."""

    def gravity_vector(self, q) -> np.ndarray:
        """g(q) = dPE/dq [N m], (..., n)."""

    def damping_torque(self, qd) -> np.ndarray:
        """B qd [N m], (..., n)."""

    def forward_dynamics(self, q, qd, tau) -> np.ndarray:
        """qdd [rad/s^2], (..., n)."""

    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        """tau [N m], (..., n)."""

    def step(self, q, qd, tau, dt: float, n_steps: int = 1
             ) -> tuple[np.ndarray, np.ndarray]:
        """RK4 with ``tau`` held: (q, qd) after ``n_steps`` steps of ``dt`` [s]."""

    def energy(self, q, qd) -> tuple[np.ndarray, np.ndarray]:
        """(kinetic, potential) [J], potential zero at the base height."""

    def joint_points(self, q) -> np.ndarray:
        """Base, each joint after it and the tip [m]: (..., n + 1, 2), for drawing."""

    def forward_kinematics(self, q) -> np.ndarray:
        """Tip position (x, y) [m], (..., 2)."""

    def jacobian(self, q) -> np.ndarray:
        """Tip Jacobian dp/dq [m/rad], (..., 2, n)."""

    def jdot_qd(self, q, qd) -> np.ndarray:
        """J'(q, qd) qd [m/s^2], (..., 2): the tip acceleration at zero qdd."""

    def inverse_dynamics_complex(self, q, qd, qdd) -> np.ndarray:
        """Inverse dynamics of one state carrying complex q, qd (complex-step derivatives)."""

    def linearize(self, q, qd, tau, period: float | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        """(A, B) about (q, qd, tau): (2n, 2n), (2n, n); continuous, or sampled with the
        torque held over ``period`` [s] (:mod:`arm_dynamics.linearize`)."""


@dataclass(frozen=True)
class ModelKind:
    """One entry of :data:`MODELS`.

    ``joints(robot)`` is the number of joints the robot parameters describe for this kind
    (raising ValueError with the reason when they cannot describe one); ``build(robot)`` the
    :class:`RobotModel` every node uses; ``closed_form_ik`` whether the planner may ask it
    for closed-form inverse kinematics with an elbow choice (and so plan straight lines).
    """

    name: str
    summary: str
    joints: Callable[[Mapping[str, Any]], int]
    build: Callable[[Mapping[str, Any]], RobotModel]
    closed_form_ik: bool = False


def _two_links(robot: Mapping[str, Any]) -> int:
    lengths = robot.get('link_lengths', TwoLinkArm.link_lengths)
    if len(lengths) != 2:
        raise ValueError(f'link_lengths has {len(lengths)} values but model '
                         f"{robot.get('model', 'two_link')} has 2 links (model: planar_chain "
                         'takes any number)')
    return 2


def _chain_links(robot: Mapping[str, Any]) -> int:
    lengths = robot.get('link_lengths', PlanarChain.link_lengths)
    if len(lengths) < 1:
        raise ValueError('link_lengths must have at least one value for model planar_chain')
    return len(lengths)


#: The models, by the ``model`` parameter's value.
MODELS: dict[str, ModelKind] = {kind.name: kind for kind in (
    ModelKind('two_link', 'the 2-R arm, closed-form dynamics and kinematics (the default)',
              _two_links, TwoLinkArm.from_params, closed_form_ik=True),
    ModelKind('planar_chain', 'n revolute links in the plane, n = the length of '
              'link_lengths; dynamics by recursive Newton-Euler', _chain_links,
              PlanarChain.from_params),
    ModelKind('single_link_geared', "the lecture's link behind an n:1 gear (simulator "
              'geared.* parameters); the other nodes see the 2-R robot parameters',
              _two_links, TwoLinkArm.from_params, closed_form_ik=True),
)}


def model_kind(robot: Mapping[str, Any]) -> ModelKind:
    """The :class:`ModelKind` named by ``robot['model']`` (default ``two_link``)."""
    name = robot.get('model', 'two_link')
    if name not in MODELS:
        raise ValueError(f"model must be one of {', '.join(MODELS)}; got {name!r}")
    return MODELS[name]


def joint_count(robot: Mapping[str, Any]) -> int:
    """How many joints the robot parameters describe (ValueError naming the reason)."""
    return model_kind(robot).joints(robot)


def robot_model(robot: Mapping[str, Any]) -> RobotModel:
    """The arm the robot parameters describe (missing ones take the defaults); ValueError
    naming a parameter the physics refuses."""
    kind = model_kind(robot)
    kind.joints(robot)
    return kind.build(robot)


def geared_link(geared: Mapping[str, Any]) -> SingleLinkGeared:
    """The simulator's ``single_link_geared`` plant from its ``geared.*`` values."""
    return SingleLinkGeared(**geared)
