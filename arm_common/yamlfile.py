"""Reading a user's YAML file with bounds (pure: no rclpy): the sweep specs, the
disturbance scenarios and the check suites all come through here.

A file of a few lines can still cost without bound: an alias repeats a node without
copying it, so nine nested ones make 10^9 values; a file can be huge, or nested thousands
deep. :func:`read_yaml` reads at most ``max_bytes``, decodes UTF-8, and parses with
PyYAML's safe loader refusing anchors, aliases and collections nested deeper than
``max_depth`` while composing, before anything is built. Every error is one line.
"""

from __future__ import annotations

from pathlib import Path


class YamlFileError(ValueError):
    """The file cannot be read as bounded YAML; the message (one line) says why, without
    the file name (the caller puts it where its own errors have it)."""


def read_yaml(path: str | Path, *, max_bytes: int, max_depth: int, what: str) -> object:
    """The parsed YAML of ``path`` (None for an empty file).

    ``max_bytes``: a longer file is refused (``more than N bytes: <what>``, ``what`` saying
    what the file should be, e.g. 'a spec is a short text'); ``max_depth``: collections
    nested deeper are refused. Raises :class:`YamlFileError` for an unreadable file, too
    many bytes, text that is not UTF-8, anchors or aliases (naming the line), too deep
    nesting, or bad YAML.
    """
    import yaml

    try:
        with open(path, 'rb') as f:
            data = f.read(max_bytes + 1)
    except OSError as exc:
        raise YamlFileError(f'cannot read it: {exc.strerror or exc}') from None
    if len(data) > max_bytes:
        raise YamlFileError(f'more than {max_bytes} bytes: {what}')
    try:
        text = data.decode('utf-8')
    except UnicodeDecodeError as exc:
        raise YamlFileError(f'not UTF-8 text: {exc.reason} at byte {exc.start}') from None

    class BoundedLoader(yaml.SafeLoader):
        depth = 0

        def compose_node(self, parent, index):
            event = self.peek_event()
            line = event.start_mark.line + 1
            if isinstance(event, yaml.AliasEvent) or getattr(event, 'anchor', None):
                mark = '*' if isinstance(event, yaml.AliasEvent) else '&'
                raise YamlFileError(f'line {line}: YAML anchors and aliases '
                                    f'({mark}{event.anchor}) are not accepted: write the '
                                    'values out')
            if self.depth >= max_depth:
                raise YamlFileError(f'line {line}: nested more than {max_depth} levels deep')
            self.depth += 1
            try:
                return super().compose_node(parent, index)
            finally:
                self.depth -= 1

    try:
        return yaml.load(text, Loader=BoundedLoader)  # a yaml.SafeLoader subclass
    except yaml.YAMLError as exc:
        first = str(exc).strip().splitlines()
        raise YamlFileError(f"not YAML: {' '.join(s.strip() for s in first)}") from None
