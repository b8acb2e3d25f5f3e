"""Running a sweep's scenarios: the batch closed loop, chunks, worker processes, Dask.

Pure: no rclpy. A chunk of scenarios sharing law, control rate and physics step runs as
one batch (:func:`run_chunk`): the control law of :mod:`arm_control.laws` on the (B, 2)
state (:func:`~arm_control.laws.law_torque`, the controller's saturation) and the plants of
:class:`~arm_dynamics.batch.BatchSimulator` (held command, the simulator's saturation, RK4,
divergence). :func:`run_single` runs one scenario the nodes' way instead;
:func:`run_sweep` runs the chunks in this process, in worker processes or on a Dask
cluster (the functions they run are referenced by module path, so they pickle).

Bounded and interruptible: at most :func:`max_workers` processes; a batch holds at most
:data:`MAX_BATCH_SAMPLES` control samples (a chunk of long scenarios runs as several
batches); a plan the planner stretched past the scenario limits
(:meth:`Scenario.too_long <arm_sim.sweep.spec.Scenario.too_long>`) is a ``refused`` row.
A KeyboardInterrupt (Ctrl-C; ``arm-sim`` raises it on SIGTERM too) or a failed chunk stops
:func:`run_sweep` at once: no further chunk starts, the workers are terminated, and
:class:`SweepStopped` carries the rows finished so far. Each worker ignores SIGINT (the
main process decides) and dies with the main process, SIGKILL included
(``prctl(PR_SET_PDEATHSIG)``, :func:`arm_common.process.watch_parent`).
"""

from __future__ import annotations

import functools
import math
import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from arm_control.core import ControllerCore
from arm_control.laws import Gains, law_torque
from arm_dynamics.batch import BatchSimulator
from arm_dynamics.integrate import simulate
from arm_dynamics.robot import JOINT_NAMES
from arm_dynamics.two_link import TwoLinkBatch
from arm_sim.sweep.metrics import Run, add_margins, finish_row, new_row
from arm_sim.sweep.plan import Planned, plan_scenario
from arm_sim.sweep.spec import Scenario, SpecError

VELOCITY_LIMIT = 1000.0   # rad/s: faster is divergence (the simulator's velocity_limit)
#: Control samples x scenarios stepped as one batch (its arrays: about 100 bytes each, so
#: some 200 MB per worker); a chunk over it runs as several batches (the same rows).
MAX_BATCH_SAMPLES = 2_000_000


def max_workers() -> int:
    """The most local worker processes a sweep starts: 4 per CPU (``os.cpu_count()``)."""
    return 4 * (os.cpu_count() or 1)


class SweepStopped(Exception):
    """A sweep stopped before its end: interrupted (``reason`` None) or a chunk failed
    (``reason`` says how); ``rows`` are the finished ones, in index order, of ``total``."""

    def __init__(self, rows: list[dict], total: int, reason: str | None = None) -> None:
        super().__init__(reason or 'interrupted')
        self.rows, self.total, self.reason = rows, total, reason


def _ticks(s: Scenario, planned: Planned) -> int:
    """Control periods simulated: the motion plus ``hold``, rounded up."""
    return s.ticks(planned.duration)


def _within_limits(s: Scenario, planned: Planned) -> Planned:
    """``planned``, or refused if the planned motion (stretched by the planner) makes more
    work than a scenario may (:meth:`Scenario.too_long`)."""
    if planned.trajectory is None:
        return planned
    reason = s.too_long(planned.duration)
    return planned if reason is None else replace(planned, trajectory=None,
                                                  refused=f'planned {reason}')


def _batches(ticks: Sequence[int]) -> list[list[int]]:
    """Consecutive positions of ``ticks`` cut so that each batch's (most ticks + 1) x
    (scenarios) stays within :data:`MAX_BATCH_SAMPLES` (one batch when it fits)."""
    out: list[list[int]] = []
    longest = 0
    for k, n in enumerate(ticks):
        longest_here = max(longest, n + 1)
        if out and longest_here * (len(out[-1]) + 1) <= MAX_BATCH_SAMPLES:
            out[-1].append(k)
            longest = longest_here
        else:
            out.append([k])
            longest = n + 1
    return out


def run_chunk(items: Sequence[tuple[int, Scenario]], keep_runs: bool = False,
              margins: bool = False) -> list[dict] | tuple[list[dict], list[Run | None]]:
    """Run scenarios as one batch; they must share law, control rate and physics step.

    Parameters
    ----------
    items : (index, scenario) pairs.
    keep_runs : also return each scenario's :class:`~arm_sim.sweep.metrics.Run` (None
        where refused).
    margins : add the margin columns (:func:`~arm_sim.sweep.metrics.add_margins`).

    Returns
    -------
    One result row per item (keys :data:`~arm_sim.sweep.columns.COLUMNS`), in order (and
    the runs).
    """
    if not items:
        return ([], []) if keep_runs else []
    first = items[0][1]
    law, (step_ns, substeps) = first.law, first.timing()
    if any(s.law != law or s.timing() != (step_ns, substeps) for _, s in items):
        raise ValueError('run_chunk: the scenarios of one chunk must share law, '
                         'control_rate and physics_step')
    planned = [_within_limits(s, plan_scenario(s)) for _, s in items]
    rows = [new_row(i, s, p) for (i, s), p in zip(items, planned)]
    runs: list[Run | None] = [None] * len(items)
    live = [k for k, p in enumerate(planned) if p.trajectory is not None]
    for batch in _batches([_ticks(items[k][1], planned[k]) for k in live]):
        ks = [live[b] for b in batch]
        for k, run in zip(ks, _run_batch([items[k][1] for k in ks], [planned[k] for k in ks],
                                         law, step_ns, substeps)):
            runs[k] = run
            finish_row(rows[k], items[k][1], planned[k], run)
    if margins:
        for (_, s), row, p in zip(items, rows, planned):
            add_margins(row, s, p)
    return (rows, runs) if keep_runs else rows


def _rows_of(items: Sequence[tuple[int, Scenario]], margins: bool = False) -> list[dict]:
    """The rows of :func:`run_chunk` (what a worker process or a Dask task runs)."""
    rows = run_chunk(items, margins=True) if margins else run_chunk(items)
    assert isinstance(rows, list)
    return rows


def _run_batch(scenarios: Sequence[Scenario], planned: Sequence[Planned], law: str,
               step_ns: int, substeps: int) -> list[Run]:
    """The closed loop of B scenarios stepped together: at each control tick the law on
    the measured (B, 2) state, saturated by the controller, then one period of the plants
    (:meth:`BatchSimulator.advance <arm_dynamics.batch.BatchSimulator.advance>`)."""
    dt = step_ns * 1e-9
    ticks = np.array([_ticks(s, p) for s, p in zip(scenarios, planned)])
    n = int(ticks.max())
    t = (np.arange(n + 1) * substeps) * dt  # as simulate() times its control ticks
    # The reference of each distinct plan at every tick (sampled as the controller does).
    plan_ids: dict[int, int] = {}
    index = np.array([plan_ids.setdefault(id(p.trajectory), len(plan_ids)) for p in planned])
    refs: list[tuple[np.ndarray, ...] | None] = [None] * len(plan_ids)
    for p in planned:
        k = plan_ids[id(p.trajectory)]
        if refs[k] is None:
            assert p.trajectory is not None
            refs[k] = p.trajectory.sample_many(t)
    ref_q, ref_qd, ref_qdd = (np.stack([r[i] for r in refs if r is not None], 1)
                              for i in range(3))
    model = TwoLinkBatch([s.model() for s in scenarios])
    kp, kd, ki, clamp = (np.array([getattr(s, g) for s in scenarios])
                         for g in ('kp', 'kd', 'ki', 'i_clamp'))
    limits = np.array([s.effort_limits for s in scenarios])
    real: dict = {}
    if any(s.real for s in scenarios):
        real = dict(friction=[s.friction() for s in scenarios],
                    sensors=[s.sensor_settings() for s in scenarios],
                    actuation_delay=[s.actuation_delay for s in scenarios])
    sim = BatchSimulator([s.plant() for s in scenarios],
                         q0=np.array([p.q_start for p in planned]),
                         qd0=np.zeros((len(scenarios), 2)), effort_limits=limits,
                         physics_step_ns=step_ns, control_period_ns=step_ns * substeps,
                         velocity_limit=VELOCITY_LIMIT, **real)
    integral = np.zeros((len(scenarios), 2))
    qs, qds, efforts = (np.empty((n + 1, len(scenarios), 2)) for _ in range(3))
    qs[0], qds[0] = sim.q, sim.qd
    for k in range(n):
        dtk = 0.0 if k == 0 else t[k] - t[k - 1]
        mq, mqd = sim.measured  # the true state itself without sensors
        raw, integral = law_torque(law, kp, kd, ki, clamp, limits, model, integral, mq, mqd,
                                   ref_q[k, index], ref_qd[k, index], ref_qdd[k, index], dtk)
        sim.advance(np.clip(raw, -limits, limits))  # the controller saturates its command
        efforts[k + 1] = sim.applied
        qs[k + 1], qds[k + 1] = sim.q, sim.qd
    efforts[0] = efforts[min(1, n)]
    died = sim.diverged_at
    out = []
    for i in range(len(scenarios)):
        m = int(ticks[i]) + 1
        msg = None
        if died[i] >= 0 and died[i] < m:
            msg = (f'diverged at t={t[died[i]]:.3f} s (|qd| > {VELOCITY_LIMIT:g} rad/s or '
                   'non-finite)')
        out.append(Run(t[:m], qs[:m, i], qds[:m, i], efforts[:m, i],
                       ref_q[:m, index[i]], msg))
    return out


def run_single(index: int, s: Scenario, keep_run: bool = False, margins: bool = False
               ) -> dict | tuple[dict, Run | None]:
    """One scenario the nodes' way, one state at a time: the controller core
    (:class:`~arm_control.core.ControllerCore` with :class:`~arm_control.laws.ControlLaw`)
    as the torque law of :func:`~arm_dynamics.integrate.simulate` at the control period,
    the plant's single-state RK4. A real-arm scenario (:attr:`Scenario.real
    <arm_sim.sweep.spec.Scenario.real>`) runs on the simulator node's core instead
    (:func:`run_core`). Returns the result row (and the run). No divergence handling
    (but in :func:`run_core`): for comparisons and benchmarks."""
    from arm_control.laws import ControlLaw

    planned = _within_limits(s, plan_scenario(s))
    row = new_row(index, s, planned)
    if margins:
        add_margins(row, s, planned)
    if planned.trajectory is None:
        return (row, None) if keep_run else row
    if s.real:
        run = run_core(s, planned)
        finish_row(row, s, planned, run)
        return (row, run) if keep_run else row
    step_ns, substeps = s.timing()
    dt = step_ns * 1e-9
    ticks = _ticks(s, planned)
    law = ControlLaw(s.law, Gains(kp=s.kp, kd=s.kd, ki=s.ki, i_clamp=s.i_clamp), s.model(),
                     s.effort_limits)
    core = ControllerCore(JOINT_NAMES, law)
    core.trajectory, core.start = planned.trajectory, 0.0
    refs: list[np.ndarray] = []

    def torque(t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        step = core.update(t, q, qd)
        refs.append(step.q_des)
        return step.command.tau

    sim = simulate(model=s.plant(), q0=planned.q_start, qd0=np.zeros(2), torque=torque,
                   duration=ticks * substeps * dt, dt=dt, control_period=substeps * dt,
                   effort_limits=s.effort_limits)
    tau = sim.tau[::substeps]
    run = Run(sim.t[::substeps], sim.q[::substeps], sim.qd[::substeps],
              np.vstack([tau[:1], tau[:-1]]), np.array(refs[:ticks + 1]))
    finish_row(row, s, planned, run)
    return (row, run) if keep_run else row


def run_core(s: Scenario, planned: Planned) -> Run:
    """The closed loop of one scenario through the nodes' cores, one state at a time: the
    simulator's :class:`~arm_dynamics.simulation.SimulatorCore` (the scenario's plant,
    friction, sensors, actuation delay, divergence check) in lockstep with the
    controller's :class:`~arm_control.core.ControllerCore` on the measurement (what the
    simulator publishes on ``joint_states``). The run records the true state."""
    from arm_control.laws import ControlLaw
    from arm_dynamics.sensors import SensorModel
    from arm_dynamics.simulation import SimulatorCore

    assert planned.trajectory is not None
    step_ns, substeps = s.timing()
    ticks = _ticks(s, planned)
    t = (np.arange(ticks + 1) * substeps) * (step_ns * 1e-9)
    core = SimulatorCore(s.plant(), q0=planned.q_start, qd0=np.zeros(2),
                         effort_limits=s.effort_limits, physics_step_ns=step_ns,
                         control_period_ns=step_ns * substeps, velocity_limit=VELOCITY_LIMIT,
                         joint_names=JOINT_NAMES, sensors=SensorModel(2, **s.sensor_settings()),
                         actuation_delay=s.actuation_delay, friction=s.friction())
    law = ControlLaw(s.law, Gains(kp=s.kp, kd=s.kd, ki=s.ki, i_clamp=s.i_clamp), s.model(),
                     s.effort_limits)
    controller = ControllerCore(JOINT_NAMES, law)
    controller.trajectory, controller.start = planned.trajectory, 0.0
    qs, qds, efforts = (np.zeros((ticks + 1, 2)) for _ in range(3))
    refs = np.zeros((ticks + 1, 2))
    qs[0], qds[0] = core.q, core.qd
    died = -1
    for k in range(ticks + 1):
        mq, mqd = core.measured if core.measuring else (core.q, core.qd)
        step = controller.update(float(t[k]), mq, mqd)
        refs[k] = step.q_des
        if k == ticks:
            break
        core.set_command(step.command.tau.tolist())
        core.advance()
        if core.diverged and died < 0:
            died = k + 1
        qs[k + 1], qds[k + 1], efforts[k + 1] = core.q, core.qd, core.applied
    efforts[0] = efforts[min(1, ticks)]
    msg = None
    if died >= 0:
        msg = (f'diverged at t={t[died]:.3f} s (|qd| > {VELOCITY_LIMIT:g} rad/s or '
               'non-finite)')
    return Run(t, qs, qds, efforts, refs, msg)


# ---------------------------------------------------------------------- orchestration
def make_chunks(scenarios: Sequence[Scenario], chunk_size: int
                ) -> list[list[tuple[int, Scenario]]]:
    """Scenarios grouped by (law, timing), sorted by requested duration within a group
    (chunks then run to similar horizons), cut into chunks of at most ``chunk_size``."""
    if chunk_size < 1:
        raise ValueError(f'chunk_size must be >= 1, got {chunk_size}')
    groups: dict[tuple, list[tuple[int, Scenario]]] = {}
    for i, s in enumerate(scenarios):
        groups.setdefault((s.law, s.timing()), []).append((i, s))
    chunks = []
    for items in groups.values():
        items.sort(key=lambda it: (0.0 if it[1].duration == 'fastest' else it[1].duration,
                                   it[0]))
        chunks += [items[k:k + chunk_size] for k in range(0, len(items), chunk_size)]
    return chunks


def default_chunk_size(count: int, workers: int) -> int:
    """About four chunks per worker, 32 to 1024 scenarios each."""
    return int(min(1024, max(32, math.ceil(count / max(1, 4 * workers)))))


class Progress:
    """``[sweep] 4000/10000 scenarios, 6.1 s, ETA 9 s`` on ``stream``, at most every
    ``every`` s of wall time, and a last line when done (if any was printed)."""

    def __init__(self, total: int, stream=sys.stderr, every: float = 1.0) -> None:
        self.total, self.stream, self.every = total, stream, every
        self.done = 0
        self.start = time.monotonic()
        self.last = self.start
        self.printed = False

    def add(self, count: int) -> None:
        self.done += count
        now = time.monotonic()
        if now - self.last >= self.every or (self.printed and self.done == self.total):
            self.last = now
            self.printed = True
            spent = now - self.start
            eta = spent / self.done * (self.total - self.done) if self.done else math.nan
            print(f'[sweep] {self.done}/{self.total} scenarios, {spent:.1f} s, ETA '
                  f'{eta:.0f} s', file=self.stream, flush=True)


def run_sweep(scenarios: Sequence[Scenario], *, workers: int = 2,
              chunk_size: int | None = None, dask: str | None = None,
              progress: Callable[[int], None] | None = None, margins: bool = False
              ) -> list[dict]:
    """Run every scenario; one row per scenario (keys
    :data:`~arm_sim.sweep.columns.COLUMNS`), in input order.

    Parameters
    ----------
    scenarios : the sweep's scenarios.
    workers : local processes (1: in this process), at most :func:`max_workers`. Ignored
        with ``dask``.
    chunk_size : scenarios per batch (default :func:`default_chunk_size`).
    dask : a Dask scheduler address (``tcp://host:8786``): run the chunks there.
    progress : called with the number of scenarios each finished chunk held.
    margins : add the margin columns (the spec's ``margins: true``).

    Raises
    ------
    SweepStopped : on KeyboardInterrupt or a failed chunk, with the rows finished so far
        (no worker process is left running).
    """
    if not 1 <= workers <= max_workers():
        raise ValueError(f'workers must be in [1, {max_workers()}] (4 per CPU), got '
                         f'{workers}')
    size = chunk_size or default_chunk_size(len(scenarios), workers)
    chunks = make_chunks(scenarios, size)
    rows: list[dict | None] = [None] * len(scenarios)

    def take(chunk_rows: list[dict]) -> None:
        for r in chunk_rows:
            rows[r['index']] = r
        if progress:
            progress(len(chunk_rows))

    rows_of = functools.partial(_rows_of, margins=margins) if margins else _rows_of
    try:
        if dask:
            _run_dask(dask, chunks, take, rows_of)
        elif workers == 1 or len(chunks) <= 1:
            for c in chunks:
                take(_checked(c, functools.partial(rows_of, c)))
        else:
            _run_pool(chunks, min(workers, len(chunks)), take, rows_of)
    except (KeyboardInterrupt, _ChunkFailed) as exc:
        done = [r for r in rows if r is not None]
        reason = str(exc) if isinstance(exc, _ChunkFailed) else None
        raise SweepStopped(done, len(scenarios), reason) from None
    assert all(r is not None for r in rows)
    return rows  # type: ignore[return-value]


class _ChunkFailed(Exception):
    """A chunk raised in a worker (or the worker died): the message says which and how."""


def _checked(chunk: list, rows: Callable[[], list[dict]]) -> list[dict]:
    """``rows()``, the rows of ``chunk``; an exception (a bug, a dead worker) as
    :class:`_ChunkFailed`."""
    try:
        return rows()
    except Exception as exc:
        n = len(chunk)
        raise _ChunkFailed(f"a chunk of {n} scenario{'s' * (n != 1)} (index {chunk[0][0]}"
                           f"{', ...' * (n != 1)}) failed: {type(exc).__name__}: {exc}") from None


def _worker_init(parent: int) -> None:
    """Each worker process: Ctrl-C reaches the whole process group, but the main process
    decides (SIGINT ignored; SIGTERM, its stop, terminates); and the kernel kills the
    worker when the main process dies, however it dies (:func:`watch_parent`)."""
    from arm_common.process import PARENT_ENV, watch_parent

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    os.environ[PARENT_ENV] = str(parent)
    watch_parent()


def _run_pool(chunks: list, workers: int, take: Callable[[list[dict]], None],
              rows_of: Callable[[list], list[dict]] = _rows_of) -> None:
    """Run the chunks on ``workers`` local processes; on any exception (KeyboardInterrupt
    included) stop at once: pending chunks cancelled, the workers terminated."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    # fork (Python 3.11's default on Linux): the workers are this process's children,
    # which watch_parent's parent-death signal relies on.
    context = multiprocessing.get_context('fork' if sys.platform.startswith('linux')
                                          else None)
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=context,
                               initializer=_worker_init, initargs=(os.getpid(),))
    try:
        futures = {pool.submit(rows_of, c): c for c in chunks}
        for f in as_completed(futures):
            take(_checked(futures[f], f.result))
    except BaseException:
        _stop_pool(pool)
        raise
    pool.shutdown()


def _stop_pool(pool) -> None:
    """Cancel the pool's pending chunks and terminate its workers now (a second Ctrl-C or
    SIGTERM meanwhile is ignored: this takes a moment and must finish)."""
    handlers = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            handlers[sig] = signal.signal(sig, signal.SIG_IGN)
        except ValueError:  # not the main thread
            pass
    try:
        procs = list((getattr(pool, '_processes', None) or {}).values())
        manager = getattr(pool, '_executor_manager_thread', None)
        pool.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            p.terminate()
        deadline = time.monotonic() + 5.0
        for p in procs:
            p.join(max(0.0, deadline - time.monotonic()))
            if p.is_alive():
                p.kill()
                p.join(1.0)
        if manager is not None:  # it sees the workers gone and fails what was pending
            manager.join(max(0.0, deadline - time.monotonic()))
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)


def _run_dask(address: str, chunks: list, take: Callable[[list[dict]], None],
              rows_of: Callable[[list], list[dict]] = _rows_of) -> None:
    """Run the chunks on the Dask cluster at ``address`` (imports dask only there)."""
    from arm_common.cluster import ClusterError, dask_map

    try:
        dask_map(address, rows_of, chunks, on_result=lambda _i, rows: take(rows))
    except ClusterError as exc:
        raise SpecError(str(exc)) from None
    except Exception as exc:  # a chunk raised there, or the cluster went away
        raise _ChunkFailed(f'the Dask cluster failed a chunk: {type(exc).__name__}: '
                           f'{exc}') from None
