"""Sensors and actuators of the simulated arm: what the controller sees and when a command
acts (pure: numpy only, no rclpy).

The simulator publishes on ``joint_states`` the *measurement* of the state, and the true
state on ``simulator/true_joint_states``. Everything here is off by default, and off it
returns the true state and the command themselves (the same arrays: bit-identical runs).

:class:`SensorModel` -- the measurement of the state at ``t_j`` (call
:meth:`SensorModel.measure` exactly once per new state, in order; a re-sent state re-uses
its measurement, never a new draw):

1. noise: ``q + position_noise * z_q``, ``qd + velocity_noise * z_qd`` with ``z_q``, ``z_qd``
   standard normal (n,), drawn in that order, as one ``standard_normal(2 n)`` call of a
   :class:`numpy.random.Generator` seeded with ``noise_seed`` (``default_rng(seed)``, PCG64)
   per state while any noise is set. The draws depend only on the seed and the number of
   states measured, never on the wall clock.
2. encoder: a joint with ``encoder_resolution`` N > 0 counts per revolution reads the
   (noisy) position rounded to the nearest count, ``round(q / s) * s`` with
   ``s = 2 pi / N`` rad; the velocity is not quantised; N = 0 is an ideal sensor.
3. sensing delay of ``k`` whole control periods: the measurement published with the state
   at ``t_j`` is the one made of the state at ``t_(j-k)``; before ``k`` states exist
   (start, or a :meth:`SensorModel.reset`) it is the first state's measurement, as if the
   arm had rested there for ever.

:class:`ActuationDelay` -- a FIFO of ``k`` whole control periods: the command held for the
period ``[t_j, t_j + T]`` (in lockstep: the answer to the state at ``t_j``) is applied over
``[t_(j+k), t_(j+k) + T]``; over the first ``k`` periods (after start or a reset) the
applied torque is zero. The lockstep hand-shake is unchanged: each state is still answered
by its own tagged command; only the plant applies it ``k`` periods later.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence

import numpy as np


def _per_joint(name: str, values: Sequence[float] | None, n: int) -> np.ndarray:
    """``values`` as a float (n,) array (None: zeros); ValueError if it is not n finite
    values >= 0."""
    if values is None:
        return np.zeros(n)
    a = np.array(values, dtype=float).reshape(-1)
    if a.shape != (n,):
        raise ValueError(f'{name} must have {n} values (one per joint), got {len(a)}')
    if not (np.isfinite(a).all() and (a >= 0).all()):
        raise ValueError(f'{name} must be finite and >= 0, got {a.tolist()}')
    return a


def _periods(name: str, k: int) -> int:
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 0:
        raise ValueError(f'{name} must be a whole number of control periods >= 0, got {k!r}')
    return int(k)


def whole_counts_reason(values: Sequence[float]) -> str | None:
    """Why ``encoder_resolution`` values are not whole counts per revolution, or None."""
    bad = [v for v in values if not (math.isfinite(v) and float(v).is_integer())]
    if bad:
        return (f'encoder_resolution must be whole counts per revolution (0 = ideal), got '
                f'{list(values)}')
    return None


class SensorModel:
    """Seeded joint-state measurement: Gaussian noise, encoder quantisation, a delay line.

    Parameters
    ----------
    n : int -- joints measured (the model's state size).
    position_noise : (n,) rad, >= 0 -- standard deviation of the position noise (None: 0).
    velocity_noise : (n,) rad/s, >= 0 -- standard deviation of the velocity noise.
    encoder_resolution : (n,) counts per revolution, whole, >= 0; 0 = ideal.
    sensing_delay : int, control periods >= 0.
    seed : int >= 0 -- ``noise_seed``: the generator's seed.

    With every setting zero, :attr:`enabled` is False and :meth:`measure` returns its
    arguments themselves.
    """

    def __init__(self, n: int, *, position_noise: Sequence[float] | None = None,
                 velocity_noise: Sequence[float] | None = None,
                 encoder_resolution: Sequence[float] | None = None,
                 sensing_delay: int = 0, seed: int = 0) -> None:
        self.n = n
        self.position_noise = _per_joint('position_noise', position_noise, n)
        self.velocity_noise = _per_joint('velocity_noise', velocity_noise, n)
        counts = _per_joint('encoder_resolution', encoder_resolution, n)
        reason = whole_counts_reason(counts.tolist())
        if reason:
            raise ValueError(reason)
        self.encoder_resolution = counts
        self.sensing_delay = _periods('sensing_delay', sensing_delay)
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f'noise_seed must be an integer >= 0, got {seed!r}')
        self.seed = int(seed)
        self.noisy = bool(self.position_noise.any() or self.velocity_noise.any())
        self.quantised = counts > 0
        #: rad per count of each quantised joint (1 where ideal: unused there).
        self.step = np.where(self.quantised, 2.0 * math.pi / np.where(self.quantised,
                                                                      counts, 1.0), 1.0)
        self.enabled = self.noisy or bool(self.quantised.any()) or self.sensing_delay > 0
        self.rng = np.random.default_rng(self.seed)
        self.line: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=self.sensing_delay + 1)
        self.measured = 0  # states measured since start

    def reset(self) -> None:
        """Empty the delay line (the next state measured is published at once and held
        while the line refills); the generator goes on (no draw is repeated)."""
        self.line.clear()

    def sample(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The undelayed measurement of one state (draws the noise of one state)."""
        if self.noisy:
            z = self.rng.standard_normal(2 * self.n)
            q = q + self.position_noise * z[:self.n]
            qd = qd + self.velocity_noise * z[self.n:]
        if self.quantised.any():
            q = np.where(self.quantised, np.round(q / self.step) * self.step, q)
        return q, qd

    def measure(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The measurement to publish with the true state ``q`` [rad], ``qd`` [rad/s] (n,)
        just reached: call once per new state, in order. Returns (q_m, qd_m), (n,) each."""
        if not self.enabled:
            return q, qd
        self.measured += 1
        # copies: the line must not follow a caller's later in-place change of q, qd
        self.line.append(self.sample(np.array(q, dtype=float), np.array(qd, dtype=float)))
        return self.line[0]


def measure_series(q: np.ndarray, qd: np.ndarray, **settings) -> tuple[np.ndarray, np.ndarray]:
    """The measurements of the states ``q``, ``qd`` (N, n) of one run from its start, in
    order, with :class:`SensorModel` ``settings`` (keywords); returns two (N, n) arrays."""
    q, qd = np.asarray(q, dtype=float), np.asarray(qd, dtype=float)
    model = SensorModel(q.shape[1], **settings)
    out = [model.measure(a, b) for a, b in zip(q, qd)]
    if not out:
        return q.copy(), qd.copy()
    return np.array([m[0] for m in out]), np.array([m[1] for m in out])


class ActuationDelay:
    """The actuator's command FIFO of ``delay`` whole control periods.

    Parameters
    ----------
    n : int -- joints.
    delay : int, control periods >= 0.

    :meth:`__call__` takes the command [N m] (n,) held for the period about to be
    integrated and returns the one to apply: the command given ``delay`` periods earlier
    (zeros before any). With ``delay`` 0 it returns its argument itself.
    """

    def __init__(self, n: int, delay: int = 0) -> None:
        self.n = n
        self.delay = _periods('actuation_delay', delay)
        self.queue: deque[np.ndarray] = deque()
        self.clear()

    def clear(self) -> None:
        """Zero torque for the next ``delay`` periods (start, reset, a drive watchdog)."""
        self.queue = deque(np.zeros(self.n) for _ in range(self.delay))

    def __call__(self, command: np.ndarray) -> np.ndarray:
        if not self.delay:
            return command
        self.queue.append(np.array(command, dtype=float))
        return self.queue.popleft()
