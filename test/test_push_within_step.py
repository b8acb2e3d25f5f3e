"""A tip push's joint torque follows the arm within each physics step (pure).

A tip force ``F`` fixed in the base frame acts on the joints as ``J(q)^T F``: a function of
the configuration, so it belongs inside the right-hand side the integrator evaluates (every
RK4 stage), not held at its value at the step's start (that is first order: ~6e-5 rad
after a 30 N, 0.1 s push on the 2-R arm at 1 ms steps). Here the simulator's core
(:class:`~arm_dynamics.simulation.SimulatorCore`, fixed 1 ms RK4 steps) is compared with
scipy's DOP853 (rtol = atol = 1e-12) of the same ODE, ``J(q)^T F`` inside its right-hand
side, the pulse's start and end as exact breakpoints.

Tolerance: 1e-8 rad and 1e-7 rad/s at the end of the push (RK4's global error at 1 ms is
~1e-10 rad here; the held-torque rule was ~6e-5 rad, so the bound separates the two by
three orders of magnitude).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from arm_dynamics.disturbance import Disturbances
from arm_dynamics.friction import JointFriction
from arm_dynamics.integrate import TipLoaded
from arm_dynamics.simulation import SimulatorCore
from arm_dynamics.two_link import TwoLinkArm

MS = 1_000_000                   # ns
NAMES = ('joint1', 'joint2')
ARM = TwoLinkArm()
FORCE = np.array([0.0, -30.0])   # N, base frame
Q0 = (-0.4, 1.2)                 # rad
Q_TOL, QD_TOL = 1e-8, 1e-7       # rad, rad/s


def pulse(at_ms: int, duration_ms: int) -> Disturbances:
    return Disturbances.from_mapping(
        {'pushes': [{'at': at_ms * 1e-3, 'tip_force': FORCE.tolist(), 'shape': 'pulse',
                     'duration': duration_ms * 1e-3}]},
        n=2, joint_names=NAMES, physics_step_ns=MS)


def core(dist: Disturbances, period_ms: int, *, qd0=(0.0, 0.0),
         friction: JointFriction | None = None) -> SimulatorCore:
    return SimulatorCore(ARM, q0=list(Q0), qd0=list(qd0), effort_limits=[60.0, 20.0],
                         physics_step_ns=MS, control_period_ns=period_ms * MS,
                         velocity_limit=1000.0, joint_names=NAMES, disturbances=dist,
                         friction=friction)


def reference(segments, x0, coulomb=(0.0, 0.0)) -> np.ndarray:
    """DOP853 over ``segments`` [(t0 s, t1 s, force (2,) N)], zero motor torque, the tip
    force's ``J(q)^T F`` and a fixed-sign Coulomb torque ``-c sign(qd)`` in the right-hand
    side; the state (4,) at the end. Asserts no velocity changes sign (so the Coulomb
    term is the smooth one the core's slipping mode integrates)."""
    c = np.asarray(coulomb)
    x = np.asarray(x0, dtype=float)
    sign = np.sign(x[2:])

    def rhs(_t, y, force):
        q, qd = y[:2], y[2:]
        tau = ARM.jacobian(q).T @ force - c * sign
        return np.concatenate([qd, ARM.forward_dynamics(q, qd, tau)])

    for t0, t1, force in segments:
        sol = solve_ivp(rhs, (t0, t1), x, method='DOP853', rtol=1e-12, atol=1e-12,
                        args=(np.asarray(force, dtype=float),), dense_output=True)
        assert sol.success, sol.message
        if c.any():
            speeds = sol.sol(np.linspace(t0, t1, 201))[2:]
            assert (np.sign(speeds) == sign[:, None]).all(), 'a velocity changed sign'
        x = sol.y[:, -1]
    return x


def run(c: SimulatorCore, periods: int) -> np.ndarray:
    for _ in range(periods):
        c.set_command([0.0, 0.0])
        c.advance()
        assert c.diverged is None
    return np.r_[c.q, c.qd]


def check(state: np.ndarray, ref: np.ndarray) -> None:
    dq = np.abs(state[:2] - ref[:2]).max()
    dqd = np.abs(state[2:] - ref[2:]).max()
    assert dq < Q_TOL and dqd < QD_TOL, f'|dq| = {dq:.3g} rad, |dqd| = {dqd:.3g} rad/s'


def test_pulse_on_a_period_grid_matches_dop853_at_its_end():
    """30 N for 0.1 s from t = 0, zero motor torque, sampled every 1 ms step: the state at
    the pulse's end is the DOP853 one to RK4's order."""
    state = run(core(pulse(0, 100), 1), 100)
    check(state, reference([(0.0, 0.1, FORCE)], np.r_[Q0, 0.0, 0.0]))


def test_pulse_starting_and_ending_inside_control_periods():
    """Pulse 23 ms .. 123 ms with 10 ms control periods: both edges inside a period, at a
    physics step boundary; the state at 130 ms is the DOP853 one of the three segments."""
    state = run(core(pulse(23, 100), 10), 13)
    ref = reference([(0.0, 0.023, (0.0, 0.0)), (0.023, 0.123, FORCE),
                     (0.123, 0.130, (0.0, 0.0))], np.r_[Q0, 0.0, 0.0])
    check(state, ref)


def test_pulse_with_slipping_friction_takes_the_same_rule():
    """Coulomb friction on, both joints slipping the whole time (fast initial velocities):
    the friction step's path carries ``J(q)^T F`` per stage too."""
    friction = JointFriction(coulomb=(1.0, 0.5), static=(1.5, 0.8))
    qd0 = (3.0, -4.0)
    c = core(pulse(0, 100), 10, qd0=qd0, friction=friction)
    state = run(c, 10)
    ref = reference([(0.0, 0.1, FORCE)], np.r_[Q0, qd0], coulomb=(1.0, 0.5))
    check(state, ref)
    assert c.friction_work > 0.0


@pytest.mark.parametrize('q', [(0.3, -0.7), (-1.2, 2.0)])
def test_tip_loaded_model_is_the_model_plus_jacobian_transpose(q):
    """The wrapped dynamics: forward adds ``J^T F`` to the torque, inverse subtracts it
    (one is the other's inverse), mass matrix and Jacobian are the arm's."""
    loaded = TipLoaded(ARM, FORCE)
    q, qd, tau = np.array(q), np.array([0.4, -0.9]), np.array([2.0, -1.0])
    load = ARM.jacobian(q).T @ FORCE
    np.testing.assert_allclose(loaded.forward_dynamics(q, qd, tau),
                               ARM.forward_dynamics(q, qd, tau + load), rtol=1e-14,
                               atol=1e-14)
    qdd = loaded.forward_dynamics(q, qd, tau)
    np.testing.assert_allclose(loaded.inverse_dynamics(q, qd, qdd), tau, rtol=1e-12,
                               atol=1e-12)
    np.testing.assert_array_equal(loaded.mass_matrix(q), ARM.mass_matrix(q))
    assert loaded.n_dof == 2
