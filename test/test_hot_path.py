"""The single-state hot paths of TwoLinkArm (issue 14): same numbers, same validation.

``test/data/two_link_reference.npz`` holds the results of ``forward_dynamics``,
``inverse_dynamics``, ``step`` and a 2000-step PD closed loop at 500 random states, computed
with the implementation before the hot paths were rewritten (arm with joint damping
(0.3, 0.2) N m s/rad; q in [-pi, pi] rad, qd in [-5, 5] rad/s, tau in [-50, 50] N m).
Speed is measured in bench/bench_dynamics.py, never here.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from arm_dynamics.two_link import TwoLinkArm, _make_accel, _make_inverse, _rk4

REF = np.load(Path(__file__).parent / 'data' / 'two_link_reference.npz')
ARM = TwoLinkArm(joint_damping=(0.3, 0.2))
KP, KD = np.array([50.0, 30.0]), np.array([10.0, 6.0])
Q_GOAL = np.array([math.pi / 4, math.pi / 3])
TOL = dict(rtol=1e-15, atol=1e-15)


def _rows(name: str) -> list[np.ndarray]:
    return list(REF[name])


def test_forward_dynamics_matches_the_saved_reference() -> None:
    out = np.array([ARM.forward_dynamics(q, qd, t)
                    for q, qd, t in zip(_rows('q'), _rows('qd'), _rows('tau'))])
    np.testing.assert_allclose(out, REF['fd'], **TOL)


def test_inverse_dynamics_matches_the_saved_reference() -> None:
    out = np.array([ARM.inverse_dynamics(q, qd, a)
                    for q, qd, a in zip(_rows('q'), _rows('qd'), _rows('fd'))])
    np.testing.assert_allclose(out, REF['inv'], **TOL)


@pytest.mark.parametrize('dt, n, key', [(1e-3, 1, 'step1'), (2e-3, 3, 'step3')])
def test_step_matches_the_saved_reference(dt: float, n: int, key: str) -> None:
    out = [ARM.step(q, qd, t, dt, n) for q, qd, t in zip(_rows('q'), _rows('qd'), _rows('tau'))]
    np.testing.assert_allclose(np.array([q for q, _ in out]), REF[f'{key}_q'], **TOL)
    np.testing.assert_allclose(np.array([qd for _, qd in out]), REF[f'{key}_qd'], **TOL)


def test_closed_loop_matches_the_saved_reference() -> None:
    """2000 PD + RK4 steps from rest hanging down (errors could only grow along the run)."""
    q, qd = np.array([-math.pi / 2, 0.0]), np.zeros(2)
    traj = []
    for _ in range(len(REF['loop'])):
        q, qd = ARM.step(q, qd, KP * (Q_GOAL - q) - KD * qd, 1e-3)
        traj.append(np.r_[q, qd])
    np.testing.assert_allclose(np.array(traj), REF['loop'], rtol=1e-13, atol=1e-13)


def test_fast_paths_are_bit_identical_to_the_generic_formulas() -> None:
    """Independent of the saved file: the inlined single-state code against the generic
    formula functions (:func:`_make_accel`, :func:`_make_inverse`, :func:`_rk4`) evaluated
    with ``math`` functions, at every reference state."""
    acc = _make_accel(ARM._k, math.cos, math.sin)
    inv = _make_inverse(ARM._k, math.cos, math.sin)
    for q, qd, t in zip(_rows('q'), _rows('qd'), _rows('tau')):
        x = (*q.tolist(), *qd.tolist(), *t.tolist())
        assert ARM.forward_dynamics(q, qd, t).tolist() == list(acc(*x))
        assert ARM.inverse_dynamics(q, qd, t).tolist() == list(inv(*x))
        for dt, n in ((1e-3, 1), (5e-4, 4)):
            sq, sqd = ARM.step(q, qd, t, dt, n)
            assert [*sq.tolist(), *sqd.tolist()] == list(_rk4(acc, x, dt, n))


def test_every_input_form_gives_the_same_numbers() -> None:
    """(2,) float arrays (hot path), tuples, lists, int arrays and a batch agree."""
    q, qd, t = REF['q'][:50], REF['qd'][:50], REF['tau'][:50]
    batch = ARM.forward_dynamics(q, qd, t)
    bq, bqd = ARM.step(q, qd, t, 1e-3)
    for i in range(50):
        hot = ARM.forward_dynamics(q[i], qd[i], t[i])
        assert hot.shape == (2,) and hot.dtype == np.float64
        assert hot.tolist() == ARM.forward_dynamics(tuple(q[i]), list(qd[i]),
                                                    tuple(t[i])).tolist()
        np.testing.assert_allclose(hot, batch[i], rtol=1e-12, atol=1e-12)
        sq, sqd = ARM.step(q[i], qd[i], t[i], 1e-3)
        np.testing.assert_allclose(sq, bq[i], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(sqd, bqd[i], rtol=1e-12, atol=1e-12)
    ints = np.array([1, 2]), np.array([-3, 4]), np.array([5, -6])
    floats = [a.astype(float) for a in ints]
    assert ARM.forward_dynamics(*ints).tolist() == ARM.forward_dynamics(*floats).tolist()
    assert ARM.inverse_dynamics(*ints).tolist() == ARM.inverse_dynamics(*floats).tolist()
    for a, b in zip(ARM.step(*ints, 1e-3), ARM.step(*floats, 1e-3)):
        assert a.tolist() == b.tolist()
    for a, b in zip(ARM.step(*floats, 1e-3, np.int64(2)), ARM.step(*floats, 1e-3, 2)):
        assert a.tolist() == b.tolist()
    for a, b in zip(ARM.step(*floats, np.float64(1e-3)), ARM.step(*floats, 1e-3)):
        assert a.tolist() == b.tolist()


@pytest.mark.parametrize('bad', [math.inf, -math.inf, math.nan])
@pytest.mark.parametrize('slot', [0, 1, 2])
@pytest.mark.parametrize('method', ['forward_dynamics', 'inverse_dynamics', 'step'])
def test_non_finite_inputs_are_refused_by_name(bad: float, slot: int, method: str) -> None:
    names = ('q', 'qd', 'qdd' if method == 'inverse_dynamics' else 'tau')
    for component in (0, 1):
        args = [np.array([0.3, -0.2]), np.array([0.1, 0.4]), np.array([1.0, -2.0])]
        args[slot][component] = bad
        extra = (1e-3,) if method == 'step' else ()
        with pytest.raises(ValueError, match=f'^{names[slot]} must be finite'):
            getattr(ARM, method)(*args, *extra)


@pytest.mark.parametrize('shape', [(1, 2), (2, 1), (3,), (1,), ()])
def test_wrong_shapes_leave_the_hot_path(shape: tuple[int, ...]) -> None:
    """Not (2,): the validating path decides (a batch broadcasts, the rest is refused)."""
    good = np.array([0.1, 0.2])
    bad = np.full(shape, 0.5)
    for method in (ARM.forward_dynamics, ARM.inverse_dynamics):
        if shape and shape[-1] == 2:
            assert method(bad, good, good).shape == (1, 2)
        else:
            with pytest.raises(ValueError, match='q must have shape'):
                method(bad, good, good)


@pytest.mark.parametrize('dt', [0.0, -1e-3, math.inf, math.nan, 'x', None])
def test_step_refuses_bad_dt(dt: object) -> None:
    z = np.zeros(2)
    with pytest.raises(ValueError, match='dt must be'):
        ARM.step(z, z, z, dt)  # type: ignore[arg-type]


@pytest.mark.parametrize('n', [0, -1, True, 1.0, 2.5, None])
def test_step_refuses_bad_n_steps(n: object) -> None:
    z = np.zeros(2)
    with pytest.raises(ValueError, match='n_steps must be an integer'):
        ARM.step(z, z, z, 1e-3, n)  # type: ignore[arg-type]


def test_overflowing_finite_inputs_still_return_the_old_values() -> None:
    """Finite inputs whose result overflows take the validating path and give what it gives
    (inf/nan, no error), and a step that diverges returns NaN."""
    z = np.zeros(2)
    huge = np.array([1e300, -1e300])
    with np.errstate(all='ignore'):
        out = ARM.forward_dynamics(np.array([0.3, 0.4]), huge, z)
        assert not np.isfinite(out).all()
        assert ARM.forward_dynamics(np.array([0.3, 0.4]), tuple(huge), z).tolist() == \
            pytest.approx(out.tolist(), nan_ok=True)
        q, qd = ARM.step(np.array([0.3, 0.4]), huge, z, 1e-3, 50)
    assert np.isnan(q).all() and np.isnan(qd).all()


def test_step_floats_gives_the_bits_of_step_and_the_saved_reference() -> None:
    for dt, n, key in ((1e-3, 1, 'step1'), (2e-3, 3, 'step3')):
        for i, (q, qd, t) in enumerate(zip(_rows('q'), _rows('qd'), _rows('tau'))):
            out = ARM.step_floats(*q.tolist(), *qd.tolist(), *t.tolist(), dt, n)
            sq, sqd = ARM.step(q, qd, t, dt, n)
            assert list(out) == [*sq.tolist(), *sqd.tolist()]
            np.testing.assert_allclose(out, np.r_[REF[f'{key}_q'][i], REF[f'{key}_qd'][i]],
                                       **TOL)


@pytest.mark.parametrize('slot, name', list(enumerate(('q1', 'q2', 'qd1', 'qd2', 'tau1',
                                                        'tau2'))))
@pytest.mark.parametrize('bad, words', [(math.nan, 'must be finite'),
                                        (math.inf, 'must be finite'),
                                        ('x', 'must be a number'),
                                        (np.array([1.0, 2.0]), 'must be a number')])
def test_step_floats_refuses_a_bad_state_by_name(slot: int, name: str, bad: object,
                                                 words: str) -> None:
    args: list[object] = [0.3, -0.2, 0.1, 0.4, 1.0, -2.0]
    args[slot] = bad
    with pytest.raises(ValueError, match=f'^{name} {words}'):
        ARM.step_floats(*args, 1e-3)  # type: ignore[arg-type]


@pytest.mark.parametrize('dt, n, words', [(0.0, 1, 'dt must be > 0'),
                                          (math.inf, 1, 'dt must be finite'),
                                          ('x', 1, 'dt must be a number'),
                                          (1e-3, 0, 'n_steps must be an integer'),
                                          (1e-3, 1.0, 'n_steps must be an integer')])
def test_step_floats_refuses_bad_dt_and_n_steps(dt: object, n: object, words: str) -> None:
    with pytest.raises(ValueError, match=words):
        ARM.step_floats(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, dt, n)  # type: ignore[arg-type]


def test_step_floats_returns_nan_for_a_state_that_diverges_within_the_call() -> None:
    out = ARM.step_floats(0.3, 0.4, 1e300, -1e300, 0.0, 0.0, 1e-3, 50)
    assert all(math.isnan(x) for x in out)


def test_the_instance_hot_paths_give_the_bits_of_the_validating_methods() -> None:
    """``arm.forward_dynamics``/``inverse_dynamics`` are per-arm closures that shadow the
    methods; the methods (the fall-backs) must give the same bits."""
    for q, qd, t in zip(_rows('q')[:100], _rows('qd')[:100], _rows('tau')[:100]):
        assert ARM.forward_dynamics(q, qd, t).tolist() == \
            TwoLinkArm.forward_dynamics(ARM, q, qd, t).tolist()
        assert ARM.inverse_dynamics(q, qd, t).tolist() == \
            TwoLinkArm.inverse_dynamics(ARM, q, qd, t).tolist()
    assert ARM.forward_dynamics.__doc__ == TwoLinkArm.forward_dynamics.__doc__


def test_an_arm_pickles_and_its_copy_computes_the_same() -> None:
    import pickle

    copy = pickle.loads(pickle.dumps(ARM))
    assert copy == ARM
    q, qd, t = _rows('q')[0], _rows('qd')[0], _rows('tau')[0]
    assert copy.forward_dynamics(q, qd, t).tolist() == ARM.forward_dynamics(q, qd, t).tolist()
