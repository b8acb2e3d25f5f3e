"""Make docs/frf-bode.png: the Bode diagram of a chirp run through the pure pipeline.

The run is test/test_frf.py's acceptance run: a log chirp 0.05 -> 17 Hz over 40 s,
amplitude 0.001 rad on both joints, about the demo pose (-0.4, 1.2) rad, through the
lockstep loop without ROS (arm_bag.frf.lockstep_run: the simulator core, RK4 1 ms steps,
the law's torque held over each 10 ms period), written to a bag and analysed as
``arm-sim analyze BAG --frf --plot`` does. Prints the analysis.

    .venv/bin/python bench/frf_picture.py [--law pd|computed_torque|...] [--out PNG]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from arm_bag.frf import format_frf, frf_analysis, lockstep_run, write_run_bag
from arm_bag.plot import plot_frf
from arm_control.closed_loop import law_equilibrium
from arm_control.laws import Gains
from arm_dynamics.models import robot_model
from arm_dynamics.robot import ROBOT_DEFAULTS
from arm_planner.excitation import chirp

DEMO = np.array([-0.4, 1.2])
PRE = 1.0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--law', default='pd')
    ap.add_argument('--amplitude', type=float, default=0.001, help='rad')
    ap.add_argument('--out', default=str(Path(__file__).resolve().parents[1] / 'docs'
                                         / 'frf-bode.png'))
    args = ap.parse_args(argv)
    plant = robot_model(ROBOT_DEFAULTS)

    def reference(t):
        q, qd, qdd = chirp([t - PRE], centre=DEMO, amplitude=args.amplitude, f0=0.05,
                           f1=17.0, duration=40.0, period=0.01)
        return q[0], qd[0], qdd[0]

    q0 = law_equilibrium(args.law, Gains(), plant, plant, DEMO)
    run = lockstep_run(plant, args.law, Gains(), reference, PRE + 45.0, q0=q0,
                       effort_limits=ROBOT_DEFAULTS['effort_limits'])
    with tempfile.TemporaryDirectory() as tmp:
        rep = frf_analysis(write_run_bag(Path(tmp) / 'chirp', run), law=args.law)
        rep.bag = f'chirp run ({args.law})'
        print(format_frf(rep))
        plot_frf(rep, args.out)
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
