"""The documentation holds together: README.md is a short front door that links every page
under docs/, and every relative link in README.md, docs/*.md and bench/README.md points to a
file that exists and, with a ``#fragment``, to a heading that exists (GitHub's heading
slugs). Pure: reads Markdown files, no ROS."""

from __future__ import annotations

import re
import unicodedata
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / 'README.md'
DOCS = ROOT / 'docs'
README_MAX_LINES = 220


def documents() -> list[Path]:
    """Every Markdown file whose links are checked."""
    return [README, *sorted(DOCS.glob('*.md')), ROOT / 'bench' / 'README.md']


# --- Markdown, as far as links and headings need it ---------------------------------------

_FENCE = re.compile(r'^ {0,3}(`{3,}|~{3,})')
_ATX = re.compile(r'^ {0,3}(#{1,6})(?:[ \t]+(.*?))?(?:[ \t]+#+)?[ \t]*$')
_SETEXT = re.compile(r'^ {0,3}(=+|-+)[ \t]*$')
# A code span: a run of backticks, then text without a blank line, then the same run.
_CODE_SPAN = re.compile(r'(?<!`)(`+)(?!`)((?:(?!\n[ \t]*\n).)+?)(?<!`)\1(?!`)', re.S)
# [text](target) and ![alt](target); the target may be <...> and followed by a "title".
_INLINE_LINK = re.compile(r'!?\[(?P<text>(?:[^\[\]]|\[[^\[\]]*\])*)\]'
                          r'\(\s*(?P<target><[^>\n]*>|[^\s)]+)(?:\s+(?:"[^"]*"|\'[^\']*\'))?\s*\)')
# [label]: target (a reference definition).
_REFERENCE_DEF = re.compile(r'^ {0,3}\[(?P<text>[^\]]+)\]:[ \t]*(?P<target><[^>\n]*>|\S+)',
                            re.M)
_SCHEME = re.compile(r'^[A-Za-z][A-Za-z0-9+.-]*:')


def _without_fenced_code(text: str) -> str:
    """``text`` with every line of a fenced code block blanked (offsets kept)."""
    out = []
    fence = ''
    for line in text.split('\n'):
        m = _FENCE.match(line)
        if fence:
            if m and m.group(1)[0] == fence[0] and len(m.group(1)) >= len(fence) \
                    and not line.strip()[len(m.group(1)):].strip():
                fence = ''
            out.append(' ' * len(line))
        elif m:
            fence = m.group(1)
            out.append(' ' * len(line))
        else:
            out.append(line)
    return '\n'.join(out)


def _without_code_spans(text: str) -> str:
    """``text`` with every code span blanked (offsets and newlines kept)."""
    return _CODE_SPAN.sub(lambda m: re.sub(r'[^\n]', ' ', m.group(0)), text)


def heading_texts(text: str) -> list[str]:
    """The headings of a Markdown document, in order, as written (ATX and setext)."""
    lines = _without_fenced_code(text).split('\n')
    found = []
    for i, line in enumerate(lines):
        m = _ATX.match(line)
        if m:
            found.append((m.group(2) or '').strip())
            continue
        prev = lines[i - 1] if i else ''
        if (_SETEXT.match(line) and prev.strip() and not prev.lstrip().startswith(('|', '#'))
                and not _ATX.match(prev) and not _SETEXT.match(prev)):
            found.append(prev.strip())
    return found


def github_slug(heading: str) -> str:
    """The anchor GitHub gives a heading: its rendered text (code, emphasis and link markup
    removed) in lower case, every character but letters, digits, '-', '_' and spaces
    removed, each space made a '-' (github-slugger)."""
    text = re.sub(r'!?\[([^\]]*)\]\([^)]*\)', r'\1', heading)   # links -> their text
    text = re.sub(r'<[^>]+>', '', text)                          # inline HTML tags
    text = text.replace('`', '').lower()
    kept = ''.join(c for c in text
                   if c in ' -_' or unicodedata.category(c)[0] in 'LMN')
    return kept.replace(' ', '-')


def heading_slugs(text: str) -> set[str]:
    """Every heading anchor of a document; a repeated slug gets -1, -2, ... as on GitHub."""
    seen: dict[str, int] = {}
    slugs: set[str] = set()
    for heading in heading_texts(text):
        base = slug = github_slug(heading)
        while slug in slugs:
            seen[base] = seen.get(base, 0) + 1
            slug = f'{base}-{seen[base]}'
        slugs.add(slug)
    return slugs


@dataclass(frozen=True)
class Link:
    line: int      # 1-based
    text: str
    target: str    # as written

    def __str__(self) -> str:
        return f'[{self.text}]({self.target})'


def links_in(text: str) -> list[Link]:
    """Every inline link, image and reference definition outside code."""
    clean = _without_code_spans(_without_fenced_code(text))   # same offsets as ``text``
    found = []
    for pattern in (_INLINE_LINK, _REFERENCE_DEF):
        for m in pattern.finditer(clean):
            target = text[m.start('target'):m.end('target')]
            if target.startswith('<') and target.endswith('>'):
                target = target[1:-1]
            found.append(Link(text.count('\n', 0, m.start()) + 1,
                              text[m.start('text'):m.end('text')], target))
    return sorted(found, key=lambda link: link.line)


def link_problem(source: Path, target: str, root: Path = ROOT) -> str | None:
    """Why the relative link ``target`` written in ``source`` does not resolve (None: it
    does, or it is not relative)."""
    if _SCHEME.match(target) or target.startswith('//'):
        return None                      # http(s)://, mailto: and the like: not checked
    path_part, _, fragment = target.partition('#')
    path_part = unquote(path_part.split('?', 1)[0])
    if not path_part:
        dest = source
    elif path_part.startswith('/'):      # GitHub: relative to the repository's root
        dest = root / path_part.lstrip('/')
    else:
        dest = source.parent / path_part
    dest = dest.resolve()
    if not dest.is_relative_to(root.resolve()):
        return f'{path_part} is outside the repository'
    if not dest.exists():
        return f'{path_part} does not exist'
    if fragment and dest.is_file() and dest.suffix.lower() == '.md':
        anchor = unquote(fragment)
        if anchor not in heading_slugs(dest.read_text(encoding='utf-8')):
            where = 'this file' if dest == source.resolve() else dest.relative_to(root.resolve())
            return f'no heading in {where} has the slug #{anchor}'
    return None


def broken_links(files: list[Path], root: Path = ROOT) -> list[str]:
    """``file:line: [text](target): reason`` for every relative link that does not
    resolve."""
    problems = []
    for path in files:
        for link in links_in(path.read_text(encoding='utf-8')):
            reason = link_problem(path, link.target, root)
            if reason:
                problems.append(f'{path.relative_to(root)}:{link.line}: {link}: {reason}')
    return problems


# --- the repository's documentation ---------------------------------------------------------

def test_every_relative_link_in_the_docs_resolves():
    problems = broken_links(documents())
    assert not problems, 'broken links:\n' + '\n'.join(problems)


def test_every_docs_page_is_linked_from_the_readme():
    linked = set()
    for link in links_in(README.read_text(encoding='utf-8')):
        if not _SCHEME.match(link.target):
            path = link.target.partition('#')[0]
            if path:
                linked.add((ROOT / unquote(path)).resolve())
    unlinked = [str(p.relative_to(ROOT)) for p in sorted(DOCS.glob('*.md'))
                if p.resolve() not in linked]
    assert not unlinked, f'docs pages README.md does not link: {unlinked}'


def test_the_readme_is_at_most_220_lines():
    lines = README.read_text(encoding='utf-8').count('\n')
    assert lines <= README_MAX_LINES, (
        f'README.md has {lines} lines (at most {README_MAX_LINES}): it is the front door; '
        'move detail into a page under docs/ and link it from the map of the docs')


@pytest.mark.parametrize('page', sorted(DOCS.glob('*.md')), ids=lambda p: p.name)
def test_every_docs_page_starts_with_a_title_and_a_summary(page):
    lines = page.read_text(encoding='utf-8').split('\n')
    assert lines[0].startswith('# ') and lines[0][2:].strip(), \
        f'{page.relative_to(ROOT)}:1: the page must start with a "# Title" line'
    rest = [line for line in lines[1:] if line.strip()]
    assert rest and not rest[0].lstrip().startswith(('#', '|', '```', '-', '*', '!')), \
        f'{page.relative_to(ROOT)}: the title must be followed by a summary paragraph'


# --- the checker itself: it sees what it must and fails when it should ---------------------

@pytest.mark.parametrize('heading, slug', [
    ('Time', 'time'),
    ('`arm-sim`', 'arm-sim'),
    ('ROS 2 from PyPI wheels', 'ros-2-from-pypi-wheels'),
    ('Experiments: sweeps', 'experiments-sweeps'),
    ('Python API (no ROS needed)', 'python-api-no-ros-needed'),
    ('Robot parameters (every node; `/**` in `config/arm.yaml`; read-only)',
     'robot-parameters-every-node--in-configarmyaml-read-only'),
    ('2026-11-25: real_time (new) and wall_clock (old real_time) side by side',
     '2026-11-25-real_time-new-and-wall_clock-old-real_time-side-by-side'),
    ('Before: old real_time only (now `wall_clock`)', 'before-old-real_time-only-now-wall_clock'),
    ('See [the demo](../README.md#the-demo)', 'see-the-demo'),
])
def test_headings_get_githubs_slugs(heading, slug):
    assert github_slug(heading) == slug


def test_a_repeated_heading_gets_githubs_numbered_slugs():
    text = '# A\n## Results\n## Results\n```\n## Results\n```\n## Results\nSetext\n---\n'
    assert heading_slugs(text) == {'a', 'results', 'results-1', 'results-2', 'setext'}


def test_the_link_check_reports_file_line_and_link_of_each_broken_link(tmp_path):
    (tmp_path / 'docs').mkdir()
    (tmp_path / 'img.png').write_bytes(b'')
    (tmp_path / 'docs' / 'page.md').write_text('# Page\n\n## Two words\n## Two words\n')
    readme = tmp_path / 'README.md'
    readme.write_text(
        '# Front\n\n## Here\n'
        '[ok](docs/page.md) [ok](docs/page.md#two-words-1) [ok](#here) ![ok](img.png)\n'
        '[ok](https://example.org/x.md#nope) [ok](mailto:a@b.c) [ok](docs/)\n'
        '`[in code](missing.md)`\n```\n[in a fence](missing.md)\n```\n'
        '[gone](docs/missing.md)\n'
        '[bad fragment](docs/page.md#two-words-2)\n'
        '[bad here](#nowhere) ![bad image](docs/img.png)\n'
        '[out](../elsewhere.md)\n'
        '[ref]: docs/nothing.md\n')
    assert broken_links([readme], tmp_path) == [
        'README.md:10: [gone](docs/missing.md): docs/missing.md does not exist',
        'README.md:11: [bad fragment](docs/page.md#two-words-2): '
        'no heading in docs/page.md has the slug #two-words-2',
        'README.md:12: [bad here](#nowhere): no heading in this file has the slug #nowhere',
        'README.md:12: [bad image](docs/img.png): docs/img.png does not exist',
        'README.md:13: [out](../elsewhere.md): ../elsewhere.md is outside the repository',
        'README.md:14: [ref](docs/nothing.md): docs/nothing.md does not exist',
    ]


def ros_install_lines() -> list[str]:
    """The command lines of docs/ros.md's "Use with a real ROS 2 Jazzy install" block."""
    text = (DOCS / 'ros.md').read_text()
    block = text.split('## Use with a real ROS 2 Jazzy install', 1)[1]
    block = block.split('```sh\n', 1)[1].split('```', 1)[0]
    return [line.split('#', 1)[0].strip() for line in block.splitlines() if line.strip()]


def test_the_ros_install_commands_name_executables_files_and_arguments_that_exist():
    """The lines need a ROS install to run; what they name is checked here: every
    ``ros2 run arm_sim X`` is a console script, every installed params file is shipped, every
    ``ros2 launch`` argument is declared, and ``ros2 topic pub --once`` waits for its
    subscribers (``-w``)."""
    import ast
    import re
    setup = (ROOT / 'setup.py').read_text()
    scripts = set(re.findall(r"'([\w-]+) = [\w.]+:main'", setup))
    launch = (ROOT / 'launch' / 'arm.launch.py').read_text()
    declared = {node.args[0].value for node in ast.walk(ast.parse(launch))
                if isinstance(node, ast.Call) and getattr(node.func, 'id', '') ==
                'DeclareLaunchArgument'}
    lines = ros_install_lines()
    runs = [line for line in lines if line.startswith('ros2 run')]
    assert len(runs) >= 4, lines
    for line in lines:
        words = line.split()
        if line.startswith('ros2 run'):
            assert words[2] == 'arm_sim' and words[3] in scripts, line
            for path in re.findall(r'install/arm_sim/share/arm_sim/(\S+)', line):
                assert (ROOT / path).is_file(), f'{line}: {path} is not shipped'
        elif line.startswith('ros2 launch'):
            assert words[2:4] == ['arm_sim', 'arm.launch.py'], line
        elif line.startswith('ros2 topic pub'):
            assert '--once' not in words or '-w' in words, f'{line}: --once without -w'
    comment = next(line for line in (DOCS / 'ros.md').read_text().splitlines()
                   if line.startswith('ros2 launch arm_sim'))
    for name in re.findall(r'(\w+):=', comment):
        assert name in declared, f'ros2 launch argument {name} is not declared'
