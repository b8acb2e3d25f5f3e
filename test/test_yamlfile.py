"""arm_common.yamlfile: the bounded YAML reading the sweep specs, disturbance scenarios and
check suites share (each caller's own tests check its messages in place)."""

from __future__ import annotations

import pytest

from arm_common.yamlfile import YamlFileError, read_yaml


def read(tmp_path, text: str | bytes, **kw):
    path = tmp_path / 'f.yaml'
    (path.write_bytes if isinstance(text, bytes) else path.write_text)(text)
    return read_yaml(path, **{'max_bytes': 1000, 'max_depth': 4, 'what': 'short', **kw})


def test_a_plain_file_reads_as_safe_yaml(tmp_path):
    assert read(tmp_path, 'a: [1, 2.5, x]\nb: {c: true}\n') == {'a': [1, 2.5, 'x'],
                                                               'b': {'c': True}}
    assert read(tmp_path, '') is None


@pytest.mark.parametrize('text, reason', [
    ('a: &x [1]\nb: *x\n', 'line 1: YAML anchors and aliases (&x) are not accepted'),
    ('a: ' + '[' * 6 + ']' * 6, 'line 1: nested more than 4 levels deep'),
    ('a: "' + 'x' * 1001 + '"', 'more than 1000 bytes: short'),
    (b'a: \xff\n', 'not UTF-8 text'),
    ('a: [1,\n', 'not YAML'),
    ('!!python/object:os.system {}', 'not YAML'),
])
def test_what_could_cost_without_bound_or_is_not_yaml_is_refused_in_one_line(
        tmp_path, text, reason):
    with pytest.raises(YamlFileError, match=reason.replace('(', r'\(').replace(')', r'\)')
                       .replace('[', r'\[')) as exc:
        read(tmp_path, text)
    assert '\n' not in str(exc.value)


def test_an_alias_bomb_is_refused_before_anything_is_built(tmp_path):
    lines = ['a0: &a0 [x, x, x, x, x, x, x, x, x, x]']
    lines += [f'a{i}: &a{i} [*a{i - 1}] ' for i in range(1, 9)]
    with pytest.raises(YamlFileError, match='anchors and aliases'):
        read(tmp_path, '\n'.join(lines), max_depth=100)


def test_an_unreadable_file_says_why(tmp_path):
    with pytest.raises(YamlFileError, match='cannot read it: No such file'):
        read_yaml(tmp_path / 'missing.yaml', max_bytes=10, max_depth=2, what='x')
