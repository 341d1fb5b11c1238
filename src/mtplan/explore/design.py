"""The designer's state and what it shows: pure functions, no web framework.

A *design* is a plain JSON-ready dict, the whole state of one browser tab (it travels in
the tab's URL, so two tabs never share it and a link reopens it)::

    {"procedure": "rotary_axis",
     "setup": {"positions": "8", "incline_deg": "25"},     # fields as typed (strings)
     "off": ["flatness"],                                  # error sources switched off
     "estimator": "patent",
     "tolerances": {"EX0C": {"lower": -10, "upper": 10, "prior": "normal:0,4",
                             "rule": "iso14253"}},
     "targets": {"EX0C": 2.0},                             # U (k = 2) targets
     "vary": {"positions": "4,6,8,12"},                    # ranges for the planner
     "lever": "incline_deg",                               # the field last moved
     "seed": 0, "trials": 10000}

An error source is sized by its set-up field (``probe_noise`` by ``probe_noise_um``); a
source switched off is that field at 0, so the exported study states it the same way.

:func:`evaluate` gives the live numbers: the GUM law of propagation (``mtplan linearize``)
with its budget by source, the duration, the identifiability and the acceptance figures
(``mtplan accept``) for the entered tolerances. :func:`sensitivity` gives U over a lever's
range. :func:`study_toml` and :func:`design_from_study` write and read a study file that
``mtplan report`` accepts.
"""

from __future__ import annotations

import functools
import json
import math
import tomllib

import numpy as np

from mtplan._parallel import one_blas_thread
from mtplan._validate import InvalidInput
from mtplan.models import get, registry
from mtplan.models.protocol import UNIT_SUFFIXES, fields_info, make, parse_fields

__all__ = ["K", "procedures_info", "procedure_info", "normalise", "setup_of", "evaluate",
           "sensitivity", "study_toml", "design_from_study", "source_fields", "lever_values",
           "plan_vary"]

#: coverage factor of the U the designer shows and its targets are stated in
K = 2.0
_RULES = ("simple", "iso14253", "dobbert", "guard:", "target-pfa:")


# --------------------------------------------------------------------------- metadata
def source_fields(proc) -> dict:
    """Error source name -> the set-up field that sizes it (``probe_noise`` ->
    ``probe_noise_um``): the field is the source's name followed by a unit suffix."""
    names = list(proc.sources(proc.Setup()))
    out = {}
    for f in fields_info(proc.Setup):
        for s in names:
            rest = f["name"][len(s) + 1:]
            if f["name"].startswith(s + "_") and rest in UNIT_SUFFIXES:
                out[s] = f["name"]
    return out


def _json_value(v):
    if isinstance(v, tuple):
        return list(v)
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def procedure_info(name: str) -> dict:
    """Everything the page needs to draw one procedure's controls."""
    proc = get(name)
    setup = proc.Setup()
    by_field = {v: k for k, v in source_fields(proc).items()}
    sources = proc.sources(setup)
    fields = []
    for f in fields_info(proc.Setup):
        kind = f["kind"]
        kind = {float: "float", int: "int", bool: "bool", str: "str"}.get(kind, "tuple")
        fields.append({
            "name": f["name"], "kind": kind, "unit": f["unit"], "doc": f["doc"] or "",
            "default": _json_value(f["default"]), "low": f["low"], "high": f["high"],
            "low_open": f["low_open"], "high_open": f["high_open"],
            "choices": list(f["choices"]) if f["choices"] else None,
            "optional": f["optional"], "min_len": f["min_len"],
            "source": by_field.get(f["name"]),
            "source_doc": sources[by_field[f["name"]]].description if f["name"] in by_field
            else "",
            "lever": f["name"] in proc.levers,
        })
    return {
        "name": proc.name, "title": proc.title, "description": proc.description,
        "estimators": list(proc.estimators), "default_estimator": proc.default_estimator,
        "measurands": [{"name": m.name, "unit": m.unit, "description": m.description}
                       for m in proc.measurands(setup)],
        "fields": fields,
    }


def procedures_info() -> list:
    """Name and title of every registered procedure."""
    return [{"name": p.name, "title": p.title} for p in registry().values()]


# --------------------------------------------------------------------------- state
def normalise(design: dict | None) -> dict:
    """A design with every key present (defaults filled), unknown keys dropped."""
    d = dict(design or {})
    name = d.get("procedure") or "rotary_axis"
    proc = get(name)
    seed = d.get("seed", 0)
    trials = d.get("trials", 10_000)
    return {
        "procedure": proc.name,
        "setup": {str(k): ("" if v is None else str(v)) for k, v in (d.get("setup") or {}).items()},
        "off": [str(s) for s in d.get("off") or []],
        "estimator": d.get("estimator") or proc.default_estimator,
        "tolerances": {str(k): dict(v) for k, v in (d.get("tolerances") or {}).items()
                       if isinstance(v, dict)},
        "targets": {str(k): v for k, v in (d.get("targets") or {}).items()
                    if v not in (None, "")},
        "vary": {str(k): str(v) for k, v in (d.get("vary") or {}).items() if str(v).strip()},
        "lever": d.get("lever") or (proc.levers[0] if proc.levers else None),
        "seed": seed,
        "trials": trials,
    }


def _values(proc, design) -> dict:
    """The set-up values the design states, with switched-off sources at 0."""
    values = {k: v for k, v in design["setup"].items() if str(v).strip() != ""}
    fields = source_fields(proc)
    for s in design["off"]:
        if s in fields:
            values[fields[s]] = "0"
    return values


def field_problems(proc, design) -> dict:
    """Field name -> the procedure's own message for each value it refuses alone."""
    infos = {f["name"] for f in fields_info(proc.Setup)}
    out = {}
    for key, value in _values(proc, design).items():
        if key not in infos:
            out[key] = f"{proc.name} has no field {key!r}"
            continue
        try:
            parse_fields(proc.Setup, {key: value}, owner=proc.name)
        except InvalidInput as exc:
            out[key] = " ".join(exc.problems)
    return out


def setup_of(design):
    """(procedure, Setup) of a design; InvalidInput with the procedure's messages."""
    proc = get(design["procedure"])
    return proc, make(proc.Setup, _values(proc, design), owner=proc.name)


# --------------------------------------------------------------------------- prediction
@functools.lru_cache(maxsize=512)
def _predict_cached(name: str, setup_key: str, estimator: str):
    proc = get(name)
    setup = make(proc.Setup, json.loads(setup_key), owner=proc.name)
    with one_blas_thread():  # small products: threads only wait on each other
        return _predict(proc, setup, estimator)


def _predict(proc, setup, estimator) -> dict:
    """u per measurand [display unit] and its budget by source (std per source): the
    first-order service's numbers (those of ``mtplan linearize`` and the planner)."""
    from mtplan.evaluation.first_order import first_order

    fo = first_order(proc, setup, estimator=estimator)
    return {"u": fo.u(), "budget": fo.budget_std(),
            "method": "GUM law of propagation (mtplan linearize)"}


def _setup_key(setup) -> str:
    return json.dumps(setup.as_dict(), sort_keys=True)


def predict(proc, setup, estimator) -> dict:
    """Cached :func:`_predict` (a set-up seen before answers at once)."""
    return _predict_cached(proc.name, _setup_key(setup), estimator)


@functools.lru_cache(maxsize=256)
def _identify_cached(name: str, geometry_key: str) -> dict:
    proc = get(name)
    setup = make(proc.Setup, json.loads(geometry_key), owner=proc.name)
    with one_blas_thread():
        return identify(proc, setup)


def _geometry_key(proc, setup) -> str:
    """The set-up without its error sources' sizes: identifiability is a property of the
    noise-free readings, so resizing a source reuses it."""
    sized = set(source_fields(proc).values())
    return json.dumps({k: v for k, v in setup.as_dict().items() if k not in sized},
                      sort_keys=True)


def identify(proc, setup) -> dict:
    """Rank, condition number, the valuation figure O1 and the measurands not determined.

    The readings' sensitivity to the measurands (or to the model's parameters, with the
    measurands as functions of them) through :mod:`mtplan.plans.identifiability`: a
    measurand is undetermined when it moves along a direction no reading sees.
    """
    from mtplan.plans.identifiability import identifiability
    from mtplan.plans.planner import readings_jacobian

    own = proc.capabilities.identifiability_report
    names = [m.name for m in proc.measurands(setup)]
    if own is not None:
        rep = own(setup)
        if "jacobian" in rep:
            r = identifiability(rep["jacobian"], scale=rep["scale"], names=rep["names"],
                                tol=rep["rank_tol"], n_poses=int(rep["readings"]),
                                functions=rep["functions"])
            undetermined = [k for k, v in r.determined.items() if not v]
            return _ident_dict(r, float(rep["condition_number"]), undetermined,
                               "the model's error coefficients")
    J, cols = readings_jacobian(proc, setup)
    r = identifiability(J, names=cols)
    undetermined = []
    if r.null_space.size:
        for j, c in enumerate(cols):
            if c in names and np.any(np.abs(r.null_space[j]) > 1e-6):
                undetermined.append(c)
    what = "the measurands" if set(cols) <= set(names) else "the model's parameters"
    return _ident_dict(r, r.condition_number, undetermined, what)


def _ident_dict(r, cond, undetermined, what) -> dict:
    return {"rank": int(r.rank), "n_params": int(r.n_params), "parameters": what,
            "condition": cond if math.isfinite(cond) else None,
            "valuation": float(r.observability["O1"]),
            "inverse_condition": float(r.observability["O2"]),
            "undetermined": list(undetermined), "null": list(r.null_combinations)}


def _acceptance(tol: dict, u: float) -> dict:
    from mtplan.plans.acceptance import plan_acceptance

    def num(key):
        v = tol.get(key)
        if v is None or (isinstance(v, str) and not v.strip()):
            return None
        return float(v)

    try:
        lower, upper = num("lower"), num("upper")
    except (TypeError, ValueError):
        return {"error": f"The tolerance limits must be numbers. Got {tol.get('lower')!r} "
                         f"and {tol.get('upper')!r} instead."}
    if lower is None and upper is None:
        return {}
    prior = (tol.get("prior") or "").strip() or None
    rule = (tol.get("rule") or "simple").strip()
    try:
        r = plan_acceptance(lower, upper, u, prior=prior, rule=rule)
    except InvalidInput as exc:
        return {"error": " ".join(exc.problems)}
    out = r.to_dict()
    out["guard_band"] = r.guard_band
    out["rule"] = rule
    out["prior"] = prior
    return out


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
        infos = [f["name"] for f in fields_info(proc.Setup)]
        for msg in exc.problems:  # a rule between fields: beside each field it names
            for f in infos:
                if f"'{f}'" in msg or f" {f} " in f" {msg} ":
                    out["field_errors"].setdefault(f, msg)
        return out
    try:
        est, _ = proc.estimator(design["estimator"])
        pred = predict(proc, setup, est)
    except InvalidInput as exc:
        out["problems"] = list(exc.problems)
        return out
    ms = []
    for m in proc.measurands(setup):
        u = pred["u"][m.name]
        row = {"name": m.name, "unit": m.unit, "description": m.description, "u": u,
               "U": K * u, "budget": pred["budget"][m.name]}
        if m.name in design["targets"]:
            try:
                row["target"] = float(design["targets"][m.name])
            except (TypeError, ValueError):
                row["target_error"] = (f"The target of {m.name} must be a number. Got "
                                       f"{design['targets'][m.name]!r} instead.")
        tol = design["tolerances"].get(m.name)
        if tol:
            row["acceptance"] = _acceptance(tol, u) if u > 0 else {
                "error": f"u({m.name}) = 0: no acceptance figures without an uncertainty"}
        ms.append(row)
    out.update(ok=True, measurands=ms, duration_s=float(proc.duration(setup)),
               method=pred["method"], estimator=est,
               identifiability=_identify_cached(proc.name, _geometry_key(proc, setup)),
               setup=_json_setup(setup))
    return out


def _json_setup(setup) -> dict:
    return {k: _json_value(v) for k, v in setup.as_dict().items()}


# --------------------------------------------------------------------------- sensitivity
def lever_values(proc, setup, field: str, n: int = 9) -> list:
    """Values of a numeric field over its range around the current value (n at most)."""
    info = next(f for f in fields_info(proc.Setup) if f["name"] == field)
    v = getattr(setup, field)
    kind = info["kind"]
    if kind not in (int, float) or v is None:
        raise InvalidInput([f"The lever {field!r} of {proc.name} is not a number; a "
                            "sensitivity needs a numeric field."])
    lo, hi = info["low"], info["high"]
    v = float(v)
    a = lo if lo is not None else (0.0 if v >= 0 else 4 * v)
    b = hi if hi is not None else max(4 * abs(v), 1.0)
    # keep the plot around the current value: at most x0.25 .. x4 on ratio-scale fields
    if lo is not None and lo >= 0 and v > 0:
        a, b = max(a, v / 4), min(b, v * 4)
    if info["low_open"] and a == lo:
        a = a + (b - a) / (4 * n)
    if info["high_open"] and b == hi:
        b = b - (b - a) / (4 * n)
    if kind is int:
        vals = sorted(set(int(round(x)) for x in np.linspace(a, b, n)) | {int(v)})
    else:
        vals = sorted(set(float(x) for x in np.linspace(a, b, n)) | {v})
    return vals


def sensitivity(design: dict, field: str | None = None, n: int = 9, *, stop=None) -> dict:
    """U (k = 2) of every measurand over a lever's range, the current value marked.

    `stop`, a callable, is asked before each point: when it says True (a newer change has
    come from the same page) the curve is given up, ``superseded`` True, so that it never
    holds up the numbers of that change.
    """
    design = normalise(design)
    proc, setup = setup_of(design)
    field = field or design["lever"]
    est, _ = proc.estimator(design["estimator"])
    xs, curves = [], {}
    for x in lever_values(proc, setup, field, n):
        if stop is not None and stop():
            return {"field": field, "superseded": True}
        try:
            s = setup.replace(**{field: x})
        except InvalidInput:
            continue  # a value the procedure refuses with the other fields: no point
        pred = predict(proc, s, est)
        xs.append(x)
        for name, u in pred["u"].items():
            curves.setdefault(name, []).append(K * u)
    info = next(f for f in fields_info(proc.Setup) if f["name"] == field)
    return {"field": field, "unit": info["unit"], "x": xs, "U": curves,
            "current": _json_value(getattr(setup, field)),
            "units": {m.name: m.unit for m in proc.measurands(setup)},
            "targets": {k: v for k, v in design["targets"].items()}}


# --------------------------------------------------------------------------- studies
def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return json.dumps(str(v))  # a TOML basic string is a JSON string


def _inline(d: dict) -> str:
    return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in d.items()) + " }"


def plan_vary(proc, design) -> dict:
    """The planner's ranges of a design, each parsed into its field's kind."""
    out = {}
    for field, text in design["vary"].items():
        parts = [s for s in (text.split("|") if "|" in text else text.split(",")) if s.strip()]
        out[field] = [_json_value(parse_fields(proc.Setup, {field: p}, owner=proc.name)[field])
                      for p in parts]
    return out


def study_toml(design: dict, *, title: str | None = None) -> str:
    """The design as a study file that ``mtplan report`` accepts.

    Every set-up field is stated (so the report's set-up is the page's whatever the
    defaults become), the estimator, the planner's targets and ranges, and one
    acceptance table per toleranced measurand. Raises InvalidInput for a design the
    procedure refuses.
    """
    design = normalise(design)
    proc, setup = setup_of(design)
    est, _ = proc.estimator(design["estimator"])
    values = {k: _json_value(v) for k, v in setup.as_dict().items() if v is not None}
    lines = [
        "# A set-up designed in `mtplan explore`; `mtplan report` computes and writes it.",
        f"title = {_toml_value(title or f'Test plan: {proc.title}')}",
        f"seed = {int(design['seed'])}",
        f"trials = {int(design['trials'])}",
        "",
        "[[procedure]]",
        f"name = {_toml_value(proc.name)}",
        f"label = {_toml_value(proc.title)}",
        f"estimators = {_toml_value([est])}",
        f"setup = {_inline(values)}",
    ]
    targets = {}
    for k, v in design["targets"].items():
        try:
            targets[k] = float(v)  # bounds on U = k u, with k stated below
        except (TypeError, ValueError):
            continue
    vary = plan_vary(proc, design) if design["vary"] else {}
    if targets and vary:
        lines += ["", "  [procedure.plan]", f"  targets = {_inline(targets)}",
                  f"  vary = {_inline(vary)}", f"  k = {K!r}"]
    for name, tol in design["tolerances"].items():
        entry = {"measurand": name}
        for key in ("lower", "upper"):
            if tol.get(key) not in (None, ""):
                entry[key] = float(tol[key])
        if "lower" not in entry and "upper" not in entry:
            continue
        if (tol.get("prior") or "").strip():
            entry["prior"] = tol["prior"].strip()
        entry["rule"] = (tol.get("rule") or "simple").strip()
        lines += ["", "  [[procedure.acceptance]]"]
        lines += [f"  {k} = {_toml_value(v)}" for k, v in entry.items()]
    return "\n".join(lines) + "\n"


def _text(v) -> str:
    """A set-up value as the page's box shows it (25.0 -> '25', a list comma-separated)."""
    if isinstance(v, list | tuple):
        return ",".join(_text(x) for x in v)
    if isinstance(v, float):
        return format(v, ".15g")
    return str(v)


def design_from_study(text: str, procedure: str | None = None) -> dict:
    """A design from a study file's text (its first procedure, or the one named).

    Raises InvalidInput when the text is not TOML, names no procedure, or holds a set-up
    the procedure refuses.
    """
    from mtplan.plans.study import load_study

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InvalidInput([f"The study is not valid TOML: {exc}"]) from None
    if "procedure" in data and "setup" in data and not isinstance(data["procedure"], list):
        data = {"procedure": [{"name": data["procedure"], "setup": data["setup"]}],
                **{k: v for k, v in data.items() if k in ("seed", "trials")}}
    entries = data.get("procedure") or []
    if isinstance(entries, dict):
        entries = [entries]
    if procedure is not None:
        entries = [e for e in entries if e.get("name") == procedure] or entries
    if not entries:
        raise InvalidInput(["The study names no [[procedure]]."])
    e = {k: v for k, v in entries[0].items() if k != "readings"}  # set-ups, not measurements
    study = load_study({**{k: v for k, v in data.items() if k != "procedure"},
                        "title": data.get("title", "study"), "procedure": [e]})
    ps = study.procedures[0]
    design = {
        "procedure": ps.name,
        "setup": {k: _text(v) for k, v in ps.setup.as_dict().items() if v is not None},
        "estimator": ps.estimators[0],
        "tolerances": {a["measurand"]: {k: a.get(k) for k in ("lower", "upper", "prior", "rule")
                                        if a.get(k) is not None}
                       for a in ps.acceptance},
        "seed": study.seed,
        "trials": ps.trials or study.trials or 10_000,
    }
    for source, f in source_fields(get(ps.name)).items():  # a source at 0 is switched off
        if design["setup"].get(f) in ("0", "0.0"):
            design.setdefault("off", []).append(source)
            del design["setup"][f]  # on again at its default size
    if ps.plan:
        k = float(ps.plan.get("k", 1.0))
        design["targets"] = {m: float(v) * K / k for m, v in ps.plan.get("targets", {}).items()}
        design["vary"] = {f: ",".join(str(x) for x in vs)
                          for f, vs in ps.plan.get("vary", {}).items()}
    return normalise(design)
