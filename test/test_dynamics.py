"""Dynamics test suite: three independent derivations of the arm's equations must agree.

* closed form -- :class:`arm_dynamics.TwoLinkArm` (hand-derived 2-link formulas);
* Christoffel route -- :func:`arm_dynamics.lagrange.planar_chain` (generic n-link ``D(q)``
  and ``PE(q)``, everything else by complex-step differentiation and Christoffel symbols);
* Newton-Euler -- :func:`arm_dynamics.newton_euler.rnea` (force/moment balance, no D, no C).

Plus integration accuracy (energy drift, RK4 against a tight DOP853 reference), the lecture's
spring-mass and geared-link examples, argument checking and batching. Every tolerance is
stated in the assertion message. Runtime is a few seconds.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from arm_dynamics import SingleLinkGeared, TwoLinkArm, simulate
from arm_dynamics.lagrange import (
    LagrangianSystem,
    geared_link_lagrangian,
    planar_chain,
    spring_mass,
)
from arm_dynamics.newton_euler import NewtonEulerChain, rnea

AGREE = 1e-10          # relative agreement between derivations (to max(1, |reference|))
N_PARAM_SETS = 100     # random parameter sets ...
N_STATES_PER_SET = 3   # ... times states per set = 300 random (parameters, state) pairs


# ---------------------------------------------------------------------- helpers
def random_chain_params(rng: np.random.Generator, n: int) -> dict:
    """A physically plausible random parameter set for an n-link planar chain."""
    lengths = rng.uniform(0.2, 2.0, n)
    masses = rng.uniform(0.1, 10.0, n)
    return {
        'link_lengths': tuple(lengths),
        'com_distances': tuple(lengths * rng.uniform(0.0, 1.0, n)),
        'link_masses': tuple(masses),
        'link_inertias': tuple(masses * lengths**2 * rng.uniform(0.01, 0.2, n)),
        'gravity': float(rng.uniform(0.0, 20.0)),
        'joint_damping': tuple(rng.uniform(0.0, 2.0, n)),
    }


def random_state(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    """(q, qd, qdd, tau): rad, rad/s, rad/s^2, N m."""
    return (rng.uniform(-np.pi, np.pi, n), rng.uniform(-5.0, 5.0, n),
            rng.uniform(-20.0, 20.0, n), rng.uniform(-50.0, 50.0, n))


def rel_err(a, b) -> float:
    """|a - b| relative to the scale of b, floored at 1 (so tiny references compare absolutely)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.linalg.norm(a - b) / max(1.0, np.linalg.norm(b)))


def ne_terms(params: dict, q: np.ndarray, qd: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """D, C qd and g recovered from Newton-Euler alone (it never forms them itself).

    D column j = rnea(q, 0, e_j) without gravity or damping; C qd = rnea(q, qd, 0) without
    gravity or damping; g = rnea(q, 0, 0) without damping.
    """
    n = len(q)
    bare = dict(params, gravity=0.0, joint_damping=(0.0,) * n)
    eye = np.eye(n)
    d = rnea(np.broadcast_to(q, (n, n)), np.zeros((n, n)), eye, **bare).T
    cqd = rnea(q, qd, np.zeros(n), **bare)
    g = rnea(q, np.zeros(n), np.zeros(n), **dict(params, joint_damping=(0.0,) * n))
    return d, cqd, g


def zero_crossing_period(t: np.ndarray, x: np.ndarray) -> float:
    """Period from the zero crossings of x(t) (linear interpolation; every crossing is half
    a period apart). Needs at least three crossings."""
    idx = np.nonzero(np.sign(x[:-1]) * np.sign(x[1:]) < 0)[0]
    assert len(idx) >= 3, f'need >= 3 zero crossings, got {len(idx)}'
    tc = t[idx] - x[idx] * (t[idx + 1] - t[idx]) / (x[idx + 1] - x[idx])
    return 2.0 * (tc[-1] - tc[0]) / (len(tc) - 1)


# ---------------------------------------------------------------------- three derivations
def test_closed_form_christoffel_and_newton_euler_agree_at_random_states_and_parameters():
    rng = np.random.default_rng(20240601)
    worst = {'tau': 0.0, 'd': 0.0, 'c': 0.0, 'cqd': 0.0, 'g': 0.0, 'qdd': 0.0}
    for _ in range(N_PARAM_SETS):
        params = random_chain_params(rng, 2)
        arm = TwoLinkArm(**params)
        chain = planar_chain(**params)
        for _ in range(N_STATES_PER_SET):
            q, qd, qdd, tau = random_state(rng, 2)
            tau_cf = arm.inverse_dynamics(q, qd, qdd)
            d_cf, c_cf, g_cf = arm.mass_matrix(q), arm.coriolis_matrix(q, qd), \
                arm.gravity_vector(q)
            d_ne, cqd_ne, g_ne = ne_terms(params, q, qd)
            checks = {
                'tau': [(chain.inverse_dynamics(q, qd, qdd), tau_cf),
                        (rnea(q, qd, qdd, **params), tau_cf)],
                'd': [(chain.mass_matrix(q), d_cf), (d_ne, d_cf)],
                'c': [(chain.coriolis_matrix(q, qd), c_cf)],
                'cqd': [(chain.coriolis_matrix(q, qd) @ qd, c_cf @ qd), (cqd_ne, c_cf @ qd)],
                'g': [(chain.gravity_vector(q), g_cf), (g_ne, g_cf)],
            }
            qdd_cf = arm.forward_dynamics(q, qd, tau)
            checks['qdd'] = [(chain.forward_dynamics(q, qd, tau), qdd_cf)]
            # Newton-Euler has no forward dynamics: it must return tau from the closed
            # form's acceleration (error measured in torque units).
            checks['tau'].append((rnea(q, qd, qdd_cf, **params), tau))
            for name, pairs in checks.items():
                for a, b in pairs:
                    worst[name] = max(worst[name], rel_err(a, b))
    for name, err in worst.items():
        assert err < AGREE, f'{name}: worst relative disagreement {err:.2e} >= {AGREE:g}'


def test_single_state_inverse_dynamics_equals_the_batch_path():
    """The controller's per-tick float path and the array path are one formula."""
    rng = np.random.default_rng(11)
    arm = TwoLinkArm(**random_chain_params(rng, 2))
    q, qd, qdd = (rng.uniform(-4, 4, (200, 2)) for _ in range(3))
    batch = arm.inverse_dynamics(q, qd, qdd)
    single = np.array([arm.inverse_dynamics(*x) for x in zip(q, qd, qdd)])
    lists = np.array([arm.inverse_dynamics(*(v.tolist() for v in x))
                      for x in zip(q, qd, qdd)])
    scale = np.maximum(1.0, np.abs(batch))
    assert (np.abs(single - batch) / scale).max() < 1e-14
    assert np.array_equal(single, lists)


def test_closed_form_matches_newton_euler_batched_at_random_states():
    rng = np.random.default_rng(7)
    params = random_chain_params(rng, 2)
    arm = TwoLinkArm(**params)
    q, qd, qdd = (rng.uniform(-4, 4, (500, 2)) for _ in range(3))
    tau_cf = arm.inverse_dynamics(q, qd, qdd)
    tau_ne = rnea(q, qd, qdd, **params)
    scale = np.maximum(1.0, np.linalg.norm(tau_cf, axis=-1))
    err = float((np.linalg.norm(tau_ne - tau_cf, axis=-1) / scale).max())
    assert err < AGREE, f'batched closed form vs Newton-Euler: {err:.2e} >= {AGREE:g} relative'


def test_three_link_chain_christoffel_route_matches_newton_euler():
    rng = np.random.default_rng(3)
    for _ in range(20):
        params = random_chain_params(rng, 3)
        chain = planar_chain(**params)
        for _ in range(5):
            q, qd, qdd, tau = random_state(rng, 3)
            tau_ne = rnea(q, qd, qdd, **params)
            err = rel_err(chain.inverse_dynamics(q, qd, qdd), tau_ne)
            assert err < AGREE, f'n=3 inverse dynamics: {err:.2e} >= {AGREE:g} relative'
            d_ne, cqd_ne, g_ne = ne_terms(params, q, qd)
            assert rel_err(chain.mass_matrix(q), d_ne) < AGREE, f'n=3 D (tol {AGREE:g})'
            assert rel_err(chain.coriolis_matrix(q, qd) @ qd, cqd_ne) < AGREE, \
                f'n=3 C qd (tol {AGREE:g})'
            assert rel_err(chain.gravity_vector(q), g_ne) < AGREE, f'n=3 g (tol {AGREE:g})'
            qdd_chain = chain.forward_dynamics(q, qd, tau)
            err = rel_err(rnea(q, qd, qdd_chain, **params), tau)
            assert err < AGREE, f'n=3 forward/inverse round trip: {err:.2e} >= {AGREE:g}'


def test_one_link_chain_is_the_damped_pendulum():
    rng = np.random.default_rng(11)
    m, lc, inertia, g0, b = 3.0, 0.4, 0.05, 9.81, 0.2
    chain = planar_chain((1.0,), (lc,), (m,), (inertia,), g0, (b,))
    for _ in range(50):
        q, qd, qdd, _ = random_state(rng, 1)
        expected = (m * lc**2 + inertia) * qdd + m * g0 * lc * np.cos(q) + b * qd
        assert rel_err(chain.inverse_dynamics(q, qd, qdd), expected) < AGREE, \
            f'1-link chain vs pendulum formula (tol {AGREE:g})'
        assert rel_err(rnea(q, qd, qdd, link_lengths=(1.0,), com_distances=(lc,),
                            link_masses=(m,), link_inertias=(inertia,), gravity=g0,
                            joint_damping=(b,)), expected) < AGREE, \
            f'1-link Newton-Euler vs pendulum formula (tol {AGREE:g})'


# ---------------------------------------------------------------------- structure of D, C
def test_mass_matrix_is_symmetric_positive_definite_at_random_configurations():
    rng = np.random.default_rng(5)
    for _ in range(40):
        params = random_chain_params(rng, 2)
        arm = TwoLinkArm(**params)
        q = rng.uniform(-np.pi, np.pi, (25, 2))
        d = arm.mass_matrix(q)
        assert np.array_equal(d, np.swapaxes(d, -1, -2)), 'D must be exactly symmetric'
        eig = np.linalg.eigvalsh(d)
        assert (eig[:, 0] > 1e-9 * eig[:, 1]).all(), \
            'D must be positive definite (smallest eigenvalue > 1e-9 x largest)'
    chain = planar_chain(**random_chain_params(rng, 4))
    for q in rng.uniform(-np.pi, np.pi, (20, 4)):
        d = chain.mass_matrix(q)
        assert np.allclose(d, d.T, rtol=0, atol=1e-14 * np.abs(d).max()), \
            'n=4 chain D symmetric to 1e-14 relative'
        assert np.linalg.eigvalsh(d)[0] > 0.0, 'n=4 chain D positive definite'


def test_d_dot_minus_two_c_is_skew_symmetric_for_the_closed_form():
    # D' = sum_k dD/dq_k qd_k by a central difference of TwoLinkArm.mass_matrix along qd:
    # step h = 1e-6 s gives truncation ~1e-12 and round-off ~1e-10 of |D| |qd|, so the
    # tolerance is 1e-8 relative to max(1, |D| |qd|).
    rng = np.random.default_rng(6)
    h = 1e-6
    for _ in range(40):
        arm = TwoLinkArm(**random_chain_params(rng, 2))
        for _ in range(5):
            q, qd, _, _ = random_state(rng, 2)
            d_dot = (arm.mass_matrix(q + h * qd) - arm.mass_matrix(q - h * qd)) / (2 * h)
            n_mat = d_dot - 2.0 * arm.coriolis_matrix(q, qd)
            scale = max(1.0, np.abs(arm.mass_matrix(q)).max() * np.abs(qd).max())
            assert np.abs(n_mat + n_mat.T).max() < 1e-8 * scale, \
                'closed form: D_dot - 2C not skew to 1e-8 relative'
            # Passivity consequence: x^T (D_dot - 2C) x = 0 for any x.
            x = rng.normal(size=2)
            assert abs(x @ n_mat @ x) < 1e-8 * scale * (x @ x), 'x^T (D_dot - 2C) x != 0'


def test_d_dot_minus_two_c_is_skew_symmetric_for_the_christoffel_route():
    # Here D' comes from the complex-step dD/dq (exact), so the tolerance is 1e-12.
    rng = np.random.default_rng(8)
    for n in (2, 3, 4):
        chain = planar_chain(**random_chain_params(rng, n))
        for _ in range(10):
            q, qd, _, _ = random_state(rng, n)
            d_dot = np.einsum('kij,k->ij', chain.mass_matrix_derivatives(q), qd)
            n_mat = d_dot - 2.0 * chain.coriolis_matrix(q, qd)
            scale = max(1.0, np.abs(d_dot).max())
            assert np.abs(n_mat + n_mat.T).max() < 1e-12 * scale, \
                f'n={n}: D_dot - 2C not skew to 1e-12 relative'


def test_complex_step_derivative_matches_central_difference():
    # Complex step is exact; a central difference (h = 1e-6) agrees to its own error ~1e-9.
    rng = np.random.default_rng(9)
    chain = planar_chain(**random_chain_params(rng, 3))
    q = rng.uniform(-np.pi, np.pi, 3)
    dd = chain.mass_matrix_derivatives(q)
    g = chain.gravity_vector(q)
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        fd = (chain.mass_matrix(q + e) - chain.mass_matrix(q - e)) / (2 * h)
        assert np.abs(dd[k] - fd).max() < 1e-7 * max(1.0, np.abs(fd).max()), \
            f'dD/dq_{k}: complex step vs central difference beyond 1e-7 relative'
        fg = (chain.potential_energy(q + e) - chain.potential_energy(q - e)) / (2 * h)
        assert abs(g[k] - fg) < 1e-7 * max(1.0, abs(fg)), \
            f'dPE/dq_{k}: complex step vs central difference beyond 1e-7 relative'


# ---------------------------------------------------------------------- integration
# Released from rest horizontal (full swings, KE up to 30 J: drift ~9e-10), hanging with a
# bend (~5e-12) and thrown from hanging (~8e-12). Releases from near upright (KE ~ 50-60 J,
# joint speeds > 10 rad/s) reach ~1.2e-8 at 1 ms: the edge of RK4 at this step.
@pytest.mark.parametrize('q0, qd0', [((0.0, 0.0), (0.0, 0.0)),
                                     ((-np.pi / 2 + 0.6, 0.8), (0.0, 0.0)),
                                     ((-np.pi / 2, 0.0), (3.0, -4.0))])
def test_energy_is_conserved_by_rk4_over_10_s_without_torque_or_damping(q0, qd0):
    arm = TwoLinkArm()
    q, qd = np.array(q0), np.array(qd0)
    e0 = sum(arm.energy(q, qd))
    energies, kinetic = [], []
    for _ in range(100):                       # 100 x 100 steps of 1 ms = 10 s
        q, qd = arm.step(q, qd, (0.0, 0.0), 1e-3, 100)
        ke, pe = arm.energy(q, qd)
        energies.append(ke + pe)
        kinetic.append(ke)
    # Energy scale: |E0| or the largest kinetic energy reached (E0 can be 0 at base height).
    scale = max(abs(e0), max(kinetic))
    drift = float(np.abs(np.array(energies) - e0).max()) / scale
    assert max(kinetic) > 1.0, 'the arm must actually move for this test to mean anything'
    assert drift < 1e-8, f'energy drift {drift:.2e} >= 1e-8 relative over 10 s of RK4 at 1 ms'


def test_energy_change_equals_damping_work_with_damping():
    # With damping and no torque the energy decreases; RK4 at 1 ms must dissipate exactly
    # the damping work int qd^T B qd dt (trapezoid on 0.1 ms substeps, tol 1e-6 relative).
    arm = TwoLinkArm(joint_damping=(0.4, 0.3))
    q, qd = np.array([0.3, 0.5]), np.zeros(2)
    e0 = sum(arm.energy(q, qd))
    work, p_prev = 0.0, 0.0
    for _ in range(20000):                     # 2 s at 0.1 ms
        q, qd = arm.step(q, qd, (0.0, 0.0), 1e-4)
        p = float(qd @ arm.damping_torque(qd))
        work += 0.5 * (p + p_prev) * 1e-4
        p_prev = p
    loss = e0 - sum(arm.energy(q, qd))
    assert loss > 0.0, 'damping must remove energy'
    assert abs(loss - work) < 1e-6 * max(1.0, work), \
        f'energy lost {loss:.9f} J vs damping work {work:.9f} J (tol 1e-6 relative)'


def test_rk4_matches_solve_ivp_reference_within_1e_8_rad_over_5_s_of_free_motion():
    arm = TwoLinkArm()
    kwargs = {'model': arm, 'q0': (-np.pi / 2 + 0.6, 0.8), 'qd0': (0.0, 0.5),
              'torque': (0.0, 0.0), 'duration': 5.0, 'dt': 1e-3}
    fixed = simulate(method='rk4', **kwargs)
    reference = simulate(method='solve_ivp', rtol=1e-12, atol=1e-12, **kwargs)
    assert np.array_equal(fixed.t, reference.t)
    assert np.ptp(fixed.q[:, 0]) > 0.5, 'the arm must swing for this test to mean anything'
    err = float(np.abs(fixed.q - reference.q).max())
    assert err < 1e-8, f'RK4 (1 ms) vs DOP853 (rtol 1e-12): {err:.2e} rad >= 1e-8 rad over 5 s'


def test_lagrangian_chain_rk4_trajectory_matches_closed_form_step():
    # The generic machinery, integrated by the same RK4, follows the closed form (1e-10 rad).
    params = {'link_lengths': (1.0, 0.8), 'com_distances': (0.5, 0.4),
              'link_masses': (2.0, 1.5), 'link_inertias': (0.1, 0.08), 'gravity': 9.81,
              'joint_damping': (0.1, 0.05)}
    arm, chain = TwoLinkArm(**params), planar_chain(**params)
    q0, qd0, tau = np.array([0.2, -0.4]), np.array([0.5, 1.0]), np.array([3.0, -1.0])
    qa, qda = arm.step(q0, qd0, tau, 1e-3, 200)
    qc, qdc = chain.step(q0, qd0, tau, 1e-3, 200)
    assert np.abs(qa - qc).max() < 1e-10, 'q after 0.2 s: closed form vs Lagrangian, 1e-10 rad'
    assert np.abs(qda - qdc).max() < 1e-9, 'qd after 0.2 s: closed form vs Lagrangian, 1e-9'


# ---------------------------------------------------------------------- lecture examples
def test_spring_mass_machinery_gives_m_xdd_plus_k_x_equals_f():
    rng = np.random.default_rng(12)
    for _ in range(50):
        m, k = rng.uniform(0.1, 10.0), rng.uniform(0.0, 100.0)
        system = spring_mass(m, k)
        x, xd, xdd, f = rng.uniform(-2.0, 2.0, 4)
        assert np.abs(system.christoffel_symbols([x])).max() == 0.0, 'constant D: no C terms'
        assert rel_err(system.gravity_vector([x]), [k * x]) < 1e-14, 'dPE/dx = k x (1e-14)'
        assert rel_err(system.inverse_dynamics([x], [xd], [xdd]), [m * xdd + k * x]) < 1e-14, \
            'F = m x_dd + k x (tol 1e-14 relative)'
        assert rel_err(system.forward_dynamics([x], [xd], [f]), [(f - k * x) / m]) < 1e-14, \
            'x_dd = (F - k x)/m (tol 1e-14 relative)'
        ke, pe = system.energy([x], [xd])
        assert math.isclose(ke, 0.5 * m * xd**2, rel_tol=1e-14)
        assert math.isclose(pe, 0.5 * k * x**2, rel_tol=1e-14, abs_tol=1e-300)


def test_spring_mass_simulated_period_is_two_pi_sqrt_m_over_k():
    m, k = 0.5, 20.0
    period = 2.0 * np.pi * np.sqrt(m / k)          # about 0.99 s
    run = simulate(model=spring_mass(m, k), q0=(0.1,), qd0=(0.0,), torque=(0.0,),
                   duration=2.1 * period, dt=1e-3)
    measured = zero_crossing_period(run.t, run.q[:, 0])
    assert abs(measured - period) < 1e-6 * period, \
        f'spring-mass period {measured:.9f} s vs 2 pi sqrt(m/k) = {period:.9f} s (tol 1e-6)'


def random_geared_params(rng: np.random.Generator) -> dict[str, float]:
    """SingleLinkGeared parameters drawn across their valid ranges."""
    return {'motor_inertia': rng.uniform(1e-4, 1e-2), 'load_inertia': rng.uniform(0.0, 2.0),
            'motor_damping': rng.uniform(0.0, 0.1), 'load_damping': rng.uniform(0.0, 1.0),
            'gear_ratio': rng.uniform(1.0, 100.0), 'mass': rng.uniform(0.0, 5.0),
            'length': rng.uniform(0.0, 1.0), 'gravity': rng.uniform(0.0, 20.0)}

def test_geared_link_matches_its_closed_form_and_the_lagrangian_machinery():
    rng = np.random.default_rng(13)
    for _ in range(50):
        p = random_geared_params(rng)
        link, lagr = SingleLinkGeared(**p), geared_link_lagrangian(**p)
        n = p['gear_ratio']
        big_j = p['motor_inertia'] + p['load_inertia'] / n**2
        big_b = p['motor_damping'] + p['load_damping'] / n**2
        big_c = p['mass'] * p['gravity'] * p['length'] / n
        th, thd, thdd, u = rng.uniform(-100.0, 100.0), *rng.uniform(-50.0, 50.0, 3)
        closed_u = big_j * thdd + big_b * thd + big_c * np.sin(th / n)
        assert rel_err(link.inverse_dynamics(th, thd, thdd), closed_u) < 1e-12, \
            'SingleLinkGeared vs J th_dd + B th_d + C sin(th/n) = u (1e-12 relative)'
        assert rel_err(lagr.inverse_dynamics([th], [thd], [thdd]), [closed_u]) < 1e-12, \
            'Lagrangian geared link vs closed form (1e-12 relative)'
        closed_acc = (u - big_b * thd - big_c * np.sin(th / n)) / big_j
        assert rel_err(link.forward_dynamics(th, thd, u), closed_acc) < 1e-12, \
            'SingleLinkGeared forward dynamics vs closed form (1e-12 relative)'
        assert rel_err(lagr.forward_dynamics([th], [thd], [u]), [closed_acc]) < 1e-12, \
            'Lagrangian geared link forward dynamics vs closed form (1e-12 relative)'
        assert rel_err(link.energy(th, thd), lagr.energy([th], [thd])) < 1e-12, \
            'geared link (KE, PE): SingleLinkGeared vs Lagrangian (1e-12 relative)'
        assert math.isclose(link.inertia, big_j, rel_tol=1e-14)
        assert math.isclose(link.damping, big_b, rel_tol=1e-14)
        assert math.isclose(link.gravity_coefficient, big_c, rel_tol=1e-14, abs_tol=1e-300)


def test_geared_link_small_oscillation_period_is_two_pi_sqrt_j_n_over_c():
    p = {'motor_inertia': 1e-4, 'load_inertia': 0.1, 'motor_damping': 0.0, 'load_damping': 0.0,
         'gear_ratio': 10.0, 'mass': 2.0, 'length': 0.5, 'gravity': 9.81}
    link = SingleLinkGeared(**p)
    n = p['gear_ratio']
    big_j = p['motor_inertia'] + p['load_inertia'] / n**2
    big_c = p['mass'] * p['gravity'] * p['length'] / n
    period = 2.0 * np.pi * np.sqrt(big_j * n / big_c)      # about 0.67 s
    assert math.isclose(link.small_oscillation_period(), period, rel_tol=1e-14)
    # Load amplitude 1e-3 rad: the finite-amplitude lengthening is ~theta^2/16 = 6e-8.
    run = simulate(model=link, q0=(1e-3 * n,), qd0=(0.0,), torque=(0.0,),
                   duration=2.1 * period, dt=1e-3)
    measured = zero_crossing_period(run.t, run.q[:, 0])
    assert abs(measured - period) < 1e-6 * period, \
        f'geared-link period {measured:.9f} s vs 2 pi sqrt(J n/C) = {period:.9f} s (tol 1e-6)'
    # The Lagrangian machinery, stepped by the same RK4, follows the same trajectory.
    q, qd = geared_link_lagrangian(**p).step((1e-3 * n,), (0.0,), (0.0,), 1e-3, 300)
    assert abs(q[0] - run.q[300, 0]) < 1e-12, 'geared link: Lagrangian vs closed form 1e-12 rad'
    assert abs(qd[0] - run.qd[300, 0]) < 1e-10, 'geared link: Lagrangian vs closed form qd'


def test_geared_link_torque_is_what_the_link_equation_needs_at_random_states():
    rng = np.random.default_rng(14)
    for _ in range(50):
        p = random_geared_params(rng)
        link, n = SingleLinkGeared(**p), p['gear_ratio']
        th, thd, u = rng.uniform(-100.0, 100.0), *rng.uniform(-50.0, 50.0, 2)
        acc = link.forward_dynamics(th, thd, u)  # motor side; the link's is acc / n
        needed = (p['load_inertia'] * acc / n + p['load_damping'] * thd / n
                  + p['mass'] * p['gravity'] * p['length'] * np.sin(th / n))
        scale = n * (abs(u) + p['motor_inertia'] * abs(acc) + p['motor_damping'] * abs(thd))
        assert abs(link.link_torque(th, thd, u) - needed) < 1e-12 * max(1.0, scale), \
            'n (u - Jm th_m" - Bm th_m\') = Jl th_l" + Bl th_l\' + M g l sin th_l (1e-12 rel.)'
    link = SingleLinkGeared()
    assert link.link_torque(0.0, 0.0, 0.0) == 0.0
    hold = link.gravity_coefficient * np.sin(0.3)  # u holding the link at 0.3 rad
    assert link.link_torque(0.3 * link.gear_ratio, 0.0, hold) == pytest.approx(
        link.gear_ratio * hold, rel=1e-12), 'at rest the link torque is n u'
    assert link.link_torque(np.zeros(3), 0.0, np.ones(3)).shape == (3,)


def test_geared_link_published_effort_is_the_link_torque_along_a_simulated_motion():
    from arm_dynamics.simulation import SimulatorCore
    link = SingleLinkGeared()  # the simulator's geared.* defaults
    n, h = link.gear_ratio, 1e-3
    core = SimulatorCore(link, q0=[0.3 * n], qd0=[0.0], effort_limits=[1.0],
                         physics_step_ns=100_000, control_period_ns=1_000_000,
                         velocity_limit=1e3, joint_names=['joint1'])
    rows = []
    for k in range(3000):  # 1 s each of u = 0.4, -0.3, 0.05 N m
        core.set_command([(0.4, -0.3, 0.05)[k // 1000]])
        core.advance()
        view = core.joint_view()
        assert view.names == ('joint1_motor', 'joint1')
        rows.append((view.position[1], view.velocity[1], view.effort[0], view.effort[1]))
    th, thd, u, effort = np.array(rows).T
    # The link's acceleration by central differences of its published speed (error ~h^2),
    # away from the command steps, where it jumps.
    acc = np.gradient(thd, h)
    ok = np.ones(len(th), bool)
    for k in (0, 999, 1000, 1999, 2000, 2999):
        ok[max(k - 1, 0):k + 2] = False
    needed = (link.load_inertia * acc + link.load_damping * thd
              + link.mass * link.gravity * link.length * np.sin(th))
    err = np.abs(effort - needed)[ok].max()
    assert err < 1e-5, f'link effort vs Jl th" + Bl th\' + M g l sin th: {err:.2e} N m (1e-5)'
    assert np.abs(n * u - needed)[ok].max() > 10.0, 'n u is not the link torque: 20 N m off'


def test_lagrangian_system_from_user_callables_derives_the_pendulum():
    # Any analytic D(q), PE(q) works: a pendulum written by hand.
    m, lc, g0 = 2.0, 0.7, 9.81
    system = LagrangianSystem(lambda q: np.array([[m * lc**2]]),
                              lambda q: -m * g0 * lc * np.cos(q[0]), n_dof=1,
                              joint_damping=(0.1,))
    q, qd, qdd = 0.4, -1.2, 3.0
    expected = m * lc**2 * qdd + m * g0 * lc * np.sin(q) + 0.1 * qd
    assert rel_err(system.inverse_dynamics([q], [qd], [qdd]), [expected]) < 1e-14, \
        'hand-written pendulum: (tol 1e-14 relative)'


# ---------------------------------------------------------------------- kinematics
def random_arms(rng: np.random.Generator, n: int) -> list[TwoLinkArm]:
    """Arms with random link lengths (l1 > l2, l1 < l2 and nearly equal all occur)."""
    return [TwoLinkArm(link_lengths=tuple(rng.uniform(0.2, 2.0, 2))) for _ in range(n)]


def test_inverse_kinematics_round_trips_with_forward_kinematics_on_both_elbows():
    rng = np.random.default_rng(41)
    for arm in random_arms(rng, 20):
        reach = sum(arm.link_lengths)
        # 1000 random states per arm, either branch, |sin q2| >= 1e-3 (off the singularity).
        q = np.stack([rng.uniform(-np.pi, np.pi, 1000),
                      rng.choice([-1.0, 1.0], 1000) * rng.uniform(1e-3, np.pi - 1e-3, 1000)],
                     -1)
        q[:, 1] = np.where(np.abs(np.sin(q[:, 1])) < 1e-3, 0.5, q[:, 1])
        p = arm.forward_kinematics(q)
        for elbow, rows in (('down', q[:, 1] > 0), ('up', q[:, 1] < 0)):
            back = arm.inverse_kinematics(p[rows], elbow)
            assert np.abs(arm.forward_kinematics(back) - p[rows]).max() < 1e-12 * reach, \
                f'FK(IK(p)) = p to 1e-12 x reach ({elbow})'
            # Recovering q loses ~eps / |sin q2| near the singularity: 1e-9 rad at 1e-3.
            turns = np.angle(np.exp(1j * (back - q[rows])))
            assert np.abs(turns).max() < 1e-9, f'IK(FK(q)) = q mod 2 pi to 1e-9 rad ({elbow})'
            assert (arm.elbow_of(back) == elbow).all() and (
                np.sign(back[:, 1]) == (1.0 if elbow == 'down' else -1.0)).all(), \
                "branch convention: 'down' is q2 > 0"
            assert (np.abs(back[:, 0]) <= np.pi).all(), 'q1 in (-pi, pi]'
            one = arm.inverse_kinematics(p[rows][0], elbow)
            assert one.shape == (2,) and np.array_equal(one, back[0]), 'single = batch row'


def test_inverse_kinematics_on_the_boundary_and_clipping_outside():
    arm = TwoLinkArm()  # l = (1.0, 0.8)
    for elbow in ('up', 'down'):
        assert np.abs(arm.inverse_kinematics((1.8, 0.0), elbow)).max() < 1e-7, 'stretched'
        assert arm.inverse_kinematics((0.2, 0.0), elbow)[1] == pytest.approx(
            np.pi if elbow == 'down' else -np.pi), 'folded'
        # Outside the annulus: the boundary point in the same direction.
        q = arm.inverse_kinematics((0.0, 3.0), elbow)
        assert np.allclose(arm.forward_kinematics(q), (0.0, 1.8), atol=1e-7)
    assert arm.elbow_of(np.array([[0.0, 0.5], [0.0, -0.5], [0.0, 0.0]])).tolist() == [
        'down', 'up', 'down'], 'sin q2 = 0 counts as down'
    with pytest.raises(ValueError, match='elbow'):
        arm.inverse_kinematics((1.0, 0.5), 'keep')


def test_jdot_qd_is_the_time_derivative_of_the_jacobian_along_a_motion():
    rng = np.random.default_rng(42)
    h = 1e-5  # s: central differences, truncation ~ h^2 |J'''| ~ 1e-9 here
    for arm in random_arms(rng, 20):
        q0, v, a = (rng.uniform(-3.0, 3.0, (50, 2)) for _ in range(3))

        def q_of(t):  # a smooth motion through q0 with q' = v, q'' = a at t = 0
            return q0 + v * np.sin(t) + 0.5 * a * t * t

        def qd_of(t):
            return v * np.cos(t) + a * t

        # d/dt (J(q(t)) q'(t)) = J q'' + J' q': the Jacobian differentiated numerically.
        jqd = [np.einsum('kij,kj->ki', arm.jacobian(q_of(t)), qd_of(t)) for t in (-h, h)]
        expected = (jqd[1] - jqd[0]) / (2 * h) - np.einsum('kij,kj->ki', arm.jacobian(q0), a)
        scale = sum(arm.link_lengths) * (1.0 + (np.abs(v).sum(-1) ** 2).max())
        assert np.abs(arm.jdot_qd(q0, v) - expected).max() < 1e-8 * scale, \
            "J' q' vs d/dt(J q') - J q'' by central differences (1e-8 relative)"
        # And the tip acceleration: p'' = J q'' + J' q' against FK's second difference.
        hp = 1e-4
        pdd = (arm.forward_kinematics(q_of(hp)) - 2 * arm.forward_kinematics(q0)
               + arm.forward_kinematics(q_of(-hp))) / hp**2
        model = np.einsum('kij,kj->ki', arm.jacobian(q0), a) + arm.jdot_qd(q0, v)
        assert np.abs(model - pdd).max() < 1e-5 * scale, "p'' = J q'' + J' q' (FK, 1e-5)"
    assert TwoLinkArm().jdot_qd(np.zeros((3, 4, 2)), np.ones(2)).shape == (3, 4, 2)


# By hand, l = (1.0, 0.8): cos q2 = (r^2 - 1.64) / 1.6, e.g. r = 1.785: 0.9664, |sin q2| =
# 0.2571.
@pytest.mark.parametrize('p, margins, pattern', [
    ((3.0, 0.0), (0.01, 0.1),
     r'^goal \(3\.0000, 0\.0000\) m is out of reach: r = 3\.0000 m > l1 \+ l2 - reach_margin '
     r'= 1\.8000 - 0\.01 = 1\.7900 m$'),
    ((0.1, 0.05), (0.01, 0.1),
     r'^goal \(0\.1000, 0\.0500\) m is too close to the base: r = 0\.1118 m < \|l1 - l2\| \+ '
     r'reach_margin = 0\.2000 \+ 0\.01 = 0\.2100 m$'),
    ((1.785, 0.0), (0.0, 0.3),
     r'^goal \(1\.7850, 0\.0000\) m is too near a singularity: \|sin q2\| = 0\.2571 < '
     r'singularity_margin 0\.3 \(r = 1\.7850 m; arm almost stretched\)$'),
    ((0.22, 0.0), (0.0, 0.3), r'too near a singularity: .* arm almost folded\)$'),
    ((math.nan, 1.0), (0.01, 0.1), r'^goal must be two finite numbers \(x, y\) in m, got '
                                   r'\[nan, 1\.0\]$'),
    ((1.0, 0.5, 0.0), (0.01, 0.1), r'^goal must be two finite numbers'),
])
def test_workspace_violation_names_the_numbers(p, margins, pattern):
    arm = TwoLinkArm()
    reason = arm.workspace_violation(p, *margins, what='goal')
    assert reason is not None and re.search(pattern, reason), reason


def test_workspace_violation_passes_points_inside_and_on_the_margins():
    arm = TwoLinkArm()
    assert arm.workspace_violation((1.0, 0.5), 0.01, 0.1) is None
    assert arm.workspace_violation((1.79, 0.0), 0.01, 0.0) is None, 'r = outer limit'
    assert arm.workspace_violation((0.0, -0.21), 0.01, 0.0) is None, 'r = inner limit'
    r = np.linspace(0.2, 1.8, 1001)
    assert np.allclose(arm.abs_sin_q2(r) ** 2 + arm.cos_q2(r) ** 2, 1.0)
    q2 = arm.inverse_kinematics(np.stack([r, 0 * r], -1), 'down')[:, 1]
    assert np.allclose(arm.abs_sin_q2(r), np.abs(np.sin(q2)), atol=1e-12)


# ---------------------------------------------------------------------- arguments, batching
_Q, _QD, _TAU = np.array([0.1, 0.2]), np.array([0.3, 0.4]), np.array([1.0, 2.0])
_NAN = float('nan')
_CHAIN2 = {'link_lengths': (1.0, 0.8), 'com_distances': (0.5, 0.4), 'link_masses': (2.0, 1.5),
           'link_inertias': (0.1, 0.08)}


@pytest.mark.parametrize('call, name', [
    (lambda: TwoLinkArm(link_masses=(0, 1)), 'link_masses'),
    (lambda: TwoLinkArm(link_lengths=(1.0,)), 'link_lengths'),
    (lambda: TwoLinkArm(com_distances=(0.5, -0.1)), 'com_distances'),
    (lambda: TwoLinkArm(gravity=_NAN), 'gravity'),
    (lambda: TwoLinkArm(joint_damping=(0.0, -1.0)), 'joint_damping'),
    (lambda: TwoLinkArm(link_inertias=(0.0, 0.0), com_distances=(0.5, 0.0)), 'link_inertias'),
    (lambda: TwoLinkArm().mass_matrix([_NAN, 0.0]), 'q'),
    (lambda: TwoLinkArm().mass_matrix([0.0, 0.0, 0.0]), 'q'),
    (lambda: TwoLinkArm().forward_dynamics([_NAN, 0.0], _QD, _TAU), 'q'),
    (lambda: TwoLinkArm().forward_dynamics(_Q, [0.0, math.inf], _TAU), 'qd'),
    (lambda: TwoLinkArm().forward_dynamics(_Q, _QD, [1.0]), 'tau'),
    (lambda: TwoLinkArm().inverse_dynamics(_Q, _QD, 'fast'), 'qdd'),
    (lambda: TwoLinkArm().coriolis_matrix(_Q, np.zeros(3)), 'qd'),
    (lambda: TwoLinkArm().step(_Q, _QD, _TAU, dt=0.0), 'dt'),
    (lambda: TwoLinkArm().energy(_Q, [_NAN, 0.0]), 'qd'),
    (lambda: TwoLinkArm().forward_kinematics([0.0, _NAN]), 'q'),
    (lambda: TwoLinkArm().jdot_qd(_Q, [0.0, 1.0, 2.0]), 'qd'),
    (lambda: TwoLinkArm().inverse_kinematics([1.0, _NAN], 'up'), 'p'),
    (lambda: TwoLinkArm().inverse_kinematics([1.0], 'up'), 'p'),
    (lambda: TwoLinkArm().inverse_kinematics([1.0, 0.5], 'left'), 'elbow'),
    (lambda: SingleLinkGeared(gear_ratio=0.0), 'gear_ratio'),
    (lambda: SingleLinkGeared(mass=-1.0), 'mass'),
    (lambda: SingleLinkGeared().forward_dynamics(_NAN, 0.0, 0.0), 'theta_m'),
    (lambda: SingleLinkGeared().forward_dynamics(0.0, 0.0, _NAN), 'u'),
    (lambda: simulate(model=TwoLinkArm(), q0=_Q, qd0=_QD, torque=_TAU, duration=1.0,
                      method='euler'), 'method'),
    (lambda: simulate(model=TwoLinkArm(), q0=[0.0], qd0=_QD, torque=_TAU, duration=1.0),
     'q0'),
    (lambda: planar_chain(**dict(_CHAIN2, com_distances=(0.5,))), 'com_distances'),
    (lambda: planar_chain(**dict(_CHAIN2, link_masses=(1.0, -1.0))), 'link_masses'),
    (lambda: planar_chain(**dict(_CHAIN2, link_lengths=())), 'link_lengths'),
    (lambda: planar_chain(**_CHAIN2, gravity=-9.81), 'gravity'),
    (lambda: planar_chain(**dict(_CHAIN2, link_inertias=(0.0, 0.0),
                                 com_distances=(0.5, 0.0))), 'link_inertias'),
    (lambda: planar_chain(**_CHAIN2).forward_dynamics([0.0, 0.0, 0.0], _QD, _TAU), 'q'),
    (lambda: planar_chain(**_CHAIN2).inverse_dynamics(_Q, [_NAN, 0.0], _TAU), 'qd'),
    (lambda: planar_chain(**_CHAIN2).forward_dynamics(_Q, _QD, np.ones((2, 2))), 'tau'),
    (lambda: planar_chain(**_CHAIN2).coriolis_matrix(_Q, 'x'), 'qd'),
    (lambda: LagrangianSystem('D', lambda q: 0.0, n_dof=1), 'mass_matrix'),
    (lambda: LagrangianSystem(lambda q: np.eye(1), None, n_dof=1), 'potential'),
    (lambda: LagrangianSystem(lambda q: np.eye(1), lambda q: 0.0, n_dof=0), 'n_dof'),
    (lambda: LagrangianSystem(lambda q: np.eye(1), lambda q: 0.0, n_dof=1,
                              joint_damping=(1.0, 2.0)), 'joint_damping'),
    (lambda: LagrangianSystem(lambda q: np.eye(2), lambda q: 0.0,
                              n_dof=1).mass_matrix([0.0]), 'mass_matrix'),
    (lambda: LagrangianSystem(lambda q: np.eye(1), lambda q: q,
                              n_dof=1).step([0.0], [0.0], [0.0], dt=-1.0), 'dt'),
    (lambda: spring_mass(1.0, 1.0).step([0.0], [0.0], [0.0], 1e-3, n_steps=2.5), 'n_steps'),
    (lambda: spring_mass(0.0, 1.0), 'mass'),
    (lambda: spring_mass(1.0, -1.0), 'stiffness'),
    (lambda: geared_link_lagrangian(gear_ratio=-2.0), 'gear_ratio'),
    (lambda: rnea(_Q, _QD, [_NAN, 0.0], **_CHAIN2), 'qdd'),
    (lambda: rnea([0.0], _QD, _TAU, **_CHAIN2), 'q'),
    (lambda: rnea(_Q, _QD, _TAU, **dict(_CHAIN2, link_inertias=(0.1,))), 'link_inertias'),
    (lambda: NewtonEulerChain(**_CHAIN2, joint_damping=(0.0, _NAN)), 'joint_damping'),
])
def test_bad_arguments_raise_value_error_naming_the_argument(call, name):
    with pytest.raises(ValueError, match=rf'\b{name}\b'):
        call()


def test_batched_calls_equal_per_state_calls():
    rng = np.random.default_rng(21)
    arm = TwoLinkArm(joint_damping=(0.2, 0.1))
    q, qd, x = (rng.uniform(-3.0, 3.0, (8, 2)) for _ in range(3))
    batched = {
        'mass_matrix': arm.mass_matrix(q),
        'coriolis_matrix': arm.coriolis_matrix(q, qd),
        'gravity_vector': arm.gravity_vector(q),
        'damping_torque': arm.damping_torque(qd),
        'forward_dynamics': arm.forward_dynamics(q, qd, x),
        'inverse_dynamics': arm.inverse_dynamics(q, qd, x),
        'forward_kinematics': arm.forward_kinematics(q),
        'jacobian': arm.jacobian(q),
        'jdot_qd': arm.jdot_qd(q, qd),
        'inverse_kinematics': arm.inverse_kinematics(x, 'up'),
        'energy': np.stack(arm.energy(q, qd), -1),
        'step': np.concatenate(arm.step(q, qd, x, 1e-3, 10), -1),
        'rnea': rnea(q, qd, x, **_CHAIN2, gravity=9.81),
    }
    for i in range(len(q)):
        single = {
            'mass_matrix': arm.mass_matrix(q[i]),
            'coriolis_matrix': arm.coriolis_matrix(q[i], qd[i]),
            'gravity_vector': arm.gravity_vector(q[i]),
            'damping_torque': arm.damping_torque(qd[i]),
            'forward_dynamics': arm.forward_dynamics(q[i], qd[i], x[i]),
            'inverse_dynamics': arm.inverse_dynamics(q[i], qd[i], x[i]),
            'forward_kinematics': arm.forward_kinematics(q[i]),
            'jacobian': arm.jacobian(q[i]),
            'jdot_qd': arm.jdot_qd(q[i], qd[i]),
            'inverse_kinematics': arm.inverse_kinematics(x[i], 'up'),
            'energy': np.array(arm.energy(q[i], qd[i])),
            'step': np.concatenate(arm.step(q[i], qd[i], x[i], 1e-3, 10)),
            'rnea': rnea(q[i], qd[i], x[i], **_CHAIN2, gravity=9.81),
        }
        for name, value in single.items():
            assert batched[name][i].shape == value.shape, f'{name}: batch row shape'
            # Single states take a pure-float (math) path, batches numpy: equal to 1e-12.
            np.testing.assert_allclose(batched[name][i], value, rtol=1e-12, atol=1e-12,
                                       err_msg=f'{name}: batch row {i} vs single call')


def test_batched_calls_broadcast_over_leading_shapes():
    arm = TwoLinkArm()
    q = np.zeros((3, 4, 2))
    assert arm.mass_matrix(q).shape == (3, 4, 2, 2)
    assert arm.forward_dynamics(q, np.zeros(2), np.zeros(2)).shape == (3, 4, 2)
    assert rnea(q, np.zeros(2), np.zeros(2), **_CHAIN2).shape == (3, 4, 2)
