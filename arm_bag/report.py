"""Terminal table of one or several analysis reports (pure)."""

from __future__ import annotations

from arm_bag.analysis import Report, Segment
from arm_bag.metrics import METRICS

_ROWS: tuple[tuple[str, str, str], ...] = (
    # (label, Segment attribute, format): where the segment is, then every metric of the
    # table (arm_bag.metrics.METRICS), labelled with its unit.
    ('mode', 'mode', 's'),
    ('duration [s]', 'duration', '.3f'),
    ('samples', 'samples', 'd'),
    ('reference', 'reference', 's'),
) + tuple((f'{m.label} [{m.unit}]', m.name, m.fmt) for m in METRICS)


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
    rows.append(['robot parameters'] + [r.robot_source for r in reports])
    if any(r.state_source != 'joint_states' for r in reports):  # a noisy or delayed arm
        rows.append(['positions from'] + [r.state_source for r in reports])
    for k in range(n_seg):
        rows.append([f'-- segment {k}'] + [''] * len(reports))
        for label, attr, fmt in _ROWS:
            cells = []
            for r in reports:
                seg: Segment | None = r.segments[k] if k < len(r.segments) else None
                cells.append('' if seg is None else _fmt(getattr(seg, attr), fmt))
            if any(c not in ('', '-') for c in cells):
                rows.append([f'  {label}'] + cells)
    widths = [max(len(row[i]) for row in rows) for i in range(len(header))]
    lines = ['  '.join(c.ljust(w) for c, w in zip(row, widths)).rstrip() for row in rows]
    lines.insert(1, '  '.join('-' * w for w in widths))
    return '\n'.join(lines)
