"""docs/iso17025.md names, for each item of ISO/IEC 17025 7.8, a text the demo's rendered
plan or report contains: each is checked on the PDF's text, not on the template."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

from tests.reports.conftest import need

TABLE = Path(__file__).resolve().parents[2] / "docs" / "iso17025.md"


def _checked() -> list[tuple[str, str, str]]:
    """(clause, document, text) for every row of the table that names a text."""
    out = []
    for line in TABLE.read_text(encoding="utf-8").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 4 or not cells[3].startswith("`"):
            continue
        document, _, text = cells[3].strip("`").partition(": ")
        out.append((cells[0], document, text))
    return out


def test_the_table_covers_every_item():
    clauses = {c for c, _, _ in _checked()}
    letters = {c.split()[1] for c in clauses if c.startswith("7.8.2.1")}
    assert letters | {"h", "k"} == set("abcdefghijklmnop")  # h, k: not applicable
    assert {"7.8.2.2", "7.8.6.1", "7.8.7.2"} <= clauses
    assert any(c.startswith("7.8.3") for c in clauses)


def test_every_listed_text_is_in_the_rendered_demo(demo_report):
    need("pdftotext")
    report, _ = demo_report
    text = {}
    for name in ("plan", "report"):
        raw = subprocess.run(["pdftotext", str(report / f"{name}.pdf"), "-"], check=True,
                             capture_output=True, text=True).stdout
        text[name] = re.sub(r"\s+", " ", raw)
    missing = [(c, d, t) for c, d, t in _checked() if t not in text[d]]
    assert not missing, missing


def test_the_demo_plan_is_a_short_contract_before_its_annex(demo_report):
    """The agreement (cover and its first section) takes at most 6 pages; the technical
    study follows as a non-binding annex."""
    need("pdftotext")
    report, _ = demo_report
    raw = subprocess.run(["pdftotext", str(report / "plan.pdf"), "-"], check=True,
                         capture_output=True, text=True).stdout
    pages = raw.split("\f")
    annex = next(i for i, p in enumerate(pages) if re.search(r"(?m)^\s*Contents\s*$", p))
    assert annex <= 6, f"the agreement takes {annex} pages"
    assert "SIMULATED READINGS" not in raw  # a plan uses no readings
