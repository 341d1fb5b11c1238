"""The report as a document model: a cover, a summary, a customer body and an appendix.

:func:`build_document` turns a :class:`~mtplan.plans.study.StudyResult` into a
:class:`Document`; the HTML and PDF renderers draw the same document, so the two
carry the same content in the same order:

1. the cover: title, the study's header (customer, machine, place, date, ambient
   temperature, document number), the standards applied per test and the sign-off;
2. the summary: one row per test and measurand that matters, with the verdict;
3. the conformity decisions: one sentence per toleranced measurand and a figure;
4. methods, estimators and terms, each explained once;
5. one page per test: its results table, one figure and what the simulation shows;
6. the appendix (:mod:`mtplan.reports.appendix`): set-ups, all tables and sweeps,
   budgets, identifiability, posterior diagnostics, provenance.

Nothing here computes a result: numbers come from the result objects and the
study's decisions (:mod:`mtplan.plans.decisions`), rounded to their uncertainty.
"""

from __future__ import annotations

from mtplan.reports import figures as figs
from mtplan.reports.labels import (
    duration_text,
    field_label,
    field_value,
    fmt,
    fmt_u,
    percent,
    prior_text,
    tolerance_text,
    unit,
)
from mtplan.reports.model import Document, Figure, Section, Table

__all__ = ["Document", "Section", "Table", "Figure", "build_document", "fmt", "fmt_u"]

_HEADER_LABELS = {"document": "document number", "revision": "revision",
                  "customer": "customer", "machine_maker": "machine maker",
                  "machine_type": "machine type", "machine_serial": "serial number",
                  "location": "location", "operator": "operator", "date": "date of the test",
                  "ambient_temperature_c": "ambient temperature"}
_SIGNOFF = (("prepared_by", "prepared"), ("checked_by", "checked"), ("approved_by", "approved"))


def _cover(result) -> tuple[dict, list, list]:
    """(header label -> value, sign-off rows, standards per test) of the cover."""
    study = result.study
    meta = {}
    for key, label in _HEADER_LABELS.items():
        if key in study.header:
            value = study.header[key]
            meta[label] = f"{value:.1f} °C" if key == "ambient_temperature_c" else str(value)
    signoff = [(role, study.header.get(key, "")) for key, role in _SIGNOFF]
    standards = []
    for o in result.outcomes:
        applied = list(o.spec.standards) + ["JCGM 101:2008 (Monte Carlo)"]
        if o.gum is not None:
            applied.append("JCGM 100:2008 (GUM)")
        if o.verdicts:
            applied += ["ISO 14253-1:2017", "JCGM 106:2012"]
        # a standard's name is not broken over two lines (no-break spaces)
        standards.append((o.spec.label, ", ".join(a.replace(" ", "\u00a0") for a in applied)))
    return meta, signoff, standards


def build_document(result) -> Document:
    """The report of a computed study."""
    from mtplan.reports import appendix

    study = result.study
    sections = [_summary_section(result), _conformity_section(result),
                _methods_section(result)]
    sections += [_test_section(k, o) for k, o in enumerate(result.outcomes, start=1)]
    csv = {}
    for k, o in enumerate(result.outcomes, start=1):
        sec, frames = appendix.procedure_section(k, o)
        sections.append(sec)
        csv.update(frames)
    sections.append(appendix.provenance_section(result.provenance))
    csv.update(_verdict_frames(result))
    csv.update(_covariance_frames(result))
    meta, signoff, standards = _cover(result)
    return Document(title=study.title, subtitle=study.meta.get("subtitle", ""), meta=meta,
                    provenance=result.provenance, sections=sections, csv=csv,
                    signoff=signoff, standards=standards)


def _verdict_frames(result) -> dict:
    import dataclasses

    import pandas as pd

    rows = [dataclasses.asdict(r) for o in result.outcomes for r in o.summary]
    for r in rows:
        r["setup"] = "; ".join(f"{k}={v}" for k, v in r["setup"].items())
    columns = ["procedure", "test", "measurand", "unit", "estimator", "lower", "upper", "u",
               "k", "U", "rule", "guard_band", "acceptance_lower", "acceptance_upper", "tur",
               "pfa", "pfr", "measured", "measured_u", "measured_low", "measured_high",
               "measured_source", "p_conform", "verdict", "reason"]
    verdicts = pd.DataFrame([v.row() for v in result.verdicts], columns=columns)
    return {"verdicts": verdicts, "summary": pd.DataFrame(rows)}


def _covariance_frames(result) -> dict:
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


# ----------------------------------------------------------------------- summary
def _setup_text(row) -> str:
    shown = [field_value(f, v) for f, v in row.setup.items()]
    return "; ".join(shown[:4] + (["..."] if len(shown) > 4 else [])) or "default set-up"


def _summary_section(result) -> Section:
    """One row per test and measurand that matters: set-up, estimator, U, duration,
    tolerance, TUR, measured value and verdict."""
    rows, notes = [], []
    for o in result.outcomes:
        for j, r in enumerate(o.summary):
            first = j == 0
            measured = "-" if r.measured is None else fmt(r.measured, r.measured_u)
            if r.verdict == "not determinable":
                measured = "n/d"
                notes.append(f"{r.label}, {r.measurand}: not determinable: {r.reason}.")
            rows.append([f"{r.section}. {r.label}" if first else "",
                         f"{r.measurand} [{unit(r.unit)}]",
                         f"{_setup_text(r)}; {r.estimator}" if first else "",
                         fmt_u(r.U), duration_text(r.duration_s) if first else "",
                         tolerance_text(r.lower, r.upper),
                         "-" if r.tur is None else f"{r.tur:.1f}", measured,
                         r.verdict or "no tolerance"])
    caption = ("Results of every test: the study's set-up (levers as tested) and the "
               "recommended estimator; U: expanded uncertainty, k = 2, of the set-up's whole "
               "error budget (Monte Carlo, JCGM 101); TUR: test uncertainty ratio, tolerance "
               "width over 2U; measured: the value from the readings.")
    blocks = [Table(caption, ["test", "measurand", "set-up and estimator", "U (k = 2)",
                              "duration", "tolerance", "TUR", "measured", "verdict"], rows),
              "Verdicts after ISO 14253-1 with the guard band w of each acceptance rule: a "
              "measured value conforms inside the tolerance reduced by w, does not conform "
              "outside the tolerance widened by w, and between the two no decision can be made "
              "(inside the guard band). Section 'Conformity decisions' states each rule and its "
              "risks; the test pages show the details."]
    blocks += notes
    return Section("Summary", blocks=blocks, anchor="summary")


# ----------------------------------------------------------------------- conformity
def _rule_text(v) -> str:
    u = unit(v.unit)
    w = fmt(v.guard_band, v.U / 10)
    kind, _, value = v.rule.partition(":")
    if kind == "simple" or not v.guard_band:
        return "simple acceptance (no guard band, JCGM 106)"
    if kind == "iso14253":
        return f"the guard band w = U = {w} {u} (k = 2, ISO 14253-1)"
    if kind == "guard":
        return f"the guard band w = {float(value):g} U = {w} {u} (k = 2, JCGM 106)"
    if kind == "target-pfa":
        return (f"the guard band w = {w} {u} that keeps the global false accept at "
                f"{percent(float(value))} (JCGM 106)")
    return f"Dobbert's managed guard band w = {w} {u}"


def _limits_text(v) -> tuple[str, str]:
    """(accept-if, reject-if) phrases of a verdict's limits."""
    u, w = unit(v.unit), v.guard_band
    res = v.U / 10
    a_lo, a_hi = v.acceptance_limits
    if v.lower is not None and v.upper is not None:
        if abs(a_lo + a_hi) < 1e-9 * max(abs(a_hi), 1):
            return (f"within ±{fmt(a_hi, res)} {u}",
                    f"beyond ±{fmt(v.upper + w, res)} {u}" if w else "")
        return (f"within [{fmt(a_lo, res)}, {fmt(a_hi, res)}] {u}",
                f"outside [{fmt(v.lower - w, res)}, {fmt(v.upper + w, res)}] {u}" if w else "")
    if v.upper is not None:
        return f"at most {fmt(a_hi, res)} {u}", f"above {fmt(v.upper + w, res)} {u}" if w else ""
    return f"at least {fmt(a_lo, res)} {u}", f"below {fmt(v.lower - w, res)} {u}" if w else ""


def decision_sentence(v) -> str:
    """The acceptance rule of one toleranced measurand, applied to its measured value."""
    u = unit(v.unit)
    text = f"{v.measurand}: "
    if v.acceptance_limits == (None, None) and v.verdict == "not determinable":
        return text + f"no acceptance plan: {v.reason}."
    accept, reject = _limits_text(v)
    text += (f"accept if the measured value lies {accept} (tolerance "
             f"{tolerance_text(v.lower, v.upper, v.unit)} reduced by {_rule_text(v)})")
    text += f", reject if {reject}." if reject else "."
    if v.pfa is not None:
        text += (f" Global false accept {percent(v.pfa)}, false reject {percent(v.pfr)} for "
                 f"items distributed {prior_text(v.prior, v.unit)}.")
    if v.tur is not None:
        text += f" TUR {v.tur:.1f}."
    if v.measured is None:
        return text + f" {v.verdict.upper()}" + (f": {v.reason}." if v.reason else ".")
    res = v.measured_u
    text += (f" Measured {fmt(v.measured, res)} {u} [{fmt(v.measured_low, res)}, "
             f"{fmt(v.measured_high, res)}] ({v.measured_source}): {v.verdict.upper()}")
    if v.p_conform is not None:
        text += f"; probability that it conforms {percent(v.p_conform)}"
    text += "."
    if v.reason:
        text += f" Note: {v.reason}."
    return text


def _conformity_section(result) -> Section:
    verdicts = result.verdicts
    sec = Section("Conformity decisions", anchor="conformity")
    if not verdicts:
        sec.blocks.append("The study states no tolerances: no conformity decision is made.")
        return sec
    sec.blocks.append("Each toleranced measurand with its decision rule (set before measuring, "
                      "from the uncertainty U of the planned set-up, k = 2), its global risks "
                      "for the stated population of items, and the rule applied to the measured "
                      "value with its 95 % interval.")
    for k, o in enumerate(result.outcomes, start=1):
        if o.verdicts:
            sec.blocks.append(f"{k}. {o.spec.label} ({o.verdicts[0].estimator} estimator):")
            sec.blocks.append([decision_sentence(v) for v in o.verdicts])
    sec.blocks.append(Figure("Measured values (dot, 95 % interval) against the tolerance "
                             "(black lines), the guard bands (amber: no decision), the zones "
                             "of conformity (green) and non-conformity (red), and the "
                             "population of items (grey curve: the prior of the risks).",
                             figs.acceptance_figure(verdicts)))
    return sec


# ----------------------------------------------------------------------- methods
_TERMS = [
    ["u", "standard uncertainty: the standard deviation of the estimate over the Monte Carlo "
          "trials of every error source (JCGM 101)"],
    ["U, k", "expanded uncertainty U = k u with coverage factor k = 2 (about 95 %)"],
    ["interval", "95 % coverage interval: probabilistically symmetric for the simulation, "
                 "the estimate less the simulated error quantiles for measured data"],
    ["bias", "mean estimate minus the true value of the simulation"],
    ["TUR", "test uncertainty ratio: tolerance width / (2U)"],
    ["guard band w", "distance between a tolerance limit and its acceptance limit"],
    ["false accept / reject", "global probabilities (JCGM 106 9.5) that an item of the stated "
                              "population is accepted although it does not conform, or "
                              "rejected although it conforms"],
    ["probability that it conforms", "specific to the measured value (JCGM 106 7.4)"],
    ["lever", "a set-up field the engineer chooses (counts, geometry, order, dwell); the "
              "other fields are properties of the machine, workpiece or instrument"],
]


def _methods_section(result) -> Section:
    from mtplan.models import get
    from mtplan.reports.labels import estimator_text

    rows = []
    for o in result.outcomes:
        proc = get(o.spec.name)
        for j, est in enumerate(o.spec.estimators):
            rows.append([o.spec.label if j == 0 else "", est,
                         estimator_text(proc.estimators[est]),
                         "recommended" if est == o.recommended else ""])
    return Section("Methods, estimators and terms", anchor="methods", blocks=[
        "Every test is simulated with its error sources (Monte Carlo, JCGM 101) to give the "
        "uncertainty of its set-up; the estimators of a test are compared on the same "
        "simulated readings. The recommended estimator has the smallest root-mean-square "
        "error (uncertainty and bias) on the measurands that matter; the patent's method "
        "(patent, three_point) is kept unless another is better beyond the Monte Carlo error.",
        Table("Estimators", ["test", "estimator", "method", "use"], rows),
        Table("Terms", ["term", "meaning"], _TERMS)])


# ----------------------------------------------------------------------- one test
def _results_table(o) -> Table:
    r = o.results[o.recommended]
    verdicts = {v.measurand: v for v in o.verdicts}
    m_res = o.measured
    header = ["measurand", "meaning", "U (k = 2)"]
    if m_res is not None:
        header += ["measured", "95 % interval"]
    if verdicts:
        header += ["tolerance", "verdict"]
    rows = []
    measured_index = ({m.name: i for i, m in enumerate(m_res.measurands)}
                      if m_res is not None else {})
    determinable = getattr(m_res, "determinable", None)
    for i, m in enumerate(r.measurands):
        big_u = 2 * float(r.mc.std[i])
        row = [f"{m.name} [{unit(m.unit)}]", m.description,
               fmt_u(big_u) if big_u > 0 else "n/d"]
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
                 f"({how}, every error source)"
                 + ("; measured: from the readings" if m_res is not None else "") + ".",
                 header, rows)


def _setup_sentence(o) -> str:
    from mtplan.models import get
    from mtplan.models.protocol import fields_info

    proc = get(o.spec.name)
    docs = {f["name"]: f["doc"] for f in fields_info(proc.Setup)}
    shown = ", ".join(f"{field_label(f, docs.get(f, '')).split(' [')[0]} {_value(v)}"
                      f"{' ' + unit(_suffix(f)) if _suffix(f) else ''}"
                      for f, v in o.setup_shown.items())
    return shown or "the default set-up"


def _value(v) -> str:
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, list | tuple):
        return ", ".join(_value(x) for x in v)
    return str(v)


def _suffix(name) -> str:
    from mtplan.reports.labels import split_field

    return split_field(name)[1]


def _test_section(k, o) -> Section:
    ps = o.spec
    standards = ", ".join(ps.standards) or "no test standard named"
    sec = Section(f"{k}. {ps.label}", anchor=f"p{k}")
    sec.blocks.append(f"{o.title}. Standards: {standards}. Set-up: {_setup_sentence(o)}; "
                      f"machine time {duration_text(o.duration_s)}. Estimator: "
                      f"{o.recommended} (recommended of {', '.join(ps.estimators)}).")
    if ps.notes:
        sec.blocks.append(ps.notes)
    sec.blocks.append(_results_table(o))
    figure = _test_figure(o)
    if figure is not None:
        sec.blocks.append(figure)
    sec.blocks.append(Section("What the simulation shows", level=2, blocks=[_findings(o)]))
    return sec


def _test_figure(o) -> Figure | None:
    """The sweep of the lever that matters most, with the target u and the study's
    set-up marked; without one, the measured values against their tolerances."""
    from mtplan.models import get
    from mtplan.models.protocol import fields_info

    effect = o.levers[0] if o.levers else None
    if effect is None:
        if not o.verdicts:
            return None
        return Figure("Measured values against their tolerances (see 'Conformity decisions').",
                      figs.acceptance_figure(o.verdicts))
    spec, table = o.sweeps[effect.sweep]
    docs = {f["name"]: f["doc"] for f in fields_info(get(o.spec.name).Setup)}
    ok = table[table["error"].astype(str) == ""] if "error" in table else table
    units = {m.name: m.unit for m in o.results[o.recommended].measurands}
    label = field_label(effect.field, docs.get(effect.field, ""))
    targets = {n: t for n, t in o.targets.items() if n in o.key}
    what = sorted({t[1] for t in targets.values()})
    return Figure(
        f"Standard uncertainty against {label} ({int(ok['trials'].max())} Monte Carlo trials "
        "per set-up; bars: Monte Carlo error of u); the star is the study's set-up"
        + (f", the dashed line the {' or '.join(what)}" if what else "")
        + "; u = 0 (an estimator constant over every trial, below its resolution) is not "
        "drawn. Other levers and all measurands: appendix.",
        figs.lever_figure(ok, effect.field, o.key[:4], units, estimator=effect.estimator,
                          recommended=o.recommended, base=effect.base_value, targets=targets,
                          xlabel=label))


# ----------------------------------------------------------------------- findings
def _source_words(name: str) -> str:
    """An error source's name as the start of a sentence: ``axial_motion`` -> Axial motion."""
    words = name.replace("_", " ")
    return words[:1].upper() + words[1:]


def _findings(o) -> list[str]:
    """What the simulation shows, in sentences an engineer can act on."""
    from mtplan.models import get
    from mtplan.models.protocol import fields_info

    docs = {f["name"]: f["doc"] for f in fields_info(get(o.spec.name).Setup)}
    notes = []
    significant = [e for e in o.levers if e.significant and e.gain > 1.05]
    for e in significant[:2]:
        label = field_label(e.field, docs.get(e.field, "")).split(" [")[0]
        u = unit(e.unit)
        if e.u_base == e.u_base:  # the study's value was swept
            notes.append(f"Lever: {label} {_value(e.best_value)} instead of "
                         f"{_value(e.base_value)} lowers u({e.measurand}) from "
                         f"{fmt_u(e.u_base)} to {fmt_u(e.u_best)} {u} ({e.gain:.1f} times); the "
                         f"test takes {duration_text(e.duration_best_s)} instead of "
                         f"{duration_text(e.duration_base_s)}.")
        else:
            notes.append(f"Lever: {label} {_value(e.best_value)} gives u({e.measurand}) = "
                         f"{fmt_u(e.u_best)} {u}, {e.gain:.1f} times less than "
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
    changed = ", ".join(field_value(f, best["setup"][f]) for f in o.spec.plan.get("vary", {})
                        if f in best["setup"])
    targets = ", ".join(f"u({n}) ≤ {t:g}" for n, t in plan.targets.items())
    return [f"Plan: {changed} meets the targets ({targets}, k = {plan.k:g}) in "
            f"{duration_text(best['duration_s'])} of machine time (confirmed by Monte "
            "Carlo; appendix)."]


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
