"""Terminal table of one or several analysis reports, and the pushes and faults of each
(pure)."""

from __future__ import annotations

from arm_bag.analysis import Report, Segment
from arm_bag.metrics import DISTURBANCE_METRICS, METRICS, PUSH_METRICS, Metric


def _head(m: Metric) -> str:
    """A metric's column or row label: its label and unit."""
    return f'{m.label} [{m.unit}]'


_ROWS: tuple[tuple[str, str, str], ...] = (
    # (label, Segment attribute, format): where the segment is, then every metric of the
    # table (arm_bag.metrics.METRICS), labelled with its unit.
    ('mode', 'mode', 's'),
    ('duration [s]', 'duration', '.3f'),
    ('samples', 'samples', 'd'),
    ('reference', 'reference', 's'),
) + tuple((_head(m), m.name, m.fmt) for m in METRICS)
#: Rows of the figures only some bags have (``friction_loss``): shown where defined.
_EXTRA_ROWS: tuple[tuple[str, str, str], ...] = tuple(
    (_head(m), m.name, m.fmt) for m in DISTURBANCE_METRICS if m.when != 'push')
_FRICTION = next(m for m in DISTURBANCE_METRICS if m.name == 'friction_loss')


def _fmt(value, fmt: str) -> str:
    if value is None:
        return '-'
    if isinstance(value, (list, tuple)):
        return ' / '.join(_fmt(v, fmt) for v in value)
    if fmt == 'pct':
        return f'{100.0 * value:.1f}'
    if fmt == 's':
        return str(value)
    if fmt == 'd':
        return str(int(value))
    return format(value, fmt)


def format_table(reports: list[Report]) -> str:
    """One column per bag, one block of rows per segment; per-joint values ``j1 / j2``."""
    header = ['metric'] + [r.bag for r in reports]
    rows: list[list[str]] = [header]
    n_seg = max((len(r.segments) for r in reports), default=0)
    rows.append(['joints'] + [', '.join(r.joint_names) for r in reports])
    rows.append(['run duration [s]'] + [f"{r.run['duration']:.3f}" for r in reports])
    rows.append(['run energy [J]'] + [_fmt(r.run['energy'], '.3f') for r in reports])
    if any('friction_loss' in r.run for r in reports):  # a robot with Coulomb friction
        rows.append([f'run {_head(_FRICTION)}']
                    + [_fmt(r.run.get('friction_loss'), _FRICTION.fmt) for r in reports])
    rows.append(['robot parameters'] + [r.robot_source for r in reports])
    if any(r.state_source != 'joint_states' for r in reports):  # a noisy or delayed arm
        rows.append(['positions from'] + [r.state_source for r in reports])
    for k in range(n_seg):
        rows.append([f'-- segment {k}'] + [''] * len(reports))
        for label, attr, fmt in _ROWS + _EXTRA_ROWS:
            cells = []
            for r in reports:
                seg: Segment | None = r.segments[k] if k < len(r.segments) else None
                cells.append('' if seg is None else _fmt(getattr(seg, attr), fmt))
            if any(c not in ('', '-') for c in cells):
                rows.append([f'  {label}'] + cells)
    return _columns(rows, rule=True)


def _columns(rows: list[list[str]], rule: bool = False, indent: str = '') -> str:
    """``rows`` as left-aligned columns (a rule of dashes under the first if ``rule``)."""
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = [(indent + '  '.join(c.ljust(w) for c, w in zip(row, widths))).rstrip()
             for row in rows]
    if rule:
        lines.insert(1, indent + '  '.join('-' * w for w in widths))
    return '\n'.join(lines)


def format_events(reports: list[Report]) -> str:
    """Each report's pushes (a table: when, which, the response figures of
    :data:`arm_bag.metrics.PUSH_METRICS`, what) and faults (a list: from, until, which,
    what); '' when no report has any."""
    blocks = []
    for r in reports:
        name = f' ({r.bag})' if len(reports) > 1 else ''
        if r.pushes:
            rows = [['time [s]', 'end [s]', 'label'] + [_head(m) for m in PUSH_METRICS]
                    + ['description']]
            for p in r.pushes:
                rows.append([_fmt(p['time'], '.3f'), _fmt(p['end'], '.3f'), p['label']]
                            + [_fmt(p.get(m.name), m.fmt) for m in PUSH_METRICS]
                            + [p['description']])
            blocks.append(f'pushes{name}\n' + _columns(rows, rule=True, indent='  '))
        if r.faults:
            lines = [f'faults{name}']
            for f in r.faults:
                until = ('to the end' if f['end'] is None else f"until {f['end']:.3f} s")
                lines.append(f"  {f['time']:.3f} s {until}  {f['label']} ({f['kind']}): "
                             f"{f['description']}")
            blocks.append('\n'.join(lines))
    return '\n\n'.join(blocks)
