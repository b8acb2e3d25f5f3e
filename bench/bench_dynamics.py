#!/usr/bin/env python3
"""Benchmark ``arm_dynamics.TwoLinkArm`` against Pinocchio and MuJoCo.

The same planar 2-R arm (the ``TwoLinkArm()`` defaults) is built three ways: our closed-form
model, a Pinocchio ``pin.Model`` built programmatically and a MuJoCo MJCF model generated
from the ``TwoLinkArm`` parameters. The script first checks that all three give the same
joint accelerations at random states (and aborts if they do not), then measures:

(a) forward-dynamics calls per second for one state,
(b) vectorised forward dynamics and RK4 steps over batches of N arms,
(c) a closed PD loop at dt = 1 ms for 10 s of simulated time, RK4 in every engine.

Every figure is the median of several repeats, all in this one process. Run from the repo
root (or with ``PYTHONPATH`` pointing at it)::

    python bench/bench_dynamics.py           # full run, ~1 minute
    python bench/bench_dynamics.py --quick   # smoke run, < 20 s

Needs ``numpy``, ``pin`` (Pinocchio) and ``mujoco``; see ``bench/README.md``.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import sys
import time
import timeit
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

try:
    from arm_dynamics import TwoLinkArm
except ImportError:  # run as `python bench/bench_dynamics.py` without PYTHONPATH
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from arm_dynamics import TwoLinkArm

try:
    import mujoco
    import pinocchio as pin
except ImportError as exc:  # pragma: no cover - depends on the venv
    sys.exit(f'bench_dynamics: {exc}; install them with `pip install pin mujoco` '
             '(see bench/README.md)')

Array = np.ndarray

DT = 1e-3                      # closed-loop time step [s] (also the MJCF timestep)
KP = np.array([50.0, 30.0])    # PD gains of the closed-loop benchmark
KD = np.array([10.0, 6.0])
Q0 = np.array([-math.pi / 2, 0.0])         # start hanging straight down, at rest
Q_GOAL = np.array([math.pi / 4, math.pi / 3])
N_CHECK = 100                  # random states of the agreement check
CHECK_RTOL = 1e-9              # |qdd_a - qdd_b| <= CHECK_RTOL * max(1, |qdd|)
LOOP_ATOL = 1e-6               # closed-loop final-state agreement ours vs MuJoCo RK4


@dataclass(frozen=True)
class Budget:
    """How long the measurements may take."""

    repeats: int            # repeats per figure (the median is reported)
    target_s: float         # wall time aimed at per repeat of a micro-benchmark
    batch_sizes: tuple[int, ...]
    sim_time: float         # simulated seconds of the closed loop


FULL = Budget(repeats=9, target_s=0.25, batch_sizes=(1_000, 10_000, 100_000), sim_time=10.0)
QUICK = Budget(repeats=5, target_s=0.05, batch_sizes=(1_000, 10_000, 100_000), sim_time=2.0)


def log(msg: str) -> None:
    """A progress line (flushed so that it shows while the benchmark runs)."""
    print(f'[bench] {msg}', flush=True)


# ---------------------------------------------------------------------------- models
def build_pinocchio(arm: TwoLinkArm) -> tuple[pin.Model, pin.Data]:
    """The arm as a Pinocchio model: two revolute-Z joints, gravity (0, -g, 0)."""
    (l1, _), (lc1, lc2) = arm.link_lengths, arm.com_distances
    model = pin.Model()
    model.name = 'two_link_arm'
    parent = 0
    placements = (pin.SE3.Identity(), pin.SE3(np.eye(3), np.array([l1, 0.0, 0.0])))
    for i, (placement, lc, m, inertia) in enumerate(
            zip(placements, (lc1, lc2), arm.link_masses, arm.link_inertias), start=1):
        jid = model.addJoint(parent, pin.JointModelRZ(), placement, f'joint{i}')
        # Rotational inertia about the CG: a rod along x, I_i about y and z.
        rot = np.diag([1e-6, inertia, inertia])
        model.appendBodyToJoint(jid, pin.Inertia(m, np.array([lc, 0.0, 0.0]), rot),
                                pin.SE3.Identity())
        parent = jid
    model.gravity.linear = np.array([0.0, -arm.gravity, 0.0])
    return model, model.createData()


def mjcf(arm: TwoLinkArm, integrator: str = 'RK4') -> str:
    """An MJCF string of the arm: hinge joints about z, gravity (0, -g, 0), no contacts.

    The ``diaginertia`` x entry (along the link) is small; y equals z = I_i, as for a rod.
    (MuJoCo refuses principal inertias that break ``A + B >= C``, so x and y cannot both be
    small; neither enters planar motion about z.)
    """
    (l1, _), (lc1, lc2) = arm.link_lengths, arm.com_distances
    (m1, m2), (i1, i2) = arm.link_masses, arm.link_inertias
    (b1, b2), g = arm.joint_damping, arm.gravity

    def joint(name: str, damping: float) -> str:
        return (f'<joint name="{name}" type="hinge" axis="0 0 1" pos="0 0 0" '
                f'damping="{damping!r}" armature="0" frictionloss="0"/>')

    return f"""<mujoco model="two_link_arm">
  <compiler angle="radian"/>
  <option timestep="{DT!r}" gravity="0 {-g!r} 0" integrator="{integrator}">
    <flag contact="disable"/>
  </option>
  <worldbody>
    <body name="link1" pos="0 0 0">
      {joint('joint1', b1)}
      <inertial pos="{lc1!r} 0 0" mass="{m1!r}" diaginertia="1e-06 {i1!r} {i1!r}"/>
      <body name="link2" pos="{l1!r} 0 0">
        {joint('joint2', b2)}
        <inertial pos="{lc2!r} 0 0" mass="{m2!r}" diaginertia="1e-06 {i2!r} {i2!r}"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def build_mujoco(arm: TwoLinkArm, integrator: str = 'RK4') -> tuple[object, object]:
    """(MjModel, MjData) from :func:`mjcf`."""
    model = mujoco.MjModel.from_xml_string(mjcf(arm, integrator))
    return model, mujoco.MjData(model)


# ---------------------------------------------------------------------------- check
def check_agreement(arm: TwoLinkArm, pmodel: pin.Model, pdata: pin.Data, mmodel: object,
                    mdata: object, rng: np.random.Generator) -> dict[str, float]:
    """Largest relative qdd difference of each engine vs ours; exit if over CHECK_RTOL."""
    q = rng.uniform(-math.pi, math.pi, (N_CHECK, 2))
    qd = rng.uniform(-5.0, 5.0, (N_CHECK, 2))
    tau = rng.uniform(-50.0, 50.0, (N_CHECK, 2))
    damping = np.asarray(arm.joint_damping)
    ours_batch = arm.forward_dynamics(q, qd, tau)
    worst = {'ours single vs batch': 0.0, 'pinocchio aba': 0.0, 'mujoco mj_forward': 0.0}
    for k in range(N_CHECK):
        ours = arm.forward_dynamics(q[k], qd[k], tau[k])
        # pin.aba knows no joint damping: fold it into the torque.
        pin_qdd = pin.aba(pmodel, pdata, q[k], qd[k], tau[k] - damping * qd[k]).copy()
        mdata.qpos[:] = q[k]
        mdata.qvel[:] = qd[k]
        mdata.qfrc_applied[:] = tau[k]
        mujoco.mj_forward(mmodel, mdata)
        scale = max(1.0, float(np.max(np.abs(ours))))
        for name, other in (('ours single vs batch', ours_batch[k]),
                            ('pinocchio aba', pin_qdd),
                            ('mujoco mj_forward', mdata.qacc)):
            worst[name] = max(worst[name], float(np.max(np.abs(other - ours))) / scale)
    bad = {name: err for name, err in worst.items() if not err <= CHECK_RTOL}
    if bad:
        detail = ', '.join(f'{name}: {err:.3e}' for name, err in bad.items())
        sys.exit(f'bench_dynamics: ABORT - the models disagree on qdd at {N_CHECK} random '
                 f'states (relative tolerance {CHECK_RTOL:g}): {detail}. Check the '
                 'Pinocchio/MJCF construction against TwoLinkArm before timing anything.')
    return worst


# ---------------------------------------------------------------------------- timing
@dataclass(frozen=True)
class Timing:
    """Seconds per unit (call or run) over the repeats: median, and the spread."""

    median: float
    low: float
    high: float

    @classmethod
    def of(cls, samples: list[float]) -> Timing:
        return cls(statistics.median(samples), min(samples), max(samples))

    def spread(self) -> str:
        """+-% of the extremes around the median, for progress lines."""
        return f'[{100 * (self.low / self.median - 1):+.0f}%, ' \
               f'{100 * (self.high / self.median - 1):+.0f}%]'


def calibrate(timer: timeit.Timer, target_s: float) -> int:
    """How many executions of ``timer``'s statement take about ``target_s``."""
    number = 1
    while True:
        elapsed = timer.timeit(number)
        if elapsed >= target_s / 4 or number >= 1 << 24:
            break
        number *= 2 if elapsed > target_s / 40 else 10
    return max(1, int(number * target_s / max(elapsed, 1e-9)))


def per_call(stmts: dict[str, str], env: dict[str, object], budget: Budget) -> dict[str, Timing]:
    """Seconds per execution of each statement (timeit, ~10 ns loop overhead per call).

    The repeats are interleaved (every statement once, then again, ...) so that a burst of
    background load hits all of them alike and the ratios stay meaningful.
    """
    timers = {name: timeit.Timer(stmt, globals=env) for name, stmt in stmts.items()}
    numbers = {name: calibrate(timer, budget.target_s) for name, timer in timers.items()}
    samples: dict[str, list[float]] = {name: [] for name in stmts}
    for _ in range(budget.repeats):
        for name, timer in timers.items():
            samples[name].append(timer.timeit(numbers[name]) / numbers[name])
    return {name: Timing.of(t) for name, t in samples.items()}


def per_run(fns: dict[str, Callable[[], object]],
            repeats: int) -> dict[str, tuple[Timing, object]]:
    """Wall seconds per run of each function, repeats interleaved; and its last result."""
    samples: dict[str, list[float]] = {name: [] for name in fns}
    results: dict[str, object] = {}
    for _ in range(repeats):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            results[name] = fn()
            samples[name].append(time.perf_counter() - t0)
    return {name: (Timing.of(t), results[name]) for name, t in samples.items()}


# ---------------------------------------------------------------------------- loops
def loop_ours(arm: TwoLinkArm, n: int) -> tuple[Array, Array]:
    """n PD + RK4 steps with ``TwoLinkArm.step`` (single-state fast path)."""
    q, qd = Q0.copy(), np.zeros(2)
    step = arm.step
    for _ in range(n):
        tau = KP * (Q_GOAL - q) - KD * qd
        q, qd = step(q, qd, tau, DT)
    return q, qd


def loop_floats(arm: TwoLinkArm, n: int) -> tuple[Array, Array]:
    """n PD + RK4 steps through the public float API ``TwoLinkArm.step_floats``: the state
    and gains kept as floats, the PD law on floats; each call validates its arguments once,
    then runs the unchecked inlined RK4. The same IEEE operations per element as
    :func:`loop_ours`, so the same trajectory bit for bit."""
    q1, q2 = Q0.tolist()
    v1 = v2 = 0.0
    g1, g2 = Q_GOAL.tolist()
    p1, p2 = KP.tolist()
    d1, d2 = KD.tolist()
    step = arm.step_floats
    for _ in range(n):
        q1, q2, v1, v2 = step(q1, q2, v1, v2, p1 * (g1 - q1) - d1 * v1,
                              p2 * (g2 - q2) - d2 * v2, DT)
    return np.array((q1, q2)), np.array((v1, v2))


def loop_mujoco(model: object, data: object, n: int) -> tuple[Array, Array]:
    """n PD steps with ``mj_step``; the torque goes in ``qfrc_applied`` (held by MuJoCo)."""
    mujoco.mj_resetData(model, data)
    data.qpos[:] = Q0
    qpos, qvel, qfrc = data.qpos, data.qvel, data.qfrc_applied
    mj_step = mujoco.mj_step
    for _ in range(n):
        qfrc[:] = KP * (Q_GOAL - qpos) - KD * qvel
        mj_step(model, data)
    return qpos.copy(), qvel.copy()


def pin_rk4_step(model: pin.Model, data: pin.Data, damping: Array, q: Array, qd: Array,
                 tau: Array) -> tuple[Array, Array]:
    """One classic RK4 step of DT around ``pin.aba``, torque held, damping folded in."""
    aba = pin.aba
    h2, h6 = 0.5 * DT, DT / 6.0
    a1 = aba(model, data, q, qd, tau - damping * qd).copy()  # aba returns data.ddq
    v2 = qd + h2 * a1
    a2 = aba(model, data, q + h2 * qd, v2, tau - damping * v2).copy()
    v3 = qd + h2 * a2
    a3 = aba(model, data, q + h2 * v2, v3, tau - damping * v3).copy()
    v4 = qd + DT * a3
    a4 = aba(model, data, q + DT * v3, v4, tau - damping * v4)
    return q + h6 * (qd + 2.0 * (v2 + v3) + v4), qd + h6 * (a1 + 2.0 * (a2 + a3) + a4)


def loop_pinocchio(arm: TwoLinkArm, model: pin.Model, data: pin.Data,
                   n: int) -> tuple[Array, Array]:
    """n PD steps with a Python RK4 (torque held) around ``pin.aba``."""
    q, qd = Q0.copy(), np.zeros(2)
    damping = np.asarray(arm.joint_damping)
    for _ in range(n):
        q, qd = pin_rk4_step(model, data, damping, q, qd, KP * (Q_GOAL - q) - KD * qd)
    return q, qd


def trajectory_deviation(arm: TwoLinkArm, engines: dict[str, tuple[object, object]],
                         pmodel: pin.Model, pdata: pin.Data, n: int) -> dict[str, float]:
    """Max over n closed-loop steps of max(|dq|, |dqd|) between each engine and ours.

    Untimed: all engines run in lockstep from the same start, each on its own state.
    """
    damping = np.asarray(arm.joint_damping)
    q, qd = Q0.copy(), np.zeros(2)
    pq, pqd = Q0.copy(), np.zeros(2)
    for model, data in engines.values():
        mujoco.mj_resetData(model, data)
        data.qpos[:] = Q0
    worst = dict.fromkeys((*engines, 'pin'), 0.0)
    for _ in range(n):
        q, qd = arm.step(q, qd, KP * (Q_GOAL - q) - KD * qd, DT)
        pq, pqd = pin_rk4_step(pmodel, pdata, damping, pq, pqd, KP * (Q_GOAL - pq) - KD * pqd)
        states = {'pin': (pq, pqd)}
        for name, (model, data) in engines.items():
            data.qfrc_applied[:] = KP * (Q_GOAL - data.qpos) - KD * data.qvel
            mujoco.mj_step(model, data)
            states[name] = (data.qpos, data.qvel)
        for name, (sq, sqd) in states.items():
            dev = max(np.max(np.abs(sq - q)), np.max(np.abs(sqd - qd)))
            worst[name] = max(worst[name], float(dev))
    return worst


def loop_pd_only(n: int) -> tuple[Array, Array]:
    """The PD law and loop alone (no dynamics): the floor every closed loop pays."""
    q, qd = Q0.copy(), np.zeros(2)
    for _ in range(n):
        tau = KP * (Q_GOAL - q) - KD * qd
    return q, tau


# ---------------------------------------------------------------------------- main
def fmt_rate(x: float) -> str:
    """A rate with an SI suffix, e.g. 1.23 M."""
    for div, suffix in ((1e9, ' G'), (1e6, ' M'), (1e3, ' k')):
        if x >= div:
            return f'{x / div:7.2f}{suffix}'
    return f'{x:7.2f}  '


def load_note() -> str:
    """The 1-min load average vs the CPU count, with a warning when timings will suffer."""
    try:
        load = os.getloadavg()[0]
    except OSError:
        return 'load average: unknown'
    cpus = os.cpu_count() or 1
    note = f'load average {load:.2f} on {cpus} CPUs'
    if load >= 0.75 * cpus:
        note += ' - WARNING: a busy machine, absolute timings are pessimistic (ratios hold up)'
    return note


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description='Benchmark arm_dynamics.TwoLinkArm against Pinocchio (pin.aba) and '
                    'MuJoCo (mj_forward / mj_step) on the same planar 2-R arm: first an '
                    'agreement check of the accelerations, then single-state, batched and '
                    'closed-loop (PD, RK4, dt = 1 ms) timings. Prints a final table.')
    parser.add_argument('--quick', action='store_true',
                        help='fewer repeats, shorter timing windows and 2 s of simulated '
                             'closed loop instead of 10 s (< 20 s in total)')
    parser.add_argument('--seed', type=int, default=0,
                        help='seed of the random states (default: %(default)s)')
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    budget = QUICK if args.quick else FULL
    t_start = time.perf_counter()
    rng = np.random.default_rng(args.seed)
    log(f'python {platform.python_version()}, numpy {np.__version__}, '
        f'pinocchio {pin.__version__}, mujoco {mujoco.__version__}, '
        f'{platform.machine()} {platform.processor() or ""}'.rstrip())
    log(f'mode: {"quick" if args.quick else "full"} (median of {budget.repeats} repeats)')
    load = load_note()
    log(load)

    arm = TwoLinkArm()
    pmodel, pdata = build_pinocchio(arm)
    mmodel, mdata = build_mujoco(arm, 'RK4')
    emodel, edata = build_mujoco(arm, 'Euler')
    log(f'arm: lengths {arm.link_lengths}, com {arm.com_distances}, masses '
        f'{arm.link_masses}, inertias {arm.link_inertias}, g {arm.gravity}, damping '
        f'{arm.joint_damping}')

    # 1. agreement --------------------------------------------------------------------
    log(f'checking qdd agreement at {N_CHECK} random states ...')
    worst = check_agreement(arm, pmodel, pdata, mmodel, mdata, rng)
    log('  agreement OK: ' + ', '.join(f'{k} {v:.1e}' for k, v in worst.items()))

    # 2a. one state -------------------------------------------------------------------
    log('(a) single-state forward dynamics ...')
    q = rng.uniform(-math.pi, math.pi, 2)
    qd = rng.uniform(-2.0, 2.0, 2)
    tau = rng.uniform(-20.0, 20.0, 2)
    mdata.qpos[:], mdata.qvel[:], mdata.qfrc_applied[:] = q, qd, tau
    env: dict[str, object] = {
        'fd': arm.forward_dynamics, 'aba': pin.aba, 'pm': pmodel, 'pd': pdata,
        'mj_forward': mujoco.mj_forward, 'mm': mmodel, 'md': mdata, 'q': q, 'qd': qd,
        'tau': tau, 'qt': tuple(q), 'qdt': tuple(qd), 'taut': tuple(tau), 'qpos': mdata.qpos,
        'qvel': mdata.qvel, 'qfrc': mdata.qfrc_applied}
    timings = per_call({
        'ours': 'fd(q, qd, tau)',
        'ours_tuple': 'fd(qt, qdt, taut)',
        'pin': 'aba(pm, pd, q, qd, tau)',
        'mj': 'mj_forward(mm, md)',
        'mj_set': 'qpos[:] = q; qvel[:] = qd; qfrc[:] = tau; mj_forward(mm, md)',
    }, env, budget)
    for name, t in timings.items():
        log(f'  {name:10s} {t.median * 1e6:7.3f} us/call  {fmt_rate(1.0 / t.median)}calls/s  '
            f'spread {t.spread()}')
    single = {name: t.median for name, t in timings.items()}

    # 2b. batches ---------------------------------------------------------------------
    log('(b) vectorised forward dynamics and RK4 steps over N arms ...')
    batch: list[tuple[int, float, float, float]] = []
    for n in budget.batch_sizes:
        bq = rng.uniform(-math.pi, math.pi, (n, 2))
        bqd = rng.uniform(-2.0, 2.0, (n, 2))
        btau = rng.uniform(-20.0, 20.0, (n, 2))
        benv: dict[str, object] = {'fd': arm.forward_dynamics, 'step': arm.step, 'q': bq,
                                   'qd': bqd, 'tau': btau, 'dt': DT}
        bt = per_call({'fd': 'fd(q, qd, tau)', 's1': 'step(q, qd, tau, dt)',
                       's10': 'step(q, qd, tau, dt, 10)'}, benv, budget)
        t_fd, t_s1, t_s10 = bt['fd'].median, bt['s1'].median, bt['s10'].median
        batch.append((n, n / t_fd, n / t_s1, 10 * n / t_s10))
        log(f'  N={n:>7d}: forward_dynamics {fmt_rate(n / t_fd)}arm-evals/s, step '
            f'{fmt_rate(n / t_s1)}arm-steps/s (n_steps=1), '
            f'{fmt_rate(10 * n / t_s10)}arm-steps/s (n_steps=10)')

    # 2c. closed loop -----------------------------------------------------------------
    n_steps = round(budget.sim_time / DT)
    log(f'(c) closed loop: PD + RK4, dt {DT * 1e3:g} ms, {budget.sim_time:g} s simulated '
        f'= {n_steps} steps ...')
    runs = per_run({'ours': lambda: loop_ours(arm, n_steps),
                    'floats': lambda: loop_floats(arm, n_steps),
                    'mj_rk4': lambda: loop_mujoco(mmodel, mdata, n_steps),
                    'mj_euler': lambda: loop_mujoco(emodel, edata, n_steps),
                    'pin': lambda: loop_pinocchio(arm, pmodel, pdata, n_steps),
                    'pd_only': lambda: loop_pd_only(n_steps)}, budget.repeats)
    loops: dict[str, tuple[Timing, tuple[Array, Array]]] = {}
    for name, (t, result) in runs.items():
        loops[name] = (t, result)  # type: ignore[assignment]
        log(f'  {name:9s} {t.median * 1e6 / n_steps:7.2f} us/step  '
            f'{budget.sim_time / t.median:8.1f} x real time  spread {t.spread()}')

    def final_diff(name: str) -> float:
        (qa, qda), (qb, qdb) = loops['ours'][1], loops[name][1]
        return float(max(np.max(np.abs(qa - qb)), np.max(np.abs(qda - qdb))))

    diffs = {name: final_diff(name) for name in ('mj_rk4', 'mj_euler', 'pin', 'floats')}
    q_end, qd_end = loops['ours'][1]
    log(f'  final state (ours): q {np.array2string(q_end, precision=6)} rad, '
        f'qd {np.array2string(qd_end, precision=6)} rad/s')
    log('  final-state difference vs ours (max |dq|, |dqd|): '
        + ', '.join(f'{k} {v:.2e}' for k, v in diffs.items()))
    log('  checking the whole trajectories in lockstep (untimed) ...')
    along = trajectory_deviation(arm, {'mj_rk4': (mmodel, mdata), 'mj_euler': (emodel, edata)},
                                 pmodel, pdata, n_steps)
    log('  max deviation from ours along the trajectory: '
        + ', '.join(f'{k} {v:.2e}' for k, v in along.items()))
    loop_ok = max(diffs['mj_rk4'], along['mj_rk4']) <= LOOP_ATOL

    # 3. table ------------------------------------------------------------------------
    us = {k: v * 1e6 for k, v in single.items()}
    width = 92
    print()
    print('=' * width)
    print(f'TwoLinkArm benchmark ({"quick" if args.quick else "full"}; median of '
          f'{budget.repeats}; numpy {np.__version__}, pinocchio {pin.__version__}, '
          f'mujoco {mujoco.__version__})')
    print(load)
    print('=' * width)
    print(f'agreement of qdd at {N_CHECK} random states (max relative difference vs ours): '
          f'pinocchio {worst["pinocchio aba"]:.1e}, mujoco {worst["mujoco mj_forward"]:.1e}')
    print()
    print('(a) forward dynamics, one state, called from Python')
    print(f'  {"engine / call":46s} {"us/call":>9s} {"calls/s":>10s} {"vs pin.aba":>11s}')
    rows_a = (
        ('TwoLinkArm.forward_dynamics (numpy (2,) in)', us['ours']),
        ('TwoLinkArm.forward_dynamics (tuples in)', us['ours_tuple']),
        ('pin.aba (numpy in)', us['pin']),
        ('mujoco.mj_forward (state already in MjData)', us['mj']),
        ('mujoco.mj_forward + write qpos/qvel/qfrc', us['mj_set']),
    )
    for label, t in rows_a:
        print(f'  {label:46s} {t:9.3f} {fmt_rate(1e6 / t):>10s} {t / us["pin"]:10.2f}x')
    print(f'  -> ours / pinocchio: {us["ours"] / us["pin"]:.2f}x the time per call '
          f'({us["pin"] / us["ours"]:.2f}x the calls/s), target <= 1.0x '
          f'{"MET" if us["ours"] <= us["pin"] else "NOT MET"}')
    print()
    print('(b) vectorised over N arm states (float64 numpy)')
    print(f'  {"N":>8s} {"forward_dynamics":>20s} {"step n_steps=1":>20s} '
          f'{"step n_steps=10":>20s}')
    print(f'  {"":8s} {"[arm-evals/s]":>20s} {"[arm-steps/s]":>20s} {"[arm-steps/s]":>20s}')
    for n, fd_rate, s1_rate, s10_rate in batch:
        print(f'  {n:8d} {fmt_rate(fd_rate):>20s} {fmt_rate(s1_rate):>20s} '
              f'{fmt_rate(s10_rate):>20s}')
    best = max(max(r[2], r[3]) for r in batch)
    print(f'  -> best step throughput {fmt_rate(best).strip()} arm-steps/s: target >= 1 M '
          f'{"MET" if best >= 1e6 else "NOT MET"}')
    print()
    print(f'(c) closed loop: PD every step in Python, RK4 (torque held), dt = 1 ms, '
          f'{budget.sim_time:g} s simulated')
    print(f'  {"engine":44s} {"us/step":>8s} {"x real time":>12s} {"vs mj_step RK4":>15s} '
          f'{"best run x":>11s}')
    ref = loops['mj_rk4'][0].median
    rows_c = (
        ('TwoLinkArm.step + numpy PD', 'ours'),
        ('TwoLinkArm.step_floats + float PD', 'floats'),
        ('mujoco.mj_step, integrator RK4', 'mj_rk4'),
        ('mujoco.mj_step, integrator Euler (default)', 'mj_euler'),
        ('Python RK4 around pin.aba (4 calls/step)', 'pin'),
        ('(PD law + loop alone, no dynamics)', 'pd_only'),
    )
    for label, key in rows_c:
        t = loops[key][0]
        print(f'  {label:44s} {t.median * 1e6 / n_steps:8.2f} {budget.sim_time / t.median:11.1f}x '
              f'{t.median / ref:14.2f}x {budget.sim_time / t.low:10.1f}x')
    rt = budget.sim_time / loops['ours'][0].median
    rt_best = budget.sim_time / loops['ours'][0].low
    print(f'  -> ours: {rt:.0f}x real time (median; best run {rt_best:.0f}x), target >= 100x '
          f'{"MET" if rt >= 100 else "NOT MET"}')
    for label, key in (('TwoLinkArm.step', 'ours'), ('TwoLinkArm.step_floats', 'floats')):
        ratio = loops[key][0].median / ref
        print(f'  -> {label} / mj_step RK4: {ratio:.2f}x the time per step, target <= 0.5x '
              f'{"MET" if ratio <= 0.5 else "NOT MET"}')
    print(f'  step_floats loop vs TwoLinkArm.step loop, final state: max difference '
          f'{diffs["floats"]:.1e} (0 = bit-identical)')
    print(f'  trajectory agreement vs ours, max(|dq| [rad], |dqd| [rad/s]) '
          f'({"OK" if loop_ok else "MISMATCH"}: MuJoCo RK4 tolerance {LOOP_ATOL:g}):')
    print(f'    {"":14s} {"final state":>12s} {"max along run":>14s}')
    for label, key in (('MuJoCo RK4', 'mj_rk4'), ('Pinocchio RK4', 'pin'),
                       ('MuJoCo Euler', 'mj_euler')):
        print(f'    {label:14s} {diffs[key]:12.2e} {along[key]:14.2e}')
    print('=' * width)
    log(f'done in {time.perf_counter() - t_start:.1f} s')
    if not loop_ok:
        print(f'bench_dynamics: closed-loop trajectories of ours and MuJoCo RK4 differ by '
              f'{max(diffs["mj_rk4"], along["mj_rk4"]):.3e} > {LOOP_ATOL:g}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
