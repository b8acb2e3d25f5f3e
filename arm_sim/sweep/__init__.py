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
end. The plant is the robot with the payload at its tip
(:meth:`~arm_dynamics.two_link.TwoLinkArm.with_payload`), the controller's model the robot
with the errors (:meth:`~arm_dynamics.two_link.TwoLinkArm.with_errors`).

Scenarios run vectorised: a chunk of them (one law, one control rate and physics step)
steps as one batch of (B, 2) states (the law: :func:`~arm_control.laws.law_torque`; the
plants: :class:`~arm_dynamics.batch.BatchSimulator` on
:class:`~arm_dynamics.two_link.TwoLinkBatch`); chunks run in parallel processes
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
  ``saturated_fraction`` [per joint], ``energy`` [J];
* only in a sweep whose spec gives a ``control_model`` (a params file or a mapping: the
  controller's model, instead of ``mass_error``/``length_error``, which are then empty):
  ``control_model`` (the file as given, ``inline``, or empty);
* only in a sweep whose spec gives a real-arm setting (motors, friction, sensors, delays;
  docs/sweeps.md): the settings (``gear_ratio``, ``motor_inertia``, ``motor_damping``,
  ``coulomb_friction``, ``static_friction``, ``position_noise``, ``velocity_noise``,
  ``encoder_resolution`` per joint; ``sensing_delay``, ``actuation_delay``,
  ``noise_seed``), ``friction_band`` [rad per joint: static / kp, pd and pd_gravity],
  ``hold_oscillation`` [rad per joint: peak-to-peak over the last half of the hold],
  ``friction_loss`` [J]; with ``margins: true`` also ``pole_radius`` (the linearised
  loop's largest pole |z|, delays included);
* only in a sweep whose spec says ``margins: true`` (:mod:`~arm_sim.sweep.margins`: the
  linearised sampled-data loop at the goal's joint angles, each joint's loop broken at its
  torque with the other closed): ``phase_margin`` [deg per joint], ``gain_margin`` [dB per
  joint; ``inf`` where the phase never reaches -180 deg below Nyquist], ``bandwidth``
  [Hz per joint, the gain crossover]; empty where the scenario was refused or the law has
  no linearisation (``message`` says why; it also says when the linearised loop is
  unstable).

The modules, each importing only those before it:

* :mod:`~arm_sim.sweep.columns`: the result table's columns, in order; the row store.
* :mod:`~arm_sim.sweep.spec`: the scenario settings (:data:`SETTINGS`, ParamSpecs checked
  as the nodes check their parameters), :class:`Scenario` (its plant and model),
  :class:`Spec` and :class:`PlotSpec`, parsing and loading a spec file
  (:class:`SpecError`), the shipped specs; the limits that bound a sweep's work
  (:data:`MAX_SCENARIOS`, :data:`MAX_AXIS_VALUES`, :data:`MAX_SAMPLES`, :data:`MAX_STEPS`,
  :data:`MAX_SPEC_BYTES`; YAML anchors and aliases refused), checked before anything is
  built.
* :mod:`~arm_sim.sweep.plan`: a scenario's plan (:class:`Planned`, :func:`plan_scenario`).
* :mod:`~arm_sim.sweep.margins`: a scenario's stability margins (``margins: true``).
* :mod:`~arm_sim.sweep.metrics`: a scenario's row and the metrics of its :class:`Run`
  (:func:`segment_metrics`).
* :mod:`~arm_sim.sweep.run`: the batch closed loop, :func:`run_chunk`,
  :func:`run_single`, chunking, :class:`Progress`, :func:`run_sweep` (processes, at most
  :func:`max_workers`, or Dask; Ctrl-C stops it with the finished rows:
  :class:`SweepStopped`).
* :mod:`~arm_sim.sweep.output`: CSV, JSON, the summary and the plot; :class:`OutputFile`
  (checked before the run, written whole or not at all).
* :mod:`~arm_sim.sweep.cli`: the ``arm-sim sweep`` parser, help and command.

This package re-exports their public names: ``from arm_sim.sweep import X`` works for each.
"""

from arm_sim.sweep.cli import (
    EPILOG,
    EXIT_ERROR,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_USAGE,
    add_sweep_parser,
    run_sweep_command,
)
from arm_sim.sweep.columns import COLUMNS, METRIC_COLUMNS, PER_JOINT, STATUSES
from arm_sim.sweep.metrics import Run, segment_metrics
from arm_sim.sweep.output import (
    OutputError,
    OutputFile,
    default_plot,
    plot_format,
    plot_sweep,
    summary,
    sweep_figure,
    to_json,
    write_csv,
)
from arm_sim.sweep.plan import FASTEST_REQUEST, IGNORE_LIMITS, Planned, plan_scenario
from arm_sim.sweep.run import (
    MAX_BATCH_SAMPLES,
    VELOCITY_LIMIT,
    Progress,
    SweepStopped,
    default_chunk_size,
    make_chunks,
    max_workers,
    run_chunk,
    run_single,
    run_sweep,
)
from arm_sim.sweep.spec import (
    ELBOWS,
    MAX_AXIS_VALUES,
    MAX_CURVES,
    MAX_GAIN,
    MAX_PLOT_PANELS,
    MAX_SAMPLES,
    MAX_SCENARIOS,
    MAX_SPEC_BYTES,
    MAX_SPEC_DEPTH,
    MAX_STEPS,
    PF,
    PROFILES,
    PS,
    ROBOT,
    SETTINGS,
    TASKS,
    VARIANT,
    PlotSpec,
    Scenario,
    Spec,
    SpecError,
    check_setting,
    load_spec,
    parse_spec,
    plot_problem,
    resolve_spec,
    shipped_specs,
)

__all__ = ['COLUMNS', 'ELBOWS', 'EPILOG', 'EXIT_ERROR', 'EXIT_INTERRUPTED', 'EXIT_OK',
           'EXIT_USAGE', 'FASTEST_REQUEST', 'IGNORE_LIMITS', 'MAX_AXIS_VALUES',
           'MAX_BATCH_SAMPLES', 'MAX_CURVES', 'MAX_GAIN', 'MAX_PLOT_PANELS', 'MAX_SAMPLES',
           'MAX_SCENARIOS', 'MAX_SPEC_BYTES', 'MAX_SPEC_DEPTH', 'MAX_STEPS', 'METRIC_COLUMNS',
           'PER_JOINT', 'PF', 'PROFILES', 'PS', 'ROBOT', 'SETTINGS', 'STATUSES', 'TASKS',
           'VARIANT', 'VELOCITY_LIMIT', 'OutputError', 'OutputFile', 'Planned', 'PlotSpec',
           'Progress', 'Run', 'Scenario', 'Spec', 'SpecError', 'SweepStopped',
           'add_sweep_parser', 'check_setting', 'default_chunk_size', 'default_plot',
           'load_spec', 'make_chunks', 'max_workers', 'parse_spec', 'plan_scenario',
           'plot_format', 'plot_problem', 'plot_sweep', 'resolve_spec', 'run_chunk',
           'run_single', 'run_sweep', 'run_sweep_command', 'segment_metrics',
           'shipped_specs', 'summary', 'sweep_figure', 'to_json', 'write_csv']
