"""``arm-sim sweep SPEC``: thousands of closed-loop runs, headless, to answer *how much*.

Pure: no rclpy.

A sweep is a grid (every combination) or a random sample of scenarios. A scenario is one
closed-loop run of the 2-R arm: a task (regulation or straight line, start and goal tip
positions, a duration or ``fastest`` feasible), a time scaling, a control law and its gains,
the controller's model errors (an unmodelled payload on the plant, relative mass and length
errors of the controller's model), a control rate and effort limits.

Every scenario runs the code the nodes run: the planner's :func:`~arm_planner.planner.
plan_goal` (the plan as the controller receives it: knot times rounded to whole ns), the
control laws of :mod:`arm_control.laws`, the plant's RK4 of :mod:`arm_dynamics.two_link`,
and the simulator's sampled-data timing (:class:`~arm_dynamics.simulation.SimulatorCore`):
at each control tick ``t_k = k T`` the law is evaluated on the measured state, the torque
saturated at the effort limits (controller, then simulator) and held over the period ``T``
while the plant takes ``T / physics_step`` RK4 steps; a state faster than 1000 rad/s or
non-finite is a divergence (the simulator's ``velocity_limit``): that scenario stops
there, held with zero torque, and is reported ``diverged``. The scenario starts at rest at
the start, ``t = 0`` is the trajectory's start, and it runs ``hold`` s past the motion's
end.

Scenarios run vectorised: a chunk of them (one law, one control rate and physics step)
steps as one batch of (B, 2) states (:class:`~arm_dynamics.two_link.TwoLinkBatch`,
:func:`~arm_control.laws.law_torque`); chunks run in parallel processes
(:class:`concurrent.futures.ProcessPoolExecutor`) or on a Dask distributed cluster
(``--dask ADDRESS``; dask is imported only then). :func:`run_single` runs one scenario the
nodes' way instead (:class:`~arm_control.core.ControllerCore` in
:func:`~arm_dynamics.integrate.simulate`); the tests check both give the same runs.

Metrics (one row per scenario) are those of ``arm-sim analyze`` for the segment the
scenario makes, from the same functions (:mod:`arm_bag.metrics`) on what the nodes would
record: joint states at every control tick, effort = the torque applied over the period
ending at that tick (at ``t = 0``: the first period's), the reference sampled at each tick.

Result columns (CSV, JSON ``rows``; per-joint values as ``<name>_1`` and ``<name>_2``,
empty / null where undefined):

* the scenario: ``index``, ``task``, ``start_x``, ``start_y``, ``goal_x``, ``goal_y`` [m],
  ``elbow``, ``duration_requested`` [s or ``fastest``], ``time_scaling``,
  ``regulation_profile``, ``feasibility``, ``law``, ``kp``, ``kd``, ``ki``, ``i_clamp``
  (per joint), ``payload`` [kg], ``mass_error``, ``length_error`` [fraction],
  ``control_rate`` [Hz], ``physics_step`` [s], ``effort_limit`` [N m per joint],
  ``hold`` [s];
* the outcome: ``status`` (``ok`` | ``refused``: the planner refused it, ``message`` says
  why | ``diverged``: ``message`` says when), ``message``, ``duration`` [s, the planned
  motion], ``planned_peak_torque`` [N m per joint], ``samples``;
* the metrics (see :mod:`arm_bag.analysis`): ``tracking_rms``, ``tracking_max``,
  ``final_error`` [rad per joint]; ``settling_time`` [s per joint],
  ``settling_time_overall`` [s], ``overshoot`` [% per joint] (regulation);
  ``deviation_max``, ``deviation_rms``, ``line_overshoot_end``, ``line_overshoot_start``
  [m] (straight line); ``torque_peak``, ``torque_rms`` [N m per joint],
  ``saturated_fraction`` [per joint], ``energy`` [J].
"""

from __future__ import annotations

import argparse
import csv
import functools
import itertools
import json
import math
import sys
import textwrap
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from arm_bag import metrics
from arm_control.core import ControllerCore
from arm_control.laws import LAWS, Gains, law_torque
from arm_control.trajectory import Trajectory
from arm_dynamics.integrate import simulate
from arm_dynamics.limits import DEFAULT_EFFORT, JointLimits
from arm_dynamics.robot import JOINT_NAMES
from arm_dynamics.two_link import TwoLinkArm, TwoLinkBatch
from arm_planner.kinematics import PlanningError
from arm_planner.planner import FEASIBILITY, MAX_DURATION, PlannerSettings, plan_goal
from arm_planner.time_scaling import KINDS

EXIT_OK, EXIT_ERROR, EXIT_USAGE = 0, 1, 2
VELOCITY_LIMIT = 1000.0   # rad/s: faster is divergence (the simulator's velocity_limit)
MAX_SCENARIOS = 1_000_000
FASTEST_REQUEST = 1e-3    # s: asked of the planner for 'fastest' (stretched to fit)
IGNORE_LIMITS = (1e9, 1e9)  # N m: the planner's limits under feasibility 'ignore'
ROBOT = TwoLinkArm()      # the robot of config/arm.yaml (the model defaults)
PS = tuple(float(v) for v in ROBOT.forward_kinematics([-0.4, 1.2]))  # the demo's Ps, m
PF = (0.5, 1.2)           # the demo's Pf, m
TASKS = ('regulation', 'straight_line')
PROFILES = ('synchronized', 'set_point')
ELBOWS = ('down', 'up')
STATUSES = ('ok', 'refused', 'diverged')
VARIANT = 'variant'       # the axis whose values are bundles of settings


class SpecError(ValueError):
    """A sweep spec that cannot run; the message (one line) names the key and the value."""


# ---------------------------------------------------------------------- scenarios
def _number(name: str, value: object, lo: float | None = None, hi: float | None = None,
            strict_lo: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer,
                                                         np.floating)):
        raise ValueError(f'{name} must be a number, got {value!r}')
    x = float(value)
    low_bad = lo is not None and (x <= lo if strict_lo else x < lo)
    if not math.isfinite(x) or low_bad or (hi is not None and x > hi):
        rng = (f"{'>' if strict_lo else '>='} {lo:g}" if lo is not None else '') + (
            f"{' and ' if lo is not None else ''}<= {hi:g}" if hi is not None else '')
        raise ValueError(f'{name} must be a finite number {rng}, got {value!r}')
    return x


def _pair(name: str, value: object, lo: float | None = None, hi: float | None = None,
          strict_lo: bool = False) -> tuple[float, float]:
    """Two numbers; one number means the same on both joints."""
    if isinstance(value, (list, tuple, np.ndarray)):
        if len(value) != 2:
            raise ValueError(f'{name} must be a number or two numbers, got {list(value)!r}')
        a, b = (_number(f'{name}[{i}]', v, lo, hi, strict_lo) for i, v in enumerate(value))
        return a, b
    x = _number(name, value, lo, hi, strict_lo)
    return x, x


def _choice(name: str, value: object, choices: Sequence[str]) -> str:
    if value not in choices:
        raise ValueError(f"{name} must be one of {', '.join(choices)}; got {value!r}")
    return str(value)


def _point(name: str, value: object) -> tuple[float, float]:
    if not (isinstance(value, (list, tuple, np.ndarray)) and len(value) == 2):
        raise ValueError(f'{name} must be a tip position [x, y] in m, got {value!r}')
    return _pair(name, value)


def _duration(name: str, value: object) -> float | str:
    if value == 'fastest':
        return 'fastest'
    if isinstance(value, str):
        raise ValueError(f"{name} must be a number of seconds or 'fastest', got {value!r}")
    return _number(name, value, 0.0, MAX_DURATION, strict_lo=True)


_GAINS = Gains()

#: Every scenario setting: (default, unit, meaning, check). The check returns the value
#: normalised or raises ValueError naming it.
SETTINGS: dict[str, tuple[Any, str, str, Callable[[str, object], Any]]] = {
    'task': ('straight_line', '', 'regulation | straight_line',
             lambda n, v: _choice(n, v, TASKS)),
    'start': (PS, 'm', 'start tip position [x, y] (at rest; the demo\'s Ps)', _point),
    'goal': (PF, 'm', 'goal tip position [x, y] (the demo\'s Pf)', _point),
    'elbow': ('down', '', 'elbow branch of the start: down (q2 > 0) | up',
              lambda n, v: _choice(n, v, ELBOWS)),
    'duration': (1.0, 's', "motion duration, or 'fastest' feasible within the effort "
                 'limits', _duration),
    'time_scaling': ('quintic', '', 'quintic | trapezoidal', lambda n, v: _choice(n, v, KINDS)),
    'regulation_profile': ('synchronized', '', 'regulation: synchronized | set_point',
                           lambda n, v: _choice(n, v, PROFILES)),
    'feasibility': ('stretch', '', "planner vs effort limits: stretch (slow down to fit) | "
                    "refuse | ignore (plan as asked; the torque saturates)",
                    lambda n, v: _choice(n, v, (*FEASIBILITY, 'ignore'))),
    'law': ('computed_torque', '', ' | '.join(LAWS), lambda n, v: _choice(n, v, LAWS)),
    'kp': (_GAINS.kp, '1/s^2 (computed_torque), N m/rad (others)', 'proportional gain',
           lambda n, v: _pair(n, v, 0.0)),
    'kd': (_GAINS.kd, '1/s (computed_torque), N m s/rad (others)', 'derivative gain',
           lambda n, v: _pair(n, v, 0.0)),
    'ki': (_GAINS.ki, 'N m/(rad s)', 'integral gain (pid)', lambda n, v: _pair(n, v, 0.0)),
    'i_clamp': (_GAINS.i_clamp, 'N m', 'bound of the integral term (pid)',
                lambda n, v: _pair(n, v, 0.0)),
    'payload': (0.0, 'kg', 'point mass at the tip of the plant, unknown to the controller '
                'and the planner', lambda n, v: _number(n, v, 0.0, 1e4)),
    'mass_error': (0.0, 'fraction', "the controller's model link masses are (1 + e) times "
                   'the real ones', lambda n, v: _number(n, v, -1.0, 100.0, strict_lo=True)),
    'length_error': (0.0, 'fraction', "the controller's model link lengths and centre of "
                     'gravity distances are (1 + e) times the real ones',
                     lambda n, v: _number(n, v, -1.0, 100.0, strict_lo=True)),
    'control_rate': (100.0, 'Hz', 'control (state and command) rate; 1/rate a whole '
                     'multiple of physics_step', lambda n, v: _number(n, v, 0.0, 1e5, True)),
    'physics_step': (0.001, 's', 'RK4 step of the plant',
                     lambda n, v: _number(n, v, 1e-6, 1.0)),
    'effort_limits': (DEFAULT_EFFORT, 'N m',
                      'torque limits (planner, controller and simulator)',
                      lambda n, v: _pair(n, v, 0.0, 1e6, True)),
    'hold': (1.0, 's', 'simulated time after the motion ends',
             lambda n, v: _number(n, v, 0.0, MAX_DURATION)),
}


@dataclass(frozen=True)
class Scenario:
    """One closed-loop run; field meanings and units in :data:`SETTINGS` (pairs are per
    joint). Validates itself: a bad value raises ValueError naming it."""

    task: str = SETTINGS['task'][0]
    start: tuple[float, float] = SETTINGS['start'][0]
    goal: tuple[float, float] = SETTINGS['goal'][0]
    elbow: str = SETTINGS['elbow'][0]
    duration: float | str = SETTINGS['duration'][0]
    time_scaling: str = SETTINGS['time_scaling'][0]
    regulation_profile: str = SETTINGS['regulation_profile'][0]
    feasibility: str = SETTINGS['feasibility'][0]
    law: str = SETTINGS['law'][0]
    kp: tuple[float, float] = SETTINGS['kp'][0]
    kd: tuple[float, float] = SETTINGS['kd'][0]
    ki: tuple[float, float] = SETTINGS['ki'][0]
    i_clamp: tuple[float, float] = SETTINGS['i_clamp'][0]
    payload: float = SETTINGS['payload'][0]
    mass_error: float = SETTINGS['mass_error'][0]
    length_error: float = SETTINGS['length_error'][0]
    control_rate: float = SETTINGS['control_rate'][0]
    physics_step: float = SETTINGS['physics_step'][0]
    effort_limits: tuple[float, float] = SETTINGS['effort_limits'][0]
    hold: float = SETTINGS['hold'][0]

    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(self, f.name, SETTINGS[f.name][3](f.name, getattr(self, f.name)))
        self.timing()  # raises on a control period that is no whole number of steps
        if self.duration == 'fastest' and self.feasibility == 'ignore':
            raise ValueError("duration 'fastest' is fastest within the effort limits: "
                             "feasibility must be stretch or refuse, not 'ignore'")

    def timing(self) -> tuple[int, int]:
        """(physics step [ns], RK4 steps per control period), as the simulator's
        ``physics_step`` and ``publish_rate`` parameters make them."""
        step_ns = round(self.physics_step * 1e9)
        period_ns = round(1e9 / self.control_rate)
        if step_ns < 1 or period_ns % step_ns:
            raise ValueError(f'control_rate {self.control_rate:g} Hz: the control period '
                             f'{period_ns} ns is not a whole multiple of physics_step '
                             f'{self.physics_step:g} s')
        return step_ns, period_ns // step_ns

    def plant(self) -> TwoLinkArm:
        """The simulated arm: the robot with ``payload`` kg at the tip of link 2."""
        if self.payload == 0.0:
            return ROBOT
        (_, l2), (_, c2) = ROBOT.link_lengths, ROBOT.com_distances
        m2, i2, p = ROBOT.link_masses[1], ROBOT.link_inertias[1], self.payload
        c = (m2 * c2 + p * l2) / (m2 + p)
        return TwoLinkArm(link_lengths=ROBOT.link_lengths,
                          com_distances=(ROBOT.com_distances[0], c),
                          link_masses=(ROBOT.link_masses[0], m2 + p),
                          link_inertias=(ROBOT.link_inertias[0],
                                         i2 + m2 * (c - c2) ** 2 + p * (l2 - c) ** 2),
                          gravity=ROBOT.gravity, joint_damping=ROBOT.joint_damping)

    def model(self) -> TwoLinkArm:
        """The controller's model: the robot (without the payload) with the errors."""
        m, s = 1.0 + self.mass_error, 1.0 + self.length_error
        if m == 1.0 and s == 1.0:
            return ROBOT
        (l1, l2), (c1, c2) = ROBOT.link_lengths, ROBOT.com_distances
        (m1, m2), (i1, i2) = ROBOT.link_masses, ROBOT.link_inertias
        return TwoLinkArm(link_lengths=(s * l1, s * l2), com_distances=(s * c1, s * c2),
                          link_masses=(m * m1, m * m2),
                          link_inertias=(m * s * s * i1, m * s * s * i2),
                          gravity=ROBOT.gravity, joint_damping=ROBOT.joint_damping)


# ---------------------------------------------------------------------- planning
@dataclass(frozen=True)
class Planned:
    """A scenario's plan as the controller tracks it, or why there is none."""

    trajectory: Trajectory | None
    q_start: np.ndarray
    set_point: np.ndarray | None = None   # (2,) rad, the plan's last point
    line: tuple[np.ndarray, np.ndarray] | None = None  # path's first and last pose, m
    duration: float = 0.0
    peak_torque: np.ndarray | None = None
    refused: str | None = None


@functools.lru_cache(maxsize=4096)
def _plan(task: str, start: tuple[float, float], goal: tuple[float, float], elbow: str,
          duration: float | str, time_scaling: str, profile: str, feasibility: str,
          limits: tuple[float, float]) -> Planned:
    q_start = ROBOT.inverse_kinematics(np.array(start), elbow)
    bad = ROBOT.workspace_violation(np.array(start), 0.01, 0.0, 'start')
    if bad:
        return Planned(None, q_start, refused=bad)
    settings = PlannerSettings(
        mode=task, elbow='keep', time_scaling=time_scaling,
        duration=FASTEST_REQUEST if duration == 'fastest' else float(duration),
        regulation_profile=profile,
        feasibility='stretch' if feasibility in ('ignore', 'stretch') else 'refuse')
    try:
        plan = plan_goal(ROBOT, IGNORE_LIMITS if feasibility == 'ignore' else limits,
                         q_start, goal, settings, JointLimits())
    except PlanningError as exc:
        return Planned(None, q_start, refused=str(exc))
    # The controller receives knot times as whole ns (builtin_interfaces/Duration).
    ns = np.round(plan.times * 1e9).astype(np.int64)
    sec, nsec = np.divmod(ns, 1_000_000_000)
    times = sec + nsec * 1e-9
    traj = Trajectory(q_start, np.zeros(2), times, plan.q, plan.qd, plan.qdd)
    path = plan.display_path
    line = (path[0], path[-1]) if task == 'straight_line' and len(path) >= 3 else None
    return Planned(traj, q_start, plan.q[-1].copy(), line, float(times[-1]),
                   np.asarray(plan.peak_torque, dtype=float))


def plan_scenario(s: Scenario) -> Planned:
    """The scenario's plan (cached per process: scenarios differing only in control
    settings share it). The planner uses the robot without payload or model errors."""
    return _plan(s.task, s.start, s.goal, s.elbow, s.duration, s.time_scaling,
                 s.regulation_profile, s.feasibility, s.effort_limits)


def _ticks(s: Scenario, planned: Planned) -> int:
    """Control periods simulated: the motion plus ``hold``, rounded up."""
    period = round(1e9 / s.control_rate) * 1e-9
    return max(1, math.ceil((planned.duration + s.hold) / period - 1e-9))


# ---------------------------------------------------------------------- metrics
#: Per-joint metric and input columns (written ``<name>_1``, ``<name>_2``).
PER_JOINT = ('kp', 'kd', 'ki', 'i_clamp', 'effort_limit', 'planned_peak_torque',
             'tracking_rms', 'tracking_max', 'final_error', 'settling_time', 'overshoot',
             'torque_peak', 'torque_rms', 'saturated_fraction')
_INPUTS = ('index', 'task', 'start_x', 'start_y', 'goal_x', 'goal_y', 'elbow',
           'duration_requested', 'time_scaling', 'regulation_profile', 'feasibility', 'law',
           'kp', 'kd', 'ki', 'i_clamp', 'payload', 'mass_error', 'length_error',
           'control_rate', 'physics_step', 'effort_limit', 'hold')
_OUTCOME = ('status', 'message', 'duration', 'planned_peak_torque', 'samples')
_METRICS = ('tracking_rms', 'tracking_max', 'final_error', 'settling_time',
            'settling_time_overall', 'overshoot', 'deviation_max', 'deviation_rms',
            'line_overshoot_end', 'line_overshoot_start', 'torque_peak', 'torque_rms',
            'saturated_fraction', 'energy')
#: Every column, in order.
COLUMNS = tuple(c for name in _INPUTS + _OUTCOME + _METRICS
                for c in ((f'{name}_1', f'{name}_2') if name in PER_JOINT else (name,)))
#: The metric columns (numbers; empty where undefined).
METRIC_COLUMNS = tuple(c for name in _METRICS
                       for c in ((f'{name}_1', f'{name}_2') if name in PER_JOINT else (name,)))


def _put(row: dict, name: str, value) -> None:
    if name in PER_JOINT:
        v = [math.nan, math.nan] if value is None else [
            math.nan if x is None else float(x) for x in value]
        row[f'{name}_1'], row[f'{name}_2'] = v
    else:
        row[name] = math.nan if value is None else value


def _row(index: int, s: Scenario, planned: Planned) -> dict:
    row: dict[str, Any] = dict.fromkeys(COLUMNS, math.nan)
    values = dict(index=index, task=s.task, start_x=s.start[0], start_y=s.start[1],
                  goal_x=s.goal[0], goal_y=s.goal[1], elbow=s.elbow,
                  duration_requested=s.duration, time_scaling=s.time_scaling,
                  regulation_profile=s.regulation_profile, feasibility=s.feasibility,
                  law=s.law, kp=s.kp, kd=s.kd, ki=s.ki, i_clamp=s.i_clamp, payload=s.payload,
                  mass_error=s.mass_error, length_error=s.length_error,
                  control_rate=s.control_rate, physics_step=s.physics_step,
                  effort_limit=s.effort_limits, hold=s.hold,
                  status='refused' if planned.refused else 'ok',
                  message=planned.refused or '', duration=planned.duration,
                  planned_peak_torque=planned.peak_torque)
    for k, v in values.items():
        _put(row, k, v)
    return row


def segment_metrics(t: np.ndarray, q: np.ndarray, qd: np.ndarray, effort: np.ndarray,
                    q_des: np.ndarray, planned: Planned, limits) -> dict[str, Any]:
    """The ``arm-sim analyze`` metrics of one segment, from :mod:`arm_bag.metrics`.

    Parameters
    ----------
    t : (N,) s from the segment's start; q, qd, effort, q_des : (N, 2) rad, rad/s, N m,
        rad -- joint states (effort: applied over the period ending at each sample) and
        the reference at each sample.
    planned : the plan (set point; the line's ends for a straight line).
    limits : (2,) N m

    Returns
    -------
    dict keyed by the metric names of :data:`COLUMNS` (per joint: (2,) lists).
    """
    out: dict[str, Any] = {}
    err = metrics.tracking_errors(q - q_des)
    out.update(tracking_rms=err['rms'], tracking_max=err['max'], final_error=err['final'])
    if planned.line is None:
        sp = planned.set_point
        assert sp is not None  # a plan was made
        st = [metrics.settling_time(t, q[:, j], q[0, j], sp[j]) for j in range(2)]
        moving = [st[j] for j in range(2) if q[0, j] != sp[j]]
        out['settling_time'] = st
        out['settling_time_overall'] = (None if not moving or any(x is None for x in moving)
                                        else max(x for x in moving if x is not None))
        out['overshoot'] = [metrics.overshoot(q[:, j], q[0, j], sp[j]) for j in range(2)]
    else:
        a, b = planned.line
        xy = ROBOT.forward_kinematics(q)
        dev = metrics.segment_deviation(xy, a, b)
        before, past = metrics.overshoot_along_line(xy, a, b)
        out.update(deviation_max=float(dev.max()),
                   deviation_rms=float(np.sqrt(np.mean(dev * dev))),
                   line_overshoot_end=float(past.max()),
                   line_overshoot_start=float(before.max()))
    stats = metrics.torque_stats(effort, limits)
    out.update(torque_peak=stats['peak'], torque_rms=stats['rms'],
               saturated_fraction=stats['saturated_fraction'],
               energy=metrics.energy_delivered(effort, q))
    return out


# ---------------------------------------------------------------------- running
@dataclass(frozen=True)
class Run:
    """One scenario's recorded run at the control ticks: t (N,) s, q, qd, effort, q_des
    (N, 2) rad, rad/s, N m (applied over the period ending there), rad; ``diverged`` the
    message if it diverged."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    effort: np.ndarray
    q_des: np.ndarray
    diverged: str | None = None


def _finish(row: dict, s: Scenario, planned: Planned, run: Run) -> dict:
    row['samples'] = len(run.t)
    if run.diverged:
        row['status'], row['message'] = 'diverged', run.diverged
        return row
    for k, v in segment_metrics(run.t, run.q, run.qd, run.effort, run.q_des, planned,
                                s.effort_limits).items():
        _put(row, k, v)
    return row


def run_chunk(items: Sequence[tuple[int, Scenario]], keep_runs: bool = False
              ) -> list[dict] | tuple[list[dict], list[Run | None]]:
    """Run scenarios as one batch; they must share law, control rate and physics step.

    Parameters
    ----------
    items : (index, scenario) pairs.
    keep_runs : also return each scenario's :class:`Run` (None where refused).

    Returns
    -------
    One result row per item (keys :data:`COLUMNS`), in order (and the runs).
    """
    if not items:
        return ([], []) if keep_runs else []
    first = items[0][1]
    law, (step_ns, substeps) = first.law, first.timing()
    if any(s.law != law or s.timing() != (step_ns, substeps) for _, s in items):
        raise ValueError('run_chunk: the scenarios of one chunk must share law, '
                         'control_rate and physics_step')
    planned = [plan_scenario(s) for _, s in items]
    rows = [_row(i, s, p) for (i, s), p in zip(items, planned)]
    runs: list[Run | None] = [None] * len(items)
    live = [k for k, p in enumerate(planned) if p.trajectory is not None]
    if live:
        for k, run in zip(live, _run_batch([items[k][1] for k in live],
                                           [planned[k] for k in live],
                                           law, step_ns, substeps)):
            runs[k] = run
            _finish(rows[k], items[k][1], planned[k], run)
    return (rows, runs) if keep_runs else rows


def _rows_of(items: Sequence[tuple[int, Scenario]]) -> list[dict]:
    """The rows of :func:`run_chunk` (what a worker process or a Dask task runs)."""
    rows = run_chunk(items)
    assert isinstance(rows, list)
    return rows


def _run_batch(scenarios: Sequence[Scenario], planned: Sequence[Planned], law: str,
               step_ns: int, substeps: int) -> list[Run]:
    """The closed loop of B scenarios stepped together (see the module docstring)."""
    b = len(scenarios)
    dt = step_ns * 1e-9
    ticks = np.array([_ticks(s, p) for s, p in zip(scenarios, planned)])
    n = int(ticks.max())
    t = (np.arange(n + 1) * substeps) * dt  # as simulate() times its control ticks
    # The reference of each distinct plan at every tick (sampled as the controller does).
    plan_ids: dict[int, int] = {}
    index = np.array([plan_ids.setdefault(id(p.trajectory), len(plan_ids)) for p in planned])
    refs: list[tuple[np.ndarray, ...] | None] = [None] * len(plan_ids)
    for p in planned:
        k = plan_ids[id(p.trajectory)]
        if refs[k] is None:
            assert p.trajectory is not None
            refs[k] = p.trajectory.sample_many(t)
    ref_q, ref_qd, ref_qdd = (np.stack([r[i] for r in refs if r is not None], 1)
                              for i in range(3))
    plant = TwoLinkBatch([s.plant() for s in scenarios])
    model = TwoLinkBatch([s.model() for s in scenarios])
    kp, kd, ki, clamp = (np.array([getattr(s, g) for s in scenarios])
                         for g in ('kp', 'kd', 'ki', 'i_clamp'))
    limits = np.array([s.effort_limits for s in scenarios])
    q = np.array([p.q_start for p in planned])
    qd = np.zeros((b, 2))
    integral = np.zeros((b, 2))
    zero = np.zeros((b, 2))
    qs, qds, efforts = np.empty((n + 1, b, 2)), np.empty((n + 1, b, 2)), np.empty((n + 1, b, 2))
    qs[0], qds[0] = q, qd
    alive = np.ones(b, dtype=bool)
    died = np.full(b, -1)
    for k in range(n):
        dtk = 0.0 if k == 0 else t[k] - t[k - 1]
        raw, integral = law_torque(law, kp, kd, ki, clamp, limits, model, integral, q, qd,
                                   ref_q[k, index], ref_qd[k, index], ref_qdd[k, index],
                                   dtk)
        tau = np.clip(np.clip(raw, -limits, limits), -limits, limits)  # controller, plant
        if not alive.all():
            tau = np.where(alive[:, None], tau, zero)
        q_new, qd_new = plant.step(q, qd, tau, dt, substeps)
        with np.errstate(invalid='ignore'):
            bad = ~(np.abs(qd_new).max(axis=1) <= VELOCITY_LIMIT) | ~np.isfinite(q_new).all(1)
        bad &= alive
        if bad.any():
            died[bad] = k + 1
            alive &= ~bad
            keep = ~alive[:, None]
            q_new, qd_new = np.where(keep, q, q_new), np.where(keep, qd, qd_new)
            tau = np.where(bad[:, None], zero, tau)
        efforts[k + 1] = tau
        q, qd = q_new, qd_new
        qs[k + 1], qds[k + 1] = q, qd
    efforts[0] = efforts[min(1, n)]
    out = []
    for i in range(b):
        m = int(ticks[i]) + 1
        msg = None
        if died[i] >= 0 and died[i] < m:
            msg = (f'diverged at t={t[died[i]]:.3f} s (|qd| > {VELOCITY_LIMIT:g} rad/s or '
                   'non-finite)')
        out.append(Run(t[:m], qs[:m, i], qds[:m, i], efforts[:m, i],
                       ref_q[:m, index[i]], msg))
    return out


def run_single(index: int, s: Scenario, keep_run: bool = False
               ) -> dict | tuple[dict, Run | None]:
    """One scenario the nodes' way, one state at a time: the controller core
    (:class:`~arm_control.core.ControllerCore` with :class:`~arm_control.laws.ControlLaw`)
    as the torque law of :func:`~arm_dynamics.integrate.simulate` at the control period,
    the plant's single-state RK4. Returns the result row (and the run). No divergence
    handling: for comparisons and benchmarks."""
    from arm_control.laws import ControlLaw

    planned = plan_scenario(s)
    row = _row(index, s, planned)
    if planned.trajectory is None:
        return (row, None) if keep_run else row
    step_ns, substeps = s.timing()
    dt = step_ns * 1e-9
    ticks = _ticks(s, planned)
    law = ControlLaw(s.law, Gains(kp=s.kp, kd=s.kd, ki=s.ki, i_clamp=s.i_clamp), s.model(),
                     s.effort_limits)
    core = ControllerCore(JOINT_NAMES, law)
    core.trajectory, core.start = planned.trajectory, 0.0
    refs: list[np.ndarray] = []

    def torque(t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        step = core.update(t, q, qd)
        refs.append(step.q_des)
        return step.command.tau

    sim = simulate(model=s.plant(), q0=planned.q_start, qd0=np.zeros(2), torque=torque,
                   duration=ticks * substeps * dt, dt=dt, control_period=substeps * dt,
                   effort_limits=s.effort_limits)
    tau = sim.tau[::substeps]
    run = Run(sim.t[::substeps], sim.q[::substeps], sim.qd[::substeps],
              np.vstack([tau[:1], tau[:-1]]), np.array(refs[:ticks + 1]))
    _finish(row, s, planned, run)
    return (row, run) if keep_run else row


# ---------------------------------------------------------------------- spec
@dataclass(frozen=True)
class PlotSpec:
    """What ``--plot`` draws: ``y`` columns against ``x``, one curve per value of ``by``."""

    x: str
    y: tuple[str, ...]
    by: str | None = None


@dataclass(frozen=True)
class Spec:
    """A parsed sweep spec (see ``arm-sim sweep --help``)."""

    name: str
    question: str
    kind: str
    scenario: dict
    axes: dict
    samples: int = 0
    seed: int = 0
    plot: PlotSpec | None = None

    def scenarios(self) -> list[Scenario]:
        """Every scenario: the grid's combinations (axes in spec order, the last varying
        fastest) or ``samples`` random draws (each axis drawn independently)."""
        base = dict(self.scenario)
        names = list(self.axes)
        if self.kind == 'grid':
            combos: Iterable[Sequence] = itertools.product(*(self.axes[n] for n in names))
        else:
            rng = np.random.default_rng(self.seed)
            draws = [_draw(rng, self.axes[n], self.samples) for n in names]
            combos = zip(*draws) if draws else ([] for _ in range(self.samples))
        out = []
        for combo in combos:
            values = dict(base)
            for n, v in zip(names, combo):
                values.update(v if n == VARIANT else {n: v})
            out.append(Scenario(**values))
        return out


def _draw(rng: np.random.Generator, axis: dict, count: int) -> list:
    kind, arg = axis['kind'], axis['arg']
    if kind == 'choice':
        return [arg[i] for i in rng.integers(0, len(arg), count)]
    lo, hi = (np.asarray(v, dtype=float) for v in arg)
    u = rng.random((count, *lo.shape))
    x = lo + (hi - lo) * u if kind == 'uniform' else np.exp(
        np.log(lo) + (np.log(hi) - np.log(lo)) * u)
    return [v.tolist() if lo.ndim else float(v) for v in x]


_TOP = {'name': 'short name (used in titles)', 'question': 'the question the sweep answers',
        'sweep': 'grid (every combination of the axes) | random (samples draws)',
        'samples': 'random: number of scenarios', 'seed': 'random: seed (default 0)',
        'scenario': 'fixed settings (the defaults below otherwise)',
        'axes': 'varied settings', 'plot': '{x: COLUMN, y: [COLUMN...], by: COLUMN}'}


def _known(what: str, key: object, known: Sequence[str] | dict) -> None:
    if key not in known:
        raise SpecError(f"{what}key {key!r} unknown (known: {', '.join(known)})")


def _check_setting(where: str, name: str, value: object) -> Any:
    try:
        return SETTINGS[name][3](name, value)
    except ValueError as exc:
        raise SpecError(f'{where}: {exc}') from None


def _variants(kind: str, value: object, taken: set[str]) -> Any:
    """The ``variant`` axis: a list of mappings of settings, each one value of the axis
    (e.g. a law with its own gains)."""
    where = f'axes.{VARIANT}'
    if not isinstance(value, list) or not value:
        raise SpecError(f'{where}: must be a non-empty list of mappings of settings (e.g. '
                        f'{{law: pd, kp: [600, 300]}}), got {value!r}')
    out = []
    for i, v in enumerate(value):
        if not isinstance(v, dict) or not v:
            raise SpecError(f'{where}[{i}]: must be a mapping of settings, got {v!r}')
        for key in v:
            _known(f'{where}[{i}]: ', key, SETTINGS)
            if key in taken:
                raise SpecError(f'{where}[{i}]: {key!r} is also in scenario or axes; give '
                                'it once')
        out.append({k: _check_setting(f'{where}[{i}].{k}', k, x) for k, x in v.items()})
    return out if kind == 'grid' else {'kind': 'choice', 'arg': out}


def _axis(kind: str, name: str, value: object) -> Any:
    """A grid axis as its list of values, or a random axis as {'kind', 'arg'}."""
    where = f'axes.{name}'
    if isinstance(value, dict):
        if len(value) != 1:
            raise SpecError(f'{where}: give one of linspace, logspace, uniform, loguniform '
                            f'(or a list of values), got {sorted(value)}')
        (op, arg), = value.items()
        ops = ('linspace', 'logspace') if kind == 'grid' else ('uniform', 'loguniform')
        _known(f'{where}: ', op, ops)
        if op in ('linspace', 'logspace'):
            if not (isinstance(arg, list) and len(arg) == 3 and isinstance(arg[2], int)
                    and not isinstance(arg[2], bool) and arg[2] >= 1):
                raise SpecError(f'{where}: {op} takes [first, last, count >= 1], got {arg!r}')
            lo, hi = (_check_setting(where, name, v) for v in arg[:2])
            if isinstance(lo, str):
                raise SpecError(f'{where}: {op} needs numbers, got {arg!r}')
            if op == 'logspace' and not (np.asarray(lo) > 0).all() & (np.asarray(hi) > 0).all():
                raise SpecError(f'{where}: logspace needs first and last > 0, got {arg!r}')
            fn = np.linspace if op == 'linspace' else np.geomspace
            values = [v.tolist() for v in fn(np.asarray(lo), np.asarray(hi), arg[2])]
        else:
            if not (isinstance(arg, list) and len(arg) == 2):
                raise SpecError(f'{where}: {op} takes [low, high], got {arg!r}')
            lo, hi = (_check_setting(where, name, v) for v in arg)
            if op == 'loguniform' and not (np.asarray(lo) > 0).all():
                raise SpecError(f'{where}: loguniform needs low > 0, got {arg!r}')
            if not (np.asarray(lo) <= np.asarray(hi)).all():
                raise SpecError(f'{where}: {op} needs low <= high, got {arg!r}')
            return {'kind': op, 'arg': (lo, hi)}
    elif isinstance(value, list):
        values = value
    else:
        raise SpecError(f'{where}: must be a list of values or '
                        f"{'{linspace: [a, b, n]}' if kind == 'grid' else '{uniform: [a, b]}'}"
                        f', got {value!r}')
    if not values:
        raise SpecError(f'{where}: no values (an empty axis makes no scenario)')
    checked = [_check_setting(where, name, v) for v in values]
    return checked if kind == 'grid' else {'kind': 'choice', 'arg': checked}


def parse_spec(doc: object, name: str = 'sweep') -> Spec:
    """Validate a spec document (the YAML's content); raises :class:`SpecError`."""
    if not isinstance(doc, dict):
        raise SpecError(f'a spec is a mapping with keys {", ".join(_TOP)}, got '
                        f'{type(doc).__name__}')
    for key in doc:
        _known('', key, _TOP)
    kind = doc.get('sweep', 'grid')
    if kind not in ('grid', 'random'):
        raise SpecError(f"sweep must be grid or random, got {kind!r}")
    samples, seed = doc.get('samples', 0), doc.get('seed', 0)
    for key, value, lo in (('samples', samples, 1 if kind == 'random' else 0),
                           ('seed', seed, 0)):
        if isinstance(value, bool) or not isinstance(value, int) or not (
                lo <= value <= MAX_SCENARIOS):
            raise SpecError(f'{key} must be an integer in [{lo}, {MAX_SCENARIOS}], got '
                            f'{value!r}')
    if kind == 'grid' and 'samples' in doc:
        raise SpecError('samples is for sweep: random (a grid runs every combination)')
    scenario, axes = doc.get('scenario') or {}, doc.get('axes') or {}
    for key, value in (('scenario', scenario), ('axes', axes)):
        if not isinstance(value, dict):
            raise SpecError(f'{key} must be a mapping of settings, got {value!r}')
    for key in scenario:
        _known('', key, SETTINGS)
    for key in axes:
        _known('axes: ', key, (*SETTINGS, VARIANT))
    both = sorted(set(scenario) & set(axes))
    if both:
        raise SpecError(f'{both[0]!r} is both in scenario and in axes; give it once')
    fixed = {k: _check_setting(f'scenario.{k}', k, v) for k, v in scenario.items()}
    taken = set(scenario) | set(axes)
    parsed = {k: (_variants(kind, v, taken) if k == VARIANT else _axis(kind, k, v))
              for k, v in axes.items()}
    if kind == 'grid':
        total = math.prod(len(v) for v in parsed.values())
        if total > MAX_SCENARIOS:
            raise SpecError(f'the grid has {total} scenarios, more than {MAX_SCENARIOS}')
    spec = Spec(name=str(doc.get('name', name)), question=str(doc.get('question', '')),
                kind=kind, scenario=fixed, axes=parsed, samples=samples, seed=seed,
                plot=_plot_spec(doc.get('plot'), parsed))
    return spec


def _plot_spec(value: object, axes: dict) -> PlotSpec | None:
    if value is None:
        return None
    if not isinstance(value, dict):
        raise SpecError(f'plot must be a mapping {{x, y, by}}, got {value!r}')
    for key in value:
        _known('plot: ', key, ('x', 'y', 'by'))
    y = value.get('y', [])
    y = [y] if isinstance(y, str) else y
    cols = [value.get('x'), *y] + ([value['by']] if value.get('by') is not None else [])
    for c in cols:
        _known('plot: column ', c, COLUMNS)
    if not y:
        raise SpecError('plot: y must name at least one column')
    return PlotSpec(x=str(value['x']), y=tuple(y), by=value.get('by'))


def load_spec(path: str | Path) -> Spec:
    """Read and validate a YAML spec; raises :class:`SpecError` (also for an unreadable
    file or bad YAML)."""
    import yaml

    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise SpecError(f'cannot read it: {exc.strerror or exc}') from None
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        first = str(exc).strip().splitlines()
        raise SpecError(f"not YAML: {' '.join(s.strip() for s in first)}") from None
    return parse_spec(doc, Path(path).stem)


def shipped_specs() -> dict[str, Path]:
    """The specs shipped in ``config/sweeps/`` (installed in share/arm_sim/config/sweeps)."""
    from arm_sim.launcher import config_file

    folder = config_file().parent / 'sweeps'
    return {p.stem: p for p in sorted(folder.glob('*.yaml'))}


def resolve_spec(arg: str) -> Path:
    """A spec file path, or the name of a shipped spec."""
    p = Path(arg)
    if p.exists() or p.suffix:
        return p
    return shipped_specs().get(arg, p)


# ---------------------------------------------------------------------- orchestration
def make_chunks(scenarios: Sequence[Scenario], chunk_size: int
                ) -> list[list[tuple[int, Scenario]]]:
    """Scenarios grouped by (law, timing), sorted by requested duration within a group
    (chunks then run to similar horizons), cut into chunks of at most ``chunk_size``."""
    if chunk_size < 1:
        raise ValueError(f'chunk_size must be >= 1, got {chunk_size}')
    groups: dict[tuple, list[tuple[int, Scenario]]] = {}
    for i, s in enumerate(scenarios):
        groups.setdefault((s.law, s.timing()), []).append((i, s))
    chunks = []
    for items in groups.values():
        items.sort(key=lambda it: (0.0 if it[1].duration == 'fastest' else it[1].duration,
                                   it[0]))
        chunks += [items[k:k + chunk_size] for k in range(0, len(items), chunk_size)]
    return chunks


def default_chunk_size(count: int, workers: int) -> int:
    """About four chunks per worker, 32 to 1024 scenarios each."""
    return int(min(1024, max(32, math.ceil(count / max(1, 4 * workers)))))


class Progress:
    """``[sweep] 4000/10000 scenarios, 6.1 s, ETA 9 s`` on ``stream``, at most every
    ``every`` s of wall time, and a last line when done (if any was printed)."""

    def __init__(self, total: int, stream=sys.stderr, every: float = 1.0) -> None:
        self.total, self.stream, self.every = total, stream, every
        self.done = 0
        self.start = time.monotonic()
        self.last = self.start
        self.printed = False

    def add(self, count: int) -> None:
        self.done += count
        now = time.monotonic()
        if now - self.last >= self.every or (self.printed and self.done == self.total):
            self.last = now
            self.printed = True
            spent = now - self.start
            eta = spent / self.done * (self.total - self.done) if self.done else math.nan
            print(f'[sweep] {self.done}/{self.total} scenarios, {spent:.1f} s, ETA '
                  f'{eta:.0f} s', file=self.stream, flush=True)


def run_sweep(scenarios: Sequence[Scenario], *, workers: int = 2,
              chunk_size: int | None = None, dask: str | None = None,
              progress: Callable[[int], None] | None = None) -> list[dict]:
    """Run every scenario; one row per scenario (keys :data:`COLUMNS`), in input order.

    Parameters
    ----------
    scenarios : the sweep's scenarios.
    workers : local processes (1: in this process). Ignored with ``dask``.
    chunk_size : scenarios per batch (default :func:`default_chunk_size`).
    dask : a Dask scheduler address (``tcp://host:8786``): run the chunks there.
    progress : called with the number of scenarios each finished chunk held.
    """
    if workers < 1:
        raise ValueError(f'workers must be >= 1, got {workers}')
    size = chunk_size or default_chunk_size(len(scenarios), workers)
    chunks = make_chunks(scenarios, size)
    rows: list[dict | None] = [None] * len(scenarios)

    def take(chunk_rows: list[dict]) -> None:
        for r in chunk_rows:
            rows[r['index']] = r
        if progress:
            progress(len(chunk_rows))

    if dask:
        _run_dask(dask, chunks, take)
    elif workers == 1 or len(chunks) <= 1:
        for c in chunks:
            take(_rows_of(c))
    else:
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(max_workers=min(workers, len(chunks))) as pool:
            futures = [pool.submit(_rows_of, c) for c in chunks]
            for f in as_completed(futures):
                take(f.result())
    assert all(r is not None for r in rows)
    return rows  # type: ignore[return-value]


def _run_dask(address: str, chunks: list, take: Callable[[list[dict]], None]) -> None:
    """Run the chunks on the Dask cluster at ``address`` (imports dask only there)."""
    from arm_common.cluster import ClusterError, dask_map

    try:
        dask_map(address, _rows_of, chunks, on_result=lambda _i, rows: take(rows))
    except ClusterError as exc:
        raise SpecError(str(exc)) from None


# ---------------------------------------------------------------------- output
def _cell(v: object) -> object:
    if isinstance(v, float) and not math.isfinite(v):
        return ''
    return v


def write_csv(rows: Sequence[dict], path: str | Path) -> None:
    """One row per scenario, columns :data:`COLUMNS`; undefined values are empty cells."""
    with open(path, 'w', newline='') as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for r in rows:
            w.writerow([_cell(r[c]) for c in COLUMNS])


def to_json(spec: Spec, rows: Sequence[dict], seconds: float) -> dict:
    """``--json``: ``name``, ``question``, ``scenarios``, ``wall_time`` s, ``status``
    counts, ``columns`` and ``rows`` (objects keyed by the columns; null = undefined)."""
    def clean(v):
        return None if isinstance(v, float) and not math.isfinite(v) else v

    counts = {k: sum(r['status'] == k for r in rows) for k in STATUSES}
    return {'name': spec.name, 'question': spec.question, 'scenarios': len(rows),
            'wall_time': seconds, 'status': counts, 'columns': list(COLUMNS),
            'rows': [{c: clean(r[c]) for c in COLUMNS} for r in rows]}


def default_plot(spec: Spec) -> PlotSpec:
    """Without a ``plot`` section: the first numeric axis across, the first other axis as
    curves, peak torques and the task's main error up."""
    x, by = 'index', None
    names = list(spec.axes)

    def numeric(n):
        values = spec.axes[n] if isinstance(spec.axes[n], list) else spec.axes[n]['arg']
        return all(isinstance(v, float) for v in values)

    nums = [n for n in names if numeric(n) and f'{n}_1' not in COLUMNS]
    if nums:
        x = nums[0]
    others = [n for n in names if n != x and n in COLUMNS]
    if others:
        by = others[0]
    elif VARIANT in names:
        by = 'law'
    task = spec.scenario.get('task', 'straight_line')
    err = 'deviation_max' if task == 'straight_line' else 'settling_time_overall'
    return PlotSpec(x=x, y=('torque_peak_1', 'torque_peak_2', err), by=by)


def plot_sweep(spec: Spec, rows: Sequence[dict], path: str | Path) -> Path:
    """Draw ``spec.plot`` (or :func:`default_plot`) into a PNG: one panel per ``y``
    column, one curve per ``by`` value (the mean where other settings vary too), the effort
    limits drawn on torque panels; refused and diverged scenarios are left out."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    ps = spec.plot or default_plot(spec)
    ok = [r for r in rows if r['status'] == 'ok']
    groups: dict[object, list[dict]] = {}
    for r in ok:
        groups.setdefault(r[ps.by] if ps.by else '', []).append(r)
    fig, axes = plt.subplots(len(ps.y), 1, figsize=(8, 2.6 * len(ps.y) + 0.8), sharex=True,
                             squeeze=False)
    for ax, col in zip(axes[:, 0], ps.y):
        for label, rs in groups.items():
            xs = sorted({float(r[ps.x]) for r in rs})
            ys = []
            for x in xs:
                v = [float(r[col]) for r in rs if float(r[ps.x]) == x]
                v = [y for y in v if math.isfinite(y)]
                ys.append(sum(v) / len(v) if v else math.nan)
            ax.plot(xs, ys, marker='.', label=f'{ps.by} = {label}' if ps.by else None)
        if col.startswith(('torque_peak_', 'torque_rms_')):
            j = col[-1]
            for lim in sorted({r[f'effort_limit_{j}'] for r in ok}):
                ax.axhline(lim, color='k', ls='--', lw=1)
                ax.annotate(f'effort limit {lim:g} N m', (0.01, lim), color='k',
                            xycoords=('axes fraction', 'data'), va='bottom', fontsize=8)
        ax.set_ylabel(_label(col))
        ax.grid(alpha=0.3, which='both')
        drawn = [float(r[col]) for r in ok if math.isfinite(float(r[col]))]
        if drawn and min(drawn) > 0 and max(drawn) > 100 * min(drawn):
            ax.set_yscale('log')  # spans decades (e.g. mm under one law, m under another)
    if ps.by and groups:
        axes[0, 0].legend(fontsize=8)
    axes[-1, 0].set_xlabel(_label(ps.x))
    xs_all = [float(r[ps.x]) for r in ok if math.isfinite(float(r[ps.x]))]
    if xs_all and min(xs_all) > 0 and max(xs_all) > 20 * min(xs_all):
        axes[-1, 0].set_xscale('log')  # a wide positive range (e.g. a logspace axis)
    skipped = len(rows) - len(ok)
    title = spec.name + (f': {spec.question}' if spec.question else '')
    fig.suptitle(textwrap.fill(title, 100) + (f'\n({skipped} refused or diverged, not drawn)'
                                              if skipped else ''), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)


_UNITS = {'duration': 's', 'payload': 'kg', 'control_rate': 'Hz', 'deviation': 'm',
          'torque': 'N m', 'settling': 's', 'tracking': 'rad', 'kp': '', 'energy': 'J',
          'overshoot': '%'}


def _label(col: str) -> str:
    unit = next((u for k, u in _UNITS.items() if col.startswith(k)), '')
    return f'{col} [{unit}]' if unit else col


def summary(spec: Spec, rows: Sequence[dict], seconds: float) -> str:
    """A few lines: counts and the extremes of the main metrics."""
    counts = {k: sum(r['status'] == k for r in rows) for k in STATUSES}
    lines = [f'{spec.name}: {len(rows)} scenarios in {seconds:.1f} s '
             f"({', '.join(f'{v} {k}' for k, v in counts.items())})"]
    if spec.question:
        lines.append(f'question: {spec.question}')
    ok = [r for r in rows if r['status'] == 'ok']
    for col in ('torque_peak_1', 'torque_peak_2', 'deviation_max', 'settling_time_overall'):
        v = np.array([r[col] for r in ok], dtype=float)
        v = v[np.isfinite(v)]
        if len(v):
            lines.append(f'  {_label(col)}: {v.min():.4g} .. {v.max():.4g}')
    return '\n'.join(lines)


# ---------------------------------------------------------------------- command line
def _settings_help() -> str:
    lines = ['scenario settings (in scenario: fixed, in axes: varied; pairs are per joint, '
             'one number = both joints):']
    for name, (default, unit, meaning, _) in SETTINGS.items():
        d = (f"[{', '.join(f'{v:.4g}' for v in default)}]" if isinstance(default, tuple)
             else default)
        u = f' [{unit}]' if unit else ''
        lines.append(f'  {name}{u}: {meaning} (default {d})')
    return '\n'.join(lines)


EPILOG = """SPEC is a YAML file (or the name of a shipped one: {shipped}):

  name: line_speed
  question: How does line deviation grow with speed under each law?
  sweep: grid                 # grid: every combination | random: `samples` draws, `seed`
  scenario: {{task: straight_line, start: [0.5, 1.2], goal: [1.478, 0.184]}}
  axes:      # grid: [values] | {{linspace: [a, b, n]}} | {{logspace: [a, b, n]}}
             # random: [choices] | {{uniform: [a, b]}} | {{loguniform: [a, b]}}
    duration: {{linspace: [0.4, 3.0, 27]}}
    payload: [0.0, 0.5, 1.0]
    variant:                  # one axis of setting bundles, e.g. a law with its gains
      - {{law: computed_torque, kp: [100, 60], kd: [20, 12]}}
      - {{law: pd, kp: [600, 300], kd: [60, 25]}}
  plot: {{x: duration, y: [torque_peak_1, deviation_max], by: law}}

{settings}

Each scenario starts at rest at `start`, plans as the planner node does (robot without
payload or model errors), and runs the controller's law and the simulator's RK4 and
sampled-data timing for the motion plus `hold` s. Output: one row per scenario with the
arm-sim analyze metrics (columns: see arm_sim/sweep.py). Exit codes: 0 ok, 1 a run or an
output failed, 2 bad spec or usage."""


def add_sweep_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``sweep`` sub-command to an argparse ``subparsers`` object."""
    try:
        shipped = ', '.join(shipped_specs()) or 'none found'
    except FileNotFoundError:
        shipped = 'none found'
    p = subparsers.add_parser(
        'sweep', help='run a grid or random sample of closed-loop scenarios headless',
        description='Run many closed-loop scenarios of the 2-R arm without ROS (the same '
        'planner, control laws, RK4 and sampled-data timing as the nodes), vectorised and '
        'in parallel, and write one row of metrics per scenario.',
        epilog=EPILOG.format(shipped=shipped, settings=_settings_help()),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('spec', metavar='SPEC', help='sweep spec (YAML) or a shipped spec name')
    p.add_argument('--output', metavar='FILE.csv', default=None,
                   help='write the results table (CSV: one row per scenario)')
    p.add_argument('--json', action='store_true', help='print the results as JSON on stdout')
    p.add_argument('--plot', metavar='FILE.png', default=None,
                   help="draw the spec's question (its plot section) into a PNG")
    p.add_argument('--workers', type=int, default=2,
                   help='local worker processes (default 2; 1 = this process)')
    p.add_argument('--chunk-size', type=int, default=None,
                   help='scenarios stepped together per batch (default: about 4 chunks '
                   'per worker, 32-1024)')
    p.add_argument('--dask', metavar='SCHEDULER_ADDRESS', default=None,
                   help='run the chunks on a Dask distributed cluster (e.g. '
                   'tcp://10.0.0.5:8786; needs the dask extra); results equal the local run')
    p.add_argument('--quiet', action='store_true', help='no progress lines on stderr')
    p.set_defaults(func=run_sweep_command)
    return p


def run_sweep_command(args: argparse.Namespace) -> int:
    """Run ``arm-sim sweep``; returns the exit code (bad input is one line, never a
    traceback)."""
    def fail(msg: str, code: int = EXIT_USAGE) -> int:
        print(f'arm-sim sweep: {msg}', file=sys.stderr)
        return code

    path = resolve_spec(args.spec)
    if args.workers < 1:
        return fail(f'--workers must be >= 1, got {args.workers}')
    if args.chunk_size is not None and args.chunk_size < 1:
        return fail(f'--chunk-size must be >= 1, got {args.chunk_size}')
    try:
        spec = load_spec(path)
        scenarios = spec.scenarios()
    except (SpecError, ValueError) as exc:
        return fail(f'{path}: {exc}')
    for out in (args.output, args.plot):
        if out and not Path(out).resolve().parent.is_dir():
            return fail(f'{out}: its directory does not exist')
    started = time.monotonic()
    bar = None if args.quiet else Progress(len(scenarios))
    try:
        rows = run_sweep(scenarios, workers=args.workers, chunk_size=args.chunk_size,
                         dask=args.dask, progress=bar.add if bar else None)
    except SpecError as exc:
        return fail(str(exc), EXIT_ERROR)
    seconds = time.monotonic() - started
    try:
        if args.output:
            write_csv(rows, args.output)
        if args.plot:
            plot_sweep(spec, rows, args.plot)
    except OSError as exc:
        return fail(f'cannot write output: {exc}', EXIT_ERROR)
    if args.json:
        json.dump(to_json(spec, rows, seconds), sys.stdout, indent=1, allow_nan=False)
        print()
    else:
        print(summary(spec, rows, seconds))
        for out in (args.output, args.plot):
            if out:
                print(f'  wrote {out}')
    return EXIT_OK


__all__ = ['COLUMNS', 'METRIC_COLUMNS', 'SETTINGS', 'Planned', 'PlotSpec', 'Run', 'Scenario',
           'Spec', 'SpecError', 'add_sweep_parser', 'load_spec', 'make_chunks', 'parse_spec',
           'plot_sweep', 'run_chunk', 'run_single', 'run_sweep', 'segment_metrics',
           'write_csv']
