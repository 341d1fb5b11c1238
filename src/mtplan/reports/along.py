"""The report's errors along the travel and the machine after compensation (predicted).

Per test whose readings state errors along the travel (geometry21's ``EXX@-50``, the
study's ``[procedure.readings] along`` or the procedure's default grid): a figure of each
error against position with its pointwise and simultaneous 95 % bands, the tolerance and
the residual predicted after compensation. Per toleranced measurand that a correction
corrects: the residual's 95 % interval, a column of the results table. Per test measured
again after an adjustment: the as-left values against that prediction. Formatting only: the
numbers come from the study (:class:`~mtplan.compensation.predicted.Predicted`, the
measured result's ``simultaneous`` band).
"""

from __future__ import annotations

import math

import numpy as np

from mtplan.reports.labels import fmt, fmt_u, unit
from mtplan.reports.model import Figure, Section, Table
from mtplan.reports.wording import measurand_name

__all__ = ["along_names", "residual_interval", "residual_text", "along_panels", "along_section", "RESIDUAL_NOTE"]

#: the note under the results table's column
RESIDUAL_NOTE = ("After compensation (predicted): the 95 % interval of the error that "
                 "remains once a compensation removes the measured value (the neutral table "
                 "of 'mtplan compensate', to full precision), from the measurement's "
                 "uncertainty and, where the procedure states one, what the test cannot see "
                 "(the machine's path deviation beyond the error polynomials), less the part "
                 "of it the estimate took up, which the table removes too; '-': the test "
                 "states no correction of it.")


def along_names(measured) -> set:
    """The measurands of a measured result that are points of an error along the travel
    (shown in the figure, not in the tables)."""
    from mtplan.evaluation.along import curves

    names = [m.name for m in measured.measurands]
    return {names[i] for idx, _ in curves(names).values() for i in idx}


def _predicted(o):
    from mtplan.compensation.predicted import Predicted

    p = getattr(o, "compensation", None)
    return p if isinstance(p, Predicted) else None


def residual_interval(o, measurand: str) -> tuple | None:
    """(low, high) of the residual's 95 % interval after compensating `measurand` of test
    ``o``, or None where no correction applies to it."""
    p = _predicted(o)
    r = None if p is None else p.of(measurand)
    return None if r is None else (r[0], r[1])


def residual_text(o, v) -> str:
    """"[-1.0, 1.0]": the residual's 95 % interval after compensating measurand ``v``
    (rounded as its U achieved), "-" where no correction applies to it."""
    r = residual_interval(o, v.measurand)
    if r is None or getattr(v, "measured", 0.0) is None:  # none, or not determinable
        return "-"
    res = None if v.measured_u is None else 2 * v.measured_u
    return f"[{fmt(r[0], res)}, {fmt(r[1], res)}]"


def along_panels(o) -> list:
    """The figure's panels (:func:`~mtplan.reports.figures.along_figure`) of test ``o``:
    one per error function the correction tabulates along an axis, [] where none."""
    p = _predicted(o)
    m = o.measured
    if p is None or m is None:
        return []
    corr, res = p.correction, p.residual
    tolerance = {}
    for v in o.verdicts:
        i = p.corrects.get(v.measurand)
        if i is not None and corr.arguments[i]:
            tolerance[corr.names[i].split("@")[0]] = (v.lower, v.upper)
    groups: dict = {}
    for i, arg in enumerate(corr.arguments):
        if arg:
            groups.setdefault(corr.names[i].split("@")[0], []).append(i)
    sim = getattr(m, "simultaneous", {}) or {}
    panels = []
    for function, idx in groups.items():
        idx = sorted(idx, key=lambda i: corr.arguments[i][1])
        value = corr.value[idx]
        interval = corr.interval[idx]
        low = np.where(np.isfinite(interval[:, 0]), interval[:, 0], value)
        high = np.where(np.isfinite(interval[:, 1]), interval[:, 1], value)
        band = np.array([sim.get(corr.names[i], (v, v)) for i, v in zip(idx, value)])
        rband = np.array([p.simultaneous.get(corr.names[i], (lo, hi)) for i, lo, hi in
                          zip(idx, res.low[idx], res.high[idx])])
        panels.append({
            "function": function, "unit": corr.units[idx[0]],
            "row": "XYZ".index(corr.arguments[idx[0]][0]),
            "position": np.array([corr.arguments[i][1] for i in idx]), "value": value,
            "low": low, "high": high, "sim_low": band[:, 0], "sim_high": band[:, 1],
            "extrapolated": np.array([corr.extrapolated[i] for i in idx]),
            "tolerance": tolerance.get(function), "res_low": res.low[idx],
            "res_high": res.high[idx], "res_sim_low": rband[:, 0], "res_sim_high": rband[:, 1]})
    return panels


def _factor_range(factors) -> str:
    values = [c for c in factors.values() if math.isfinite(c)]
    if not values:
        return ""
    lo, hi = min(values), max(values)
    return f"{lo:.2f}" if abs(hi - lo) < 0.005 else f"{lo:.2f} to {hi:.2f}"


def _as_left_rows(k, o) -> list:
    """The as-left values of the corrected toleranced measurands against the residual
    predicted after compensation: E_n = (as left - predicted centre) / sqrt(U_pred^2 +
    U_left^2), U_pred the half width of the predicted 95 % interval."""
    p = _predicted(o)
    if p is None or o.as_left is None:
        return []
    rows = []
    for v in o.as_left_verdicts:
        r = p.of(v.measurand)
        if r is None or v.measured is None or v.measured_u is None:
            continue
        centre, half = (r[0] + r[1]) / 2, (r[1] - r[0]) / 2
        U = 2 * v.measured_u
        en = (v.measured - centre) / math.hypot(half, U) if math.hypot(half, U) > 0 else math.nan
        rows.append([str(k), measurand_name(v.description, v.measurand), unit(v.unit),
                     f"[{fmt(r[0], U)}, {fmt(r[1], U)}]", f"{fmt(v.measured, U)} ± {fmt_u(U)}",
                     f"{en:.2f}", "consistent" if abs(en) <= 1 else "NOT consistent"])
    return rows


def along_section(result) -> Section | None:
    """The section of the errors along the travel and the as-left comparison, or None
    where no test has either."""
    from mtplan.reports import figures as figs

    blocks = []
    for k, o in enumerate(result.outcomes, start=1):
        panels = along_panels(o)
        if not panels:
            continue
        p = _predicted(o)
        m = o.measured
        factors = (getattr(m, "sections", {}) or {}).get("simultaneous", {}).get("factor", {})
        outside = any(bool(np.any(q["extrapolated"])) for q in panels)
        blocks.append(
            f"Test {k} ({o.spec.label}): each error function at {len(panels[0]['position'])} "
            f"positions along its axis, as measured ({m.estimator} estimator), with its "
            "pointwise 95 % band (each point alone) and its simultaneous 95 % band (the "
            "whole curve at once: the band to use where a decision needs the whole curve, "
            "such as its largest value over the travel). The simultaneous band is the "
            "sup-t band: each point's interval widened about its value by c / 1.96, c the "
            "95 % quantile of the largest |z| over the curve's points for z normal with "
            "the points' correlation from the result's covariance"
            + (f" (here c = {_factor_range(factors)})" if factors else "") + ". Every "
            "function is zero at the machine coordinates' zero by the definition of its "
            "reference (ISO 230-1). The residual after compensation (predicted) is what "
            "remains once the measured curve is removed by a compensation table (its "
            "points as 'mtplan compensate' writes them); it includes what the test cannot "
            "see (" + (p.correction.unseen[0] if p.correction.unseen and
                       p.correction.unseen[0] else "none stated")
            + ("), less the part of it that the estimate took up (the table removes that "
               "part too: the residual's covariance with the estimate's error), with the "
               "points' joint covariance in its simultaneous band"
               if p.correction.unseen_covariance.size else
               "), taken as independent from point to point in its simultaneous band")
            + (f" (c = {_factor_range(p.factor)})" if p.factor else "") + "."
            + (" Hollow markers: outside the measured travel (extrapolated)." if outside
               else ""))
        blocks.append(Figure(f"Test {k}: errors along the travel (blue: measured, pointwise "
                             "and simultaneous 95 % bands), the tolerance (dashed) where one "
                             "is given, and the residual after compensation (predicted, "
                             "orange: pointwise band; dotted: simultaneous band).",
                             figs.along_figure(panels)))
    left = [row for k, o in enumerate(result.outcomes, start=1) for row in _as_left_rows(k, o)]
    if left:
        blocks.append(Table("As left against the residual predicted after compensation: "
                            "each corrected toleranced measurand measured again after the "
                            "adjustment (value ± U, k = 2) and the 95 % interval predicted "
                            "for it; E_n = (as left - predicted centre) / sqrt(U_pred^2 + "
                            "U^2), U_pred the predicted interval's half width: consistent "
                            "where |E_n| <= 1. It holds where the adjustment applied the "
                            "correction as the neutral table states it.",
                            ["test", "measurand", "unit", "predicted after compensation",
                             "as left", "E_n", "agreement"], left, grow=1, size=7.0,
                            whole=(6,)))
    if not blocks:
        return None
    return Section("Errors along the travel and after compensation (predicted)",
                   blocks=blocks, anchor="along")
