"""The test report (certificate) and the test plan as document models.

:func:`build_report` is what the customer signs after the test: the ISO/IEC 17025 7.8.2.1
items on its cover, the overall result and the actions on the first page after it, the
as-found results of each toleranced measurand (achieved U beside the plan's prediction),
the test conditions and instruments, the deviations from the plan, a glossary and an end
mark. :func:`build_plan` is what both parties sign before it: per test the set-up,
instruments, estimator, predicted U, TUR, duration, identifiability and the decision rule
in ILAC-G8 wording with its risks, then the planning study (sweeps, estimators, levers)
and its appendices. Formatting only: the numbers come from the study and the plan.
"""

from __future__ import annotations

import dataclasses
import datetime
import math

from mtplan.reports.labels import duration_text, fmt, fmt_u, prior_text, tolerance_text, unit
from mtplan.reports.model import Document, Figure, Section, Table
from mtplan.reports.wording import (
    GLOSSARY,
    customer_words,
    measurand_name,
    method_citation,
    population_text,
    probability_text,
    rules_text,
    value_warnings,
    verdict_short,
)

__all__ = ["build_report", "build_plan", "overall_result", "final_verdicts", "measured_frame",
           "fit_summary",
           "RESULTS_RELATE", "END_MARK"]

RESULTS_RELATE = ("The results relate only to the item tested, in the condition and under "
                  "the test conditions stated. This report shall not be reproduced except in "
                  "full without the written approval of the laboratory.")
END_MARK = "End of report"
WATERMARK = "SIMULATED READINGS - NOT A MEASUREMENT"


# ----------------------------------------------------------------------- shared pieces
def _item(header) -> str:
    parts = [header.get(k) for k in ("machine_maker", "machine_type")]
    text = ", ".join(p for p in parts if p) or "not stated"
    if header.get("machine_serial"):
        text += f"; serial number {header['machine_serial']}"
    return text


def _lab(study) -> str:
    lab = study.laboratory
    return lab.get("name", "not stated in the study")


def _methods(result) -> list:
    """(test, method source, standards) rows: each source method cited once."""
    rows = []
    for o in result.outcomes:
        applied = list(o.spec.standards) + ["JCGM 101:2008"]
        if any(v.zone for v in o.verdicts) and not any(a.startswith("ISO 1101")
                                                       for a in applied):
            applied.append("ISO 1101:2017")  # a position tolerance as a diameter zone
        if o.verdicts:
            applied += ["ISO 14253-1:2017", "JCGM 106:2012", "ILAC-G8:09/2019"]
        rows.append([o.spec.label, method_citation(o.spec.name),
                     ", ".join(a.replace(" ", "\u00a0") for a in applied)])
    return rows


def _certificate_text(inst) -> str:
    """The certificate as what it is: a calibration or a verification, accredited or not."""
    what = inst.get("kind", "calibration")
    accredited = inst.get("accredited")
    how = ("accredited" if accredited else "not accredited" if accredited is False
           else "accreditation not stated")
    return f"{what} {inst['certificate']} ({how})"


def _instruments(study, procedure: str | None = None) -> list:
    from mtplan.plans.agreement import instrument_findings

    status = instrument_findings(study)[0]
    state = {"valid": "valid", "expired": "EXPIRED", "no due date": "MISSING",
             "not checked": "not checked (no test date)"}
    rows = []
    for inst, st in zip(study.instruments, status, strict=True):
        if procedure is not None and inst["used_in"] and procedure not in inst["used_in"]:
            continue
        shown = state[st["state"]] + ("; customer agreed" if st["agreed"] and
                                      st["state"] != "valid" else "")
        rows.append([inst["name"], inst["serial"], _certificate_text(inst),
                     inst.get("calibration_due", "-"), shown,
                     f"{inst.get('traceability', 'not stated')} (as declared by "
                     f"{inst.get('declared_by', 'the certificate issuer')})"])
    return rows


def _instrument_table(study) -> Table | None:
    rows = _instruments(study)
    if not rows:
        return None
    date = study.header.get("date", "not stated")
    return Table(f"Instruments used, each certificate's due date against the date of the "
                 f"test ({date}); a verification (conformity to a specification) is not a "
                 "calibration.", ["instrument", "serial number", "certificate",
                                  "due", "on the test date", "traceability"], rows)


def _issue_date(study) -> str:
    return study.header.get("issue_date") or datetime.date.today().isoformat()


_EVALUATION = {"mc": "U of the readings by Monte Carlo",
               "posterior": "U of the readings from the Bayesian posterior"}


def _verdict_word(v) -> str:
    return verdict_short(v.verdict)


# ----------------------------------------------------------------------- overall result
def final_verdicts(result) -> list:
    """The verdicts the overall result rests on: a test's results as left where it was
    measured again after an adjustment (``[procedure.as_left]``), else as found."""
    out = []
    for o in result.outcomes:
        left = {v.measurand: v for v in getattr(o, "as_left_verdicts", [])}
        out += [left.get(v.measurand, v) for v in o.verdicts]
    return out


def overall_result(result) -> tuple[str, list, list]:
    """(result, deciding measurands, undecided measurands): "not accepted" when any
    toleranced measurand does not conform (those decide), else "no decision" when any has
    no verdict (those decide), else "accepted". Results as left replace those as found
    (:func:`final_verdicts`)."""
    from mtplan.plans.decisions import CONFORMS, DOES_NOT_CONFORM

    verdicts = final_verdicts(result)
    failed = [v for v in verdicts if v.verdict == DOES_NOT_CONFORM]
    open_ = [v for v in verdicts if v.verdict not in (CONFORMS, DOES_NOT_CONFORM)]
    if failed:
        return "not accepted", failed, open_
    if open_:
        return "no decision", open_, []
    return ("accepted" if verdicts else "no decision"), [], []


def _needed_u(v) -> float | None:
    """The predicted U that would decide a value inside the guard band: the distance of
    the measured value to the nearest tolerance limit, over the rule's w / U."""
    if v.measured is None or not (v.u and v.guard_band):
        return None
    limits = [x for x in (v.lower, v.upper) if x is not None]
    gap = min(abs(v.measured - x) for x in limits)
    return gap * (2 * v.u) / v.guard_band


def _lever_for(o, v, needed) -> str:
    """A swept set-up whose predicted U is below ``needed``, in words, or ""."""
    from mtplan.models import get
    from mtplan.models.protocol import fields_info
    from mtplan.reports.labels import field_label

    docs = {f["name"]: f["doc"] for f in fields_info(get(o.spec.name).Setup)}
    best = None
    for spec, table in o.sweeps:
        if isinstance(table, str) or len(spec["vary"]) != 1:
            continue
        f = next(iter(spec["vary"]))
        if f not in get(o.spec.name).levers:
            continue
        rows = table[(table["measurand"] == v.measurand) & (table["estimator"] == v.estimator)]
        rows = rows[(2 * rows["u"] <= needed) & (rows["u"] > 0)]
        for r in rows.itertuples():
            cand = (float(getattr(r, "duration_s", math.nan)), f, getattr(r, f), 2 * r.u)
            if best is None or cand[0] < best[0]:
                best = cand
    if best is None:
        return ""
    label = field_label(best[1], docs.get(best[1], "")).split(" [")[0]
    value = f"{best[2]:g}" if isinstance(best[2], float) else str(best[2])
    return (f"set {label} to {value} (predicted U {fmt_u(best[3])} {unit(v.unit)} < "
            f"{fmt_u(needed)} {unit(v.unit)}, agreed in a revised plan) and re-test")


def _actions(result, failed, open_) -> list:
    by_proc = {o.spec.name: (k, o) for k, o in enumerate(result.outcomes, start=1)}
    out = []
    for v in failed:
        k, o = by_proc[v.procedure]
        u = unit(v.unit)
        res = v.measured_u
        target = 0.0 if v.lower is not None and v.upper is not None and v.lower < 0 < v.upper \
            else ((v.lower or 0) + (v.upper or 0)) / 2
        out.append(f"Adjust the {measurand_name(v.description, v.measurand)[:1].lower()}"
                   f"{measurand_name(v.description, v.measurand)[1:]}: measured "
                   f"{fmt(v.measured, res)} {u} against the tolerance "
                   f"{tolerance_text(v.lower, v.upper, v.unit)}; correct it by about "
                   f"{fmt(target - v.measured, res)} {u} (for a machine axis: its location in "
                   "the control's kinematic model or the mechanical alignment), then re-test "
                   f"test {k} ({o.spec.label}) and report the result as left.")
    for v in open_:
        k, o = by_proc[v.procedure]
        name = measurand_name(v.description, v.measurand)
        if v.verdict.startswith("no decision: the readings"):
            out.append(f"{name}: the readings do not fit the model; find the cause (set-up, "
                       f"instrument, machine state) and repeat test {k} ({o.spec.label}).")
            continue
        needed = _needed_u(v)
        if needed is None:
            out.append(f"{name}: {v.verdict}" + (f" ({v.reason})" if v.reason else "")
                       + f"; repeat test {k} ({o.spec.label}).")
            continue
        lever = _lever_for(o, v, needed)
        reps = math.ceil((2 * v.u / needed) ** 2) if needed > 0 else None
        how = lever or (f"no swept set-up reaches it: repeat the test {reps} times and "
                        "average (U falls with the square root of the repeats), agreed in a "
                        "revised plan" if reps else "no set-up can decide it")
        out.append(f"{name}: no decision (inside the guard band). A decision needs a "
                   f"predicted U below {fmt_u(needed)} {unit(v.unit)} (now "
                   f"{fmt_u(2 * v.u)}): {how}.")
    return out


def _overall_section(result) -> Section:
    outcome, deciding, undecided = overall_result(result)
    codes = ", ".join(v.measurand for v in deciding)
    head = f"Overall result: {outcome}" + (f": {codes}" if codes else "") + "."
    blocks = [head]
    if undecided:
        blocks.append("Also without a decision: " + ", ".join(
            f"{v.measurand} ({v.verdict})" for v in undecided) + ".")
    final = final_verdicts(result)
    n_ok = sum(v.verdict == "conforms" for v in final)
    blocks.append(f"{n_ok} of {len(final)} toleranced measurands conform to the rules of the "
                  "test plan.")
    left = [f"test {k} ({o.spec.label}" + (f"; adjusted: {o.spec.as_left['adjustment']}"
                                            if o.spec.as_left.get("adjustment") else "") + ")"
            for k, o in enumerate(result.outcomes, start=1) if o.as_left_verdicts]
    if left:
        blocks.append("The overall result uses the results as left (measured again after "
                      "an adjustment) for " + "; ".join(left) + ", and the results as found "
                      "for the other tests.")
    actions = _actions(result, deciding if outcome == "not accepted" else [],
                       undecided if outcome == "not accepted" else deciding)
    if actions:
        blocks += ["Actions required:", actions]
    else:
        blocks.append("No action required.")
    return Section("Overall result and actions", blocks=blocks, anchor="overall")


# ----------------------------------------------------------------------- results
def _interval(v) -> str:
    res = v.measured_u
    return ("-" if v.measured_low is None else
            f"[{fmt(v.measured_low, res)}, {fmt(v.measured_high, res)}]")


def _result_rows(k, o) -> list:
    rows = []
    for v in o.verdicts:
        res = v.measured_u
        measured = "-" if v.measured is None else fmt(v.measured, res)
        achieved = "-" if res is None else fmt_u(2 * res)
        rows.append([str(k), measurand_name(v.description, v.measurand),
                     tolerance_text(v.lower, v.upper, v.unit, v.zone), measured,
                     f"{achieved} ({fmt_u(2 * v.u)})", _interval(v),
                     probability_text(v.p_conform), _verdict_word(v)])
    return rows


def _value_text(v) -> str:
    """"12.9 ± 3.1" (value ± U achieved) or "-"."""
    if v is None or v.measured is None:
        return "-"
    if v.measured_u is None:
        return fmt(v.measured)
    return f"{fmt(v.measured, v.measured_u)} ± {fmt_u(2 * v.measured_u)}"


def _as_left_rows(k, o) -> list:
    """As found and as left side by side, one row per toleranced measurand of a test that
    was measured again after an adjustment."""
    found = {v.measurand: v for v in o.verdicts}
    rows = []
    for v in o.as_left_verdicts:
        f = found.get(v.measurand)
        rows.append([str(k), measurand_name(v.description, v.measurand),
                     tolerance_text(v.lower, v.upper, v.unit, v.zone), _value_text(f),
                     "-" if f is None else _verdict_word(f), _value_text(v), _interval(v),
                     _verdict_word(v)])
    return rows


def _probability_lines(verdicts, when="") -> list:
    out = []
    for v in verdicts:
        if v.p_conform is None:
            if v.reason:
                out.append(f"{v.measurand}{when}: {v.verdict}: {v.reason}.")
            continue
        alone = ("from the measurement's own samples" if v.p_conform_samples is not None
                 else "from the measurement alone")
        line = f"{v.measurand}{when}: {probability_text(v.p_conform)} {alone}"
        if v.p_conform_population is not None and v.prior is not None:
            line += (f"; {probability_text(v.p_conform_population)} with the population "
                     f"{population_text(prior_text(v.prior, v.unit), v.population_source)}")
        if v.reason:
            line += f". Note: {v.reason}"
        out.append(line + ".")
    return out


def fit_summary(fit) -> dict:
    """The fit check of one evaluation as the documents show it: ``chi2``, ``dof``, ``p``,
    ``worst`` (the worst readings in words), ``ok`` (True, False or None: not made) and
    ``outcome`` in words. Read defensively: a check may lack any of these."""
    if fit is None:
        return {"chi2": None, "dof": None, "p": None, "worst": "", "ok": None,
                "outcome": "not made: no fit check for this evaluation"}
    p = getattr(fit, "p_value", getattr(fit, "p", None))
    ok = getattr(fit, "ok", None)
    worst = fit.worst_text() if hasattr(fit, "worst_text") and getattr(fit, "worst", None) \
        else ""
    alpha = getattr(fit, "alpha", 0.01)
    outcome = ("the readings fit the model (p >= {a:g})" if ok else
               "the readings do NOT fit the model (p < {a:g}): no decision" if ok is False else
               "not made: " + str(getattr(fit, "reason", "") or "no reason given"))
    return {"chi2": getattr(fit, "chi2", None), "dof": getattr(fit, "dof", None), "p": p,
            "worst": worst, "ok": ok, "outcome": outcome.format(a=alpha)}


def _fit_rows(result) -> list:
    rows = []
    for k, o in enumerate(result.outcomes, start=1):
        for m, state in ((o.measured, ""), (getattr(o, "as_left", None), " as left")):
            if m is None:
                continue
            f = fit_summary(getattr(m, "fit", None))
            rows.append([f"{k}{state}", "-" if f["chi2"] is None else f"{f['chi2']:.1f}",
                         "-" if f["dof"] is None else str(f["dof"]),
                         "-" if f["p"] is None else f"{f['p']:.2g}", f["worst"] or "-",
                         f["outcome"]])
    return rows


def _results_section(result) -> Section:
    from mtplan.reports import figures as figs

    adjusted = [k for k, o in enumerate(result.outcomes, start=1) if o.as_left_verdicts]
    sec = Section("Results as found" + (" and as left" if adjusted else ""), anchor="results")
    sec.blocks.append("Each toleranced measurand as found (before any adjustment), decided "
                      "with the rule and the guard band of the test plan. U achieved: the "
                      "measurement's own expanded uncertainty (k = 2); in parentheses the U "
                      "the plan predicted. "
                      + ("As left: no adjustment was made during this test; the results as "
                         "found are the results as left." if not adjusted else
                         "As left: test " + ", ".join(map(str, adjusted)) + " was measured "
                         "again after an adjustment and decided by the same rules (below); "
                         "the other tests were not adjusted."))
    rows, tests = [], []
    for k, o in enumerate(result.outcomes, start=1):
        if o.verdicts:
            rows += _result_rows(k, o)
            how = _EVALUATION.get(getattr(o.measured, "uncertainty", None), "no readings")
            tests.append(f"{k}: {o.spec.label} ({o.verdicts[0].estimator} estimator; {how})")
    if rows:
        sec.blocks.append(Table("Results as found. Tests: " + "; ".join(tests) + ".",
                                ["test", "measurand", "tolerance", "measured",
                                 "U achieved (predicted)", "95 % interval",
                                 "probability of conformity", "verdict"], rows,
                                grow=1, size=7.0))
        sec.blocks += rules_text(result.verdicts)
        lines = _probability_lines(result.verdicts)
        if lines:
            sec.blocks += ["Probability of conformity (JCGM 106 7.4):", lines]
    if adjusted:
        left = [row for k, o in enumerate(result.outcomes, start=1) if o.as_left_verdicts
                for row in _as_left_rows(k, o)]
        sec.blocks.append(Table("Results as found and as left (after the adjustment), each "
                                "decided by the rules of the test plan; value ± U achieved "
                                "(k = 2).", ["test", "measurand", "tolerance", "as found",
                                             "verdict as found", "as left",
                                             "95 % interval as left",
                                             "verdict as left"], left, grow=1, size=7.0))
        lines = _probability_lines([v for o in result.outcomes for v in o.as_left_verdicts],
                                   " as left")
        if lines:
            sec.blocks += ["Probability of conformity as left:", lines]
    fits = _fit_rows(result)
    if fits:
        sec.blocks.append(Table("Fit check of each test's readings (chi-square of the "
                                "readings against the model and its error budget): the "
                                "achieved U holds only where they fit; a test whose readings "
                                "do not fit gets no decision. Worst readings: row and column "
                                "of the readings file, z the standardised residual.",
                                ["test", "chi-square", "dof", "p", "worst readings",
                                 "outcome"], fits, grow=4, size=7.0))
    untoleranced = sum(len(o.measured.measurands) for o in result.outcomes
                       if o.measured is not None) - sum(
        len(o.verdicts) for o in result.outcomes if o.measured is not None)
    if untoleranced > 0:
        what = "quantity" if untoleranced == 1 else f"{untoleranced} quantities"
        sec.blocks.append(f"The measured {what} without a tolerance: with U in the appendix "
                          "and in results/measured.csv.")
    if result.verdicts:
        sec.blocks.append(Figure("Measured values as found (dot, 95 % interval) against the "
                                 "tolerance (black lines), the guard bands (amber: no "
                                 "decision), the zones of conformity (green) and "
                                 "non-conformity (red).",
                                 figs.acceptance_figure(result.verdicts)))
    return sec


def _conditions_section(result) -> Section:
    from mtplan.plans.study import CONDITION_KEYS

    study = result.study
    rows = []
    for key, (label, kind) in CONDITION_KEYS.items():
        value = study.conditions.get(key)
        if value is None:
            shown = "not recorded"
        elif kind == "temperature":
            shown = f"{value:.1f} °C"
        elif kind == "bool":
            shown = "on" if value else "off"
        else:
            shown = str(value)
        rows.append([label, shown])
    blocks = [Table("Test conditions (ISO 230-1 6.1: temperatures, warm-up, compensation).",
                    ["condition", "value"], rows)]
    table = _instrument_table(study)
    if table is not None:
        blocks.append(table)
        blocks.append("Traceability: as declared by the party named in each row, on the "
                      "certificate cited; the laboratory has checked each certificate's due "
                      "date against the date of the test, not the declared chain itself. An "
                      "instrument not valid on the test date is a deviation (below).")
    else:
        blocks.append("No instruments are named in the study: the traceability of these "
                      "results cannot be stated.")
    return Section("Test conditions and instruments", blocks=blocks, anchor="conditions")


def _deviations_section(deviations) -> Section:
    blocks = ["Deviations from the test plan, additions and exclusions:"]
    blocks.append([customer_words(d) for d in deviations] if deviations else ["none"])
    return Section("Deviations from the plan", blocks=blocks, anchor="deviations")


def _glossary_section() -> Section:
    return Section("Glossary", anchor="glossary", blocks=[Table("Terms used in this document.",
                                                                ["term", "meaning"],
                                                                GLOSSARY)])


def measured_frame(result):
    """Every measured measurand of every test with its U, as found and (where a test was
    measured again after an adjustment) as left: ``results/measured.csv``."""
    import pandas as pd

    rows = []
    for o, m, state in [(o, m, state) for o in result.outcomes
                        for m, state in ((o.measured, "as found"), (o.as_left, "as left"))]:
        if m is None:
            continue
        det = getattr(m, "determinable", None)
        fit = fit_summary(getattr(m, "fit", None))
        for j, q in enumerate(m.measurands):
            ok = det is None or bool(det[j])
            u = float(m.std[j]) if ok else math.nan
            rows.append({"procedure": o.spec.name, "test": o.spec.label, "state": state,
                         "measurand": q.name,
                         "description": q.description, "unit": q.unit,
                         "value": float(m.value[j]) if ok else math.nan, "u": u, "k": 2.0,
                         "U": 2 * u, "low": float(m.low[j]) if ok else math.nan,
                         "high": float(m.high[j]) if ok else math.nan,
                         "estimator": m.estimator, "uncertainty": m.uncertainty,
                         "determinable": ok, "fit_chi2": fit["chi2"], "fit_dof": fit["dof"],
                         "fit_p": fit["p"], "fit_ok": fit["ok"], "fit_worst": fit["worst"]})
    return pd.DataFrame(rows, columns=["procedure", "test", "state", "measurand", "description",
                                       "unit", "value", "u", "k", "U", "low", "high",
                                       "estimator", "uncertainty", "determinable", "fit_chi2",
                                       "fit_dof", "fit_p", "fit_ok", "fit_worst"])


def _measured_appendix(k, o) -> Section:
    from mtplan.reports.appendix import measured_blocks

    m = o.measured
    det = getattr(m, "determinable", None)
    rows, items = [], []
    for j, q in enumerate(m.measurands):
        ok = det is None or bool(det[j])
        u = float(m.std[j]) if ok else None
        if ok:
            items.append((q.name, float(m.value[j]), u, float(m.low[j]), float(m.high[j])))
        rows.append([measurand_name(q.description, q.name),
                     unit(q.unit),
                     fmt(m.value[j], u) if ok else "n/d", fmt_u(2 * u) if ok else "n/d",
                     f"[{fmt(m.low[j], u)}, {fmt(m.high[j], u)}]" if ok else "-"])
    sec = Section(f"A{k}. {o.spec.label}: every measured quantity", anchor=f"m{k}",
                  appendix=True)
    warnings, flagged = value_warnings(items)
    for row, q in zip(rows, m.measurands, strict=True):
        row[0] += " *" if q.name in flagged else ""
    sec.blocks.append(Table(f"Every measured quantity of test {k} ({m.estimator} estimator)"
                            + ("; *: read with care (below)." if warnings else "."),
                            ["measurand", "unit", "measured", "U (k = 2)", "95 % interval"],
                            rows, grow=0))
    if warnings:
        sec.blocks += ["* Read these values with care:", warnings]
    sec.blocks += measured_blocks(m, warn=False)
    return sec


def _cover_meta(result, plan, kind) -> dict:
    study = result.study
    h = study.header
    lab = study.laboratory
    doc_no = h.get("document", "not stated")
    meta = {}
    if kind == "report":
        meta["title"] = "Test report (certificate of the acceptance test)"
        meta["report number"] = f"{doc_no}" + (f", revision {h['revision']}"
                                               if h.get("revision") else "")
        meta["test plan"] = f"{plan['document']}, issued {plan['issued']}"
        meta["plan fingerprint (SHA-256)"] = plan["fingerprint"]
    else:
        meta["title"] = "Test plan (to be agreed before the test)"
        meta["plan number"] = plan["document"] + (f", revision {plan['revision']}"
                                                  if plan.get("revision") else "")
        meta["plan fingerprint (SHA-256)"] = plan["fingerprint"]
    meta["laboratory"] = _lab(study)
    meta["laboratory address"] = lab.get("address", "not stated in the study")
    if lab.get("accreditation"):
        meta["accreditation"] = lab["accreditation"]
    meta["place of the test"] = h.get("location", "not stated")
    meta["customer"] = h.get("customer", "not stated")
    if h.get("customer_address"):
        meta["customer address"] = h["customer_address"]
    meta["item tested"] = _item(h)
    meta["condition of the item"] = h.get("item_condition", "not stated")
    meta["date of the test"] = h.get("date", "not stated")
    if kind == "report":
        meta["date of issue"] = _issue_date(study)
        meta["authorised by"] = h.get("approved_by") or "not yet authorised (see sign-off)"
    else:
        meta["date of issue"] = plan["issued"]
    return meta


def _document(result, plan, kind, sections, csv) -> Document:
    study = result.study
    meta = _cover_meta(result, plan, kind)
    title = meta.pop("title")
    number = (meta.get("report number") if kind == "report" else meta.get("plan number"))
    signoff = ([("prepared", study.header.get("prepared_by", "")),
                ("checked", study.header.get("checked_by", "")),
                ("authorised", study.header.get("approved_by", ""))] if kind == "report" else
               [("agreed for the laboratory", study.header.get("approved_by", "")),
                ("agreed for the customer", "")])
    doc = Document(title=title, subtitle=study.title, meta=meta,
                   provenance=result.provenance, sections=sections, csv=csv,
                   signoff=signoff, standards=[])
    doc.methods = _methods(result)
    doc.identification = f"{number} - {title.split(' (')[0]}"
    doc.watermark = WATERMARK if study.simulated else ""
    doc.end_mark = END_MARK if kind == "report" else "End of test plan"
    doc.flow = kind == "report"
    doc.statement = RESULTS_RELATE if kind == "report" else (
        "The decision rules, guard bands and risks below are agreed before the test; the test "
        "report will apply exactly these rules. The fingerprint covers the number, revision, "
        "issue date, parties, conditions and rules: the report cites it in full.")
    return doc


# ----------------------------------------------------------------------- the report
def build_report(result, plan, deviations=()) -> Document:
    """The test report of a computed study decided by :func:`~mtplan.plans.agreement.
    apply_plan` with ``plan``."""
    from mtplan.reports.appendix import provenance_section
    from mtplan.reports.document import covariance_frames, verdict_frames

    sections = [_overall_section(result), _results_section(result),
                _conditions_section(result), _deviations_section(deviations),
                _glossary_section()]
    for k, o in enumerate(result.outcomes, start=1):
        if o.measured is not None:
            sections.append(_measured_appendix(k, o))
    sections.append(provenance_section(result.provenance))
    csv = verdict_frames(result)
    csv["measured"] = measured_frame(result)
    csv.update(covariance_frames(result))
    return _document(result, plan, "report", sections, csv)


# ----------------------------------------------------------------------- the plan
def _plan_rows(o, plan) -> list:
    rules = {(r["procedure"], r["test"], r["measurand"]): r for r in plan["rules"]}
    index = {m.name: i for i, m in enumerate(o.results[o.recommended].measurands)}
    rows = []
    for v in o.verdicts:
        r = rules[(v.procedure, v.label, v.measurand)]
        u = unit(v.unit)
        w = "-" if r["guard_band"] is None else fmt(r["guard_band"], r["u_planned"] / 5)
        rows.append([measurand_name(v.description, v.measurand), u,
                     tolerance_text(v.lower, v.upper, zone=v.zone),
                     "-" if r["u_planned"] is None else fmt_u(2 * r["u_planned"]),
                     "-" if r["tur"] is None else f"{r['tur']:.1f}", w,
                     _pct(r["pfa"]), _pct(r["pfr"])])
    for name in o.key:
        if name in {v.measurand for v in o.verdicts} or name not in index:
            continue
        m = o.results[o.recommended].measurands[index[name]]
        u2 = 2 * float(o.results[o.recommended].mc.std[index[name]])
        rows.append([measurand_name(m.description, name), unit(m.unit), "-", fmt_u(u2), "-",
                     "-", "-", "-"])
    return rows


def _pct(p) -> str:
    from mtplan.reports.labels import percent

    return "-" if p is None else percent(p)


def _plan_test(k, o, plan, study) -> Section:
    from mtplan.reports.document import setup_sentence

    blocks = [f"Set-up: {setup_sentence(o)}. Estimator: {o.recommended}. Duration (machine "
              f"time): {duration_text(o.duration_s)}. Method: {method_citation(o.spec.name)}; "
              f"standards: {', '.join(o.spec.standards) or 'none named'}."]
    inst = _instruments(study, o.spec.name)
    blocks.append("Instruments: " + ("; ".join(f"{r[0]} (serial {r[1]}, certificate {r[2]})"
                                               for r in inst) if inst else
                                     "none named in the study") + ".")
    ident = o.identifiability
    if ident is not None:
        full = ident.rank >= ident.n_params
        blocks.append(f"Identifiability: the readings determine {ident.rank} of "
                      f"{ident.n_params} parameters"
                      + (" (full rank)" if full else ": some combinations cannot be "
                         "separated") + f"; condition number {ident.condition_number:.3g}.")
    blocks.append(Table(f"Test {k}: predicted U (k = 2) and the agreed decision rules.",
                        ["measurand", "unit", "tolerance", "U predicted", "TUR",
                         "guard band w", "PFA", "PFR"], _plan_rows(o, plan), grow=0))
    blocks += rules_text(o.verdicts)
    populations = [f"{v.measurand} "
                   f"{population_text(prior_text(v.prior, v.unit), v.population_source)}"
                   for v in o.verdicts if v.prior is not None]
    if populations:
        blocks.append("Population of items the risks (PFA, PFR) assume: "
                      + "; ".join(populations) + ".")
    return Section(f"{k}. {o.spec.label}", level=2, blocks=blocks)


def plan_parts(k, o) -> tuple:
    """What the test plan draws from test ``k`` alone (its figures): (its body section,
    (its appendix section, the appendix's CSV frames)). Each test's parts can be drawn in
    another process (:func:`build_plan`'s ``parts``), each part in its own
    (:data:`PLAN_PARTS`)."""
    return plan_body(k, o), plan_appendix(k, o)


def plan_body(k, o):
    """Test ``k``'s section of the plan's body (:func:`plan_parts`)."""
    from mtplan.reports.document import test_section

    return test_section(k, dataclasses.replace(o, measured=None, verdicts=[]))


def plan_appendix(k, o) -> tuple:
    """Test ``k``'s appendix section of the plan and its CSV frames (:func:`plan_parts`)."""
    from mtplan.reports import appendix

    return appendix.procedure_section(k, o, measured=False)


#: :func:`plan_parts` as two functions, each drawn where it runs (``run_study``'s ``then``)
PLAN_PARTS = (plan_body, plan_appendix)


def build_plan(result, plan, parts=None) -> Document:
    """The test plan of a computed study (its readings, if any, are not used). ``parts``:
    :func:`plan_parts` of each test, in test order, where they were drawn already."""
    from mtplan.reports import appendix
    from mtplan.reports.document import methods_section

    if parts is None:
        parts = [plan_parts(k, o) for k, o in enumerate(result.outcomes, start=1)]
    study = result.study
    rules = Section("Tests and decision rules", anchor="rules", blocks=[
        "What each test measures, how, with which instruments and how long, the uncertainty "
        "it is predicted to reach and the decision rule both parties agree before measuring "
        f"(coverage {study.coverage:.0%}, k = 2)."])
    rules.blocks += [_plan_test(k, o, plan, study)
                     for k, o in enumerate(result.outcomes, start=1)]
    sections = [rules, methods_section(result), _glossary_section()]
    sections += [body for body, _ in parts]
    csv = {}
    for _, (sec, frames) in parts:
        sections.append(sec)
        csv.update(frames)
    sections.append(appendix.provenance_section(result.provenance, document="plan"))
    return _document(result, plan, "plan", sections, csv)
