"""Synthetic arm_sim bags for tests and benchmarks, written without ROS (pure)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from arm_bag.cdr import (
    decode_joint_state,
    encode_diagnostic_status,
    encode_joint_state,
    encode_joint_trajectory,
    encode_path,
)
from arm_bag.msgdefs import QosProfile, qos_yaml, schema_text, type_hash
from arm_bag.reader import PUSH_KINDS, SimEvent
from arm_bag.writer import BagWriter
from arm_dynamics.robot import JOINT_NAMES, ROBOT_DEFAULTS

NAMES = JOINT_NAMES
TOPICS = {'joint_states': 'sensor_msgs/msg/JointState',
          'arm_controller/reference': 'sensor_msgs/msg/JointState',
          'arm_controller/joint_trajectory': 'trajectory_msgs/msg/JointTrajectory',
          'planner/path': 'nav_msgs/msg/Path'}
#: Registered only when asked (:func:`open_bag`): a bag without them is byte for byte what
#: it was.
TRUE_STATE_TOPIC = {'simulator/true_joint_states': 'sensor_msgs/msg/JointState'}
EVENTS_TOPIC = {'simulator/events': 'diagnostic_msgs/msg/DiagnosticStatus'}
ROBOT = {k: ROBOT_DEFAULTS[k] for k in ('joint_names', 'link_lengths', 'effort_limits')}


def open_bag(path: str | Path, robot: dict | None = ROBOT, compression: str = 'none',
             chunk_size: int = 1 << 20, true_state: bool = False,
             events: bool = False) -> tuple[BagWriter, dict[str, int]]:
    """A BagWriter with the arm_sim topics registered (and the robot record unless None);
    ``true_state``: also ``simulator/true_joint_states`` (:func:`write_run`'s ``q_true``),
    ``events``: also ``simulator/events`` (:func:`write_events`)."""
    w = BagWriter(path, compression=compression, chunk_size=chunk_size)
    qos = qos_yaml([QosProfile()])
    topics = {**TOPICS, **(TRUE_STATE_TOPIC if true_state else {}),
              **(EVENTS_TOPIC if events else {})}
    ch = {'/' + t: w.add_topic('/' + t, ty, schema_text(ty), qos, type_hash(ty))
          for t, ty in topics.items()}
    if robot is not None:
        w.add_metadata('arm_sim_robot', {k: json.dumps(v) for k, v in robot.items()})
    return w, ch


def joint_state_block(stamps_ns: np.ndarray, position: np.ndarray, velocity: np.ndarray,
                      effort: np.ndarray, names=NAMES) -> list[bytes]:
    """CDR JointStates for N samples at once: stamps (N,) ns; arrays (N, J)."""
    j = len(names)
    template = encode_joint_state(0, names, [0.0] * j, [0.0] * j, [0.0] * j)
    *_, layout = decode_joint_state(template)
    n = len(stamps_ns)
    rows = np.tile(np.frombuffer(template, np.uint8), (n, 1))
    sec, nsec = np.divmod(np.asarray(stamps_ns, np.int64), 1_000_000_000)
    rows[:, 4:8] = sec.astype('<i4')[:, None].view(np.uint8)
    rows[:, 8:12] = nsec.astype('<u4')[:, None].view(np.uint8)
    for (off, cnt), arr in zip((layout.position, layout.velocity, layout.effort),
                               (position, velocity, effort)):
        rows[:, off:off + 8 * cnt] = np.ascontiguousarray(arr, '<f8').view(np.uint8)
    blob = rows.tobytes()
    size = len(template)
    return [blob[i * size:(i + 1) * size] for i in range(n)]


def write_run(w: BagWriter, ch: dict[str, int], t0_log: int, t: np.ndarray,
              q: np.ndarray, qd: np.ndarray, tau: np.ndarray, ref: np.ndarray | None,
              trajectory: tuple[np.ndarray, np.ndarray] | None = None,
              path_xy: np.ndarray | None = None, stamp0: int = 0,
              path_start: int | None = None, q_true: np.ndarray | None = None) -> int:
    """Write one segment: a trajectory (positions (P, 2), times (P,) s, stamped ``stamp0``:
    it starts there) and path (its poses stamped ``path_start`` [ns], default ``stamp0``)
    at ``t0_log`` [ns receive time], then a joint state (and reference, and with
    ``q_true`` (N, J) rad a true state: velocity ``qd``, effort ``tau``, a bag opened with
    ``true_state``) per sample of ``t`` [s, simulated time from ``stamp0`` ns], received
    1 us apart. Returns the next free receive time."""
    log = t0_log
    if trajectory is not None:
        w.write(ch['/arm_controller/joint_trajectory'],
                encode_joint_trajectory(stamp0, NAMES, *trajectory), log)
        log += 1000
    if path_xy is not None:
        w.write(ch['/planner/path'], encode_path(stamp0, path_xy, pose_stamp_ns=path_start),
                log)
        log += 1000
    stamps = stamp0 + np.round(np.asarray(t) * 1e9).astype(np.int64)
    states = joint_state_block(stamps, q, qd, tau)
    refs = (joint_state_block(stamps, ref, np.zeros_like(ref), tau)
            if ref is not None else None)
    trues = joint_state_block(stamps, q_true, qd, tau) if q_true is not None else None
    js, rc = ch['/joint_states'], ch['/arm_controller/reference']
    for i, data in enumerate(states):
        if trues is not None:  # as the simulator: the true state, then the measured one
            w.write(ch['/simulator/true_joint_states'], trues[i], log)
            log += 1000
        w.write(js, data, log)
        log += 1000
        if refs is not None:
            w.write(rc, refs[i], log)
            log += 1000
    return log


def encode_event(event: SimEvent) -> bytes:
    """A ``simulator/events`` message (diagnostic_msgs/DiagnosticStatus) as the simulator
    publishes it: level, name and message from ``event``, hardware_id '', values time_ns,
    kind, edge, label."""
    return encode_diagnostic_status(
        event.level, event.name, event.description, '',
        [('time_ns', str(event.time_ns)), ('kind', event.kind), ('edge', event.edge),
         ('label', event.label)])


def make_event(time_ns: int, kind: str, edge: str, label: str, description: str = ''
               ) -> SimEvent:
    """A :class:`~arm_bag.reader.SimEvent` as the simulator makes it: a push (level 0,
    'simulator: push') for the push kinds, else a fault (level 1, 'simulator: fault')."""
    push = kind in PUSH_KINDS
    return SimEvent(int(time_ns), f"simulator: {'push' if push else 'fault'}", kind, edge,
                    label, description or f"{'push' if push else 'fault'}: {kind}",
                    0 if push else 1)


def write_events(w: BagWriter, ch: dict[str, int], events, log: int) -> int:
    """Write ``events`` (:class:`~arm_bag.reader.SimEvent`) on ``simulator/events`` (a bag
    opened with ``events``) from receive time ``log`` [ns] on, 1 us apart; returns the
    next free receive time."""
    for event in events:
        w.write(ch['/simulator/events'], encode_event(event), log)
        log += 1000
    return log
