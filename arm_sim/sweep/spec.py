"""A sweep's spec: the scenario settings, the scenarios, and the YAML that lists them.

Pure: no rclpy.

Every scenario setting is an :class:`~arm_common.params.ParamSpec` (:data:`SETTINGS`: name,
kind, default, meaning, unit, range or choices), checked by :meth:`ParamSpec.check
<arm_common.params.ParamSpec.check>` as the nodes check their parameters, with the sweep's
own forms on top: a per-joint pair may be one number (both joints), a tip position is
``[x, y]``, a duration may be ``fastest``. A :class:`Scenario` validates itself; a
:class:`Spec` is a parsed spec file (:func:`parse_spec`, :func:`load_spec`) whose
:meth:`Spec.scenarios` are the grid's combinations or the random draws. Every refusal is
one line naming the key, the value and where (:class:`SpecError`).
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from arm_common.params import ParamSpec, resolve
from arm_common.yamlfile import YamlFileError, read_yaml
from arm_control.laws import BATCH_LAWS, Gains
from arm_control.model_params import CONTROL_MODEL_PARAMS, MODEL_KEYS, controller_model
from arm_dynamics.friction import (
    STATIC_FRICTION_RULE,
    JointFriction,
    static_friction_problem,
    static_friction_used,
)
from arm_dynamics.limits import DEFAULT_EFFORT
from arm_dynamics.models import joint_count
from arm_dynamics.robot import ROBOT_PARAMS
from arm_dynamics.sensors import whole_counts_reason
from arm_dynamics.two_link import TwoLinkArm
from arm_planner.planner import FEASIBILITY, MAX_DURATION
from arm_planner.time_scaling import KINDS
from arm_sim.sweep.columns import (
    COLUMNS,
    MARGIN_COLUMNS,
    MODEL_COLUMNS,
    REAL_COLUMNS,
    REAL_PER_JOINT,
    columns,
)

# The limits that size a sweep's work, all checked before anything is built or run
# (``arm-sim sweep --help`` and docs/sweeps.md state them).
MAX_SCENARIOS = 1_000_000     # scenarios per sweep (a grid's product of axis lengths, samples)
MAX_AXIS_VALUES = 100_000     # values of one axis (a list, a linspace/logspace count)
MAX_SAMPLES = 1_000_000       # control samples per scenario: (duration + hold) x control_rate
MAX_STEPS = 10_000_000        # RK4 steps per scenario: (duration + hold) / physics_step
MAX_SPEC_BYTES = 1_000_000    # a spec file (a short text: its axes make the scenarios)
MAX_SPEC_DEPTH = 16           # nesting of the spec's YAML collections
MAX_GAIN = 1e6                # kp, kd, ki, i_clamp: the controller node's gains.* maximum
MAX_PLOT_PANELS = 8           # plot: y columns (one panel each)
MAX_CURVES = 50               # plot: curves (values of `by`)
ROBOT = TwoLinkArm()      # the robot of config/arm.yaml (the model defaults)
PS = tuple(float(v) for v in ROBOT.forward_kinematics([-0.4, 1.2]))  # the demo's Ps, m
PF = (0.5, 1.2)           # the demo's Pf, m
TASKS = ('regulation', 'straight_line')
PROFILES = ('synchronized', 'set_point')
ELBOWS = ('down', 'up')
VARIANT = 'variant'       # the axis whose values are bundles of settings


class SpecError(ValueError):
    """A sweep spec that cannot run; the message (one line) names the key and the value."""


# ---------------------------------------------------------------------- settings
_GAINS = Gains()

#: Every scenario setting, in order: ``kind`` 'string' (one of ``choices``), 'double' or
#: 'doubles' of ``length`` 2 (per joint, or a tip position [x, y]), ``minimum`` /
#: ``maximum`` bounding every number. The check is :func:`check_setting`.
SETTINGS: dict[str, ParamSpec] = {p.name: p for p in (
    ParamSpec('task', 'string', 'straight_line', 'regulation | straight_line',
              choices=TASKS),
    ParamSpec('start', 'doubles', PS, "start tip position [x, y] (at rest; the demo's Ps)",
              'm', minimum=-10.0, maximum=10.0, length=2),
    ParamSpec('goal', 'doubles', PF, "goal tip position [x, y] (the demo's Pf)", 'm',
              minimum=-10.0, maximum=10.0, length=2),
    ParamSpec('elbow', 'string', 'down', 'elbow branch of the start: down (q2 > 0) | up',
              choices=ELBOWS),
    ParamSpec('duration', 'double', 1.0, "motion duration, or 'fastest' feasible within the "
              'effort limits', 's', minimum=0.0, maximum=MAX_DURATION, strict_min=True),
    ParamSpec('time_scaling', 'string', 'quintic', 'quintic | trapezoidal', choices=KINDS),
    ParamSpec('regulation_profile', 'string', 'synchronized',
              'regulation: synchronized | set_point', choices=PROFILES),
    ParamSpec('feasibility', 'string', 'stretch', 'planner vs effort limits: stretch (slow '
              'down to fit) | refuse | ignore (plan as asked; the torque saturates)',
              choices=(*FEASIBILITY, 'ignore')),
    ParamSpec('law', 'string', 'computed_torque', ' | '.join(BATCH_LAWS),
              choices=BATCH_LAWS),
    ParamSpec('kp', 'doubles', _GAINS.kp, 'proportional gain',
              '1/s^2 (computed_torque), N m/rad (others)', minimum=0.0, maximum=MAX_GAIN,
              length=2),
    ParamSpec('kd', 'doubles', _GAINS.kd, 'derivative gain',
              '1/s (computed_torque), N m s/rad (others)', minimum=0.0, maximum=MAX_GAIN,
              length=2),
    ParamSpec('ki', 'doubles', _GAINS.ki, 'integral gain (pid)', 'N m/(rad s)', minimum=0.0,
              maximum=MAX_GAIN, length=2),
    ParamSpec('i_clamp', 'doubles', _GAINS.i_clamp, 'bound of the integral term (pid)', 'N m',
              minimum=0.0, maximum=MAX_GAIN, length=2),
    ParamSpec('payload', 'double', 0.0, 'point mass at the tip of the plant, unknown to the '
              'controller and the planner', 'kg', minimum=0.0, maximum=1e4),
    ParamSpec('mass_error', 'double', 0.0, "the controller's model link masses are (1 + e) "
              'times the real ones', 'fraction', minimum=-1.0, maximum=100.0,
              strict_min=True),
    ParamSpec('length_error', 'double', 0.0, "the controller's model link lengths and centre "
              'of gravity distances are (1 + e) times the real ones', 'fraction',
              minimum=-1.0, maximum=100.0, strict_min=True),
    ParamSpec('control_model', 'string', '', "the controller's model instead of mass_error "
              'and length_error: a params file (FILE.yaml, as arm-sim identify --params-out '
              "writes it: its /** and /**/controller control_model.* values, checked as the "
              "controller checks them; relative to the spec's folder) or a mapping "
              '{link_lengths, com_distances: [m, m], link_masses: [kg, kg], link_inertias: '
              '[kg m^2, kg m^2], joint_damping: [N m s/rad, N m s/rad], gravity: m/s^2}, '
              'unset keys the robot\'s', 'file or mapping'),
    ParamSpec('control_rate', 'double', 100.0, 'control (state and command) rate; 1/rate a '
              'whole multiple of physics_step', 'Hz', minimum=0.1, maximum=1e5),
    ParamSpec('physics_step', 'double', 0.001, 'RK4 step of the plant', 's', minimum=1e-6,
              maximum=1.0),
    ParamSpec('effort_limits', 'doubles', DEFAULT_EFFORT,
              'torque limits (planner, controller and simulator)', 'N m', minimum=0.0,
              maximum=1e6, strict_min=True, length=2),
    ParamSpec('hold', 'double', 1.0, 'simulated time after the motion ends', 's', minimum=0.0,
              maximum=MAX_DURATION),
    # The real arm (docs/real-arm.md): the robot's motors and friction (planner, controller
    # and plant know the motors, as every node reads the robot parameters; only the plant
    # has friction), the simulator's sensors and actuation delay.
    ParamSpec('gear_ratios', 'doubles', ROBOT.gear_ratios, 'gear reduction of each joint '
              'motor (motor turns per joint turn)', '', minimum=0.0, strict_min=True,
              maximum=1e4, length=2),
    ParamSpec('motor_inertias', 'doubles', ROBOT.motor_inertias, 'rotor inertia of each '
              'motor, motor side (the joint sees gear_ratio^2 times it)', 'kg m^2',
              minimum=0.0, maximum=1e4, length=2),
    ParamSpec('motor_damping', 'doubles', ROBOT.motor_damping, 'viscous friction of each '
              'motor, motor side (the joint sees gear_ratio^2 times it)', 'N m s/rad',
              minimum=0.0, maximum=1e4, length=2),
    ParamSpec('coulomb_friction', 'doubles', (0.0, 0.0), 'Coulomb (sliding) friction of '
              'each joint, link side (plant only; stick/slip exact)', 'N m', minimum=0.0,
              maximum=1e4, length=2),
    ParamSpec('static_friction', 'doubles', (0.0, 0.0), 'break-away friction of each joint: '
              + STATIC_FRICTION_RULE, 'N m', minimum=0.0, maximum=1e4,
              length=2),
    ParamSpec('position_noise', 'doubles', (0.0, 0.0), 'standard deviation of the Gaussian '
              'noise on each measured joint position', 'rad', minimum=0.0, maximum=10.0,
              length=2),
    ParamSpec('velocity_noise', 'doubles', (0.0, 0.0), 'standard deviation of the Gaussian '
              'noise on each measured joint velocity', 'rad/s', minimum=0.0, maximum=1000.0,
              length=2),
    ParamSpec('encoder_resolution', 'doubles', (0.0, 0.0), 'encoder counts per revolution '
              'of each joint, whole (the measured position rounded to a count); 0 = ideal',
              'counts/rev', minimum=0.0, maximum=1e6, length=2),
    ParamSpec('sensing_delay', 'int', 0, 'the controller sees the measurement of the state '
              'k control periods old', 'periods', minimum=0, maximum=1000),
    ParamSpec('actuation_delay', 'int', 0, 'the command is applied k control periods after '
              'it answered its state (zero torque before)', 'periods', minimum=0,
              maximum=1000),
    ParamSpec('noise_seed', 'int', 0, 'seed of the measurement noise (numpy PCG64; the '
              "simulator's noise_seed: the same seed, the same draws)", '', minimum=0,
              maximum=1e9),
)}
#: The real-arm settings (their columns: :data:`~arm_sim.sweep.columns.REAL_COLUMNS`).
REAL_SETTINGS = ('gear_ratios', 'motor_inertias', 'motor_damping', 'coulomb_friction',
                 'static_friction', 'position_noise', 'velocity_noise', 'encoder_resolution',
                 'sensing_delay', 'actuation_delay', 'noise_seed')
#: The pairs that are tip positions (always [x, y]; other pairs may be one number).
POINTS = ('start', 'goal')
#: Per pair: the checks of one number given for both joints, of item 0 and of item 1
#: (each a 'double' ParamSpec, named ``kp``, ``kp[0]``, ``kp[1]`` in its messages).
_ITEMS = {n: (replace(p, kind='double', length=None),
              *(replace(p, name=f'{n}[{i}]', kind='double', length=None) for i in (0, 1)))
          for n, p in SETTINGS.items() if p.kind == 'doubles'}


def _number(param: ParamSpec, value: object) -> float:
    """``value`` as a float, or ValueError with :meth:`ParamSpec.check`'s reason (and the
    whole range where the setting has a maximum: the reason names the bound it broke)."""
    if isinstance(value, (np.integer, np.floating)):
        value = value.item()  # numpy numbers are numbers (ParamSpec knows int and float)
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 2 ** 1000:
        # beyond any range (and beyond a float: ParamSpec.check would overflow)
        bound = f'>= {param.minimum:g}' if value < 0 else f'<= {param.maximum:g}'
        raise ValueError(f'{param.name} must be {bound}, got an integer of '
                         f'{value.bit_length()} bits')
    reason = param.check(value)
    if reason:
        if param.maximum is not None and param.minimum is not None:
            reason += (f" (range {'(' if param.strict_min else '['}{param.minimum:g}, "
                       f'{param.maximum:g}])')
        raise ValueError(reason)
    return float(value)  # type: ignore[arg-type]


def check_setting(name: str, value: object) -> Any:
    """``value`` for setting ``name``, normalised: a string, a float (or ``'fastest'``),
    or a pair as a tuple of two floats (one number: the same on both joints); raises
    ValueError naming the setting and the value (:meth:`ParamSpec.check`'s reason)."""
    if name == 'control_model':
        return control_model_setting(value)
    param = SETTINGS[name]
    if param.kind == 'string':
        if not isinstance(value, str):  # ParamSpec would say "a string": name the choices
            raise ValueError(f"{name} must be one of {', '.join(param.choices or ())}; got "
                             f'{value!r}')
        reason = param.check(value)
        if reason:
            raise ValueError(reason)
        return str(value)
    if name == 'duration' and isinstance(value, str):
        if value == 'fastest':
            return value
        raise ValueError(f"{name} must be a number of seconds or 'fastest', got {value!r}")
    if param.kind == 'double':
        return _number(param, value)
    if param.kind == 'int':
        if isinstance(value, np.integer):
            value = value.item()
        if isinstance(value, float) and value.is_integer():
            value = int(value)  # 2.0 from a linspace: the whole number it is
        if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 2 ** 62:
            raise ValueError(f'{name} must be <= {param.maximum:g}, got an integer of '
                             f'{value.bit_length()} bits')
        reason = param.check(value)
        if reason:
            raise ValueError(f'{reason} (whole {param.unit or "number"}, range '
                             f'[{param.minimum:g}, {param.maximum:g}])')
        assert isinstance(value, int)
        return value
    one, first, second = _ITEMS[name]
    if isinstance(value, (list, tuple, np.ndarray)):
        if len(value) == 2:
            return _number(first, value[0]), _number(second, value[1])
        if name not in POINTS:
            raise ValueError(f'{name} must be a number or two numbers, got {list(value)!r}')
    elif name not in POINTS:
        x = _number(one, value)
        return x, x
    raise ValueError(f'{name} must be a tip position [x, y] in m, got {value!r}')


# ---------------------------------------------------------------------- control model
# MODEL_KEYS and CONTROL_MODEL_PARAMS: arm_control.model_params, the controller's own.
_MODEL_SPECS = ROBOT_PARAMS + CONTROL_MODEL_PARAMS
_INLINE_KEYS = (*MODEL_KEYS, 'gravity')


@dataclass(frozen=True)
class ControlModel:
    """A scenario's ``control_model``: the controller's model as the controller node
    builds it from ``values`` (its robot and ``control_model.*`` parameters, checked);
    ``source`` the params file as given, or ``inline``."""

    source: str
    values: tuple[tuple[str, Any], ...]

    def arm(self, robot: dict[str, Any] | None = None) -> TwoLinkArm:
        """The controller's model: ``control_model.<key>`` or the robot's ``<key>``, as
        ``ControllerNode`` builds it; ``robot`` overrides robot parameters (a scenario's
        motors)."""
        model = controller_model({**dict(self.values), **(robot or {})})
        assert isinstance(model, TwoLinkArm)  # checked by control_model_setting
        return model


def _model_values(given: dict, where: str) -> tuple[tuple[str, Any], ...]:
    """The resolved robot and control_model.* parameters for ``given`` (the controller
    node's start-up checks: :func:`arm_common.params.resolve`); ValueError naming each
    refused value."""
    try:
        p = resolve(_MODEL_SPECS, given, joint_count)
    except ValueError as exc:
        raise ValueError(f'{where}: {exc}') from None
    values = tuple((k, tuple(v) if isinstance(v, list) else v) for k, v in sorted(p.items()))
    cm = ControlModel(where, values)
    try:
        model = cm.arm() if p['model'] == 'two_link' else None
    except ValueError as exc:
        raise ValueError(f'{where}: {exc}') from None
    if model is None:
        raise ValueError(f"{where}: model {p['model']!r}: a sweep runs the two-link arm "
                         "(model 'two_link')")
    return values


def control_model_setting(value: object, base: Path | None = None) -> ControlModel | None:
    """A ``control_model`` value: None (the robot with ``mass_error``/``length_error``), a
    :class:`ControlModel`, a params file path (relative to ``base``, default the current
    folder) or a mapping of :data:`MODEL_KEYS` and ``gravity``; ValueError naming the bad
    value."""
    if value is None or isinstance(value, ControlModel):
        return value
    if isinstance(value, dict):
        unknown = [k for k in value if k not in _INLINE_KEYS]
        if unknown:
            raise ValueError(f'control_model: key {unknown[0]!r} unknown (known: '
                             f"{', '.join(_INLINE_KEYS)})")
        if not value:
            raise ValueError('control_model: an empty mapping (give link_masses, ... or '
                             'leave control_model out)')
        given = {f'control_model.{k}': v for k, v in value.items()}
        return ControlModel('inline', _model_values(given, 'control_model'))
    if not isinstance(value, str) or not value:
        raise ValueError('control_model must be a params file (FILE.yaml) or a mapping '
                         f'{{link_masses: [kg, kg], ...}}, got {value!r}')
    path = Path(value)
    if base is not None and not path.is_absolute():
        path = base / path
    where = f'control_model {value}'
    try:
        doc = read_yaml(path, max_bytes=MAX_SPEC_BYTES, max_depth=MAX_SPEC_DEPTH,
                        what='not a params file')
    except YamlFileError as exc:
        raise ValueError(f'{where}: {exc}') from None
    found: dict[str, Any] = {}
    for section in ('/**', '/**/controller'):
        params = doc.get(section, {}) if isinstance(doc, dict) else None
        params = params.get('ros__parameters', {}) if isinstance(params, dict) else None
        if not isinstance(params, dict):
            raise ValueError(f'{where}: not a params file (a mapping {section}: '
                             '{ros__parameters: {...}})')
        found.update(params)
    names = {s.name for s in _MODEL_SPECS}
    found = {k: v for k, v in found.items() if k in names}
    if not any(k.startswith('control_model.') for k in found):
        raise ValueError(f'{where}: sets no /**/controller control_model.* parameter (the '
                         'controller would use the robot itself)')
    return ControlModel(value, _model_values(found, where))


# ---------------------------------------------------------------------- scenarios
def _default(name: str) -> Any:
    return SETTINGS[name].default


@dataclass(frozen=True)
class Scenario:
    """One closed-loop run; field meanings and units in :data:`SETTINGS` (pairs are per
    joint). Validates itself: a bad value raises ValueError naming it."""

    task: str = _default('task')
    start: tuple[float, float] = _default('start')
    goal: tuple[float, float] = _default('goal')
    elbow: str = _default('elbow')
    duration: float | str = _default('duration')
    time_scaling: str = _default('time_scaling')
    regulation_profile: str = _default('regulation_profile')
    feasibility: str = _default('feasibility')
    law: str = _default('law')
    kp: tuple[float, float] = _default('kp')
    kd: tuple[float, float] = _default('kd')
    ki: tuple[float, float] = _default('ki')
    i_clamp: tuple[float, float] = _default('i_clamp')
    payload: float = _default('payload')
    mass_error: float = _default('mass_error')
    length_error: float = _default('length_error')
    control_model: ControlModel | None = None
    control_rate: float = _default('control_rate')
    physics_step: float = _default('physics_step')
    effort_limits: tuple[float, float] = _default('effort_limits')
    hold: float = _default('hold')
    gear_ratios: tuple[float, float] = _default('gear_ratios')
    motor_inertias: tuple[float, float] = _default('motor_inertias')
    motor_damping: tuple[float, float] = _default('motor_damping')
    coulomb_friction: tuple[float, float] = _default('coulomb_friction')
    static_friction: tuple[float, float] = _default('static_friction')
    position_noise: tuple[float, float] = _default('position_noise')
    velocity_noise: tuple[float, float] = _default('velocity_noise')
    encoder_resolution: tuple[float, float] = _default('encoder_resolution')
    sensing_delay: int = _default('sensing_delay')
    actuation_delay: int = _default('actuation_delay')
    noise_seed: int = _default('noise_seed')

    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(self, f.name, check_setting(f.name, getattr(self, f.name)))
        problem = static_friction_problem(self.static_friction, self.coulomb_friction)
        if problem:
            raise ValueError(problem)
        reason = whole_counts_reason(self.encoder_resolution)
        if reason:
            raise ValueError(reason)
        if self.control_model is not None and (self.mass_error or self.length_error):
            raise ValueError(f'control_model {self.control_model.source} and mass_error '
                             f'{self.mass_error:g} / length_error {self.length_error:g} '
                             "both set the controller's model: give one")
        self.timing()  # raises on a control period that is no whole number of steps
        if self.duration == 'fastest' and self.feasibility == 'ignore':
            raise ValueError("duration 'fastest' is fastest within the effort limits: "
                             "feasibility must be stretch or refuse, not 'ignore'")
        # The requested motion; a plan the planner stretches is checked again when planned.
        reason = self.too_long(0.0 if self.duration == 'fastest' else float(self.duration))
        if reason:
            raise ValueError(reason)

    def ticks(self, duration: float) -> int:
        """Control periods simulated for a motion of ``duration`` s: the motion plus
        ``hold``, rounded up."""
        period = round(1e9 / self.control_rate) * 1e-9
        return max(1, math.ceil((duration + self.hold) / period - 1e-9))

    def too_long(self, duration: float) -> str | None:
        """Why a motion of ``duration`` s (plus ``hold``) is more than one scenario may run
        (:data:`MAX_SAMPLES` control samples, :data:`MAX_STEPS` RK4 steps), or None."""
        ticks = self.ticks(duration)
        what = f'duration {duration:g} s + hold {self.hold:g} s'
        if ticks > MAX_SAMPLES:
            return (f'{what} at control_rate {self.control_rate:g} Hz is {ticks} control '
                    f'samples, more than {MAX_SAMPLES} per scenario')
        steps = ticks * self.timing()[1]
        if steps > MAX_STEPS:
            return (f'{what} at physics_step {self.physics_step:g} s is {steps} RK4 steps, '
                    f'more than {MAX_STEPS} per scenario')
        return None

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

    @property
    def motors(self) -> tuple[tuple[float, float], tuple[float, float], tuple[float, float]]:
        """``(gear_ratios, motor_inertias, motor_damping)``."""
        return self.gear_ratios, self.motor_inertias, self.motor_damping

    def robot(self) -> TwoLinkArm:
        """The robot with this scenario's motors (the one every node builds from the robot
        parameters): :data:`ROBOT` itself without motors."""
        return robot_with_motors(*self.motors)

    def plant(self) -> TwoLinkArm:
        """The simulated arm: the robot (its motors included) with ``payload`` kg at the
        tip of link 2 (:meth:`TwoLinkArm.with_payload
        <arm_dynamics.two_link.TwoLinkArm.with_payload>`)."""
        return self.robot().with_payload(self.payload)

    def model(self) -> TwoLinkArm:
        """The controller's model: the ``control_model``'s (:meth:`ControlModel.arm`; the
        scenario's motors where it sets none), or else the robot (its motors, without the
        payload) with the errors (:meth:`TwoLinkArm.with_errors
        <arm_dynamics.two_link.TwoLinkArm.with_errors>`). No friction: the laws know none."""
        if self.control_model is not None:
            return self.control_model.arm(dict(zip(_MOTOR_KEYS, self.motors)))
        return self.robot().with_errors(self.mass_error, self.length_error)

    def friction(self) -> JointFriction:
        """The plant's joint friction (a ``static_friction`` of 0: the joint's
        ``coulomb_friction``), as the simulator node builds it."""
        c = self.coulomb_friction
        return _friction(c, static_friction_used(self.static_friction, c))

    def sensor_settings(self) -> dict[str, Any]:
        """The keywords of :class:`~arm_dynamics.sensors.SensorModel` (``n`` apart)."""
        return dict(position_noise=self.position_noise, velocity_noise=self.velocity_noise,
                    encoder_resolution=self.encoder_resolution,
                    sensing_delay=self.sensing_delay, seed=self.noise_seed)

    @property
    def sensing(self) -> bool:
        """Whether the measurement can differ from the true state."""
        return bool(any(self.position_noise) or any(self.velocity_noise)
                    or any(self.encoder_resolution) or self.sensing_delay)

    @property
    def real(self) -> bool:
        """Whether any real-arm setting (:data:`REAL_SETTINGS`) differs from its default."""
        return any(getattr(self, k) != SETTINGS[k].default for k in REAL_SETTINGS)


_MOTOR_KEYS = ('gear_ratios', 'motor_inertias', 'motor_damping')


@functools.lru_cache(maxsize=256)
def robot_with_motors(gear_ratios: tuple[float, float], motor_inertias: tuple[float, float],
                      motor_damping: tuple[float, float]) -> TwoLinkArm:
    """:data:`ROBOT` with these motors (ROBOT itself for its own)."""
    if (gear_ratios, motor_inertias, motor_damping) == (
            ROBOT.gear_ratios, ROBOT.motor_inertias, ROBOT.motor_damping):
        return ROBOT
    return replace(ROBOT, gear_ratios=gear_ratios, motor_inertias=motor_inertias,
                   motor_damping=motor_damping)


@functools.lru_cache(maxsize=256)
def _friction(coulomb: tuple[float, ...], static: tuple[float, ...]) -> JointFriction:
    return JointFriction(coulomb=np.array(coulomb), static=np.array(static))


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
    margins: bool = False

    @property
    def columns(self) -> tuple[str, ...]:
        """Its result columns (:func:`~arm_sim.sweep.columns.columns`): :data:`~arm_sim.
        sweep.columns.COLUMNS`, the ``control_model`` column if a scenario gives one, the
        margin columns if ``margins``."""
        return columns(self.margins, self.uses_control_model, self.uses_real_arm)

    @property
    def uses_real_arm(self) -> bool:
        """Whether the spec gives a real-arm setting (:data:`REAL_SETTINGS`), in
        ``scenario``, ``axes`` or a ``variant``."""
        bundles = self.axes.get(VARIANT)
        if bundles is not None and not isinstance(bundles, list):
            bundles = bundles['arg']
        return any(k in self.scenario or k in self.axes
                   or any(k in b for b in bundles or ()) for k in REAL_SETTINGS)

    @property
    def uses_control_model(self) -> bool:
        """Whether some scenario's controller model is a ``control_model``."""
        values = setting_values(self, 'control_model') or ()
        return any(isinstance(v, ControlModel) for v in values)

    def count(self) -> int:
        """The number of scenarios (without building them)."""
        if self.kind == 'random':
            return self.samples
        return math.prod(len(v) for v in self.axes.values())

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
        for i, combo in enumerate(combos):
            values = dict(base)
            for n, v in zip(names, combo):
                values.update(v if n == VARIANT else {n: v})
            try:
                out.append(Scenario(**values))
            except ValueError as exc:
                raise ValueError(f'scenario {i}: {exc}') from None
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
        'axes': 'varied settings', 'plot': '{x: COLUMN, y: [COLUMN...], by: COLUMN}',
        'margins': 'true: add the stability-margin columns phase_margin [deg], gain_margin '
                   '[dB], bandwidth [Hz] per joint (the linearised loop at the goal; some ms '
                   'per scenario); default false'}


def _known(what: str, key: object, known: Sequence[str] | dict) -> None:
    if key not in known:
        raise SpecError(f"{what}key {key!r} unknown (known: {', '.join(known)})")


def _check_setting(where: str, name: str, value: object) -> Any:
    try:
        return check_setting(name, value)
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
            if not isinstance(lo, (float, tuple)):
                raise SpecError(f'{where}: {op} needs numbers, got {arg!r}')
            if op == 'logspace' and not (np.asarray(lo) > 0).all() & (np.asarray(hi) > 0).all():
                raise SpecError(f'{where}: logspace needs first and last > 0, got {arg!r}')
            fn = np.linspace if op == 'linspace' else np.geomspace
            values = [v.tolist() for v in fn(np.asarray(lo), np.asarray(hi), arg[2])]
        else:
            if not (isinstance(arg, list) and len(arg) == 2):
                raise SpecError(f'{where}: {op} takes [low, high], got {arg!r}')
            lo, hi = (_check_setting(where, name, v) for v in arg)
            if not isinstance(lo, (float, tuple)):
                raise SpecError(f'{where}: {op} needs numbers, got {arg!r}')
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


def _count(value: object) -> int | None:
    """The number of values an axis lists (a list, or a linspace/logspace count), read off
    the spec before anything is built; None for a random range or a malformed axis (its
    parsing says why)."""
    if isinstance(value, list):
        return len(value)
    if isinstance(value, dict) and len(value) == 1:
        (op, arg), = value.items()
        if (op in ('linspace', 'logspace') and isinstance(arg, list) and len(arg) == 3
                and isinstance(arg[2], int) and not isinstance(arg[2], bool)):
            return arg[2]
    return None


def _control_models(scenario: dict, axes: dict, base: Path | None) -> None:
    """Read every ``control_model`` of the spec in place (a file relative to ``base``) as a
    :class:`ControlModel`; refuse it beside ``mass_error``/``length_error``."""
    where: list[str] = []
    errors = [k for k in ('mass_error', 'length_error') if k in scenario or k in axes]

    def read(at: str, value: object) -> ControlModel | None:
        try:
            return control_model_setting(value, base)
        except ValueError as exc:
            reason = str(exc)
            for prefix in ('control_model: ', 'control_model '):
                reason = reason.removeprefix(prefix)
            raise SpecError(f'{at}: {reason}') from None

    if 'control_model' in scenario:
        where.append('scenario')
        scenario['control_model'] = read('scenario.control_model', scenario['control_model'])
    if 'control_model' in axes:
        where.append('axes')
        values = axes['control_model']
        if not isinstance(values, list):
            raise SpecError('axes.control_model: must be a list of models (params files or '
                            f'mappings), got {values!r}')
        axes['control_model'] = [read(f'axes.control_model[{i}]', v)
                                 for i, v in enumerate(values)]
    bundles = axes.get(VARIANT)
    if isinstance(bundles, list):
        for i, b in enumerate(bundles):
            if isinstance(b, dict):
                if 'control_model' in b:
                    where.append(f'axes.{VARIANT}[{i}]')
                    b['control_model'] = read(f'axes.{VARIANT}[{i}].control_model',
                                              b['control_model'])
                errors += [k for k in ('mass_error', 'length_error') if k in b]
    if where and errors:
        raise SpecError(f"control_model (in {where[0]}) and {errors[0]} both set the "
                        "controller's model: give one (a control_model is the whole model; "
                        'mass_error and length_error scale the robot)')


def parse_spec(doc: object, name: str = 'sweep', base: str | Path | None = None) -> Spec:
    """Validate a spec document (the YAML's content); raises :class:`SpecError`. The work
    it asks for is bounded before anything is built: :data:`MAX_AXIS_VALUES` per axis,
    :data:`MAX_SCENARIOS` in all; each scenario's length by :class:`Scenario`. ``base``:
    the folder a ``control_model`` file is relative to (default: the current one)."""
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
    margins = doc.get('margins', False)
    if not isinstance(margins, bool):
        raise SpecError(f'margins must be true or false (true: add the stability-margin '
                        f'columns), got {margins!r}')
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
    # Size the work before building any axis.
    counts = {k: _count(v) for k, v in axes.items()}
    for k, n in counts.items():
        if n is not None and n > MAX_AXIS_VALUES:
            raise SpecError(f'axes.{k}: {n} values, more than {MAX_AXIS_VALUES} per axis')
    if kind == 'grid':
        total = math.prod(n for n in counts.values() if n is not None)
        if total > MAX_SCENARIOS:
            sizes = ' x '.join(f'{k} {n}' for k, n in counts.items() if n is not None)
            raise SpecError(f'the grid has {total} scenarios ({sizes}), more than '
                            f'{MAX_SCENARIOS}')
    scenario, axes = dict(scenario), dict(axes)
    if VARIANT in axes and isinstance(axes[VARIANT], list):
        axes[VARIANT] = [dict(b) if isinstance(b, dict) else b for b in axes[VARIANT]]
    _control_models(scenario, axes, None if base is None else Path(base))
    fixed = {k: _check_setting(f'scenario.{k}', k, v) for k, v in scenario.items()}
    taken = set(scenario) | set(axes)
    parsed = {k: (_variants(kind, v, taken) if k == VARIANT else _axis(kind, k, v))
              for k, v in axes.items()}
    spec = Spec(name=str(doc.get('name', name)), question=str(doc.get('question', '')),
                kind=kind, scenario=fixed, axes=parsed, samples=samples, seed=seed,
                margins=margins)
    return replace(spec, plot=_plot_spec(doc.get('plot'), spec))


#: Result columns that hold text, not numbers (``duration_requested`` holds 'fastest'
#: where a scenario asks for it).
TEXT_COLUMNS = ('task', 'elbow', 'time_scaling', 'regulation_profile', 'feasibility', 'law',
                'status', 'message')
#: The setting behind each input column (the others are the run's outcome).
COLUMN_SETTING = {
    **{n: n for n in SETTINGS if n in COLUMNS and n != 'duration'},  # 'duration': planned
    'start_x': 'start', 'start_y': 'start', 'goal_x': 'goal', 'goal_y': 'goal',
    'duration_requested': 'duration', 'effort_limit_1': 'effort_limits',
    'effort_limit_2': 'effort_limits',
    **{f'{g}_{j}': g for g in ('kp', 'kd', 'ki', 'i_clamp') for j in (1, 2)},
    **{f'{c}_{j}': s for c, s in zip(REAL_PER_JOINT, REAL_SETTINGS) for j in (1, 2)},
    **{n: n for n in ('sensing_delay', 'actuation_delay', 'noise_seed')}}


def setting_values(spec: Spec, name: str) -> list | None:
    """The values setting ``name`` takes in the spec's scenarios (with repeats), or None
    where a random axis draws it from a range."""
    if name in spec.scenario:
        return [spec.scenario[name]]
    axis = spec.axes.get(name)
    if axis is not None:
        return axis if isinstance(axis, list) else (
            axis['arg'] if axis['kind'] == 'choice' else None)
    bundles = spec.axes.get(VARIANT)
    if bundles is not None:
        bundles = bundles if isinstance(bundles, list) else bundles['arg']
        if any(name in b for b in bundles):
            return [b.get(name, SETTINGS[name].default) for b in bundles]
    return [SETTINGS[name].default]


def plot_problem(ps: PlotSpec, spec: Spec) -> str | None:
    """Why ``ps`` cannot be drawn from the rows of ``spec`` (checked before the run: a
    text column across or up, too many panels or curves), or None."""
    if len(ps.y) > MAX_PLOT_PANELS:
        return f'y has {len(ps.y)} columns, more than {MAX_PLOT_PANELS} panels'
    fastest = 'fastest' in (setting_values(spec, 'duration') or ())
    for where, col in (('x', ps.x), *(('y', c) for c in ps.y)):
        if col in TEXT_COLUMNS or (col == 'duration_requested' and fastest):
            why = ("is 'fastest' in some scenarios (the planned duration is 'duration')"
                   if col == 'duration_requested' else 'holds text')
            return f'{where}: column {col!r} {why}; {where} must be a number column'
    if ps.by is None:
        return None
    if ps.by == 'index':
        n = spec.count()
    elif ps.by in COLUMN_SETTING:
        values = setting_values(spec, COLUMN_SETTING[ps.by])
        if values is None:
            return (f'by: {ps.by!r} is drawn from a range (one curve per value): draw it '
                    'across (x), or give its axis a list of values')
        n = len({tuple(v) if isinstance(v, list) else v for v in values})
    else:
        return None  # an outcome: counted when drawn
    if n > MAX_CURVES:
        return f'by: {ps.by!r} has {n} values, more than {MAX_CURVES} curves'
    return None


def _plot_spec(value: object, spec: Spec) -> PlotSpec | None:
    if value is None:
        return None
    if not isinstance(value, dict):
        raise SpecError(f'plot must be a mapping {{x, y, by}}, got {value!r}')
    for key in value:
        _known('plot: ', key, ('x', 'y', 'by'))
    y = value.get('y', [])
    y = [y] if isinstance(y, str) else y
    if not isinstance(y, list):
        raise SpecError(f'plot: y must be a column or a list of columns, got {y!r}')
    cols = [value.get('x'), *y] + ([value['by']] if value.get('by') is not None else [])
    for c in cols:
        if c in MARGIN_COLUMNS and not spec.margins:
            raise SpecError(f"plot: column {c!r} needs 'margins: true' (the margin columns "
                            'are computed only when asked)')
        if c in MODEL_COLUMNS and not spec.uses_control_model:
            raise SpecError(f"plot: column {c!r} needs a control_model setting")
        if c in REAL_COLUMNS and not spec.uses_real_arm:
            raise SpecError(f'plot: column {c!r} needs a real-arm setting (one of '
                            f"{', '.join(REAL_SETTINGS)})")
        if c == 'pole_radius' and not (spec.uses_real_arm and spec.margins):
            raise SpecError("plot: column 'pole_radius' needs 'margins: true' and a real-arm "
                            'setting')
        _known('plot: column ', c, spec.columns)
    if not y:
        raise SpecError('plot: y must name at least one column')
    ps = PlotSpec(x=str(value['x']), y=tuple(y), by=value.get('by'))
    reason = plot_problem(ps, spec)
    if reason:
        raise SpecError(f'plot: {reason}')
    return ps


def load_spec(path: str | Path) -> Spec:
    """Read and validate a YAML spec; raises :class:`SpecError` (also for an unreadable
    file, bad YAML, a file over :data:`MAX_SPEC_BYTES`, YAML anchors or aliases)."""
    try:
        doc = read_yaml(path, max_bytes=MAX_SPEC_BYTES, max_depth=MAX_SPEC_DEPTH,
                        what='a spec is a short text (its axes make the scenarios)')
    except YamlFileError as exc:
        raise SpecError(str(exc)) from None
    return parse_spec(doc, Path(path).stem, Path(path).parent)


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
