"""The numbers docs/fit_check.md prints in "What one bad reading can do unseen" are the
code's: each row of its checked table recomputed (benchmarks/reliability_table.py's
``row``, first order, deterministic) and compared at its printed digits; and the figures
its prose quotes from the table are the table's."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "fit_check.md"
MARKER = "<!-- table checked by tests/evaluation/test_reliability_docs.py -->"


def _script():
    spec = importlib.util.spec_from_file_location(
        "reliability_table", ROOT / "benchmarks" / "reliability_table.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _table() -> tuple[list[str], list[list[str]]]:
    text = PAGE.read_text(encoding="utf-8")
    assert MARKER in text
    rows = []
    for line in text.split(MARKER, 1)[1].strip().splitlines():
        if not line.startswith("|"):
            break
        rows.append([c.strip() for c in line.strip().strip("|").split("|")])
    return rows[0], rows[2:]


HEADER, ROWS = _table()


def test_the_table_has_the_scripts_rows_and_columns():
    script = _script()
    assert HEADER == script.HEADER
    assert [(r[0], r[1]) for r in ROWS] == [(n, script.setup_text(f)) for n, f in script.ROWS]


@pytest.mark.parametrize("index", range(len(ROWS)), ids=[" ".join(r[:2]) for r in ROWS])
def test_each_row_is_the_codes(index):
    script = _script()
    name, fields = script.ROWS[index]
    assert script.row(name, fields) == ROWS[index]


def test_the_prose_quotes_the_table():
    text = " ".join(PAGE.read_text(encoding="utf-8").split())
    default = next(r for r in ROWS if r[:2] == ["circle_centre", "default"])
    eight = next(r for r in ROWS if r[:2] == ["circle_centre", "n_points=8"])
    contact, shift, in_u = default[4], default[6], default[5].split()[-1]
    assert (f"A contact error along its probing direction needs {contact} to be flagged with "
            f"80 % power, and that moves centre_x by {shift}, {in_u} u, unseen") in text
    assert f"the default three points cannot ({shift})" in text
    assert f"eight can ({eight[6]};" in text
    assert re.search(rf"a single coordinate is the worst \({eight[6]}, {eight[5].split()[-1]} u\)",
                     text)
