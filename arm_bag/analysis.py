"""Analyse a recorded run: split it into segments and compute their metrics (pure).

Everything is on simulated time (header stamps), so the figures depend only on the recorded
states, never on when the recorder received them. A joint state that comes again with the
same stamp (lockstep re-sends an unanswered state) counts once. A new segment starts at
each ``arm_controller/joint_trajectory`` message's start: its ``header.stamp`` (arm_sim's
planner stamps the simulated time it planned from), or, for a trajectory stamped zero ("on
arrival"), the first joint state received after it (a warning says so: that start depends
on the recording's latency). A trajectory equal to the one before it (the same nonzero
stamp and points: the planner sending it again until the controller confirms it) starts no
segment of its own. Joint states before the first trajectory are not analysed.
Per segment:

* ``mode``: ``straight_line`` if the segment's ``planner/path`` poses (the path stamped
  like the trajectory, else the one received closest to it, within 1 s before it or any
  time before the next one) -- or,
  with no path, the forward kinematics of the trajectory points -- are >= 3 points lying
  within 1e-6 m of the segment from the first to the last; else ``regulation``.
* tracking error = joint position minus reference: the ``arm_controller/reference``
  position with the same header stamp, or, with no reference topic, the trajectory's last
  point (the set point).
* which state: with ``simulator/true_joint_states`` in the bag (a simulator with sensor
  effects on publishes the true state beside the measured ``joint_states``, same stamps),
  every figure of the joint positions (tracking error, settling, overshoot, the tip's line
  deviation, energy) is computed on the true positions matched by stamp; without it, or
  if it misses a state's stamp (a warning says so), on ``joint_states``. The report says
  which (``state_source``). Torques are ``joint_states`` efforts either way.
* regulation: settling time (2% band of the step from the first position of the segment
  to the set point, per joint and overall = the largest) and overshoot (% of the step).
* straight_line: the end effector (forward kinematics of the recorded positions, link
  lengths from the ``arm_sim_robot`` record) against the commanded segment from the path's
  first pose to its last, from the path's start on (its first pose's stamp: later than the
  trajectory's when the planner first brought a moving arm to rest): its distance from the
  segment (a tip beyond an end is measured to that end, not to the infinite line) and how
  far it went along the line past the end and before the start (overshoot).
* torque: peak and RMS applied torque (JointState effort), saturated fraction
  (|effort| >= effort_limit - 1e-9), energy delivered (the exact work of the held torques,
  sum of tau_k . (q_k - q_(k-1)) over the actuated joints, each effort sample being the
  torque held over the period that ends there: a geared link's output beside its
  ``_motor`` entry is not counted).
* friction (a robot record with a non-zero ``coulomb_friction``, N m per joint of the
  model: a geared link's motor entry): ``friction_loss``, the energy the Coulomb friction
  took, ``sum_i c_i sum_k |q_i,k - q_i,(k-1)|`` over the same periods as the energy (so
  segments add up to the run), on the positions the figures use (true when the bag has
  them); exact but for a period in which a joint reverses (undercounted).
* pushes and faults (``simulator/events``, :attr:`arm_bag.reader.BagData.events`): each
  push's response over its window, from its start to the next push's start (or the end of
  the run): how far the tip (forward kinematics of the positions the figures use) and each
  joint get from where they should be -- the reference at the same stamps when the bag has
  one for every state of the window, else where they were at the push (the last state
  at or before it) -- and when the tip is back (:data:`arm_bag.metrics.PUSH_METRICS`); each
  fault's start and end. An end event is paired with the earliest open start of the same
  label and kind.

Times are header stamps (simulated time) relative to the segment's first joint state.

JSON (``Report.to_dict()``, ``arm-sim analyze --json``): NaN/undefined values are null;
per-joint values are lists in ``joint_names`` order.

* ``bag`` (str), ``joint_names`` [str], ``robot_source`` ("bag" | "defaults"),
  ``link_lengths`` [m], ``effort_limits`` [N m], ``message_counts`` {topic: count},
  ``truncated`` (bool), ``warnings`` [str], ``state_source`` ("true_joint_states" when
  the figures are computed on the true positions; absent: on ``joint_states``)
* ``run``: ``duration`` s, ``samples``, ``torque_peak`` / ``torque_rms`` [N m per joint],
  ``saturated_fraction`` [per joint], ``energy`` J
* ``segments``: list of

  - ``index``, ``mode`` ("regulation" | "straight_line" | null when there is no
    trajectory), ``start`` s (since the first joint state of the run), ``duration`` s,
    ``samples``, ``reference`` ("reference_topic" | "set_point" | null), ``set_point`` [rad]
  - ``line_start``, ``line_end`` [x, y m] (straight_line only, else null)
  - every metric of :data:`arm_bag.metrics.METRICS`, by its name (unit, per joint or not,
    meaning: that table; null where undefined, e.g. settling time on a line)
  - ``friction_loss`` J: only with friction (else absent; also ``run.friction_loss``)

* ``pushes`` (only when the bag has push events): list of ``time`` s (since the first
  joint state, as ``start``), ``time_ns`` (simulated, as in the bag), ``end`` s /
  ``end_ns`` (a pulse's end; null: none recorded), ``kind``, ``label``, ``description``,
  ``baseline`` ("reference" | "push_start": where the arm should be; null: no state in
  the window), then every metric of :data:`arm_bag.metrics.PUSH_METRICS`
  (``peak_deviation`` m and ``recovery_time`` s: null without end-effector metrics;
  ``peak_joint_deviation`` [rad per joint])
* ``faults`` (only when the bag has fault events): list of ``time``, ``time_ns``, ``end``,
  ``end_ns`` (null: no end event: to the end of the run), ``kind``, ``label``,
  ``description``
"""

from __future__ import annotations

import bisect
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from arm_bag import metrics
from arm_bag.reader import BagData, JointStates, PathMsg, SimEvent, read_bag
from arm_dynamics.models import RobotModel, joint_count, robot_model
from arm_dynamics.robot import ROBOT_DEFAULTS, resolve_robot

PATH_LEAD = 1_000_000_000  # ns: a path may arrive up to 1 s before its trajectory


class NothingToAnalyse(Exception):
    """The bag holds no joint states: no metric can be computed."""


@dataclass
class Segment:
    """One segment: where it is, and its metrics by name (:data:`arm_bag.metrics.METRICS`:
    ``seg.tracking_rms`` etc. read them; None where undefined)."""

    index: int
    mode: str | None
    start: float
    duration: float
    samples: int
    reference: str | None = None
    set_point: list | None = None
    line_start: list | None = None
    line_end: list | None = None
    values: dict = field(default_factory=dict)  # metric name -> JSON-ready value
    # arrays for plotting (not in to_dict)
    series: dict = field(default_factory=dict, repr=False)

    def __getattr__(self, name: str) -> Any:
        if name in metrics.METRIC_NAMES or name in metrics.SEGMENT_DISTURBANCE_METRICS:
            return self.__dict__.get('values', {}).get(name)
        raise AttributeError(f'{type(self).__name__} has no attribute {name!r}')

    def to_dict(self) -> dict:
        """JSON-ready: the place fields, then every metric of the table (None: undefined),
        then ``friction_loss`` if the segment has it."""
        out = {k: v for k, v in asdict(self).items() if k not in ('values', 'series')}
        out.update({name: self.values.get(name) for name in metrics.METRIC_NAMES})
        out.update({name: self.values[name] for name in metrics.SEGMENT_DISTURBANCE_METRICS
                    if name in self.values})
        return out


@dataclass
class Report:
    """Analysis of one bag."""

    bag: str
    joint_names: list[str]
    robot_source: str
    link_lengths: list[float]
    effort_limits: list[float]
    message_counts: dict[str, int]
    truncated: bool
    warnings: list[str]
    run: dict
    segments: list[Segment]
    #: The topic whose positions the figures use: 'true_joint_states' or 'joint_states'.
    state_source: str = 'joint_states'
    #: Each push with its response (keys: the module docstring), by time.
    pushes: list[dict] = field(default_factory=list)
    #: Each fault, its start and end, by time.
    faults: list[dict] = field(default_factory=list)

    def to_dict(self) -> dict:
        """JSON-ready dictionary (keys documented in the module docstring)."""
        out = {k: v for k, v in asdict(self).items() if k != 'segments'}
        if self.state_source == 'joint_states':
            del out['state_source']  # implied: reports of bags without true states unchanged
        for key in ('pushes', 'faults'):
            if not out[key]:
                del out[key]  # a bag without events: its report as it was
        out['segments'] = [seg.to_dict() for seg in self.segments]
        return _clean(out)


def _clean(x):
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    if isinstance(x, (np.floating, float)):
        return None if not math.isfinite(float(x)) else float(x)
    if isinstance(x, np.integer):
        return int(x)
    return x


def _list(a) -> list | None:
    return None if a is None else [None if not np.isfinite(v) else float(v)
                                   for v in np.asarray(a, np.float64).ravel()]


def analyze(path: str | Path) -> Report:
    """Read the bag at ``path`` and analyse it (raises reader.BagError, NothingToAnalyse)."""
    return analyze_data(read_bag(path, lean=True))


def _robot(bag: BagData, warnings: list[str], joints: int) -> tuple[str, list, list]:
    robot = bag.robot or {}
    source = 'bag' if bag.robot else 'defaults'
    if not bag.robot:
        warnings.append('no arm_sim_robot record in the bag: using the default robot '
                        f"(link lengths {ROBOT_DEFAULTS['link_lengths']} m; effort limits "
                        f"{ROBOT_DEFAULTS['effort_limits']} N m)")

    def get(name: str, fallback: list) -> list:
        value = robot.get(name)
        ok = (isinstance(value, list) and len(value) == joints
              and all(isinstance(v, (int, float)) and v > 0 for v in value))
        if value is not None and not ok:
            warnings.append(f'arm_sim_robot {name}={value!r} unusable; using {fallback}')
        return [float(v) for v in value] if ok and value is not None else list(fallback)

    lengths = get('link_lengths', ROBOT_DEFAULTS['link_lengths'])
    limits = get('effort_limits', ROBOT_DEFAULTS['effort_limits'][:joints]
                 + [math.inf] * max(0, joints - 2))
    return source, lengths, limits


def _coulomb(bag: BagData, names, warnings: list[str]) -> np.ndarray | None:
    """The robot record's ``coulomb_friction`` [N m] of the model's joints (the
    :func:`actuated` entries of ``names``: a geared link's motor), or None when it has
    none, or only zeros, or an unusable value (warned)."""
    value = (bag.robot or {}).get('coulomb_friction')
    if value is None or value == []:
        return None
    driven = int(actuated(names).sum())
    ok = (isinstance(value, list) and len(value) == driven
          and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                  and math.isfinite(v) and v >= 0 for v in value))
    if not ok:
        warnings.append(f'arm_sim_robot coulomb_friction={value!r} unusable (needs {driven} '
                        'values >= 0 N m): no friction_loss')
        return None
    c = np.array(value, dtype=np.float64)
    return c if c.any() else None


def _kinematics(bag: BagData, lengths: list, joints: int, warnings: list[str]
                ) -> RobotModel | None:
    """The arm whose forward kinematics give the end-effector metrics: the bag's robot
    model (``arm_sim_robot``'s ``model``; older bags and none: two_link) with its link
    lengths, or None (warned) when it does not have the bag's joint count."""
    kind = (bag.robot or {}).get('model', 'two_link')
    try:
        robot = resolve_robot({'model': kind, 'link_lengths': lengths})
        if joint_count(robot) == joints:
            return robot_model(robot)
    except ValueError:
        pass
    if kind in ('two_link', 'single_link_geared'):
        warnings.append(f'{joints} joints: no end-effector metrics (the 2-R model needs 2)')
    else:
        warnings.append(f'{joints} joints: no end-effector metrics (model {kind!r} with '
                        f'link lengths {lengths} does not describe them)')
    return None


def _unique_states(js: JointStates) -> JointStates:
    """``js`` without the states that repeat the previous one's stamp (re-sent states)."""
    if len(js) < 2:
        return js
    keep = np.r_[True, np.diff(js.stamp) != 0]
    if keep.all():
        return js
    return JointStates(js.topic, js.names, js.stamp[keep], js.log_time[keep],
                       js.position[keep], js.velocity[keep], js.effort[keep])


def _times(js: JointStates, warnings: list[str]) -> np.ndarray:
    """Sample times [ns]: header stamps if they increase, else receive times."""
    st = js.stamp
    if len(st) > 1 and (np.diff(st) < 0).any() or (len(st) > 1 and st[-1] == st[0]):
        warnings.append(f'{js.topic}: header stamps do not increase; using receive times')
        return js.log_time
    return st


def analyze_data(bag: BagData) -> Report:
    """Analyse what :func:`arm_bag.reader.read_bag` returned."""
    warnings = list(bag.warnings)
    js = bag.joint_states
    if js is not None:
        js = _unique_states(js)
    if js is None or len(js) == 0:
        raise NothingToAnalyse(f'{bag.path}: no joint_states messages (topics: '
                               + (', '.join(sorted(bag.topics)) or 'none') + ')')
    true = _true_state(bag, js, warnings)
    state_source = 'joint_states' if true is None else 'true_joint_states'
    js = js if true is None else true
    joints = len(js.names)
    source, lengths, limits = _robot(bag, warnings, joints)
    arm = _kinematics(bag, lengths, joints, warnings)
    t_ns = _times(js, warnings)
    t = (t_ns - t_ns[0]) * 1e-9
    ref = _reference(bag, js, warnings)
    trajs = [tr for tr in bag.trajectories if tr.trajectory.joint_names == js.names
             and len(tr.trajectory.positions)]
    if len(trajs) < len(bag.trajectories):
        warnings.append(f'{len(bag.trajectories) - len(trajs)} trajectories with other '
                        f'joint names or no points ignored')
    trajs = _without_resends(_valid_trajectories(trajs, warnings))
    coulomb = _coulomb(bag, js.names, warnings)
    run = {'duration': float(t[-1]), 'samples': len(js)}
    run.update(_torque(js.effort, js.position, limits, slice(None), js.names, coulomb))
    segments: list[Segment] = []
    if not trajs:
        warnings.append('no joint_trajectory messages: the whole run is one segment '
                        'without a set point')
        segments.append(_segment(0, None, None, slice(0, len(js)), t, js, ref, arm, limits,
                                 bag, warnings, coulomb))
    else:
        bounds = _segment_starts(trajs, js, t_ns, warnings)
        bounds.append(len(js))
        if bounds[0] > 0:
            warnings.append(f'{bounds[0]} joint states before the first trajectory not '
                            'analysed')
        for k, tr in enumerate(trajs):
            sl = slice(bounds[k], bounds[k + 1])
            if sl.stop - sl.start < 1:
                warnings.append(f'segment {k}: no joint states after its trajectory')
                continue
            nxt = trajs[k + 1].log_time if k + 1 < len(trajs) else None
            segments.append(_segment(k, tr, nxt, sl, t, js, ref, arm, limits, bag,
                                     warnings, coulomb))
    pushes, faults = _disturbances(bag.events, js, t_ns, ref, arm, warnings)
    return Report(bag=bag.path, joint_names=list(js.names), robot_source=source,
                  link_lengths=lengths, effort_limits=limits,
                  message_counts={k: v[1] for k, v in sorted(bag.topics.items())},
                  truncated=bag.truncated, warnings=warnings, run=_clean(run),
                  segments=segments, state_source=state_source,
                  pushes=_clean(pushes), faults=_clean(faults))


def _true_state(bag: BagData, js: JointStates, warnings: list[str]) -> JointStates | None:
    """``js`` with the true positions (``simulator/true_joint_states``, matched by stamp;
    a re-sent stamp's first) in place of the measured ones; None without true states, or
    when they do not cover every state of ``js`` (a warning says so)."""
    tr = bag.true_joint_states
    if tr is None or len(tr) == 0:
        return None
    if tr.names != js.names:
        warnings.append(f'{tr.topic}: joint names {list(tr.names)} differ from '
                        f'{list(js.names)}; figures from {js.topic}')
        return None
    rows, hit = _match_stamps(tr.stamp, tr.position, js.stamp, keep='first')
    if not hit.all():
        warnings.append(f'{tr.topic}: no true state for {int((~hit).sum())} of {len(js)} '
                        f'joint states; figures from the measured {js.topic}')
        return None
    return JointStates(js.topic, js.names, js.stamp, js.log_time, rows, js.velocity,
                       js.effort)


def _match_stamps(st: np.ndarray, pos: np.ndarray, stamps: np.ndarray,
                  keep: str) -> tuple[np.ndarray, np.ndarray]:
    """The row of ``pos`` (N, J) whose stamp ``st`` (N,) [ns] is each of ``stamps`` (M,),
    the ``keep='first'`` or ``'last'`` one of a repeated stamp: (rows (M, J), hit (M,)),
    the rows where ``hit`` is False being any row (the caller decides)."""
    if len(st) > 1 and not (st[1:] > st[:-1]).all():  # sort and drop repeats
        order = np.argsort(st, kind='stable')
        st, pos = st[order], pos[order]
        same = st[1:] == st[:-1]
        kept = np.r_[True, ~same] if keep == 'first' else np.r_[~same, True]
        st, pos = st[kept], pos[kept]
    i = np.clip(np.searchsorted(st, stamps), 0, len(st) - 1)
    return pos[i], st[i] == stamps


def _valid_trajectories(trajs, warnings: list[str]) -> list:
    """The trajectories the controller accepts (:func:`arm_control.trajectory.
    validate_trajectory`: finite values, increasing times, ...); each one it refuses is
    listed in ``warnings`` as refused, with the controller's reason, and starts no
    segment (the controller kept its reference, so the states after it stay in the
    segment before)."""
    from arm_control.trajectory import TrajectoryError, TrajectoryPoint, validate_trajectory

    kept = []
    for tr in trajs:
        m = tr.trajectory
        n = len(m.positions)
        points = [TrajectoryPoint(float(m.time_from_start[k]), m.positions[k],
                                  m.velocities[k] if k < len(m.velocities) else (),
                                  m.accelerations[k] if k < len(m.accelerations) else ())
                  for k in range(n)]
        try:
            validate_trajectory(m.joint_names, points, m.joint_names)
        except TrajectoryError as exc:
            warnings.append(f'trajectory received at {tr.log_time} ns (stamp {m.stamp} ns) '
                            f'refused as the controller refuses it ({exc}): not a segment')
            continue
        kept.append(tr)
    return kept


def _without_resends(trajs: list) -> list:
    """``trajs`` without the re-sends: a trajectory equal to the one before it (the same
    nonzero stamp, joints and points) is the planner sending it again until a controller
    confirms it, which the controller runs as the one it has: one motion, one segment."""
    kept: list = []
    for tr in trajs:
        m = tr.trajectory
        if kept and m.stamp and _same_trajectory(kept[-1].trajectory, m):
            continue
        kept.append(tr)
    return kept


def _same_trajectory(a, b) -> bool:
    return (a.stamp == b.stamp and a.joint_names == b.joint_names
            and np.array_equal(a.positions, b.positions)
            and np.array_equal(a.time_from_start, b.time_from_start)
            and len(a.velocities) == len(b.velocities)
            and all(np.array_equal(x, y) for x, y in zip(a.velocities, b.velocities))
            and len(a.accelerations) == len(b.accelerations)
            and all(np.array_equal(x, y) for x, y in zip(a.accelerations, b.accelerations)))


def _segment_starts(trajs, js: JointStates, t_ns: np.ndarray, warnings: list[str]) -> list[int]:
    """Index of the first joint state of each trajectory's segment: the first state at or
    after its start stamp (simulated time), or, unstamped, the first received after it."""
    on_stamps = t_ns is js.stamp
    starts = []
    unstamped = 0
    for tr in trajs:
        stamp = tr.trajectory.stamp
        if stamp and on_stamps:
            starts.append(int(np.searchsorted(js.stamp, stamp)))
        else:
            unstamped += 1
            starts.append(int(np.searchsorted(js.log_time, tr.log_time)))
    if unstamped:
        warnings.append(f'{unstamped} trajectories without a header stamp (or joint states '
                        'without increasing stamps): their segments start at the first joint '
                        'state received after them, which depends on recording latency')
    return starts


def _reference(bag: BagData, js: JointStates, warnings: list[str]) -> np.ndarray | None:
    """Reference positions (N, J) matched to the joint states by stamp (NaN: none)."""
    r = bag.reference
    if r is None or len(r) == 0:
        return None
    if r.names != js.names:
        warnings.append(f'reference joint names {list(r.names)} differ from '
                        f'{list(js.names)}; reference ignored')
        return None
    st, pos = r.stamp, r.position
    increasing = len(st) < 2 or bool((st[1:] > st[:-1]).all())
    if increasing and len(st) == len(js.stamp) and (st == js.stamp).all():
        return pos  # one reference per state, same increasing stamps (usual): no copy
    rows, hit = _match_stamps(st, pos, js.stamp, keep='last')  # the last reference wins
    out = np.full_like(js.position, np.nan)
    out[hit] = rows[hit]
    if not hit.any():
        warnings.append('no reference stamp matches a joint state stamp; reference ignored')
        return None
    return out


def actuated(names) -> np.ndarray:
    """Which JointState entries are driven by their own actuator: all but a geared link's
    output ``<j>`` published beside its motor ``<j>_motor``, whose power is the motor's
    passed through the gear (counting both would count the energy twice)."""
    listed = set(names)
    return np.array([f'{n}_motor' not in listed for n in names], dtype=bool)


_finite_rows = metrics.finite_rows


def _json(values: dict) -> dict:
    """Metric values as the report holds them: per-joint arrays as lists (NaN: None)."""
    return {k: _list(v) if isinstance(v, (np.ndarray, list)) else v for k, v in values.items()}


def _torque(effort, position, limits, sl, names, coulomb=None) -> dict:
    """Torque figures of the states ``sl``; the energy is the work of the torques the
    segment's states were answered with: the periods starting at its states, so the one
    ending at the next segment's first state too (segments add up to the run); the
    friction loss (``coulomb`` (J_driven,) N m, or None: none) over the same periods."""
    driven = actuated(names)
    held = slice(sl.start, None if sl.stop is None else sl.stop + 1)
    if driven.all():  # no copies: the same values either way
        work = effort[held], position[held]
    else:
        work = effort[held][:, driven], position[held][:, driven]
    friction = None if coulomb is None else (coulomb, work[1])
    return _json(metrics.segment_metrics(effort=effort[sl], effort_limits=limits, work=work,
                                         friction=friction))


def _path_for(bag: BagData, log_time: int, nxt: int | None,
              stamp: int = 0) -> PathMsg | None:
    """The trajectory's planned path: the one stamped like it (none if paths are stamped
    but none is stamped so), else the one received closest to it (within PATH_LEAD
    before it, or any time before the next trajectory)."""
    if stamp and any(p.stamp for p in bag.paths):  # stamped paths: only its own
        same = [p for p in bag.paths if p.stamp == stamp]
        return same[-1] if same else None
    best = None
    for p in bag.paths:
        if p.log_time < log_time - PATH_LEAD or (nxt is not None and p.log_time >= nxt):
            continue
        if best is None or abs(p.log_time - log_time) < abs(best.log_time - log_time):
            best = p
    return best


def _segment(k, tr, nxt, sl, t, js, ref, arm, limits, bag, warnings,
             coulomb=None) -> Segment:
    q = js.position[sl]
    ts = t[sl]
    seg = Segment(index=k, mode=None, start=float(ts[0]), duration=float(ts[-1] - ts[0]),
                  samples=len(ts))
    seg.values.update(_torque(js.effort, js.position, limits, sl, js.names, coulomb))
    seg.series = {'t': ts - ts[0], 'q': q, 'effort': js.effort[sl]}
    set_point = None
    points = None
    line_from = 0  # ns: a line after a stop is measured from its own start
    if tr is not None:
        traj = tr.trajectory
        set_point = traj.positions[-1]
        seg.set_point = _list(set_point)
        path = _path_for(bag, tr.log_time, nxt, traj.stamp)
        if path is not None and len(path.xy):
            points = path.xy
            line_from = path.start if path.stamp and path.start > path.stamp else 0
        elif arm is not None:
            points = arm.forward_kinematics(traj.positions)
        straight = points is not None and metrics.is_straight_line(points)
        seg.mode = 'straight_line' if straight else 'regulation'
    desired = None
    if ref is not None:
        desired = ref[sl]
        seg.reference = 'reference_topic'
    elif set_point is not None:
        desired = np.broadcast_to(set_point, q.shape)
        seg.reference = 'set_point'
    line = xy = None
    if seg.mode == 'straight_line' and arm is not None:
        assert points is not None  # straight means the points make a line
        line = points[0], points[-1]
        measured = _finite_rows(q) & (js.stamp[sl] >= line_from)
        xy = arm.forward_kinematics(q[measured])
        seg.line_start, seg.line_end = _list(line[0]), _list(line[1])
        seg.series.update(xy=xy, line=line)
    elif arm is not None:
        finite = _finite_rows(q)
        seg.series['xy'] = arm.forward_kinematics(q if finite.all() else q[finite])
    found = metrics.segment_metrics(
        seg.series['t'], q, desired=desired, line=line, xy=xy, series=seg.series,
        set_point=set_point if seg.mode == 'regulation' else None)
    if desired is not None:
        if 'tracking_rms' in found:
            seg.series['ref'] = desired
        else:
            warnings.append(f'segment {k}: no joint state has a matching reference')
    seg.values.update(_json(found))
    return seg


# ---------------------------------------------------------------------- pushes and faults
def _disturbances(events: list[SimEvent], js: JointStates, t_ns: np.ndarray, ref, arm,
                  warnings: list[str]) -> tuple[list[dict], list[dict]]:
    """The pushes (with their response) and faults of ``events`` (by time): each start,
    its end paired with the earliest open start of the same label and kind."""
    if not events:
        return [], []
    origin = int(js.stamp[0])
    pushes: list[dict] = []
    faults: list[dict] = []
    open_starts: dict[tuple, list[dict]] = {}
    for e in events:
        key = (e.is_push, e.label, e.kind)
        when = {'time': (e.time_ns - origin) * 1e-9, 'time_ns': e.time_ns}
        if e.edge == 'start':
            entry = {**when, 'end': None, 'end_ns': None, 'kind': e.kind, 'label': e.label,
                     'description': e.description}
            (pushes if e.is_push else faults).append(entry)
            open_starts.setdefault(key, []).append(entry)
        elif open_starts.get(key):
            start = open_starts[key].pop(0)
            start['end'], start['end_ns'] = when['time'], when['time_ns']
        else:
            warnings.append(f"{'push' if e.is_push else 'fault'} {e.label} ({e.kind}) ends "
                            f"at {when['time']:.3f} s without a start in the bag")
    if pushes:
        on_stamps = t_ns is js.stamp
        if not on_stamps:
            warnings.append('push responses need increasing header stamps: not computed')
        starts = sorted({p['time_ns'] for p in pushes})
        for p in pushes:
            k = bisect.bisect_right(starts, p['time_ns'])  # the next push starts there
            figures = _push_response(js, ref, arm, p['time_ns'],
                                     starts[k] if k < len(starts) else None,
                                     origin) if on_stamps else {}
            p['baseline'] = figures.pop('baseline', None)
            p.update({m.name: figures.get(m.name) for m in metrics.PUSH_METRICS})
    return pushes, faults


def _push_response(js: JointStates, ref, arm, start_ns: int, next_ns: int | None,
                   origin: int) -> dict:
    """One push's figures (:data:`arm_bag.metrics.PUSH_METRICS`, ``baseline``) over the
    states stamped from ``start_ns`` to before ``next_ns`` (None: to the end)."""
    st = js.stamp
    lo = int(np.searchsorted(st, start_ns, 'left'))
    hi = len(st) if next_ns is None else int(np.searchsorted(st, next_ns, 'left'))
    if hi <= lo:
        return {}
    q = js.position[lo:hi]
    if ref is not None and metrics.finite_rows(ref[lo:hi]).all():
        desired, baseline = ref[lo:hi], 'reference'
    else:  # where the arm was at the push: the last state at or before it
        k0 = max(int(np.searchsorted(st, start_ns, 'right')) - 1, lo)
        desired, baseline = np.broadcast_to(js.position[k0], q.shape), 'push_start'
    ok = metrics.finite_rows(q, desired)
    if not ok.any():
        return {}
    q, desired = q[ok], desired[ok]
    out: dict[str, Any] = {'baseline': baseline,
                           'peak_joint_deviation': np.abs(q - desired).max(axis=0)}
    if arm is not None:
        gap = arm.forward_kinematics(q) - arm.forward_kinematics(desired)
        t = (st[lo:hi][ok] - origin) * 1e-9
        peak, recovery = metrics.push_response(t, np.hypot(gap[:, 0], gap[:, 1]),
                                               (start_ns - origin) * 1e-9)
        out.update(peak_deviation=peak, recovery_time=recovery)
    return _json(out)
