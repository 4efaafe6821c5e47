"""The documentation lives in the repository and says what the repository holds.

* No file points to notes outside the repository: every markdown file a file
  names is one of the repository's (what a reader needs of the project's notes
  is in docs/conventions.md, docs/known_answers.md and docs/time_stepping.md).
* Every relative markdown link in README.md, REPRODUCTION.md and docs/**/*.md
  points to a file that exists, and every section cited as ``README, "Section"``
  or ``docs/page.md, "Section"`` exists.
* The developer guide's layout section names every module of the package.
* README.md is one screenful (at most 150 lines) and copies no benchmark row: every
  benchmark table lives once, in benchmarks/*.md (the docs include it from there).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCANNED_DIRS = ("capsim", "tests", "docs", "configs", "campaigns", "benchmarks")
SCANNED_FILES = ("README.md", "REPRODUCTION.md", "Makefile", "pyproject.toml")
TEXT_SUFFIXES = {".py", ".md", ".yaml", ".yml", ".toml", ".txt", ".cfg", ".ini", ".json"}
MARKDOWN = ("README.md", "REPRODUCTION.md", "docs/*.md", "docs/**/*.md")

# a path-like token naming a markdown file: it must be a file of the repository
_MD_TOKEN = re.compile(r"[\w./-]*\w\.md\b")
# absolute paths of the machines the notes were written on, and the folder beside the repository
_OUTSIDE = re.compile(r"/work/|\.\./shared\b|\bshared/\w")
_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
_CITED_SECTION = re.compile(r"(README|docs/[\w/]+\.md),\s+\"([^\"]+)\"")
README_MAX_LINES = 150
# pages the docs build generates from the code (docs/gen_reference.py): real, though not files
GENERATED = {ROOT / "docs" / "reference" / "case_file.md", ROOT / "docs" / "reference" / "quantities.md"}


def _scanned_files() -> list[Path]:
    files = [ROOT / name for name in SCANNED_FILES if (ROOT / name).is_file()]
    for d in SCANNED_DIRS:
        for p in sorted((ROOT / d).rglob("*")):
            if p.is_file() and p.suffix in TEXT_SUFFIXES and "__pycache__" not in p.parts:
                files.append(p)
    return [p for p in files if p.resolve() != Path(__file__).resolve()]


def _read(p: Path) -> str:
    try:
        return p.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        return ""


def _dangling_markdown_reference(token: str, source: Path) -> bool:
    """True when no file of the repository answers to `token`: relative to the file
    that names it, to the repository root, to docs/ or to benchmarks/, or as the name of
    a markdown file anywhere in the tree (text often names a file without its folder)."""
    for base in (source.parent, ROOT, ROOT / "docs", ROOT / "benchmarks"):
        if (base / token).is_file() or (base / token).resolve() in GENERATED:
            return False
    name = token.rsplit("/", 1)[-1]
    return not any(p.name == name for d in SCANNED_DIRS for p in (ROOT / d).rglob("*.md")) and \
        not (ROOT / name).is_file()


def _markdown_files() -> list[Path]:
    out: list[Path] = []
    for pattern in MARKDOWN:
        out.extend(sorted(ROOT.glob(pattern)))
    return out


def _prose(text: str) -> str:
    """Markdown without its code: fenced blocks, indented blocks, inline spans."""
    text = re.sub(r"^(```|~~~).*?^\1[^\n]*$", "", text, flags=re.M | re.S)
    out, prev_indent, code_indent, blank = [], 0, None, True
    for line in text.splitlines():
        indent = len(line) - len(line.lstrip(" "))
        if not line.strip():
            blank = True
            continue
        if code_indent is not None and indent >= code_indent:
            continue
        code_indent = None
        if blank and indent >= prev_indent + 4:
            code_indent = indent
            continue
        out.append(line)
        prev_indent, blank = indent, False
    return re.sub(r"`[^`]*`", "", "\n".join(out))


def _section(text: str, heading: str) -> str:
    m = re.search(rf"^## {re.escape(heading)}\s*$(.*?)(?=^## |\Z)", text, re.M | re.S)
    return m.group(1) if m else ""


def test_no_reference_to_notes_outside_the_repository():
    bad = []
    for p in _scanned_files():
        text = _read(p)
        rel = p.relative_to(ROOT)
        for lineno, line in enumerate(text.splitlines(), 1):
            tokens = _MD_TOKEN.findall(line) if ".md" in line else []
            for token in tokens:
                if _dangling_markdown_reference(token, p):
                    bad.append(f"{rel}:{lineno}: {token}")
            if _OUTSIDE.search(line):
                bad.append(f"{rel}:{lineno}: {line.strip()}")
    assert not bad, "references to files outside the repository (use docs/):\n" + "\n".join(bad)


@pytest.mark.parametrize("token,bad", [
    ("docs/known_answers.md", False),
    ("docs/time_stepping.md", False),
    ("time_stepping.md", False),       # named without its folder
    ("time_schemes.md", False),        # benchmarks/
    ("README.md", False),
    ("notes.md", True),                # no such file in the repository
    ("../elsewhere/notes.md", True),
])
def test_markdown_reference_rule(token, bad):
    assert _dangling_markdown_reference(token, ROOT / "README.md") is bad


def test_relative_markdown_links_resolve():
    broken = []
    for md in _markdown_files():
        for target in _LINK.findall(_prose(_read(md))):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
                continue  # URLs, mailto:, in-page anchors
            path = target.split("#", 1)[0]
            if not (md.parent / path).exists() and (md.parent / path).resolve() not in GENERATED:
                broken.append(f"{md.relative_to(ROOT)}: {target}")
    assert not broken, "broken relative links:\n" + "\n".join(broken)


def _headings(path: Path) -> set[str]:
    return {m.group(1).strip() for m in re.finditer(r"^#{2,4} (.+?)(?:\s*\{#[\w-]+\})?$", _read(path), re.M)}


def test_cited_sections_exist():
    missing = []
    for p in _scanned_files() + [ROOT / "README.md"]:
        text = re.sub(r"\s+", " ", _read(p))
        for page, name in _CITED_SECTION.findall(text):
            target = ROOT / ("README.md" if page == "README" else page)
            if not target.is_file() or not any(h == name or h.startswith(name + " (") for h in _headings(target)):
                missing.append(f"{p.relative_to(ROOT)}: {page}, \"{name}\"")
    assert not missing, "cited sections that do not exist:\n" + "\n".join(missing)


def test_developer_guide_layout_names_every_module():
    layout = _section(_read(ROOT / "docs" / "developer.md"), "Layout")
    assert layout, "docs/developer.md has no '## Layout' section"
    modules = sorted(p.name for p in (ROOT / "capsim").rglob("*.py") if p.name != "__init__.py")
    modules += sorted(f"{p.parent.name}/" for p in (ROOT / "capsim").glob("*/__init__.py"))
    unlisted = [m for m in modules if not re.search(rf"(?<![\w.]){re.escape(m)}(?!\w)", layout)]
    assert not unlisted, f"the developer guide's layout does not list: {unlisted}"
    for folder in ("capsim", "configs", "campaigns", "tests", "benchmarks", "docs"):
        assert re.search(rf"^\s*{folder}/", layout, re.M), f"the developer guide layout does not list {folder}/"


def _benchmark_rows() -> dict[str, str]:
    """Every data row of a table in benchmarks/*.md -> its file."""
    rows = {}
    for md in sorted((ROOT / "benchmarks").glob("*.md")):
        for line in _read(md).splitlines():
            if line.startswith("|") and not re.fullmatch(r"\|[\s|:-]+\|", line.strip()):
                rows[line.strip()] = md.name
    return rows


def test_readme_is_one_screenful():
    lines = _read(ROOT / "README.md").splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines (at most {README_MAX_LINES})"


def test_no_benchmark_row_is_copied():
    rows = _benchmark_rows()
    assert rows, "benchmarks/*.md hold no table rows"
    copied = []
    for md in [ROOT / "README.md", ROOT / "REPRODUCTION.md"] + sorted((ROOT / "docs").rglob("*.md")):
        for lineno, line in enumerate(_read(md).splitlines(), 1):
            if line.strip() in rows:
                copied.append(f"{md.relative_to(ROOT)}:{lineno}: a row of benchmarks/{rows[line.strip()]}")
    assert not copied, "benchmark rows copied (include the file in docs/benchmarks.md):\n" + "\n".join(copied)


def test_no_page_repeats_a_section_or_a_paragraph():
    """A page holds each heading once and no long paragraph twice: an edit that pasted a section again
    (docs/performance.md held its "Around the evaluations" twice for one commit) reads as two answers."""
    repeated = []
    for md in [ROOT / "README.md", ROOT / "REPRODUCTION.md"] + sorted((ROOT / "docs").rglob("*.md")):
        text = re.sub(r"^```.*?^```", "", _read(md), flags=re.S | re.M)  # not the comments of code blocks
        headings = [line for line in text.splitlines() if re.match(r"#{1,6} ", line)]
        repeated += [f"{md.relative_to(ROOT)}: heading {h!r}" for h in sorted(set(headings)) if headings.count(h) > 1]
        paragraphs = [p.strip() for p in re.split(r"\n\s*\n", text) if len(p.strip()) > 300]
        repeated += [f"{md.relative_to(ROOT)}: paragraph {p[:60]!r}…" for p in sorted(set(paragraphs))
                     if paragraphs.count(p) > 1]
    assert not repeated, "repeated in a page:\n" + "\n".join(repeated)
