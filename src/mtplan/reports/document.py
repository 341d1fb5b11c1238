"""The report as a document model: sections of paragraphs, tables and figures.

:func:`build_document` turns a :class:`~mtplan.plans.study.StudyResult` into a
:class:`Document`; the HTML and PDF renderers draw the same document, so the two
carry the same content. Nothing here computes an uncertainty: values come from
the result objects, rounded to their uncertainty (two significant digits of u).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mtplan.reports import figures as figs

__all__ = ["Document", "Section", "Table", "Figure", "build_document", "fmt"]


def fmt(value, u=None) -> str:
    """`value` rounded to the resolution its uncertainty `u` supports."""
    if value is None:
        return "-"
    try:
        value = float(value)
    except (TypeError, ValueError):
        return str(value)
    if not math.isfinite(value):
        return str(value)
    if u is None or not (math.isfinite(u) and u > 0):
        return f"{value:.4g}"
    decimals = max(0, 1 - math.floor(math.log10(u)))
    return f"{value:.{min(decimals, 9)}f}"


def fmt_u(u) -> str:
    """An uncertainty to two significant digits."""
    if u is None or not math.isfinite(u):
        return "-"
    if u == 0:
        return "0"
    decimals = max(0, 1 - math.floor(math.log10(abs(u))))
    return f"{u:.{min(decimals, 9)}f}"


@dataclass
class Table:
    caption: str
    header: list
    rows: list


@dataclass
class Figure:
    caption: str
    png: bytes


@dataclass
class Section:
    title: str
    blocks: list = field(default_factory=list)
    level: int = 1
    anchor: str = ""


@dataclass
class Document:
    title: str
    subtitle: str
    meta: dict
    provenance: dict
    sections: list
    csv: dict = field(default_factory=dict)  # name -> DataFrame for results/*.csv


def _setup_table(ps) -> Table:
    from mtplan.models import get
    from mtplan.models._protocol import fields_info

    proc = get(ps.name)
    docs = {f["name"]: f["doc"] for f in fields_info(proc.Setup)}
    defaults = proc.Setup().as_dict()
    rows = []
    for k, v in ps.setup.as_dict().items():
        shown = "axis default" if v is None else (", ".join(f"{x:g}" for x in v)
                                                  if isinstance(v, list) else str(v))
        mark = "" if v == defaults.get(k) else " *"
        rows.append([k, shown + mark, docs.get(k, "")])
    return Table("Set-up (* differs from the default)", ["field", "value", "meaning"], rows)


def _uncertainty_table(outcome) -> Table:
    rows = []
    gum = outcome.gum
    for est, r in outcome.results.items():
        for i, m in enumerate(r.measurands):
            u = float(r.mc.std[i])
            u_gum = (float(gum.std[gum.index(m.name)])
                     if gum is not None and est == outcome.spec.estimators[0] else None)
            rows.append([est, m.name, m.unit, fmt(r.true[i], u), fmt(r.mc.mean[i], u),
                         fmt(r.bias[i], u), fmt_u(u), fmt_u(u_gum) if u_gum is not None else "-",
                         f"[{fmt(r.mc.low[i], u)}, {fmt(r.mc.high[i], u)}]"])
    first = next(iter(outcome.results.values()))
    trials = first.mc.trials
    if first.mc.digits:
        counts = sorted({r.mc.trials for r in outcome.results.values()})
        how = (f"adaptive Monte Carlo to {first.mc.digits} significant digits "
               f"({', '.join(str(c) for c in counts)} trials)")
        stopped = [e for e, r in outcome.results.items() if not r.mc.converged]
        if stopped:
            how += f"; {', '.join(stopped)} stopped at the trial limit before all digits settled"
    else:
        how = f"{trials} Monte Carlo trials"
    gum_note = ("; u GUM is the linearised prediction (law of propagation) for the first "
                "estimator" if gum is not None else "")
    header = ["estimator", "measurand", "unit", "true", "mean", "bias", "u", "u GUM", "interval"]
    if gum is None:
        header.remove("u GUM")
        rows = [r[:7] + r[8:] for r in rows]
    return Table(
        f"Uncertainty: {how}; {100 * first.mc.coverage:g} % probabilistically symmetric coverage "
        f"intervals; values rounded to two significant digits of u{gum_note}.", header, rows)


def _budget_table(outcome) -> Table:
    b = outcome.budget
    rows = []
    for out, g in b.groupby("output", sort=False):
        g = g.sort_values("share", ascending=False)
        top = [f"{r.input} {100 * r.share:.0f} %" for r in g.itertuples() if r.share >= 0.005]
        rows.append([out, "; ".join(top[:4]) or "-"])
    how = ("GUM law of propagation" if outcome.gum is not None else
           f"Monte Carlo, each source alone, {outcome.spec.budget_trials} trials")
    return Table(f"Budget: share of each error source in u^2 ({how}; "
                 f"{outcome.spec.estimators[0]} estimator)",
                 ["measurand", "largest error sources"], rows)


def _findings(outcome) -> list[str]:
    """What the simulation shows that the seed's method hides: bias, spread, observability."""
    notes = []
    results = outcome.results
    ests = list(results)
    first = results[ests[0]]
    for i, m in enumerate(first.measurands):
        r = first
        se = r.mc.std[i] / math.sqrt(r.mc.trials)
        if abs(r.bias[i]) > 4 * se and abs(r.bias[i]) > 0.1 * r.mc.std[i]:
            size = (f"{abs(r.bias[i]) / r.mc.std[i]:.1f} u" if r.mc.std[i] > 0 else
                    "every trial gave the same value")  # e.g. a quantised estimate
            notes.append(f"{ests[0]}: {m.name} is biased by {fmt(r.bias[i], r.mc.std[i])} {m.unit} "
                         f"({size}), beyond its Monte Carlo error.")
    for est in ests[1:]:
        r = results[est]
        for i, m in enumerate(r.measurands):
            a, b = first.mc.std[i], r.mc.std[i]
            if b > 0 and a / b > 1.2:
                notes.append(f"{est} determines {m.name} {a / b:.1f} times better than "
                             f"{ests[0]} (u {fmt_u(b)} against {fmt_u(a)} {m.unit}).")
            elif a > 0 and b / a > 1.2:
                notes.append(f"{ests[0]} determines {m.name} {b / a:.1f} times better than {est}.")
    obs = outcome.extras.get("observability")
    if obs:
        for est, angles in obs.items():
            if est not in results:
                continue
            for name, o in angles.items():
                if not getattr(o, "observable", True):
                    notes.append(f"{est}: {name} is not observable at this set-up: {o.reason}.")
                elif getattr(o, "quantum_urad", 0) > 0:
                    notes.append(f"{est}: {name} is quantised: {o.reason}.")
                elif not getattr(o, "signed", True):
                    notes.append(f"{est}: {name} has no sign: {o.reason}.")
    for est, table in (outcome.extras.get("identifiability") or {}).items():
        counts = table["status"].value_counts()
        bad = {k: int(v) for k, v in counts.items() if k != "identified"}
        if bad:
            notes.append(f"{est}: of the 21 error functions, {int(counts.get('identified', 0))} "
                         "are identified; " + ", ".join(f"{v} {k}" for k, v in bad.items())
                         + " (see the identifiability table).")
    ident = outcome.identifiability
    if ident is not None and ident.rank < ident.n_params:
        notes.append(f"The readings determine only {ident.rank} of {ident.n_params} truth "
                     "parameters: some combinations are unobservable (see the identifiability "
                     "table).")
    if not notes:
        notes.append("No significant bias; the estimators agree within their Monte Carlo error.")
    notes += _dominant_sources(outcome.budget)
    return notes


def _dominant_sources(budget) -> list[str]:
    """One sentence per error source that dominates (>= 50 %) some measurands' variance."""
    if budget is None or not len(budget):
        return []
    top = budget.sort_values("share", ascending=False).groupby("output", sort=False).head(1)
    top = top[top["share"] >= 0.5]
    out = []
    for source, group in top.groupby("input", sort=False):
        shown = ", ".join(f"{r.output} {100 * r.share:.0f} %" for r in group.itertuples())
        out.append(f"{source} is the largest error source of {shown} of u^2: the place to "
                   "improve the set-up.")
    return out


def _identifiability_table(ident) -> Table | None:
    if ident is None:
        return None
    rows = [["parameters", f"{ident.n_params} ({', '.join(ident.names)})"],
            ["numerical rank", str(ident.rank)],
            ["condition number (scaled)", f"{ident.condition_number:.3g}"]]
    rows += [[key, f"{val:.4g}"] for key, val in ident.observability.items()]
    if ident.null_combinations:
        rows.append(["cannot be separated", "; ".join(ident.null_combinations)[:400]])
    return Table("Identifiability of the truth parameters from the noise-free readings "
                 "(column-scaled sensitivities; observability indices O1-O5)",
                 ["quantity", "value"], rows)


def _hook_tables(extras) -> list:
    """Tables from a procedure's own identifiability/observability functions."""
    out = []
    ident = extras.get("identifiability")
    if ident:
        ests = list(ident)
        first = ident[ests[0]]
        rows = []
        for name in first.index:
            row = [name]
            for est in ests:
                r = ident[est].loc[name]
                text = str(r["status"])
                if r.get("confounded_with"):
                    text += f" (with {r['confounded_with']})"
                if r.get("first_order_bias", 0):
                    text += f"; first-order bias up to {r['first_order_bias']:.2g}"
                row.append(text)
            rows.append(row)
        out.append(Table("Identifiability of each error function, per estimator (identified, "
                         "unidentifiable: confounded with the functions named; biased: the "
                         "seed's stepwise estimate moves with the errors named, bias per "
                         "typical error [um or urad])", ["function"] + ests, rows))
    obs = extras.get("observability")
    if obs:
        rows = []
        for est, angles in obs.items():
            for name, o in angles.items():
                rows.append([est, name, "yes" if o.observable else "no",
                             "yes" if o.signed else "no",
                             f"{o.quantum_urad:.3g}" if o.quantum_urad else "-",
                             f"{o.floor_urad:.3g}" if o.floor_urad else "-", o.reason])
        out.append(Table("Observability of each angle, per estimator (quantum: resolution of "
                         "the estimate; floor: smallest magnitude distinguishable from 0) [urad]",
                         ["estimator", "angle", "observable", "sign", "quantum", "floor",
                          "why"], rows))
    return out


def build_document(result) -> Document:
    """The report of a computed study."""
    study = result.study
    sections = []
    csv = {}
    for k, outcome in enumerate(result.outcomes, start=1):
        ps = outcome.spec
        sec = Section(f"{k}. {ps.label}", anchor=f"p{k}")
        sec.blocks.append(f"Procedure: {outcome.title} ({ps.name}). Estimators: "
                          f"{', '.join(ps.estimators)}.")
        if ps.notes:
            sec.blocks.append(ps.notes)
        sec.blocks.append(_setup_table(ps))
        sec.blocks.append(_uncertainty_table(outcome))
        first = next(iter(outcome.results.values()))
        sec.blocks.append(Figure(f"Monte Carlo distributions of the measurands ({ps.estimators[0]}); "
                                 "black: true value, band: coverage interval.",
                                 figs.histogram_figure(first)))
        if len(outcome.results) > 1:
            sec.blocks.append(Figure("Bias of each estimator with its +-2u bars, in units of the "
                                     "first estimator's standard uncertainty u1 (the seed's "
                                     "method first): a bar shorter than the first one's is a "
                                     "better estimator.",
                                     figs.estimator_figure(outcome.results)))
        sec.blocks.append(_budget_table(outcome))
        sec.blocks.append(Figure("Uncertainty budget by error source.",
                                 figs.budget_figure(outcome.budget)))
        csv[f"{ps.name}_{k}_uncertainty"] = _summary_frame(outcome)
        csv[f"{ps.name}_{k}_budget"] = outcome.budget
        units = {m.name: m.unit for m in first.measurands}
        for j, (spec, table) in enumerate(outcome.sweeps, start=1):
            vary = spec["vary"]
            if isinstance(table, str):
                sec.blocks.append(f"The sweep over {', '.join(vary)} could not be computed: "
                                  f"{table}")
                continue
            errors = table["error"] if "error" in table else None
            failed = (table[errors.notna() & (errors.astype(str) != "")]
                      if errors is not None else table.iloc[:0])
            ok = table.drop(failed.index)
            if len(ok):
                shown = list(units)
                more = ""
                if len(shown) > 12:  # keep the panels readable; the CSV has them all
                    shown = shown[:10]
                    more = (f" The first {len(shown)} of {len(units)} measurands; all are in "
                            f"results/{ps.name}_{k}_sweep{j}.csv.")
                sec.blocks.append(Figure(
                    f"Standard uncertainty against {', '.join(vary)} (Monte Carlo, "
                    f"{int(ok['trials'].max())} trials per set-up; bars: Monte Carlo error of u)."
                    + more,
                    figs.sweep_figure(ok, vary, shown, units)))
            for (est, *values), group in failed.groupby(["estimator", *vary], sort=False):
                shown = ", ".join(f"{f} = {v}" for f, v in zip(vary, values, strict=True))
                sec.blocks.append(f"{est} cannot evaluate the set-up {shown}: "
                                  f"{group['error'].iloc[0]}")
            csv[f"{ps.name}_{k}_sweep{j}"] = table
        if outcome.plan is not None:
            sec.blocks += _plan_blocks(outcome.plan, ps.plan.get("vary", {}))
            if not isinstance(outcome.plan, str):
                csv[f"{ps.name}_{k}_plan"] = outcome.plan.table
        if outcome.acceptance is not None:
            sec.blocks.append(_acceptance_table(outcome.acceptance))
        if outcome.measured is not None:
            sec.blocks += _measured_blocks(outcome.measured)
        t = _identifiability_table(outcome.identifiability)
        if t is not None:
            sec.blocks.append(t)
        sec.blocks += _hook_tables(outcome.extras)
        bands = outcome.extras.get("bands")
        if bands is not None:
            sec.blocks.append(Figure(bands["caption"], figs.bands_figure(bands["tables"])))
        path = outcome.extras.get("path")
        if path is not None:
            sec.blocks.append(Figure(path.get("caption", "Planned path."), figs.path_figure(path)))
        sec.blocks.append(Section("What the simulation shows", level=2,
                                  blocks=[_findings(outcome)]))
        sections.append(sec)
    prov = result.provenance
    rows = [["date", prov["date"]], ["study file", prov["study_file"]],
            ["study SHA-256 (16 hex)", prov["study_sha256"]], ["seed", str(prov["seed"])],
            ["Python", prov["python"]]]
    rows += [[k, v] for k, v in prov["versions"].items()]
    sections.append(Section("Provenance", anchor="provenance",
                            blocks=[Table("Software, seeds and study", ["item", "value"], rows)]))
    return Document(title=study.title, subtitle=study.meta.get("subtitle", ""), meta=study.meta,
                    provenance=prov, sections=sections, csv=csv)


def _summary_frame(outcome):
    import pandas as pd

    frames = []
    for est, r in outcome.results.items():
        df = r.summary().reset_index()
        df.insert(0, "estimator", est)
        frames.append(df)
    return pd.concat(frames, ignore_index=True)


def _plan_blocks(plan, vary) -> list:
    if isinstance(plan, str):
        return [Section("Plan", level=2, blocks=[f"No set-up meets the targets: {plan}"])]
    best = plan.best
    rows = [[n, f"<= {v:g}", fmt_u(best["predicted"][n]), fmt_u(best["confirmed"][n])]
            for n, v in plan.targets.items()]
    changed = [f"{f} = {best['setup'][f]}" for f in vary if f in best["setup"]]
    blocks = [Section("Plan: the cheapest set-up meeting the targets", level=2, blocks=[
        f"Recommended: {', '.join(changed) or 'the base set-up'}; duration "
        f"{best['duration_s'] / 60:.1f} min (confirmed by Monte Carlo).",
        Table(f"Targets (k = {plan.k:g}) against the linearised prediction and the Monte Carlo "
              "confirmation", ["measurand", "target", "predicted", "Monte Carlo"], rows)])]
    from mtplan.plans.planner import pareto_front

    front = list(pareto_front(plan.table["duration_s"].to_numpy(), plan.table["worst"].to_numpy()))
    blocks.append(Figure("Pareto front: duration against the worst ratio of predicted uncertainty "
                         "to target; the star is the recommended set-up.",
                         figs.pareto_figure(plan.table, front, best["candidate"])))
    return blocks


def _acceptance_table(acc: dict) -> Table:
    limits = acc.get("acceptance_limits")
    shown = ", ".join("-" if x is None else f"{x:.4g}" for x in limits) if limits else "-"

    def p(x):
        return "-" if x is None else f"{100 * float(x):.3g} %"

    rows = [["measurand", f"{acc['measurand']} [{acc['unit']}]"],
            ["tolerance", f"[{acc.get('lower', '-')}, {acc.get('upper', '-')}]"],
            ["standard uncertainty u", fmt_u(acc["u"])],
            ["process (prior)", str(acc.get("prior") or "-")],
            ["decision rule", str(acc["rule"])],
            ["acceptance limits", shown],
            ["probability of false accept", p(acc.get("pfa"))],
            ["probability of false reject", p(acc.get("pfr"))],
            ["conditional false accept", p(acc.get("conditional_pfa"))],
            ["TUR", "-" if acc.get("tur") is None else f"{acc['tur']:.3g}"],
            ["Cm", "-" if acc.get("cm") is None else f"{acc['cm']:.3g}"]]
    return Table("Acceptance plan (JCGM 106 / ISO 14253-1)", ["quantity", "value"], rows)


def _measured_blocks(measured) -> list:
    doc = measured.to_dict() if hasattr(measured, "to_dict") else dict(measured)
    rows = []
    for m in doc.get("measurands", []):
        u = m.get("std")
        iv = m.get("interval") or [None, None]
        rows.append([m["name"], m.get("unit", ""), fmt(m.get("estimate"), u),
                     fmt(m.get("value", m.get("mean")), u), fmt_u(u),
                     f"[{fmt(iv[0], u)}, {fmt(iv[1], u)}]"])
    how = {"mc": "Monte Carlo of the set-up's error sources about the estimate",
           "posterior": "Bayesian posterior of the forward model (emcee)"}.get(
        doc.get("uncertainty", ""), doc.get("uncertainty", ""))
    source = getattr(measured, "source", "")
    text = [f"Readings{' from ' + source if source else ''}, {doc.get('estimator', '')} "
            f"estimator; uncertainty: {how}."]
    text += [str(n) for n in doc.get("notes", [])]
    blocks = [Section("Measured data", level=2, blocks=text + [
        Table("Measurands from the readings (estimate: the estimator's value; value: the "
              "reported value, the posterior mean for a posterior)",
              ["measurand", "unit", "estimate", "value", "u", "interval"], rows)])]
    post = getattr(measured, "details", None)
    if getattr(measured, "uncertainty", "") == "posterior" and post is not None:
        names = [m.name for m in post.measurands]
        samples = {f"{n} [{u}]": post.samples[n] for n, u in
                   ((m.name, m.unit) for m in post.measurands)}
        state = ("converged" if post.converged else "NOT CONVERGED: read with care")
        blocks.append(Table(
            f"Posterior diagnostics ({state}; {post.chains.shape[0]} ensembles of "
            f"{post.n_walkers} walkers, {post.n_steps} steps, burn-in {post.discard}, thinned by "
            f"{post.thin}); tau: integrated autocorrelation time [steps]; R-hat: split over "
            "ensembles; ESS: effective sample size",
            ["quantity", "mean", "u", "tau", "R-hat", "ESS"],
            [[n, fmt(post.mean[n], post.std[n]), fmt_u(post.std[n]),
              f"{post.tau.get(n, float('nan')):.3g}", f"{post.rhat[n]:.4f}", f"{post.ess[n]:.0f}"]
             for n in names + list(post.parameters)]))
        blocks.append(Figure("Posterior of the measurands: pairwise samples and marginal "
                             "histograms (corner plot); lines: posterior mean.",
                             figs.corner_figure(samples)))
        blocks.append(Figure("Walker traces of the free parameters (every walker of the first "
                             "ensemble; grey: discarded burn-in).",
                             figs.trace_figure({p: post.trace(p)[0] for p in post.parameters},
                                               discard=post.discard)))
    return blocks


_ = np
