"""Print the error-budget tables of docs/line_laser.md and docs/circle_centre.md.

    PYTHONPATH=src python docs/budget_table.py line_laser     # about 5 min on one core
    PYTHONPATH=src python docs/budget_table.py circle_centre  # about 10 s

For each estimator: the standard uncertainty u (Monte Carlo standard deviation) of every
measurand with the error sources the procedure had before issue 17 and with all of them,
at the default set-up (and, for line_laser, at the former default scan), then each
source's u alone and its share of the sum of the single-source variances
(:func:`mtplan.evaluation.source_budget`). Fixed seed and trial count: the numbers
repeat exactly; a standard deviation from N = 2000 trials is good to about 1.6 %.
"""

from __future__ import annotations

import sys

from mtplan.evaluation import simulate_uncertainty, source_budget
from mtplan.models import get

N, SEED = 2000, 1
#: the sources issue 17 added, and the set-ups compared, per procedure
CASES = {
    "line_laser": dict(new=["linearity", "z_scale", "squareness_xy", "squareness_zy", "drift"],
                       estimators=["patent", "registration"],
                       former_setup=dict(lines=40, shift_fraction=0.6)),
    "circle_centre": dict(new=["tip_radius", "bore_temperature"],
                          estimators=["three_point"], former_setup=None),
}


def _u(proc, setup, estimator, sources=None):
    r = simulate_uncertainty(proc, setup, estimator=estimator, sources=sources, trials=N,
                             rng=SEED, progress=False)
    return {m.name: (float(s), m.unit) for m, s in zip(r.measurands, r.mc.std)}


def _percent(share: float) -> str:
    pct = 100 * share
    return f"{pct:.0f} %" if pct >= 1 else f"{pct:.1f} %" if pct >= 0.1 else "< 0.1 %"


def main(name: str) -> None:
    case = CASES[name]
    proc = get(name)
    setup = proc.Setup()
    old = [s for s in proc.active_sources(setup) if s not in case["new"]]
    for est in case["estimators"]:
        cols = {}
        if case["former_setup"]:
            former = proc.setup(case["former_setup"])
            cols["former scan, former sources"] = _u(proc, former, est, old)
        cols["former sources"] = _u(proc, setup, est, old)
        cols["all sources"] = _u(proc, setup, est)
        print(f"\n### {name}, estimator {est}: u at the default set-up\n")
        print("| measurand | unit | " + " | ".join(cols) + " |")
        print("|---|---|" + "---:|" * len(cols))
        for m in proc.measurands(setup):
            vals = " | ".join(f"{c[m.name][0]:.3g}" for c in cols.values())
            print(f"| {m.name} | {m.unit} | {vals} |")
        budget = source_budget(proc, setup, estimator=est, trials=N, rng=SEED)
        names = [m.name for m in proc.measurands(setup)]
        print(f"\n{name}, estimator {est}: u of each source alone, and its share of the sum "
              "of the single-source u^2\n")
        print("| source | " + " | ".join(names) + " |")
        print("|---|" + "---:|" * len(names))
        for src, rows in budget.groupby("source", sort=False):
            rows = rows.set_index("measurand")
            cells = []
            for m in names:
                std, share = rows.loc[m, "std"], rows.loc[m, "share"]
                cells.append("0" if std == 0 else "< 0.001" if std < 1e-3
                             else f"{std:.3g} ({_percent(share)})")
            star = " (new)" if src in case["new"] else ""
            print(f"| {src}{star} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "line_laser")
