"""Everything the page shows for a design (:func:`evaluate`): the GUM law of propagation
(``mtplan linearize``) with its budget by source, the duration, the identifiability, the
trust of each number and the acceptance figures (``mtplan accept``) of the entered
tolerances."""

from __future__ import annotations

from mtplan._validate import InvalidInput
from mtplan.explore.info import anchor, help_text, measurand_rows
from mtplan.explore.prediction import TooCostly, guard_cost, identify_cached, predict
from mtplan.explore.size import size_problem
from mtplan.explore.state import (K, field_problems, json_setup, normalise, setup_of,
                                  source_fields)
from mtplan.explore.tolerances import acceptance_figures, input_problem
from mtplan.explore.trust import check, known_spot, resolution_steps, trust
from mtplan.models import get
from mtplan.models.protocol import fields_info

__all__ = ["evaluate", "checked", "withheld", "source_inputs", "budget_table"]


def evaluate(design: dict) -> dict:
    """Everything the page shows for a design, or the problems that stop it.

    Returns
    -------
    dict with ``design`` (normalised), ``ok``; when ok: ``measurands`` (name, unit, u,
    U, budget by source), ``duration_s``, ``identifiability``, ``method``; else
    ``field_errors`` (field -> message) and ``problems`` (messages of rules between
    fields).
    """
    design = normalise(design)
    proc = get(design["procedure"])
    out = {"design": design, "ok": False, "field_errors": {}, "problems": []}
    fe = field_problems(proc, design)
    if fe:
        out["field_errors"] = fe
        return out
    try:
        proc, setup = setup_of(design)
    except InvalidInput as exc:
        out["problems"] = list(exc.problems)
        infos = [f.name for f in fields_info(proc.Setup)]
        for msg in exc.problems:  # a rule between fields: beside each field it names
            for f in infos:
                if f"'{f}'" in msg or f" {f} " in f" {msg} ":
                    out["field_errors"].setdefault(f, msg)
        return out
    _, too_large = size_problem(proc, setup.as_dict())  # before anything is built
    if too_large:
        out.update(problems=[f"{too_large} Make the set-up smaller, or confirm it by Monte "
                             "Carlo."], refused="cost")
        return out
    if not proc.measurands(setup):
        out["problems"] = [f"This {proc.name} set-up gives no measurand to predict."]
        return out
    try:
        est, _ = proc.estimator(design["estimator"])
        guard_cost(proc, setup, est)
        pred = predict(proc, setup, est)
    except TooCostly as exc:
        out["problems"] = list(exc.problems)
        out["refused"] = "cost"
        out["measurand_names"] = measurand_rows(proc, setup)
        return out
    except InvalidInput as exc:
        out["problems"] = list(exc.problems)
        return out
    trusted = trust(pred["u"], known_spot(proc, setup, est), resolution_steps(proc, setup, est))
    inputs = source_inputs(proc, setup)
    ms = []
    for m in proc.measurands(setup):
        u = pred["u"][m.name]
        row = {"name": m.name, "unit": m.unit, "description": m.description, "u": u,
               "help": help_text(m.name, m.description), "anchor": anchor(m.name),
               "U": K * u, "budget": pred["budget"][m.name], **trusted[m.name],
               "budget_table": budget_table(pred["budget"][m.name], u, inputs)}
        if m.name in design["targets"]:
            try:
                row["target"] = float(design["targets"][m.name])
            except (TypeError, ValueError):
                row["target_error"] = (f"The target of {m.name} must be a number. Got "
                                       f"{design['targets'][m.name]!r} instead.")
        tol = design["tolerances"].get(m.name)
        if tol:  # a row's own mistakes always; decisions only on a checked number
            problem = input_problem(tol)
            row["acceptance"] = {"error": problem} if problem else \
                withheld(m.name, row) if row["trust"] != "ok" else \
                acceptance_figures(tol, u) if u > 0 else {
                    "error": f"u({m.name}) = 0: no acceptance figures without an uncertainty"}
        ms.append(row)
    out.update(ok=True, measurands=ms, duration_s=float(proc.duration(setup)),
               method=pred["method"], estimator=est,
               identifiability=identify_cached(proc, setup),
               setup=json_setup(setup))
    return out


def withheld(name: str, row: dict) -> dict:
    """Why a toleranced measurand gets no TUR, risks, zones or verdict: its u is not a
    checked number (failed, being checked, or not checked), in words, with what to do."""
    state = {"no": "failed its check", "unchecked": "is not checked yet" if row.get("pending")
             else "is not checked"}[row["trust"]]
    return {"error": f"no decision: u({name}) {state}: {row['todo']}", "withheld": row["trust"]}


def checked(design: dict) -> dict:
    """:func:`evaluate` after the spot check of the design's numbers (:func:`check`): what
    the page shows once the check is made, failed or too costly included. A design the
    check refuses (a bad field, beyond the live cost) answers as :func:`evaluate` does."""
    try:
        check(design)
    except InvalidInput:
        pass  # evaluate says why, beside the fields or in its problems
    return evaluate(design)


def source_inputs(proc, setup) -> dict:
    """Source -> (its size, the unit of the field that states it): the input u of the
    budget table (a source of many elements has this u for each)."""
    out = {}
    units = {f.name: f.unit for f in fields_info(proc.Setup)}
    for source, field in source_fields(proc).items():
        v = getattr(setup, field, None)
        if isinstance(v, int | float) and not isinstance(v, bool):
            out[source] = (float(v), units.get(field) or "")
    return out


def budget_table(budget: dict, u: float, inputs: dict) -> list:
    """GUM Workbench's budget rows of one measurand, largest first: the source, its input
    u and unit, the sensitivity coefficient c = contribution / input u (the source's
    combined effect per unit of its size), the contribution (u of the measurand from that
    source alone) and its share of u^2."""
    rows = []
    for source, contribution in budget.items():
        x, unit = inputs.get(source, (None, ""))
        rows.append({"source": source, "input_u": x, "input_unit": unit,
                     "c": contribution / x if x else None, "contribution": contribution,
                     "share": contribution**2 / u**2 if u > 0 else None})
    return sorted(rows, key=lambda r: -r["contribution"])
