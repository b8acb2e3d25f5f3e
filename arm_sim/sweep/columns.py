"""The result table of a sweep: its columns, in order (meanings and units: the
:mod:`arm_sim.sweep` docstring), and how a row stores a value. Pure: no rclpy."""

from __future__ import annotations

import math

from arm_bag.metrics import METRIC_NAMES, PER_JOINT_METRICS

#: The stability margins a spec asks for with ``margins: true`` (per joint): phase margin
#: [deg], gain margin [dB], bandwidth (the gain crossover) [Hz]
#: (:mod:`arm_sim.sweep.margins`).
MARGIN_NAMES = ('phase_margin', 'gain_margin', 'bandwidth')
#: The real arm's per-joint input columns (a spec's ``gear_ratios`` is ``gear_ratio_1``,
#: ``gear_ratio_2``, ...; ``static_friction`` the value used: 0 given is the Coulomb one).
REAL_PER_JOINT = ('gear_ratio', 'motor_inertia', 'motor_damping', 'coulomb_friction',
                  'static_friction', 'position_noise', 'velocity_noise', 'encoder_resolution')
#: The real arm's outcome columns: ``friction_band`` [rad per joint] static friction over
#: kp (pd, pd_gravity: the half-width of the band a proportional loop can stop in),
#: ``hold_oscillation`` [rad per joint] (the peak-to-peak joint position over the last
#: half of the hold: 0 at rest, large where the loop oscillates), ``friction_loss`` [J].
REAL_OUTCOMES = ('friction_band', 'hold_oscillation', 'friction_loss')
#: Per-joint metric and input columns (written ``<name>_1``, ``<name>_2``).
PER_JOINT = ('kp', 'kd', 'ki', 'i_clamp', 'effort_limit', 'planned_peak_torque',
             *PER_JOINT_METRICS, *MARGIN_NAMES, *REAL_PER_JOINT,
             'friction_band', 'hold_oscillation')
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
#: The real-arm columns, after :data:`COLUMNS` (and the ``control_model`` one) in a sweep
#: whose spec gives a real-arm setting (motors, friction, sensors, delays): the settings,
#: then :data:`REAL_OUTCOMES`; ``pole_radius`` (the linearised loop's largest pole
#: magnitude, delays included: > 1 is unstable) also needs ``margins: true``.
REAL_COLUMNS = tuple(c for name in (*REAL_PER_JOINT, 'sensing_delay', 'actuation_delay',
                                    'noise_seed', *REAL_OUTCOMES)
                     for c in ((f'{name}_1', f'{name}_2') if name in PER_JOINT else (name,)))
#: The margin column of a real-arm sweep with ``margins: true``.
POLE_COLUMNS = ('pole_radius',)
#: The ``control_model`` column, after :data:`COLUMNS` in a sweep whose spec gives a
#: ``control_model`` (the params file, or ``inline``).
MODEL_COLUMNS = ('control_model',)


def columns(margins: bool = False, control_model: bool = False,
            real: bool = False) -> tuple[str, ...]:
    """A sweep's columns: :data:`COLUMNS`, then :data:`MODEL_COLUMNS` if its spec gives a
    ``control_model``, :data:`REAL_COLUMNS` if it gives a real-arm setting, then
    :data:`MARGIN_COLUMNS` if it asks for ``margins`` (and :data:`POLE_COLUMNS` with
    both)."""
    return COLUMNS + (MODEL_COLUMNS if control_model else ()) + (
        REAL_COLUMNS if real else ()) + (MARGIN_COLUMNS if margins else ()) + (
        POLE_COLUMNS if real and margins else ())


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
