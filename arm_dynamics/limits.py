"""Joint limits of the arm, as ros2_control's joint limits are used (no rclpy).

One :class:`JointLimits` serves everyone: the controller refuses trajectories whose points
leave it, the planner refuses goals and lines that would, and the simulator reports a state
outside it (and, as an option, stops the joint there). Its :meth:`JointLimits.envelope`,
the limits plus a margin, bounds what is physically plausible: a state leaving that is a
runaway fault.

An unbounded joint has ``-inf`` / ``inf`` limits.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Defaults, with their reason. Shoulder: one turn either way, as a cable-wrapped joint
#: allows and every shortest-motion goal needs. Elbow: not past folded onto link 1 (+-pi).
#: Speed: 8 rad/s at both joints, nearly 3x the fastest motion of the demo (2.9 rad/s).
DEFAULT_POSITION_LOWER = (-2.0 * math.pi, -math.pi)
DEFAULT_POSITION_UPPER = (2.0 * math.pi, math.pi)
DEFAULT_VELOCITY = (8.0, 8.0)
#: Torque: 60 and 20 N m. Holding the default arm out straight takes 30.4 and 5.9 N m,
#: so the limits leave about 2x (shoulder) and 3.4x (elbow) that for acceleration.
DEFAULT_EFFORT = (60.0, 20.0)


@dataclass(frozen=True)
class JointLimits:
    """Per-joint position and speed limits.

    Parameters
    ----------
    lower, upper : (n,) rad -- position limits, ``lower < upper``; ``-inf`` / ``inf`` for
        none.
    velocity : (n,) rad/s, > 0 -- speed limits; ``inf`` for none.
    """

    lower: tuple[float, ...] = DEFAULT_POSITION_LOWER
    upper: tuple[float, ...] = DEFAULT_POSITION_UPPER
    velocity: tuple[float, ...] = DEFAULT_VELOCITY

    def __post_init__(self) -> None:
        lo, hi, v = (tuple(float(x) for x in a) for a in (self.lower, self.upper,
                                                           self.velocity))
        if not len(lo) == len(hi) == len(v):
            raise ValueError(f'joint limits need one value per joint, got lower {lo}, '
                             f'upper {hi}, velocity {v}')
        for j, (a, b) in enumerate(zip(lo, hi)):
            if not a < b or a == math.inf or b == -math.inf:
                raise ValueError(f'joint {j + 1} position limits must satisfy lower < upper, '
                                 f'got [{a:g}, {b:g}] rad')
        if not all(x > 0 for x in v):
            raise ValueError(f'velocity limits must be > 0 rad/s, got {list(v)}')
        object.__setattr__(self, 'lower', lo)
        object.__setattr__(self, 'upper', hi)
        object.__setattr__(self, 'velocity', v)

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> JointLimits:
        """From the robot parameters ``position_limits_lower``/``_upper`` and
        ``velocity_limits``."""
        return cls(tuple(params['position_limits_lower']),
                   tuple(params['position_limits_upper']), tuple(params['velocity_limits']))

    def envelope(self, position_margin: float, velocity_factor: float) -> JointLimits:
        """The limits widened by ``position_margin`` [rad] each side and speeds times
        ``velocity_factor``: beyond this no controlled arm goes."""
        return JointLimits(tuple(a - position_margin for a in self.lower),
                           tuple(b + position_margin for b in self.upper),
                           tuple(v * velocity_factor for v in self.velocity))

    def position_violation(self, q, what: str = 'position') -> str | None:
        """Why positions ``q`` ((n,) or (k, n) rad) leave the limits (the value furthest
        beyond a limit, its joint and the limit), or None."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        lo, hi = np.array(self.lower), np.array(self.upper)
        with np.errstate(invalid='ignore'):
            excess = np.nan_to_num(np.maximum(lo - q, q - hi), nan=np.inf)
        if not (excess > 0).any():
            return None
        k, j = np.unravel_index(np.argmax(excess), q.shape)
        value = q[k, j]
        side = f'< lower limit {lo[j]:g}' if value < lo[j] else f'> upper limit {hi[j]:g}'
        where = f' (point {k})' if len(q) > 1 else ''
        return f'joint {j + 1} {what} {value:.6g} rad {side} rad{where}'

    def velocity_violation(self, qd, what: str = 'speed') -> str | None:
        """Why velocities ``qd`` ((n,) or (k, n) rad/s) exceed the speed limits (the
        fastest beyond its limit), or None."""
        qd = np.atleast_2d(np.asarray(qd, dtype=float))
        v = np.array(self.velocity)
        excess = np.nan_to_num(np.abs(qd) - v, nan=np.inf)
        if not (excess > 0).any():
            return None
        k, j = np.unravel_index(np.argmax(excess), qd.shape)
        where = f' (point {k})' if len(qd) > 1 else ''
        return (f'joint {j + 1} {what} {abs(qd[k, j]):.6g} rad/s > limit {v[j]:g} '
                f'rad/s{where}')

    def violation(self, q, qd) -> str | None:
        """The first reason the state ((n,) rad, (n,) rad/s) leaves the limits, or None."""
        if self.contains(q, qd):  # the every-tick case, without numpy overhead
            return None
        return self.position_violation(q) or self.velocity_violation(qd)

    def contains(self, q, qd) -> bool:
        """Whether one state ((n,) rad, (n,) rad/s) is within every limit."""
        q, qd = list(q), list(qd)
        return all(lo <= x <= hi and abs(v) <= vmax for x, v, lo, hi, vmax in
                   zip(q, qd, self.lower, self.upper, self.velocity))

    def hard_stop(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A joint past a position limit is put back on it with its outward velocity
        removed (an inelastic end stop); others unchanged."""
        lo, hi = np.array(self.lower), np.array(self.upper)
        clipped = np.clip(q, lo, hi)
        outward = ((q < lo) & (qd < 0)) | ((q > hi) & (qd > 0))
        return clipped, np.where(outward, 0.0, qd)
