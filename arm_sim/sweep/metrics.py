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
from arm_sim.sweep.columns import COLUMNS, put
from arm_sim.sweep.plan import Planned
from arm_sim.sweep.spec import ROBOT, Scenario


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
    """The row of scenario ``s`` before its run: settings, plan outcome (``ok`` or
    ``refused``), every metric undefined (NaN)."""
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
    dict keyed by the metric names of :data:`~arm_sim.sweep.columns.COLUMNS` (per joint:
    (2,) lists).
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
    return row
