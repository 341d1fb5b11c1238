"""The planning study of a test plan: estimators and the page of each test.

:func:`methods_section` explains every test's estimators once; :func:`test_section` gives
one test's results table, the figure of the lever that matters most and what the
simulation shows (levers, dominant sources, the plan, estimator biases);
:func:`verdict_frames` writes ``results/verdicts.csv`` and ``results/summary.csv``. The
test plan and the test report (:mod:`mtplan.reports.certificate`) are built from them.

Nothing here computes a result: numbers come from the result objects and the
study's decisions (:mod:`mtplan.plans.decisions`), rounded to their uncertainty.
"""

from __future__ import annotations

from mtplan.plans.decisions import K
from mtplan.reports import figures as figs
from mtplan.reports.labels import (
    duration_text,
    field_label,
    field_value,
    fmt,
    fmt_u,
    tolerance_text,
    unit,
)
from mtplan.reports.model import Document, Figure, Section, Table
from mtplan.reports.wording import probability_text
from mtplan.uncertainty.coverage import coverage_text

__all__ = ["Document", "Section", "Table", "Figure", "methods_section", "test_section",
           "setup_sentence", "verdict_frames", "covariance_frames", "fmt", "fmt_u"]

def verdict_frames(result) -> dict:
    """``results/verdicts.csv`` and ``results/summary.csv`` of a computed study."""
    import dataclasses

    import pandas as pd

    rows = [dataclasses.asdict(r) for o in result.outcomes for r in o.summary]
    for r in rows:
        r["setup"] = "; ".join(f"{k}={v}" for k, v in r["setup"].items())
    columns = ["procedure", "test", "measurand", "unit", "estimator", "lower", "upper", "u",
               "k", "U", "U_coverage", "U_coverage_se", "rule", "guard_band",
               "acceptance_lower",
               "acceptance_upper", "tur", "pfa", "pfr", "measured", "measured_u",
               "measured_low", "measured_high", "measured_U", "measured_U_coverage",
               "measured_U_coverage_se",
               "measured_U_coverage_from", "measured_source", "p_conform", "p_conform_population", "population_source",
               "verdict", "reason"]
    verdicts = pd.DataFrame([v.row() for v in result.verdicts], columns=columns)
    # the probabilities as the PDF states them: never certain ("> 99.9 %" is 0.999 here,
    # not 1.0), with the printed text beside them
    for name in ("p_conform", "p_conform_population"):
        verdicts[f"{name}_text"] = [probability_text(p) for p in verdicts[name]]
        verdicts[name] = verdicts[name].clip(lower=0.001, upper=0.999)
    return {"verdicts": verdicts, "summary": pd.DataFrame(rows)}


def covariance_frames(result) -> dict:
    """``results/covariance_<procedure>_<k>.csv`` per test: the covariance of the measured
    values where the test has readings, else of the recommended estimator's Monte Carlo."""
    from mtplan.evaluation.covariance import covariance_frame

    frames = {}
    for k, o in enumerate(result.outcomes, start=1):
        m = o.measured
        if m is not None:
            frame = covariance_frame(m.measurands, m.covariance)
            source = f"measured ({m.estimator}, {m.uncertainty})"
        else:
            r = o.results[o.recommended]
            frame = covariance_frame(r.measurands, r.mc.cov)
            source = f"simulated ({r.estimator}, Monte Carlo of the set-up)"
        frame.insert(2, "source", source)
        frames[f"covariance_{o.spec.name}_{k}"] = frame
    return frames


# ----------------------------------------------------------------------- methods
def methods_section(result) -> Section:
    rows = []
    for o in result.outcomes:
        proc = o.spec.procedure
        for j, est in enumerate(o.spec.estimators):
            rows.append([o.spec.label if j == 0 else "", est,
                         proc.estimators[est].description,
                         "recommended" if est == o.recommended else ""])
    return Section("Methods and estimators", anchor="methods", blocks=[
        "Every test is simulated with its error sources (Monte Carlo, JCGM 101) to give the "
        "uncertainty of its set-up; the estimators of a test are compared on the same "
        "simulated readings. The recommended estimator has the smallest root-mean-square "
        "error (uncertainty and bias) on the measurands that matter; the source method's own "
        "estimator (patent, three_point) is kept unless another is better beyond the Monte "
        "Carlo error.",
        Table("Estimators", ["test", "estimator", "method", "use"], rows)])


# ----------------------------------------------------------------------- one test
def _results_table(o) -> Table:
    r = o.results[o.recommended]
    verdicts = {v.measurand: v for v in o.verdicts}
    m_res = o.measured
    header = ["measurand", "meaning", "U (k = 2)", "±U covers"]
    if m_res is not None:
        header += ["measured", "95 % interval"]
    if verdicts:
        header += ["tolerance", "verdict"]
    rows = []
    measured_index = ({m.name: i for i, m in enumerate(m_res.measurands)}
                      if m_res is not None else {})
    determinable = getattr(m_res, "determinable", None)
    for i, m in enumerate(r.measurands):
        big_u = K * float(r.mc.std[i])
        row = [f"{m.name} [{unit(m.unit)}]", m.description,
               fmt_u(big_u) if big_u > 0 else "n/d",
               coverage_text(float(r.U_coverage[i]), se=float(r.U_coverage_se[i]))
               if big_u > 0 else "-"]
        if m_res is not None:
            j = measured_index[m.name]
            ok = determinable is None or bool(determinable[j])
            uj = float(m_res.std[j]) if ok else None
            row += ([fmt(m_res.value[j], uj),
                     f"[{fmt(m_res.low[j], uj)}, {fmt(m_res.high[j], uj)}]"] if ok
                    else ["n/d", "-"])
        if verdicts:
            v = verdicts.get(m.name)
            row += ([tolerance_text(v.lower, v.upper), v.verdict] if v else ["-", ""])
        rows.append(row)
    how = (f"{r.mc.trials} Monte Carlo trials" if not r.mc.digits else
           f"adaptive Monte Carlo, {r.mc.trials} trials")
    return Table(f"Results with the {o.recommended} estimator: U of the study's set-up "
                 f"({how}, every error source) with the fraction of its Monte Carlo values "
                 "within ± U"
                 + ("; measured: from the readings" if m_res is not None else "") + ".",
                 header, rows)


def setup_sentence(o) -> str:
    from mtplan.models.protocol import fields_info

    proc = o.spec.procedure
    docs = {f.name: f.doc for f in fields_info(proc.Setup)}
    shown = ", ".join(f"{field_label(f, docs.get(f, '')).split(' [')[0]} {_value(v)}"
                      f"{' ' + unit(_suffix(f)) if _suffix(f) else ''}"
                      for f, v in o.setup_shown.items())
    return shown or "the default set-up"


def datasheet_text(o) -> str:
    """The test's conditions outside its instruments' data sheets, in plain words, as one
    paragraph ("" where the set-up is within them): :meth:`~mtplan.models.protocol.
    SetupBase.datasheet_notes` of the set-up its results come from (the readings' where the
    test has them), each naming the condition and the rule the budget applies there. The
    plan, the plan's annex and the report print it with the test's set-up."""
    from mtplan.models.protocol import DATASHEET_NOTE
    from mtplan.reports.labels import plain_fields
    from mtplan.reports.wording import customer_words

    setup = getattr(o.measured, "setup", None) or o.spec.setup
    notes = [n.removeprefix(DATASHEET_NOTE) for n in setup.datasheet_notes()]
    if not notes:
        return ""
    return ("Outside the instruments' data sheets: "
            + "; ".join(customer_words(plain_fields(n, type(setup))) for n in notes) + ".")


def setting_text(o, field: str, value) -> str:
    """A set-up field at a value as the set-up sentence words it: "arc of A covered by the
    points 90 deg"."""
    from mtplan.models.protocol import fields_info

    docs = {f.name: f.doc for f in fields_info(o.spec.procedure.Setup)}
    label = field_label(field, docs.get(field, "")).split(" [")[0]
    return f"{label} {_value(value)}" + (f" {unit(_suffix(field))}" if _suffix(field) else "")


def _value(v) -> str:
    from mtplan.reports.labels import value_text

    return value_text(v)


def _suffix(name) -> str:
    from mtplan.reports.labels import split_field

    return split_field(name)[1]


def test_section(k, o) -> Section:
    ps = o.spec
    standards = ", ".join(ps.standards) or "no test standard named"
    sec = Section(f"{k}. {ps.label}", anchor=f"p{k}")
    sec.blocks.append(f"{o.title}. Standards: {standards}. Set-up: {setup_sentence(o)}; "
                      f"machine time {duration_text(o.duration_s)}. Estimator: "
                      f"{o.recommended} (recommended among {', '.join(ps.estimators)}).")
    if ps.notes:
        sec.blocks.append(ps.notes)
    if datasheet_text(o):
        sec.blocks.append(datasheet_text(o))
    sec.blocks.append(_results_table(o))
    figure = _test_figure(o)
    if figure is not None:
        sec.blocks.append(figure)
    sec.blocks.append(Section("What the simulation shows", level=2, blocks=[_findings(o)]))
    return sec


def _test_figure(o) -> Figure | None:
    """The sweep of the lever that matters most, with the target u and the study's
    set-up marked; without one, the measured values against their tolerances."""
    from mtplan.models.protocol import fields_info

    effect = o.levers[0] if o.levers else None
    if effect is None:
        if not o.verdicts:
            return None
        return Figure("Measured values against their tolerances (see 'Conformity decisions').",
                      figs.acceptance_figure(o.verdicts))
    spec, table = o.sweeps[effect.sweep]
    docs = {f.name: f.doc for f in fields_info(o.spec.procedure.Setup)}
    ok = table[table["error"].astype(str) == ""] if "error" in table else table
    first = o.results[o.recommended]
    units = {m.name: m.unit for m in first.measurands}
    marked = {m.name: float(first.mc.std[i]) for i, m in enumerate(first.measurands)}
    label = field_label(effect.field, docs.get(effect.field, ""))
    targets = {n: t for n, t in o.targets.items() if n in o.key}
    what = sorted({_target_words(t[1]) for t in targets.values()})
    return Figure(
        f"Expanded uncertainty U (k = {K:g}) against {label} ({int(ok['trials'].max())} Monte "
        "Carlo trials per set-up; bars: Monte Carlo error of U); the star is the study's "
        f"set-up with the {o.recommended} estimator, at the U of the table above"
        + (f", the dashed line {' or '.join(what)}" if what else "")
        + "; U = 0 (an estimator constant over every trial, below its resolution) is not "
        "drawn. Other levers and all measurands: appendix.",
        figs.lever_figure(ok, effect.field, o.key[:4], units, estimator=effect.estimator,
                          recommended=o.recommended, base=effect.base_value, targets=targets,
                          xlabel=label, marked=marked, coverage=K))


def _target_words(what: str) -> str:
    """The dashed line of a sweep figure in words, at the figure's k: "the U for TUR = 4",
    "the plan's target"."""
    return "the plan's target" if "plan" in what else "the U for TUR = 4"


def _duration_change(before: float, after: float) -> str:
    """"; the test takes 12 min instead of 8 min", in one unit; "" when it is the same."""
    if not (before == before and after == after) or abs(after - before) < 0.5:
        return "; the test takes as long"
    if max(before, after) >= 120:
        return f"; the test takes {after / 60:.1f} min instead of {before / 60:.1f} min"
    return f"; the test takes {after:.0f} s instead of {before:.0f} s"


# ----------------------------------------------------------------------- findings
def _source_words(name: str) -> str:
    """An error source's name as the start of a sentence: ``axial_motion`` -> Axial motion."""
    words = name.replace("_", " ")
    return words[:1].upper() + words[1:]


def lever_U(o, e) -> tuple[float, float]:  # noqa: N802
    """(U at the agreed set-up, U at the lever's best value) of a lever effect, quoted
    from the same computation as the test's table: the table's U, and that U times the
    sweep's ratio u_best / u_base (the sweep runs fewer trials than the table, so its own
    U at the agreed value differs from the table's by its Monte Carlo error)."""
    r = o.results[o.recommended] if e.estimator not in o.results else o.results[e.estimator]
    index = {m.name: i for i, m in enumerate(r.measurands)}
    if e.measurand not in index or not (e.u_base == e.u_base and e.u_base > 0):
        return K * e.u_base, K * e.u_best
    u = float(r.mc.std[index[e.measurand]])
    return K * u, K * u * e.u_best / e.u_base


def _findings(o) -> list[str]:
    """What the simulation shows, in sentences an engineer can act on."""
    from mtplan.models.protocol import fields_info

    docs = {f.name: f.doc for f in fields_info(o.spec.procedure.Setup)}
    notes = []
    significant = [e for e in o.levers if e.significant and e.gain > 1.05]
    for e in significant[:2]:
        label = field_label(e.field, docs.get(e.field, "")).split(" [")[0]
        u = unit(e.unit)
        if e.u_base == e.u_base:  # the study's value was swept
            before, after = lever_U(o, e)
            notes.append(f"Lever: {label} {_value(e.best_value)} instead of "
                         f"{_value(e.base_value)} lowers U({e.measurand}) from "
                         f"{fmt_u(before)} to {fmt_u(after)} {u} "
                         f"({e.gain:.1f} times)"
                         + _duration_change(e.duration_base_s, e.duration_best_s) + ".")
        else:
            notes.append(f"Lever: {label} {_value(e.best_value)} gives U({e.measurand}) = "
                         f"{fmt_u(K * e.u_best)} {u}, {e.gain:.1f} times less than "
                         f"{_value(e.ref_value)} (the study's {_value(e.base_value)} was not "
                         "swept).")
    if o.levers and not significant:
        swept = ", ".join(field_label(e.field, docs.get(e.field, "")).split(" [")[0]
                          for e in o.levers)
        notes.append(f"No swept lever ({swept}) lowers the uncertainty of "
                     f"{', '.join(o.key)} beyond the Monte Carlo error.")
    for d in o.dominant[:2]:
        shown = ", ".join(f"{n} {100 * s:.0f} %" for n, s in d["measurands"][:4])
        more = (f" and {len(d['measurands']) - 4} more measurands"
                if len(d["measurands"]) > 4 else "")
        if d["lever"]:
            notes.append(f"{_source_words(d['source'])} carries {shown}{more} of u²: the "
                         "place to improve the set-up.")
        else:
            notes.append(f"{_source_words(d['source'])} dominates ({shown}{more} of u²): a "
                         "property of the machine, workpiece or instrument, not a lever of "
                         "the set-up.")
    notes += _plan_finding(o)
    notes += _estimator_findings(o)
    notes += _hook_findings(o)
    return notes or ["No significant bias; the estimators agree within their Monte Carlo "
                     "error."]


def _plan_finding(o) -> list[str]:
    plan = o.plan
    if plan is None:
        return []
    if isinstance(plan, str):
        return [f"No set-up of the plan's grid meets the targets: {plan}"]
    best = plan.best
    changed = ", ".join(field_value(f, best["setup"][f]) for f in plan_fields(o)
                        if f in best["setup"])
    adopted = " (the agreed set-up)" if plan_adopted(o) else ""
    return [f"Plan: {changed}{adopted} meets the targets ({target_text(o)}) in "
            f"{duration_text(best['duration_s'])} of machine time (confirmed by Monte "
            "Carlo; appendix)."]


def plan_fields(o) -> list:
    """The set-up fields the plan chose: those of its grid (``vary``), else those its
    search over the levers changed, a calibration's own fields included."""
    vary = o.spec.plan.get("vary", {})
    if vary or o.plan is None or isinstance(o.plan, str):
        return list(vary)
    best = o.plan.best
    cal = [c for c in o.spec.procedure.capabilities.calibrations if c.name == best.get("calibration")]
    return [f for f in best.get("changes", {}) if f != "calibration"] + [
        f for c in cal for f in c.values]


def plan_targets(plan) -> dict:
    """The plan's targets as expanded uncertainties at the documents' k: {measurand: U}
    (a study may state them at another k, ``[procedure.plan] k``)."""
    return {n: float(t) * K / plan.k for n, t in plan.targets.items()}


def target_text(o) -> str:
    """"U(centre_x) ≤ 2 µm, U(centre_y) ≤ 2 µm (k = 2)": the plan's targets as the
    documents print every U."""
    units = {m.name: unit(m.unit) for m in o.results[o.recommended].measurands}
    shown = ", ".join(f"U({n}) ≤ {t:g} {units.get(n, '')}".rstrip()
                      for n, t in plan_targets(o.plan).items())
    return f"{shown} (k = {K:g})"


def plan_adopted(o) -> bool:
    """Whether the planner's cheapest set-up meeting the targets is the agreed one (the
    fields the plan varies have the study's values)."""
    plan = o.plan
    if plan is None or isinstance(plan, str):
        return False
    agreed = o.spec.setup.as_dict()
    fields = plan_fields(o)
    return all(best == agreed.get(f) for f, best in plan.best["setup"].items() if f in fields)


def _estimator_findings(o) -> list[str]:
    notes = []
    comp = o.comparison
    n_all = len(next(iter(o.results.values())).measurands)
    for better, worse, factors in comp.get("better", []):
        if o.recommended not in (better, worse):
            continue
        name, top = max(factors, key=lambda t: t[1])
        notes.append(f"{better} determines {len(factors)} of {n_all} measurands better than "
                     f"{worse} (up to {top:.1f} times, {name}).")
    biases = [b for b in comp.get("bias", []) if b[0] == o.recommended]
    for est, name, b, s in biases[:3]:
        u = unit(next(m.unit for m in o.results[est].measurands if m.name == name))
        size = f"{abs(b) / s:.1f} u" if s > 0 else "every trial gave the same value"
        notes.append(f"{est}: {name} is biased by {fmt(b, s)} {u} ({size}).")
    if len(biases) > 3:
        notes.append(f"{est}: {len(biases) - 3} more biased measurands (appendix).")
    return notes


def _hook_findings(o) -> list[str]:
    """Observability and identifiability from the procedure's own analysis."""
    notes = []
    for est, angles in (o.extras.get("observability") or {}).items():
        if est != o.recommended:
            continue
        for name, ob in angles.items():
            if not getattr(ob, "observable", True):
                notes.append(f"{est}: {name} is not observable at this set-up: {ob.reason}.")
            elif getattr(ob, "quantum_urad", 0) > 0:
                notes.append(f"{est}: {name} is quantised: {ob.reason}.")
    for est, table in (o.extras.get("identifiability") or {}).items():
        if est != o.recommended:
            continue
        counts = table["status"].value_counts()
        bad = {k: int(v) for k, v in counts.items() if k != "identified"}
        if bad:
            notes.append(f"{est}: of the 21 error functions, {int(counts.get('identified', 0))} "
                         "are identified; " + ", ".join(f"{v} {k}" for k, v in bad.items())
                         + " (appendix).")
    ident = o.identifiability
    if ident is not None and ident.rank < ident.n_params:
        notes.append(f"The readings determine only {ident.rank} of {ident.n_params} "
                     "parameters: some combinations cannot be separated (appendix).")
    return notes
