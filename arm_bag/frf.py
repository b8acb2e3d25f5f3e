"""Frequency response from a recorded excitation, against the linearised prediction (pure).

What ``arm-sim analyze BAG --frf`` computes. A bag of a chirp (or multi-sine) run holds,
on the control period's grid ``t_k = k T``, the controller's reference ``r_k =
(q_des, qd_des)`` and command ``u_k`` (``arm_controller/reference``: position, velocity,
effort) and the measured state ``x_k = (q_k, qd_k)`` (``joint_states``), one of each per
stamp. From them, per excited joint ``j``:

* **the excitation window** (:func:`excitation_window`): the reference moves about its
  final value ``centre`` (the set point it ends at rest on); the window runs from the end
  of the last stretch of at least ``DWELL`` s at rest exactly at ``centre`` before the
  last excursion (the planner's chirp mode first brings the arm there and waits) -- or the
  first sample -- to the end of the recording. A reference that does not start there at
  rest (a regulation move, a line) is no excitation about a pose, and refused.
* **the closed-loop response** ``H_j = S_(r q_j) / S_(r r)`` (H1 estimate; Bendat and
  Piersol) from the deviation ``r`` of the reference joint's ``q_des`` to the deviation of
  ``q_j``: cross and auto spectra by :func:`scipy.signal.csd` / :func:`scipy.signal.welch`.
  A chirp is a transient (it starts and ends at rest), so the default estimate takes the
  whole window as one rectangular segment (``nperseg = window``): the ratio of the
  transforms, exact for a linear system whose response has died out by the window's end.
  The **coherence** ``|S_rq|^2 / (S_rr S_qq)`` needs averaging: it comes from Welch
  segments (``COHERENCE_SEGMENTS`` Hann segments, half overlapping) and tells how much of
  ``q_j`` is the linear response to ``r`` (1: all; less: nonlinearity, noise, other inputs).
* **the loop return ratio** with the command: ``R_j = [Cx(z) S_(r x)]_j / S_(r u_j)``, the
  part of the command the law feeds back from the state per unit of command, with the
  reference as instrument (Cx the law's linear feedback, :mod:`arm_control.closed_loop`).
  With one joint excited by a law whose feedforward acts on that joint alone (pd,
  pd_gravity, pid) it is that joint's loop broken at its plant input with the others
  closed, ``L_j``; in general it is the return ratio under this excitation, and
  :func:`frf_analysis` predicts exactly that for comparison.

Several joints may move if they move with proportional signals (the planner's chirp moves
each joint by its amplitude times the same sweep): ``r`` is then the reference of the
joint with the largest amplitude and the prediction for joint ``j`` is ``sum_i H_ji v_i /
v_j`` with ``v`` the amplitudes (the response to this excitation, per unit of ``q_des_j``).

The prediction (:func:`arm_control.closed_loop.closed_loop`) is the linearised
sampled-data loop about the law's rest position for ``centre``: the plant of the bag's
``arm_sim_robot`` record, discretised with the control period's hold, plus ``delay``
periods. Frequencies Hz, gains dB, phases deg.

References: Bendat and Piersol, *Random Data* (4th ed., Wiley 2010), §9.1-9.2 (H1,
coherence); Pintelon and Schoukens (2012), §2.6 (transient excitations); Franklin,
Powell, Workman (1998), §7.2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import signal

from arm_bag.reader import BagData, JointStates, read_bag
from arm_control.closed_loop import ClosedLoop, Margins, closed_loop, loop_margins
from arm_control.laws import Gains
from arm_dynamics.models import robot_model
from arm_dynamics.robot import ROBOT_PARAMS, resolve_robot

#: s: a stretch at rest at the centre at least this long ends what came before the
#: excitation (the planner's chirp mode waits ``CHIRP_DWELL`` = 1 s there).
DWELL = 0.2
#: rad, rad/s: "at rest at the centre".
REST_TOL = 1e-9
#: Welch segments for the coherence.
COHERENCE_SEGMENTS = 8
#: The frequencies of the printed table [Hz] (those below Nyquist / 3 and in the band).
TABLE_FREQUENCIES = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 16.0)
#: Input power, relative to its peak in the checked band, below which a frequency counts
#: as not excited (no estimate there).
EXCITED_DB = -40.0


class FrfError(ValueError):
    """The bag cannot give a frequency response; the message says why in one line."""


@dataclass
class JointFrf:
    """One excited joint's estimate and prediction at ``freqs`` (F,) Hz: complex
    ``measured`` / ``predicted`` closed loop (rad/rad), ``coherence`` (F,) in [0, 1],
    ``excited`` (F,) bool (input power above ``EXCITED_DB``), ``loop_measured`` /
    ``loop_predicted`` (F,) the return ratio, ``margins`` the predicted loop's
    (:class:`~arm_control.closed_loop.Margins`), ``worst_db`` / ``worst_deg`` the largest
    |gain| / |phase| difference over the checked band (excited bins) and where [Hz]."""

    joint: int
    name: str
    amplitude: float
    freqs: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    coherence: np.ndarray
    excited: np.ndarray
    loop_measured: np.ndarray
    loop_predicted: np.ndarray
    margins: Margins
    worst_db: float = math.nan
    worst_db_at: float = math.nan
    worst_deg: float = math.nan
    worst_deg_at: float = math.nan


@dataclass
class FrfReport:
    """What :func:`frf_analysis` found: the window ``start``..``end`` [s from the first
    state], ``period`` [s], the checked band ``band`` (Hz, Hz), the law and its loop, and
    one :class:`JointFrf` per excited joint."""

    bag: str
    law: str
    period: float
    delay: int
    centre: np.ndarray
    start: float
    end: float
    band: tuple[float, float]
    loop: ClosedLoop
    joints: list[JointFrf]
    warnings: list[str] = field(default_factory=list)


def gain_db(h) -> np.ndarray:
    """20 log10 |h| [dB]."""
    return 20.0 * np.log10(np.abs(h))


def phase_deg(h) -> np.ndarray:
    """angle(h) [deg] in (-180, 180]."""
    return np.degrees(np.angle(h))


def phase_difference(a, b) -> np.ndarray:
    """angle(a / b) [deg], wrapped to (-180, 180]."""
    return np.degrees(np.angle(np.asarray(a) / np.asarray(b)))


def excitation_window(q_des: np.ndarray, qd_des: np.ndarray, period: float,
                      dwell: float = DWELL) -> tuple[int, int]:
    """``(start, stop)`` sample indices of the excitation (see the module docstring):
    ``q_des``, ``qd_des`` (N, n) rad, rad/s on the period's grid. FrfError when the
    reference never leaves its final value."""
    centre = q_des[-1]
    dev = np.abs(q_des - centre).max(axis=1)
    speed = np.abs(np.nan_to_num(qd_des)).max(axis=1)
    moving = np.flatnonzero(dev > REST_TOL)
    if moving.size == 0:
        raise FrfError('the reference never leaves its final value: no excitation to '
                       'analyse (record a chirp: planner mode chirp)')
    last = int(moving[-1])
    rest = (dev <= REST_TOL) & (speed <= REST_TOL)
    need = max(1, int(round(dwell / period)))
    start = 0
    run = 0
    for k in range(last):
        run = run + 1 if rest[k] else 0
        if run >= need:
            start = k + 1 - need  # keep the dwell's samples: the chirp starts from rest
    # the start of the final dwell before the excursion: keep a little rest before it
    if start:
        k = start
        while k < last and rest[k]:
            k += 1
        start = max(start, k - need)
    if not rest[start]:
        raise FrfError(f'the reference does not start at rest at the value it ends on '
                       f'(q_des = {np.array2string(q_des[start], precision=4)} rad, final '
                       f'{np.array2string(centre, precision=4)} rad): a move, not an '
                       'excitation about a pose (record a chirp: planner mode chirp)')
    return start, len(q_des)


def estimate(x: np.ndarray, y: np.ndarray, period: float, nperseg: int | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """H1 estimate of ``y`` (N, m) per ``x`` (N,), sampled every ``period`` s.

    Returns ``freqs`` (F,) Hz, ``cross`` (F, m) ``S_xy`` and ``auto`` (F,) ``S_xx`` (one
    rectangular segment of the whole record when ``nperseg`` is None, else Hann segments
    of ``nperseg`` samples half overlapping, zero-padded to at least 4x the record for a
    fine grid); ``H1 = cross / auto``."""
    n = len(x)
    fs = 1.0 / period
    if nperseg is None:
        kw: dict[str, Any] = dict(window='boxcar', nperseg=n, noverlap=0,
                                  nfft=max(4 * n, 1 << 12), detrend=False)
    else:
        kw = dict(window='hann', nperseg=nperseg, noverlap=nperseg // 2, detrend=False)
    f, sxx = signal.welch(x, fs=fs, **kw)
    _, sxy = signal.csd(x[:, None], y, fs=fs, axis=0, **kw)
    return f, sxy, sxx


def coherence(x: np.ndarray, y: np.ndarray, period: float, freqs: np.ndarray,
              segments: int = COHERENCE_SEGMENTS) -> np.ndarray:
    """Magnitude-squared coherence of ``y`` (N,) with ``x`` (N,) from Welch Hann segments
    (``2 segments / (segments + 1)`` of the record... about N / ``segments`` x 2 long,
    half overlapping), interpolated to ``freqs`` (F,) Hz."""
    nper = max(16, int(2 * len(x) / (segments + 1)))
    f, c = signal.coherence(x, y, fs=1.0 / period, window='hann', nperseg=nper,
                            noverlap=nper // 2, detrend=False)
    return np.interp(freqs, f, c)


def robot_of(bag: BagData, warnings: list[str]):
    """The plant model of the bag's ``arm_sim_robot`` record (defaults for what it lacks)."""
    known = {s.name for s in ROBOT_PARAMS}
    given = {k: v for k, v in (bag.robot or {}).items() if k in known}
    if not bag.robot:
        warnings.append('no arm_sim_robot record in the bag: predicting with the default '
                        'robot')
    try:
        return robot_model(resolve_robot(given))
    except ValueError as exc:
        raise FrfError(f'arm_sim_robot record: {exc}') from None


def _grid(js: JointStates, ref: JointStates) -> tuple[np.ndarray, ...]:
    """States and references on common stamps (re-sent duplicates dropped)."""
    keep = np.r_[True, np.diff(js.stamp) != 0]
    st, q, qd = js.stamp[keep], js.position[keep], js.velocity[keep]
    order = np.argsort(ref.stamp, kind='stable')
    rs = ref.stamp[order]
    last = np.r_[rs[1:] != rs[:-1], True]
    rs = rs[last]
    rq, rqd, ru = (a[order][last] for a in (ref.position, ref.velocity, ref.effort))
    common, i_s, i_r = np.intersect1d(st, rs, return_indices=True)
    return common, q[i_s], qd[i_s], rq[i_r], rqd[i_r], ru[i_r]


def frf_analysis(bag: BagData | str | Path, *, law: str = 'computed_torque',
                 gains: Gains | None = None, delay: int = 0, f_min: float = 0.1,
                 f_max: float | None = None, nperseg: int | None = None) -> FrfReport:
    """Estimate and predict the frequency response of the excitation in ``bag``.

    Parameters
    ----------
    bag : a bag path or what :func:`arm_bag.reader.read_bag` returned
    law, gains : the controller's law and gains (bags do not record them)
    delay : control periods between a state and the torque answering it (lockstep: 0)
    f_min, f_max : Hz, the band checked against the prediction (default f_max: a third of
        the Nyquist rate)
    nperseg : samples per Welch segment of the estimate (None: the whole window, one
        rectangular segment)

    Raises FrfError (one line) for a bag without states, reference or excitation.
    """
    data = read_bag(bag) if isinstance(bag, (str, Path)) else bag
    warnings = list(data.warnings)
    js, ref = data.joint_states, data.reference
    if js is None or len(js) == 0:
        raise FrfError(f'{data.path}: no joint_states messages')
    if ref is None or len(ref) == 0:
        raise FrfError(f'{data.path}: no arm_controller/reference messages: the frequency '
                       "response needs the controller's reference")
    if ref.names != js.names:
        raise FrfError(f'reference joints {list(ref.names)} differ from the states\' '
                       f'{list(js.names)}')
    stamps, q, qd, rq, rqd, ru = _grid(js, ref)
    if len(stamps) < 64:
        raise FrfError(f'only {len(stamps)} joint states have a reference with the same '
                       'stamp: too few for a frequency response')
    steps = np.diff(stamps)
    period = float(np.median(steps)) * 1e-9
    if not (np.abs(steps - np.median(steps)) <= 1000).all():
        raise FrfError('the states are not on one control period\'s grid (missing or '
                       'irregular stamps): the frequency response needs evenly sampled data')
    start, stop = excitation_window(rq, rqd, period)
    sl = slice(start, stop)
    centre = rq[-1].copy()
    dev_r = rq[sl] - centre
    amp = np.abs(dev_r).max(axis=0)
    excited = np.flatnonzero(amp > 1e-9)
    ref_j = int(excited[np.argmax(amp[excited])])
    x = dev_r[:, ref_j]
    v = dev_r.T @ x / (x @ x)        # amplitude of each joint per unit of the reference
    resid = np.abs(dev_r - np.outer(x, v)).max(axis=0)
    if (resid[excited] > 1e-6 * amp[excited]).any():
        raise FrfError('the excited joints do not move with proportional signals: excite '
                       'one joint at a time, or all with the same sweep')
    nyq = 0.5 / period
    f_hi = nyq / 3.0 if f_max is None else f_max
    if not 0 < f_min < f_hi <= nyq:
        raise FrfError(f'band {f_min:g} .. {f_hi:g} Hz must satisfy 0 < f_min < f_max <= '
                       f'Nyquist {nyq:g} Hz')
    plant = robot_of(data, warnings)
    gains = Gains() if gains is None else gains
    if len(gains.kp) != plant.n_dof:
        raise FrfError(f'gains have {len(gains.kp)} values per joint, the bag\'s robot '
                       f'{plant.n_dof} joints')
    try:
        loop = closed_loop(law, gains, plant, centre, period, delay=delay)
    except ValueError as exc:
        raise FrfError(str(exc)) from None
    dq = q[sl] - loop.q_eq
    dx = np.hstack([dq, qd[sl]])
    du = ru[sl] - loop.tau_eq
    f, s_xy, s_xx = estimate(x, np.hstack([dx, du]), period, nperseg)
    n = plant.n_dof
    in_band = (f >= f_min * (1 - 1e-9)) & (f <= f_hi * (1 + 1e-9))
    if not in_band.any():
        raise FrfError(f'no frequency of the estimate lies in {f_min:g} .. {f_hi:g} Hz '
                       '(the window is too short)')
    power = 10.0 * np.log10(np.maximum(s_xx, 1e-300) / s_xx[in_band].max())
    excited_bins = power >= EXCITED_DB
    covered = excited_bins[in_band].mean()
    if covered < 0.9:
        lo_hi = f[in_band & excited_bins]
        span = f'{lo_hi.min():.3g} .. {lo_hi.max():.3g} Hz' if lo_hi.size else 'nowhere'
        raise FrfError(f'the reference is no broadband excitation: within {-EXCITED_DB:g} '
                       f'dB of its peak only {span} of the band {f_min:g} .. {f_hi:g} Hz '
                       '(record a chirp: planner mode chirp)')
    keep = f > 0
    f, s_xy, s_xx, excited_bins = f[keep], s_xy[keep], s_xx[keep], excited_bins[keep]
    in_band = in_band[keep]
    h_x = s_xy[:, :2 * n] / s_xx[:, None]
    cx = loop.feedback(f)
    fb = np.einsum('fij,fj->fi', cx, s_xy[:, :2 * n])
    x_pred, u_pred = loop.responses(f)
    xp = x_pred @ v
    up = u_pred @ v
    fb_pred = np.einsum('fij,fj->fi', cx, xp)
    marg = loop_margins(loop)
    joints = []
    for j in excited:
        meas = h_x[:, j] / v[j]
        pred = xp[:, j] / v[j]
        coh = coherence(x, dq[:, j], period, f)
        jf = JointFrf(int(j), js.names[j], float(amp[j]), f, meas, pred, coh, excited_bins,
                      fb[:, j] / s_xy[:, 2 * n + j], fb_pred[:, j] / up[:, j], marg[j])
        check = in_band & excited_bins
        ddb = np.abs(gain_db(meas[check]) - gain_db(pred[check]))
        ddeg = np.abs(phase_difference(meas[check], pred[check]))
        fc = f[check]
        jf.worst_db, jf.worst_db_at = float(ddb.max()), float(fc[np.argmax(ddb)])
        jf.worst_deg, jf.worst_deg_at = float(ddeg.max()), float(fc[np.argmax(ddeg)])
        joints.append(jf)
    t0 = stamps[0]
    return FrfReport(data.path, law, period, delay, centre, (stamps[start] - t0) * 1e-9,
                     (stamps[stop - 1] - t0) * 1e-9, (f_min, f_hi), loop, joints, warnings)


def _fmt_margins(m: Margins) -> str:
    gm = ('inf (phase never -180 deg below Nyquist)' if not math.isfinite(m.gain_db)
          else f'{m.gain_db:.2f} dB at {m.phase_crossover:.3g} Hz')
    low = ('' if not math.isfinite(m.lower_gain_db)
           else f' (lower: {m.lower_gain_db:.2f} dB at {m.lower_crossover:.3g} Hz)')
    pm = ('none (gain never crosses 0 dB)' if not math.isfinite(m.phase_deg)
          else f'{m.phase_deg:.2f} deg at {m.gain_crossover:.3g} Hz')
    return f'gain margin {gm}{low}; phase margin {pm}'


def format_frf(rep: FrfReport) -> str:
    """The text ``arm-sim analyze --frf`` prints."""
    lines = [f'{rep.bag}: frequency response, law {rep.law}, control period '
             f'{rep.period * 1e3:g} ms, delay {rep.delay} periods; excitation '
             f'{rep.start:.2f} .. {rep.end:.2f} s about q = '
             f'{np.array2string(rep.centre, precision=4)} rad (rest under the law: '
             f'{np.array2string(rep.loop.q_eq, precision=4)} rad)']
    lo, hi = rep.band
    for jf in rep.joints:
        lines.append('')
        lines.append(f'{jf.name} (amplitude {jf.amplitude:.4g} rad): closed loop q / q_des')
        lines.append(f"{'f Hz':>8} {'meas dB':>9} {'pred dB':>9} {'meas deg':>9} "
                     f"{'pred deg':>9} {'coh':>6} {'ret dB':>8} {'ret deg':>9} "
                     f"{'pred ret dB':>12} {'pred ret deg':>13}")
        for f in (*[f for f in TABLE_FREQUENCIES if lo <= f <= hi], hi):
            k = int(np.argmin(np.abs(jf.freqs - f)))
            m, p, lm, lp = (jf.measured[k], jf.predicted[k], jf.loop_measured[k],
                            jf.loop_predicted[k])
            lines.append(f'{jf.freqs[k]:8.3f} {gain_db(m):9.3f} {gain_db(p):9.3f} '
                         f'{phase_deg(m):9.2f} {phase_deg(p):9.2f} {jf.coherence[k]:6.3f} '
                         f'{gain_db(lm):8.2f} {phase_deg(lm):9.2f} {gain_db(lp):12.2f} '
                         f'{phase_deg(lp):13.2f}')
        lines.append(f'worst difference {lo:g} .. {hi:.3g} Hz: {jf.worst_db:.3f} dB at '
                     f'{jf.worst_db_at:.3g} Hz, {jf.worst_deg:.3f} deg at '
                     f'{jf.worst_deg_at:.3g} Hz')
        lines.append('ret: the return ratio at the plant input, measured with the command '
                     '(the feedback part of the command per unit of command) and predicted')
        lines.append(f'predicted loop (broken at {jf.name}\'s torque, the other joints '
                     f'closed): {_fmt_margins(jf.margins)}')
    return '\n'.join(lines)


# ---------------------------------------------------------------------- synthetic runs
@dataclass
class LockstepRun:
    """A closed-loop run on the control period's grid: ``t`` (N,) s; state ``q``, ``qd``
    (N, n) at ``t``; ``applied`` (N, n) N m, the torque held over the period ending at
    ``t`` (zeros at the first); reference ``q_des``, ``qd_des`` (N, n) and the command
    ``tau`` (N, n) N m (saturated) answering the state at ``t``."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    applied: np.ndarray
    q_des: np.ndarray
    qd_des: np.ndarray
    tau: np.ndarray


def lockstep_run(plant, law: str, gains: Gains, reference, duration: float, *,
                 q0, period_ns: int = 10_000_000, physics_step_ns: int = 1_000_000,
                 effort_limits=None, model=None) -> LockstepRun:
    """The lockstep loop without ROS: the simulator core (:class:`arm_dynamics.simulation.
    SimulatorCore`, RK4 physics steps, the command held and saturated over each period)
    answered at every state by the controller's law (:class:`arm_control.laws.ControlLaw`)
    for ``reference(t)`` -> ``(q_des, qd_des, qdd_des)`` (each (n,)), from rest at ``q0``
    for ``duration`` s. What the nodes do in lockstep, for tests and the docs picture."""
    from arm_control.laws import ControlLaw
    from arm_dynamics.simulation import SimulatorCore

    n = plant.n_dof
    limits = np.full(n, 1e6) if effort_limits is None else np.asarray(effort_limits, float)
    sim = SimulatorCore(plant, q0=q0, qd0=np.zeros(n), effort_limits=limits,
                        physics_step_ns=physics_step_ns, control_period_ns=period_ns,
                        velocity_limit=1e3, joint_names=[f'joint{i + 1}' for i in range(n)])
    ctrl = ControlLaw(law, gains, plant if model is None else model, tuple(limits))
    steps = int(round(duration * 1e9 / period_ns)) + 1
    out = {k: np.zeros((steps, n)) for k in ('q', 'qd', 'applied', 'q_des', 'qd_des', 'tau')}
    period = period_ns * 1e-9
    for k in range(steps):
        t = k * period_ns * 1e-9
        q_des, qd_des, qdd_des = reference(t)
        cmd = ctrl(sim.q, sim.qd, q_des, qd_des, qdd_des, period if k else 0.0)
        for name, value in (('q', sim.q), ('qd', sim.qd), ('applied', sim.applied),
                            ('q_des', q_des), ('qd_des', qd_des), ('tau', cmd.tau)):
            out[name][k] = value
        sim.set_command(cmd.tau.tolist())
        sim.advance()
        if sim.diverged:
            raise RuntimeError(sim.diverged)
    return LockstepRun(np.arange(steps) * period, **out)


def write_run_bag(path: str | Path, run: LockstepRun, robot: dict | None = None,
                  names=None) -> Path:
    """Write ``run`` as an arm_sim bag (``joint_states`` and ``arm_controller/reference``
    per period, the ``arm_sim_robot`` record ``robot``; default: the default robot)."""
    from arm_bag.synthetic import joint_state_block, open_bag
    from arm_dynamics.robot import ROBOT_DEFAULTS

    robot = dict(ROBOT_DEFAULTS) if robot is None else robot
    names = tuple(robot.get('joint_names', ROBOT_DEFAULTS['joint_names'])) \
        if names is None else tuple(names)
    w, ch = open_bag(path, robot=robot)
    stamps = np.round(run.t * 1e9).astype(np.int64) + 1_000_000_000
    states = joint_state_block(stamps, run.q, run.qd, run.applied, names)
    refs = joint_state_block(stamps, run.q_des, run.qd_des, run.tau, names)
    log = 1
    for s, r in zip(states, refs):
        w.write(ch['/joint_states'], s, log)
        w.write(ch['/arm_controller/reference'], r, log + 1)
        log += 2
    w.close()
    return Path(path)
