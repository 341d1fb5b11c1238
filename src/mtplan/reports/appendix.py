"""The appendix of a report: everything behind the customer body, per test.

Set-up parameter dumps, the uncertainty of every estimator, distributions, budgets,
all sweeps, the plan, the measured data in full with posterior diagnostics,
identifiability and observability, and the provenance. Formatting only.
"""

from __future__ import annotations

from mtplan.reports import figures as figs
from mtplan.reports.model import Figure, Section, Table
from mtplan.reports.wording import customer_words, value_warnings
from mtplan.reports.labels import duration_text, field_label, field_value, fmt, fmt_u, \
    plain_fields, unit

__all__ = ["procedure_section", "provenance_section", "measured_blocks"]


def procedure_section(k, outcome, measured: bool = True) -> tuple[Section, dict]:
    """(appendix section, results CSV frames) of test ``k``; ``measured=False`` leaves the
    readings' evaluation out (the test plan is issued before measuring)."""
    ps = outcome.spec
    sec = Section(f"A{k}. {ps.label}: details", anchor=f"a{k}", appendix=True)
    sec.blocks.append(f"Procedure: {outcome.title} ({ps.name}). Estimators compared: "
                      f"{', '.join(ps.estimators)}; recommended: {outcome.recommended}.")
    sec.blocks.append(_setup_table(ps))
    sec.blocks += _uncertainty_table(outcome)
    first = outcome.results[outcome.recommended]
    shown, more = _panel_names(outcome, 8, f"results/{ps.name}_{k}_uncertainty.csv")
    sec.blocks.append(Figure(f"Monte Carlo distributions of the measurands "
                             f"({outcome.recommended}); black: true value, band: coverage "
                             f"interval.{more}", figs.histogram_figure(first, shown)))
    if len(outcome.results) > 1:
        sec.blocks.append(Figure("Bias of each estimator with its ±2u bars, in units of the "
                                 "first estimator's standard uncertainty u1 (the source method "
                                 "first): a bar shorter than the first one's is a better "
                                 "estimator.", figs.estimator_figure(outcome.results)))
    sec.blocks.append(_budget_table(outcome))
    sec.blocks.append(Figure("Uncertainty budget by error source.",
                             figs.budget_figure(outcome.budget)))
    csv = {f"{ps.name}_{k}_uncertainty": _summary_frame(outcome),
           f"{ps.name}_{k}_budget": outcome.budget}
    sec.blocks += _sweep_blocks(k, outcome, csv)
    if outcome.plan is not None:
        from mtplan.reports.document import plan_fields

        sec.blocks += _plan_blocks(outcome.plan, plan_fields(outcome))
        if not isinstance(outcome.plan, str):
            csv[f"{ps.name}_{k}_plan"] = outcome.plan.table
    if outcome.measured is not None and measured:
        sec.blocks += measured_blocks(outcome.measured)
    t = _identifiability_table(outcome.identifiability)
    if t is not None:
        sec.blocks.append(t)
    sec.blocks += _hook_tables(outcome.extras)
    bands = outcome.extras.get("bands")
    if bands is not None:
        sec.blocks.append(Figure(customer_words(bands["caption"]),
                                 figs.bands_figure(bands["tables"])))
    path = outcome.extras.get("path")
    if path is not None:
        sec.blocks.append(Figure(customer_words(path.get("caption", "Planned path.")),
                                 figs.path_figure(path)))
    return sec, csv


def provenance_section(prov: dict, document: str = "report") -> Section:
    """Software, command, seed, study and, in a report, the readings files. A test plan
    (``document="plan"``) is agreed before measuring: it names no readings."""
    from pathlib import PurePath

    plan = document == "plan"
    study = PurePath(str(prov["study_file"]))

    def relative(path) -> str:  # a file named relative to the study's folder, never absolute
        try:
            return PurePath(str(path)).relative_to(study.parent).as_posix()
        except ValueError:
            return PurePath(str(path)).name

    rows = [[f"computed on (the {document}'s date of issue is on its cover)", prov["date"]],
            ["command", prov.get("command", "-")],
            ["mtplan git commit", prov.get("git_commit") or "not known (not run from a "
                                                             "git checkout)"],
            ["study file", study.name], ["study SHA-256", prov["study_sha256"]]]
    for label, path, digest in [] if plan else prov.get("readings", []):
        rows += [[f"readings of {label}", relative(path)],
                 [f"readings SHA-256 of {label}", digest]]
    rows += [["seed", str(prov["seed"])], ["Python", prov["python"]]]
    rows += [[k, v] for k, v in prov["versions"].items()]
    if prov.get("cached"):  # the numbers of an earlier run with the same inputs and code
        rows.append(["study result", f"read from the cache file "
                     f"{PurePath(str(prov['cached'])).name}, stored by an earlier run "
                     "of the same study, readings, mtplan code and numeric packages"])
    return Section("Provenance", anchor="provenance", appendix=True,
                   blocks=[Table("Software, command, seed and study" if plan else
                                 "Software, command, seeds, study and readings files",
                                 ["item", "value"], rows)])


# ----------------------------------------------------------------------- tables
def _setup_table(ps) -> Table:
    from mtplan.models.protocol import fields_info

    proc = ps.procedure
    docs = {f.name: f.doc for f in fields_info(proc.Setup)}
    defaults = proc.Setup().as_dict()
    rows = []
    for k, v in ps.setup.as_dict().items():
        shown = "axis default" if v is None else (", ".join(f"{x:g}" for x in v)
                                                  if isinstance(v, list) else str(v))
        mark = "" if v == defaults.get(k) else " *"
        kind = "lever" if k in proc.levers else "property"
        rows.append([k, shown + mark, kind, customer_words(docs.get(k, ""))])
    return Table("Set-up (* differs from the default; lever: chosen by the engineer, "
                 "property: of the machine, workpiece or instrument)",
                 ["field", "value", "kind", "meaning"], rows, grow=0)


def _uncertainty_table(outcome) -> list:
    """The Monte Carlo of every estimator (a table), and a warning under it for each
    estimate its interval or u makes unreliable (:func:`~mtplan.reports.wording.
    value_warnings`)."""
    rows, items = [], []
    gum = outcome.gum
    for est, r in outcome.results.items():
        for i, m in enumerate(r.measurands):
            u = float(r.mc.std[i])
            u_gum = (float(gum.std[gum.index(m.name)])
                     if gum is not None and est == outcome.recommended else None)
            shown_u = u if u > 0 else None
            items.append(((f"{m.name} ({est})", float(r.true[i]), u, float(r.mc.low[i]),
                           float(r.mc.high[i])), abs(float(r.bias[i])) >= u))
            rows.append([est, m.name, unit(m.unit), fmt(r.true[i], shown_u),
                         fmt(r.mc.mean[i], shown_u), fmt(r.bias[i], shown_u),
                         fmt_u(u) if u > 0 else "n/d",
                         fmt_u(u_gum) if u_gum is not None else "-",
                         f"[{fmt(r.mc.low[i], shown_u)}, {fmt(r.mc.high[i], shown_u)}]"
                         if u > 0 else "n/d"])
    # an interval cut by a bound, and a true value U does not resolve where the estimator
    # is also biased by u or more (a true value near zero is no finding in a simulation)
    cut, flagged = value_warnings([i for i, _ in items], resolution=False)
    blind, flagged_too = value_warnings([i for i, biased in items if biased], bound=False)
    warnings, flagged = cut + blind, flagged | flagged_too
    for row, (item, _) in zip(rows, items, strict=True):
        row[1] += " *" if item[0] in flagged else ""
    first = next(iter(outcome.results.values()))
    if first.mc.digits:
        counts = sorted({r.mc.trials for r in outcome.results.values()})
        how = (f"adaptive Monte Carlo to {first.mc.digits} significant digits "
               f"({', '.join(str(c) for c in counts)} trials)")
        stopped = [e for e, r in outcome.results.items() if not r.mc.converged]
        if stopped:
            how += f"; {', '.join(stopped)} stopped at the trial limit before all digits settled"
    else:
        how = f"{first.mc.trials} Monte Carlo trials"
    gum_note = (f"; u GUM is the linearised prediction (law of propagation) for "
                f"{outcome.recommended}" if gum is not None else "")
    header = ["estimator", "measurand", "unit", "true", "mean", "bias", "u", "u GUM", "interval"]
    if gum is None:
        header.remove("u GUM")
        rows = [r[:7] + r[8:] for r in rows]
    return [Table(
        f"Uncertainty: {how}; {100 * first.mc.coverage:g} % probabilistically symmetric coverage "
        f"intervals; values rounded to two significant digits of u; n/d: the estimator gives "
        f"the same value in every trial{gum_note}.", header, rows)] + (
        ["Read with care (u against the true value):", warnings] if warnings else [])


def _budget_table(outcome) -> Table:
    b = outcome.budget
    rows = []
    for out, g in b.groupby("output", sort=False):
        g = g.sort_values("share", ascending=False)
        top = [f"{r.input} {100 * r.share:.0f} %" for r in g.itertuples() if r.share >= 0.005]
        rows.append([out, "; ".join(top[:4]) or "-"])
    how = ("GUM law of propagation" if outcome.gum is not None else
           f"Monte Carlo, each source alone, {outcome.spec.budget_trials} trials")
    return Table(f"Budget: share of each error source in u² ({how}; "
                 f"{outcome.budget_estimator or outcome.recommended} estimator)",
                 ["measurand", "largest error sources"], rows)


def _summary_frame(outcome):
    import pandas as pd

    frames = []
    for est, r in outcome.results.items():
        df = r.summary().reset_index()
        df.insert(0, "estimator", est)
        df["trials"] = int(r.mc.trials)  # what the Monte Carlo columns (U_coverage) rest on
        frames.append(df)
    return pd.concat(frames, ignore_index=True)


def _panel_names(outcome, limit, csv_name) -> tuple[list, str]:
    """The measurands a many-panel figure shows (those that matter first) and the
    caption's note on the rest, which the CSV holds."""
    names = [m.name for m in outcome.results[outcome.recommended].measurands]
    if len(names) <= limit + 1:
        return names, ""
    ordered = list(outcome.key) + [n for n in names if n not in outcome.key]
    return ordered[:limit], (f" {limit} of {len(names)} measurands (toleranced ones first); "
                             f"all are in {csv_name}.")


def _sweep_blocks(k, outcome, csv) -> list:
    from mtplan.models.protocol import fields_info

    ps = outcome.spec
    docs = {f.name: f.doc for f in fields_info(ps.procedure.Setup)}
    units = {m.name: m.unit for m in outcome.results[outcome.recommended].measurands}
    base = ps.setup.as_dict()
    blocks = []
    for j, (spec, table) in enumerate(outcome.sweeps, start=1):
        vary = spec["vary"]
        if isinstance(table, str):
            blocks.append(f"The sweep over {', '.join(vary)} could not be computed: {table}")
            continue
        errors = table["error"] if "error" in table else None
        failed = (table[errors.notna() & (errors.astype(str) != "")]
                  if errors is not None else table.iloc[:0])
        ok = table.drop(failed.index)
        if len(ok):
            shown, more = _panel_names(outcome, 6, f"results/{ps.name}_{k}_sweep{j}.csv")
            x = next(iter(vary))
            label = field_label(x, docs.get(x, ""))
            base_value = base.get(x)
            blocks.append(Figure(
                f"Standard uncertainty against {label} (Monte Carlo, "
                f"{int(ok['trials'].max())} trials per set-up; bars: Monte Carlo error of u; "
                "curves offset sideways so that equal ones stay visible; u = 0, an estimator "
                "constant over every trial, not drawn)." + more,
                figs.sweep_figure(ok, vary, shown, units, xlabel=label,
                                  base=base_value if isinstance(base_value, int | float)
                                  else None)))
        for (est, *values), group in failed.groupby(["estimator", *vary], sort=False):
            shown = ", ".join(field_value(f, v) for f, v in zip(vary, values, strict=True))
            blocks.append(f"{est} cannot evaluate the set-up {shown}: "
                          f"{group['error'].iloc[0]}")
        csv[f"{ps.name}_{k}_sweep{j}"] = table
    return blocks


def _plan_blocks(plan, vary) -> list:
    if isinstance(plan, str):
        return [Section("Plan", level=2, blocks=[f"No set-up meets the targets: {plan}"])]
    best = plan.best
    from mtplan.plans.decisions import K

    scale = K / plan.k  # the planner's k-scaled u as U at the documents' k
    rows = [[n, f"≤ {v * scale:g}", fmt_u(scale * best["predicted"][n]),
             fmt_u(scale * best["confirmed"][n])] for n, v in plan.targets.items()]
    changed = [field_value(f, best["setup"][f]) for f in vary if f in best["setup"]]
    blocks = [Section("Plan: the cheapest set-up meeting the targets", level=2, blocks=[
        f"Recommended by the plan: {', '.join(changed) or 'the base set-up'}; machine time "
        f"{duration_text(best['duration_s'])} (confirmed by Monte Carlo).",
        Table(f"Targets for U (k = {K:g}) against the linearised prediction and the Monte "
              "Carlo confirmation", ["measurand", "U target", "U predicted", "U Monte Carlo"],
              rows)])]
    from mtplan.plans.planner import pareto_front

    front = list(pareto_front(plan.table["duration_s"].to_numpy(), plan.table["worst"].to_numpy()))
    blocks.append(Figure("Pareto front: machine time against the worst ratio of predicted "
                         "uncertainty to target; the star is the recommended set-up.",
                         figs.pareto_figure(plan.table, front, best["candidate"])))
    return blocks


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
                 "(column-scaled sensitivities; observability indices O1-O5, see the glossary)",
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
                         "source method's stepwise estimate moves with the errors named, bias per "
                         "typical error [µm or µrad])", ["function"] + ests, rows))
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
                         "the estimate; floor: smallest magnitude distinguishable from 0) [µrad]",
                         ["estimator", "angle", "observable", "sign", "quantum", "floor",
                          "why"], rows))
    return out


def measured_blocks(measured, warn: bool = True) -> list:
    """The readings' evaluation in full: estimate, bias correction, value, u, interval;
    ``warn``: with the warnings of :func:`~mtplan.reports.wording.value_warnings` (False
    where the page already gives them)."""
    import numpy as np

    n = len(measured.measurands)
    determinable = getattr(measured, "determinable", None)
    determinable = np.ones(n, dtype=bool) if determinable is None else np.asarray(determinable)
    correction = getattr(measured, "bias_correction", None)
    correction = np.zeros(n) if correction is None else np.asarray(correction, dtype=float)
    reasons = getattr(measured, "reasons", None) or {}
    from mtplan.reports.along import along_names

    along = along_names(measured)  # drawn in their own figure
    rows, items = [], []
    for i, m in enumerate(measured.measurands):
        if m.name in along:
            continue
        u = float(measured.std[i])
        if not determinable[i]:
            rows.append([m.name, unit(m.unit), fmt(measured.estimate[i]), "-", "n/d", "n/d",
                         "n/d"])
            continue
        items.append((m.name, float(measured.value[i]), u, float(measured.low[i]),
                      float(measured.high[i])))
        rows.append([m.name, unit(m.unit),
                     fmt(measured.estimate[i], u), fmt(correction[i], u),
                     fmt(measured.value[i], u), fmt_u(u),
                     f"[{fmt(measured.low[i], u)}, {fmt(measured.high[i], u)}]"])
    how = {"mc": "Monte Carlo of the set-up's error sources about the estimate",
           "posterior": "Bayesian posterior of the forward model (emcee)"}.get(
        measured.uncertainty, measured.uncertainty)
    text = [f"Readings evaluated with the {measured.estimator} estimator; uncertainty: {how}."]
    text += [f"{name}: not determinable: {why}." for name, why in reasons.items()]
    warnings, flagged = value_warnings(items) if warn else ([], set())
    for row in rows:
        row[0] += " *" if row[0] in flagged else ""
    text += [f"* {w}" for w in warnings]
    setup_cls = type(getattr(measured, "setup", None))
    words = (customer_words if not hasattr(setup_cls, "__dataclass_fields__") else
             lambda x: customer_words(plain_fields(x, setup_cls)))
    text += [words(str(x)) for x in measured.notes]
    blocks = [Section("Measured data", level=2, blocks=text + [
        Table("Measurands from the readings (estimate: the estimator's value; correction: "
              "the bias correction added; value: the reported value, the posterior mean for "
              "a posterior; n/d: not determinable)",
              ["measurand", "unit", "estimate", "correction", "value", "u", "interval"],
              rows)])]
    post = getattr(measured, "details", None)
    if measured.uncertainty == "posterior" and post is not None:
        blocks += _posterior_blocks(post)
    return blocks


def _posterior_blocks(post) -> list:
    from mtplan.reports.along import along_names

    along = along_names(post)  # the errors along the travel: in their own figure
    names = [m.name for m in post.measurands if m.name not in along]
    samples = {f"{m.name} [{unit(m.unit)}]": post.samples[m.name] for m in post.measurands
               if m.name not in along}
    state = "converged" if post.converged else "NOT CONVERGED: read with care"
    # a free parameter that is a measurand in its field's units (EX0C_um) is listed once
    others = [p for p in post.parameters if p.rsplit("_", 1)[0] not in names]
    return [
        Table(f"Posterior diagnostics ({state}): the posterior is sampled by Markov chain "
              f"Monte Carlo, {post.chains.shape[0]} ensembles of {post.n_walkers} walkers "
              f"(chains that move together) over {post.n_steps} steps; the first "
              f"{post.discard} steps (burn-in) are discarded and "
              + ("every step is kept (no thinning)" if post.thin == 1 else
                 f"one step in {post.thin} is kept (thinning)") + ". tau: integrated autocorrelation time, the steps between "
              "independent samples; R-hat: the Gelman-Rubin ratio of the spread between "
              "ensembles to that within them (near 1: they agree); ESS: effective sample "
              "size, the number of independent samples the chains are worth.",
              ["quantity", "mean", "u", "tau", "R-hat", "ESS"],
              [[n, fmt(post.mean[n], post.std[n]), fmt_u(post.std[n]),
                f"{post.tau.get(n, float('nan')):.3g}", f"{post.rhat[n]:.4f}",
                f"{post.ess[n]:.0f}"] for n in names + others]),
        Figure("Posterior of the measurands: pairwise samples and marginal histograms "
               "(corner plot); lines: posterior mean.", figs.corner_figure(samples)),
        Figure("The path of every walker (chain) of the first ensemble through each free "
               "parameter, step by step (grey: the discarded burn-in).",
               figs.trace_figure({p: post.trace(p)[0] for p in post.parameters},
                                 discard=post.discard))]
