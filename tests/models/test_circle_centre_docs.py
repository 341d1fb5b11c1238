"""The numbers docs/circle_centre.md prints are the code's: every row of its checked table is
recomputed here (same trials, same seed), so the page cannot go stale.

The table follows the marker ``<!-- table checked by tests/models/test_circle_centre_docs.py
-->``; its columns are estimator, set-up (``--set`` pairs, or ``default``), sources (``all``
or names) and one u per measurand [display unit], printed to two decimals. The same seed
gives the same draws, so the tolerance is the printed rounding plus 1 % for another BLAS.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from mtplan.evaluation.simulation import simulate_uncertainty
from mtplan.models import registry

DOCS = Path(__file__).resolve().parents[2] / "docs"


def checked_rows(page: str, test_name: str) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of the table after the marker that names `test_name` on `page`."""
    text = (DOCS / page).read_text(encoding="utf-8")
    marker = f"<!-- table checked by tests/models/{test_name} -->"
    assert marker in text, f"{page} has no table checked by {test_name}"
    lines = text.split(marker, 1)[1].strip().splitlines()
    table = []
    for line in lines:
        if not line.startswith("|"):
            break
        table.append([c.strip() for c in line.strip().strip("|").split("|")])
    return table[0], table[2:]


def parse_setup(text: str) -> dict:
    if text == "default":
        return {}
    return dict(pair.strip().split("=", 1) for pair in text.split(","))


def parse_sources(text: str):
    return None if text == "all" else [s.strip() for s in text.split(",")]


def check_row(procedure: str, header, row, *, trials: int, seed: int) -> None:
    proc = registry()[procedure]
    estimator, setup, sources, *values = row
    setup = proc.setup(parse_setup(setup))
    r = simulate_uncertainty(proc, setup, estimator=estimator, sources=parse_sources(sources),
                             trials=trials, rng=seed, progress=False)
    u = dict(zip([m.name for m in r.measurands], r.mc.std))
    for head, printed in zip(header[3:], values):
        name = head.split("(", 1)[1].split(")", 1)[0]
        assert float(printed) == pytest.approx(u[name], rel=0.01, abs=0.005), (
            f"{procedure} {row[:3]}: the page prints u({name}) = {printed}, the code gives "
            f"{u[name]:.3f}")


HEADER, ROWS = checked_rows("circle_centre.md", "test_circle_centre_docs.py")


@pytest.mark.parametrize("row", ROWS, ids=[" ".join(r[:3]) for r in ROWS])
def test_the_pages_table_is_the_codes(row):
    check_row("circle_centre", HEADER, row, trials=4000, seed=3)
