"""The actions of a test report: what would follow for each measurand without a pass.

A fail is adjusted and re-tested. A value in the guard band is decided by a smaller U, and
what reaches it comes from the budget (:func:`mtplan.plans.actions.budget_action`): a
swept set-up of the study, a calibration of the instrument or artefact that owns a source,
repeats where the random share allows them, or nothing the laboratory can do, said so.
A measurand without a statement because an instrument was not valid gets a calibration,
never a set-up. Formatting only: the numbers come from the budget, the sweeps and the plan.
"""

from __future__ import annotations

import math

from mtplan.plans.decisions import K
from mtplan.reports.labels import duration_text, field_label, fmt, fmt_u, tolerance_text, unit
from mtplan.reports.wording import measurand_name

__all__ = ["actions", "needed_u", "lever_for", "below", "three", "scaled_lever_u"]


def needed_u(v) -> float | None:
    """The predicted U that would decide a value inside the guard band: the distance of
    the measured value to the nearest tolerance limit, over the rule's w / U."""
    if v.measured is None or not (v.u and v.guard_band):
        return None
    limits = [x for x in (v.lower, v.upper) if x is not None]
    gap = min(abs(v.measured - x) for x in limits)
    return gap * (2 * v.u) / v.guard_band


def below(x: float) -> str:
    """An upper bound to three significant digits, rounded down (never "below 11" for
    10.7)."""
    if not (x > 0 and math.isfinite(x)):
        return fmt_u(x)
    decimals = max(0, 2 - math.floor(math.log10(x)))
    step = 10.0 ** -decimals
    return f"{math.floor(x / step + 1e-9) * step:.{decimals}f}"


def three(x: float) -> str:
    """A U after an action to three significant digits (the tests recompute it to 2 %)."""
    if not (x > 0 and math.isfinite(x)):
        return fmt_u(x)
    return f"{x:.{max(0, 2 - math.floor(math.log10(x)))}f}"


def scaled_lever_u(o, table, field, value, measurand, estimator, u_table) -> float | None:
    """The U a swept set-up gives, quoted from the same computation as the plan's table:
    the agreed U (``2 u_table``) times the sweep's ratio of u at ``value`` to u at the
    agreed set-up's value (the sweep ran fewer trials than the table); the sweep's own U
    where it did not run the agreed value."""
    rows = table[(table["measurand"] == measurand) & (table["estimator"] == estimator)]
    at = rows[rows[field] == value]
    if not len(at):
        return None
    base = o.spec.setup.as_dict().get(field)
    ref = rows[[_same(x, base) for x in rows[field]]]
    u_at = float(at["u"].iloc[0])
    if len(ref) and float(ref["u"].iloc[0]) > 0 and u_table and u_table > 0:
        return K * u_table * u_at / float(ref["u"].iloc[0])
    return K * u_at


def _same(a, b) -> bool:
    try:
        return math.isclose(float(a), float(b), rel_tol=1e-9, abs_tol=1e-12)
    except (TypeError, ValueError):
        return str(a) == str(b)


def lever_for(o, v, needed) -> str:
    """A swept or planned set-up whose predicted U is below ``needed``, in words, or ""."""
    from mtplan.reports.document import setting_text

    best = None
    for spec, table in o.sweeps:
        if isinstance(table, str) or len(spec["vary"]) != 1:
            continue
        f = next(iter(spec["vary"]))
        if f not in o.spec.procedure.levers:
            continue
        for value in table[f].unique():
            big_u = scaled_lever_u(o, table, f, value, v.measurand, v.estimator, v.u)
            if big_u is None or not 0 < big_u <= needed:
                continue
            rows = table[(table[f] == value) & (table["measurand"] == v.measurand)]
            cand = (float(rows["duration_s"].iloc[0]) if "duration_s" in rows else math.nan,
                    f, value, big_u)
            if best is None or cand[0] < best[0]:
                best = cand
    plan = o.plan if not isinstance(o.plan, str) else None
    column = f"u_{v.measurand}"
    if plan is not None and getattr(plan, "table", None) is not None \
            and column in plan.table:  # the planner's candidates: k times the linearised u
        t = plan.table
        ok = t[(2 * t[column] / plan.k <= needed) & (t[column] > 0)]
        if len(ok):
            r = ok.loc[ok["cost_s"].idxmin()]
            vary = o.spec.plan.get("vary", {})  # else the levers the search changed
            base = o.spec.setup.as_dict()
            fields = [f for f in (vary or o.spec.procedure.levers) if f in t.columns
                      and (vary or str(r[f]) != str(base.get(f)))]
            shown = [setting_text(o, f, r[f]) for f in fields]
            if r.get("calibration"):
                shown.append(f"with the calibration {r['calibration']}")
            cand = (float(r["cost_s"]), None, ", ".join(shown), 2 * r[column] / plan.k)
            if best is None or cand[0] < best[0]:
                best = cand
    if best is None:
        return ""
    if best[1] is None:
        return (f"the planner's cheapest set-up that reaches it: {best[2]} (predicted U "
                f"{fmt_u(best[3])} {unit(v.unit)}, {duration_text(best[0])}), agreed in a "
                "revised plan, and re-test")
    return (f"set {setting_text(o, best[1], best[2])} (predicted U {fmt_u(best[3])} {unit(v.unit)}, below "
            f"{below(needed)} {unit(v.unit)}, agreed in a revised plan) and re-test")


def _source_words(o, name: str) -> str:
    """An error source by its sizing field's declared label: "grid plate's own error"."""
    from mtplan.models.protocol import fields_info

    for f in fields_info(o.spec.procedure.Setup):
        if f.name.startswith(f"{name}_"):
            return field_label(f.name, f.doc or "").split(" [")[0]
    return name.replace("_", " ")


def _instruments(study, procedure) -> str:
    names = [f"{i['name']} (serial {i['serial']})" for i in study.instruments
             if not i.get("used_in") or procedure in i["used_in"]]
    return " and ".join(names) or "the instrument"


#: what acting on a source of each owner means
_ACT = {"instrument": "calibrate the {inst} (a calibration that corrects or bounds it, or a "
                      "better grade)",
        "artefact": "calibrate the artefact (or use a better one)",
        "method": "change the set-up (mounting, order, counts)",
        "environment": "hold the conditions tighter during the test"}


def _budget_text(o, v, needed, study, lever: str = "") -> str:
    """The budget by source and the action it supports (:func:`~mtplan.plans.actions.
    budget_action`), in sentences."""
    from mtplan.plans.actions import ACTIONABLE, budget_action, source_owners

    u = unit(v.unit)
    act = budget_action(o.budget, v.measurand, 2 * v.u, needed,
                        source_owners(o.spec.procedure))
    if act is None:
        return "the budget does not say which sources carry U"
    shown = [e for e in act.effects if e.share >= 0.05][:4]
    parts = "; ".join(f"{_source_words(o, e.source)} ({e.owner}, {100 * e.share:.0f} %: "
                      f"U {three(e.U_without)} without it, {three(e.U_halved)} halved)"
                      for e in shown)
    text = f"its budget by source (owner, share of u²): {parts}"
    if act.acted:
        owners = sorted({e.owner for e in act.acted})
        what = "; ".join(_ACT[w].format(inst=_instruments(study, o.spec.name)) for w in owners)
        names = ", ".join(_source_words(o, e.source) for e in act.acted)
        text += (f". Action ({act.kind}): {what}: with {names} {act.how}, U "
                 f"{three(act.U_after)} {u}, below {below(needed)} {u}; agreed in a revised "
                 "plan, then re-test")
    else:
        rest = [e for e in act.effects if e.owner not in ACTIONABLE and e.share >= 0.05]
        whose = ", ".join(f"{_source_words(o, e.source)} {100 * e.share:.0f} %" for e in rest)
        owners = sorted({e.owner for e in rest})
        text += (f". {'No calibration' if lever else 'No set-up or calibration'} can decide "
                 f"it: with every source the laboratory can act on removed, U is still "
                 f"{three(act.floor)} {u}, above {below(needed)} {u}"
                 + (f"; the rest is the {' and '.join(owners)}'s own ({whose} of u²), which no "
                    "better instrument or artefact reduces" if rest else ""))
    if act.repeats is not None:
        from mtplan.plans.decisions import repeated_U

        text += (f". Repeats: {100 * act.random:.0f} % of u² is random from reading to "
                 f"reading; the average of {act.repeats} repeats gives U "
                 f"{three(repeated_U(act.U, act.random, act.repeats))} {u}")
    elif act.random > 0:
        text += (f". Repeats do not reach it: {100 * act.random:.0f} % of u² is random from "
                 "reading to reading, the rest stays in every repeat")
    return text


def actions(result, failed, open_) -> list:
    """One action per measurand that fails (``failed``) or has no pass (``open_``)."""
    from mtplan.plans.agreement import NO_INSTRUMENT
    from mtplan.plans.conditions import NO_CONDITION

    by_proc = {o.spec.name: (k, o) for k, o in enumerate(result.outcomes, start=1)}
    out = []
    for v in failed:
        k, o = by_proc[v.procedure]
        u = unit(v.unit)
        res = None if v.measured_u is None else 2 * v.measured_u
        target = 0.0 if v.lower is not None and v.upper is not None and v.lower < 0 < v.upper \
            else ((v.lower or 0) + (v.upper or 0)) / 2
        name = measurand_name(v.description, v.measurand)
        out.append(f"Adjust the {name[:1].lower()}{name[1:]}: measured "
                   f"{fmt(v.measured, res)} {u} against the tolerance "
                   f"{tolerance_text(v.lower, v.upper, v.unit)}; correct it by about "
                   f"{fmt(target - v.measured, res)} {u} (for a machine axis: its location in "
                   "the control's kinematic model or the mechanical alignment), then re-test "
                   f"test {k} ({o.spec.label}) and report the result as left.")
    for v in open_:
        k, o = by_proc[v.procedure]
        name = measurand_name(v.description, v.measurand)
        if v.verdict == NO_INSTRUMENT:
            out.append(f"{name}: no statement of conformity ({v.reason}). Action "
                       f"(calibration): calibrate {_instruments(result.study, o.spec.name)}, "
                       f"or have the customer agree in writing, and repeat test {k} "
                       f"({o.spec.label}); no set-up replaces a valid calibration.")
            continue
        if v.verdict == NO_CONDITION:
            out.append(f"{name}: no statement of conformity ({v.reason}). Action "
                       f"(conditions): repeat test {k} ({o.spec.label}) under the conditions "
                       "the plan agreed; no set-up replaces them.")
            continue
        if v.verdict.startswith("no decision: the readings"):
            out.append(f"{name}: the readings do not fit the model; find the cause (set-up, "
                       f"instrument, machine state) and repeat test {k} ({o.spec.label}).")
            continue
        needed = needed_u(v)
        if needed is None or v.verdict not in ("conditional pass", "conditional fail"):
            out.append(f"{name}: {v.verdict}" + (f" ({v.reason})" if v.reason else "")
                       + f"; repeat test {k} ({o.spec.label}).")
            continue
        lever = lever_for(o, v, needed)
        how = (f"{lever}; " if lever else "no swept or planned set-up of the study reaches "
               "it; ") + _budget_text(o, v, needed, result.study, lever)
        out.append(f"{name}: {v.verdict} (inside the guard band). A pass or a fail needs a "
                   f"predicted U below {below(needed)} {unit(v.unit)} (now "
                   f"{fmt_u(2 * v.u)}): {how}.")
    return out


def signing_title() -> str:
    """The heading of the plan's warnings, with the bounds they use."""
    from mtplan.plans.signing import PFR_BOUND, TUR_BOUND, ZONE_SHARE

    return (f"Before signing: agreed decisions unlikely to be reachable (PFR above "
            f"{100 * PFR_BOUND:.0f} %, TUR below {TUR_BOUND:g}, or an acceptance zone under "
            f"{100 * ZONE_SHARE:.0f} % of the tolerance)")


def signing_lines(result) -> list:
    """The plan's warnings before signing (:func:`~mtplan.plans.signing.signing_warnings`),
    one sentence per measurand with the set-up or rule that would fix it."""
    from mtplan.plans.signing import signing_warnings
    from mtplan.reports.document import setting_text
    from mtplan.reports.labels import percent

    by_label = {o.spec.label: o for o in result.outcomes}
    out = []
    for w in signing_warnings(result):
        o = by_label[w.label]
        u = unit(w.unit)
        broken = "; ".join(
            f"PFR {percent(x)} above {percent(b)}" if what == "PFR" else
            f"TUR {x:.1f} below {b:g}" if what == "TUR" else
            f"acceptance zone {100 * x:.0f} % of the tolerance, under {100 * b:.0f} %"
            for what, x, b in w.why)
        fixes = []
        if w.setup is not None:
            f, value, big_u, pfr, duration = w.setup
            fixes.append(f"the set-up with {setting_text(o, f, value)} (U {fmt_u(big_u)} {u}, "
                         f"PFR {percent(pfr)}, {duration_text(duration)})")
        if w.rule is not None:
            rule, gw, pfr, pfa = w.rule
            fixes.append(f"the rule {rule} (w {fmt_u(gw)} {u}: PFR {percent(pfr)}, the "
                         f"customer's PFA {percent(pfa)})")
        fix = (" or ".join(fixes) if fixes else
               "no swept set-up and no rule of the ladder does: agree another tolerance or "
               "accept that no decision is likely")
        out.append(f"{w.measurand} (test {list(by_label).index(w.label) + 1}): {broken}: a "
                   f"conforming machine is unlikely to pass. Would fix it: {fix}.")
    return out
