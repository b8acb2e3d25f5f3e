"""Coulomb and static joint friction (:mod:`arm_dynamics.friction`), pure.

Every behaviour is checked against something the module does not share: closed forms (a
single link under constant torque: constant accelerations), a bit-level comparison with the
frictionless ``model.step``, an event-driven DOP853 reference written here from the models'
``mass_matrix``, ``coriolis_matrix``, ``gravity_vector`` and ``damping_torque`` (the module
uses inverse-dynamics differences and the model's RK4) with its own mode decision (it
enumerates every stick/slip combination instead of releasing the most overloaded joint
first), and the energy balance of the whole run. Tolerances are stated where they are used,
with what they measured when written.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from arm_dynamics.friction import (
    EVENT_TOLERANCE,
    JointFriction,
    friction_step,
    friction_step_batch,
    static_friction_problem,
    static_friction_used,
)
from arm_dynamics.planar_chain import PlanarChain
from arm_dynamics.two_link import TwoLinkArm, TwoLinkBatch

DT = 1e-3
ARM = TwoLinkArm()
DAMPED = TwoLinkArm(joint_damping=(0.2, 0.1))
CHAIN = PlanarChain(link_lengths=(1.0, 0.8, 0.6), com_distances=(0.5, 0.4, 0.3),
                    link_masses=(2.0, 1.5, 1.0), link_inertias=(0.1, 0.08, 0.05),
                    joint_damping=(0.2, 0.1, 0.05))
FR2 = JointFriction(coulomb=[2.0, 1.0], static=[3.0, 1.5])
FR3 = JointFriction(coulomb=[2.0, 1.0, 0.5], static=[3.0, 1.5, 0.8])
Q2 = np.array([-0.4, 1.2])
Q3 = np.array([-0.4, 1.2, -0.5])


def run(model, friction, q0, qd0, torque, steps, locked=None):
    """``steps`` friction steps of DT; ``torque(k, q, qd)`` is held over step k. Returns
    q, qd (steps + 1, n), stuck (steps + 1, n), work (steps,), tau (steps, n)."""
    n = model.n_dof
    q, qd = np.array(q0, dtype=float), np.array(qd0, dtype=float)
    stuck = np.zeros(n, dtype=bool)
    qs, qds, sts = [q], [qd], [stuck]
    works, taus = [], []
    for k in range(steps):
        tau = np.asarray(torque(k, q, qd), dtype=float)
        q, qd, stuck, w = friction_step(model, q, qd, tau, DT, stuck, friction, locked)
        qs.append(q)
        qds.append(qd)
        sts.append(stuck)
        works.append(w)
        taus.append(tau)
    return np.array(qs), np.array(qds), np.array(sts), np.array(works), np.array(taus)


def bits(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64).view(np.int64)


# ------------------------------------------------------------------ 1. at rest in band
@pytest.mark.parametrize('model, friction, q0', [(ARM, FR2, Q2), (CHAIN, FR3, Q3)],
                         ids=['two_link', 'chain3'])
def test_a_net_torque_inside_the_static_band_moves_nothing_for_10_s(model, friction, q0):
    # Gravity compensated, plus 95% of the static friction on every joint (alternating
    # signs): 10 s of 1 ms steps. Tolerance: none -- the positions are the same bits.
    n = model.n_dof
    extra = 0.95 * friction.static * np.array([1.0, -1.0, 1.0][:n])
    tau = model.gravity_vector(q0) + extra
    q, qd, stuck, work, _ = run(model, friction, q0, np.zeros(n), lambda k, q, qd: tau,
                                10_000)
    assert (bits(q) == bits(q0)).all(), np.abs(q - q0).max()   # drift exactly 0, < 1e-9
    assert (qd == 0.0).all()
    assert stuck[1:].all()
    assert (work == 0.0).all()


def test_an_arm_hanging_where_gravity_is_inside_the_band_stays_put():
    # No torque at all, near the hanging pose: gravity's torque itself is in the band.
    q0 = np.array([-math.pi / 2 + 0.05, 0.1])
    assert (np.abs(ARM.gravity_vector(q0)) < FR2.static).all(), ARM.gravity_vector(q0)
    q, qd, stuck, _, _ = run(ARM, FR2, q0, [0.0, 0.0], lambda k, q, qd: np.zeros(2), 2000)
    assert (bits(q) == bits(q0)).all() and (qd == 0.0).all() and stuck[1:].all()
    # ... and from a small swing it comes to rest and stays (the last 0.5 s identical).
    q, qd, stuck, _, _ = run(ARM, FR2, q0, [0.5, -0.3], lambda k, q, qd: np.zeros(2), 3000)
    assert stuck[-500:].all() and (qd[-500:] == 0.0).all()
    assert (bits(q[-500:]) == bits(q[-1])).all()


# ------------------------------------------------------------------ 2. event-driven reference
class Reference:
    """Event-located DOP853 (rtol = atol = 1e-12) of the piecewise dynamics, written
    independently: D from ``mass_matrix``, the bias from ``coriolis_matrix``,
    ``gravity_vector`` and ``damping_torque``; terminal events at a slipping joint's zero
    velocity and a stuck joint's holding torque reaching its static friction; the mode at
    a switch chosen by enumerating every stick/slip combination of the joints at rest and
    keeping the consistent one with the most joints stuck."""

    def __init__(self, model, friction):
        self.model, self.n = model, model.n_dof
        self.c, self.s = friction.coulomb, friction.static

    def parts(self, q, qd, tau, stuck, sigma):
        m = self.model
        d = m.mass_matrix(q)
        r = (tau - self.c * sigma - m.coriolis_matrix(q, qd) @ qd - m.gravity_vector(q)
             - m.damping_torque(qd))
        free, held = np.flatnonzero(~stuck), np.flatnonzero(stuck)
        qdd = np.zeros(self.n)
        if free.size:
            qdd[free] = np.linalg.solve(d[np.ix_(free, free)], r[free])
        lam = d[np.ix_(held, free)] @ qdd[free] - r[held]
        return qdd, lam

    def decide(self, q, qd, tau):
        rest = [i for i in range(self.n) if qd[i] == 0.0]
        best = None
        for choice in itertools.product((0.0, 1.0, -1.0), repeat=len(rest)):
            stuck = np.zeros(self.n, dtype=bool)
            sigma = np.sign(qd)
            for i, ch in zip(rest, choice):
                stuck[i] = ch == 0.0
                sigma[i] = ch
            qdd, lam = self.parts(q, qd, tau, stuck, sigma)
            held = np.flatnonzero(stuck)
            ok = all(abs(lam[k]) <= self.s[i] for k, i in enumerate(held))
            ok = ok and all(ch == 0.0 or ch * qdd[i] > 0.0 for i, ch in zip(rest, choice))
            if ok and (best is None or stuck.sum() > best[0].sum()):
                best = (stuck, sigma)
        assert best is not None, f'no consistent mode at q={q}, qd={qd}'
        return best

    def run(self, q0, segments, t_end, grid):
        """``segments``: [(t_start, tau)], torque held from each start. Returns q at the
        ``grid`` times (len(grid), n) and the events [(t, joint, kind)], kind in 'stick',
        'slip' (break-away), 'reverse'."""
        from scipy.integrate import solve_ivp
        n = self.n
        y = np.concatenate([np.asarray(q0, float), np.zeros(n)])
        out = np.full((len(grid), n), np.nan)
        events = []
        bounds = [s[0] for s in segments[1:]] + [t_end]
        t = 0.0
        stuck_before = np.zeros(n, dtype=bool)
        for (_, tau), t_stop in zip(segments, bounds):
            tau = np.asarray(tau, float)
            while t < t_stop:
                q, qd = y[:n], y[n:].copy()
                stuck, sigma = self.decide(q, qd, tau)
                for i in range(n):
                    if stuck_before[i] and not stuck[i]:
                        events.append((t, i, 'slip'))
                    if not stuck_before[i] and stuck[i] and t > 0.0:
                        events.append((t, i, 'stick'))
                stuck_before = stuck

                def rhs(_t, x, tau=tau, stuck=stuck, sigma=sigma):
                    qdd, _ = self.parts(x[:n], x[n:], tau, stuck, sigma)
                    v = x[n:].copy()
                    v[stuck] = 0.0
                    return np.concatenate([v, qdd])

                fns = []
                for i in range(n):
                    if stuck[i]:
                        def f(_t, x, i=i, tau=tau, stuck=stuck, sigma=sigma):
                            _, lam = self.parts(x[:n], x[n:], tau, stuck, sigma)
                            return self.s[i] - abs(lam[list(np.flatnonzero(stuck)).index(i)])
                    elif sigma[i] != 0.0:
                        def f(_t, x, i=i, sg=sigma[i]):
                            return sg * x[n + i]
                    else:
                        continue
                    f.terminal, f.direction = True, -1
                    fns.append((i, stuck[i], f))
                sol = solve_ivp(rhs, (t, t_stop), y, method='DOP853', rtol=1e-12,
                                atol=1e-12, dense_output=True, events=[f for *_, f in fns])
                assert sol.success, sol.message
                t_new = sol.t[-1]
                sel = (grid > t - 1e-15) & (grid <= t_new + 1e-15)
                if sel.any():
                    out[sel] = sol.sol(grid[sel])[:n].T
                y = sol.y[:, -1].copy()
                if sol.status == 1:   # an event
                    for (i, was_stuck, _), te in zip(fns, sol.t_events):
                        if te.size and not was_stuck:
                            y[n + i] = 0.0
                            events.append((t_new, i, 'zero'))
                t = t_new
        # A velocity zero is a stick or a reversal, by what the next mode did.
        resolved = []
        for k, (te, i, kind) in enumerate(events):
            if kind == 'zero':
                stuck_next = any(e[1] == i and e[2] == 'stick' and abs(e[0] - te) < 1e-12
                                 for e in events[k + 1:])
                if not stuck_next:
                    resolved.append((te, i, 'reverse'))
            else:
                resolved.append((te, i, kind))
        return out, resolved


def module_events(qd, stuck):
    """[(t_end_of_step, joint, kind)] from the recorded steps: a stuck flag set (stick) or
    cleared (slip), a velocity changing sign between two slipping states (reverse)."""
    events = []
    for k in range(1, len(stuck)):
        for i in range(stuck.shape[1]):
            if stuck[k, i] and not stuck[k - 1, i] and k > 1:
                events.append((k * DT, i, 'stick'))
            elif stuck[k - 1, i] and not stuck[k, i]:
                events.append((k * DT, i, 'slip'))
            elif qd[k, i] * qd[k - 1, i] < 0.0:
                events.append((k * DT, i, 'reverse'))
    return events


#: A stepped torque on the damped 2-R arm near its hanging pose: inside the band (stuck),
#: then a push that breaks both joints away (slip), joint 2 sticks, joint 1 stops and
#: sticks, an opposite push (second break-away), a reversal with joint 2 stuck.
Q_HANG = np.array([-math.pi / 2 + 0.1, 0.2])
SEGMENTS = [(0.0, DAMPED.gravity_vector(Q_HANG) + [2.0, -1.0]), (0.3, [12.0, 0.5]),
            (1.5, [-8.0, -1.0])]


def stepped(k, q, qd):
    t = k * DT
    return [tau for t0, tau in SEGMENTS if t0 <= t + 1e-12][-1]


def test_stick_slip_motion_matches_an_event_located_dop853_reference():
    steps = 3000
    q, qd, stuck, _, _ = run(DAMPED, FR2, Q_HANG, [0.0, 0.0], stepped, steps)
    grid = np.arange(steps + 1) * DT
    ref_q, ref_events = Reference(DAMPED, FR2).run(Q_HANG, SEGMENTS, steps * DT, grid)
    err = np.abs(q - ref_q).max()
    # RK4 at 1 ms, events located to 1e-12 s: measured 1.6e-11 rad (2026-11-25).
    assert err < 1e-6, err
    got = module_events(qd, stuck)
    kinds = [(i, kind) for _, i, kind in got]
    assert kinds == [(i, kind) for _, i, kind in ref_events], (got, ref_events)
    # The scenario has what it promises.
    assert kinds.count((0, 'slip')) == 2 and (0, 'stick') in kinds and (1, 'stick') in kinds
    assert (0, 'reverse') in kinds
    for (t_mod, _, _), (t_ref, _, _) in zip(got, ref_events):
        # Each instant inside the step the module reports it in (within one step).
        assert t_mod - DT - 1e-12 <= t_ref <= t_mod + 1e-12, (t_mod, t_ref)


def test_chain_of_three_matches_the_reference_through_break_away_and_stick():
    # The 3-link chain: in band, then a push breaks joints 1 and 2 away; joint 2 sticks
    # again while joint 1 keeps going; joint 3 holds throughout (0.6 s).
    steps = 600
    q0 = np.array([-math.pi / 2 + 0.1, 0.2, -0.1])
    segments = [(0.0, CHAIN.gravity_vector(q0) + [1.0, -0.5, 0.3]),
                (0.1, CHAIN.gravity_vector(q0) + [6.0, 0.0, 0.0])]

    def torque(k, q, qd):
        return [tau for t0, tau in segments if t0 <= k * DT + 1e-12][-1]

    q, qd, stuck, _, _ = run(CHAIN, FR3, q0, np.zeros(3), torque, steps)
    grid = np.arange(steps + 1) * DT
    ref_q, ref_events = Reference(CHAIN, FR3).run(q0, segments, steps * DT, grid)
    err = np.abs(q - ref_q).max()
    assert err < 1e-6, err   # measured 1.1e-11 rad
    got = module_events(qd, stuck)
    assert [(i, k) for _, i, k in got] == [(i, k) for _, i, k in ref_events], (got, ref_events)
    assert any(k == 'slip' for _, _, k in got) and any(k == 'stick' for _, _, k in got)
    for (t_mod, _, _), (t_ref, _, _) in zip(got, ref_events):
        assert t_mod - DT - 1e-12 <= t_ref <= t_mod + 1e-12, (t_mod, t_ref)


# ------------------------------------------------------------------ 3. closed form
LINK = PlanarChain(link_lengths=(1.0,), com_distances=(0.5,), link_masses=(2.0,),
                   link_inertias=(0.1,), gravity=0.0)
I_EFF = 2.0 * 0.5**2 + 0.1   # kg m^2 about the joint
FR1 = JointFriction(coulomb=[2.0], static=[3.0])


def test_single_link_pushed_beyond_static_accelerates_at_tau_minus_c_then_stops_on_time():
    # N m > s = 3; 0.4 s of push, then none: it stops at 1.02468 s, inside a step.
    tau, push = 5.1234, 400
    q, qd, stuck, work, _ = run(LINK, FR1, [0.0], [0.0],
                                lambda k, q, qd: [tau if k < push else 0.0], 1500)
    t = np.arange(push + 1) * DT
    a = (tau - 2.0) / I_EFF
    # Constant acceleration: RK4 is exact for it, so only rounding: 1e-12 (measured 3e-16
    # rad, 2e-15 rad/s).
    assert np.abs(q[: push + 1, 0] - 0.5 * a * t**2).max() < 1e-12
    assert np.abs(qd[: push + 1, 0] - a * t).max() < 1e-12
    assert not stuck[1: push + 1].any()
    # Released: decelerates at c / I, stops at the predicted time and place, stays stuck.
    v1, q1, decel = a * t[-1], 0.5 * a * t[-1] ** 2, 2.0 / I_EFF
    t_stop = t[-1] + v1 / decel
    q_stop = q1 + v1**2 / (2.0 * decel)
    k_stop = int(np.argmax(stuck[:, 0]))
    assert (k_stop - 1) * DT < t_stop <= k_stop * DT
    assert abs(q[k_stop, 0] - q_stop) < 1e-9, q[k_stop, 0] - q_stop   # measured 9e-15 rad
    tk = np.arange(push, k_stop) * DT
    assert np.abs(qd[push:k_stop, 0] - (v1 - decel * (tk - t[-1]))).max() < 1e-10
    assert stuck[k_stop:].all() and (qd[k_stop:] == 0.0).all()
    assert (bits(q[k_stop:]) == bits(q[k_stop])).all()
    # The friction took c * distance, exactly the kinetic energy the push left over.
    assert abs(work.sum() - 2.0 * q_stop) < 1e-9


def test_a_torque_between_coulomb_and_static_does_not_start_a_joint_at_rest():
    # 2.5 N m: above Coulomb (2), below static (3): it stays (the stiction band).
    q, qd, stuck, _, _ = run(LINK, FR1, [0.3], [0.0], lambda k, q, qd: [2.5], 500)
    assert (q == 0.3).all() and (qd == 0.0).all() and stuck[1:].all()
    # ... but once slipping, the same torque keeps it going, accelerating at (2.5 - 2) / I.
    q, qd, stuck, _, _ = run(LINK, FR1, [0.0], [1.0], lambda k, q, qd: [2.5], 500)
    assert not stuck.any()
    assert abs(qd[-1, 0] - (1.0 + 0.5 / I_EFF * 0.5)) < 1e-12


def test_exactly_the_static_friction_holds_and_one_ulp_more_breaks_away():
    # Gravity 0, so the holding torque is exactly -tau: the band is closed, |lambda| <= s.
    stay = friction_step(LINK, np.array([0.2]), np.array([0.0]), np.array([3.0]), DT,
                         np.array([True]), FR1)
    assert stay[0][0] == 0.2 and stay[1][0] == 0.0 and stay[2][0] and stay[3] == 0.0
    go = friction_step(LINK, np.array([0.2]), np.array([0.0]),
                       np.array([np.nextafter(3.0, 4.0)]), DT, np.array([True]), FR1)
    assert go[1][0] > 0.0 and not go[2][0]
    # ... and slips against Coulomb friction from the start of the step: exactly
    # a = (tau - c) / I over the step (RK4 on a constant acceleration: 1e-15 relative).
    assert go[1][0] == pytest.approx((np.nextafter(3.0, 4.0) - 2.0) / I_EFF * DT, rel=1e-14)
    back = friction_step(LINK, np.array([0.2]), np.array([0.0]),
                         np.array([-np.nextafter(3.0, 4.0)]), DT, np.array([True]), FR1)
    assert back[1][0] < 0.0 and back[0][0] < 0.2


def test_stop_instant_is_located_to_the_event_tolerance():
    # One step containing the stop: the position the step returns is the closed-form stop.
    v0 = 0.00123   # rad/s; decel c / I = 3.33 rad/s^2 stops it after 0.369 ms, mid-step
    q, qd, stuck, work = friction_step(LINK, np.array([0.0]), np.array([v0]),
                                       np.array([0.0]), DT, np.array([False]), FR1)
    decel = 2.0 / I_EFF
    assert stuck[0] and qd[0] == 0.0
    # Position error of a stop found within EVENT_TOLERANCE: v * dt_err ~ 1e-14.
    assert abs(q[0] - v0**2 / (2.0 * decel)) < 1e-15 + v0 * EVENT_TOLERANCE
    assert abs(work - 2.0 * q[0]) < 1e-18


# ------------------------------------------------------------------ 4. no chatter
def test_a_torque_just_below_static_shows_zero_velocity_in_every_step():
    tau = ARM.gravity_vector(Q2) + np.nextafter(FR2.static, 0.0) * np.array([1.0, -1.0])
    tau = tau - 1e-9 * np.sign(tau - ARM.gravity_vector(Q2))   # just inside the band
    q, qd, stuck, _, _ = run(ARM, FR2, Q2, [0.0, 0.0], lambda k, q, qd: tau, 2000)
    assert (qd == 0.0).all() and stuck[1:].all()
    assert (bits(q) == bits(Q2)).all()


def test_a_torque_oscillating_inside_the_band_never_moves_the_joint():
    g = ARM.gravity_vector(Q2)

    def torque(k, q, qd):
        t = k * DT
        return g + 0.98 * FR2.static * np.array([math.sin(2 * math.pi * 7 * t),
                                                 math.cos(2 * math.pi * 3 * t)])

    q, qd, stuck, _, _ = run(ARM, FR2, Q2, [0.0, 0.0], torque, 2000)
    assert (qd == 0.0).all() and stuck[1:].all() and (bits(q) == bits(Q2)).all()


def test_a_stuck_joint_does_not_creep_while_the_other_swings():
    # Joint 2 hangs from a fixed joint 1 and swings; joint 1 holds with a torque in band.
    q0 = np.array([-0.4, 1.2])
    fr = JointFriction(coulomb=[20.0, 0.1], static=[40.0, 0.2])
    tau = ARM.gravity_vector(q0) * [1.0, 0.0]
    q, qd, stuck, _, _ = run(ARM, fr, q0, [0.0, 0.0], lambda k, q, qd: tau, 1000)
    assert stuck[1:, 0].all() and (qd[:, 0] == 0.0).all()
    assert (bits(q[:, 0]) == bits(q0[0])).all()
    assert np.ptp(q[:, 1]) > 0.5   # joint 2 swung


# ------------------------------------------------------------------ 5. energy
@pytest.mark.parametrize('model', [ARM, DAMPED], ids=['undamped', 'damped'])
def test_energy_change_is_input_work_minus_damping_minus_friction_work(model):
    steps = 3000
    q, qd, stuck, work, tau = run(model, FR2, Q_HANG, [0.0, 0.0], stepped, steps)
    assert (work >= 0.0).all()
    kinetic, potential = model.energy(q, qd)
    energy = kinetic + potential
    w_in = np.einsum('ki,ki->k', tau, np.diff(q, axis=0))
    b = np.asarray(model.joint_damping)
    power = np.einsum('ki,i,ki->k', qd, b, qd)
    # Damping work by Simpson's rule over pairs of steps (O(dt^4) on smooth stretches;
    # the kinks are at zero velocity, where the damping power and its slope are zero).
    w_damp = DT / 3.0 * (power[0:-1:2] + 4.0 * power[1::2] + power[2::2])
    balance = (energy[2::2] - energy[0]) - (np.cumsum(w_in)[1::2] - np.cumsum(w_damp)
                                           - np.cumsum(work)[1::2])
    # Measured: 4.1e-11 J undamped, 9.7e-8 J damped (Simpson's error at the stick-slip
    # switches), while friction takes 6.7 J (6.0 J and damping 0.83 J when damped).
    assert np.abs(balance).max() < 1e-6, np.abs(balance).max()
    assert work.sum() > 5.0


# ------------------------------------------------------------------ 6. off, locked
@pytest.mark.parametrize('model', [ARM, DAMPED, CHAIN], ids=['two_link', 'damped', 'chain3'])
def test_disabled_friction_is_model_step_bit_for_bit(model):
    rng = np.random.default_rng(3)
    n = model.n_dof
    off = JointFriction.none(n)
    for _ in range(50):
        q, qd, tau = rng.normal(size=n), rng.normal(size=n), 5.0 * rng.normal(size=n)
        qd[rng.integers(n)] = 0.0
        ref = model.step(q, qd, tau, DT, 1)
        for locked in (None, np.zeros(n, dtype=bool)):
            q1, qd1, stuck, work = friction_step(model, q, qd, tau, DT, np.zeros(n, bool),
                                                 off, locked)
            assert (bits(q1) == bits(ref[0])).all() and (bits(qd1) == bits(ref[1])).all()
            assert not stuck.any() and work == 0.0
    # From params with no friction keys: the same.
    assert not JointFriction.from_params({}, n).enabled


def test_slipping_without_events_is_model_step_under_tau_minus_coulomb():
    q, qd, tau = Q2, np.array([0.5, -0.7]), np.array([3.0, 1.0])
    q1, qd1, stuck, work = friction_step(ARM, q, qd, tau, DT, np.zeros(2, bool), FR2)
    ref = ARM.step(q, qd, tau - FR2.coulomb * np.sign(qd), DT, 1)
    assert (bits(q1) == bits(ref[0])).all() and (bits(qd1) == bits(ref[1])).all()
    assert not stuck.any()
    assert work == pytest.approx(float(FR2.coulomb @ np.abs(q1 - q)), rel=1e-15)


def test_a_locked_joint_never_moves_and_the_free_joint_follows_the_constrained_dynamics():
    from scipy.integrate import solve_ivp
    locked = np.array([True, False])
    q0 = np.array([-0.4, 1.2])
    rng = np.random.default_rng(5)
    huge = rng.normal(scale=500.0, size=(1000, 2))   # any torque on the locked joint
    for friction in (JointFriction.none(2), FR2):
        q, qd, stuck, work, _ = run(DAMPED, friction, q0, [0.0, 0.0],
                                    lambda k, q, qd: [huge[k, 0], 0.0], 1000, locked)
        assert (bits(q[:, 0]) == bits(q0[0])).all() and (qd[:, 0] == 0.0).all()
        assert stuck[1:, 0].all()
        if friction.enabled:
            continue
        # Joint 2 as a pendulum on the fixed link 1: D22 qdd2 = -(C qd)_2 - g2 - b2 qd2.

        def rhs(_t, x):
            qq, vv = np.array([q0[0], x[0]]), np.array([0.0, x[1]])
            d = DAMPED.mass_matrix(qq)
            h = (DAMPED.coriolis_matrix(qq, vv) @ vv + DAMPED.gravity_vector(qq)
                 + DAMPED.damping_torque(vv))
            return [x[1], -h[1] / d[1, 1]]

        t = np.arange(1001) * DT
        sol = solve_ivp(rhs, (0.0, 1.0), [q0[1], 0.0], method='DOP853', rtol=1e-12,
                        atol=1e-12, t_eval=t)
        err = np.abs(q[:, 1] - sol.y[0]).max()
        assert err < 1e-8, err   # RK4 at 1 ms: measured 8e-12 rad
        assert np.ptp(q[:, 1]) > 1.0 and (work == 0.0).all()


def test_a_brake_catching_a_moving_joint_keeps_the_free_momentum_and_counts_the_loss():
    q, qd = np.array([-0.4, 1.2]), np.array([1.5, -0.8])
    locked = np.array([True, False])
    fr = JointFriction.none(2)
    # A zero-length step would show the impact alone; take the smallest step instead and
    # compare with the impact followed by the locked dynamics, from the closed form.
    d = ARM.mass_matrix(q)
    after = qd[1] + d[1, 0] * qd[0] / d[1, 1]
    lost = 0.5 * qd @ d @ qd - 0.5 * d[1, 1] * after**2
    q1, qd1, stuck, work = friction_step(ARM, q, qd, np.zeros(2), 1e-9, np.zeros(2, bool),
                                         fr, locked)
    assert qd1[0] == 0.0 and q1[0] == q[0] and stuck[0]
    assert abs(qd1[1] - after) < 1e-7   # 1 ns of pendulum acceleration
    assert work == pytest.approx(lost, rel=1e-12)


# ------------------------------------------------------------------ 7. validation
def test_static_below_coulomb_is_refused_naming_both():
    with pytest.raises(ValueError, match=r'static_friction\[1\] = 0\.5 N m is below '
                                         r'coulomb_friction\[1\] = 0\.8'):
        JointFriction(coulomb=[1.0, 0.8], static=[2.0, 0.5])
    with pytest.raises(ValueError, match=r'static_friction\[0\] = 1\.0 .*coulomb_friction'):
        JointFriction.from_params({'coulomb_friction': [2.0, 0.0],
                                   'static_friction': [1.0, 0.0]}, 2)


def test_one_static_friction_rule_for_robot_parameters_simulator_and_sweeps():
    """``static_friction`` 0 is the joint's Coulomb value, and a non-zero one below it is
    refused with one message, the same in the robot parameters (``resolve_robot``), the
    simulator's friction (``JointFriction.from_params``) and a sweep's scenario."""
    from arm_dynamics.robot import resolve_robot
    from arm_sim.sweep import PF, PS, Scenario

    reg = dict(task='regulation', start=PS, goal=PF, duration=1.0, hold=1.0)
    for c, s, used in [((1.5, 0.5), (0.0, 0.0), (1.5, 0.5)),
                       ((1.5, 0.5), (1.95, 0.0), (1.95, 0.5)),
                       ((0.0, 0.0), (0.5, 0.0), (0.5, 0.0))]:
        assert static_friction_used(s, c) == used
        robot = resolve_robot({'coulomb_friction': list(c), 'static_friction': list(s)})
        assert JointFriction.from_params(robot, 2) == JointFriction(coulomb=c, static=used)
        assert Scenario(**reg, coulomb_friction=c, static_friction=s).friction() == \
            JointFriction(coulomb=c, static=used)
    message = ('static_friction[0] = 1 N m is below coulomb_friction[0] = 1.5 N m: the '
               'break-away torque is at least the sliding one (0 = equal to it)')
    assert static_friction_problem((1.0, 0.0), (1.5, 0.5)) == message
    assert static_friction_problem((0.0, 0.5), (1.5, 0.5)) is None
    with pytest.raises(ValueError) as err:
        resolve_robot({'coulomb_friction': [1.5, 0.5], 'static_friction': [1.0, 0.0]})
    assert message in str(err.value)
    with pytest.raises(ValueError) as err:
        Scenario(**reg, coulomb_friction=(1.5, 0.5), static_friction=(1.0, 0.0))
    assert str(err.value) == message
    with pytest.raises(ValueError, match=r'static_friction\[0\] = 1\.0 N m is below '):
        JointFriction.from_params({'coulomb_friction': [1.5, 0.5],
                                   'static_friction': [1.0, 0.0]}, 2)


@pytest.mark.parametrize('params, message', [
    ({'coulomb_friction': [-1.0, 0.0]}, r'coulomb_friction\[0\] must be >= 0, got -1\.0'),
    ({'coulomb_friction': [1.0, math.nan]}, r'coulomb_friction\[1\] must be finite'),
    ({'coulomb_friction': [1.0]}, r'coulomb_friction must have 2 elements, got 1'),
    ({'static_friction': [1.0, 2.0, 3.0]}, r'static_friction must have 2 elements, got 3'),
    ({'static_friction': 'abc'}, r"static_friction must be a sequence of 2 numbers, got 'abc'"),
    ({'coulomb_friction': [1.0, 'x']}, r"coulomb_friction\[1\] must be a number, got 'x'"),
])
def test_bad_friction_parameters_are_refused_naming_the_value(params, message):
    with pytest.raises(ValueError, match=message):
        JointFriction.from_params(params, 2)


def test_from_params_defaults_static_to_coulomb_and_missing_to_zero():
    f = JointFriction.from_params({'coulomb_friction': [1.0, 2.0]}, 2)
    assert f.static.tolist() == [1.0, 2.0] and f.enabled
    f = JointFriction.from_params({'coulomb_friction': [], 'static_friction': []}, 3)
    assert f.coulomb.tolist() == [0.0] * 3 and not f.enabled
    f = JointFriction.from_params({'static_friction': [0.5, 0.0]}, 2)
    assert f.coulomb.tolist() == [0.0, 0.0] and f.static.tolist() == [0.5, 0.0] and f.enabled
    assert f == JointFriction(coulomb=[0.0, 0.0], static=[0.5, 0.0])
    assert hash(f) == hash(JointFriction(coulomb=[0.0, 0.0], static=[0.5, 0.0]))
    with pytest.raises(ValueError):
        f.coulomb[0] = 1.0   # read-only
    import pickle
    assert pickle.loads(pickle.dumps(f)) == f


@pytest.mark.parametrize('kw, message', [
    (dict(stuck=np.array([True, False]), qd=np.array([0.1, 0.0])),
     r'stuck\[0\] is True but qd\[0\] = 0\.1 rad/s'),
    (dict(stuck=[0, 0]), r'stuck must be 2 booleans, got \[0, 0\]'),
    (dict(locked=np.array([True])), r'locked must be 2 booleans'),
    (dict(q=np.zeros(3)), r'q must have shape \(2,\), got shape \(3,\)'),
    (dict(dt=0.0), r'dt must be > 0, got 0\.0'),
    (dict(dt=math.inf), r'dt must be finite, got inf'),
    (dict(model=CHAIN), r'friction has 2 joints but the model has 3'),
])
def test_bad_step_arguments_are_refused_naming_the_value(kw, message):
    args = dict(model=ARM, q=Q2, qd=np.zeros(2), tau=np.zeros(2), dt=DT,
                stuck=np.zeros(2, bool), friction=FR2, locked=None)
    args.update(kw)
    with pytest.raises(ValueError, match=message):
        friction_step(**args)


# ------------------------------------------------------------------ batch
def test_batch_rows_match_single_steps_slipping_stuck_and_with_events():
    rng = np.random.default_rng(11)
    rows = 12
    q = rng.normal(scale=0.5, size=(rows, 2)) + Q2
    qd = rng.normal(size=(rows, 2))
    qd[3:6] = 0.0                     # at rest: stick or break away
    qd[6] = [1e-4, -2e-4]             # about to stop: an event inside the step
    tau = np.array([ARM.gravity_vector(x) for x in q]) + rng.normal(scale=2.0, size=(rows, 2))
    stuck = np.zeros((rows, 2), dtype=bool)
    locked = np.zeros((rows, 2), dtype=bool)
    locked[7, 1] = True
    frictions = [FR2] * rows
    frictions[8] = JointFriction.none(2)
    for model in (ARM, TwoLinkBatch([ARM.with_payload(0.1 * i) for i in range(rows)])):
        out = friction_step_batch(model, q, qd, tau, DT, stuck, frictions, locked)
        for i in range(rows):
            arm = model.arms[i] if hasattr(model, 'arms') else model
            one = friction_step(arm, q[i], qd[i], tau[i], DT, stuck[i], frictions[i],
                                locked[i])
            # Batched and single-state RK4 round differently (numpy vs math cos): 1e-12.
            assert np.abs(out[0][i] - one[0]).max() < 1e-12
            assert np.abs(out[1][i] - one[1]).max() < 1e-12
            assert (out[2][i] == one[2]).all() and abs(out[3][i] - one[3]) < 1e-12
    assert out[2][3:6].any() and not out[2][:3].any()


def test_batch_shapes_are_checked():
    with pytest.raises(ValueError, match=r'tau must have shape \(2, 2\)'):
        friction_step_batch(ARM, np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((3, 2)), DT,
                            np.zeros((2, 2), bool), FR2)
    with pytest.raises(ValueError, match=r'friction must be one JointFriction or 2, got 3'):
        friction_step_batch(ARM, np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((2, 2)), DT,
                            np.zeros((2, 2), bool), [FR2] * 3)
