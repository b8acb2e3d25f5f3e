"""The result table of a sweep: its columns, in order (meanings and units: the
:mod:`arm_sim.sweep` docstring), and how a row stores a value. Pure: no rclpy."""

from __future__ import annotations

import math

from arm_bag.metrics import METRIC_NAMES, PER_JOINT_METRICS

#: The stability margins a spec asks for with ``margins: true`` (per joint): phase margin
#: [deg], gain margin [dB], bandwidth (the gain crossover) [Hz]
#: (:mod:`arm_sim.sweep.margins`).
MARGIN_NAMES = ('phase_margin', 'gain_margin', 'bandwidth')
#: Per-joint metric and input columns (written ``<name>_1``, ``<name>_2``).
PER_JOINT = ('kp', 'kd', 'ki', 'i_clamp', 'effort_limit', 'planned_peak_torque',
             *PER_JOINT_METRICS, *MARGIN_NAMES)
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
#: The margin columns, after :data:`COLUMNS` in a sweep whose spec asks for them
#: (``margins: true``); a spec without it has :data:`COLUMNS` only.
MARGIN_COLUMNS = tuple(f'{name}_{j}' for name in MARGIN_NAMES for j in (1, 2))
#: The ``control_model`` column, after :data:`COLUMNS` in a sweep whose spec gives a
#: ``control_model`` (the params file, or ``inline``).
MODEL_COLUMNS = ('control_model',)


def columns(margins: bool = False, control_model: bool = False) -> tuple[str, ...]:
    """A sweep's columns: :data:`COLUMNS`, then :data:`MODEL_COLUMNS` if its spec gives a
    ``control_model``, then :data:`MARGIN_COLUMNS` if it asks for ``margins``."""
    return COLUMNS + (MODEL_COLUMNS if control_model else ()) + (
        MARGIN_COLUMNS if margins else ())


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
