"""The numbers docs/geometry21.md prints in its checked table are the code's: first order
(``mtplan linearize``, deterministic), recomputed row by row; the table's form is that of
tests/models/test_circle_centre_docs.py."""

from __future__ import annotations

import pytest

from mtplan.evaluation.simulation import linearize_procedure
from mtplan.models import registry
from tests.models.test_circle_centre_docs import checked_rows, parse_setup, parse_sources

HEADER, ROWS = checked_rows("geometry21.md", "test_geometry21_docs.py")


@pytest.mark.parametrize("row", ROWS, ids=[" ".join(r[:3]) for r in ROWS])
def test_the_pages_table_is_the_codes(row):
    proc = registry()["geometry21"]
    estimator, setup, sources, *values = row
    g = linearize_procedure(proc, proc.setup(parse_setup(setup)), estimator=estimator,
                            sources=parse_sources(sources))
    u = dict(zip(g.names, g.std))
    for head, printed in zip(HEADER[3:], values):
        name = head.split("(", 1)[1].split(")", 1)[0]
        assert float(printed) == pytest.approx(u[name], rel=0.005, abs=0.005), (row[:3], name)
