"""The result table of a sweep: its columns, in order (meanings and units: the
:mod:`arm_sim.sweep` docstring), and how a row stores a value. Pure: no rclpy."""

from __future__ import annotations

import math

from arm_bag.metrics import METRIC_NAMES, PER_JOINT_METRICS

#: Per-joint metric and input columns (written ``<name>_1``, ``<name>_2``).
PER_JOINT = ('kp', 'kd', 'ki', 'i_clamp', 'effort_limit', 'planned_peak_torque',
             *PER_JOINT_METRICS)
_INPUTS = ('index', 'task', 'start_x', 'start_y', 'goal_x', 'goal_y', 'elbow',
           'duration_requested', 'time_scaling', 'regulation_profile', 'feasibility', 'law',
           'kp', 'kd', 'ki', 'i_clamp', 'payload', 'mass_error', 'length_error',
           'control_rate', 'physics_step', 'effort_limit', 'hold')
_OUTCOME = ('status', 'message', 'duration', 'planned_peak_torque', 'samples')
_METRICS = METRIC_NAMES  # the metric table's, in its order (arm_bag.metrics.METRICS)
#: Every column, in order.
COLUMNS = tuple(c for name in _INPUTS + _OUTCOME + _METRICS
                for c in ((f'{name}_1', f'{name}_2') if name in PER_JOINT else (name,)))
#: The metric columns (numbers; empty where undefined).
METRIC_COLUMNS = tuple(c for name in _METRICS
                       for c in ((f'{name}_1', f'{name}_2') if name in PER_JOINT else (name,)))
#: The values of the ``status`` column.
STATUSES = ('ok', 'refused', 'diverged')


def put(row: dict, name: str, value) -> None:
    """Store ``value`` under ``name`` in ``row``: a per-joint name as its two columns
    (None, or a None item, is NaN: undefined), any other as it is (None: NaN)."""
    if name in PER_JOINT:
        v = [math.nan, math.nan] if value is None else [
            math.nan if x is None else float(x) for x in value]
        row[f'{name}_1'], row[f'{name}_2'] = v
    else:
        row[name] = math.nan if value is None else value
