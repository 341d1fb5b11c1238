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

from mtplan.plans.decisions import K
from mtplan.uncertainty.coverage import ASSUMED, coverage_text
from mtplan.reports.labels import (
    duration_text,
    field_value,
    fmt,
    fmt_u,
    prior_text,
    tolerance_text,
    unit,
)
from mtplan.reports import reliability
from mtplan.reports.model import Document, Figure, Section, Table
from mtplan.reports.results import ASYMMETRIC_NOTE
from mtplan.reports.results import asymmetric_mark as _asymmetric_mark
from mtplan.reports.wording import (
    GLOSSARY,
    customer_words,
    measurand_name,
    method_citation,
    population_text,
    p_text,
    probability_text,
    rules_text,
    value_warnings,
    verdict_short,
)

__all__ = ["build_report", "build_plan", "overall_result", "final_verdicts", "measured_frame",
           "fit_summary", "machines", "machine_results", "result_box",
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


def _methods(result, estimators: bool = True) -> list:
    from mtplan.reports.accreditation import lab_procedure_text

    """(test, method source and (``estimators``) the estimator that evaluates it,
    standards) rows: each source method cited once, each estimator described where it is
    first named (the plan names and describes them in its agreement, after its cover)."""
    from mtplan.reports.accreditation import lab_procedure_text

    rows = []
    for o in result.outcomes:
        applied = list(o.spec.standards) + ["JCGM 101:2008"]
        if any(v.zone for v in o.verdicts) and not any(a.startswith("ISO 1101")
                                                       for a in applied):
            applied.append("ISO 1101:2017")  # a position tolerance as a diameter zone
        if o.verdicts:
            applied += ["ISO 14253-1:2017", "JCGM 106:2012", "ILAC-G8:09/2019"]
        how = (f"; evaluated with the {agreed_estimator(o)} estimator: "
               f"{_estimator_words(o).rstrip('.')}" if estimators else "")
        how += "; " + lab_procedure_text(result.study.laboratory, o.spec.name)
        rows.append([o.spec.label, method_citation(o.spec.procedure) + how,
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


def _combine(verdicts) -> tuple[str, list, list]:
    """(result, deciding, undecided) of some verdicts by the overall acceptance rule
    (:data:`~mtplan.reports.wording.OVERALL_RULE`)."""
    from mtplan.plans.decisions import FAIL, PASS

    failed = [v for v in verdicts if v.verdict == FAIL]
    open_ = [v for v in verdicts if v.verdict not in (PASS, FAIL)]
    if failed:
        return "not accepted", failed, open_
    if open_:
        return "no decision", open_, []
    return ("accepted" if verdicts else "no decision"), [], []


def overall_result(result) -> tuple[str, list, list]:
    """(result, deciding measurands, undecided measurands) over every machine: "not
    accepted" when any toleranced measurand fails (those decide), else "no decision" when
    any has no pass (those decide), else "accepted". Results as left replace those as found
    (:func:`final_verdicts`)."""
    return _combine(final_verdicts(result))


def machines(result) -> list:
    """(machine, test numbers) in the order of the tests: the serial each test names
    (``machine`` of its procedure), else the header's ``machine_serial``."""
    default = result.study.header.get("machine_serial", "")
    out: dict = {}
    for k, o in enumerate(result.outcomes, start=1):
        serial = getattr(o.spec, "machine", "") or default
        out.setdefault(f"machine {serial}" if serial else "the machine tested", []).append(k)
    return list(out.items())


def machine_results(result) -> list:
    """(machine, test numbers, result, deciding, undecided) per machine, by the overall
    acceptance rule applied to the final verdicts of its tests."""
    final = final_verdicts(result)
    out = []
    for machine, tests in machines(result):
        labels = {result.outcomes[k - 1].spec.label for k in tests}
        names = {result.outcomes[k - 1].spec.name for k in tests}
        own = [v for v in final if v.label in labels and v.procedure in names]
        out.append((machine, tests, *_combine(own)))
    return out


def _tests_text(tests) -> str:
    return ("test " if len(tests) == 1 else "tests ") + ", ".join(map(str, tests))


def result_box(result) -> list:
    """The overall result per machine as the box on page 1 shows it."""
    lines = []
    for machine, tests, outcome, deciding, undecided in machine_results(result):
        why = ""
        if deciding or undecided:
            by = {}
            for v in deciding + undecided:
                by.setdefault(v.verdict, []).append(v.measurand)
            why = ": " + "; ".join(f"{verdict_short(w)} {', '.join(n)}" for w, n in by.items())
        lines.append(f"{machine[:1].upper()}{machine[1:]} ({_tests_text(tests)}): "
                     f"{outcome.upper()}{why}.")
    return lines


def _overall_section(result) -> Section:
    from mtplan.reports.wording import BURDEN_OF_PROOF, OVERALL_RULE

    outcome, deciding, undecided = overall_result(result)
    blocks = []
    for machine, tests, m_outcome, m_deciding, m_undecided in machine_results(result):
        codes = ", ".join(v.measurand for v in m_deciding)
        blocks.append(f"Overall result for {machine} ({_tests_text(tests)}): "
                      f"{m_outcome}" + (f": {codes}" if codes else "") + ".")
        if m_undecided:
            blocks.append("Also without a pass: " + ", ".join(
                f"{v.measurand} ({verdict_short(v.verdict)})" for v in m_undecided) + ".")
    final = final_verdicts(result)
    n_ok = sum(v.verdict == "pass" for v in final)
    blocks.append(f"{n_ok} of {len(final)} toleranced measurands pass by the rules of the "
                  f"test plan. {OVERALL_RULE} {BURDEN_OF_PROOF}")
    left = [f"test {k} ({o.spec.label}" + (f"; adjusted: {o.spec.as_left['adjustment']}"
                                            if o.spec.as_left.get("adjustment") else "") + ")"
            for k, o in enumerate(result.outcomes, start=1) if o.as_left_verdicts]
    if left:
        blocks.append("The overall result uses the results as left (measured again after "
                      "an adjustment) for " + "; ".join(left) + ", and the results as found "
                      "for the other tests.")
    from mtplan.reports.actions import actions as actions_for

    actions = actions_for(result, deciding if outcome == "not accepted" else [],
                          undecided if outcome == "not accepted" else deciding)
    author = (result.study.header.get("prepared_by") or _lab(result.study))
    if actions:
        blocks += [f"Opinions and interpretations (ISO/IEC 17025 7.8.7), by {author}, not "
                   "part of the results: the actions that would follow.", actions]
    else:
        blocks.append("No action required.")
    return Section("Overall result and actions", blocks=blocks, anchor="overall")


# ----------------------------------------------------------------------- results
def _U(v):
    """The printed U of a measured value (k = 2): values are rounded to its decimal."""
    return None if v.measured_u is None else 2 * v.measured_u


def _interval(v) -> str:
    res = _U(v)
    return ("-" if v.measured_low is None else
            f"[{fmt(v.measured_low, res)}, {fmt(v.measured_high, res)}]")


def _value_text(v) -> str:
    """"12.9 ± 3.1" (value ± U achieved) or "-"."""
    if v is None or v.measured is None:
        return "-"
    if v.measured_u is None:
        return fmt(v.measured)
    from mtplan.reports.results import covers_text

    return f"{fmt(v.measured, _U(v))} ± {fmt_u(_U(v))} ({covers_text(v)})"


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
        line = (f"{v.measurand}{when}: 95 % interval {_interval(v)} {unit(v.unit)}; "
                f"{probability_text(v.p_conform)} {alone}")
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
                "outcome": "not made: no fit check for this evaluation", "alpha": None}
    # the smallest alpha at which the check flags the readings (chi-square and largest |w|
    # together), so that "p below alpha: no decision" holds; the chi-square's own p before
    p = getattr(fit, "p_overall", None)
    p = getattr(fit, "p_value", getattr(fit, "p", None)) if p is None else p
    ok = getattr(fit, "ok", None)
    worst = fit.worst_text() if hasattr(fit, "worst_text") and getattr(fit, "worst", None) \
        else ""
    alpha = getattr(fit, "alpha", 0.01)
    outcome = ("fits" if ok else "does NOT fit: no decision" if ok is False else
               "not made: " + str(getattr(fit, "reason", "") or "no reason given"))
    return {"chi2": getattr(fit, "chi2", None), "dof": getattr(fit, "dof", None), "p": p,
            "worst": worst, "ok": ok, "outcome": outcome, "alpha": alpha}


def _fit_rows(result) -> list:
    rows = []
    for k, o in enumerate(result.outcomes, start=1):
        for m, state in ((o.measured, ""), (getattr(o, "as_left", None), " as left")):
            if m is None:
                continue
            f = fit_summary(getattr(m, "fit", None))
            rows.append([f"{k}{state}", "-" if f["chi2"] is None else f"{f['chi2']:.1f}",
                         "-" if f["dof"] is None else str(f["dof"]),
                         p_text(f["p"]), f["worst"] or "-",
                         f["outcome"]])
    return rows


def _results_section(result) -> Section:
    from mtplan.reports import figures as figs

    adjusted = [k for k, o in enumerate(result.outcomes, start=1) if o.as_left_verdicts]
    sec = Section("Results as found" + (" and as left" if adjusted else ""), anchor="results")
    sec.blocks.append("Each toleranced measurand as found (before any adjustment), decided "
                      "with the rule and the guard band of the test plan. U achieved: the "
                      "measurement's own expanded uncertainty (k = 2); in parentheses the U "
                      "the plan predicted. ±U covers: the fraction of each value's "
                      "distribution (Monte Carlo or posterior) within ± U, achieved and "
                      "(predicted). "
                      + ("As left: no adjustment was made during this test; the results as "
                         "found are the results as left." if not adjusted else
                         "As left: test " + ", ".join(map(str, adjusted)) + " was measured "
                         "again after an adjustment and decided by the same rules (below); "
                         "the other tests were not adjusted."))
    from mtplan.reports.results import (DEFAULT_TRUTH_NOTE, ZONES, rounding_sentence,
                                        verdict_table)

    tests = []
    for k, o in enumerate(result.outcomes, start=1):
        if o.verdicts:
            how = _EVALUATION.get(getattr(o.measured, "uncertainty", None), "no readings")
            tests.append(f"{k}: {o.spec.label} ({o.verdicts[0].estimator} estimator; {how})")
    if tests:
        table = verdict_table(result, tests)
        sec.blocks.append(table)
        if any("†" in row[5] for row in table.rows):
            sec.blocks.append(ASYMMETRIC_NOTE)
        if any("‡" in row[6] for row in table.rows):
            sec.blocks.append(DEFAULT_TRUTH_NOTE)
        if "after compensation (predicted)" in table.header:
            from mtplan.reports.along import RESIDUAL_NOTE

            sec.blocks.append(RESIDUAL_NOTE)
        from mtplan.reports.accreditation import uncertainty_statement

        sec.blocks += [ZONES, rounding_sentence(result),
                       uncertainty_statement(result.study.coverage)]
        sec.blocks += rules_text(result.verdicts)
        lines = _probability_lines(result.verdicts)
        if lines:
            sec.blocks += ["Probability of conformity (JCGM 106 7.4):", lines]
    if adjusted:
        left = [row for k, o in enumerate(result.outcomes, start=1) if o.as_left_verdicts
                for row in _as_left_rows(k, o)]
        sec.blocks.append(Table("Results as found and as left (after the adjustment), each "
                                "decided by the rules of the test plan; value ± U achieved "
                                "(k = 2) with the fraction of its distribution within ± U.", ["test", "measurand", "tolerance", "as found",
                                             "verdict as found", "as left",
                                             "95 % interval as left",
                                             "verdict as left"], left, grow=1, size=7.0))
        lines = _probability_lines([v for o in result.outcomes for v in o.as_left_verdicts],
                                   " as left")
        if lines:
            sec.blocks += ["Probability of conformity as left:", lines]
    from mtplan.evaluation.fitcheck import FIT_ALPHA

    fits = _fit_rows(result)
    if fits:
        sec.blocks.append(Table("Fit check of each test's readings (chi-square of the "
                                "readings against the model and its error budget): the "
                                "achieved U holds only where they fit; a test whose readings "
                                f"do not fit (p below {FIT_ALPHA:g}) gets no decision; p is "
                                "the smallest significance level at which the chi-square or "
                                "the largest standardised residual flags them. Worst "
                                "readings: "
                                "row and column of the readings file, z the standardised "
                                "residual.",
                                ["test", "chi-square", "dof", "p", "worst readings",
                                 "outcome"], fits, grow=4, size=7.0, whole=(3,)))
    unseen = reliability.report_section(result)
    if unseen is not None:
        sec.blocks.append(unseen)
    from mtplan.reports.document import datasheet_text
    from mtplan.reports.along import along_names

    sec.blocks += [f"Test {k} ({o.spec.label}): {datasheet_text(o)}"
                   for k, o in enumerate(result.outcomes, start=1) if datasheet_text(o)]
    untoleranced = sum(len(o.measured.measurands) - len(along_names(o.measured))
                       for o in result.outcomes if o.measured is not None) - sum(
        len(o.verdicts) for o in result.outcomes if o.measured is not None)
    if untoleranced > 0:
        what = "quantity" if untoleranced == 1 else f"{untoleranced} quantities"
        sec.blocks.append(f"The measured {what} without a tolerance: with U in the appendix "
                          "and in results/measured.csv.")
    if result.verdicts:
        sec.blocks.append(Figure("Measured values as found (dot, 95 % interval) against the "
                                 "tolerance (black lines): the acceptance zone (green: "
                                 "pass), the guard bands (amber: conditional pass inside "
                                 "the tolerance, conditional fail outside it) and the zones "
                                 "beyond the tolerance widened by w (red: fail).",
                                 figs.acceptance_figure(result.verdicts)))
    return sec


def _conditions_section(result, plan) -> Section:
    from mtplan.reports.conditions import condition_blocks

    study = result.study
    blocks = condition_blocks(study, plan.get("conditions", {}))
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
    blocks.append(SUPPLIED)
    return Section("Test conditions and instruments", blocks=blocks, anchor="conditions")


def _deviations_section(deviations) -> Section:
    blocks = ["Deviations from the test plan, additions and exclusions:"]
    blocks.append([customer_words(d) for d in deviations] if deviations else ["none"])
    return Section("Deviations from the plan", blocks=blocks, anchor="deviations")


def _words(blocks) -> str:
    """Every text of some blocks (paragraphs, lists, tables, sub-sections), lower case."""
    out = []
    for b in blocks:
        if isinstance(b, str):
            out.append(b)
        elif isinstance(b, list):
            out.append(_words(b))
        elif isinstance(b, Table):
            out += [b.caption, " ".join(map(str, b.header))]
            out += [" ".join(map(str, row)) for row in b.rows]
        elif isinstance(b, Section):
            out += [b.title, _words(b.blocks)]
        elif isinstance(b, Figure):
            out.append(b.caption)
    return " ".join(out).lower()


def _glossary_section(sections=None) -> Section:
    """The glossary of the terms that ``sections`` use (each term's words, split at "/"
    and ","), or of every term."""
    rows = GLOSSARY
    if sections is not None:
        import re

        text = _words(sections)
        rows = [row for row in GLOSSARY
                if any(re.search(rf"(?<![a-z]){re.escape(t.strip().lower())}(?![a-z])", text)
                       for t in re.split(r"[/,]", row[0]) if t.strip())]
    return Section("Glossary", anchor="glossary", blocks=[Table("Terms used in this document.",
                                                                ["term", "meaning"], rows,
                                                                keep=True)])


def measured_frame(result):
    """Every measured measurand of every test with its U, as found and (where a test was
    measured again after an adjustment) as left: ``results/measured.csv``; a point of an
    error along the travel also with its simultaneous band, a corrected measurand as found
    with the 95 % interval of its residual predicted after compensation."""
    import pandas as pd

    from mtplan.reports.along import residual_interval

    nan2 = (math.nan, math.nan)
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
                         "value": float(m.value[j]) if ok else math.nan, "u": u, "k": K,
                         "U": K * u, "U_coverage": float(m.U_coverage[j]) if ok else math.nan,
                         "U_coverage_se": _se(m, j) if ok else math.nan,
                         "U_coverage_from": m.U_from if ok else "",
                         "low": float(m.low[j]) if ok else math.nan,
                         "high": float(m.high[j]) if ok else math.nan,
                         "estimator": m.estimator, "uncertainty": m.uncertainty,
                         "determinable": ok, "fit_chi2": fit["chi2"], "fit_dof": fit["dof"],
                         "fit_p": fit["p"], "fit_p_text": p_text(fit["p"]),
                         "fit_ok": fit["ok"], "fit_worst": fit["worst"]})
            band = (getattr(m, "simultaneous", None) or {}).get(q.name, nan2)
            after = residual_interval(o, q.name) if state == "as found" else None
            rows[-1].update({"simultaneous_low": band[0], "simultaneous_high": band[1],
                             "after_compensation_low": (after or nan2)[0],
                             "after_compensation_high": (after or nan2)[1]})
    return pd.DataFrame(rows, columns=["procedure", "test", "state", "measurand", "description",
                                       "unit", "value", "u", "k", "U", "U_coverage",
                                       "U_coverage_se", "U_coverage_from", "low", "high",
                                       "estimator", "uncertainty", "determinable", "fit_chi2",
                                       "fit_dof", "fit_p", "fit_p_text", "fit_ok",
                                       "fit_worst", "simultaneous_low", "simultaneous_high",
                                       "after_compensation_low", "after_compensation_high"])


def _se(result, j) -> float:
    """The standard error of a measured result's coverage of ± U of measurand `j` (NaN
    where it has none: assumed)."""
    se = getattr(result, "U_coverage_se", None)
    return math.nan if se is None else float(se[j])


def _measured_appendix(k, o) -> Section:
    from mtplan.reports.appendix import measured_blocks

    from mtplan.reports.along import along_names

    m = o.measured
    det = getattr(m, "determinable", None)
    rows, items = [], []
    along = along_names(m)  # drawn in their own figure, and in results/measured.csv
    shown = [(j, q) for j, q in enumerate(m.measurands) if q.name not in along]
    for j, q in shown:
        ok = det is None or bool(det[j])
        u = float(m.std[j]) if ok else None
        if ok:
            items.append((q.name, float(m.value[j]), u, float(m.low[j]), float(m.high[j])))
        rows.append([measurand_name(q.description, q.name),
                     unit(q.unit),
                     (fmt(m.value[j], 2 * u) + _asymmetric_mark(m.value[j], 2 * u, m.low[j],
                                                                m.high[j])) if ok else "n/d",
                     fmt_u(2 * u) if ok else "n/d",
                     coverage_text(float(m.U_coverage[j]), assumed=m.U_from == ASSUMED,
                                   se=_se(m, j)) if ok else "-",
                     f"[{fmt(m.low[j], 2 * u)}, {fmt(m.high[j], 2 * u)}]" if ok else "-"])
    sec = Section(f"A{k}. {o.spec.label}: every measured quantity", anchor=f"m{k}",
                  appendix=True)
    warnings, flagged = value_warnings(items)
    for row, (_, q) in zip(rows, shown, strict=True):
        row[0] += " *" if q.name in flagged else ""
    sec.blocks.append(Table(f"Every measured quantity of test {k} ({m.estimator} estimator)"
                            + ("; *: read with care (below)." if warnings else "."),
                            ["measurand", "unit", "measured", "U (k = 2)", "±U covers",
                             "95 % interval"], rows, grow=0))
    if any("†" in row[2] for row in rows):
        sec.blocks.append(ASYMMETRIC_NOTE)
    if along:
        sec.blocks.append(f"The {len(along)} values of the errors along the travel: drawn "
                          "in the section 'Errors along the travel and after compensation "
                          "(predicted)', each with its U in results/measured.csv.")
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
    from mtplan.reports.accreditation import accreditation_text, signatory_text

    meta["accreditation"] = accreditation_text(lab)
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
        meta["signatory (name and function)"] = signatory_text(lab)
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
                ("agreed for the customer", ""), ("agreed for the machine builder", "")])
    doc = Document(title=title, subtitle=study.title, meta=meta,
                   provenance=result.provenance, sections=sections, csv=csv,
                   signoff=signoff, standards=[])
    doc.methods = _methods(result, estimators=kind == "report")
    if kind == "report":
        doc.box = result_box(result)
    else:  # what the parties should know before they sign
        from mtplan.reports.actions import signing_lines, signing_title

        doc.box = signing_lines(result)
        doc.box_title = signing_title()
    doc.identification = f"{number} - {title.split(' (')[0]}"
    # a plan uses no readings: no readings stamp, and its numbers come from the study alone
    doc.watermark = WATERMARK if study.simulated and kind == "report" else ""
    if kind != "report":
        doc.inputs = "the study file and the random seed (the plan uses no readings)"
    doc.end_mark = END_MARK if kind == "report" else "End of test plan"
    doc.flow = kind == "report"
    from mtplan.reports.accreditation import ilac_p8_text

    p8 = ilac_p8_text(study.laboratory)
    doc.statement = RESULTS_RELATE + (" " + p8 if p8 else "") if kind == "report" else (
        "The agreement (its first section) is what the parties sign before the test: the "
        "acceptance limits, decision rules, conditions and clauses; the test report will "
        "apply exactly these. The sections after it are the technical study behind them, a "
        "non-binding annex. The fingerprint covers the number, revision, issue date, parties, "
        "conditions, rules, the item, the tests with their machines and set-ups, the "
        "instruments and the method's version: the report cites it in full.")
    return doc


# ----------------------------------------------------------------------- the report
def build_report(result, plan, deviations=()) -> Document:
    """The test report of a computed study decided by :func:`~mtplan.plans.agreement.
    apply_plan` with ``plan``."""
    from mtplan.reports.appendix import provenance_section
    from mtplan.reports.document import covariance_frames, verdict_frames

    from mtplan.reports.along import along_section

    sections = [_overall_section(result), _results_section(result),
                _conditions_section(result, plan),
                _deviations_section(list(deviations) + exclusions(result))]
    along = along_section(result)
    if along is not None:
        sections.insert(2, along)
    for k, o in enumerate(result.outcomes, start=1):
        if o.measured is not None:
            sections.append(_measured_appendix(k, o))
    # the terms the whole report uses, after the deviations
    sections.insert(5 if along is not None else 4, _glossary_section(sections))
    sections.append(provenance_section(result.provenance))
    csv = verdict_frames(result)
    csv["measured"] = measured_frame(result)
    csv.update(covariance_frames(result))
    return _document(result, plan, "report", sections, csv)


# ----------------------------------------------------------------------- the plan
def _agreed_coverage(o, rule) -> str:
    """The coverage of ± U predicted of an agreed rule's measurand (its verdict's)."""
    v = next((v for v in getattr(o, "verdicts", []) if v.measurand == rule["measurand"]), None)
    return "-" if v is None or rule.get("u_planned") is None else \
        coverage_text(v.U_coverage, se=v.U_coverage_se)


def _plan_rows(o, plan) -> list:
    rules = {(r["procedure"], r["test"], r["measurand"]): r for r in plan["rules"]}
    index = {m.name: i for i, m in enumerate(o.results[o.recommended].measurands)}
    rows = []
    for v in o.verdicts:
        r = rules[(v.procedure, v.label, v.measurand)]
        u = unit(v.unit)
        step = _agreed_step(o, r)
        w = "-" if r["guard_band"] is None else fmt(r["guard_band"], step)
        rows.append([measurand_name(v.description, v.measurand), u,
                     tolerance_text(v.lower, v.upper, zone=v.zone),
                     "-" if r["u_planned"] is None else fmt(2 * r["u_planned"], step),
                     coverage_text(v.U_coverage, se=v.U_coverage_se),
                     "-" if r["tur"] is None else f"{r['tur']:.1f}", w,
                     _pct(r["pfa"]), _pct(r["pfr"])])
    for name in o.key:
        if name in {v.measurand for v in o.verdicts} or name not in index:
            continue
        r = o.results[o.recommended]
        m = r.measurands[index[name]]
        u2 = 2 * float(r.mc.std[index[name]])
        rows.append([measurand_name(m.description, name), unit(m.unit), "-", fmt_u(u2),
                     coverage_text(float(r.U_coverage[index[name]]),
                                   se=float(r.U_coverage_se[index[name]])),
                     "-", "-", "-", "-"])
    return rows


def _pct(p) -> str:
    from mtplan.reports.labels import percent

    return "-" if p is None else percent(p)


def _set_up_choices(o) -> list:
    """Per test, what its planning study found better than the agreed set-up, adopted or
    why not, from the same numbers: the planner's cheapest set-up meeting the targets, and
    each swept change that lowers U beyond the Monte Carlo error at no extra machine time
    (not adopted where it raises the U of another measurand of the test)."""
    from mtplan.reports.document import (lever_U, plan_adopted, plan_fields, plan_targets,
                                         setting_text, target_text)

    out = []
    plan = o.plan
    if plan is not None and not isinstance(plan, str):
        best = plan.best
        changed = ", ".join(field_value(f, best["setup"][f]) for f in plan_fields(o)
                            if f in best["setup"]) or "the base set-up"
        if plan_adopted(o):
            out.append(f"Set-up from the planner: {changed}, the cheapest set-up of its grid "
                       f"that meets the targets ({target_text(o)}), in "
                       f"{duration_text(best['duration_s'])}; adopted.")
        else:
            index = {m.name: i for i, m in enumerate(o.results[o.recommended].measurands)}
            units = {m.name: unit(m.unit) for m in o.results[o.recommended].measurands}
            missed = [f"U({n}) {fmt_u(K * float(o.results[o.recommended].mc.std[index[n]]))} "
                      f"{units[n]} against {t:g}" for n, t in plan_targets(plan).items()
                      if n in index and K * float(o.results[o.recommended].mc.std[index[n]]) > t]
            out.append(f"The planner's cheapest set-up meeting the targets ({target_text(o)}) "
                       f"is {changed}, in {duration_text(best['duration_s'])}; not adopted: "
                       "the study fixes the agreed set-up"
                       + (f", which misses the targets ({'; '.join(missed)}): signing this "
                          "plan accepts the U agreed below." if missed else
                          ", which meets the targets as well."))
    for e in o.levers:
        if not (e.significant and math.isfinite(e.u_base) and e.best_value != e.base_value
                and e.duration_best_s <= e.duration_base_s):
            continue
        before, after = lever_U(o, e)
        what = (f"{setting_text(o, e.field, e.best_value)} lowers U({e.measurand}) from "
                f"{fmt_u(before)} to {fmt_u(after)} {unit(e.unit)} at no extra "
                f"machine time ({duration_text(e.duration_best_s)})")
        worse = _raised(o, e)
        if worse:
            name, before, after, u = worse
            out.append(f"Considered: {what}; not adopted: it raises U({name}) from "
                       f"{fmt_u(K * before)} to {fmt_u(K * after)} {u}.")
        else:
            out.append(f"Found better: {what}; not adopted, and the study gives no reason "
                       "(adopting it needs the plan issued again before the test).")
    return out


def _raised(o, e):
    """(measurand, u before, u after, unit) of the measurand of the test whose u the lever
    ``e`` raises the most, in proportion, beyond twice the Monte Carlo error of the
    difference in its sweep; None when it raises none."""
    _, table = o.sweeps[e.sweep]
    rows = table[(table["estimator"] == e.estimator) & table["measurand"].isin(o.key)]
    field = rows[e.field].astype(float)
    before = rows[field == float(e.base_value)].set_index("measurand")
    after = rows[field == float(e.best_value)].set_index("measurand")
    worst, ratio = None, 1.0
    for name in o.key:
        if name not in before.index or name not in after.index:
            continue
        ub, ua = float(before.at[name, "u"]), float(after.at[name, "u"])
        se = math.hypot(ub / math.sqrt(2 * (float(before.at[name, "trials"]) - 1)),
                        ua / math.sqrt(2 * (float(after.at[name, "trials"]) - 1)))
        if ua - ub > 2 * se and ub > 0 and ua / ub > ratio:
            worst, ratio = (name, ub, ua, unit(str(before.at[name, "unit"]))), ua / ub
    return worst


def _plan_test(k, o, plan, study) -> Section:
    from mtplan.reports.document import datasheet_text, setup_sentence

    blocks = [f"Set-up: {setup_sentence(o)}. Estimator: {agreed_estimator(o)}. Duration (machine "
              f"time): {duration_text(o.duration_s)}. Method: {method_citation(o.spec.procedure)}; "
              f"standards: {', '.join(o.spec.standards) or 'none named'}."]
    blocks += [t for t in (datasheet_text(o),) if t]
    blocks += _set_up_choices(o)
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
    blocks.append(Table(f"Test {k}: predicted U (k = 2) and the agreed decision rules. ±U "
                        "covers: the fraction of the set-up's Monte Carlo values within ± U "
                        "predicted.",
                        ["measurand", "unit", "tolerance", "U predicted", "±U covers", "TUR",
                         "guard band w", "PFA", "PFR"], _plan_rows(o, plan), grow=0))
    blocks += rules_text(o.verdicts)
    blocks += reliability.plan_blocks(k, o)
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


#: ISO/IEC 17025 7.8.2.2: data supplied by the customer or a third party, marked as such
SUPPLIED = ("Data marked \u201ccustomer-supplied\u201d (tolerances and their sources, the "
            "populations of items behind the risks, certificates of instruments the laboratory "
            "did not calibrate) is supplied by the customer or a third party; the laboratory "
            "is not responsible for it, and the results and risks that depend on it can be "
            "affected by it (ISO/IEC 17025 7.8.2.2).")


def method_id(o, version: str) -> str:
    """The method of a test identified by procedure and version: "mtplan procedure
    rotary_axis, mtplan 1.2, patent estimator"."""
    return f"mtplan procedure {o.spec.name} (mtplan {version}), {agreed_estimator(o)} estimator"


def agreed_estimator(o) -> str:
    """The estimator the plan agrees for a test: the one its decisions use (the readings'
    estimator where the study names one), else the recommended one."""
    return next((v.estimator for v in o.verdicts if v.estimator), o.recommended)


def _not_listed(o) -> list:
    """(name, why) of each error the procedure defines that the set-up does not determine,
    from its identifiability table (``extras["identifiability"]``: per estimator a table
    with ``status``, ``listed`` and ``confounded_with``)."""
    tables = (o.extras or {}).get("identifiability")
    table = tables.get(o.recommended, next(iter(tables.values()), None)) \
        if isinstance(tables, dict) and tables else None
    if table is None or not {"listed", "status"} <= set(getattr(table, "columns", ())):
        return []
    out = []
    for name, row in table[~table["listed"].astype(bool)].iterrows():
        status = str(row["status"])
        if status == "no effect":
            why = "no effect on any reading at this set-up"
        elif str(row.get("confounded_with", "")):
            why = ("the same effect on the readings as "
                   f"{str(row['confounded_with']).replace('mounting', 'the mounting')}")
        else:
            why = f"{status} at this set-up"
        out.append((str(name), why))
    return out


def exclusions(result) -> list:
    """One line per test whose set-up does not determine errors its procedure defines:
    which, and why (its identifiability analysis)."""
    out = []
    for k, o in enumerate(result.outcomes, start=1):
        missing = _not_listed(o)
        if not missing:
            continue
        whys: dict = {}
        for name, why in missing:
            whys.setdefault(why, []).append(name)
        out.append(f"Test {k} ({o.spec.label}): {', '.join(n for n, _ in missing)} are not "
                   "reported, since the readings of this set-up do not determine them "
                   "(identifiability analysis, in the plan's annex): "
                   + "; ".join(f"{', '.join(names)}: {why}" for why, names in whys.items())
                   + ".")
    return out


def _mc_error(o, rule) -> float | None:
    """The Monte Carlo standard error of the agreed U = 2u [unit]: 2u / sqrt(2 (N - 1))
    from the N trials of the estimator the plan agreed."""
    if o is None or not rule.get("u_planned"):
        return None
    r = o.results.get(rule.get("estimator")) or o.results.get(o.recommended)
    n = int(getattr(getattr(r, "mc", None), "trials", 0) or 0)
    return 2 * rule["u_planned"] / math.sqrt(2 * (n - 1)) if n > 1 else None


def _mc_errors(se, rule) -> str:
    """The Monte Carlo standard errors of the agreed U and of w (w's in proportion, as a
    guard band set from U), one value where they are equal."""
    if not se:
        return "-"
    w, big_u = rule.get("guard_band"), 2 * rule["u_planned"]
    if w is None or math.isclose(w, big_u, rel_tol=1e-9):
        return fmt_u(se)
    return f"{fmt_u(se)}, {fmt_u(se * w / big_u)}"


def _agreed_step(o, rule) -> float | None:
    """The resolution the agreed U, w and limits are printed to (:func:`fmt` keeps two
    significant digits of its second argument): the step the plan rounded w to
    (:func:`~mtplan.plans.acceptance.agreed_resolution`), so the printed limits are the
    ones decided with."""
    from mtplan.plans.acceptance import agreed_resolution

    if not rule.get("u_planned"):
        return None
    r = None if o is None else (o.results.get(rule.get("estimator"))
                                or o.results.get(o.recommended))
    trials = int(getattr(getattr(r, "mc", None), "trials", 0) or 0)
    return 10 * agreed_resolution(rule["u_planned"], trials)


def _estimator_words(o) -> str:
    """What the agreed estimator of a test does, as its procedure describes it."""
    est = o.spec.procedure.estimators[agreed_estimator(o)].description
    return est[:1].lower() + est[1:] if est[1:2].islower() else est


def _requirement_rows(req) -> list:
    from mtplan.plans.study import REQUIREMENT_KEYS

    rows = []
    for key, (label, kind) in REQUIREMENT_KEYS.items():
        if key not in req or key in ("outside", "adjustment", "retests", "as_left",
                                     "larger_u", "schedule", "outside_effect"):
            continue
        value = req[key]

        def shown(value, kind=kind):
            if isinstance(value, dict):  # per machine serial number
                return "; ".join(f"machine {k}: {shown(v)}" for k, v in value.items())
            return (f"{value[0]:g} to {value[1]:g} °C" if kind == "band" else
                    ("on" if value else "off") if isinstance(value, bool) else
                    f"at least {value:g} min" if kind == "minutes" else
                    f"at most {value:g}" if kind == "number" else str(value))
        rows.append([label, shown(value)])
    return rows


def _clauses(req) -> list:
    """The clauses for what happens outside the conditions, on a fail or a conditional
    result, and on a larger U than agreed."""
    larger = {"widen": "the guard band of that measurand is widened in proportion (w times "
                       "U achieved / U agreed)",
              "no decision": "no decision is made on that measurand"}
    out = []
    if req.get("outside"):
        out.append(f"Outside a required condition: {req['outside']}.")
    kept = [k for k, v in req.get("outside_effect", {}).items() if v == "verdicts stand"]
    if _requirement_rows(req):
        out.append("A required condition outside its band or not recorded removes the statements "
                   "of conformity of the tests run under it"
                   + (f", except for {', '.join(kept)}, whose verdicts stand." if kept
                      else "."))
    if req.get("adjustment"):
        out.append(f"On a fail or a conditional result: {req['adjustment']}.")
    if "retests" in req:
        out.append(f"Re-tests allowed after an adjustment: {req['retests']}.")
    if req.get("as_left"):
        out.append(f"As left: {req['as_left']}.")
    if req.get("larger_u"):
        out.append("Achieved U more than 10 % above the agreed U: "
                   f"{larger[req['larger_u']]}.")
    return out or ["No clause for a fail, a conditional result or a larger U is stated in the "
                   "study: the parties settle it after the test."]


def _agreement_section(result, plan) -> Section:
    """The contract: parties, item and tests, acceptance limits, rules, burden of proof,
    overall rule, required conditions, clauses, duration, exclusions, supplied data."""
    from mtplan.reports.wording import BURDEN_OF_PROOF, OVERALL_RULE

    study = result.study
    p = plan.get("parties", {})
    version = result.provenance.get("versions", {}).get("mtplan", "")
    blocks = [f"Parties: the laboratory {p.get('laboratory') or 'not stated'}; the customer "
              f"{p.get('customer') or 'not stated'}; the machine builder "
              f"{p.get('machine_builder') or 'not stated'}. Each signs this plan on its cover "
              "before the test; the report will apply exactly what is agreed here."]
    serial = {k: m.removeprefix("machine ") for m, tests in machines(result) for k in tests}
    rows = [[str(k), o.spec.label, serial[k], method_id(o, version),
             ", ".join(o.spec.standards) or "-", duration_text(o.duration_s)]
            for k, o in enumerate(result.outcomes, start=1)]
    blocks.append(Table("Tests, the machine each is run on (serial number), the method "
                        "(procedure and version) and the machine time.",
                        ["test", "title", "machine", "method", "standards", "duration"],
                        rows, grow=3, size=7.0))
    blocks += ["The estimator of each method, part of the method (readings evaluated with "
               "another are a deviation):",
               [f"test {k}, {agreed_estimator(o)}: {_estimator_words(o)}"
                for k, o in enumerate(result.outcomes, start=1)]]
    total = sum(o.duration_s for o in result.outcomes if math.isfinite(o.duration_s))
    schedule = study.requirements.get("schedule")
    blocks.append(f"Total duration (machine time): {duration_text(total)}; date of the test: "
                  f"{study.header.get('date', 'not stated')}"
                  + (f"; schedule: {schedule}" if schedule else "") + ".")
    limits = []
    by_label = {o.spec.label: o for o in result.outcomes}
    for r in plan["rules"]:
        u = unit(r.get("unit", ""))
        se = _mc_error(by_label.get(r["test"]), r)
        step = _agreed_step(by_label.get(r["test"]), r)
        lo, hi = (None if r[k] is None else fmt(r[k], step)
                  for k in ("acceptance_lower", "acceptance_upper"))
        acc = ("-" if r.get("guard_band") is None else
               f"[{'-∞' if lo is None else lo}, {'∞' if hi is None else hi}]")
        limits.append([r["measurand"], u, tolerance_text(r["lower"], r["upper"]), acc,
                       "-" if r.get("guard_band") is None else fmt(r["guard_band"], step),
                       "-" if r.get("u_planned") is None else fmt(2 * r["u_planned"], step),
                       _mc_errors(se, r), _agreed_coverage(by_label.get(r["test"]), r),
                       r.get("tolerance_source") or "not stated"])
    # one tolerance source for every measurand is stated once, under the table
    sources = {row[-1] for row in limits}
    header = ["measurand", "unit", "tolerance", "acceptance limits", "w", "U predicted",
              "MC error", "±U covers", "tolerance source"]
    if len(sources) == 1:
        limits, header = [row[:-1] for row in limits], header[:-1]
    blocks.append(Table("Acceptance limits per measurand: a pass needs the measured value "
                        "within them (the tolerance reduced by the guard band w). U predicted "
                        f"at k = {K:g}; MC error: the Monte Carlo tolerance of U and of w, the "
                        "standard error of the simulation (JCGM 101 7.9; one value where "
                        "w = U). U, w and the limits are printed to two significant digits of "
                        "U, or fewer where the Monte Carlo does not support them (GUM 7.2.6). "
                        "±U covers: the fraction of the set-up's Monte Carlo values within "
                        "± U predicted.",
                        header, limits, grow=len(header) - 1 if len(sources) > 1 else 0,
                        size=7.0))
    if len(sources) == 1:
        blocks.append(f"The tolerance source of every measurand: {sources.pop()}.")
    from mtplan.reports.actions import signing_lines, signing_title
    from mtplan.reports.results import rounding_sentence

    blocks.append(rounding_sentence(result))
    warned = signing_lines(result)
    blocks += [f"{signing_title()}:", warned] if warned else [
        f"{signing_title()}: none."]
    frames: dict = {}
    for r in plan["rules"]:
        frames.setdefault(r.get("frame") or "not stated in the study", []).append(r["measurand"])
    blocks += ["Sign convention and reference frame of each measurand (a correction's sign "
               "depends on it):", [f"{', '.join(names)}: {text}" for text, names in
                                   frames.items()]]
    blocks += rules_text(result.verdicts)
    blocks += [BURDEN_OF_PROOF, OVERALL_RULE]
    req = study.requirements
    rows = _requirement_rows(req)
    if rows:
        blocks.append(Table("Required test conditions (ISO 230-1 6.1), recorded in the report.",
                            ["condition", "required"], rows))
    else:
        blocks.append("No required test conditions are stated in the study.")
    blocks += ["Clauses agreed for what happens after the test:", _clauses(req)]
    excluded = exclusions(result)
    blocks += (["Exclusions:", excluded] if excluded else ["Exclusions: none."])
    blocks.append(SUPPLIED)
    return Section("The agreement", anchor="agreement", blocks=blocks)


def build_plan(result, plan, parts=None) -> Document:
    """The test plan of a computed study (its readings, if any, are not used). ``parts``:
    :func:`plan_parts` of each test, in test order, where they were drawn already."""
    from mtplan.reports import appendix
    from mtplan.reports.document import methods_section

    if parts is None:
        parts = [plan_parts(k, o) for k, o in enumerate(result.outcomes, start=1)]
    study = result.study
    rules = Section("Annex: tests and decision rules (technical study)", anchor="rules",
                    blocks=[
        "What each test measures, how, with which instruments and how long, the uncertainty "
        "it is predicted to reach and the decision rule both parties agree before measuring "
        f"(U at k = {K:g}, with the fraction of the Monte Carlo values within ± U beside it; "
        f"intervals at {study.coverage:.0%})."])
    rules.blocks += [_plan_test(k, o, plan, study)
                     for k, o in enumerate(result.outcomes, start=1)]
    sections = [_agreement_section(result, plan), rules, methods_section(result)]
    sections += [body for body, _ in parts]
    csv = {}
    for _, (sec, frames) in parts:
        sections.append(sec)
        csv.update(frames)
    sections.insert(3, _glossary_section(sections))  # the terms the whole plan uses
    sections.append(appendix.provenance_section(result.provenance, document="plan"))
    return _document(result, plan, "plan", sections, csv)
