"""Linearisation of every model (``model.linearize``): against central differences of the
equations the integrator steps, against the closed form of the 2-R arm at an equilibrium,
and the sampled pair against the simulator's own RK4 over a control period."""

from __future__ import annotations

import math

import numpy as np
import pytest

from arm_dynamics.linearize import discretize
from arm_dynamics.models import robot_model
from arm_dynamics.planar_chain import PlanarChain
from arm_dynamics.robot import resolve_robot
from arm_dynamics.two_link import TwoLinkArm

RNG = np.random.default_rng(26)
MODELS = {
    'two_link': TwoLinkArm(joint_damping=(0.3, 0.1)),
    'planar_chain_3': robot_model(resolve_robot({
        'model': 'planar_chain', 'link_lengths': [1.0, 0.8, 0.6],
        'com_distances': [0.5, 0.4, 0.3], 'link_masses': [2.0, 1.5, 1.0],
        'link_inertias': [0.1, 0.08, 0.05], 'joint_damping': [0.1, 0.2, 0.05]})),
    'planar_chain_1': PlanarChain([0.7], [0.3], [1.2], [0.02], joint_damping=[0.3]),
}


def central_differences(model, q, qd, tau, h=1e-5):
    """d(q', qd')/d(q, qd) and /dtau of the equations of motion, by central differences."""
    n = model.n_dof
    x = np.r_[q, qd]

    def f(x, u):
        return np.r_[x[n:], model.forward_dynamics(x[:n], x[n:], u)]
    a = np.stack([(f(x + h * e, tau) - f(x - h * e, tau)) / (2 * h) for e in np.eye(2 * n)],
                 -1)
    b = np.stack([(f(x, tau + h * e) - f(x, tau - h * e)) / (2 * h) for e in np.eye(n)], -1)
    return a, b


@pytest.mark.parametrize('name', sorted(MODELS))
def test_the_linearisation_equals_central_differences_of_the_dynamics_to_1e_8(name):
    model = MODELS[name]
    n = model.n_dof
    for _ in range(10):
        q, qd = RNG.uniform(-math.pi, math.pi, n), RNG.uniform(-3, 3, n)
        tau = RNG.uniform(-20, 20, n)
        a, b = model.linearize(q, qd, tau)
        assert a.shape == (2 * n, 2 * n) and b.shape == (2 * n, n)
        a_fd, b_fd = central_differences(model, q, qd, tau)
        assert np.abs(a - a_fd).max() <= 1e-8 * np.abs(a).max()
        assert np.abs(b - b_fd).max() <= 1e-8 * np.abs(b).max()


def test_at_an_equilibrium_the_2r_arm_linearises_to_its_closed_form():
    """At rest with ``tau = g(q)``: ``A = [[0, I], [-D^-1 dg/dq, -D^-1 B]]``, with
    ``g = (G1 cos q1 + G2 cos(q1 + q2), G2 cos(q1 + q2))``, ``G1 = (m1 lc1 + m2 l1) g0``,
    ``G2 = m2 lc2 g0``."""
    arm = MODELS['two_link']
    (m1, m2), (lc1, lc2), l1 = arm.link_masses, arm.com_distances, arm.link_lengths[0]
    g1, g2 = (m1 * lc1 + m2 * l1) * arm.gravity, m2 * lc2 * arm.gravity
    for q in RNG.uniform(-math.pi, math.pi, (10, 2)):
        s1, s12 = math.sin(q[0]), math.sin(q[0] + q[1])
        dg = np.array([[-g1 * s1 - g2 * s12, -g2 * s12], [-g2 * s12, -g2 * s12]])
        d_inv = np.linalg.inv(arm.mass_matrix(q))
        expected = np.block([[np.zeros((2, 2)), np.eye(2)],
                             [-d_inv @ dg, -d_inv @ np.diag(arm.joint_damping)]])
        a, b = arm.linearize(q, np.zeros(2), arm.gravity_vector(q))
        np.testing.assert_allclose(a, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
        np.testing.assert_allclose(b[2:], d_inv, rtol=0, atol=1e-12 * np.abs(d_inv).max())


@pytest.mark.parametrize('name', sorted(MODELS))
def test_the_sampled_pair_is_the_simulators_rk4_period_linearised(name):
    """At an equilibrium (at rest, ``tau = g(q)``), ``(Ad, Bd)`` for the 10 ms control
    period against central differences of ten 1 ms RK4 steps (the simulator's period):
    equal to the integrator's own error, 1e-7. (About a moving state the pair is the hold
    equivalent of the linearisation at the period's start, not the flow's Jacobian.)"""
    model = MODELS[name]
    n, period = model.n_dof, 0.01
    q, qd = RNG.uniform(-1, 1, n), np.zeros(n)
    tau = np.asarray(model.gravity_vector(q))
    ad, bd = model.linearize(q, qd, tau, period=period)
    h = 1e-5

    def step(x, u):
        q1, qd1 = model.step(x[:n], x[n:], u, 0.001, 10)
        return np.r_[q1, qd1]
    x = np.r_[q, qd]
    ad_fd = np.stack([(step(x + h * e, tau) - step(x - h * e, tau)) / (2 * h)
                      for e in np.eye(2 * n)], -1)
    bd_fd = np.stack([(step(x, tau + h * e) - step(x, tau - h * e)) / (2 * h)
                      for e in np.eye(n)], -1)
    assert np.abs(ad - ad_fd).max() <= 1e-7 * np.abs(ad).max()
    assert np.abs(bd - bd_fd).max() <= 1e-7 * np.abs(bd).max()


def test_the_zero_order_hold_of_a_double_integrator_is_the_textbook_pair():
    """``x'' = u``: ``Ad = [[1, T], [0, 1]]``, ``Bd = [[T^2/2], [T]]``."""
    ad, bd = discretize(np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[0.0], [1.0]]), 0.01)
    np.testing.assert_allclose(ad, [[1.0, 0.01], [0.0, 1.0]], atol=1e-15)
    np.testing.assert_allclose(bd, [[5e-5], [0.01]], atol=1e-15)
    with pytest.raises(ValueError, match='period must be > 0'):
        discretize(np.zeros((2, 2)), np.zeros((2, 1)), 0.0)
