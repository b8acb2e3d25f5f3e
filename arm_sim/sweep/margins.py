"""A scenario's stability margins: the linearised sampled-data loop's phase and gain
margins and its gain crossover, per joint (the ``margins: true`` columns).

Pure: no rclpy. The loop is :func:`arm_control.closed_loop.closed_loop` with the
scenario's own objects: its law, gains (:class:`~arm_control.laws.Gains`), plant
(:meth:`Scenario.plant <arm_sim.sweep.spec.Scenario.plant>`, payload included), the
controller's model (:meth:`Scenario.model <arm_sim.sweep.spec.Scenario.model>`), the
control period ``1 / control_rate`` [s], about the goal's joint angles (the plan's last
point, the set point the arm comes to rest near), with the scenario's ``sensing_delay`` plus
``actuation_delay`` as the loop's extra delay (whole periods; lockstep without them). The
plant's friction is not in it (no linearisation: the loop about a stuck joint is open). Its margins
are :func:`arm_control.closed_loop.margins` of each joint's loop broken at its plant input
with the other joint's loop closed (:meth:`ClosedLoop.loop
<arm_control.closed_loop.ClosedLoop.loop>`), as :func:`~arm_control.closed_loop.
loop_margins` finds them, on fewer frequencies: :data:`POINTS` log-spaced ones from
:data:`F_MIN` Hz to just below Nyquist, and :data:`REFINE` more inside each interval where
a joint's gain crosses 0 dB or its phase crosses -180 deg (mod 360), so the crossings are
interpolated on a grid finer than ``loop_margins``' 6000 points (tested to agree within
0.1 deg and 0.1 dB). About 0.6 ms per scenario, plus the linearisation (1-8 ms,
:func:`closed_loop`: the equilibrium, a matrix exponential).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from arm_control.closed_loop import LINEAR_LAWS, ClosedLoop, Margins, closed_loop, margins
from arm_control.laws import Gains
from arm_sim.sweep.columns import MARGIN_NAMES
from arm_sim.sweep.spec import Scenario

F_MIN = 1e-3        # Hz: the lowest frequency searched (loop_margins' default)
POINTS = 400        # log-spaced frequencies, F_MIN to just below Nyquist
REFINE = 32         # more frequencies inside each interval holding a crossing


def refined_margins(loop: ClosedLoop, f_min: float = F_MIN, points: int = POINTS,
                    refine: int = REFINE) -> list[Margins]:
    """:func:`~arm_control.closed_loop.loop_margins` of ``loop`` on ``points`` log-spaced
    frequencies [Hz] from ``f_min`` to just below Nyquist plus ``refine`` log-spaced
    frequencies inside each interval where a joint's gain crosses 0 dB or its phase
    crosses -180 deg (mod 360); one :class:`~arm_control.closed_loop.Margins` per joint."""
    f = np.geomspace(f_min, loop.nyquist * (1.0 - 1e-6), points)
    coarse = loop.loop(f)                                          # (F, n)
    mag = 20.0 * np.log10(np.abs(coarse))
    level = np.floor((np.degrees(np.unwrap(np.angle(coarse), axis=0)) + 180.0) / 360.0)
    crossing = ((np.diff(np.sign(mag), axis=0) != 0) | (np.diff(level, axis=0) != 0)).any(1)
    extra = [np.geomspace(f[i], f[i + 1], refine + 2)[1:-1] for i in np.flatnonzero(crossing)]
    if extra:
        f = np.concatenate([f, *extra])
        order = np.argsort(f)
        f = f[order]
        fine = np.concatenate([coarse, loop.loop(np.concatenate(extra))])[order]
    else:
        fine = coarse
    return [margins(f, fine[:, j]) for j in range(loop.n)]


def scenario_loop(s: Scenario, centre) -> ClosedLoop:
    """The linearised loop of scenario ``s`` about ``centre`` (2,) rad: its law, gains,
    plant, controller's model and control period (raises ValueError where
    :func:`closed_loop` does: no rest position found)."""
    gains = Gains(kp=s.kp, kd=s.kd, ki=s.ki, i_clamp=s.i_clamp)
    return closed_loop(s.law, gains, s.plant(), np.asarray(centre, dtype=float),
                       1.0 / s.control_rate, model=s.model(),
                       delay=s.sensing_delay + s.actuation_delay)


def scenario_margins(s: Scenario, centre) -> tuple[dict[str, Any], str | None]:
    """The margin columns of scenario ``s`` linearised about ``centre`` (2,) rad: a dict
    ``{name: [joint 1, joint 2]}`` over :data:`MARGIN_NAMES` (NaN where undefined) and
    ``pole_radius`` (the largest closed-loop pole magnitude, a float: > 1 unstable), and
    why they are undefined or what to know about them (None when there is nothing to say):
    a law without a linearisation, no rest position, an unstable linearised loop."""
    undefined: dict[str, Any] = {k: [math.nan, math.nan] for k in MARGIN_NAMES}
    undefined['pole_radius'] = math.nan
    if s.law not in LINEAR_LAWS:
        return undefined, f'margins: no linearisation of law {s.law!r}'
    try:
        loop = scenario_loop(s, centre)
    except (ValueError, np.linalg.LinAlgError) as exc:
        return undefined, f'margins: {exc}'
    ms = refined_margins(loop)
    pole = float(np.abs(loop.eigenvalues()).max())
    out: dict[str, Any] = {'phase_margin': [m.phase_deg for m in ms],
                           'gain_margin': [m.gain_db for m in ms],
                           'bandwidth': [m.gain_crossover for m in ms], 'pole_radius': pole}
    note = None
    if not pole < 1.0:
        note = (f'margins: the linearised loop is unstable (largest pole |z| = {pole:.4g}): '
                'the margins do not measure its distance from instability')
    return out, note
