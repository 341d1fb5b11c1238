"""The neutral correction table: CSV and JSON, with ISO 230-1 / ISO 230-7 names, the values,
their U, the sign convention and the predicted residual after compensation.

Every procedure's correction can be written in it; it is the record the controllers'
formats are checked against, and what a user enters by hand where no format fits.
"""

from __future__ import annotations

import csv
import io
import json

import numpy as np

from mtplan.compensation.formats import CompensationFormat, residual


def _plain(value):
    """A float for the files: None where it has no value (NaN)."""
    return None if isinstance(value, float) and value != value else value

__all__ = ["FORMAT", "COLUMNS"]

COLUMNS = ("procedure", "term", "unit", "axis", "position", "extrapolated", "value", "u", "U",
           "k", "interval_low", "interval_high", "unseen_u", "residual_low", "residual_high",
           "kind", "frame", "sign", "unseen", "description")


def _render(correction, options) -> dict:
    res = residual(correction)
    rows = []
    for row, r in zip(correction.rows(), res.rows()):
        rows.append({k: _plain(v) for k, v in {
            **row, "residual_low": r["residual_low"], "residual_high": r["residual_high"],
            "kind": correction.kind, "frame": correction.frame, "sign": correction.sign}.items()})
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if v is None else repr(float(v)) if isinstance(v, float)
                             else v) for k, v in row.items() if k in COLUMNS})
    doc = {"procedure": correction.procedure, "kind": correction.kind,
           "frame": correction.frame, "sign": correction.sign, "k": correction.k,
           "source": dict(correction.source),
           "terms": [{k: row[k] for k in ("term", "unit", "axis", "position", "extrapolated",
                                          "value", "u", "U", "interval_low", "interval_high",
                                          "unseen_u", "unseen", "description")}
                     for row in rows],
           "covariance": {"names": list(correction.names), "units": list(correction.units),
                          "matrix": np.asarray(correction.covariance).tolist()},
           "residual_after_compensation": {
               "coverage": 0.95,
               "what": "the error left once these values are applied, from the result's "
                       "state of knowledge; what the test cannot see is not in it",
               "terms": [{k: _plain(v) for k, v in r.items()} for r in res.rows()]},
           "setup": dict(correction.setup)}
    return {"correction.csv": text.getvalue(),
            "correction.json": json.dumps(doc, indent=1, default=str) + "\n"}


FORMAT = CompensationFormat(
    name="neutral",
    title="neutral table: CSV and JSON with ISO 230 names, values, U and the sign convention",
    source="ISO 230-1:2012 and ISO 230-7:2015 names of the geometric errors; ISO/TR "
           "16907:2015 clauses 11 and 12 (validation and documentation of a numerical "
           "compensation)",
    kinds=("*",),
    render=_render,
)
