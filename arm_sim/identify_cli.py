"""``arm-sim identify BAG...``: the arm's dynamic parameters from recorded runs (no rclpy).

Reads the joint states of each bag (the torque each state's ``effort`` says was held over
the control period ending there), estimates the base parameters by weighted least squares
on the momentum form integrated over each hold period (:mod:`arm_dynamics.identify`),
prints them with standard errors beside the nominal arm's, the tip payload that explains
the change, and the check on a held-out bag; writes the identified model as a params file
the controller loads (``control_model.*``) and a picture. Errors are one line and an exit
code, never a traceback. docs/identify.md is the user's page.

Exit codes: 0 ok; 2 usage (a bad option, nominal params file or output path: checked
before any work); 3 the data cannot identify the arm (no hold periods, no motion, a
regressor that does not excite the parameters, a robot model other than two_link, or no
physical arm with the identified parameters); 4 a bag that cannot be read.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
import yaml

from arm_common.exits import EXIT_NOTHING, EXIT_OK, EXIT_UNREADABLE, EXIT_USAGE
from arm_control.model_params import MODEL_KEYS as CONTROLLER_MODEL_KEYS
from arm_dynamics import identify as ident
from arm_dynamics.robot import ROBOT_DEFAULTS, ROBOT_PARAMS, resolve_robot
from arm_dynamics.two_link import TwoLinkArm

#: The controller's model parameters the params file sets (``control_model.<key>``:
#: :data:`arm_control.model_params.MODEL_KEYS` plus gravity).
MODEL_KEYS = (*CONTROLLER_MODEL_KEYS, 'gravity')
CONTROLLER_SECTION = '/**/controller'

DESCRIPTION = """\
Estimate the arm's dynamic parameters from recorded runs: the base parameters, the
groupings of masses, centre-of-gravity distances and inertias the torques depend on (ZZ1R =
I1 + m1 lc1^2 + m2 l1^2 [kg m^2], MX1R = m1 lc1 + m2 l1 [kg m], ZZ2 = I2 + m2 lc2^2 [kg m^2],
MX2 = m2 lc2 [kg m]) and the joints' viscous friction FV1, FV2 [N m s/rad], by weighted
least squares, with standard errors and the regressor's condition number. The link lengths
and gravity are the nominal arm's. Then the tip payload [kg] that takes the nominal arm to
the identified one, the torque prediction error on a held-out bag [N m RMS and %], and the
identified model as a params file for the controller.

Each bag must hold joint states with position, velocity and effort (what the simulator
publishes: the effort is the torque held over the control period ending at that state) of
a motion that excites every parameter: the planner's chirp mode about a configuration,
both joints, ~0.15 rad, 0.2-1.5 Hz (docs/identify.md). Exit codes: 0 ok, 2 usage (bad option,
params file or output path), 3 the data cannot identify the arm, 4 unreadable bag."""


class IdentifyError(Exception):
    """A one-line error with its exit code."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


def add_identify_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``identify`` sub-command to an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        'identify', help="estimate the arm's dynamic parameters (and a tip payload) from bags",
        description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    _arguments(p)
    p.set_defaults(func=run_identify)
    return p


def _arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('bags', nargs='+', metavar='BAG',
                   help='bag directory or .mcap file of an excitation run; several are '
                   'pooled (they should share the control period)')
    p.add_argument('--holdout', metavar='BAG', default=None,
                   help='another bag, not used for the estimate: prints how well the '
                   'identified model (and the nominal one) predict its torques [N m RMS, '
                   "%% of the RMS torque]")
    p.add_argument('--nominal', metavar='PARAMS.yaml', default=None,
                   help="ROS 2 params file whose /** section is the nominal arm (the link "
                   'lengths [m] and gravity [m/s^2] the identification uses, the masses '
                   '[kg] the payload is measured from), e.g. config/arm.yaml; default: the '
                   "first bag's robot record (what the recorder ran with), else the "
                   'robot defaults')
    p.add_argument('--damping', choices=('identified', 'known'), default='identified',
                   help="joint viscous friction [N m s/rad]: identified (default) or held at "
                   "the nominal arm's joint_damping")
    p.add_argument('--params-out', metavar='FILE.yaml', default=None,
                   help='write a ROS 2 params file: the --nominal file (default the shipped '
                   'config/arm.yaml) with the controller\'s control_model.* set to the '
                   'identified arm (link masses [kg], com distances [m], inertias [kg m^2], '
                   'damping [N m s/rad]); load it with `arm-sim bringup --params-file '
                   'FILE.yaml` or `ros2 run arm_sim controller --ros-args --params-file '
                   'FILE.yaml`')
    p.add_argument('--plot', metavar='FILE.png', default=None,
                   help='write a picture: identified vs nominal parameters (error bars 2 '
                   'standard errors) and, with --holdout, measured vs predicted torques')
    p.add_argument('--json', action='store_true',
                   help='print JSON (parameters, payload, holdout, model) instead of text')


def build_parser() -> argparse.ArgumentParser:
    """A parser of ``arm-sim identify``'s arguments alone (for :func:`main`)."""
    p = argparse.ArgumentParser(prog='arm-sim identify', description=DESCRIPTION,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    _arguments(p)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """``arm-sim identify`` on its own: parse ``argv`` and run; returns the exit code."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # argparse: usage error (2) or --help (0)
        return int(exc.code or 0)
    return run_identify(args)


# ---------------------------------------------------------------------- the work
@dataclass
class Result:
    """What one ``identify`` run found (the JSON output is :meth:`to_dict`)."""

    bags: list[str]
    nominal: TwoLinkArm
    nominal_source: str
    periods: ident.HoldPeriods
    estimate: ident.Estimate
    payload: float
    payload_se: float
    model: TwoLinkArm
    holdout: str | None = None
    holdout_periods: ident.HoldPeriods | None = None
    holdout_rms: np.ndarray | None = None
    holdout_pct: np.ndarray | None = None
    nominal_rms: np.ndarray | None = None
    nominal_pct: np.ndarray | None = None
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        est, nom = self.estimate, ident.base_parameters(self.nominal)
        out: dict[str, Any] = {
            'bags': self.bags,
            'periods': len(self.periods),
            'duration_s': float(self.periods.period.sum()),
            'condition_number': est.condition,
            'residual_rms_nm': est.residual_rms.tolist(),
            'nominal_source': self.nominal_source,
            'parameters': [
                {'name': p.name, 'formula': p.formula, 'unit': p.unit,
                 'estimate': float(est.values[i]), 'std_error': float(est.std_errors[i]),
                 'held': i in est.fixed, 'nominal': float(nom[i])}
                for i, p in enumerate(ident.BASE_PARAMETERS)],
            'payload_kg': {'estimate': self.payload, 'std_error': self.payload_se},
            'model': model_values(self.model),
            'warnings': self.warnings,
        }
        if self.holdout is not None:
            assert self.holdout_rms is not None and self.nominal_rms is not None
            out['holdout'] = {'bag': self.holdout, 'periods': len(self.holdout_periods or ()),
                              'rms_error_nm': self.holdout_rms.tolist(),
                              'rms_error_percent': _nan_none(self.holdout_pct),
                              'nominal_rms_error_nm': self.nominal_rms.tolist(),
                              'nominal_rms_error_percent': _nan_none(self.nominal_pct)}
        return out


def _nan_none(a) -> list:
    return [None if not math.isfinite(v) else float(v) for v in np.asarray(a, float)]


def model_values(arm: TwoLinkArm) -> dict[str, Any]:
    """The controller model parameters of ``arm`` (names :data:`MODEL_KEYS`)."""
    return {k: (list(getattr(arm, k)) if k != 'gravity' else float(arm.gravity))
            for k in MODEL_KEYS}


def _read(path: str) -> tuple[ident.HoldPeriods, dict | None, list[str]]:
    """The hold periods of a bag's joint states, its robot record and its warnings."""
    from arm_bag.cli import reason
    from arm_bag.reader import BagError, read_bag

    try:
        bag = read_bag(path, lean=True)
    except BagError as exc:
        raise IdentifyError(reason(exc), EXIT_UNREADABLE) from None
    except (OSError, MemoryError) as exc:
        raise IdentifyError(f'{path}: cannot read: {reason(exc)}', EXIT_UNREADABLE) from None
    js = bag.joint_states
    if js is None or len(js) == 0:
        raise IdentifyError(f'{path}: no joint states (sensor_msgs/JointState on '
                            'joint_states) to identify from', EXIT_NOTHING)
    if js.position.shape[1] != 2:
        raise IdentifyError(f'{path}: joint states of {js.position.shape[1]} joints; '
                            'identify takes the 2-R arm (model two_link)', EXIT_NOTHING)
    order = np.argsort(js.stamp, kind='stable')
    periods = ident.hold_periods(js.stamp[order], js.position[order], js.velocity[order],
                                 js.effort[order])
    if len(periods) == 0:
        raise IdentifyError(f'{path}: no control period with position, velocity and effort '
                            'at both ends (identify needs the states the simulator '
                            'publishes)', EXIT_NOTHING)
    return periods, bag.robot, list(bag.warnings)


def _nominal(args: argparse.Namespace, record: dict | None, warnings: list[str]
             ) -> tuple[TwoLinkArm, str]:
    """The nominal arm: --nominal's /** section, else the bag's robot record, else the
    defaults."""
    if args.nominal:
        from arm_sim.urdf_cli import robot_params_from_file

        try:
            given = robot_params_from_file(args.nominal)
            robot = resolve_robot(given)
        except ValueError as exc:
            raise IdentifyError(f'--nominal {args.nominal}: {exc}', EXIT_USAGE) from None
        source = f'--nominal {args.nominal}'
    elif record:
        known = {s.name for s in ROBOT_PARAMS}
        try:
            robot = resolve_robot({k: v for k, v in record.items() if k in known})
        except ValueError as exc:
            raise IdentifyError(f"{args.bags[0]}: its robot record is unusable: {exc}; give "
                                'the nominal arm with --nominal PARAMS.yaml',
                                EXIT_NOTHING) from None
        source = f"{args.bags[0]}'s robot record"
    else:
        robot = dict(ROBOT_DEFAULTS)
        source = 'the robot defaults'
        warnings.append(f'{args.bags[0]}: no robot record in the bag: the nominal arm is the '
                        'robot defaults (give another with --nominal PARAMS.yaml)')
    if robot.get('model', 'two_link') != 'two_link':
        raise IdentifyError(f"the nominal arm's model is {robot['model']!r}: identify takes "
                            'the 2-R arm (model two_link)', EXIT_NOTHING)
    return TwoLinkArm.from_params(robot), source


def identify_bags(args: argparse.Namespace) -> Result:
    """The identification ``args`` asks for (raises :class:`IdentifyError`)."""
    warnings: list[str] = []
    parts, records = [], []
    for path in args.bags:
        periods, record, w = _read(path)
        parts.append(periods)
        records.append(record)
        warnings += w
    nominal, source = _nominal(args, records[0], warnings)
    if not args.nominal:
        for path, rec in zip(args.bags[1:], records[1:]):
            if rec != records[0]:
                warnings.append(f'{path}: its robot record differs from {args.bags[0]}\'s; '
                                'the nominal arm is the first')
    steps = sorted({round(float(p.period[0]) * 1e9) for p in parts})
    if len(steps) > 1:
        warnings.append(f'the bags have different control periods ({steps} ns)')
    periods = ident.HoldPeriods.concatenate(parts)
    l1, g0 = nominal.link_lengths[0], nominal.gravity
    fixed = ({ident.FV1: nominal.joint_damping[0], ident.FV2: nominal.joint_damping[1]}
             if args.damping == 'known' else {})
    if g0 == 0.0:
        fixed[ident.MX1R] = float(ident.base_parameters(nominal)[ident.MX1R])
    try:
        est = ident.identify(periods, l1, g0, fixed)
        mass, se = ident.payload_mass(est, nominal)
        model = ident.identified_arm(est.values, nominal, mass, est.std_errors)
        resolve_robot(model_values(model))  # what the controller checks the values with
    except ValueError as exc:
        names = ', '.join(args.bags)
        raise IdentifyError(f'{names}: {exc}', EXIT_NOTHING) from None
    result = Result(list(args.bags), nominal, source, periods, est, mass, se, model,
                    warnings=warnings)
    if args.holdout:
        hp, _, w = _read(args.holdout)
        warnings += w
        result.holdout, result.holdout_periods = args.holdout, hp
        result.holdout_rms, result.holdout_pct = ident.prediction_error(est.values, hp, l1, g0)
        result.nominal_rms, result.nominal_pct = ident.prediction_error(
            ident.base_parameters(nominal), hp, l1, g0)
    return result


# ---------------------------------------------------------------------- outputs
def params_file_text(result: Result, base: str | Path | None) -> str:
    """The params file: ``base`` (a ROS 2 params file; None: the shipped config/arm.yaml)
    with ``/**/controller``'s ``control_model.*`` set to the identified arm."""
    if base is None:
        from arm_sim.launcher import config_file

        base = config_file()
    data = yaml.safe_load(Path(base).read_text()) or {}
    if not isinstance(data, dict):
        raise ValueError(f'{base} is not a ROS 2 params file')
    section = data.setdefault(CONTROLLER_SECTION, {})
    if not isinstance(section, dict):
        raise ValueError(f'{base}: {CONTROLLER_SECTION} is not a mapping')
    params = section.setdefault('ros__parameters', {})
    for k, v in model_values(result.model).items():
        params[f'control_model.{k}'] = v
    head = (f"# Written by arm-sim identify from {', '.join(result.bags)}: {base} with the\n"
            '# controller\'s model (control_model.*) set to the identified arm: tip payload '
            f'{result.payload:.4f} +- {result.payload_se:.2g} kg\n'
            f'# over the nominal arm ({result.nominal_source}). Load it with\n'
            '#   arm-sim bringup --params-file THIS_FILE   or\n'
            '#   ros2 run arm_sim controller --ros-args --params-file THIS_FILE\n')
    return head + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)


def text_report(result: Result) -> str:
    """The human-readable report."""
    est, nom = result.estimate, ident.base_parameters(result.nominal)
    n = len(result.periods)
    lines = [f"identified from {', '.join(result.bags)}: {n} hold periods "
             f'({result.periods.period.sum():.2f} s), regressor condition number '
             f'{est.condition:.3g} (columns scaled; < 100 is a good excitation)',
             f'nominal arm: {result.nominal_source}', '',
             f"{'parameter':<10}{'grouping':<26}{'estimate':>13}{'std error':>11}"
             f"{'nominal':>12}  unit"]
    for i, p in enumerate(ident.BASE_PARAMETERS):
        se = 'held' if i in est.fixed else f'{est.std_errors[i]:.2g}'
        lines.append(f'{p.name:<10}{p.formula:<26}{est.values[i]:>13.6f}{se:>11}'
                     f'{nom[i]:>12.6f}  {p.unit}')
    r = est.residual_rms
    lines += ['', f'tip payload over the nominal arm: {result.payload:.4f} kg (std error '
              f'{result.payload_se:.2g} kg)',
              f'torque residual on these bags: RMS {r[0]:.3g} / {r[1]:.3g} N m (joint 1 / 2)']
    if result.holdout is not None:
        assert result.holdout_rms is not None and result.holdout_pct is not None
        assert result.nominal_rms is not None and result.nominal_pct is not None
        h, hp = result.holdout_rms, result.holdout_pct
        m, mp = result.nominal_rms, result.nominal_pct
        lines += [f'held-out check on {result.holdout} ({len(result.holdout_periods or ())} '
                  'periods): torque prediction error RMS',
                  f'  identified model: {h[0]:.3g} / {h[1]:.3g} N m = {hp[0]:.3g} / '
                  f'{hp[1]:.3g} % of the RMS torque (joint 1 / 2)',
                  f'  nominal model:    {m[0]:.3g} / {m[1]:.3g} N m = {mp[0]:.3g} / '
                  f'{mp[1]:.3g} %']
    mv = model_values(result.model)
    lines += ['', 'identified model (control_model.*): ' + '; '.join(
        f"{k} {_fmt(v)}" for k, v in mv.items() if k != 'gravity')]
    return '\n'.join(lines)


def _fmt(v: Any) -> str:
    return '[' + ', '.join(f'{x:.6g}' for x in v) + ']' if isinstance(v, list) else f'{v:.6g}'


def identify_figure(result: Result, true: Sequence[float] | None = None) -> Any:
    """The picture: identified vs nominal (and ``true`` (6,), if known) base parameters
    with 2-standard-error bars; with a held-out bag, its measured torque against the
    identified and the nominal models' predictions. The caller closes it."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    held = result.holdout_periods
    fig = plt.figure(figsize=(12, 7.5 if held is not None else 4.5))
    grid = fig.add_gridspec(3 if held is not None else 1, 2, width_ratios=(1, 1.6),
                            hspace=0.45, wspace=0.25)
    ax = fig.add_subplot(grid[:, 0])
    est, nom = result.estimate, ident.base_parameters(result.nominal)
    y = np.arange(len(ident.NAMES))[::-1]
    ax.barh(y + 0.2, nom, 0.38, color='0.75', label='nominal arm')
    ax.barh(y - 0.2, est.values, 0.38, xerr=2 * est.std_errors, color='tab:blue',
            capsize=3, label='identified, ±2 std errors')
    if true is not None:
        ax.plot(true, y - 0.2, 'kd', ms=7, label='true (the simulated arm)')
    for yi, v, s in zip(y, est.values, est.std_errors):
        ax.annotate(f'{v:.4f} ± {s:.1g}', (max(v, 0.0), yi - 0.2), xytext=(8, 0),
                    textcoords='offset points', va='center', fontsize=8)
    ax.set_yticks(y, [f'{p.name}\n[{p.unit}]' for p in ident.BASE_PARAMETERS], fontsize=8)
    ax.set_xlabel('value (unit beside each name)')
    ax.set_title(f'base parameters: tip payload {result.payload:.4f} kg', fontsize=10)
    ax.legend(fontsize=7, loc='lower right')
    ax.set_xlim(0, max(float(np.max(est.values)), float(np.max(nom))) * 1.45)
    if held is not None:
        l1, g0 = result.nominal.link_lengths[0], result.nominal.gravity
        t = (held.end_ns - held.end_ns[0]) * 1e-9
        pred = ident.predict(est.values, held, l1, g0)
        pnom = ident.predict(nom, held, l1, g0)
        shown = t <= min(float(t[-1]), 8.0)
        assert result.holdout_rms is not None and result.nominal_rms is not None
        for j in range(2):
            a = fig.add_subplot(grid[j, 1])
            a.plot(t[shown], held.tau[shown, j], color='k', lw=2.5, alpha=0.35,
                   label='measured (held torque)')
            a.plot(t[shown], pred[shown, j], color='tab:blue', lw=1,
                   label=f'identified model (RMS error {result.holdout_rms[j]:.2g} N m)')
            a.plot(t[shown], pnom[shown, j], color='tab:red', lw=1, ls='--',
                   label=f'nominal model (RMS error {result.nominal_rms[j]:.2g} N m)')
            a.set_ylabel(f'joint {j + 1} torque [N m]')
            lo, hi = a.get_ylim()
            a.set_ylim(lo, hi + 0.5 * (hi - lo))  # room for the legend above the curves
            a.legend(fontsize=7, loc='upper center', ncol=2, framealpha=0.9)
            if j == 0:
                a.set_title(f'held-out bag {Path(result.holdout or "").name}: torque '
                            'prediction', fontsize=10)
        a = fig.add_subplot(grid[2, 1])
        err = pred - held.tau
        for j, c in enumerate(('tab:blue', 'tab:green')):
            a.plot(t[shown], err[shown, j], color=c, lw=1, label=f'joint {j + 1}')
        a.set_ylabel('identified model\nerror [N m]')
        a.set_xlabel('time in the held-out bag [s]')
        a.legend(fontsize=7, loc='best')
    return fig


def _prepare(path: str | None, what: str):
    """An :class:`~arm_sim.sweep.output.OutputFile` for ``path``, checked now."""
    if not path:
        return None
    from arm_sim.sweep.output import OutputError, OutputFile

    out = OutputFile(path)
    try:
        out.prepare()
    except OutputError as exc:
        raise IdentifyError(f'{what}: {exc}', EXIT_USAGE) from None
    return out


def run_identify(args: argparse.Namespace) -> int:
    """Run ``identify``; returns the exit code (bad input: one line on stderr)."""
    from arm_sim.sweep.output import OutputError

    outputs = []
    fmt = 'png'
    try:
        if args.nominal and not Path(args.nominal).is_file():
            raise IdentifyError(f'--nominal {args.nominal}: no such file', EXIT_USAGE)
        if args.plot:
            from arm_sim.sweep.output import plot_format

            try:
                fmt = plot_format(args.plot)
            except ValueError as exc:
                raise IdentifyError(f'--plot {args.plot}: {exc}', EXIT_USAGE) from None
        params_out = _prepare(args.params_out, '--params-out')
        plot_out = _prepare(args.plot, '--plot')
        outputs = [o for o in (params_out, plot_out) if o is not None]
        result = identify_bags(args)
        for w in result.warnings:
            print(f'warning: {w}', file=sys.stderr)
        if params_out is not None:
            try:
                text = params_file_text(result, args.nominal)
            except (OSError, ValueError, yaml.YAMLError) as exc:
                raise IdentifyError(f'--params-out: cannot make the params file: '
                                    f'{" ".join(str(exc).split())}', EXIT_USAGE) from None

            def fill(f: IO) -> None:
                f.write(text)

            params_out.write(fill)
        if plot_out is not None:
            import matplotlib.pyplot as plt

            fig = identify_figure(result)
            try:
                plot_out.write(lambda f: fig.savefig(f, format=fmt, dpi=100), binary=True)
            finally:
                plt.close(fig)
        if args.json:
            doc = result.to_dict()
            doc['params_out'] = args.params_out
            print(json.dumps(doc, indent=2))
        else:
            print(text_report(result))
            if args.params_out:
                print(f'wrote {args.params_out}: load it with `arm-sim bringup --params-file '
                      f'{args.params_out}`')
    except IdentifyError as exc:
        print(f'arm-sim identify: {" ".join(str(exc).split())}', file=sys.stderr)
        return exc.code
    except OutputError as exc:
        print(f'arm-sim identify: {exc}', file=sys.stderr)
        return EXIT_USAGE
    finally:  # nothing half-written is left (a written file's temporary is gone already)
        for o in outputs:
            o.discard()
    return EXIT_OK
