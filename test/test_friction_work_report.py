"""Every figure of a /diagnostics summary is of the simulated time the summary says.

The simulator sets its summary (``friction_work`` [J] and the counts) once per reporting
window, and /diagnostics went out on its own timer, stamped with the simulated time *at
publish*: in lockstep the figures lagged their ``sim_time`` by up to ~2 s of simulated time
(7.367 J published with a ``sim_time`` whose true friction work was 7.876 J). Now a summary
carries the simulated time it was set at (:class:`arm_common.node.Diagnostics`).

Checked on a real simulator process (lockstep, Coulomb/static friction, the test as the
controller, a sinusoidal tracking law that keeps the joints slipping): for every periodic
summary, ``friction_work`` equals the pure :class:`~arm_dynamics.simulation.SimulatorCore`'s
at that summary's ``sim_time``, run with the same answers (the node's states are the core's
bit for bit, test_real_arm.py), to the 1e-6 J the summary prints. And on a probe node: the
summary's ``sim_time`` is the one at :meth:`~arm_common.node.Diagnostics.set`.
"""

from __future__ import annotations

import math

import numpy as np

from arm_dynamics import TwoLinkArm
from arm_dynamics.friction import JointFriction
from arm_dynamics.simulation import SimulatorCore

STEP_NS, PERIOD_NS = 1_000_000, 10_000_000
NAMES = ('joint1', 'joint2')
COULOMB, STATIC = [1.5, 0.5], [1.95, 0.65]       # N m (config/real_arm.yaml's)
KP, KD = np.array([60.0, 30.0]), np.array([10.0, 4.0])
Q0 = np.array([-0.4, 1.2])                         # the simulator's default start [rad]
REPORTS = 3                                        # periodic summaries to check


def law(arm: TwoLinkArm, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """PD + gravity to a goal swinging 0.4 rad at 0.7 Hz: the joints keep slipping, so
    friction work keeps growing (a lag shows)."""
    goal = Q0 + 0.4 * math.sin(2.0 * math.pi * 0.7 * t)
    return KP * (goal - q) - KD * qd + arm.gravity_vector(q)


def summary_ns(status) -> int | None:
    from conftest import values

    v = values(status)
    if 'sim_time' not in v or 'friction_work' not in v:
        return None
    return round(float(v['sim_time']) * 1e9)


def test_summary_friction_work_is_of_its_sim_time(ros, launch):
    from conftest import statuses, values
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    from arm_sim.client import stamp_of

    launch('simulator', params={'timing_mode': 'lockstep', 'coulomb_friction': COULOMB,
                                'static_friction': STATIC})
    diags = ros.collect(DiagnosticArray, '/diagnostics')
    states = ros.collect(JointState, 'joint_states')
    pub = ros.publisher(Float64MultiArray, 'effort_controller/commands')
    ros.wait_for(lambda: states, timeout=30, what='the first state')
    arm = TwoLinkArm()
    answered: set[float] = set()

    def running() -> list:
        return [s for s in statuses(diags, '/simulator', 'summary')
                if (summary_ns(s) or 0) > 0 and s.message.startswith('running')]

    def answer() -> bool:
        m = states[-1]
        t = stamp_of(m)
        if t not in answered:
            answered.add(t)
            tau = law(arm, t, np.array(m.position), np.array(m.velocity))
            pub.publish(Float64MultiArray(data=[float(v) for v in tau]))
        return len(running()) >= REPORTS

    ros.wait_for(answer, timeout=90, what=f'{REPORTS} periodic summaries while running')
    reports = running()
    # The pure core with the same answers (the law of the state it publishes).
    core = SimulatorCore(arm, q0=Q0, qd0=[0.0, 0.0], effort_limits=[60.0, 20.0],
                         physics_step_ns=STEP_NS, control_period_ns=PERIOD_NS,
                         velocity_limit=1000.0, joint_names=NAMES,
                         friction=JointFriction(coulomb=COULOMB, static=STATIC))
    last = max(summary_ns(s) or 0 for s in reports)
    work = {0: core.friction_work}
    while core.time_ns < last:
        core.set_command(law(arm, core.time, core.q, core.qd))
        core.advance()
        work[core.time_ns] = core.friction_work
    for s in reports:
        t_ns = summary_ns(s)
        assert t_ns is not None and t_ns % PERIOD_NS == 0, values(s)
        got = float(values(s)['friction_work'])
        assert abs(got - work[t_ns]) <= 1e-6, (
            f'friction_work {got:.6f} J published with sim_time {t_ns * 1e-9:.3f} s; the '
            f'core had {work[t_ns]:.6f} J then')
    assert work[last] > 1.0, 'the joints slipped: friction took work'


def test_a_summary_keeps_the_sim_time_it_was_set_at(ros):
    """Set at 1.5 s, published after the simulated time moved on to 4.0 s: the summary
    says 1.5 s, the time of its figures."""
    from conftest import statuses, values
    from diagnostic_msgs.msg import DiagnosticArray

    from arm_common.node import Diagnostics

    node = ros.rclpy.create_node('probe', namespace='/fw_report', context=ros.context)
    ros.executor.add_node(node)
    try:
        sim = {'t': 1.5}
        diag = Diagnostics(node, period=0.2, sim_time=lambda: sim['t'])
        arrays = ros.collect(DiagnosticArray, '/diagnostics')
        diag.set('OK', 'figures of 1.5 s', widgets=3)
        sim['t'] = 4.0
        found = ros.wait_for(lambda: statuses(arrays, '/fw_report/probe', 'summary'),
                             what='a periodic report')
        assert values(found[0]) == {'sim_time': '1.500000000', 'widgets': '3'}
    finally:
        ros.executor.remove_node(node)
        node.destroy_node()
