"""The simulator's plant side for a batch of two-link arms, free of ROS: what a parameter
sweep steps.

:class:`BatchSimulator` is :class:`~arm_dynamics.simulation.SimulatorCore`'s sampled-data
loop for ``B`` arms at once, each with its own parameters (:class:`~arm_dynamics.two_link.
TwoLinkBatch`): each control period it takes the command of every arm, holds it over the
period saturated at that arm's effort limits while the plants take fixed RK4 physics
steps, and checks each arm for divergence (a state faster than ``velocity_limit`` or
non-finite, as the simulator's ``velocity_limit``). A diverged arm stops: it keeps its last
good state, with zero torque applied, for the rest of the run; the others go on. No joint
limits, hard stops or runaway envelope (the sweep's arms run free).

The control law is the caller's (e.g. :func:`arm_control.laws.law_torque` on the (B, 2)
state): this module knows the plants only.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from arm_dynamics.two_link import TwoLinkArm, TwoLinkBatch


class BatchSimulator:
    """``B`` two-link plants, each under its own held, saturated torque command.

    Row ``i`` of every (B, 2) array belongs to ``plants[i]``.

    Parameters
    ----------
    plants : sequence of B :class:`~arm_dynamics.two_link.TwoLinkArm`, B >= 1
    q0, qd0 : (B, 2) rad, rad/s -- the initial states.
    effort_limits : (B, 2) N m, > 0 -- each applied torque is clipped to +-limits.
    physics_step_ns : int, ns > 0 -- the RK4 step.
    control_period_ns : int, ns -- a whole multiple of the physics step; one
        :meth:`advance` is one control period.
    velocity_limit : rad/s -- an arm with any |qd| above it, or a non-finite state, after
        a period has diverged.

    Attributes
    ----------
    q, qd : (B, 2) rad, rad/s -- the current states (a diverged arm: its last good one).
    applied : (B, 2) N m -- the torque applied over the last period (zero before the
        first, and for an arm that diverged in it or before).
    alive : (B,) bool -- the arms that have not diverged.
    diverged_at : (B,) int -- the number of the period (1 = the first :meth:`advance`)
        after which each arm diverged; -1 while it has not.
    periods : int -- control periods advanced so far.
    dt : s -- the physics step; ``substeps`` RK4 steps per control period.
    """

    def __init__(self, plants: Sequence[TwoLinkArm], *, q0, qd0, effort_limits,
                 physics_step_ns: int, control_period_ns: int,
                 velocity_limit: float) -> None:
        if physics_step_ns <= 0 or control_period_ns % physics_step_ns:
            raise ValueError(
                f'control period {control_period_ns} ns must be a whole multiple of the '
                f'physics step {physics_step_ns} ns')
        self.plant = TwoLinkBatch(plants)
        b = len(self.plant)
        shape = (b, 2)
        arrays = {}
        for name, value in (('q0', q0), ('qd0', qd0), ('effort_limits', effort_limits)):
            arr = np.array(value, dtype=float)
            if arr.shape != shape:
                raise ValueError(f'{name} must have shape {shape} (one row per plant), got '
                                 f'{arr.shape}')
            arrays[name] = arr
        self.q, self.qd, self.limits = arrays['q0'], arrays['qd0'], arrays['effort_limits']
        self.dt = physics_step_ns * 1e-9
        self.substeps = control_period_ns // physics_step_ns
        self.velocity_limit = velocity_limit
        self.applied = np.zeros(shape)
        self.alive = np.ones(b, dtype=bool)
        self.diverged_at = np.full(b, -1)
        self.periods = 0

    def __len__(self) -> int:
        return len(self.plant)

    def advance(self, command) -> None:
        """Integrate one control period: ``command`` (B, 2) [N m] held, saturated at the
        effort limits (zero for a diverged arm), ``substeps`` RK4 steps of ``dt``; then
        every arm that went faster than ``velocity_limit`` or non-finite is diverged (its
        state put back to the last good one, its applied torque zero)."""
        self.periods += 1
        tau = np.clip(command, -self.limits, self.limits)
        if not self.alive.all():
            tau = np.where(self.alive[:, None], tau, 0.0)
        q, qd = self.plant.step(self.q, self.qd, tau, self.dt, self.substeps)
        with np.errstate(invalid='ignore'):
            bad = ~(np.abs(qd).max(axis=1) <= self.velocity_limit) | ~np.isfinite(q).all(1)
        bad &= self.alive
        if bad.any():
            self.diverged_at[bad] = self.periods
            self.alive &= ~bad
            tau = np.where(bad[:, None], 0.0, tau)
        if not self.alive.all():
            held = ~self.alive[:, None]
            q, qd = np.where(held, self.q, q), np.where(held, self.qd, qd)
        self.q, self.qd, self.applied = q, qd, tau
