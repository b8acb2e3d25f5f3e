"""The 2-R arm's float path of the stick/slip step (``arm_dynamics.friction._Step2``, what
``friction_step`` takes on a :class:`~arm_dynamics.two_link.TwoLinkArm` with an event):
the generic array path's operations on plain floats, so its bits. Pure.
"""

from __future__ import annotations

import numpy as np
import pytest

from arm_dynamics.friction import JointFriction, _Step, _Step2, friction_step
from arm_dynamics.two_link import TwoLinkArm

REAL = TwoLinkArm(gear_ratios=(100.0, 80.0), motor_inertias=(1.2e-5, 6e-6),
                  motor_damping=(1e-5, 1e-5))


def _cases(seed: int, count: int):
    """States in every mode (slipping, about to stop, one or both joints at rest with
    torques about the band) with random payloads, frictions and steps."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        arm = REAL.with_payload(float(rng.uniform(0.0, 1.0)))
        x = rng.uniform(0.2, 3.0)
        friction = JointFriction(coulomb=np.array([1.5, 0.5]) * x,
                                 static=np.array([1.95, 0.65]) * x)
        q = rng.uniform(-3.0, 3.0, 2)
        qd = rng.normal(size=2) * rng.choice([1e-4, 1e-2, 1.0], 2)
        qd[rng.random(2) < 0.4] = 0.0
        tau = (arm.gravity_vector(q) + rng.uniform(-1.3, 1.3, 2) * friction.static
               if rng.random() < 0.7 else rng.normal(scale=20.0, size=2))
        yield arm, friction, q, qd, tau, float(rng.choice([1e-3, 1e-4, 1e-2]))


def _run(cls, arm, friction, q, qd, tau, dt):
    """The step's result, or the error it raised (type and message)."""
    try:
        return cls(arm, tau, friction, None).run(q, qd, dt)
    except (ValueError, ArithmeticError) as e:
        return f'{type(e).__name__}: {e}'


@pytest.mark.parametrize('seed', [0, 1])
def test_the_float_step_gives_the_array_steps_bits(seed):
    # Tolerance: 0. The same operations on the same floats (numpy's float64 arithmetic is
    # IEEE's, as Python's): no rounding to allow for.
    events = 0
    for arm, friction, q, qd, tau, dt in _cases(seed, 400):
        a = _run(_Step, arm, friction, q, qd, tau, dt)
        b = _run(_Step2, arm, friction, q, qd, tau, dt)
        assert type(a) is type(b)
        for x, y in zip(a[:3], b[:3]):
            assert np.array_equal(x, y)
        assert a[3] == b[3]
        events += not np.array_equal(a[2], np.abs(qd) == 0.0)
    assert events > 50   # stick/slip changes (located events) among them


def test_friction_step_takes_the_float_path_on_the_two_link_arm(monkeypatch):
    runs = []
    real = _Step2.run
    monkeypatch.setattr(_Step2, 'run', lambda self, *a: runs.append(1) or real(self, *a))
    friction = JointFriction(coulomb=[1.5, 0.5], static=[1.95, 0.65])
    friction_step(REAL, np.array([0.3, 0.5]), np.array([0.0, 2.0]), np.zeros(2), 1e-3,
                  np.zeros(2, dtype=bool), friction)
    assert runs == [1]


@pytest.mark.parametrize('q, qd, tau, static', [
    ([0.3, 0.5], [1e154, 0.0], [1e300, 0.0], [0.0, 1e300]),   # held joint, overflow
    ([0.3, 0.5], [1.0, 0.0], [1e200, 0.0], [0.0, 1e300]),
    ([0.3, 0.5], [1e150, -1e150], [1e300, -1e300], [1.0, 1.0]),  # both slipping
    ([0.3, 0.5], [0.0, 0.0], [1e300, 1e300], [1.0, 1.0]),        # both break away
])
def test_a_state_going_non_finite_in_the_step_ends_as_on_the_array_path(q, qd, tau, static):
    # Whatever the array path does with a step that overflows (NaN, or an error), the
    # float path does the same: it hands such a step to the array path's own methods.
    friction = JointFriction(coulomb=np.minimum(static, 40.0), static=static)
    q, qd, tau = np.array(q), np.array(qd), np.array(tau)
    with np.errstate(all='ignore'):
        a = _run(_Step, REAL, friction, q, qd, tau, 1e-3)
        b = _run(_Step2, REAL, friction, q, qd, tau, 1e-3)
    if isinstance(a, str):
        assert a == b
    else:
        assert not isinstance(b, str)
        for x, y in zip(a[:3], b[:3]):
            assert np.array_equal(x, y, equal_nan=True)
