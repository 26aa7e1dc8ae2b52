"""The user documentation as the tests read it: README.md and the pages under docs/ (all but
docs/readme_claims.md, the map of their claims to tests). Shared by test_readme.py,
test_readme_claims.py, test_readme_claims_ros.py and the other tests that check documented text."""
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PAGES = ['README.md', 'docs/cli.md', 'docs/ros.md', 'docs/library.md', 'docs/accuracy.md', 'docs/solver.md',
         'docs/calibration.md', 'docs/performance.md', 'docs/development.md', 'docs/architecture.md',
         'docs/camera_info_model.md', 'docs/report.md', 'docs/cli_output.md']
"""Every user page, README first; a new page under docs/ must be added here
(test_readme.py::test_every_docs_page_is_checked)."""


def page(name: str) -> str:
    return (REPO / name).read_text()


def all_pages() -> str:
    return '\n\n'.join(page(name) for name in PAGES)


def section(name: str, title: str) -> str:
    """The text of the section of page ``name`` whose heading starts with ``title``, up to the
    next heading of the same or a higher level (its subsections included)."""
    text = page(name)
    match = re.search(rf'^(#+) {re.escape(title)}.*?$', text, re.M)
    assert match, f'{name}: no heading starting with {title!r}'
    level = len(match.group(1))
    rest = text[match.end():]
    end = re.search(rf'^#{{1,{level}}} ', _blank_code(rest), re.M)
    return rest[:end.start()] if end else rest


def _blank_code(text: str) -> str:
    """``text`` with the lines of its fenced code blocks blanked (same length), so that a '#'
    comment in a shell block is never taken for a heading."""
    out, inside = [], False
    for line in text.splitlines(keepends=True):
        if line.lstrip(' ').startswith('```'):
            inside = not inside
            out.append(line)
        else:
            out.append(' ' * (len(line) - 1) + ('\n' if line.endswith('\n') else '') if inside else line)
    return ''.join(out)


def fenced_blocks(text: str):
    """(info string, body, text after the block) of every fenced code block (also indented ones,
    as in a list item)."""
    blocks, lines, i = [], text.splitlines(keepends=True), 0
    while i < len(lines):
        stripped = lines[i].lstrip(' ')
        if stripped.startswith('```'):
            indent = len(lines[i]) - len(stripped)
            info, body, i = stripped[3:].strip(), [], i + 1
            while not lines[i].lstrip(' ').startswith('```'):
                body.append(lines[i][indent:] if lines[i][:indent].strip() == '' else lines[i])
                i += 1
            blocks.append((info, ''.join(body), ''.join(lines[i + 1:])))
        i += 1
    return blocks


def markdown_rows(text: str):
    """Cells of every markdown table row in ``text`` (separator rows left out)."""
    rows = []
    for line in text.splitlines():
        if line.startswith('|') and not re.fullmatch(r'\|[-:| ]+\|', line.strip()):
            rows.append([c.strip() for c in line.strip().strip('|').split('|')])
    return rows


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces made '-'."""
    text = re.sub(r'[`*_]', '', heading.strip().lower())
    text = re.sub(r'[^\w\- ]', '', text)
    return text.replace(' ', '-')


def anchors(name: str) -> set:
    return {slug(m.group(2)) for m in re.finditer(r'^(#+) (.+?)\s*$', _blank_code(page(name)), re.M)}
