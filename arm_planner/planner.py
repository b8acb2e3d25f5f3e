"""Goal poses to torque-feasible joint trajectories for the 2-R arm (no rclpy).

Two tasks, as in the lecture:

* :func:`plan_regulation` -- reach the goal point: its joint angles as a set point (one
  trajectory point), or a synchronised joint-space point-to-point profile (both joints
  start and stop together: ``q(t) = q0 + (qf - q0) s(t)``).
* :func:`plan_straight_line` -- move the end effector from where it is to the goal on the
  straight segment: ``x(t) = xs + (xf - xs) s(t)``; every trajectory point carries
  ``q = IK(x)``, ``q' = J^-1 x'`` and ``q'' = J^-1 (x'' - J' q')``.

:func:`plan_goal` dispatches on :class:`PlannerSettings` (what the ``planner`` node calls).

Sampling rule (straight line)
-----------------------------
The controller interpolates between points with quintics in ``q`` (value, velocity and
acceleration at both ends: :class:`arm_control.trajectory.Trajectory`). The points are
placed adaptively in normalised time ``tau = t / T``: start with 8 equal segments (plus
the trapezoid's acceleration breaks, each as a pair of points ``BREAK_GAP`` apart in
``tau`` so that the acceleration jump sits inside a tiny segment instead of spoiling its
neighbours); interpolate each segment exactly as the controller does, check the distance
of the forward kinematics from the segment at ``CHECK_POINTS`` interior times per segment,
and halve every segment that deviates more than the tolerance (``LINE_TOLERANCE``, 0.05
mm). A segment that passes is then *proven* within the tolerance, not just sampled
(:func:`_line_bound`): it is evaluated at ``PROOF_STEPS + 1`` equally spaced times and
the distance between them bounded by the second derivative of the path, itself bounded
through a Bernstein bound on the quintic's third derivative; a segment the bound does not
clear is halved too. Repeat until every segment is proven. So the interpolated tip path,
at any time the controller samples it, is within the tolerance of the line (up to rounding,
~1e-15 m). Seven check points alone are not enough: the path peaks between them, and on
2000 random lines up to 3% above what they saw (0.0516 mm for a 0.05 mm threshold).
Tolerances below ``MIN_LINE_TOLERANCE`` (1 nm; 51 points for the everyday line, 99 at
most on 150 random lines) are refused: at 1e-15 m the segments shrink to the floor (``4
BREAK_GAP``) and the bound still fails, after half a second. Quintic Hermite interpolation is
invariant under uniform time scaling, so the placement holds for any duration (and
survives stretching). The finished trajectory is then checked once more at 1 ms steps (for
plans longer than ``MAX_VERIFY_SAMPLES`` ms at that many equal steps: the interpolated
path is the same in ``tau`` for any duration, so the check's density along the path is
what counts), in chunks of ``VERIFY_CHUNK`` samples; that worst deviation, what a 1 kHz
controller sees, is reported in :attr:`Plan.max_line_deviation`.

Bounded cost
------------
Every plan is bounded: at most ``MAX_DURATION`` s (a duration derived from tiny speed or
acceleration limits, or stretched to fit the torque limits, beyond it is refused with the
numbers), at most ``MAX_POINTS`` trajectory points, at most ``MAX_VERIFY_SAMPLES``
verification samples held ``VERIFY_CHUNK`` at a time. The worst case is measured by
``bench/bench_planner.py``.

Torque feasibility
------------------
Along a path fixed in ``tau``, the joint torque at duration ``T`` is, with ``u = 1 / T``,
``tau(u) = u^2 (D q_tautau + C(q, q_tau) q_tau) + u B q_tau + g(q)``: quadratic in ``u``
with the gravity term independent of the duration. The three coefficient arrays come from
two batched :meth:`TwoLinkArm.inverse_dynamics` calls (``u = 0`` and ``u = 1``) and
:meth:`TwoLinkArm.damping_torque`, on a grid of ``tau`` (the trajectory points, 1001
uniform points and both sides of every acceleration break). First ``u = 0`` (gravity
alone, infinitely slow) is checked: if it exceeds the limits no duration fits and the plan
is refused. Otherwise, if the requested duration exceeds the limits, bisection on ``u``
between ``0`` (feasible) and ``1 / T_requested`` (infeasible) keeps a feasible and an
infeasible end until they differ by less than ``STRETCH_TOLERANCE`` (0.5%); the feasible
end is the stretched duration (policy ``stretch``), or the plan is refused naming it
(policy ``refuse``). The bracket is valid whether or not the peak torque is monotonic in
the duration, so a plan returned is always within the limits and an infeasible duration
lies within 0.5% below it. "Within the limits" leaves the tracking its margin: at each
grid point the predicted torque stays within ``limits - TRACKING_MARGIN (limits - |g(q)|)``
(20% of the headroom above gravity, kept for the controller's feedback; gravity alone is
never cut, so what the limits can hold still fits).

From a moving arm
-----------------
A goal that comes while the arm moves (a joint faster than ``REST_SPEED``) first brings
it to rest, then holds ``STOP_DWELL`` s, then makes the motion from there
(:func:`plan_goal`). The 2-R arm stops **along its path** (:func:`plan_path_stop`): the
tip decelerates on the tangent of its path (for a straight line, the line itself) in the
shortest time the torque allows with the tracking margin, so it ends ``|w| T / 2`` on from
where it was (``w`` its velocity, ``T`` the stop's duration) and never leaves that
segment by more than the line tolerance (the reference; tracked, by the tracking error).
Measured on the demo's fast line (2.4 rad/s at its middle): 0.52 m on, 2.3 mm off the old
line, where the joint-space stop at ``joint_max_acceleration`` went 1.65 m off it; the line
after it deviates as the same line from rest does, unsaturated. Other arms, and a 2-R arm
whose tangent leaves the workspace or nears a singularity, stop joint by joint
(:func:`plan_stop`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, cast

import numpy as np

from arm_control.trajectory import Trajectory
from arm_dynamics.limits import JointLimits
from arm_dynamics.models import RobotModel, robot_model
from arm_dynamics.two_link import TwoLinkArm
from arm_planner.excitation import SWEEPS, ExcitationError, chirp
from arm_planner.kinematics import PlanningError, check_point, nearest_equivalent, solve_ik
from arm_planner.time_scaling import KINDS, TimeScaling, from_limits

MODES = ('regulation', 'straight_line', 'chirp')
PROFILES = ('set_point', 'synchronized')
FEASIBILITY = ('stretch', 'refuse')
ELBOW_CHOICES = ('up', 'down', 'keep')
NO_ELBOW = 'none'          # the elbow of a plan for an arm without closed-form IK
LINE_TOLERANCE = 5e-5     # m: controller-interpolated path vs the line, proven
INITIAL_SEGMENTS = 8
MIN_LINE_TOLERANCE = 1e-9  # m: finer line tolerances are refused (bounded cost)
CHECK_POINTS = 7          # interior check times per segment while refining
PROOF_STEPS = 64          # sub-intervals per segment of the bound (_line_bound)
BREAK_GAP = 1e-4          # tau: width of the segment holding an acceleration jump
MAX_POINTS = 20000
MAX_DURATION = 3600.0     # s: the longest plan (the planner's duration parameter's maximum)
MAX_VERIFY_SAMPLES = 200_001
VERIFY_CHUNK = 50_000
STRETCH_TOLERANCE = 0.005  # relative gap between feasible and infeasible durations
EVAL_POINTS = 1001
MIN_LENGTH = 1e-9         # m (line) / rad (joint move): shorter counts as no motion
VERIFY_STEP = 0.001       # s: final check of the interpolated line
REST_SPEED = 1e-3         # rad/s: a joint slower than this counts as at rest
STOP_KNOTS = 9            # points of the stop that brings a moving arm to rest
STOP_DWELL = 0.5          # s: held at rest after a stop, for the tracking to settle
STOP_MIN_DURATION = 0.1   # s: the shortest stop along the path (10 control periods at 100 Hz)
STOP_GROWTH = 1.25        # the path stop's duration search: x this per try, then bisection
#: Share of the headroom above gravity (``effort_limits - |g(q)|`` at each point of the
#: motion) that a plan leaves free for the controller's feedback: the predicted torque stays
#: within ``limits - TRACKING_MARGIN (limits - |g(q)|)``. A plan fitted to the limits
#: themselves leaves the tracking nothing, and the loop saturates (the line Ps -> (0.5, 1.2)
#: asked in 0.3 s: stretched to the limits, 0.637 s, it saturated 2.6% of the time and left
#: the line by 6.3 mm; with the margin, 0.714 s, never, 5.4 mm). Gravity alone is never
#: cut: a motion the limits can hold still fits, only slower.
TRACKING_MARGIN = 0.2
CHIRP_DWELL = 1.0         # s: held at the chirp's centre after moving there, to settle


@dataclass(frozen=True)
class Plan:
    """A planned motion and its predicted torque.

    Attributes
    ----------
    mode : 'regulation' or 'straight_line'
    profile : 'set_point', 'synchronized' (regulation) or 'line'
    times : (K,) s -- time from start of each point; ``times[0] == 0``.
    q, qd, qdd : (K, 2) rad, rad/s, rad/s^2 -- desired joint state at each point.
    ee_path : (K, 2) m -- forward kinematics of ``q``.
    duration : s -- ``times[-1]`` (0 for a set point).
    peak_torque : (2,) N m -- largest predicted ``|tau|`` per joint (inverse dynamics of
        the planner's model along the plan; for a set point the holding torque at the
        goal).
    margin : (2,) N m -- ``effort_limits - peak_torque`` (>= 0 for every returned plan).
    stretched_from : s or None -- the requested duration if the plan was slowed down to
        fit the limits.
    messages : human-readable notes (how the duration was chosen, stretching, ...).
    elbow : 'up' or 'down' -- branch of the final configuration.
    ee_start : (2,) m -- end-effector position when the plan was made.
    goal : (2,) m
    time_scaling : the scaling used (None for a set point).
    ee_velocity, ee_acceleration : (K, 2) m/s, m/s^2 -- ``J q'`` and its derivative.
    max_line_deviation : m or None -- straight line: worst distance from the segment of
        the controller-interpolated path, checked at 1 ms steps (at most
        ``MAX_VERIFY_SAMPLES`` equal steps). At any time in between it is within the
        line tolerance too (proven while placing the points).
    stop_duration : s -- time spent first bringing a moving arm to rest and holding it
        there (0: it started at rest); the motion proper (the line) starts then.
    """

    mode: str
    profile: str
    times: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    ee_path: np.ndarray
    duration: float
    peak_torque: np.ndarray
    margin: np.ndarray
    stretched_from: float | None
    messages: tuple[str, ...]
    elbow: str
    ee_start: np.ndarray
    goal: np.ndarray
    time_scaling: TimeScaling | None = None
    ee_velocity: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    ee_acceleration: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    max_line_deviation: float | None = None
    stop_duration: float = 0.0

    @property
    def display_path(self) -> np.ndarray:
        """(M, 2) m: the end-effector path to show (a set point: start and goal; a line
        after a stop: the line alone, from where the arm came to rest)."""
        if self.profile == 'set_point':
            return np.vstack([self.ee_start, self.ee_path])
        if self.profile == 'line' and self.stop_duration > 0.0:
            return self.ee_path[self.times >= self.stop_duration]
        return self.ee_path

    def summary(self, effort_limits=None) -> str:
        """One line: mode, duration, peak torque vs limits, stretched or not."""
        lim = ''
        if effort_limits is not None:
            lim = f' / limits {_fmt(effort_limits, 1)}'
        stretch = (f', stretched from {self.stretched_from:.3f} s'
                   if self.stretched_from is not None else ', not stretched')
        kind = f' {self.time_scaling.kind}' if self.time_scaling else ''
        return (f'{self.mode} ({self.profile}{kind}, elbow {self.elbow}) to '
                f'({self.goal[0]:.4f}, {self.goal[1]:.4f}) m: {self.duration:.3f} s, '
                f'{len(self.times)} points, peak torque {_fmt(self.peak_torque, 2)}{lim} N m'
                f'{stretch}')


@dataclass(frozen=True)
class PlannerSettings:
    """Everything :func:`plan_goal` needs besides the arm, its limits and the state.

    Units: ``duration`` s (0: derive from the speed limits), ``max_speed`` m/s,
    ``max_acceleration`` m/s^2, ``joint_max_velocity`` rad/s, ``joint_max_acceleration``
    rad/s^2, ``reach_margin`` m, ``singularity_margin`` on ``|sin q2|``, ``line_tolerance``
    m. See the ``planner`` node's parameters for the meaning of each. ``chirp_*``: mode
    chirp's excitation (:func:`plan_chirp`): amplitude rad (one value, or one per joint),
    band ``f0``..``f1`` Hz, ``duration`` s, ``sweep``, the joints moved (indices; empty:
    all) and ``period`` s, the control period the points are sampled on.
    """

    mode: str = 'regulation'
    elbow: str = 'keep'
    time_scaling: str = 'quintic'
    duration: float = 0.0
    max_speed: float = 0.5
    max_acceleration: float = 1.0
    joint_max_velocity: float = 1.5
    joint_max_acceleration: float = 3.0
    regulation_profile: str = 'set_point'
    feasibility: str = 'stretch'
    reach_margin: float = 0.01
    singularity_margin: float = 0.1
    line_tolerance: float = LINE_TOLERANCE
    chirp_amplitude: tuple[float, ...] = (0.001,)
    chirp_f0: float = 0.05
    chirp_f1: float = 17.0
    chirp_duration: float = 40.0
    chirp_sweep: str = 'log'
    chirp_joints: tuple[int, ...] = ()
    chirp_period: float = 0.01


def make_arm(robot: dict) -> RobotModel:
    """The planner's model from robot parameters (the ROBOT_PARAMS names, ``model`` naming
    the kind; extra keys are ignored)."""
    return robot_model(robot)


def plan_goal(arm: RobotModel, effort_limits, q_current, goal,
              settings: PlannerSettings, joint_limits: JointLimits | None = None,
              qd_current=None) -> Plan:
    """Plan per ``settings.mode``: :func:`plan_regulation` or :func:`plan_straight_line`.

    From a moving arm (``qd_current`` faster than ``REST_SPEED`` at some joint) the plan
    first brings it to rest, blending from its velocity with no jump in velocity: the 2-R
    arm along the path it is on (:func:`plan_path_stop`: the tip stays on the tangent of
    its path, within ``|w| T / 2`` of where it was), others joint by joint
    (:func:`plan_stop`); it holds it there ``STOP_DWELL`` s (a hard stop leaves a tracking
    error that would otherwise spill into the line: 6.6 mm at 20 rad/s^2 without the
    hold), then makes the motion from there: a straight line then starts at rest on its
    own line, so the tip keeps the same deviation bound as from rest. A set point is not
    preceded by a stop (it is a step anyway).

    Parameters
    ----------
    arm : the planner's model.
    effort_limits : (2,) N m, > 0
    q_current : (2,) rad -- measured joint positions (the plan starts here).
    goal : (2,) m -- end-effector target in the base frame.
    settings : PlannerSettings
    qd_current : (2,) rad/s or None -- measured joint velocities (None: at rest).
    joint_limits : the arm's joint limits (None: none): goals, lines and joint speeds stay
        within them (speeds by stretching the duration, or refusing, per ``feasibility``).

    Raises
    ------
    PlanningError
        With the reason, naming the numbers.
    """
    s = settings
    if s.mode == 'straight_line' and not closed_form_ik(arm):
        raise PlanningError(
            f'straight lines need closed-form inverse kinematics, which only the 2-R arm '
            f'(model two_link) has; this arm has {arm.n_dof} joints: use mode regulation')
    moving = qd_current is not None and not (
        np.abs(np.asarray(qd_current, dtype=float)) < REST_SPEED).all()
    set_point = s.mode == 'regulation' and s.regulation_profile == 'set_point'
    if moving and not set_point:
        stop = _stop(arm, effort_limits, q_current, qd_current, s, joint_limits)
        rest = plan_goal(arm, effort_limits, stop.q[-1], goal, s, joint_limits)
        if stop.duration + STOP_DWELL + rest.duration > MAX_DURATION:
            raise PlanningError(f'the stop ({stop.duration:.4g} s) and the motion '
                                f'({rest.duration:.4g} s) together are longer than '
                                f'{MAX_DURATION:g} s, the longest plan')
        return _after_stop(arm, effort_limits, stop, rest)
    common: dict[str, Any] = dict(
        elbow=s.elbow, time_scaling=s.time_scaling, duration=s.duration,
        feasibility=s.feasibility, reach_margin=s.reach_margin,
        singularity_margin=s.singularity_margin, joint_limits=joint_limits)
    if s.mode == 'regulation':
        return plan_regulation(arm, effort_limits, q_current, goal,
                               profile=s.regulation_profile,
                               joint_max_velocity=s.joint_max_velocity,
                               joint_max_acceleration=s.joint_max_acceleration, **common)
    if s.mode == 'chirp':
        return plan_chirp(arm, effort_limits, q_current, goal, s, joint_limits)
    if s.mode == 'straight_line':
        return plan_straight_line(cast(TwoLinkArm, arm), effort_limits, q_current, goal,
                                  max_speed=s.max_speed,
                                  max_acceleration=s.max_acceleration,
                                  tolerance=s.line_tolerance, **common)
    raise ValueError(f"mode must be one of {', '.join(MODES)}, got {s.mode!r}")


# ---------------------------------------------------------------------- stopping
def _stop(arm: RobotModel, effort_limits, q_current, qd_current, s: PlannerSettings,
          joint_limits: JointLimits | None) -> Plan:
    """The stop :func:`plan_goal` makes from a moving arm: along the path it is on
    (:func:`plan_path_stop`) for the 2-R arm, else, or where that stop cannot be made (a
    singular start, a tangent leaving the workspace), each joint on its own
    (:func:`plan_stop`), the reason why in the plan's messages."""
    if not closed_form_ik(arm):
        return plan_stop(arm, effort_limits, q_current, qd_current,
                         joint_max_acceleration=s.joint_max_acceleration,
                         joint_limits=joint_limits)
    try:
        return plan_path_stop(cast(TwoLinkArm, arm), effort_limits, q_current, qd_current,
                              reach_margin=s.reach_margin,
                              singularity_margin=s.singularity_margin,
                              tolerance=s.line_tolerance, joint_limits=joint_limits)
    except PlanningError as exc:
        why = str(exc)
    stop = plan_stop(arm, effort_limits, q_current, qd_current,
                     joint_max_acceleration=s.joint_max_acceleration,
                     joint_limits=joint_limits)
    return replace(stop, messages=(*stop.messages, f'(joint by joint: {why})'))


def plan_stop(arm: RobotModel, effort_limits, q_current, qd_current, *,
              joint_max_acceleration=3.0, joint_limits: JointLimits | None = None) -> Plan:
    """Bring a moving arm to rest: each joint ``q(t) = q0 + v T (s - s^3 + s^4 / 2)``,
    ``s = t / T``, so velocity ``v (1 - 3 s^2 + 2 s^3)`` falls from ``v`` to 0 with zero
    acceleration at both ends (no jump in the command). It travels ``v T / 2``, its peak
    deceleration is ``1.5 |v| / T``.

    ``T`` is the shortest within ``joint_max_acceleration`` [rad/s^2] (scalar or per joint),
    lengthened by 25% steps until the predicted torque fits ``effort_limits``. Refused
    (PlanningError) if no ``T`` up to ``MAX_DURATION`` fits, or if the arm cannot come to
    rest inside ``joint_limits``.
    """
    n = arm.n_dof
    limits = _positive_pair('effort_limits', effort_limits, n)
    q0 = np.asarray(q_current, dtype=float)
    v = np.asarray(qd_current, dtype=float)
    if q0.shape != (n,) or v.shape != (n,) or not (np.isfinite(q0).all()
                                                   and np.isfinite(v).all()):
        raise PlanningError(f'the current joint state must be finite ({n} positions, {n} '
                            f'velocities), got {q0.ravel().tolist()}, {v.ravel().tolist()}')
    amax = _positive_pair('joint_max_acceleration', joint_max_acceleration, n)
    now = np.abs(arm.inverse_dynamics(q0, v, np.zeros(n)))  # the stop's first instant
    if (now > limits).any():
        j = int(np.argmax(now / limits))
        raise PlanningError(
            f'the arm moving at {_fmt(v, 3)} rad/s is beyond its effort limits already: '
            f'at q = {_fmt(q0, 4)} rad gravity and the velocity terms alone need '
            f'{now[j]:.2f} N m at joint {j + 1} > limit {limits[j]:g} N m; no stop fits')
    duration = float((1.5 * np.abs(v) / amax).max())
    s = np.linspace(0.0, 1.0, EVAL_POINTS)[:, None]
    while True:
        if not duration <= MAX_DURATION:
            raise PlanningError(
                f'the arm moving at {_fmt(v, 3)} rad/s cannot be brought to rest within '
                f'{MAX_DURATION:g} s (joint_max_acceleration {_fmt(amax, 3)} rad/s^2, '
                f'effort limits {_fmt(limits, 1)} N m)')
        q, qd, qdd = _stop_states(q0, v, duration, s)
        peak = np.abs(arm.inverse_dynamics(q, qd, qdd)).max(axis=0)
        if (peak <= limits).all():
            break
        duration *= 1.25
    if joint_limits is not None:
        outside = joint_limits.position_violation(q, 'would reach')
        if outside:
            raise PlanningError('the moving arm cannot come to rest within its joint '
                                f'limits: {outside.split(" (")[0]}')
    knots = np.linspace(0.0, 1.0, STOP_KNOTS)
    qk, qdk, qddk = _stop_states(q0, v, duration, knots[:, None])
    note = (f'the arm was moving at {_fmt(v, 3)} rad/s: brought to rest first, in '
            f'{duration:.3f} s at q = {_fmt(qk[-1], 4)} rad (peak torque {_fmt(peak, 2)} '
            'N m)')
    jac = arm.jacobian(qk)
    return Plan(mode='stop', profile='stop', times=knots * duration, q=qk, qd=qdk, qdd=qddk,
                ee_path=arm.forward_kinematics(qk), duration=duration, peak_torque=peak,
                margin=limits - peak, stretched_from=None, messages=(note,),
                elbow=_elbow_of(arm, qk[-1]), ee_start=arm.forward_kinematics(q0),
                goal=arm.forward_kinematics(qk[-1]),
                ee_velocity=np.einsum('kij,kj->ki', jac, qdk),
                ee_acceleration=np.einsum('kij,kj->ki', jac, qddk) + arm.jdot_qd(qk, qdk),
                stop_duration=duration)


class _NoBreaks:
    """What :func:`_line_knots` reads of a time scaling: no acceleration breaks (the stop's
    profile is one polynomial)."""

    breaks: tuple[float, ...] = ()


def plan_path_stop(arm: TwoLinkArm, effort_limits, q_current, qd_current, *,
                   reach_margin: float = 0.01, singularity_margin: float = 0.1,
                   tolerance: float = LINE_TOLERANCE,
                   joint_limits: JointLimits | None = None) -> Plan:
    """Bring a moving 2-R arm to rest **along the path it is on**: the tip decelerates on
    the tangent of its path at the measured state (for a straight line, the line itself),
    ``x(t) = x0 + w T (s - s^3 + s^4 / 2)``, ``s = t / T``, ``w = J(q0) q0'`` its velocity,
    so the tip's speed falls from ``|w|`` to 0 with zero acceleration at both ends. The tip
    stays on that tangent (the controller-interpolated path proven within ``tolerance`` of
    it, as a line's) and ends ``|w| T / 2`` from ``x0``: that is the stop's whole excursion
    from where the arm was when the goal came.

    ``T`` is the shortest duration (at least ``STOP_MIN_DURATION``, found to
    ``STRETCH_TOLERANCE``) whose predicted torque leaves the tracking margin free
    (:data:`TRACKING_MARGIN`): the shorter the stop, the shorter its excursion.

    Raises
    ------
    PlanningError
        The start is too near a singularity, the tangent leaves the workspace (less
        ``reach_margin``), nears a singularity or a joint limit before the arm can stop on
        it, or no duration up to ``MAX_DURATION`` fits the limits; the caller may stop in
        joint space instead (:func:`plan_stop`).
    """
    limits = _positive_pair('effort_limits', effort_limits)
    q0 = np.asarray(q_current, dtype=float)
    v = np.asarray(qd_current, dtype=float)
    if q0.shape != (2,) or v.shape != (2,) or not (np.isfinite(q0).all()
                                                   and np.isfinite(v).all()):
        raise PlanningError(f'the current joint state must be finite (2 positions, 2 '
                            f'velocities), got {q0.ravel().tolist()}, {v.ravel().tolist()}')
    if abs(math.sin(q0[1])) < singularity_margin:
        raise PlanningError(f'the arm is too near a singularity to stop along its path: '
                            f'|sin q2| = {abs(math.sin(q0[1])):.4f} < singularity_margin '
                            f'{singularity_margin:g}')
    branch = str(arm.elbow_of(q0))
    x0 = arm.forward_kinematics(q0)
    w = arm.jacobian(q0) @ v
    speed = float(np.hypot(*w))
    if not speed > MIN_LENGTH:
        raise PlanningError(f'the tip is not moving (joints at {_fmt(v, 3)} rad/s): '
                            'no path to stop along')

    def states_for(duration: float):
        end = x0 + 0.5 * duration * w

        def states(tau):
            # (q, q', q'') per unit tau, as plan_straight_line's states: the joint path
            # unwrapped along a dense grid from q0's whole turns.
            dense, index = np.unique(np.concatenate([np.linspace(0.0, 1.0, 257), tau]),
                                     return_inverse=True)
            x = x0 + duration * w * _stop_profile(dense[:, None])[0]
            q = np.unwrap(arm.inverse_kinematics(x, branch), axis=0)
            q = (q + 2.0 * np.pi * np.round((q0 - q[0]) / (2.0 * np.pi)))[index[257:]]
            _, dp, ddp = _stop_profile(np.asarray(tau)[:, None])
            return _joint_states(arm, q, duration * w * dp, duration * w * ddp)
        return end, states

    def fits(duration: float) -> tuple[bool, Any]:
        """Whether a stop of ``duration`` fits, and (states, grid values, peak) if so."""
        end, states = states_for(duration)
        try:
            _check_line(arm, x0, end, reach_margin, singularity_margin)
        except PlanningError:
            return False, None  # longer stops reach further: none fits
        grid = np.linspace(0.0, 1.0, EVAL_POINTS)
        qg, dqg, ddqg = states(grid)
        if joint_limits is not None and joint_limits.position_violation(qg):
            return False, None
        u = 1.0 / duration
        tau = arm.inverse_dynamics(qg, dqg * u, ddqg * u * u)
        usable = _usable(limits, arm.gravity_vector(qg))
        return bool((np.abs(tau) <= usable).all()), (states, np.abs(tau).max(axis=0))

    lo, hi = 0.0, STOP_MIN_DURATION  # lo: too short (or none tried); hi: to try
    found = None
    while found is None:
        if hi > MAX_DURATION:
            raise PlanningError(f'the arm moving at {_fmt(v, 3)} rad/s cannot be brought to '
                                f'rest along its path within {MAX_DURATION:g} s and the '
                                f'effort limits {_fmt(limits, 1)} N m')
        ok, data = fits(hi)
        if ok:
            found = (hi, data)
        elif data is None:  # the tangent leaves the workspace or the joint limits
            why = (f'even the shortest stop along it ({hi:g} s) would take it '
                   f'{0.5 * hi * speed:.3f} m on' if lo == 0.0 else
                   f'within the effort limits a stop along it takes longer than {lo:.3f} s, '
                   f'and one of {hi:.3f} s would take it {0.5 * hi * speed:.3f} m on')
            raise PlanningError(f'the arm moving at {_fmt(v, 3)} rad/s (tip {speed:.3f} '
                                f'm/s) cannot stop along its path: {why}, out of the '
                                'workspace, near a singularity or past a joint limit')
        else:
            lo, hi = hi, hi * STOP_GROWTH
    duration, (states, peak) = found
    if lo > 0.0:  # bisection between a duration too short and one that fits
        while duration - lo > STRETCH_TOLERANCE * lo:
            mid = 0.5 * (lo + duration)
            ok, data = fits(mid)
            if ok:
                duration, (states, peak) = mid, data
            else:
                lo = mid
    end = x0 + 0.5 * duration * w
    knots = _line_knots(arm, cast(TimeScaling, _NoBreaks()), states, x0, end, tolerance)
    qk, dqk, ddqk = states(knots)
    u = 1.0 / duration
    qd, qdd = dqk * u, ddqk * u * u
    qk[0], qd[0] = q0, v  # exactly the measured state (IK(FK(q0)) differs by rounding)
    qd[-1] = 0.0
    note = (f'the arm was moving at {_fmt(v, 3)} rad/s (tip {speed:.3f} m/s): brought to '
            f'rest first, along its path, in {duration:.3f} s, {0.5 * duration * speed:.4f} '
            f'm on from ({x0[0]:.4f}, {x0[1]:.4f}) m, at q = {_fmt(qk[-1], 4)} rad (peak '
            f'torque {_fmt(peak, 2)} N m)')
    jac = arm.jacobian(qk)
    return Plan(mode='stop', profile='stop', times=knots * duration, q=qk, qd=qd, qdd=qdd,
                ee_path=arm.forward_kinematics(qk), duration=duration, peak_torque=peak,
                margin=limits - peak, stretched_from=None, messages=(note,), elbow=branch,
                ee_start=x0, goal=arm.forward_kinematics(qk[-1]),
                ee_velocity=np.einsum('kij,kj->ki', jac, qd),
                ee_acceleration=np.einsum('kij,kj->ki', jac, qdd) + arm.jdot_qd(qk, qd),
                stop_duration=duration)


def _stop_profile(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``p(s) = s - s^3 + s^4 / 2`` and its first two derivatives: from speed 1 to rest,
    zero acceleration at both ends, ``p(1) = 1 / 2``."""
    return s - s**3 + 0.5 * s**4, 1.0 - 3.0 * s**2 + 2.0 * s**3, -6.0 * s + 6.0 * s**2


def _stop_states(q0, v, duration: float, s: np.ndarray) -> tuple[np.ndarray, ...]:
    """Joint (q, qd, qdd) of :func:`plan_stop` at normalised times ``s`` (K, 1)."""
    q = q0 + v * duration * (s - s**3 + 0.5 * s**4)
    qd = v * (1.0 - 3.0 * s**2 + 2.0 * s**3)
    qdd = v / duration * (-6.0 * s + 6.0 * s**2)
    return q, qd, qdd


def _after_stop(arm: RobotModel, effort_limits, stop: Plan, rest: Plan) -> Plan:
    """``rest`` (planned from where ``stop`` ends, at rest) after ``stop`` and a
    ``STOP_DWELL`` hold, as one plan."""
    limits = _positive_pair('effort_limits', effort_limits)
    if len(rest.times) == 1:  # already at the goal once at rest: the stop ends there
        times, profile, start = stop.times, 'stop', stop.duration
        q = np.vstack([stop.q[:-1], rest.q])
        qd, qdd = stop.qd, stop.qdd
    else:  # rest's first point is where the stop ends; held there, then the motion
        start = stop.duration + STOP_DWELL
        times, profile = np.concatenate([stop.times, start + rest.times]), rest.profile
        q = np.vstack([stop.q, rest.q])
        qd = np.vstack([stop.qd, rest.qd])
        qdd = np.vstack([stop.qdd, rest.qdd])
    jac = arm.jacobian(q)
    peak = np.maximum(stop.peak_torque, rest.peak_torque)
    return Plan(mode=rest.mode, profile=profile, times=times, q=q, qd=qd, qdd=qdd,
                ee_path=arm.forward_kinematics(q), duration=float(times[-1]),
                peak_torque=peak, margin=limits - peak, stretched_from=rest.stretched_from,
                messages=stop.messages + rest.messages, elbow=rest.elbow,
                ee_start=stop.ee_start, goal=rest.goal, time_scaling=rest.time_scaling,
                ee_velocity=np.einsum('kij,kj->ki', jac, qd),
                ee_acceleration=np.einsum('kij,kj->ki', jac, qdd) + arm.jdot_qd(q, qd),
                max_line_deviation=rest.max_line_deviation, stop_duration=start)


# ---------------------------------------------------------------------- regulation
def plan_regulation(arm: RobotModel, effort_limits, q_current, goal, *, elbow: str = 'keep',
                    profile: str = 'set_point', time_scaling: str = 'quintic',
                    duration: float = 0.0, joint_max_velocity=1.5,
                    joint_max_acceleration=3.0, feasibility: str = 'stretch',
                    reach_margin: float = 0.01, singularity_margin: float = 0.1,
                    joint_limits: JointLimits | None = None) -> Plan:
    """Reach ``goal`` in joint space.

    Parameters
    ----------
    arm : TwoLinkArm
    effort_limits : (2,) N m
    q_current : (2,) rad
    goal : (2,) m
    elbow : 'up', 'down' or 'keep' (the branch of ``q_current``) -- see
        :mod:`arm_dynamics.two_link`. Each goal joint angle is taken within pi of the
        current one (shortest motion; the arm has no joint position limits).
    profile : 'set_point' (one point at t = 0: the goal angles) or 'synchronized'
        (``q0 + (qf - q0) s(t)``, both joints start and stop together).
    time_scaling : 'quintic' or 'trapezoidal' (synchronized only).
    duration : s -- 0: the shortest duration meeting ``joint_max_velocity`` [rad/s] and
        ``joint_max_acceleration`` [rad/s^2] (scalars or per joint) on the slowest joint.
    feasibility : 'stretch' or 'refuse' -- what to do when the torque would exceed the
        limits (a set point cannot be stretched: it is refused only if holding the goal
        against gravity exceeds them).
    reach_margin : m; singularity_margin : on ``|sin q2|`` -- goal checks.

    Returns
    -------
    Plan
    """
    limits, q_current, goal = _common_inputs(effort_limits, q_current, goal, arm.n_dof)
    _choice('profile', profile, PROFILES)
    _choice('time_scaling', time_scaling, KINDS)
    _choice('feasibility', feasibility, FEASIBILITY)
    if closed_form_ik(arm):
        two_link = cast(TwoLinkArm, arm)
        branch = _branch(two_link, elbow, q_current)
        check_point(two_link, goal, reach_margin, singularity_margin)
        q_goal = nearest_equivalent(two_link.inverse_kinematics(goal, branch), q_current)
    else:  # any planar chain: numeric IK from where the arm is; no elbow to choose
        branch = NO_ELBOW
        q_goal = nearest_equivalent(solve_ik(arm, goal, q_current, reach_margin), q_current)
    if joint_limits is not None:
        q_goal = _within_limits(q_goal, q_current, joint_limits, goal)
    ee_start = arm.forward_kinematics(q_current)
    delta = q_goal - q_current
    if profile == 'set_point' or np.abs(delta).max() < MIN_LENGTH:
        note = ('already at the goal: holding it' if profile == 'synchronized' else
                'set point: the trajectory is the goal angles at t = 0; the predicted '
                'torque is the holding (gravity) torque at the goal, the transient depends '
                "on the controller's gains")
        return _set_point(arm, limits, q_goal, goal, ee_start, branch, 'regulation', note)
    vmax = _positive_pair('joint_max_velocity', joint_max_velocity, arm.n_dof)
    amax = _positive_pair('joint_max_acceleration', joint_max_acceleration, arm.n_dof)
    messages = []
    if duration > 0.0:
        scaling = _requested(time_scaling, duration)
        messages.append(f'duration {duration:g} s as requested')
    else:
        moved = np.abs(delta)
        scaling = _from_limits(time_scaling, float((moved / vmax).max()),
                               float((moved / amax).max()),
                               f'joint_max_velocity {_fmt(vmax, 3)} rad/s and '
                               f'joint_max_acceleration {_fmt(amax, 3)} rad/s^2 over '
                               f'{_fmt(moved, 4)} rad')
        messages.append(f'duration {scaling.duration:.3f} s from joint_max_velocity '
                        f'{_fmt(vmax, 3)} rad/s and joint_max_acceleration {_fmt(amax, 3)} '
                        'rad/s^2 on the slowest joint')

    def states(tau):
        s, ds, dds = scaling.normalised(tau)
        return (q_current + s[:, None] * delta, ds[:, None] * delta, dds[:, None] * delta)

    knots = _initial_knots(scaling, 50)
    return _finish(arm, limits, 'regulation', 'synchronized', branch, ee_start, goal,
                   scaling, knots, states, feasibility, messages, line=None,
                   joint_limits=joint_limits)


# ---------------------------------------------------------------------- straight line
def plan_straight_line(arm: TwoLinkArm, effort_limits, q_current, goal, *,
                       elbow: str = 'keep', time_scaling: str = 'quintic',
                       duration: float = 0.0, max_speed: float = 0.5,
                       max_acceleration: float = 1.0, feasibility: str = 'stretch',
                       reach_margin: float = 0.01, singularity_margin: float = 0.1,
                       tolerance: float = LINE_TOLERANCE,
                       joint_limits: JointLimits | None = None) -> Plan:
    """Move the end effector on the straight segment from where it is to ``goal``.

    Parameters
    ----------
    arm : TwoLinkArm
    effort_limits : (2,) N m
    q_current : (2,) rad -- the line starts at its forward kinematics, at rest.
    goal : (2,) m
    elbow : 'up', 'down' or 'keep'. The branch cannot change along a line (that would
        pass the stretched/folded singularity): asking for the other one is refused.
    time_scaling : 'quintic' or 'trapezoidal'.
    duration : s -- 0: the shortest duration with Cartesian speed <= ``max_speed`` [m/s]
        and acceleration <= ``max_acceleration`` [m/s^2]. A trapezoid with a given
        duration accelerates for the first third and decelerates for the last.
    feasibility : 'stretch' or 'refuse'.
    reach_margin : m; singularity_margin : minimum ``|sin q2|`` anywhere on the line.
    tolerance : m, >= ``MIN_LINE_TOLERANCE`` -- the controller-interpolated path stays
        this close to the line at every time (proven, see the module docstring).

    Returns
    -------
    Plan

    Raises
    ------
    PlanningError
        Goal unreachable/singular, line through or near a singularity, elbow flip
        needed, torque infeasible (per policy), ``tolerance`` below
        ``MIN_LINE_TOLERANCE`` or sampling cannot meet it.
    """
    limits, q_current, goal = _common_inputs(effort_limits, q_current, goal)
    _choice('time_scaling', time_scaling, KINDS)
    _choice('feasibility', feasibility, FEASIBILITY)
    if not tolerance >= MIN_LINE_TOLERANCE:
        raise PlanningError(f'line tolerance {tolerance:g} m is below {MIN_LINE_TOLERANCE:g} '
                            'm, the finest the line check proves at bounded cost')
    current = arm.elbow_of(q_current)
    branch = _branch(arm, elbow, q_current)
    check_point(arm, goal, reach_margin, singularity_margin)
    if branch != current:
        raise PlanningError(
            f'a straight line cannot flip the elbow: the arm is elbow-{current} now (q2 = '
            f'{q_current[1]:.4f} rad) and elbow {branch!r} was requested; the flip passes '
            "the stretched/folded singularity. Use mode regulation, or elbow 'keep'")
    start = arm.forward_kinematics(q_current)
    s_now = abs(math.sin(q_current[1]))
    if s_now < singularity_margin:
        raise PlanningError(
            f'the start configuration q = ({q_current[0]:.4f}, {q_current[1]:.4f}) rad is '
            f'too near a singularity: |sin q2| = {s_now:.4f} < singularity_margin '
            f'{singularity_margin:g}; a straight line cannot start there')
    delta = goal - start
    length = float(np.hypot(*delta))
    if length <= max(MIN_LENGTH, tolerance):
        # Within the line's own tolerance: no line to draw (it would last less than a
        # control period), the goal's angles held, a step of at most the tolerance.
        q_goal = q_current if length < MIN_LENGTH else nearest_equivalent(
            arm.inverse_kinematics(goal, branch), q_current)
        return _set_point(arm, limits, q_goal, goal, start, branch, 'straight_line',
                          f'already at the goal ({length:.2e} m away, within the line '
                          f'tolerance {tolerance:g} m): holding it')
    _check_line(arm, start, goal, reach_margin, singularity_margin)
    messages = []
    if duration > 0.0:
        scaling = _requested(time_scaling, duration)
        messages.append(f'duration {duration:g} s as requested')
    else:
        if not (max_speed > 0.0 and max_acceleration > 0.0):
            raise PlanningError(f'max_speed {max_speed!r} m/s and max_acceleration '
                                f'{max_acceleration!r} m/s^2 must be > 0 when duration is 0')
        scaling = _from_limits(time_scaling, length / max_speed, length / max_acceleration,
                               f'max_speed {max_speed:g} m/s and max_acceleration '
                               f'{max_acceleration:g} m/s^2 over {length:.4f} m')
        messages.append(f'duration {scaling.duration:.3f} s from max_speed {max_speed:g} m/s '
                        f'and max_acceleration {max_acceleration:g} m/s^2 over '
                        f'{length:.4f} m')

    def states(tau):
        # The joint path is unwrapped along a dense grid (no joint turns pi between its
        # neighbours) and starts at q_current's whole turns.
        dense, index = np.unique(np.concatenate([np.linspace(0.0, 1.0, 1025), tau]),
                                 return_inverse=True)
        s = scaling.normalised(dense)[0]
        q = np.unwrap(arm.inverse_kinematics(start + s[:, None] * delta, branch), axis=0)
        q = (q + 2.0 * np.pi * np.round((q_current - q[0]) / (2.0 * np.pi)))[index[1025:]]
        s, ds, dds = scaling.normalised(tau)
        return _joint_states(arm, q, ds[:, None] * delta, dds[:, None] * delta)

    line = (start, goal, tolerance)
    knots = _line_knots(arm, scaling, states, start, goal, tolerance)
    messages.append(f'{len(knots)} points placed adaptively (start {INITIAL_SEGMENTS} '
                    f'segments, halve any whose interpolated path may leave the line by '
                    f'more than {tolerance * 1e3:g} mm: checked at {CHECK_POINTS} points, '
                    f'then bounded between {PROOF_STEPS + 1})')
    return _finish(arm, limits, 'straight_line', 'line', branch, start, goal, scaling, knots,
                   states, feasibility, messages, line=line, joint_limits=joint_limits)


# ---------------------------------------------------------------------- internals
def _within_limits(q_goal: np.ndarray, q_current: np.ndarray, limits: JointLimits,
                   goal) -> np.ndarray:
    """The goal angles, shifted by whole turns per joint into the joint limits (nearest the
    current angles); refused with the numbers if no turn fits."""
    out = []
    for j, (q, now) in enumerate(zip(q_goal, q_current)):
        lo, hi = limits.lower[j], limits.upper[j]
        turns = [q + 2.0 * np.pi * k for k in range(-2, 3)]
        inside = [x for x in turns if lo <= x <= hi]
        if not inside:
            raise PlanningError(
                f'goal ({goal[0]:.4f}, {goal[1]:.4f}) m needs joint {j + 1} at {q:.4f} rad '
                f'(or whole turns from it), outside its limits [{lo:g}, {hi:g}] rad')
        out.append(min(inside, key=lambda x: abs(x - now)))
    return np.array(out)


def _requested(kind: str, duration: float) -> TimeScaling:
    if not duration <= MAX_DURATION:
        raise PlanningError(f'duration {duration:g} s is longer than {MAX_DURATION:g} s, the '
                            'longest plan')
    return TimeScaling(kind, float(duration))


def _from_limits(kind: str, speed_time: float, accel_time: float, what: str) -> TimeScaling:
    """:func:`from_limits`, refused with the numbers when the duration exceeds
    ``MAX_DURATION`` (degenerate limits such as 1e-6 m/s or 1e-300 rad/s^2)."""
    # Either scaling takes at least max(speed_time, sqrt(accel_time)): refuse on that
    # bound first, before a degenerate trapezoid (blend ~ 0) can be formed.
    bound = max(speed_time, math.sqrt(accel_time))
    if not math.isfinite(bound):
        took = 'longer than any float'
    elif bound > MAX_DURATION:
        took = f'at least {bound:.4g} s'
    else:
        scaling = from_limits(kind, speed_time, accel_time)
        if scaling.duration <= MAX_DURATION:
            return scaling
        took = f'{scaling.duration:.4g} s'
    raise PlanningError(f'the motion would take {took} with {what}: longer than '
                        f'{MAX_DURATION:g} s, the longest plan; raise the limits')


def _tuple(q) -> str:
    """Joint values as ``(a, b, ...)`` with 4 decimals."""
    return '(' + ', '.join(f'{float(v):.4f}' for v in np.ravel(q)) + ')'


def closed_form_ik(arm) -> bool:
    """Does the model offer closed-form inverse kinematics with an elbow choice (the 2-R
    arm)? Only then can the planner make straight lines."""
    return hasattr(arm, 'inverse_kinematics')


def _elbow_of(arm, q) -> str:
    return str(arm.elbow_of(q)) if closed_form_ik(arm) else NO_ELBOW


def _fmt(values, digits: int) -> str:
    return '[' + ', '.join(f'{float(v):.{digits}f}' for v in np.ravel(values)) + ']'


def _choice(name: str, value: str, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ValueError(f"{name} must be one of {', '.join(choices)}, got {value!r}")


def _positive_pair(name: str, value, n: int | None = None) -> np.ndarray:
    """``value`` (a scalar or one per joint) as (n,) positive numbers, or ValueError; n
    None: as many as given (a scalar: two)."""
    if n is None:
        n = int(np.size(value)) if np.ndim(value) else 2
    try:
        v = np.broadcast_to(np.asarray(value, dtype=float), (n,)).copy()
    except ValueError:
        raise ValueError(f'{name} must have {n} values (one per joint), got '
                         f'{np.ravel(value).tolist()}') from None
    if not (np.isfinite(v).all() and (v > 0).all()):
        raise ValueError(f'{name} must be > 0, got {np.ravel(value).tolist()}')
    return v


def _common_inputs(effort_limits, q_current, goal, n: int = 2) -> tuple[np.ndarray, ...]:
    limits = _positive_pair('effort_limits', effort_limits, n)
    q = np.asarray(q_current, dtype=float)
    if q.shape != (n,) or not np.isfinite(q).all():
        count = 'two' if n == 2 else str(n)
        raise PlanningError(f'the current joint positions must be {count} finite numbers, '
                            f'got {q.ravel().tolist()}')
    p = np.asarray(goal, dtype=float)
    if p.shape != (2,) or not np.isfinite(p).all():
        raise PlanningError(f'goal must be two finite numbers (x, y) in m, got '
                            f'{p.ravel().tolist()}')
    return limits, q, p


def _branch(arm: TwoLinkArm, elbow: str, q_current: np.ndarray) -> str:
    _choice('elbow', elbow, ELBOW_CHOICES)
    return str(arm.elbow_of(q_current)) if elbow == 'keep' else elbow


def _check_line(arm: TwoLinkArm, start, goal, reach_margin: float,
                singularity_margin: float) -> None:
    """Refuse a segment that leaves the reachable annulus or nears a singularity.

    ``|sin q2|`` depends on the distance ``r`` from the base only and is smallest at the
    ends of the annulus, so along a segment its minimum is at the point nearest the base
    or at the farther end.
    """
    l1, l2 = arm.link_lengths
    d = goal - start
    s_near = float(np.clip(-(start @ d) / (d @ d), 0.0, 1.0))
    near = start + s_near * d
    r_near = float(np.hypot(*near))
    r_far = max(float(np.hypot(*start)), float(np.hypot(*goal)))
    where = (f'the straight line from ({start[0]:.4f}, {start[1]:.4f}) to '
             f'({goal[0]:.4f}, {goal[1]:.4f}) m')
    inner = abs(l1 - l2) + reach_margin
    if r_near < inner:
        raise PlanningError(
            f'{where} passes r = {r_near:.4f} m from the base at ({near[0]:.4f}, '
            f'{near[1]:.4f}) m, inside |l1 - l2| + reach_margin = {inner:.4f} m')
    for r, label in ((r_near, 'nearest the base'), (r_far, 'farthest from the base')):
        s = float(arm.abs_sin_q2(r))
        if s < singularity_margin:
            raise PlanningError(
                f'{where} passes too near a singularity: |sin q2| = {s:.4f} < '
                f'singularity_margin {singularity_margin:g} at its point {label} '
                f'(r = {r:.4f} m); use mode regulation or another goal')


def _joint_states(arm: TwoLinkArm, q, xd, xdd) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``q' = J^-1 x'``, ``q'' = J^-1 (x'' - J' q')`` for (K, 2) arrays (any time unit)."""
    jac = arm.jacobian(q)
    det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]

    def solve(b):
        return np.stack([(jac[:, 1, 1] * b[:, 0] - jac[:, 0, 1] * b[:, 1]) / det,
                         (jac[:, 0, 0] * b[:, 1] - jac[:, 1, 0] * b[:, 0]) / det], -1)

    qd = solve(xd)
    return q, qd, solve(xdd - arm.jdot_qd(q, qd))


def _initial_knots(scaling: TimeScaling, segments: int) -> np.ndarray:
    """``segments`` equal steps in tau plus each break as a pair ``BREAK_GAP`` apart."""
    tau = np.linspace(0.0, 1.0, segments + 1)
    extra = [b for br in scaling.breaks for b in (br, br + BREAK_GAP)]
    tau = np.union1d(tau, extra)
    # Drop points closer than the break gap to a break pair (except the pair itself).
    keep = np.ones(len(tau), bool)
    for br in scaling.breaks:
        close = (np.abs(tau - br) < 2 * BREAK_GAP) & (tau != br) & (tau != br + BREAK_GAP)
        keep &= ~close
    return tau[keep]


def _segment_distance(points, start, goal) -> np.ndarray:
    """Distance [m] of points (..., 2) from the segment start-goal."""
    d = goal - start
    s = np.clip(((points - start) @ d) / (d @ d), 0.0, 1.0)
    return np.hypot(*np.moveaxis(points - start - s[..., None] * d, -1, 0))


def _line_knots(arm: TwoLinkArm, scaling: TimeScaling, states, start, goal,
                tolerance: float) -> np.ndarray:
    """Adaptive knot placement in tau (see the module docstring): every segment of the
    returned knots is proven within ``tolerance`` [m] of the line by :func:`_line_bound`."""
    tau = _initial_knots(scaling, INITIAL_SEGMENTS)
    frac = np.arange(1, CHECK_POINTS + 1) / (CHECK_POINTS + 1)
    proven = np.zeros(0)  # left ends (tau) of segments already proven within tolerance
    while len(tau) <= MAX_POINTS:
        q, qd, qdd = states(tau)
        traj = Trajectory(q[0], np.zeros(2), tau, q, qd, qdd)
        h = np.diff(tau)
        t = (tau[:-1, None] + h[:, None] * frac).ravel()
        dev = _segment_distance(arm.forward_kinematics(traj.sample_many(t)[0]), start, goal)
        bad = dev.reshape(len(h), CHECK_POINTS).max(axis=1) > tolerance
        todo = np.flatnonzero(~bad & ~np.isin(tau[:-1], proven))
        for chunk in np.array_split(todo, -(-len(todo) * PROOF_STEPS // VERIFY_CHUNK) or 1):
            if not len(chunk):
                continue
            bound = _line_bound(arm, traj, tau, (q, qd, qdd), chunk, start, goal)
            bad[chunk] = bound > tolerance
            proven = np.union1d(proven, tau[chunk][bound <= tolerance])
        if not bad.any():
            return tau
        short = bad & (h <= 4 * BREAK_GAP)
        if short.any():
            k = int(np.flatnonzero(short)[0])
            raise PlanningError(
                f'cannot keep the line within {tolerance * 1e3:g} mm: the segment at '
                f'{tau[k]:.6f}-{tau[k + 1]:.6f} of the motion is as short as it may get and '
                'may still leave it by more (a tolerance this fine is below what the check '
                'can prove)')
        tau = np.union1d(tau, tau[:-1][bad] + 0.5 * h[bad])
    raise PlanningError(f'cannot sample the line within {tolerance * 1e3:g} mm with '
                        f'{MAX_POINTS} points')


def _line_bound(arm: TwoLinkArm, traj: Trajectory, tau, knots, segments: np.ndarray,
                start, goal) -> np.ndarray:
    """Upper bound [m] on the distance from the segment ``start``-``goal`` of the
    controller-interpolated tip path, over all of each knot segment in ``segments``.

    Each knot segment is sampled at ``PROOF_STEPS + 1`` equally spaced times (its ends
    included); between two samples ``a``, ``b`` (``h`` apart) a C^2 function ``f`` stays
    within ``max(|f(a)|, |f(b)|) + h^2 / 8 sup|f''|`` (linear interpolation error), and
    ``sup|f''| <= max(|f''(a)|, |f''(b)|) + h / 2 sup|f'''|``. This bounds the signed
    distance ``e`` from the line (``e'' = n . p''``, ``p'' = J q'' + J' q'`` evaluated at the
    samples) and the overshoot beyond either end (along the line: ``u . p''``), with
    ``|n . p'''|, |u . p'''| <= |p'''|`` bounded by :func:`_jerk_bound`. The distance from
    the segment is at most ``hypot(|e|, overshoot)``. Exact up to rounding (~1e-15 m).

    Parameters
    ----------
    traj : the controller's interpolation of ``knots`` = (q, q', q'') (K, 2) at ``tau``
        (K,) [rad, rad per unit tau, ...].
    segments : (S,) indices k of the knot segments [tau_k, tau_k+1] to bound.

    Returns
    -------
    (S,) m
    """
    q, dq, ddq = knots
    m = PROOF_STEPS
    a, h = tau[segments], tau[segments + 1] - tau[segments]
    t = (a[:, None] + h[:, None] * (np.arange(m + 1) / m)).reshape(-1)
    qs, dqs, ddqs = (x.reshape(len(segments), m + 1, 2) for x in traj.sample_many(t))
    # The ends are the knots themselves: the quintic's one-sided values (after the last
    # point the controller holds the pose, so sample_many gives q' = q'' = 0 at tau = 1).
    for j, k in ((0, segments), (m, segments + 1)):
        qs[:, j], dqs[:, j], ddqs[:, j] = q[k], dq[k], ddq[k]
    p = arm.forward_kinematics(qs) - start
    pdd = np.einsum('...ij,...j->...i', arm.jacobian(qs), ddqs) + arm.jdot_qd(qs, dqs)
    line = goal - start
    length = float(np.hypot(*line))
    u = line / length
    n = np.array([-u[1], u[0]])
    jerk = _jerk_bound(arm, h, q, dq, ddq, segments)[:, None]
    step = (h / m)[:, None]

    def pair_max(x):  # over the two ends of each sub-interval: (S, m)
        return np.maximum(x[:, :-1], x[:, 1:])

    def excess(f_dd):  # h^2/8 sup|f''| on each sub-interval
        return step**2 / 8.0 * (pair_max(np.abs(f_dd)) + step / 2.0 * jerk)

    across = pair_max(np.abs(p @ n)) + excess(pdd @ n)
    along, along_dd = p @ u, excess(pdd @ u)
    over = np.maximum(np.maximum(pair_max(-along), pair_max(along - length)) + along_dd, 0.0)
    return np.hypot(across, over).max(axis=1)


def _jerk_bound(arm: TwoLinkArm, h, q, dq, ddq, segments) -> np.ndarray:
    """Upper bound on ``|p'''|`` [m per unit tau^3] over each knot segment in ``segments``.

    ``p = sum_i l_i (cos th_i, sin th_i)`` with the link angles ``th_1 = q1``, ``th_2 = q1 +
    q2``, so ``|p'''| <= sum_i l_i (|th_i'''| + 3 |th_i'| |th_i''| + |th_i'|^3)``. Each
    ``th_i`` is the controller's quintic on the segment (width ``h``); its derivatives are
    bounded by their Bernstein coefficients (a polynomial on an interval lies within the
    range of its Bernstein coefficients), computed from the knot values, slopes and
    curvatures at both ends.
    """
    k0, k1 = segments, segments + 1
    hh = h[:, None]
    total = 0.0
    for length, mix in zip(arm.link_lengths, ([1.0, 0.0], [1.0, 1.0])):
        p0, v0, a0 = (x[k0] @ mix for x in (q, dq, ddq))
        p1, v1, a1 = (x[k1] @ mix for x in (q, dq, ddq))
        p0, v0, a0, p1, v1, a1 = (x[:, None] for x in (p0, v0, a0, p1, v1, a1))
        d1 = np.hstack([v0, v0 + hh * a0 / 4.0,
                        5.0 * (p1 - p0) / hh - 2.0 * (v0 + v1) + hh * (a1 - a0) / 4.0,
                        v1 - hh * a1 / 4.0, v1])
        d2 = 4.0 / hh * np.diff(d1, axis=1)
        d3 = 3.0 / hh * np.diff(d2, axis=1)
        b1, b2, b3 = (np.abs(d).max(axis=1) for d in (d1, d2, d3))
        total = total + length * (b3 + 3.0 * b1 * b2 + b1**3)
    return np.asarray(total)


def _torque_terms(arm: RobotModel, q, dq, ddq) -> tuple[np.ndarray, ...]:
    """Coefficients of ``tau(u) = a u^2 + b u + c``, ``u = 1 / T`` [1/s], each (M, 2) N m."""
    c = arm.inverse_dynamics(q, np.zeros_like(dq), np.zeros_like(ddq))
    b = arm.damping_torque(dq)
    a = arm.inverse_dynamics(q, dq, ddq) - b - c
    return a, b, c


def _usable(limits, gravity) -> np.ndarray:
    """The torque a plan may use at each grid point [N m]: the limits less
    ``TRACKING_MARGIN`` of the headroom above the gravity torque ``gravity`` there."""
    return limits - TRACKING_MARGIN * (limits - np.abs(gravity))


def _load(terms, limits, u: float) -> float:
    """Largest ``|tau| / usable`` (:func:`_usable`) over the grid and joints at ``u = 1 /
    T``; at most 1 when the plan leaves the tracking margin free."""
    a, b, c = terms
    return float((np.abs((a * u + b) * u + c) / _usable(limits, c)).max())


def _fit_duration(terms, limits, requested: float, policy: str, q_grid,
                  messages: list[str]) -> tuple[float, float | None]:
    """Duration that fits the effort limits (see the module docstring)."""
    a, b, c = terms
    if _load(terms, limits, 0.0) > 1.0:
        k, j = np.unravel_index(np.argmax(np.abs(c) / limits), c.shape)
        qk = q_grid[k]
        raise PlanningError(
            f'gravity alone exceeds the effort limits along the plan: holding q = '
            f'{_tuple(qk)} rad needs {abs(c[k, j]):.2f} N m at joint {j + 1} > '
            f'limit {limits[j]:g} N m; no duration fits')
    if _load(terms, limits, 1.0 / requested) <= 1.0:
        return requested, None
    if _load(terms, limits, 1.0 / MAX_DURATION) > 1.0:
        raise PlanningError(
            f'the predicted torque exceeds the effort limits {_fmt(limits, 1)} N m even at '
            f'{MAX_DURATION:g} s, the longest plan: the limits barely hold the arm against '
            'gravity along this motion')
    lo, hi = 1.0 / MAX_DURATION, 1.0 / requested  # u = 1/T: lo fits, hi does not
    while hi - lo > STRETCH_TOLERANCE * lo:
        mid = 0.5 * (lo + hi)
        if _load(terms, limits, mid) <= 1.0:
            lo = mid
        else:
            hi = mid
    fitted = 1.0 / lo
    peak = np.abs((a / requested + b) / requested + c).max(axis=0)
    what = (f'at duration {requested:.3f} s the predicted peak torque {_fmt(peak, 2)} N m '
            f'exceeds the limits {_fmt(limits, 1)} N m less the tracking margin '
            f'({TRACKING_MARGIN:.0%} of the headroom above gravity, kept for the feedback)')
    if policy == 'refuse':
        raise PlanningError(f'{what}; the fastest duration that fits is {fitted:.3f} s '
                            '(feasibility refuse)')
    messages.append(f'stretched from {requested:.3f} s to {fitted:.3f} s: {what} '
                    f'(bisection to {STRETCH_TOLERANCE:.1%})')
    return fitted, requested


# ---------------------------------------------------------------------- chirp
def plan_chirp(arm: RobotModel, effort_limits, q_current, goal, s: PlannerSettings,
               joint_limits: JointLimits | None = None) -> Plan:
    """Mode chirp: excite the arm about the goal's configuration (the frequency response,
    ``arm-sim analyze --frf``, docs/frf.md).

    The goal's joint angles (as regulation finds them) are the centre. An arm not already
    there is first moved there by a synchronized regulation profile and held
    ``CHIRP_DWELL`` s; then :func:`arm_planner.excitation.chirp` runs, one trajectory point
    every ``s.chirp_period`` s (positions, velocities and accelerations of the analytic
    chirp: the controller's reference equals it exactly at each state), the last point at
    the chirp's end, at rest at the centre. Refused (PlanningError naming the value) when
    the chirp's parameters are invalid, its points would be more than ``MAX_POINTS``, it
    leaves the joint limits, or the torque it needs (inverse dynamics of the planner's
    model along it) exceeds the effort limits: the message names the largest amplitude
    that fits, ``a * limit / peak``.
    """
    limits = _positive_pair('effort_limits', effort_limits, arm.n_dof)
    move = plan_regulation(arm, limits, q_current, goal, elbow=s.elbow,
                           profile='synchronized', time_scaling=s.time_scaling,
                           duration=s.duration, joint_max_velocity=s.joint_max_velocity,
                           joint_max_acceleration=s.joint_max_acceleration,
                           feasibility=s.feasibility, reach_margin=s.reach_margin,
                           singularity_margin=s.singularity_margin,
                           joint_limits=joint_limits)
    centre = move.q[-1]
    offset = 0.0 if move.duration == 0.0 else move.duration + CHIRP_DWELL
    _choice('chirp.sweep', s.chirp_sweep, SWEEPS)
    times = chirp_times(s.chirp_duration, s.chirp_period)
    if len(times) + len(move.times) > MAX_POINTS:
        raise PlanningError(f'chirp.duration {s.chirp_duration:g} s at one point every '
                            f'{s.chirp_period:g} s makes {len(times)} points > {MAX_POINTS}')
    try:
        q, qd, qdd = chirp(times, centre=centre, amplitude=np.asarray(s.chirp_amplitude),
                           f0=s.chirp_f0, f1=s.chirp_f1, duration=s.chirp_duration,
                           joints=list(s.chirp_joints) or None, sweep=s.chirp_sweep,
                           period=s.chirp_period,
                           lower=None if joint_limits is None else joint_limits.lower,
                           upper=None if joint_limits is None else joint_limits.upper)
    except ExcitationError as exc:
        raise PlanningError(f'chirp: {exc}') from None
    if joint_limits is not None:
        fast = joint_limits.velocity_violation(qd)
        if fast:
            raise PlanningError(f'chirp: {fast}')
    peak = np.abs(arm.inverse_dynamics(q, qd, qdd)).max(axis=0)
    moved = np.abs(q - centre).max(axis=0)
    if (peak > limits).any():
        j = int(np.argmax(peak / limits))
        scale = float((limits / peak).min())
        raise PlanningError(
            f'chirp: amplitude {_fmt(moved, 4)} rad up to {s.chirp_f1:g} Hz needs '
            f'{peak[j]:.1f} N m at joint {j + 1} > effort limit {limits[j]:g} N m; about '
            f'{_fmt(moved * scale, 4)} rad fits (or lower chirp.f1)')
    note = (f'chirp {s.chirp_sweep} {s.chirp_f0:g} -> {s.chirp_f1:g} Hz over '
            f'{s.chirp_duration:g} s, amplitude {_fmt(moved, 4)} rad about {_tuple(centre)} '
            'rad')
    if offset:
        times = np.concatenate([move.times, offset + times])
        q, qd, qdd = (np.vstack([a, b]) for a, b in ((move.q, q), (move.qd, qd),
                                                     (move.qdd, qdd)))
        peak = np.maximum(peak, move.peak_torque)
        note += f', after moving there ({move.duration:.3f} s) and holding {CHIRP_DWELL:g} s'
    jac = arm.jacobian(q)
    return Plan(mode='chirp', profile='chirp', times=times, q=q, qd=qd, qdd=qdd,
                ee_path=arm.forward_kinematics(q), duration=float(times[-1]),
                peak_torque=peak, margin=limits - peak, stretched_from=None,
                messages=(note,), elbow=move.elbow, ee_start=move.ee_start, goal=move.goal,
                ee_velocity=np.einsum('kij,kj->ki', jac, qd),
                ee_acceleration=np.einsum('kij,kj->ki', jac, qdd) + arm.jdot_qd(q, qd),
                stop_duration=offset)


def chirp_times(duration: float, period: float) -> np.ndarray:
    """The chirp's point times [s from its start]: every ``period`` s, and ``duration``."""
    count = int(math.floor(duration / period + 1e-9)) + 1
    times = np.arange(count) * period
    return times if times[-1] >= duration - 1e-12 else np.append(times, duration)


def _finish(arm: RobotModel, limits, mode: str, profile: str, branch: str, ee_start, goal,
            scaling: TimeScaling, knots: np.ndarray, states, policy: str,
            messages: list[str], line, joint_limits: JointLimits | None = None) -> Plan:
    """Joint limits (positions refused, speeds stretched or refused), torque check
    (stretch/refuse), then the trajectory arrays at the final duration."""
    grid = np.union1d(knots, np.linspace(0.0, 1.0, EVAL_POINTS))
    qg, dqg, ddqg = states(grid)
    requested = scaling.duration
    if joint_limits is not None:
        outside = joint_limits.position_violation(qg, 'would reach')
        if outside:
            raise PlanningError(f'the motion leaves the joint limits: {outside.split(" (")[0]}')
        # Joint speed is dq/dtau / T: the shortest duration within the speed limits.
        fastest = float((np.abs(dqg) / np.array(joint_limits.velocity)).max())
        if fastest > requested:
            what = (f'at duration {requested:.3f} s a joint would exceed its speed limit '
                    f'{_fmt(joint_limits.velocity, 1)} rad/s')
            if policy == 'refuse' or fastest > MAX_DURATION:
                raise PlanningError(f'{what}; the fastest duration within them is '
                                    f'{fastest:.3f} s (feasibility {policy})')
            messages.append(f'stretched from {requested:.3f} s to {fastest:.3f} s: {what}')
            requested = fastest
    terms = _torque_terms(arm, qg, dqg, ddqg)
    duration, stretched_from = _fit_duration(terms, limits, requested, policy, qg, messages)
    if requested != scaling.duration:
        stretched_from = scaling.duration
    scaling = scaling.with_duration(duration)
    u = 1.0 / duration
    tau_grid = arm.inverse_dynamics(qg, dqg * u, ddqg * u * u)
    peak = np.abs(tau_grid).max(axis=0)
    q, dq, ddq = states(knots)
    times = knots * duration
    times[0], times[-1] = 0.0, duration
    qd, qdd = dq * u, ddq * u * u
    jac = arm.jacobian(q)
    xd = np.einsum('kij,kj->ki', jac, qd)
    xdd = np.einsum('kij,kj->ki', jac, qdd) + arm.jdot_qd(q, qd)
    deviation = None
    if line is not None:
        start, end, tolerance = line
        traj = Trajectory(q[0], np.zeros(2), times, q, qd, qdd)
        n = min(MAX_VERIFY_SAMPLES, max(2, int(math.ceil(duration / VERIFY_STEP)) + 1))
        t = np.linspace(0.0, duration, n)
        deviation = max(float(_segment_distance(
            arm.forward_kinematics(traj.sample_many(chunk)[0]), start, end).max())
            for chunk in np.array_split(t, -(-n // VERIFY_CHUNK)))
        if deviation > tolerance:
            raise PlanningError(f'the interpolated line deviates {deviation * 1e3:.4f} mm > '
                                f'{tolerance * 1e3:g} mm (sampling failed)')
        messages.append(f'controller-interpolated path within {deviation * 1e6:.2f} um of '
                        f'the line (checked at {n} times, {duration / (n - 1) * 1e3:.3g} ms '
                        'apart)')
    return Plan(mode=mode, profile=profile, times=times, q=q, qd=qd, qdd=qdd,
                ee_path=arm.forward_kinematics(q), duration=duration, peak_torque=peak,
                margin=limits - peak, stretched_from=stretched_from,
                messages=tuple(messages), elbow=branch, ee_start=np.asarray(ee_start),
                goal=np.asarray(goal), time_scaling=scaling, ee_velocity=xd,
                ee_acceleration=xdd, max_line_deviation=deviation)


def _set_point(arm: RobotModel, limits, q_goal, goal, ee_start, branch: str, mode: str,
               note: str) -> Plan:
    """A one-point plan holding ``q_goal``; refused if gravity there exceeds the limits."""
    hold = np.abs(arm.gravity_vector(q_goal))
    if (hold > limits).any():
        j = int(np.argmax(hold / limits))
        raise PlanningError(
            f'holding the goal q = {_tuple(q_goal)} rad against gravity '
            f'needs {hold[j]:.2f} N m at joint {j + 1} > limit {limits[j]:g} N m')
    q = np.asarray(q_goal, dtype=float)[None, :]
    zero = np.zeros((1, len(q_goal)))
    return Plan(mode=mode, profile='set_point', times=np.zeros(1), q=q, qd=zero, qdd=zero,
                ee_path=arm.forward_kinematics(q), duration=0.0, peak_torque=hold,
                margin=limits - hold, stretched_from=None, messages=(note,), elbow=branch,
                ee_start=np.asarray(ee_start), goal=np.asarray(goal), time_scaling=None,
                ee_velocity=zero, ee_acceleration=zero)
