"""The docs' budget tables: u of each measurand before and after a change of the error
model, and the share of each source in u^2 (a helper of the bench_* scripts, not a test).

u comes from the Monte Carlo (``simulate_uncertainty``), the shares from the GUM budget
(``linearize_procedure``, the same as ``mtplan linearize PROC --json``): with independent
sources each share is that source's variance over the sum, exact for a linear model.
For an estimator far from linear (line_laser's patent: whole rows, an arccos) the shares
can come from the Monte Carlo instead (``shares="mc"``: ``source_budget``, each source
alone), which is also cheaper where the readings are many.
"""

from __future__ import annotations

import numpy as np

from mtplan.evaluation.simulation import linearize_procedure, simulate_uncertainty, source_budget


def mc_std(proc, setup, trials, estimator=None, sources=None, rng=3) -> dict:
    """Monte Carlo standard uncertainty of each measurand (display units)."""
    r = simulate_uncertainty(proc, setup, trials=trials, rng=rng, estimator=estimator,
                             sources=sources, progress=False)
    return dict(zip([m.name for m in r.measurands], r.mc.std, strict=True))


def budget_table(proc, setup, before, trials, estimator=None, short=None, shares="gum") -> str:
    """Markdown: measurand, u before, u after, share of each source in u^2 [%].

    `before` is ``(setup, sources)`` of the old error model (None: no such column), or a
    dict of u per measurand; `short` renames source columns; `shares` is ``"gum"`` or
    ``"mc"`` (each source alone through the Monte Carlo, `trials` trials).
    """
    if isinstance(before, tuple):
        before = mc_std(proc, before[0], trials, estimator, before[1])
    after = mc_std(proc, setup, trials, estimator)
    if shares == "mc":
        b = source_budget(proc, setup, estimator=estimator, trials=trials, rng=3)
        groups = list(dict.fromkeys(b["input"]))
        var = (b.pivot(index="output", columns="input", values="contribution")
               .loc[[m.name for m in proc.measurands(setup)], groups].to_numpy() ** 2)
    else:
        gum = linearize_procedure(proc, setup, estimator=estimator)
        groups, var = gum.group_variance()
    total = var.sum(axis=1, keepdims=True)
    share = np.divide(var, total, out=np.zeros_like(var), where=total > 0)
    short = short or {}
    lines = ["| measurand | u before | u after | "
             + " | ".join(short.get(g, g) for g in groups) + " |",
             "|---|---:|---:|" + "---:|" * len(groups)]
    for i, m in enumerate(proc.measurands(setup)):
        old = f"{before[m.name]:.3g}" if before and m.name in before else "-"
        cells = " | ".join(f"{100 * share[i, j]:.0f}" for j in range(len(groups)))
        lines.append(f"| {m.name} [{m.unit}] | {old} | {after[m.name]:.3g} | {cells} |")
    return "\n".join(lines)
