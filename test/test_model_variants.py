"""The model variants of :class:`TwoLinkArm` a sweep builds: the arm carrying a payload at
its tip (:meth:`TwoLinkArm.with_payload`) and a controller's model with relative mass and
length errors (:meth:`TwoLinkArm.with_errors`), against hand-written formulas (pure)."""

from __future__ import annotations

import numpy as np
import pytest

from arm_dynamics.two_link import TwoLinkArm

RNG = np.random.default_rng(11)
ARMS = [TwoLinkArm(),
        TwoLinkArm(link_lengths=(0.7, 1.1), com_distances=(0.3, 0.6), link_masses=(3.0, 0.8),
                   link_inertias=(0.2, 0.05), gravity=9.5, joint_damping=(0.1, 0.3))]


def tip_point_mass_matrix(arm: TwoLinkArm, p: float, q: np.ndarray) -> np.ndarray:
    """D(q) of ``arm`` plus a point mass ``p`` at the tip, by hand: the point mass's
    kinetic energy is p |v_tip|^2 / 2 with v_tip = J q', so it adds p J^T J, with
    J^T J = [[l1^2 + l2^2 + 2 l1 l2 cos q2, l2^2 + l1 l2 cos q2],
             [l2^2 + l1 l2 cos q2,          l2^2]]."""
    l1, l2 = arm.link_lengths
    c2 = np.cos(q[1])
    jtj = np.array([[l1 * l1 + l2 * l2 + 2 * l1 * l2 * c2, l2 * l2 + l1 * l2 * c2],
                    [l2 * l2 + l1 * l2 * c2, l2 * l2]])
    return arm.mass_matrix(q) + p * jtj


@pytest.mark.parametrize('arm', ARMS)
def test_with_payload_zero_is_the_arm(arm):
    assert arm.with_payload(0) is arm
    assert arm.with_payload(0.0) == arm


@pytest.mark.parametrize('arm', ARMS)
def test_with_payload_is_the_arm_plus_a_point_mass_at_the_tip(arm):
    for p in (0.3, 1.0, 4.5):
        loaded = arm.with_payload(p)
        # link 1, the lengths, gravity and damping unchanged; link 2 heavier
        assert loaded.link_lengths == arm.link_lengths
        assert loaded.link_masses == (arm.link_masses[0], arm.link_masses[1] + p)
        assert (loaded.link_inertias[0], loaded.com_distances[0]) == (
            arm.link_inertias[0], arm.com_distances[0])
        assert (loaded.gravity, loaded.joint_damping) == (arm.gravity, arm.joint_damping)
        for q in RNG.uniform(-np.pi, np.pi, (5, 2)):
            want = tip_point_mass_matrix(arm, p, q)
            assert np.abs(loaded.mass_matrix(q) - want).max() <= 1e-12 * np.abs(want).max()
            # potential of the point mass: p g0 y_tip, so g gains p g0 d(y_tip)/dq
            l1, l2 = arm.link_lengths
            dy = np.array([l1 * np.cos(q[0]) + l2 * np.cos(q[0] + q[1]),
                           l2 * np.cos(q[0] + q[1])])
            want_g = arm.gravity_vector(q) + p * arm.gravity * dy
            assert np.abs(loaded.gravity_vector(q) - want_g).max() <= 1e-12 * max(
                1.0, np.abs(want_g).max())


def test_with_payload_uses_the_formulas_the_sweep_used():
    arm, p = TwoLinkArm(), 0.7
    (_, l2), (_, c2) = arm.link_lengths, arm.com_distances
    m2, i2 = arm.link_masses[1], arm.link_inertias[1]
    c = (m2 * c2 + p * l2) / (m2 + p)
    loaded = arm.with_payload(p)
    assert loaded.com_distances[1] == c
    assert loaded.link_inertias[1] == i2 + m2 * (c - c2) ** 2 + p * (l2 - c) ** 2


@pytest.mark.parametrize('arm', ARMS)
def test_with_errors_zero_is_the_arm(arm):
    assert arm.with_errors(0, 0) is arm
    assert arm.with_errors(0.0, 0.0) == arm


@pytest.mark.parametrize('arm', ARMS)
def test_with_errors_scales_masses_lengths_and_inertias(arm):
    em, el = 0.2, -0.1
    m, s = 1.0 + em, 1.0 + el
    wrong = arm.with_errors(em, el)
    assert wrong == TwoLinkArm(
        link_lengths=tuple(s * v for v in arm.link_lengths),
        com_distances=tuple(s * v for v in arm.com_distances),
        link_masses=tuple(m * v for v in arm.link_masses),
        link_inertias=tuple(m * s * s * v for v in arm.link_inertias),
        gravity=arm.gravity, joint_damping=arm.joint_damping)
    # every body scaled alike: D scales by m s^2, g by m s
    for q in RNG.uniform(-np.pi, np.pi, (5, 2)):
        want_d = m * s * s * arm.mass_matrix(q)
        assert np.abs(wrong.mass_matrix(q) - want_d).max() <= 1e-12 * np.abs(want_d).max()
        want_g = m * s * arm.gravity_vector(q)
        assert np.abs(wrong.gravity_vector(q) - want_g).max() <= 1e-12 * max(
            1.0, np.abs(want_g).max())
    # one error alone
    assert arm.with_errors(em, 0.0).link_lengths == arm.link_lengths
    assert arm.with_errors(0.0, el).link_masses == arm.link_masses


def test_bad_payloads_and_errors_are_refused_naming_them():
    arm = TwoLinkArm()
    with pytest.raises(ValueError, match='mass must be >= 0'):
        arm.with_payload(-0.1)
    with pytest.raises(ValueError, match='mass must be finite'):
        arm.with_payload(float('nan'))
    with pytest.raises(ValueError, match='mass_error must be > -1'):
        arm.with_errors(-1.0, 0.0)
    with pytest.raises(ValueError, match='length_error must be finite'):
        arm.with_errors(0.0, float('inf'))
