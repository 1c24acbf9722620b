"""The README and the docs describe the project as it is.

* No development history: no numbered work periods ("session 7"), issue numbers, commit hashes,
  dates or clock times, names of development tools, or the load of the machine a figure was
  measured on.  History belongs in commit messages.
* Every relative link resolves: the file exists and a ``#anchor`` names one of its headings
  (GitHub's slugs).
* Every ``docs/….md`` that code, scripts and tests name exists.
* The README stays a front door (about 150 lines).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])

HISTORY = {
    "a numbered work period": re.compile(r"\bsessions?[ -]\d+", re.IGNORECASE),
    "an issue number": re.compile(r"\b(?:issues?|PR) ?#?\d+", re.IGNORECASE),
    "a commit hash": re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b"),
    "a date": re.compile(r"\b(?:19|20)\d\d-[01]\d-[0-3]\d\b"),
    "a clock time": re.compile(r"\b[0-2]\d:[0-5]\d(?:[-–][0-2]\d:[0-5]\d)? UTC\b"),
    "a development tool": re.compile(r"\bfarm-(?:bench|studio)\b", re.IGNORECASE),
    "the machine's load": re.compile(r"\bload average[ ~]*\d|\bat load ~?\d|\(load ~?\d", re.IGNORECASE),
}


def _rel(p: Path) -> str:
    return p.relative_to(ROOT).as_posix()


def _without_code(text: str) -> str:
    """The text without fenced code blocks and inline code (links there are not links)."""
    text = re.sub(r"^```.*?^```", "", text, flags=re.MULTILINE | re.DOTALL)
    return re.sub(r"`[^`\n]*`", "", text)


def slugs(text: str) -> set[str]:
    """GitHub's anchors of a page's headings: lower case, punctuation dropped, spaces to hyphens,
    repeats numbered."""
    seen: dict[str, int] = {}
    out = set()
    body = re.sub(r"^```.*?^```", "", text, flags=re.MULTILINE | re.DOTALL)
    for m in re.finditer(r"^#{1,6} +(.+?) *#*$", body, re.MULTILINE):
        s = re.sub(r"[^\w\- ]", "", m.group(1).lower()).replace(" ", "-")
        n = seen.get(s, 0)
        seen[s] = n + 1
        out.add(s if n == 0 else f"{s}-{n}")
    return out


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_no_development_history(page):
    found = []
    for n, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1):
        for what, rx in HISTORY.items():
            for m in rx.finditer(line):
                found.append(f"{_rel(page)}:{n}: {what}: {m.group(0)!r} in {line.strip()[:120]!r}")
    assert not found, "development history in the docs:\n" + "\n".join(found)


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_links_resolve(page):
    text = page.read_text(encoding="utf-8")
    bad = []
    for m in re.finditer(r"!?\[[^\]]*\]\(([^)\s]+)\)", _without_code(text)):
        target = m.group(1)
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            bad.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in slugs(dest.read_text(encoding="utf-8")):
            bad.append(f"{target}: no heading with that anchor in {_rel(dest)}")
    assert not bad, f"{_rel(page)}: broken links:\n" + "\n".join(bad)


def test_docs_named_in_the_code_exist():
    missing = []
    for folder in ("phyir", "viewer", "tests", "scripts", "benchmarks", "shaders", ".ci"):
        for f in (ROOT / folder).rglob("*"):
            if f.suffix not in (".py", ".sh", ".toml", ".glsl", ".frag", ".vert", "") or not f.is_file():
                continue
            text = f.read_text(encoding="utf-8", errors="replace")
            for m in re.finditer(r"\bdocs/([\w./-]+?\.md)\b", text):
                if not (ROOT / "docs" / m.group(1)).is_file():
                    missing.append(f"{_rel(f)}: docs/{m.group(1)}")
    assert not missing, "docs named in the code that do not exist:\n" + "\n".join(sorted(set(missing)))


def test_the_readme_is_a_front_door():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert 100 <= len(lines) <= 200, f"README.md has {len(lines)} lines; about 150 keeps it a front door"
