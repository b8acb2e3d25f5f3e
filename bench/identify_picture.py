"""Draw docs/identify-parameters.png: ``arm-sim identify`` on the acceptance scenario.

    .venv/bin/python bench/identify_picture.py [--out docs/identify-parameters.png]

The scenario is test/test_identify.py's (its helpers are imported from there, so the
picture shows what the test asserts): a 20 s multi-sine excitation through the lockstep
closed loop (computed torque with the nominal model; the plant carries an unmodelled 1 kg
tip payload), recorded to a bag; a second bag (another seed and configuration) held out.
The picture is ``arm-sim identify``'s own (:func:`arm_sim.identify_cli.identify_figure`)
with the true parameters (the simulated arm's) added, and in its title the payload sweep's
straight-line deviation with the nominal, the identified and the correct controller model.
About 10 s.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / 'test')]

import matplotlib  # noqa: E402

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import test_identify as scenario  # noqa: E402

from arm_dynamics import identify as ident  # noqa: E402
from arm_sim import identify_cli  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', default=str(ROOT / 'docs' / 'identify-parameters.png'))
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        excite = scenario.excitation_bag(Path(tmp) / 'excite', 1)
        holdout = scenario.excitation_bag(Path(tmp) / 'holdout', 2, q0=(0.9, 1.0))
        ns = identify_cli.build_parser().parse_args([str(excite), '--holdout', str(holdout)])
        result = identify_cli.identify_bags(ns)
        result.bags = ['excite']
        result.holdout = 'holdout'
        result.nominal_source = "the bag's robot record"
        plant = scenario.NOMINAL.with_payload(scenario.PAYLOAD)
        gains = dict(kp=(100.0, 60.0), kd=(20.0, 12.0))
        dev = [1000 * scenario._line_deviation(m, gains)
               for m in (scenario.NOMINAL, result.model, plant)]
        fig = identify_cli.identify_figure(result, true=ident.base_parameters(plant))
        fig.suptitle(
            f'arm-sim identify: 1 kg unmodelled tip payload, estimated '
            f'{result.payload:.4f} kg.\nPayload sweep (1 s line, kp 100/60): line deviation '
            f'{dev[0]:.0f} mm with the nominal model, {dev[1]:.2f} mm with the identified '
            f'one (correct model {dev[2]:.2f} mm)', fontsize=9.5)
        fig.savefig(args.out, dpi=90)
        plt.close(fig)
    print(f'wrote {args.out}: payload {result.payload:.6f} kg, deviation nominal / identified '
          f'/ correct {dev[0]:.2f} / {dev[1]:.4f} / {dev[2]:.4f} mm')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
