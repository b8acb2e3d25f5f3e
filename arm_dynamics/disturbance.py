"""Pushes and faults at exact simulated times: the schedule the simulator consults (pure:
numpy only, no rclpy).

A *disturbance scenario* (the simulator's ``disturbance_file``, YAML; the example
``config/disturbances/example.yaml`` documents every entry) lists

* **pushes** -- external loads on the arm: a force at the tip (``tip_force`` [N], base
  frame) or torques at the joints (``joint_torque`` [N m]), shaped as a ``step`` (held from
  ``at`` to the end of the run), a ``pulse`` (held for ``duration``) or an ``impulse`` (an
  instant change of momentum; the value is then an impulse, N s or N m s);
* **faults** -- from ``at`` until ``until`` (absent: to the end of the run): a joint's
  ``torque_loss`` (it delivers ``fraction`` x its command), a ``brake`` holding a joint, an
  ``encoder_frozen`` or ``encoder_bias`` on a joint's position measurement, and
  ``commands_dropped`` (effort commands never arrive).

Joints are named in the file by their 1-based number (as a user counts them: ``joint: 2``)
or by their name in ``joint_names`` (``joint: joint2``); in the API they are 0-based indices.

Time
----
Every time is simulated, integer nanoseconds. The file gives seconds (``at``, ``until``,
``duration``); each must be a whole number of nanoseconds (read exactly from its decimal
text, so ``0.1`` is 100 000 000 ns) *and* a whole multiple of the physics step, or the file
is refused naming the entry and the value. So every change happens exactly at a physics
step boundary, and over a physics step ``[t, t + dt)`` everything is constant: a push or a
fault is active at ``t`` iff ``start <= t < end`` (``end`` None: for ever). A pulse of 0.1 s
at a 1 ms step is active over exactly 100 steps; an impulse acts at the boundary ``at``,
before the step starting there.

How the simulator uses it (per physics step starting at ``t``)
--------------------------------------------------------------
1. velocities jump by :func:`apply_impulse` for each of :meth:`Disturbances.impulses`
   ``(t, t + dt)``, and by :func:`engage_brakes` where :meth:`Disturbances.locked` gains a
   joint;
2. the motor torque is ``torque_scale(t) * clip(command)`` (a torque loss acts on what the
   drive delivers, after the effort limits), plus the joint torques of :meth:`Disturbances.
   loads` -- an external load, never clipped; its tip force ``F`` enters the dynamics
   (:class:`~arm_dynamics.integrate.TipLoaded`): ``J(q)^T F`` at every RK4 stage;
3. braked joints stay put: :func:`braked_forward_dynamics` gives their acceleration zero
   (and the other joints' dynamics with those joints held);
4. an effort command arriving at ``t`` with :meth:`Disturbances.commands_dropped` is lost
   (a dropped message: the drive keeps the last command it received);
5. the published measurement is :meth:`Disturbances.measure` of the sensor model's one;
6. :meth:`Disturbances.events` of the period integrated go to the log, /diagnostics and the
   bag, one line each.

Modelled, and not
-----------------
* A tip force acts at the tool point (the arm's ``forward_kinematics`` point), in the plane,
  components in the base frame, fixed in direction while the arm moves; its joint torque is
  ``J(q)^T F`` (virtual work), ``J`` the tip Jacobian at the arm's configuration: the
  simulator evaluates it at every RK4 stage (:class:`~arm_dynamics.integrate.TipLoaded`),
  so it follows the arm within a physics step, exact to the integrator's order (the motor
  command is held).
  No moment at the tip, no force on an intermediate link, no contact.
* An impulse is an instant change of momentum, ``D(q) (qd+ - qd-) = J^T P`` (tip, ``P`` in
  N s) or ``= P`` (joints, N m s); positions do not jump.
* A torque loss scales the torque the joint delivers; the command and the effort limits
  are unchanged. Overlapping faults of one kind on one joint are refused (no ambiguity of
  how two losses combine).
* A brake is ideal: it grabs at ``at`` (the joint's velocity drops to zero in a plastic
  impact, :func:`engage_brakes`, the other joints taking the reaction) and holds with any
  torque until ``until``; no slip, no engagement time.
* A frozen encoder is a position counter that stops counting: the measured position holds
  the measurement made at the fault's start (the first :meth:`~Disturbances.measure` at or
  after ``at``: exact when ``at`` is on the control period grid, where the simulator
  measures), and the measured velocity -- which a drive derives from the counts -- is 0.
  The reading resumes true at ``until`` (an absolute encoder; an incremental one would keep
  the counts missed as an offset: model that with an ``encoder_bias`` from ``until``). A
  separate tachometer is not modelled.
* An encoder bias adds ``bias`` [rad] to the measured position (of a frozen joint too:
  freeze first, then bias); the measured velocity is unchanged (a constant offset has no
  rate).
* Dropped commands are the commands sent in the window; what the drive then does is the
  simulator's (holding the last command received is what a lost message gives).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from decimal import Decimal
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from arm_common.yamlfile import YamlFileError, read_yaml

#: Push kinds: a tip force [N] or joint torques [N m] (as an impulse: N s, N m s).
PUSH_KINDS = ('tip_force', 'joint_torque')
#: Push shapes.
SHAPES = ('step', 'pulse', 'impulse')
#: Fault kinds, and the keys each one's mapping takes.
FAULT_KEYS: dict[str, tuple[str, ...]] = {
    'torque_loss': ('joint', 'fraction'),
    'brake': ('joint',),
    'encoder_frozen': ('joint',),
    'encoder_bias': ('joint', 'bias'),
    'commands_dropped': (),
}
FAULT_KINDS = tuple(FAULT_KEYS)

# Bounds of a scenario, all checked before anything is built.
MAX_FILE_BYTES = 100_000     # a disturbance file (a short list of entries)
MAX_DEPTH = 8                # nesting of its YAML collections
MAX_ENTRIES = 1_000          # pushes, and faults, in one file
MAX_PUSHES = 10_000          # pushes in the schedule, live ones included
MAX_TIME_S = 1e6             # at, until, duration [s] (11.6 days of simulated time)
MAX_LOAD = 1e6               # |each component| of a force [N], torque [N m] or impulse
_NEVER = np.iinfo(np.int64).max

_UNITS = {('tip_force', False): 'N', ('joint_torque', False): 'N m',
          ('tip_force', True): 'N s', ('joint_torque', True): 'N m s'}


class DisturbanceError(ValueError):
    """A scenario or push that cannot be scheduled; the message (one line) names the file,
    the entry and the bad value."""


class ArmModel(Protocol):
    """What the pushes and brakes need of a model (every
    :class:`~arm_dynamics.models.RobotModel` has it)."""

    @property
    def n_dof(self) -> int: ...

    def jacobian(self, q) -> np.ndarray:
        """Tip Jacobian dp/dq [m/rad], (2, n)."""

    def mass_matrix(self, q) -> np.ndarray:
        """D(q) [kg m^2], (n, n)."""

    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        """tau [N m], (n,)."""

    def forward_dynamics(self, q, qd, tau) -> np.ndarray:
        """qdd [rad/s^2], (n,)."""


def _is_int(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def _setup(n: int, joint_names: Sequence[str], physics_step_ns: int
           ) -> tuple[int, tuple[str, ...], int]:
    """``(n, joint_names, physics_step_ns)`` checked (ValueError naming the bad one)."""
    if not _is_int(n) or n < 1:
        raise ValueError(f'n must be an integer >= 1, got {n!r}')
    if not _is_int(physics_step_ns) or physics_step_ns <= 0:
        raise ValueError(f'physics_step_ns must be an integer > 0, got {physics_step_ns!r}')
    names = tuple(joint_names)
    if len(names) != n or not all(isinstance(s, str) and s for s in names):
        raise ValueError(f'joint_names must be {n} non-empty names, got {list(names)!r}')
    return int(n), names, int(physics_step_ns)


def _fmt(values: Sequence[float]) -> str:
    return '[' + ', '.join(f'{v:g}' for v in values) + ']'


def _seconds(ns: int) -> str:
    return f'{ns * 1e-9:g} s'


@dataclass(frozen=True)
class Push:
    """An external load from ``start_ns``.

    ``kind`` 'tip_force' (``value`` (2,) N at the tool point, base frame) or 'joint_torque'
    (``value`` (n,) N m); ``shape`` 'step' (``end_ns`` None: held for ever), 'pulse'
    (active over ``[start_ns, end_ns)``) or 'impulse' (``end_ns`` None; ``value`` in N s or
    N m s, applied at ``start_ns``). ``label`` names it in events ('pushes[0]', 'live').
    """

    start_ns: int
    end_ns: int | None
    kind: str
    value: tuple[float, ...]
    shape: str
    label: str = field(default='', compare=False)

    def __post_init__(self) -> None:
        if self.kind not in PUSH_KINDS:
            raise ValueError(f"push kind must be one of {', '.join(PUSH_KINDS)}, got "
                             f'{self.kind!r}')
        if self.shape not in SHAPES:
            raise ValueError(f"push shape must be one of {', '.join(SHAPES)}, got "
                             f'{self.shape!r}')
        if not _is_int(self.start_ns) or self.start_ns < 0:
            raise ValueError(f'push start_ns must be an integer >= 0, got {self.start_ns!r}')
        end = self.end_ns
        if self.shape == 'pulse':
            if end is None or not _is_int(end) or end <= self.start_ns:
                raise ValueError(f'a pulse needs end_ns > start_ns {self.start_ns}, got '
                                 f'{self.end_ns!r}')
        elif end is not None:
            raise ValueError(f'a {self.shape} push has no end_ns, got {self.end_ns!r}')
        try:
            value = tuple(float(v) for v in self.value)
        except (TypeError, ValueError):
            raise ValueError(f'push value must be numbers, got {self.value!r}') from None
        if not value or not all(math.isfinite(v) and abs(v) <= MAX_LOAD for v in value):
            raise ValueError(f'push value must be finite numbers of magnitude <= '
                             f'{MAX_LOAD:g}, got {list(self.value)!r}')
        if self.kind == 'tip_force' and len(value) != 2:
            raise ValueError(f'a tip force has 2 components [x, y], got {len(value)}: '
                             f'{list(value)!r}')
        object.__setattr__(self, 'start_ns', int(self.start_ns))
        if self.end_ns is not None:
            object.__setattr__(self, 'end_ns', int(self.end_ns))
        object.__setattr__(self, 'value', value)

    @property
    def array(self) -> np.ndarray:
        """``value`` as a float array."""
        return np.array(self.value)

    def active(self, t_ns: int) -> bool:
        """Is this step or pulse acting over the physics step starting at ``t_ns``?
        (An impulse never is: it acts at an instant, see :meth:`Disturbances.impulses`.)"""
        if self.shape == 'impulse':
            return False
        return self.start_ns <= t_ns and (self.end_ns is None or t_ns < self.end_ns)


@dataclass(frozen=True)
class Fault:
    """A fault over ``[start_ns, end_ns)`` (``end_ns`` None: for ever).

    ``kind`` one of :data:`FAULT_KINDS`; ``joint`` the 0-based joint (None for
    'commands_dropped' only); ``fraction`` in [0, 1] the share of its torque a
    'torque_loss' joint delivers; ``bias`` [rad] what 'encoder_bias' adds.
    """

    start_ns: int
    end_ns: int | None
    kind: str
    joint: int | None = None
    fraction: float = 0.0
    bias: float = 0.0
    label: str = field(default='', compare=False)

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"fault kind must be one of {', '.join(FAULT_KINDS)}, got "
                             f'{self.kind!r}')
        if not _is_int(self.start_ns) or self.start_ns < 0:
            raise ValueError(f'fault start_ns must be an integer >= 0, got {self.start_ns!r}')
        if self.end_ns is not None and (not _is_int(self.end_ns)
                                        or self.end_ns <= self.start_ns):
            raise ValueError(f'fault end_ns must be > start_ns {self.start_ns} (or None), '
                             f'got {self.end_ns!r}')
        if self.kind == 'commands_dropped':
            if self.joint is not None:
                raise ValueError(f'commands_dropped concerns no joint, got joint '
                                 f'{self.joint!r}')
        elif self.joint is None or not _is_int(self.joint) or self.joint < 0:
            raise ValueError(f'a {self.kind} fault needs a joint index >= 0 (0-based), got '
                             f'{self.joint!r}')
        if not (isinstance(self.fraction, numbers.Real) and 0.0 <= self.fraction <= 1.0):
            raise ValueError(f'fraction must be in [0, 1], got {self.fraction!r}')
        if not (isinstance(self.bias, numbers.Real) and math.isfinite(self.bias)):
            raise ValueError(f'bias must be a finite number of rad, got {self.bias!r}')

    @property
    def index(self) -> int:
        """The 0-based joint (ValueError for 'commands_dropped', which has none)."""
        if self.joint is None:
            raise ValueError(f'a {self.kind} fault concerns no joint')
        return self.joint

    def active(self, t_ns: int) -> bool:
        """Is the fault on over the physics step starting at ``t_ns``?"""
        return self.start_ns <= t_ns and (self.end_ns is None or t_ns < self.end_ns)


@dataclass(frozen=True)
class Event:
    """A push or fault starting or ending at ``time_ns``: ``kind`` the push or fault kind,
    ``edge`` 'start' or 'end', ``label`` its entry ('pushes[0]', 'faults[2]', 'live'),
    ``description`` one line for the log, /diagnostics and the bag."""

    time_ns: int
    kind: str
    edge: str
    label: str
    description: str


class Disturbances:
    """The schedule of pushes and faults of one run of ``n`` joints.

    Parameters
    ----------
    pushes, faults : the schedule (checked against ``n`` and the step grid).
    n : int >= 1 -- joints.
    joint_names : (n,) names, for joints named in a file and for the events' text.
    physics_step_ns : int > 0 -- every time must be a whole multiple of it.
    source : names the schedule in errors (the file's path).
    tip_forces : False when the model has no tip (the geared link): tip pushes are refused.

    :meth:`load` and :meth:`from_mapping` build one from a scenario; :meth:`add_push` adds
    live pushes. Every query takes a time [ns] on the step grid and is pure except
    :meth:`measure` (a frozen encoder remembers what it held; call it in time order).
    """

    def __init__(self, pushes: Sequence[Push] = (), faults: Sequence[Fault] = (), *, n: int,
                 joint_names: Sequence[str], physics_step_ns: int, source: str = '<mapping>',
                 tip_forces: bool = True) -> None:
        self.n, self.joint_names, self.physics_step_ns = _setup(n, joint_names,
                                                                physics_step_ns)
        self.source = source
        self.tip_forces = tip_forces
        self._pushes: list[Push] = []
        self._arrays: tuple[np.ndarray, ...] | None = None
        for push in pushes:
            self.add_push(push)
        self._faults: tuple[Fault, ...] = tuple(faults)
        for f in self._faults:
            self._check_fault(f)
        self._check_overlaps()
        self._held: dict[int, float] = {}  # frozen encoders: fault index -> position held

    # ------------------------------------------------------------------ building
    @classmethod
    def load(cls, path: str | Path, *, n: int, joint_names: Sequence[str],
             physics_step_ns: int, tip_forces: bool = True) -> Disturbances:
        """The schedule of a scenario file (YAML). Raises :class:`DisturbanceError` naming
        the file, the entry and the bad value (also for an unreadable file, bad YAML or
        UTF-8, a file over :data:`MAX_FILE_BYTES`, YAML anchors or aliases, nesting deeper
        than :data:`MAX_DEPTH`)."""
        where = str(path)
        try:
            doc = read_yaml(path, max_bytes=MAX_FILE_BYTES, max_depth=MAX_DEPTH,
                            what='a disturbance file is a short list of pushes and faults')
        except YamlFileError as exc:
            raise DisturbanceError(f'{where}: {exc}') from None
        return cls.from_mapping(doc, n=n, joint_names=joint_names,
                                physics_step_ns=physics_step_ns, source=where,
                                tip_forces=tip_forces)

    @classmethod
    def from_mapping(cls, data: object, *, n: int, joint_names: Sequence[str],
                     physics_step_ns: int, source: str = '<mapping>',
                     tip_forces: bool = True) -> Disturbances:
        """The schedule of a parsed scenario ``{pushes: [...], faults: [...]}`` (None or
        empty: nothing). Raises :class:`DisturbanceError` naming ``source``, the entry and
        the bad value."""
        try:
            setup = _setup(n, joint_names, physics_step_ns)
        except ValueError as exc:
            raise DisturbanceError(f'{source}: {exc}') from None
        pushes, faults = _Parser(source, *setup, tip_forces).parse(data)
        return cls(pushes, faults, n=n, joint_names=joint_names,
                   physics_step_ns=physics_step_ns, source=source, tip_forces=tip_forces)

    def add_push(self, push: Push) -> None:
        """Schedule ``push`` (a live one: from a topic, starting at a step boundary the
        simulator chooses). Raises :class:`DisturbanceError` if it does not fit this arm or
        the step grid, or the schedule holds :data:`MAX_PUSHES` already."""
        label = push.label or 'push'
        where = f'{self.source}: {label}'
        if len(self._pushes) >= MAX_PUSHES:
            raise DisturbanceError(f'{where}: the schedule holds {MAX_PUSHES} pushes already')
        if push.kind == 'tip_force' and not self.tip_forces:
            raise DisturbanceError(f'{where}: tip_force {_fmt(push.value)}: this model has '
                                   'no tip; push with joint_torque')
        if push.kind == 'joint_torque' and len(push.value) != self.n:
            raise DisturbanceError(f'{where}: joint_torque must have {self.n} values (one '
                                   f'per joint), got {len(push.value)}: {_fmt(push.value)}')
        for name, t in (('start_ns', push.start_ns), ('end_ns', push.end_ns)):
            if t is not None and t % self.physics_step_ns:
                raise DisturbanceError(f'{where}: {name} {t} is not on the physics step grid '
                                       f'(a multiple of {self.physics_step_ns} ns)')
        self._pushes.append(push)
        self._arrays = None

    def _check_fault(self, f: Fault) -> None:
        where = f'{self.source}: {f.label or "fault"}'
        if f.joint is not None and f.joint >= self.n:
            raise DisturbanceError(f'{where}: joint index {f.joint} (0-based) >= {self.n} '
                                   'joints')
        for name, t in (('start_ns', f.start_ns), ('end_ns', f.end_ns)):
            if t is not None and t % self.physics_step_ns:
                raise DisturbanceError(f'{where}: {name} {t} is not on the physics step grid '
                                       f'(a multiple of {self.physics_step_ns} ns)')

    def _check_overlaps(self) -> None:
        """One fault of a kind per joint at a time (how two would combine is undefined)."""
        last: dict[tuple[str, int | None], Fault] = {}
        for f in sorted(self._faults, key=lambda f: f.start_ns):
            key = (f.kind, f.joint)
            prev = last.get(key)
            if prev is not None and (prev.end_ns is None or prev.end_ns > f.start_ns):
                on = '' if f.joint is None else f' on {self._joint_text(f.joint)}'
                until = 'the end' if prev.end_ns is None else _seconds(prev.end_ns)
                raise DisturbanceError(
                    f'{self.source}: {f.label or "fault"}: {f.kind}{on} at '
                    f'{_seconds(f.start_ns)} overlaps {prev.label or "another"} (until '
                    f'{until}): one {f.kind} per joint at a time')
            last[key] = f

    # ------------------------------------------------------------------ queries
    @property
    def pushes(self) -> tuple[Push, ...]:
        """Every push scheduled, file order then live ones in the order added."""
        return tuple(self._pushes)

    @property
    def faults(self) -> tuple[Fault, ...]:
        return self._faults

    @property
    def enabled(self) -> bool:
        """Is anything scheduled? (False: the simulator may skip every query.)"""
        return bool(self._pushes or self._faults)

    def _push_arrays(self) -> tuple[np.ndarray, ...]:
        """start, end, tip force (k, 2), joint torque (k, n) of the steps and pulses."""
        if self._arrays is None:
            held = [p for p in self._pushes if p.shape != 'impulse']
            start = np.array([p.start_ns for p in held], dtype=np.int64)
            end = np.array([_NEVER if p.end_ns is None else p.end_ns for p in held],
                           dtype=np.int64)
            tip = np.zeros((len(held), 2))
            joint = np.zeros((len(held), self.n))
            for i, p in enumerate(held):
                (tip if p.kind == 'tip_force' else joint)[i] = p.value
            self._arrays = (start, end, tip, joint)
        return self._arrays

    def loads(self, t_ns: int) -> tuple[np.ndarray, np.ndarray | None]:
        """The steps and pulses active over the physics step starting at ``t_ns``: the sum
        of their joint torques (n,) [N m] (constant over the step) and the sum ``F`` of
        their tip forces (2,) [N, base frame], None when it is zero. ``F``'s joint torque
        ``J(q)^T F`` depends on the configuration: integrate it inside the right-hand side
        (:class:`~arm_dynamics.integrate.TipLoaded`), not held at the step's start."""
        start, end, tip, joint = self._push_arrays()
        on = (start <= t_ns) & (t_ns < end)
        tau = joint[on].sum(axis=0) if on.any() else np.zeros(self.n)
        force = tip[on].sum(axis=0)
        return tau, (force if force.any() else None)

    def external_torque(self, t_ns: int, q, model: ArmModel) -> np.ndarray:
        """(n,) N m: the joint torque of the steps and pulses active over the physics step
        starting at ``t_ns``, at the configuration ``q``: ``J(q)^T F`` of the tip forces'
        sum ``F`` plus the joint torques. Zeros when none is (the model is then not
        asked)."""
        tau, force = self.loads(t_ns)
        if force is not None:
            tau = tau + np.asarray(model.jacobian(q), dtype=float).T @ force
        return tau

    def impulses(self, t0_ns: int, t1_ns: int) -> list[Push]:
        """The impulses at ``t0_ns <= at < t1_ns``, in time order (then schedule order):
        apply each with :func:`apply_impulse` before integrating the step starting there."""
        found = [p for p in self._pushes
                 if p.shape == 'impulse' and t0_ns <= p.start_ns < t1_ns]
        return sorted(found, key=lambda p: p.start_ns)

    def torque_scale(self, t_ns: int) -> np.ndarray:
        """(n,): the share of its torque each joint delivers over the step starting at
        ``t_ns`` (1.0, or a torque loss's ``fraction``)."""
        scale = np.ones(self.n)
        for f in self._faults:
            if f.kind == 'torque_loss' and f.active(t_ns):
                scale[f.index] = f.fraction
        return scale

    def locked(self, t_ns: int) -> np.ndarray | None:
        """(n,) bool: the joints a brake holds over the step starting at ``t_ns``; None
        when none is."""
        mask = np.zeros(self.n, dtype=bool)
        for f in self._faults:
            if f.kind == 'brake' and f.active(t_ns):
                mask[f.index] = True
        return mask if mask.any() else None

    def commands_dropped(self, t_ns: int) -> bool:
        """Is an effort command arriving at ``t_ns`` lost?"""
        return any(f.kind == 'commands_dropped' and f.active(t_ns) for f in self._faults)

    def measure(self, t_ns: int, q_meas, qd_meas) -> tuple[np.ndarray, np.ndarray]:
        """The measurement published at ``t_ns`` given the sensor model's ``q_meas`` [rad],
        ``qd_meas`` [rad/s] (n,): a frozen joint reads the position measured at its fault's
        start (the first call at or after it) and velocity 0; a bias adds to the position.
        Returns the arguments themselves when no encoder fault is on. Call in time order
        (a frozen encoder remembers what it holds)."""
        on = [(i, f) for i, f in enumerate(self._faults)
              if f.kind in ('encoder_frozen', 'encoder_bias') and f.active(t_ns)]
        if not on:
            return q_meas, qd_meas
        raw = np.asarray(q_meas, dtype=float)
        q, qd = raw.copy(), np.array(qd_meas, dtype=float)
        for i, f in on:
            if f.kind == 'encoder_frozen':
                j = f.index
                q[j] = self._held.setdefault(i, float(raw[j]))
                qd[j] = 0.0
        for _, f in on:
            if f.kind == 'encoder_bias':
                q[f.index] += f.bias
        return q, qd

    def events(self, t0_ns: int, t1_ns: int) -> list[Event]:
        """The starts and ends at ``t0_ns <= t < t1_ns``, in time order (at one time: ends
        first, then schedule order), each once: a step push and an impulse have a start
        only, a fault without ``until`` too."""
        found: list[tuple[int, int, int, Event]] = []
        items: list[Push | Fault] = [*self._pushes, *self._faults]
        for seq, item in enumerate(items):
            for edge, t in (('start', item.start_ns), ('end', item.end_ns)):
                if t is not None and t0_ns <= t < t1_ns:
                    event = Event(t, item.kind, edge, item.label, self.describe(item, edge))
                    found.append((t, edge == 'start', seq, event))
        return [e for *_, e in sorted(found, key=lambda x: x[:3])]

    # ------------------------------------------------------------------ text
    def _joint_text(self, j: int) -> str:
        return f'joint {j + 1} ({self.joint_names[j]})'

    def describe(self, item: Push | Fault, edge: str = 'start') -> str:
        """One line for a push's or fault's start (or ``edge`` 'end'), e.g. ``push: tip
        force [0, -30] N pulse 0.1 s``."""
        if isinstance(item, Push):
            impulse = item.shape == 'impulse'
            what = (f"{item.kind.replace('_', ' ')} {_fmt(item.value)} "
                    f'{_UNITS[item.kind, impulse]}')
            if item.end_ns is not None:
                shape = f'pulse {_seconds(item.end_ns - item.start_ns)}'
            else:
                shape = 'impulse' if impulse else 'step (held)'
            return f"push{' end' if edge == 'end' else ''}: {what} {shape}"
        if item.kind == 'commands_dropped':
            text = 'effort commands dropped'
        else:
            text = f"{self._joint_text(item.index)} {item.kind.replace('_', ' ')}"
            if item.kind == 'torque_loss':
                text += f': delivers {item.fraction:g} x its command'
            elif item.kind == 'encoder_bias':
                text += f' {item.bias:+g} rad'
            elif item.kind == 'brake':
                text = f'{self._joint_text(item.index)} braked'
        if edge == 'end':
            return f'fault end: {text}'
        until = ' (to the end)' if item.end_ns is None else f' until {_seconds(item.end_ns)}'
        return f'fault: {text}{until}'


# ---------------------------------------------------------------------- impulses, brakes
def apply_impulse(model: ArmModel, q, qd, kind: str, value) -> np.ndarray:
    """The velocity [rad/s] (n,) right after an impulse at configuration ``q``:
    ``qd + D(q)^-1 J(q)^T P`` for a tip impulse ``P`` (2,) [N s] (``kind`` 'tip_force'),
    ``qd + D(q)^-1 P`` for joint impulses (n,) [N m s] ('joint_torque')."""
    p = np.asarray(value, dtype=float)
    if kind == 'tip_force':
        p = np.asarray(model.jacobian(q), dtype=float).T @ p
    elif kind != 'joint_torque':
        raise ValueError(f"kind must be one of {', '.join(PUSH_KINDS)}, got {kind!r}")
    return np.asarray(qd, dtype=float) + np.linalg.solve(model.mass_matrix(q), p)


def _free(locked) -> np.ndarray:
    return ~np.asarray(locked, dtype=bool)


def engage_brakes(model: ArmModel, q, qd, locked) -> np.ndarray:
    """The velocity [rad/s] (n,) right after brakes grab the ``locked`` joints ((n,) bool):
    a plastic impact -- the locked joints stop, the brakes' impulses act on them only, so
    the free joints keep their momentum: ``D (qd+ - qd) = S^T lambda``, ``S qd+ = 0``
    (``S`` selects the locked joints). Kinetic energy never grows."""
    qd = np.asarray(qd, dtype=float)
    free = _free(locked)
    out = np.zeros_like(qd)
    if free.any():
        d = np.asarray(model.mass_matrix(q), dtype=float)
        # momentum of the free joints kept: (D qd+)_free = (D qd)_free with qd+_locked = 0
        out[free] = np.linalg.solve(d[np.ix_(free, free)], (d @ qd)[free])
    return out


def braked_forward_dynamics(model: ArmModel, q, qd, tau, locked) -> np.ndarray:
    """qdd [rad/s^2] (n,) with the ``locked`` joints ((n,) bool) held by their brakes:
    zero there, and ``D_ff qdd_f = (tau - h(q, qd))_f`` for the free joints, ``h`` the
    bias torque (Coriolis, gravity, damping). Call it at a state whose locked joints are at
    rest (after :func:`engage_brakes`); as the ``fd`` of an RK4 step it keeps them there."""
    tau = np.asarray(tau, dtype=float)
    free = _free(locked)
    qdd = np.zeros_like(tau)
    if free.any():
        h = np.asarray(model.inverse_dynamics(q, qd, np.zeros_like(tau)), dtype=float)
        d = np.asarray(model.mass_matrix(q), dtype=float)
        qdd[free] = np.linalg.solve(d[np.ix_(free, free)], (tau - h)[free])
    return qdd


class _Parser:
    """Checks a parsed scenario entry by entry; every error names source, entry, value."""

    def __init__(self, source: str, n: int, names: tuple[str, ...], step_ns: int,
                 tip_forces: bool) -> None:
        self.source, self.n, self.names = source, n, names
        self.step_ns, self.tip_forces = step_ns, tip_forces

    def error(self, where: str, reason: str) -> DisturbanceError:
        return DisturbanceError(f'{self.source}: {where}: {reason}')

    def parse(self, data: object) -> tuple[list[Push], list[Fault]]:
        if data is None:
            return [], []
        if not isinstance(data, Mapping):
            raise DisturbanceError(f'{self.source}: a disturbance scenario is a mapping '
                                   f'{{pushes: [...], faults: [...]}}, got {data!r:.80}')
        unknown = [k for k in data if k not in ('pushes', 'faults')]
        if unknown:
            raise self.error(str(unknown[0]), 'unknown key (a scenario has pushes and '
                             'faults)')
        pushes = [self.push(f'pushes[{i}]', e) for i, e in
                  enumerate(self.entries('pushes', data.get('pushes')))]
        faults = [self.fault(f'faults[{i}]', e) for i, e in
                  enumerate(self.entries('faults', data.get('faults')))]
        return pushes, faults

    def entries(self, where: str, value: object) -> list[Mapping[str, Any]]:
        if value is None:
            return []
        if not isinstance(value, list):
            raise self.error(where, f'must be a list of entries, got {value!r:.80}')
        if len(value) > MAX_ENTRIES:
            raise self.error(where, f'{len(value)} entries, more than {MAX_ENTRIES}')
        for i, e in enumerate(value):
            if not isinstance(e, Mapping):
                raise self.error(f'{where}[{i}]', f'must be a mapping, got {e!r:.80}')
        return value

    def keys(self, where: str, entry: Mapping[str, Any], allowed: Sequence[str]) -> None:
        for k in entry:
            if k not in allowed:
                raise self.error(f'{where}.{k}', f"unknown key (expected {', '.join(allowed)})")

    def time(self, where: str, value: object, *, positive: bool = False) -> int:
        """Seconds -> ns, exactly (from the number's decimal text), on the step grid."""
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            hint = ''
            if isinstance(value, str):
                try:
                    float(value)
                    hint = ' (YAML reads 1e-3 as text: write 1.0e-3)'
                except ValueError:
                    pass
            raise self.error(where, f'must be a number of seconds, got {value!r:.80}{hint}')
        x = float(value)
        if not math.isfinite(x):
            raise self.error(where, f'must be finite, got {value!r}')
        if (x <= 0.0) if positive else (x < 0.0):
            raise self.error(where, f"must be {'> 0' if positive else '>= 0'} s, got {value!r}")
        if x > MAX_TIME_S:
            raise self.error(where, f'must be <= {MAX_TIME_S:g} s, got {value!r}')
        ns_exact = Decimal(repr(x)) * 1_000_000_000  # exact: the number as written
        if ns_exact != ns_exact.to_integral_value():
            raise self.error(where, f'{value!r} s is not a whole number of nanoseconds')
        ns = int(ns_exact)
        if ns % self.step_ns:
            lo = ns - ns % self.step_ns
            raise self.error(where, f'{value!r} s is not on the physics step grid (a whole '
                             f'multiple of {_seconds(self.step_ns)}, {self.step_ns} ns); the '
                             f'nearest are {_seconds(lo)} and {_seconds(lo + self.step_ns)}')
        return ns

    def vector(self, where: str, value: object, size: int, what: str) -> tuple[float, ...]:
        if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, np.ndarray)):
            raise self.error(where, f'must be a list of {size} numbers ({what}), got '
                             f'{value!r:.80}')
        if len(value) != size:
            raise self.error(where, f'must have {size} values ({what}), got {len(value)}: '
                             f'{list(value)!r:.80}')
        out = []
        for i, v in enumerate(value):
            if isinstance(v, bool) or not isinstance(v, numbers.Real):
                raise self.error(f'{where}[{i}]', f'must be a number, got {v!r:.80}')
            x = float(v)
            if not math.isfinite(x):
                raise self.error(f'{where}[{i}]', f'must be finite, got {v!r}')
            if abs(x) > MAX_LOAD:
                raise self.error(f'{where}[{i}]', f'must be within +-{MAX_LOAD:g}, got {v!r}')
            out.append(x)
        return tuple(out)

    def number(self, where: str, value: object, lo: float, hi: float, unit: str) -> float:
        if isinstance(value, bool) or not isinstance(value, numbers.Real) or not (
                math.isfinite(float(value)) and lo <= float(value) <= hi):
            raise self.error(where, f'must be a number in [{lo:g}, {hi:g}] {unit}, got '
                             f'{value!r:.80}')
        return float(value)

    def joint(self, where: str, value: object) -> int:
        """A 1-based joint number or a joint name -> 0-based index."""
        if isinstance(value, (int, np.integer)) and not isinstance(value, bool) and (
                1 <= int(value) <= self.n):
            return int(value) - 1
        if isinstance(value, str) and value in self.names:
            return self.names.index(value)
        raise self.error(where, f'must be a joint number 1..{self.n} (counted from 1) or a '
                         f"name ({', '.join(self.names)}), got {value!r:.80}")

    def push(self, where: str, e: Mapping[str, Any]) -> Push:
        if 'until' in e:
            raise self.error(f'{where}.until', 'a push ends by its shape: shape pulse with '
                             f"a duration (got until: {e['until']!r:.80})")
        self.keys(where, e, ('at', 'tip_force', 'joint_torque', 'shape', 'duration'))
        kinds = [k for k in PUSH_KINDS if k in e]
        if len(kinds) != 1:
            raise self.error(where, 'needs exactly one of tip_force [x, y] (N) or '
                             f'joint_torque (N m per joint), got {kinds or "neither"}')
        kind = kinds[0]
        if 'at' not in e:
            raise self.error(f'{where}.at', 'missing (the start time, s)')
        start = self.time(f'{where}.at', e['at'])
        shape = e.get('shape')
        if shape not in SHAPES:
            raise self.error(f'{where}.shape', f"must be one of {', '.join(SHAPES)}, got "
                             f'{shape!r:.80}')
        if kind == 'tip_force' and not self.tip_forces:
            raise self.error(f'{where}.tip_force', f'{e[kind]!r:.80}: this model has no tip; '
                             'push with joint_torque')
        size, what = ((2, f"[x, y] {_UNITS[kind, shape == 'impulse']}, base frame")
                      if kind == 'tip_force' else
                      (self.n, f"{_UNITS[kind, shape == 'impulse']}, one per joint"))
        value = self.vector(f'{where}.{kind}', e[kind], size, what)
        end = None
        if shape == 'pulse':
            if 'duration' not in e:
                raise self.error(f'{where}.duration', 'missing (a pulse lasts duration s)')
            end = start + self.time(f'{where}.duration', e['duration'], positive=True)
        elif 'duration' in e:
            raise self.error(f'{where}.duration', f"{e['duration']!r:.80}: only a pulse has "
                             f'a duration (shape {shape} is '
                             f"{'held to the end' if shape == 'step' else 'instant'})")
        return Push(start, end, kind, value, shape, label=where)

    def fault(self, where: str, e: Mapping[str, Any]) -> Fault:
        self.keys(where, e, ('at', 'until', *FAULT_KINDS))
        kinds = [k for k in FAULT_KINDS if k in e]
        if len(kinds) != 1:
            raise self.error(where, f"needs exactly one of {', '.join(FAULT_KINDS)}, got "
                             f'{kinds or "none"}')
        kind = kinds[0]
        if 'at' not in e:
            raise self.error(f'{where}.at', 'missing (the start time, s)')
        start = self.time(f'{where}.at', e['at'])
        end = None
        if e.get('until') is not None:
            end = self.time(f'{where}.until', e['until'])
            if end <= start:
                raise self.error(f'{where}.until', f"{e['until']!r} s must be after at "
                                 f"{e['at']!r} s")
        body = e[kind] if e[kind] is not None else {}
        at = f'{where}.{kind}'
        if not isinstance(body, Mapping):
            keys = ', '.join(FAULT_KEYS[kind])
            raise self.error(at, f'must be a mapping {{{keys}}}, got {body!r:.80}')
        self.keys(at, body, FAULT_KEYS[kind])
        joint = None
        if 'joint' in FAULT_KEYS[kind]:
            if 'joint' not in body:
                raise self.error(f'{at}.joint', 'missing (a joint number from 1, or a name)')
            joint = self.joint(f'{at}.joint', body['joint'])
        fraction = bias = 0.0
        if 'fraction' in body:
            fraction = self.number(f'{at}.fraction', body['fraction'], 0.0, 1.0,
                                   '(share of the command delivered)')
        if kind == 'encoder_bias':
            if 'bias' not in body:
                raise self.error(f'{at}.bias', 'missing (rad added to the position)')
            bias = self.number(f'{at}.bias', body['bias'], -MAX_LOAD, MAX_LOAD, 'rad')
        return Fault(start, end, kind, joint, fraction, bias, label=where)
