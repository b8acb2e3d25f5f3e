"""The batch plant's real-arm parts (:mod:`arm_dynamics.batch`), pure: friction stepped a
period at a time with every mode batched (slipping, one joint held, both held, a
break-away) and the rows with an event handed to ``friction_step``; the held rows' terms
kept from one period to the next; the sensors. Each row is checked against the single-arm
reference it must equal (:func:`arm_dynamics.friction.friction_step`,
:class:`arm_dynamics.sensors.SensorModel`). Tolerances are stated where they are used;
the batched RK4 and inverse dynamics use numpy's cos/sin where the single arm uses math's,
and both rounded identically (0 difference) for every case here when written.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import arm_dynamics.batch as batch_module
from arm_dynamics.batch import BatchSimulator, batch_friction_step
from arm_dynamics.friction import JointFriction, friction_step
from arm_dynamics.sensors import SensorModel
from arm_dynamics.two_link import TwoLinkArm, TwoLinkBatch

#: config/real_arm.yaml's motors and friction.
REAL = TwoLinkArm(gear_ratios=(100.0, 80.0), motor_inertias=(1.2e-5, 6e-6),
                  motor_damping=(1e-5, 1e-5))
C, S = np.array([1.5, 0.5]), np.array([1.95, 0.65])
#: Rounding of the batched path against the single arm (numpy vs math cos/sin): 1e-12 rad
#: on positions, 1e-12 rad/s on velocities, as test_friction's batch test (measured 0 when
#: written: bit for bit).
TOL_Q, TOL_QD = 1e-12, 1e-12


def _mix(seed: int, rows: int):
    """Arms, frictions, q, qd, tau of rows in every mode: slipping; one joint at rest
    (held, or breaking away: torques near the band); both at rest (held or not); about to
    stop (an event inside the step); a joint without friction."""
    rng = np.random.default_rng(seed)
    arms = [REAL.with_payload(p) for p in rng.uniform(0.0, 1.0, rows)]
    frictions = []
    for i, x in enumerate(rng.uniform(0.3, 3.0, rows)):
        c, s = C * x, S * x
        if i % 7 == 6:
            c[0] = s[0] = 0.0
        elif i % 11 == 10:
            c[1] = s[1] = 0.0
        frictions.append(JointFriction(coulomb=c, static=s))
    q = rng.uniform(-2.5, 2.5, (rows, 2))
    qd = rng.normal(size=(rows, 2)) * rng.choice([1e-4, 1e-2, 1.0], (rows, 2))
    kind = np.arange(rows) % 5
    qd[kind == 0, 1] = 0.0
    qd[kind == 1, 0] = 0.0
    qd[kind == 2] = 0.0
    qd[kind == 3] *= 1e-3   # about to stop
    gravity = TwoLinkBatch(arms).gravity_vector(q)
    band = np.array([f.static for f in frictions])
    tau = gravity + rng.uniform(-1.4, 1.4, (rows, 2)) * np.maximum(band, 0.5)
    loud = rng.random(rows) < 0.25
    tau[loud] = rng.normal(scale=10.0, size=(int(loud.sum()), 2))
    return arms, frictions, q, qd, tau


def _steps(arm, friction, q, qd, tau, dt, steps):
    """``steps`` friction_step calls of one row: (q, qd, stuck), NaN once it refuses."""
    stuck = np.zeros(2, dtype=bool)
    for _ in range(steps):
        try:
            q, qd, stuck, _ = friction_step(arm, q, qd, tau, dt, stuck, friction)
        except ValueError:
            return np.full(2, math.nan), np.full(2, math.nan), np.zeros(2, dtype=bool)
    return q, qd, stuck


def _close(a, b, tol):
    return np.array_equal(a, b, equal_nan=True) or np.abs(a - b).max() <= tol


@pytest.mark.parametrize('dt', [1e-3, 1e-4])
def test_a_batch_step_equals_friction_step_row_by_row_in_every_mode(monkeypatch, dt):
    rows = 400
    arms, frictions, q, qd, tau = _mix(3, rows)
    index = {id(arm): i for i, arm in enumerate(arms)}
    handed = set()   # the rows the batch left to friction_step
    monkeypatch.setattr(batch_module, 'friction_step',
                        lambda arm, *a: handed.add(index[id(arm)]) or friction_step(arm, *a))
    with np.errstate(all='ignore'):
        q1, qd1, stuck1 = batch_friction_step(TwoLinkBatch(arms), q, qd, tau, dt,
                                              np.zeros((rows, 2), dtype=bool), frictions)
    active = np.array([f.static > 0.0 for f in frictions])
    rest = active & (qd == 0.0)
    for i, arm in enumerate(arms):
        q2, qd2, stuck2 = _steps(arm, frictions[i], q[i], qd[i], tau[i], dt, 1)
        assert _close(q1[i], q2, TOL_Q) and _close(qd1[i], qd2, TOL_QD), i
        assert np.array_equal(stuck1[i], stuck2), i
        # the batch stepped every row without an event itself: slipping on (no joint
        # with friction at rest, every one keeping its direction), both held
        kept = (~active[i] | (np.sign(qd[i]) * qd2 > 0.0)).all()
        if not rest[i].any() and kept:
            assert i not in handed, i
        if rest[i].all() and stuck2.all():
            assert i not in handed, i
    # one joint held, and a break-away from rest, batched (not handed over)
    one = rest[:, 0] != rest[:, 1]
    held = [i for i in np.flatnonzero(one & (stuck1 == rest).all(axis=1)) if i not in handed]
    away = [i for i in np.flatnonzero(one & ~stuck1.any(axis=1)) if i not in handed]
    assert len(held) > 30 and len(away) > 5
    assert len(handed) < rows / 2


def test_periods_of_ten_steps_equal_friction_step_per_row_and_step():
    # BatchSimulator's friction path: each period decided once, its rows kept in their
    # mode from step to step while no event happens, the held rows' terms carried over
    # to the next period; every row, every period, as friction_step step by step.
    rows = 200
    arms, frictions, q0, qd0, tau0 = _mix(5, rows)
    limits = np.full((rows, 2), 200.0)
    sim = BatchSimulator(arms, q0=q0, qd0=qd0, effort_limits=limits,
                         physics_step_ns=1_000_000, control_period_ns=10_000_000,
                         velocity_limit=1e9, friction=frictions)
    q, qd = q0.copy(), qd0.copy()
    stuck = np.zeros((rows, 2), dtype=bool)
    rng = np.random.default_rng(8)
    for period in range(6):
        # mostly the same torque (held rows stay held: the carried terms are used)
        command = tau0 + (rng.normal(scale=0.05, size=(rows, 2)) if period % 2 else 0.0)
        with np.errstate(all='ignore'):
            sim.advance(command)
        for i, arm in enumerate(arms):
            if not sim.alive[i]:
                continue
            st = stuck[i]
            a, b = q[i], qd[i]
            for _ in range(10):
                a, b, st, _ = friction_step(arm, a, b, command[i], 1e-3, st, frictions[i])
            q[i], qd[i], stuck[i] = a, b, st
            assert _close(sim.q[i], a, TOL_Q) and _close(sim.qd[i], b, TOL_QD), (period, i)
            assert np.array_equal(sim.stuck[i], st), (period, i)
    assert sim.alive.all()
    assert (sim.stuck[:, 0] != sim.stuck[:, 1]).sum() > 20


def test_a_stuck_joint_stays_exactly_put_while_the_other_swings():
    # Joint 2 held by a large static friction, joint 1 (no friction) swinging under
    # gravity: the held joint does not creep (position bit for bit, velocity exactly 0.0)
    # through 30 periods of 10 batched steps.
    rows = 8
    arms = [REAL.with_payload(0.1 * i) for i in range(rows)]
    frictions = [JointFriction(coulomb=[0.0, 40.0], static=[0.0, 50.0])] * rows
    q0 = np.column_stack((np.linspace(-0.5, 0.5, rows), np.linspace(0.3, 1.2, rows)))
    qd0 = np.zeros((rows, 2))
    qd0[:, 0] = 0.5
    sim = BatchSimulator(arms, q0=q0, qd0=qd0, effort_limits=np.full((rows, 2), 100.0),
                         physics_step_ns=1_000_000, control_period_ns=10_000_000,
                         velocity_limit=1e9, friction=frictions)
    for _ in range(30):
        sim.advance(np.zeros((rows, 2)))
        assert np.abs(sim.q[:, 1] - q0[:, 1]).max() < 1e-12   # measured: exactly 0
        assert (sim.q[:, 1] == q0[:, 1]).all() and (sim.qd[:, 1] == 0.0).all()
        assert sim.stuck[:, 1].all() and not sim.stuck[:, 0].any()
    assert np.abs(sim.q[:, 0] - q0[:, 0]).min() > 0.1   # joint 1 did swing
    for i, arm in enumerate(arms):
        a, b, _ = _steps(arm, frictions[i], q0[i], qd0[i], np.zeros(2), 1e-3, 300)
        assert _close(sim.q[i], a, TOL_Q) and _close(sim.qd[i], b, TOL_QD)


def test_the_held_rows_terms_are_reused_only_from_the_state_they_were_computed_at(
        monkeypatch):
    rows = 6
    arms = [REAL.with_payload(0.1 * i) for i in range(rows)]
    frictions = [JointFriction(coulomb=[0.0, 40.0], static=[0.0, 50.0])] * rows
    q0 = np.column_stack((np.linspace(-0.5, 0.5, rows), np.full(rows, 0.7)))
    qd0 = np.column_stack((np.full(rows, 0.5), np.zeros(rows)))
    sim = BatchSimulator(arms, q0=q0, qd0=qd0, effort_limits=np.full((rows, 2), 100.0),
                         physics_step_ns=1_000_000, control_period_ns=1_000_000,
                         velocity_limit=1e9, friction=frictions)
    calls = []
    real = batch_module._held_terms
    monkeypatch.setattr(batch_module, '_held_terms',
                        lambda *a: calls.append(1) or real(*a))
    sim.advance(np.zeros((rows, 2)))
    assert len(calls) == 2    # the decision and the end of the step
    sim.advance(np.zeros((rows, 2)))
    assert len(calls) == 3    # the decision took the terms of the step before
    # a state changed in place between periods: the terms are computed afresh
    sim.q[2, 1] += 1e-3
    start_q, start_qd = sim.q.copy(), sim.qd.copy()
    sim.advance(np.zeros((rows, 2)))
    assert len(calls) == 5
    for i, arm in enumerate(arms):
        a, b, _ = _steps(arm, frictions[i], start_q[i], start_qd[i], np.zeros(2), 1e-3, 1)
        assert _close(sim.q[i], a, TOL_Q) and _close(sim.qd[i], b, TOL_QD)


@pytest.mark.parametrize('mixed', [False, True])
def test_the_batch_sensors_equal_the_sensor_model_row_by_row(mixed):
    # config/real_arm.yaml's sensors on every row (one delay, every row noisy and
    # quantised: the shortcuts), or settings that differ from row to row. Bit for bit.
    rows = 12
    settings = [dict(position_noise=(4e-4, 4e-4), velocity_noise=(0.01, 0.01),
                     encoder_resolution=(16384.0, 16384.0), sensing_delay=1, seed=i)
                for i in range(rows)]
    if mixed:
        settings[1] = dict(encoder_resolution=(4096.0, 0.0), sensing_delay=3)
        settings[2] = dict(position_noise=(1e-3, 0.0), seed=5)
        settings[3] = {}
    sensors = batch_module._Sensors(rows, settings)
    models = [SensorModel(2, **m) for m in settings]
    rng = np.random.default_rng(2)
    for _ in range(600):   # more than one block of noise draws
        q, qd = rng.normal(size=(rows, 2)), rng.normal(size=(rows, 2))
        mq, mqd = sensors.measure(q, qd)
        for i, model in enumerate(models):
            a, b = model.measure(q[i], qd[i])
            assert np.array_equal(mq[i], a) and np.array_equal(mqd[i], b)
