"""The test plan agreed before measuring, and the report held to it.

ISO/IEC 17025 7.1.3 and ILAC-G8:09/2019 expect the decision rule, and so the guard band,
to be agreed with the customer before anything is measured; ISO/TR 14253-6 asks both
parties to agree when the default rule is left. The workflow:

1. ``mtplan report STUDY --out DIR --plan-only`` computes the study without its readings
   and issues the plan: ``plan.pdf``, ``plan.html`` and ``plan.json`` (:func:`issue_plan`),
   whose rules carry a document number and a SHA-256 fingerprint (:func:`fingerprint`).
2. The parties sign the plan; the test is run; the readings are added to the study.
3. ``mtplan report STUDY --out DIR --plan plan.json`` first checks that the study still
   states exactly the plan's rules (:func:`check_study`: a changed tolerance, rule,
   population or coverage is refused with one line naming it), then evaluates the readings
   and decides with the plan's own guard bands (:func:`apply_plan`).

What the documents state is checked, not only printed: the fingerprint covers everything
the parties sign (number, revision, issue date, parties, rules with their limits, the
required conditions, and the terms of :mod:`mtplan.plans.terms`: the item, the tests and
their machines, set-ups and standards, the instruments, the method's version), so an
edited ``plan.json`` is refused; a study that moves a test to another machine is refused
and one that changes a set-up or an instrument lists each change as a deviation; a
report under a plan needs the date of the test and the time of each test
(:func:`require_dates`); a plan issued after the test is refused unless the study records
that the customer accepts it (:func:`check_dates`); an instrument whose calibration had
run out, has no due date or cannot be checked against a test date is a deviation and the
tests that used it get no statement of conformity unless the customer agreed
(:func:`instrument_findings`); a required condition outside the agreement or not recorded
is a deviation that removes the statements of conformity of the tests run under it
unless the plan's clause keeps them (:mod:`mtplan.plans.conditions`); an estimator other
than the plan's is a deviation.

Without ``--plan`` (and in ``mtplan demo``) the plan is issued and applied in the same run;
the report says so among its deviations from the plan.
"""

from __future__ import annotations

import datetime
import hashlib
import json
import math
from pathlib import Path

from mtplan._validate import InvalidInput

__all__ = ["PLAN_FORMAT", "declared_rules", "fingerprint", "signed_content", "parties",
           "issue_plan", "read_plan", "check_study", "check_dates", "require_dates",
           "instrument_findings",
           "apply_plan", "p_conform_measured", "FIT_NO_DECISION", "NO_INSTRUMENT",
           "LARGER_U_NO_DECISION"]

PLAN_FORMAT = "mtplan-test-plan-3"
#: the verdict of a toleranced measurand whose readings do not fit the model
FIT_NO_DECISION = "no decision: the readings do not fit the model"
#: the verdict of a toleranced measurand measured with an instrument that was not calibrated
#: (or verified) on the date of the test, without the customer's agreement
NO_INSTRUMENT = "no statement: an instrument was not calibrated on the test date"
_DECLARED = ("lower", "upper", "rule", "prior")
#: the verdicts that state conformity or non-conformity (ILAC-G8 4.2.3)
STATEMENTS = ("pass", "conditional pass", "conditional fail", "fail")


def declared_rules(study) -> list[dict]:
    """The rules a study states, one per toleranced measurand: what both parties agree
    (tolerance, decision rule, population of items) and the study's coverage."""
    out = []
    for ps in study.procedures:
        for a in ps.acceptance:
            out.append({"procedure": ps.name, "test": ps.label, "measurand": a["measurand"],
                        "lower": a.get("lower"), "upper": a.get("upper"),
                        "rule": str(a.get("rule", "simple")), "prior": a.get("prior"),
                        "population_source": a.get("population_source", ""),
                        "tolerance_source": a.get("tolerance_source", ""),
                        "frame": a.get("frame", ""),
                        "coverage": study.coverage})
            if "position" in a:  # a diameter zone (ISO 1101): what it is a zone of
                out[-1].update({"position": list(a["position"]),
                                "nominal": [float(x) for x in a["nominal"]]})
    return out


def fingerprint(content) -> str:
    """SHA-256 (hex, 64 digits) of ``content`` as canonical JSON (keys sorted, no spaces):
    of a plan, everything the parties sign (:func:`signed_content`)."""
    text = json.dumps(content, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def signed_content(plan: dict) -> dict:
    """What the parties sign: the whole plan but its fingerprint (number, revision, issue
    date, time of computation, parties, required conditions, rules with their limits and
    guard bands, and the terms: item, tests, machines, set-ups, instruments, method
    version)."""
    return {k: v for k, v in plan.items() if k != "fingerprint"}


def parties(study) -> dict:
    """The parties who sign the plan: the laboratory, the customer and the machine
    builder, as the study names them ("" where it does not)."""
    h = study.header
    return {"laboratory": study.laboratory.get("name", ""),
            "customer": h.get("customer", ""), "machine_builder": h.get("machine_maker", "")}


def _plan_number(study) -> str:
    header = study.header
    if header.get("plan_document"):
        return header["plan_document"]
    return f"{header.get('document', 'MTPLAN')}-PLAN"


def issue_plan(result) -> dict:
    """The plan of a computed study: its declared rules with the guard band, acceptance
    limits, predicted uncertainty and risks each one fixes, a document number and the
    fingerprint of the rules and terms (:func:`~mtplan.plans.terms.agreed_terms`), and when
    it was computed (``computed``: the study's computation, UTC). Numbers are the planned
    set-up's (no readings used)."""
    from mtplan.plans.terms import agreed_terms

    study = result.study
    verdicts = {(v.procedure, v.label, v.measurand): v for v in result.verdicts}
    rules = []
    for r in declared_rules(study):
        v = verdicts.get((r["procedure"], r["test"], r["measurand"]))
        fixed = dict(r)
        fixed.update({"unit": v.unit if v else "", "u_planned": _num(v.u if v else None),
                      "k": v.k if v else 2.0,
                      "guard_band": _num(v.guard_band if v else None),
                      "acceptance_lower": _num(v.acceptance_limits[0] if v else None),
                      "acceptance_upper": _num(v.acceptance_limits[1] if v else None),
                      "pfa": _num(v.pfa if v else None), "pfr": _num(v.pfr if v else None),
                      "tur": _num(v.tur if v else None), "estimator": v.estimator if v else "",
                      "planned_verdict": "" if v is None or v.guard_band == v.guard_band
                      else v.verdict})
        rules.append(fixed)
    header = study.header
    plan = {"format": PLAN_FORMAT, "document": _plan_number(study),
            "revision": header.get("revision", ""),
            "issued": header.get("plan_date") or datetime.date.today().isoformat(),
            "computed": (result.provenance or {}).get("date", ""),
            "study_title": study.title, "parties": parties(study),
            "conditions": dict(getattr(study, "requirements", {}) or {}), "rules": rules,
            **agreed_terms(study)}
    plan["fingerprint"] = fingerprint(plan)
    return plan


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def read_plan(path) -> dict:
    """A plan written by :func:`issue_plan` (``plan.json``), checked against its own
    fingerprint."""
    where = f"--plan {str(path)!r}"
    try:
        plan = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InvalidInput([f"{where}: no such file."]) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InvalidInput([f"{where}: not a plan written by mtplan ({exc})."]) from None
    if not isinstance(plan, dict) or plan.get("format") != PLAN_FORMAT:
        raise InvalidInput([f"{where}: not a plan written by mtplan (format must be "
                            f"{PLAN_FORMAT!r})."])
    if fingerprint(signed_content(plan)) != plan.get("fingerprint"):
        raise InvalidInput([f"{where}: its content (number, revision, issue date, parties, "
                            "conditions, rules, tests, machines, set-ups or instruments) "
                            "does not match its fingerprint "
                            f"{plan.get('fingerprint')}: the file was changed after it was "
                            "issued."])
    return plan


def check_study(study, plan) -> None:
    """Refuse a study whose parties, conditions, rules, item, tests or machines differ
    from the plan's, naming the first difference (set-ups and instruments that differ are
    deviations: :func:`apply_plan`).

    Raises
    ------
    InvalidInput
        One problem: what differs, the plan's value and the study's.
    """
    from mtplan.plans.terms import compare_terms

    number = plan.get("document", "the plan")
    refusals = compare_terms(study, plan)[0]
    if refusals:
        raise InvalidInput(refusals[:1])
    for role, name in parties(study).items():
        agreed = plan.get("parties", {}).get(role, "")
        if name != agreed:
            raise InvalidInput([f"The study names {name!r} as the "
                                f"{role.replace('_', ' ')}, plan {number} {agreed!r}: the "
                                "parties who signed cannot change after the test (issue a "
                                "new plan)."])
    required = dict(getattr(study, "requirements", {}) or {})
    if required != plan.get("conditions", {}):
        raise InvalidInput([f"The study's required conditions differ from those of plan "
                            f"{number} ({plan.get('conditions', {})!r}); the conditions "
                            "agreed before the test cannot change after it (issue a new "
                            "plan)."])
    planned = {(r["procedure"], r["test"], r["measurand"]): r for r in plan["rules"]}
    stated = {(r["procedure"], r["test"], r["measurand"]): r for r in declared_rules(study)}
    for key in planned:
        if key not in stated:
            raise InvalidInput([f"The study no longer tolerances {key[2]} of {key[0]} "
                                f"({key[1]}), which plan {number} does; issue a new plan."])
    for key, r in stated.items():
        if key not in planned:
            raise InvalidInput([f"The study tolerances {key[2]} of {key[0]} ({key[1]}), "
                                f"which plan {number} does not; issue a new plan."])
        p = planned[key]
        for name in (*_DECLARED, "population_source", "tolerance_source", "frame", "coverage",
                     "position", "nominal"):
            if r.get(name) != p.get(name):
                raise InvalidInput([f"{key[0]} {key[2]} {name}: plan {number} says "
                                    f"{p.get(name)!r}, the study {r.get(name)!r}; the rules "
                                    "agreed before the test cannot change after it (issue a "
                                    "new plan)."])


def _date(text):
    try:
        return datetime.date.fromisoformat(str(text)[:10])
    except ValueError:
        return None


def require_dates(study) -> None:
    """A report under a plan needs the date of the test (``[header] date``) and the time
    of each test (``[[procedure]] time``): every date check (the plan's issue date, the
    instruments' due dates) depends on them.

    Raises
    ------
    InvalidInput
        One line naming what is missing.
    """
    missing = [] if _date(study.header.get("date")) else ["the date of the test ([header] "
                                                          "date)"]
    untimed = [str(k) for k, ps in enumerate(study.procedures, start=1) if not ps.time]
    if untimed:
        missing.append(f"the time of test{'s' if len(untimed) > 1 else ''} "
                       f"{', '.join(untimed)} ([[procedure]] time, \"08:30-09:40\")")
    if missing:
        raise InvalidInput([f"The study does not record {' or '.join(missing)}: a report "
                            "under a plan checks the plan's date and each instrument's "
                            "calibration against them."])


def check_dates(study, plan) -> list[str]:
    """The plan's issue date against the date of the test (ISO/IEC 17025 7.1.3: the
    decision rule is agreed before the test).

    Returns
    -------
    list of str
        The deviation of a plan issued after the test that the study explicitly accepts
        (its header's ``late_plan``: who accepted it, when and why); else empty.

    Raises
    ------
    InvalidInput
        A plan issued after the test that the study does not accept (one line).
    """
    issued, tested = _date(plan.get("issued")), _date(study.header.get("date"))
    if issued is None or tested is None or issued <= tested:
        return []
    number = plan.get("document") or "of this study"
    accepted = study.header.get("late_plan")
    if not accepted:
        raise InvalidInput([f"Plan {number} was issued on {issued}, after the test on "
                            f"{tested}: a decision rule must be agreed before the test "
                            "(ISO/IEC 17025 7.1.3); issue the report without this plan, or "
                            "record who accepted the late plan in the study's header "
                            "'late_plan'."])
    return [f"The test plan {number} was issued on {issued}, after the test on {tested}; "
            f"accepted as recorded in the study: {accepted}."]


def instrument_findings(study) -> tuple[list[dict], list[str], dict]:
    """Each instrument's calibration (or verification) against the date of the test.

    Returns
    -------
    status : list of dict
        Per instrument (study order): ``name``, ``serial``, ``state`` ("valid", "expired",
        "no due date" or "not checked": no test date), ``due`` and ``agreed`` (the
        customer's agreement the study records, or "").
    deviations : list of str
        One per instrument not valid on the test date.
    blocked : dict
        ``{procedure: reason}``: the tests that used an instrument not valid on the test
        date, or whose validity could not be checked (no test date), without the
        customer's agreement; they get no statement of conformity.
    """
    tested = _date(study.header.get("date"))
    status, deviations, blocked = [], [], {}
    for inst in study.instruments:
        due = _date(inst.get("calibration_due", "")) if inst.get("calibration_due") else None
        what = inst.get("kind", "calibration")
        if tested is None:
            state = "not checked"
        elif due is None:
            state = "no due date"
        elif due < tested:
            state = "expired"
        else:
            state = "valid"
        agreed = inst.get("customer_agreement", "")
        status.append({"name": inst["name"], "serial": inst["serial"], "state": state,
                       "due": "" if due is None else due.isoformat(), "agreed": agreed})
        if state == "valid":
            continue
        ident = f"{inst['name']} (serial {inst['serial']})"
        why = (f"its {what} ran out on {due}, before the test on {tested}" if state ==
               "expired" else f"its {what} states no due date" if state == "no due date"
               else f"the date of the test is not stated, so its {what} could not be checked "
                    "against it")
        used = inst.get("used_in") or [ps.name for ps in study.procedures]
        labels = ", ".join(ps.label for ps in study.procedures if ps.name in used)
        if agreed:
            deviations.append(f"{ident}: {why}; used for {labels} with the customer's "
                              f"agreement recorded in the study: {agreed}.")
            continue
        deviations.append(f"{ident}: {why}; no statement of conformity is made on the tests "
                          f"that used it ({labels}).")
        for name in used:
            blocked.setdefault(name, f"{ident}: {why}")
    return status, deviations, blocked


def p_conform_measured(value, u, lower, upper) -> float | None:
    """Probability that the true value lies within the tolerance from the measurement
    alone: a normal distribution of the measured value with its own standard uncertainty
    (no population of items)."""
    if value is None or u is None or not (u > 0 and math.isfinite(u)):
        return None
    lo = -math.inf if lower is None else (float(lower) - value) / u
    hi = math.inf if upper is None else (float(upper) - value) / u

    def cdf(z):
        return 0.5 * math.erfc(-z / math.sqrt(2.0))

    return max(0.0, cdf(hi) - cdf(lo))


def apply_plan(result, plan) -> list[str]:
    """Decide every toleranced measurand of a computed study with the plan's guard bands.

    The verdicts of ``result`` are updated in place: guard band, acceptance limits, planned
    u and risks from the plan; the probability of conformity from the measurement alone
    (``p_conform``; the population's stays in ``p_conform_population``; a position zone's
    from its own samples). The as-left verdicts (readings after an adjustment) are decided
    the same way. Readings that do not fit the model
    (:func:`~mtplan.plans.decisions.fit_verdict`) get no verdict: :data:`FIT_NO_DECISION`.

    Returns
    -------
    list of str
        The deviations from the plan found on the way (a measurement whose own U exceeds
        the predicted one, a guard band the study would now compute differently).
    """
    from mtplan.plans.conditions import NO_CONDITION, check_conditions
    from mtplan.plans.terms import compare_terms

    planned = {(r["procedure"], r["test"], r["measurand"]): r for r in plan["rules"]}
    _, deviations, blocked = instrument_findings(result.study)
    _, conditions, unconditioned = check_conditions(result.study, plan.get("conditions", {}))
    deviations += conditions + compare_terms(result.study, plan)[1]
    for o in result.outcomes:
        for verdicts, measured, when in ((o.verdicts, o.measured, ""),
                                         (getattr(o, "as_left_verdicts", []),
                                          getattr(o, "as_left", None), " as left")):
            deviations += _apply(verdicts, measured, planned, when,
                                 plan.get("conditions", {}).get("larger_u"))
            for block, key, verdict in ((blocked, o.spec.name, NO_INSTRUMENT),
                                        (unconditioned, (o.spec.name, o.spec.label),
                                         NO_CONDITION)):
                for v in verdicts:
                    if key in block and v.measured is not None and v.verdict not in (
                            NO_INSTRUMENT, NO_CONDITION):
                        v.verdict, v.reason = verdict, block[key]
            for v in verdicts:  # no probability of conformity where no statement is made
                if v.verdict not in STATEMENTS:
                    v.p_conform = None
    return deviations


def _estimator_deviations(verdicts, planned) -> list[str]:
    """One line per test whose measurands were decided with another estimator than the one
    the plan agreed (the estimator is part of the method)."""
    from mtplan._numbers import fmt_u, unit

    def u_text(w):
        r = planned[(w.procedure, w.label, w.measurand)]
        achieved = "-" if w.measured_u is None else fmt_u(2 * w.measured_u)
        agreed = "-" if r.get("u_planned") is None else fmt_u(2 * r["u_planned"])
        return f"{w.measurand} (U {achieved} {unit(w.unit)}; plan's U {agreed} {unit(w.unit)})"

    out, seen = [], set()
    for v in verdicts:
        agreed = planned[(v.procedure, v.label, v.measurand)].get("estimator")
        if not agreed or v.estimator == agreed or (v.label, v.estimator) in seen:
            continue
        seen.add((v.label, v.estimator))
        names = ", ".join(u_text(w) for w in verdicts if w.estimator == v.estimator)
        out.append(f"{v.label}: decided with the {v.estimator} estimator, not the {agreed} "
                   f"estimator the plan agreed (a change of method): {names}; the plan's "
                   "guard bands are applied.")
    return out


#: the verdict of a measurand whose achieved U exceeds the agreed one where the plan's
#: clause says so (``larger_u = "no decision"``)
LARGER_U_NO_DECISION = "no decision: the achieved U exceeds the agreed U"


def _apply(verdicts, measured, planned, when, larger_u=None) -> list[str]:
    """:func:`apply_plan` for the verdicts of one evaluation of a test's readings."""
    from mtplan._numbers import fmt, fmt_u, unit
    from mtplan.plans.decisions import NOT_DETERMINABLE, NOT_MEASURED, decide, fit_verdict

    misfit = None if measured is None else fit_verdict(measured.fit)
    deviations = [] if when else _estimator_deviations(verdicts, planned)
    for v in verdicts:
        r = planned[(v.procedure, v.label, v.measurand)]
        if v.p_conform_population is None:  # once: apply_plan may run again
            v.p_conform_population = v.p_conform
        if r["guard_band"] is None:  # the plan could not fix a rule for it
            v.verdict, v.p_conform = NOT_DETERMINABLE, None
            continue
        if not math.isclose(r["guard_band"], v.guard_band, rel_tol=1e-9,
                            abs_tol=1e-12) and not when:
            step = r["u_planned"] / 5 if r["u_planned"] else None
            deviations.append(f"{v.measurand}: this run's planned set-up gives a guard band "
                              f"of {fmt(v.guard_band, step)} {unit(v.unit)}; the plan's "
                              f"{fmt(r['guard_band'], step)} {unit(v.unit)} is applied.")
        v.u, v.guard_band = r["u_planned"], r["guard_band"]
        v.acceptance_limits = (r["acceptance_lower"], r["acceptance_upper"])
        v.pfa, v.pfr, v.tur = r["pfa"], r["pfr"], r["tur"]
        v.p_conform = (v.p_conform_samples if v.p_conform_samples is not None else
                       p_conform_measured(v.measured, v.measured_u, v.lower, v.upper))
        if v.verdict in (NOT_MEASURED, NOT_DETERMINABLE) or v.measured is None:
            continue
        if misfit is not None:
            v.verdict, v.reason = misfit
            continue
        v.verdict = decide(v.measured, v.lower, v.upper, v.guard_band)
        if v.measured_u is not None and v.measured_u > 1.1 * v.u:
            line = (f"{v.measurand}{when}: the measurement's U ({fmt_u(2 * v.measured_u)} "
                    f"{unit(v.unit)}) exceeds the plan's predicted U ({fmt_u(2 * v.u)} "
                    f"{unit(v.unit)}) that set the guard band by more than 10 %")
            if larger_u == "widen":
                wider = v.guard_band * v.measured_u / v.u
                v.guard_band = wider
                v.acceptance_limits = (None if v.lower is None else v.lower + wider,
                                       None if v.upper is None else v.upper - wider)
                v.verdict = decide(v.measured, v.lower, v.upper, wider)
                line += (f"; as the plan agreed, the guard band is widened to "
                         f"{fmt(wider, v.measured_u / 5)} {unit(v.unit)}")
            elif larger_u == "no decision":
                v.verdict, v.reason = LARGER_U_NO_DECISION, line
                line += "; as the plan agreed, no decision is made on it"
            deviations.append(line + ".")
    return deviations
