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

__all__ = ["PLAN_FORMAT", "declared_rules", "fingerprint", "issue_plan", "read_plan",
           "check_study", "apply_plan", "p_conform_measured", "FIT_NO_DECISION"]

PLAN_FORMAT = "mtplan-test-plan-1"
#: the verdict of a toleranced measurand whose readings do not fit the model
FIT_NO_DECISION = "no decision: the readings do not fit the model"
_DECLARED = ("lower", "upper", "rule", "prior")


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
                        "coverage": study.coverage})
            if "position" in a:  # a diameter zone (ISO 1101): what it is a zone of
                out[-1].update({"position": list(a["position"]),
                                "nominal": [float(x) for x in a["nominal"]]})
    return out


def fingerprint(rules: list[dict]) -> str:
    """SHA-256 (hex) of the rules as canonical JSON (keys sorted, no spaces)."""
    text = json.dumps(rules, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _plan_number(study) -> str:
    header = study.header
    if header.get("plan_document"):
        return header["plan_document"]
    return f"{header.get('document', 'MTPLAN')}-PLAN"


def issue_plan(result) -> dict:
    """The plan of a computed study: its declared rules with the guard band, acceptance
    limits, predicted uncertainty and risks each one fixes, a document number and the
    fingerprint of the rules. Numbers are the planned set-up's (no readings used)."""
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
    return {"format": PLAN_FORMAT, "document": _plan_number(study),
            "revision": header.get("revision", ""),
            "issued": header.get("plan_date") or datetime.date.today().isoformat(),
            "study_title": study.title, "rules": rules, "fingerprint": fingerprint(rules)}


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
    if fingerprint(plan.get("rules", [])) != plan.get("fingerprint"):
        raise InvalidInput([f"{where}: its rules do not match its fingerprint "
                            f"{str(plan.get('fingerprint'))[:16]}: the file was changed "
                            "after it was issued."])
    return plan


def check_study(study, plan) -> None:
    """Refuse a study whose rules differ from the plan's, naming the first difference.

    Raises
    ------
    InvalidInput
        One problem: the measurand and field, the plan's value and the study's.
    """
    number = plan.get("document", "the plan")
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
        for name in (*_DECLARED, "population_source", "coverage", "position", "nominal"):
            if r.get(name) != p.get(name):
                raise InvalidInput([f"{key[0]} {key[2]} {name}: plan {number} says "
                                    f"{p.get(name)!r}, the study {r.get(name)!r}; the rules "
                                    "agreed before the test cannot change after it (issue a "
                                    "new plan)."])


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
    planned = {(r["procedure"], r["test"], r["measurand"]): r for r in plan["rules"]}
    deviations = []
    for o in result.outcomes:
        for verdicts, measured, when in ((o.verdicts, o.measured, ""),
                                         (getattr(o, "as_left_verdicts", []),
                                          getattr(o, "as_left", None), " as left")):
            deviations += _apply(verdicts, measured, planned, when)
    return deviations


def _apply(verdicts, measured, planned, when) -> list[str]:
    """:func:`apply_plan` for the verdicts of one evaluation of a test's readings."""
    from mtplan.plans.decisions import NOT_DETERMINABLE, NOT_MEASURED, decide, fit_verdict

    misfit = None if measured is None else fit_verdict(measured.fit)
    deviations = []
    for v in verdicts:
        r = planned[(v.procedure, v.label, v.measurand)]
        if v.p_conform_population is None:  # once: apply_plan may run again
            v.p_conform_population = v.p_conform
        if r["guard_band"] is None:  # the plan could not fix a rule for it
            v.verdict, v.p_conform = NOT_DETERMINABLE, None
            continue
        if not math.isclose(r["guard_band"], v.guard_band, rel_tol=1e-9,
                            abs_tol=1e-12) and not when:
            deviations.append(f"{v.measurand}: this run's planned set-up gives a guard band "
                              f"of {v.guard_band:.4g} {v.unit}; the plan's "
                              f"{r['guard_band']:.4g} {v.unit} is applied.")
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
            deviations.append(f"{v.measurand}{when}: the measurement's U "
                              f"({2 * v.measured_u:.3g} {v.unit}) exceeds the plan's "
                              f"predicted U ({2 * v.u:.3g} {v.unit}) that set the guard "
                              "band.")
    return deviations
