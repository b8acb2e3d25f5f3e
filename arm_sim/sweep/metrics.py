"""A scenario's result row: its settings, its outcome, and the ``arm-sim analyze`` metrics
of its recorded run (from :mod:`arm_bag.metrics`, the functions the analysis uses).

Pure: no rclpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from arm_bag import metrics
from arm_sim.sweep.columns import COLUMNS, MARGIN_NAMES, REAL_COLUMNS, REAL_PER_JOINT, put
from arm_sim.sweep.margins import scenario_margins
from arm_sim.sweep.plan import Planned
from arm_sim.sweep.spec import REAL_SETTINGS, ROBOT, Scenario

#: The laws whose ``friction_band`` is defined: kp in N m/rad acts alone at rest.
BAND_LAWS = ('pd', 'pd_gravity')
#: ``hold_oscillation`` looks at the last this fraction of the hold.
HOLD_WINDOW = 0.5


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


def new_row(index: int, s: Scenario, planned: Planned) -> dict:
    """The row of scenario ``s`` before its run: settings (``control_model``: the params
    file, ``inline`` or empty; with one, ``mass_error`` and ``length_error`` NaN), plan
    outcome (``ok`` or ``refused``), every metric undefined (NaN)."""
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
        put(row, k, v)
    if s.control_model is not None:  # the model is the file's or the mapping's: no errors
        row['mass_error'] = row['length_error'] = math.nan
    row['control_model'] = '' if s.control_model is None else s.control_model.source
    row.update(dict.fromkeys(REAL_COLUMNS, math.nan))
    for col, name in zip(REAL_PER_JOINT, REAL_SETTINGS):
        put(row, col, getattr(s, name))
    put(row, 'static_friction', s.friction().static.tolist())  # 0 given: the Coulomb value
    for name in ('sensing_delay', 'actuation_delay', 'noise_seed'):
        row[name] = getattr(s, name)
    if s.law in BAND_LAWS:
        put(row, 'friction_band', [f / k if k > 0 else math.inf for f, k in
                                   zip(s.friction().static.tolist(), s.kp)])
    return row


def segment_metrics(t: np.ndarray, q: np.ndarray, qd: np.ndarray, effort: np.ndarray,
                    q_des: np.ndarray, planned: Planned, limits) -> dict[str, Any]:
    """The ``arm-sim analyze`` metrics of one segment: :func:`arm_bag.metrics.segment_metrics`,
    the function ``analyze`` uses.

    Parameters
    ----------
    t : (N,) s from the segment's start; q, qd, effort, q_des : (N, 2) rad, rad/s, N m,
        rad -- joint states (effort: applied over the period ending at each sample) and
        the reference at each sample.
    planned : the plan (set point; the line's ends for a straight line).
    limits : (2,) N m

    Returns
    -------
    dict keyed by the metric names of :data:`~arm_sim.sweep.columns.COLUMNS` (per joint:
    (2,) lists).
    """
    if planned.line is None:
        assert planned.set_point is not None  # a plan was made
        return metrics.segment_metrics(t, q, desired=q_des, set_point=planned.set_point,
                                       effort=effort, effort_limits=limits,
                                       work=(effort, q))
    return metrics.segment_metrics(t, q, desired=q_des, line=planned.line,
                                   xy=ROBOT.forward_kinematics(q), effort=effort,
                                   effort_limits=limits, work=(effort, q))


def add_margins(row: dict, s: Scenario, planned: Planned) -> dict:
    """Add the margin columns (:data:`~arm_sim.sweep.columns.MARGIN_COLUMNS`) to ``row``:
    :func:`~arm_sim.sweep.margins.scenario_margins` about the goal's joint angles (the
    plan's last point); NaN where there is no plan (``refused``) or no linearisation (the
    reason appended to ``message``)."""
    for name in MARGIN_NAMES:
        put(row, name, None)
    row['pole_radius'] = math.nan
    if planned.set_point is None:
        return row
    values, note = scenario_margins(s, planned.set_point)
    for k, v in values.items():
        put(row, k, v)
    if note:
        row['message'] = f"{row['message']}; {note}" if row['message'] else note
    return row


def finish_row(row: dict, s: Scenario, planned: Planned, run: Run) -> dict:
    """Complete ``row`` with the run: ``samples``, and ``diverged`` with its message or
    the metrics of :func:`segment_metrics`."""
    row['samples'] = len(run.t)
    if run.diverged:
        row['status'], row['message'] = 'diverged', run.diverged
        return row
    for k, v in segment_metrics(run.t, run.q, run.qd, run.effort, run.q_des, planned,
                                s.effort_limits).items():
        put(row, k, v)
    tail = run.t >= run.t[-1] - HOLD_WINDOW * s.hold
    put(row, 'hold_oscillation', np.ptp(run.q[tail], axis=0).tolist())
    row['friction_loss'] = metrics.friction_loss(s.friction().coulomb, run.q)
    return row
