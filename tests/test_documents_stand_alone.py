"""The documents, the code's comments and the examples stand alone: they cite no file outside
the repository and no tracker number, and "seed" means only a random seed.

The first test is ``grep -rn "issue [0-9]\\|PROCEDURES.md\\|DESIGN.md" README.md docs src
examples`` (build output such as ``*.egg-info`` left out: it is made from README.md)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _files():
    yield ROOT / "README.md"
    for top in ("docs", "src", "examples"):
        for path in sorted((ROOT / top).rglob("*")):
            if path.is_file() and not any(p.endswith(".egg-info") or p == "__pycache__"
                                          for p in path.parts):
                yield path


def _hits(pattern):
    found = []
    for path in _files():
        try:
            text = path.read_text(encoding="utf-8")
        except (UnicodeDecodeError, OSError):
            continue
        for n, line in enumerate(text.splitlines(), 1):
            if pattern.search(line):
                found.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()[:120]}")
    return found


@pytest.mark.parametrize("what,pattern", [
    ("tracker numbers and files outside the repository",
     re.compile(r"issue [0-9]|PROCEDURES\.md|DESIGN\.md")),
    ('"seed" for the source method (it means a random seed; the method is "the patent")',
     re.compile(r"(?<!random )\bseed's\b|\bseed 00[0-9]\b|\bseed patent\b|\bseeds/", re.I)),
])
def test_documents_stand_alone(what, pattern):
    hits = _hits(pattern)
    assert not hits, f"{what}:\n" + "\n".join(hits)


#: a Markdown link to a file of the repository: [text](path) or [text](path#anchor)
LINK = re.compile(r"\]\((?!https?:|mailto:|#)([^)#\s]+)(?:#[^)]*)?\)")


def _links(path: Path) -> set[Path]:
    return {(path.parent / target).resolve()
            for target in LINK.findall(path.read_text(encoding="utf-8"))}


def test_the_readme_is_short_and_reaches_every_document():
    """A newcomer's page: at most 200 lines, and every file in docs/ is reached from it by
    links (directly or through another document), each link to a file that exists."""
    readme = ROOT / "README.md"
    assert len(readme.read_text(encoding="utf-8").splitlines()) <= 200
    reached, todo, broken = set(), [readme.resolve()], []
    while todo:
        page = todo.pop()
        if page in reached:
            continue
        reached.add(page)
        for target in _links(page):
            if not target.exists():
                broken.append(f"{page.relative_to(ROOT)} -> {target}")
            elif target.suffix == ".md":
                todo.append(target)
    assert not broken, "links to missing files:\n" + "\n".join(broken)
    docs = {p.resolve() for p in (ROOT / "docs").rglob("*.md")}
    unreached = sorted(str(p.relative_to(ROOT)) for p in docs - reached)
    assert not unreached, f"documents no link from README.md reaches: {unreached}"


def test_a_licence_file_matches_the_package_metadata():
    import tomllib

    meta = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert meta["license"] == "MIT"
    assert (ROOT / "LICENSE").read_text(encoding="utf-8").startswith("MIT License")
