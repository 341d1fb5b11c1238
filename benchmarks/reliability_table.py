"""The table of docs/fit_check.md, "What one bad reading can do unseen": per procedure and
set-up, the fit check's minimal detectable bias (80 % power at alpha 0.05) of one reading
(largest over the readings, per unit) and of one error the procedure declares (a contact
along its probing direction), and the measurand one undetected error moves most in units
of its u (GUM, ``mtplan linearize``), with its shift and the error that causes it.

Deterministic (first order at the design readings): ``python benchmarks/reliability_table.py``
prints the table's rows; tests/evaluation/test_reliability_docs.py recomputes each row of the
page with :func:`row` and compares it at its printed digits. geometry21 and line_laser run on
the smaller set-ups of benchmarks/bench_fitcheck.py (their defaults: 10-30 s each).
"""

from __future__ import annotations

import math

from mtplan.evaluation.first_order import first_order
from mtplan.evaluation.reliability import reliability
from mtplan.models import get

#: (procedure, set-up fields) of the table's rows, in order
ROWS = [("rotary_axis", {}),
        ("circle_centre", {}),
        ("circle_centre", {"n_points": 8}),
        ("tracker_frame", {}),
        ("line_laser", {"lines": 16, "points_per_line": 9}),
        ("geometry21", {"line_repeats": 1, "line_points": 7, "circle_points": 12})]

HEADER = ["procedure", "set-up", "readings", "MDB of one reading (largest)",
          "MDB of one contact (largest)", "moved most, in u", "its shift", "caused by"]


def setup_text(fields: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in fields.items()) or "default"


def _largest_per_unit(groups) -> str:
    best: dict = {}
    for g in groups:
        best[g["unit"]] = max(best.get(g["unit"], -math.inf), g["largest"])
    return ", ".join(f"{v:.3g} {u}" for u, v in best.items()) or "-"


def row(name: str, fields: dict) -> list[str]:
    """One row of the table, as printed."""
    proc = get(name)
    setup = proc.Setup(**fields)
    u = first_order(proc, setup).u()
    rel = reliability(proc, setup, u=u)
    arrays = {k for k in (proc.forward(setup, proc.Truth(), proc.zero_errors(setup, 1)))}
    own = [g for g in rel.mdb if g["readings"] in arrays]
    declared = [g for g in rel.mdb if g["readings"] not in arrays]
    ranked = [(n, r) for n, r in rel.measurands.items() if r["in_u"] is not None]
    worst, r = max(ranked, key=lambda kv: kv[1]["in_u"])
    cause = r["at"] if r["at"].startswith("contact") else r["at"].split()[-1]
    return [name, setup_text(fields), str(rel.n_readings), _largest_per_unit(own),
            _largest_per_unit(declared), f"{worst} {r['in_u']:.2g}",
            f"{r['shift']:.3g} {r['unit']}", cause]


def main() -> None:
    print("| " + " | ".join(HEADER) + " |")
    print("|" + "---|" * len(HEADER))
    for name, fields in ROWS:
        print("| " + " | ".join(row(name, fields)) + " |", flush=True)


if __name__ == "__main__":
    main()
