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
import io
import json
import math
import re
import tomllib
from pathlib import Path

import numpy as np

from mtplan._parallel import one_blas_thread
from mtplan._validate import InvalidInput
from mtplan.models import get, registry
from mtplan.models.protocol import UNIT_SUFFIXES, fields_info, file_fields, make, parse_fields

__all__ = ["K", "procedures_info", "procedure_info", "normalise", "setup_of", "evaluate",
           "sensitivity", "study_toml", "design_from_study", "source_fields", "lever_values",
           "glossary", "explain", "sliders",
           "plan_vary", "whole", "check", "trust", "spot_check", "prediction_cost",
           "guard_cost", "TooCostly"]

#: coverage factor of the U the designer shows and its targets are stated in
K = 2.0
_RULES = ("simple", "iso14253", "dobbert", "guard:", "target-pfa:")


# --------------------------------------------------------------------------- metadata
def source_fields(proc) -> dict:
    """Error source name -> the set-up field that sizes it (``probe_noise`` ->
    ``probe_noise_um``): the field is the source's name followed by a unit suffix."""
    return dict(_source_fields(proc.name))


@functools.lru_cache(maxsize=64)
def _source_fields(name: str) -> tuple:  # asked several times a change: once per procedure
    proc = get(name)
    names = list(proc.sources(proc.Setup()))
    out = {}
    for f in fields_info(proc.Setup):
        for s in names:
            rest = f.name[len(s) + 1:]
            if f.name.startswith(s + "_") and rest in UNIT_SUFFIXES:
                out[s] = f.name
    return tuple(out.items())


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
        if f.file:  # a path on this machine: never a browser's (_refuse_files)
            continue
        kind = f.kind
        kind = {float: "float", int: "int", bool: "bool", str: "str"}.get(kind, "tuple")
        fields.append({
            "name": f.name, "kind": kind, "unit": f.unit, "doc": f.doc or "",
            "default": _json_value(f.default), "low": f.low, "high": f.high,
            "low_open": f.low_open, "high_open": f.high_open,
            "choices": list(f.choices) if f.choices else None,
            "optional": f.optional, "min_len": f.min_len,
            "source": by_field.get(f.name),
            "source_doc": sources[by_field[f.name]].description if f.name in by_field
            else "",
            "lever": f.name in proc.levers,
        })
        fields[-1]["slider"] = _slider(fields[-1])
    return {
        "name": proc.name, "title": proc.title, "description": proc.description,
        "estimators": list(proc.estimators), "default_estimator": proc.default_estimator,
        "estimator_help": {k: e.description for k, e in proc.estimators.items()},
        "measurands": _measurand_rows(proc, setup),
        "fields": fields,
    }


def _slider(f: dict) -> bool:
    """Whether the page draws a field as a slider: a bounded number whose range is of the
    order of its default (not 0 .. 100000 for a 1 um noise)."""
    if f["kind"] not in ("int", "float") or f["default"] is None:
        return False
    lo, hi = f["low"], f["high"]
    return lo is not None and hi is not None and math.isfinite(lo) and math.isfinite(hi) \
        and hi - lo <= 50 * max(abs(f["default"]), 1)


def sliders(name: str) -> list:
    """The fields of a procedure that the page draws as sliders."""
    return [f for f in procedure_info(name)["fields"] if f["slider"]]


#: the documentation's glossary (docs/glossary.md), packaged beside this module so that an
#: installed mtplan explains its codes as a checkout does
GLOSSARY = Path(__file__).with_name("glossary.md")


@functools.lru_cache(maxsize=1)
def glossary() -> list:
    """The rows of the documentation's glossary (``docs/glossary.md``, packaged with the
    designer): ``{"names": [...], "meaning": text, "section": heading}``. The page explains
    its codes and terms (EX0C, O1, TUR, PFR) with them."""
    text = GLOSSARY.read_text(encoding="utf-8")
    out, section = [], ""
    for line in text.splitlines():
        if line.startswith("## "):
            section = line[3:].strip()
        cells = [c.strip() for c in line.strip().strip("|").split("|")] if \
            line.startswith("|") else []
        if len(cells) != 2 or set(cells[0]) <= set("-") or cells[1] == "meaning":
            continue
        names = [n.strip(" `") for n in re.split(r",|\.\.\.|=", cells[0]) if n.strip(" `")]
        names += [n.split(": ", 1)[1] for n in names if ": " in n]  # "decision rule: simple"
        label = cells[0].replace("`", "")
        out.append({"names": names, "label": label, "meaning": cells[1].replace("`", ""),
                    "section": section, "anchor": "help-" + re.sub(r"[^A-Za-z0-9]+", "-",
                                                                   label).strip("-")})
    return out


@functools.lru_cache(maxsize=2048)
def explain(code: str) -> dict | None:
    """The glossary's row for a code or term shown on the page, or None.

    A row's name matches itself and its placeholders: ``_k`` any number (``origin_x_k``
    is ``origin_x_2``), and ``:R`` or ``:P`` after a colon any value (``guard:R`` is
    ``guard:1``).
    """
    for row in glossary():
        for name in row["names"]:
            pattern = re.escape(name)
            pattern = re.sub(r"_k$", r"_\\d+", pattern)
            pattern = re.sub(r":[A-Z]$", r":.+", pattern)
            if re.fullmatch(pattern, code):
                return row
    return None


def _help(code: str, description: str = "") -> str:
    """The page's help for a code: the glossary's words, then the procedure's own."""
    row = explain(code)
    words = f"{row['label']}: {row['meaning']}" if row else ""
    return ". ".join(t for t in (words, description) if t)


def procedures_info() -> list:
    """Name and title of every registered procedure."""
    return [{"name": p.name, "title": p.title} for p in registry().values()]


# --------------------------------------------------------------------------- state
def whole(value, name: str, *, low: int = 0, high: int | None = None) -> int:
    """An integer from a number or its text, scientific notation included ('1e6'), in
    [low, high]; InvalidInput naming `name` otherwise."""
    allowed = f"a whole number >= {low}" + (f" and <= {high}" if high is not None else "")
    try:
        x = float(str(value).strip()) if not isinstance(value, bool) else math.nan
    except ValueError:
        x = math.nan
    if not math.isfinite(x) or x != int(x) or x < low or (high is not None and x > high):
        raise InvalidInput([f"The '{name}' must be {allowed}. Got {str(value)[:40]!r} instead."])
    return int(x)


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
        "estimator": d.get("estimator") or proc.estimator(None)[0],  # the command line's
        "tolerances": {str(k): dict(v) for k, v in (d.get("tolerances") or {}).items()
                       if isinstance(v, dict)},
        "targets": {str(k): v for k, v in (d.get("targets") or {}).items()
                    if v not in (None, "")},
        "vary": {str(k): str(v) for k, v in (d.get("vary") or {}).items() if str(v).strip()},
        "lever": d.get("lever") or (proc.levers[0] if proc.levers else None),
        "seed": seed,
        "trials": trials,
    }


def _refuse_files(proc, setup: dict) -> None:
    """Refuse a design that states a file field: the page never names a path on this
    machine (such a field is set in a set-up file, for the command line)."""
    named = [f for f in file_fields(proc.Setup) if str(setup.get(f) or "").strip()]
    if named:
        raise InvalidInput([f"The designer does not read files: {', '.join(named)} of "
                            f"{proc.name} names one; set it in the set-up file (mtplan simulate "
                            "--config FILE.toml) and leave it out here."])


def _values(proc, design) -> dict:
    """The set-up values the design states, with switched-off sources at 0."""
    _refuse_files(proc, design["setup"])
    values = {k: v for k, v in design["setup"].items() if str(v).strip() != ""}
    fields = source_fields(proc)
    for s in design["off"]:
        if s in fields:
            values[fields[s]] = "0"
    return values


def field_problems(proc, design) -> dict:
    """Field name -> the procedure's own message for each value it refuses alone."""
    infos = {f.name for f in fields_info(proc.Setup)}
    try:
        values = _values(proc, design)
    except InvalidInput as exc:  # a file field: named beside itself
        return {f: " ".join(exc.problems) for f in file_fields(proc.Setup)
                if str(design["setup"].get(f) or "").strip()}
    out = {}
    for key, value in values.items():
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
    return {"u": fo.u(), "budget": fo.budget_std(), "method": fo.method}


def _setup_key(setup) -> str:
    return json.dumps(setup.as_dict(), sort_keys=True)


def predict(proc, setup, estimator) -> dict:
    """Cached :func:`_predict` (a set-up seen before answers at once)."""
    return _predict_cached(proc.name, _setup_key(setup), estimator)


# --------------------------------------------------------------------------- cost guard
#: the most memory [bytes] and time [s] a live prediction may be estimated to take; a
#: set-up beyond either is refused with the estimate, before anything is computed. Times
#: are learnt as the CPU time of the computing thread (BLAS on that one thread): what
#: the computation takes on an idle machine, so that the same set-up is answered or
#: refused whatever else the machine is doing
LIVE_MEMORY = 1.5e9
LIVE_SECONDS = 2.0
#: the longest a sensitivity curve may be estimated to take [s] (fewer points beyond)
CURVE_SECONDS = 3.0


class TooCostly(InvalidInput):
    """A live computation refused from its estimated cost (carries the estimate)."""

    def __init__(self, message: str, cost: dict):
        super().__init__([message])
        self.cost = cost


@functools.lru_cache(maxsize=64)
def _closed_form(name: str, estimator: str) -> tuple:
    """(path, factor or None) of a procedure's estimator: which path the
    first-order service (:func:`mtplan.evaluation.first_order.first_order`) takes for it,
    asked once of the procedure's derivative hook at the default set-up (a closed form is a
    property of the estimator, not of the size), and what the prediction and the
    identifiability took there: over the readings to the power :data:`CLOSED_FORM_POWER`
    for a closed form, over :func:`_chain_estimate`'s estimate for the chain rule.

    Paths: 'sensitivities' (the procedure's closed-form sensitivities) or 'chain' (the
    service's chain rule through forward model and estimator; not timed, None, where its
    estimate at the default set-up is over :data:`CHAIN_PROBE_SECONDS` or its memory over
    :data:`LIVE_MEMORY`: line_laser's registration at the full scan, 3.7 GiB and minutes,
    which the probe itself once ran)."""
    import time

    from mtplan.evaluation.first_order import first_order

    proc = get(name)
    setup = proc.Setup()
    hook = proc.capabilities.first_order_sensitivities
    with one_blas_thread():
        # the hook's first answer is the cold computation (it may keep what it computed:
        # a prediction timed after it would be a cache's, 12 ms where geometry21 takes 140)
        t = time.thread_time()  # CPU time, as LIVE_SECONDS says
        closed = hook is not None and hook(setup, proc.Truth(), estimator=estimator,
                                           sources=None) is not None
        seconds = time.thread_time() - t
    path = "sensitivities" if closed else "chain"
    if not closed:
        # the chain rule at the default set-up: timed when its estimate from single runs
        # (which overstates a batched run many times) allows, else never run here
        chain = _chain_estimate(proc, setup, estimator)
        estimate = chain["seconds"]
        if estimate > CHAIN_PROBE_SECONDS or chain["bytes"] > LIVE_MEMORY:
            return path, None  # (beyond the memory a live answer may use: never run here)
    with one_blas_thread():
        t = time.thread_time()
        if not closed:
            first_order(proc, setup, estimator=estimator).u()
        identify(proc, setup)
        seconds += time.thread_time() - t
    if path == "chain":  # the measured time over the estimate: scales the estimate elsewhere
        return path, seconds / max(estimate, 1e-9)
    return path, seconds / max(_readings(name, _setup_key(setup)), 1) ** CLOSED_FORM_POWER


#: a closed form's time grows as the readings to this power: a little faster than in
#: proportion, as reading noise brings elements with the readings (geometry21: 15 times the
#: readings took 22.6 times as long, a power of 1.15)
CLOSED_FORM_POWER = 1.2


#: the chain rule is timed at a procedure's default set-up when its estimate from single
#: runs is at most this [s]
CHAIN_PROBE_SECONDS = 60.0


def _chain_estimate(proc, setup, estimator: str) -> dict:
    """Memory [bytes] and time [s] of the chain rule from the set-up's size and the time of
    single runs: up to ``WHOLE_MAX`` elements the whole chain, 4 n + 1 runs of forward model
    and estimator; above, the readings' effect of every element (8 r n bytes, twice in
    flight) and the estimator's map, 2 r + 1 runs of the estimator."""
    from mtplan.evaluation.first_order import WHOLE_MAX

    n = int(sum(src.size for src in proc.active_sources(setup).values()))
    m = len(proc.measurands(setup))
    r = _readings(proc.name, _setup_key(setup))
    runs = 4 * n + 1 if n <= WHOLE_MAX else 2 * r + 1
    memory = 8.0 * runs * (r + m) if n <= WHOLE_MAX else 16.0 * r * n
    seconds = runs * trial_seconds(proc, setup, estimator) if memory <= LIVE_MEMORY else 0.0
    return {"bytes": memory, "seconds": seconds}


def prediction_cost(proc, setup, estimator: str) -> dict:
    """Estimated memory [bytes] and time [s] of the live first-order prediction, from the
    set-up alone (its sources' elements n, readings r, measurands m, one timed block of
    trials), along the first-order service's paths:

    - 'sensitivities': the closed form (the procedure's linear maps: the m x n sensitivities
      and r x m maps), its time learnt at the default set-up, grown as the readings to the
      power :data:`CLOSED_FORM_POWER`;
    - 'chain': :func:`_chain_estimate`'s memory and time, the time scaled by what the
      chain rule took at the default set-up over that estimate there, where it was timed
      (never below 1/20 of the estimate).
    """
    n = int(sum(src.size for src in proc.active_sources(setup).values()))
    m = len(proc.measurands(setup))
    r = _readings(proc.name, _setup_key(setup))
    path, per_reading = _closed_form(proc.name, estimator)
    if path == "sensitivities":
        return {"path": path, "inputs": n, "readings": r,
                "seconds": per_reading * max(r, 1) ** CLOSED_FORM_POWER,
                "bytes": 8.0 * (m + r) * m + 8.0 * m * n}
    chain = _chain_estimate(proc, setup, estimator)  # its growth with n and r, not linear
    seconds = chain["seconds"] * (1.0 if per_reading is None else max(per_reading, 0.05))
    return {"path": path, "inputs": n, "readings": r, "bytes": chain["bytes"],
            "seconds": seconds}


@functools.lru_cache(maxsize=256)
def _readings(name: str, setup_key: str) -> int:
    """Number of readings of a set-up (one noise-free measurement)."""
    proc = get(name)
    setup = make(proc.Setup, json.loads(setup_key), owner=proc.name)
    out = proc.forward(setup, proc.Truth(), proc.zero_errors(setup, 1))
    return int(sum(np.size(v) for v in out.values()))


def guard_cost(proc, setup, estimator: str) -> dict:
    """The cost of a live prediction, or TooCostly with a plain message."""
    cost = prediction_cost(proc, setup, estimator)
    what = (f"The first-order prediction of this {proc.name} set-up ({estimator} estimator, "
            f"{cost['readings']} readings, {cost['inputs']} error inputs)")
    if cost["bytes"] > LIVE_MEMORY:
        raise TooCostly(f"{what} would need about {cost['bytes'] / 2**30:.3g} GiB of memory, "
                        f"more than the {LIVE_MEMORY / 2**30:.3g} GiB a live answer may use: "
                        "make the set-up smaller, or confirm it by Monte Carlo.", cost)
    if cost["seconds"] > LIVE_SECONDS:
        minutes = cost["seconds"] / 60
        took = f"{minutes:.0f} min" if minutes >= 1.5 else f"{cost['seconds']:.0f} s"
        raise TooCostly(f"{what} would take about {took} here, more than a live answer may: "
                        "make the set-up smaller (fewer readings), or confirm it by Monte "
                        "Carlo.", cost)
    return cost


# --------------------------------------------------------------------------- trust
#: trials of the spot check that tests each first-order u against a small Monte Carlo
SPOT_TRIALS = 200
#: fewest trials a spot check may have to judge (fewer: the cells stay "not checked")
SPOT_MIN_TRIALS = 40
#: a cell shown as trusted is within this factor of the Monte Carlo ...
TRUST_FACTOR = 1.5
#: ... with this many standard errors of the spot check's u to spare: a first-order u is
#: trusted where the check's u lies within TRUST_FACTOR / (1 + z / sqrt(2 (n - 1))) of it
#: (1.33 with 200 trials, 1.19 with 40)
TRUST_Z = 2.5
#: the longest a spot check may take [s] and the most memory its block may hold [bytes]
SPOT_BUDGET_S = 4.0
SPOT_MEMORY = 256e6
_SPOT_SEED = 20240605
_spots: dict = {}  # (procedure, set-up key, estimator) -> spot check, newest last


def trial_seconds(proc, setup, estimator: str) -> float:
    """Seconds per Monte Carlo trial of a set-up, timed once per size: a trial's work is
    set by the numbers of readings, error elements and measurands, not by the values of
    angles, radii or source sizes, so moving such a lever reuses the time of a set-up of
    the same size (the first one timed) instead of running trials again."""
    key = _setup_key(setup)
    elements = int(sum(src.size for src in proc.active_sources(setup).values()))
    size = (_readings(proc.name, key), elements, len(proc.measurands(setup)))
    sized = (proc.name, size, estimator)
    if sized not in _timed:
        while len(_timed) >= 256:
            _timed.pop(next(iter(_timed)))
        _timed[sized] = _trial_seconds(proc.name, key, estimator)
    return _timed[sized]


_timed: dict = {}  # (procedure, (readings, elements, measurands), estimator) -> s per trial


def _trial_seconds(name: str, setup_key: str, estimator: str) -> float:
    """Timed on a block of two trials after one that warms the caches (that one alone
    when it is already slow)."""
    import time

    from mtplan.evaluation.simulation import procedure_block
    from mtplan.uncertainty.streams import as_seed_sequence

    proc = get(name)
    setup = make(proc.Setup, json.loads(setup_key), owner=proc.name)
    truth, active = proc.Truth(), tuple(proc.active_sources(setup))
    root = as_seed_sequence(0)
    t, wall = time.thread_time(), time.perf_counter()  # CPU time, as LIVE_SECONDS says
    with one_blas_thread():
        procedure_block(proc, setup, truth, estimator, active, root, 0, 1)
        one = time.thread_time() - t  # with the one-off costs (caches, imports)
        if one > 1.0 or time.perf_counter() - wall > 2.0:
            return one  # a trial of a second: more would not tell whether it fits
        t = time.thread_time()
        procedure_block(proc, setup, truth, estimator, active, root, 1, 2)
    return (time.thread_time() - t) / 2


def spot_check(proc, setup, estimator: str) -> dict:
    """A small Monte Carlo of the set-up (:data:`SPOT_TRIALS` trials, a fixed seed) that
    the first-order u of every measurand is judged against; cached per set-up.

    Returns ``{"trials": n, "u": {measurand: u}}`` [display unit], with ``trials`` 0 and
    ``reason`` where the check would exceed its time or memory budget. A quantised
    estimator's measurand that never left its step is given ``step / sqrt(12)`` as
    ``mtplan simulate`` states it.
    """
    key = (proc.name, _setup_key(setup), estimator)
    if key in _spots:
        return _spots[key]
    from mtplan.evaluation.simulation import procedure_block
    from mtplan.uncertainty.streams import as_seed_sequence

    floats = sum(src.size for src in proc.active_sources(setup).values())
    per = trial_seconds(proc, setup, estimator)
    n = int(min(SPOT_TRIALS, SPOT_BUDGET_S / max(per, 1e-9), SPOT_MEMORY / (80.0 * floats + 1)))
    if n < SPOT_MIN_TRIALS:
        out = {"trials": 0, "reason": f"a check by {SPOT_MIN_TRIALS} Monte Carlo trials would "
                                      f"take about {SPOT_MIN_TRIALS * per:.2g} s"}
    else:
        with one_blas_thread():
            est = procedure_block(proc, setup, proc.Truth(), estimator,
                                  tuple(proc.active_sources(setup)),
                                  as_seed_sequence(_SPOT_SEED), 0, n)
        steps = proc.estimators[estimator].steps(setup)
        u = {}
        for m in proc.measurands(setup):
            a = np.asarray(est[m.name], dtype=float)
            spread = float(np.std(a, ddof=1)) if np.all(np.isfinite(a)) else math.inf
            if spread == 0.0 and steps.get(m.name):
                spread = steps[m.name] * m.scale / math.sqrt(12.0)
            u[m.name] = spread
        out = {"trials": n, "u": u, "steps": {m.name: steps[m.name] * m.scale
                                             for m in proc.measurands(setup)
                                             if steps.get(m.name)}}
    _spots[key] = out
    while len(_spots) > 512:
        _spots.pop(next(iter(_spots)))
    return out


def resolution_steps(proc, setup, estimator: str) -> dict:
    """Measurand -> the step [display unit] its estimator's values come in (a quantised
    estimator, its record's ``resolution``); {} for a continuous one."""
    steps = proc.estimators[estimator].steps(setup) or {}
    return {m.name: steps[m.name] * m.scale for m in proc.measurands(setup) if steps.get(m.name)}


def known_spot(proc, setup, estimator: str) -> dict | None:
    """The spot check of a set-up when it has been made, else None (never computes)."""
    return _spots.get((proc.name, _setup_key(setup), estimator))


def trust_ratio(trials: int) -> float:
    """The factor within which a spot check of `trials` trials must find first order."""
    return TRUST_FACTOR / (1 + TRUST_Z / math.sqrt(2 * (trials - 1)))


def trust(pred_u: dict, spot: dict | None, steps: dict | None = None) -> dict:
    """Measurand -> ``{"trust": "ok" | "no" | "unchecked", "why": text, "mc_u": u}``.

    First order is not trusted where it gives u = 0 while the Monte Carlo does not (a
    measurand the linearisation is blind to, or a quantised one), where the estimator's
    values come in steps larger than u, or where the spot check's u differs from it by
    more than :func:`trust_ratio`. Until the check is made the cells are "unchecked".
    `steps` (measurand -> step [display unit], :func:`resolution_steps`) judge before it.
    """
    out = {}
    for name, u in pred_u.items():
        step = (steps or {}).get(name)
        if step and step > u:
            out[name] = {"trust": "no", "mc_u": None, "why": f"the estimator's values come in "
                                                           f"steps of {step:.3g}, more than u"}
            continue
        if u <= 0 and not (spot and spot.get("trials")):
            out[name] = {"trust": "no", "mc_u": None, "why": "u = 0 at first order: the "
                         "linearisation does not see it; confirm by Monte Carlo"}
            continue
        if spot is None:
            out[name] = {"trust": "unchecked", "why": "being checked against a small Monte "
                                                      "Carlo", "mc_u": None}
            continue
        if not spot.get("trials"):
            out[name] = {"trust": "unchecked", "mc_u": None,
                         "why": f"not checked: {spot.get('reason')}; confirm by Monte Carlo"}
            continue
        mc = spot["u"].get(name)
        step = spot.get("steps", {}).get(name)
        n = spot["trials"]
        why = None
        if mc is None or not math.isfinite(mc):
            why = f"the estimator fails in some of {n} Monte Carlo trials"
        elif step and step > u:
            why = f"the estimator's values come in steps of {step:.3g}, more than u"
        elif u <= 0:
            why = (None if mc == 0 else
                   f"u = 0 at first order, {mc:.3g} by {n} Monte Carlo trials")
        elif not 1 / trust_ratio(n) <= mc / u <= trust_ratio(n):
            why = f"{n} Monte Carlo trials give u = {mc:.3g}, {mc / u:.2g} times first order"
        out[name] = ({"trust": "ok", "why": f"agrees with {n} Monte Carlo trials", "mc_u": mc}
                     if why is None else {"trust": "no", "why": why, "mc_u": mc})
    return out


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
    rule = (tol.get("rule") or "simple").strip()
    try:
        prior, prior_text = tolerance_prior(tol)
        r = plan_acceptance(lower, upper, u, prior=prior, rule=rule)
    except InvalidInput as exc:
        return {"error": " ".join(exc.problems)}
    out = r.to_dict()
    out["guard_band"] = r.guard_band
    out["rule"] = rule
    out["prior"] = prior_text
    out["lower"], out["upper"], out["u"] = lower, upper, u
    out["p_conform"] = r.p_conform_prior  # the share of good machines (for the verdict)
    if prior is not None and lower is not None and upper is not None:
        try:
            out["curve"] = risk_curve(lower, upper, u, prior)
        except InvalidInput:  # the figures stand; only the curve is left out
            out["curve"] = None
    return out


#: guard bands of the risk curve [multiples of U = K u]
GUARDS = tuple(0.125 * i for i in range(13))


def risk_curve(lower: float, upper: float, u: float, prior) -> dict:
    """PFA and PFR against the guard band (0 to 1.5 U, in the tolerance's unit): the
    acceptance figures of the rule ``guard:R`` (a guard band of R U) for each R of
    :data:`GUARDS` that leaves an acceptance zone."""
    from mtplan.plans.acceptance import plan_acceptance

    g, pfa, pfr = [], [], []
    for R in GUARDS:
        if R * K * u >= (upper - lower) / 2:  # no acceptance zone left
            break
        r = plan_acceptance(lower, upper, u, prior=prior, rule=f"guard:{R}")
        g.append(r.guard_band)
        pfa.append(r.pfa)
        pfr.append(r.pfr)
    return {"guard_band": g, "pfa": pfa, "pfr": pfr}


_PRIOR_TEXT = re.compile(r"\s*(normal|gamma)\s*:", flags=re.I)


def tolerance_prior(tol: dict):
    """(prior, its text) of a tolerance row: ``normal:MEAN,SD``, ``gamma:SHAPE,SCALE`` or
    the content of a CSV file uploaded from the page (``prior_csv``, with ``prior_name``).

    A browser field never names a file on the server: any other text is refused, so the
    designer never reads a path it is sent.
    """
    from mtplan.plans.acceptance import parse_prior, prior_from_csv

    content = tol.get("prior_csv")
    if isinstance(content, str) and content.strip():
        name = str(tol.get("prior_name") or "prior.csv")[:80]
        try:
            return prior_from_csv(io.StringIO(content)), f"{name} (uploaded)"
        except InvalidInput as exc:
            raise InvalidInput(_renamed(exc.problems, name)) from None
    text = str(tol.get("prior") or "").strip()
    if not text:
        return None, None
    if not _PRIOR_TEXT.match(text):
        raise InvalidInput([f"The 'prior' (population) must be 'normal:MEAN,SD', "
                            f"'gamma:SHAPE,SCALE' or a CSV file uploaded with its button; the "
                            f"designer reads no file on the server. Got {text[:60]!r} instead."])
    return parse_prior(text), text


def _renamed(problems, name: str) -> list:
    """The CSV reader's messages with the uploaded file's name for the in-memory one."""
    return [re.sub(r"'<_io\.StringIO object at 0x[0-9a-f]+>'", repr(name), m) for m in problems]


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
        out["measurand_names"] = _measurand_rows(proc, setup)
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
               "help": _help(m.name, m.description), "anchor": _anchor(m.name),
               "U": K * u, "budget": pred["budget"][m.name], **trusted[m.name],
               "budget_table": budget_table(pred["budget"][m.name], u, inputs)}
        if m.name in design["targets"]:
            try:
                row["target"] = float(design["targets"][m.name])
            except (TypeError, ValueError):
                row["target_error"] = (f"The target of {m.name} must be a number. Got "
                                       f"{design['targets'][m.name]!r} instead.")
        tol = design["tolerances"].get(m.name)
        if tol:
            if row["trust"] == "no":
                row["acceptance"] = {"error": f"u({m.name}) is not reliable at first order "
                                              f"({row['why']}): confirm by Monte Carlo"}
            else:
                row["acceptance"] = _acceptance(tol, u) if u > 0 else {
                    "error": f"u({m.name}) = 0: no acceptance figures without an uncertainty"}
        ms.append(row)
    out.update(ok=True, measurands=ms, duration_s=float(proc.duration(setup)),
               method=pred["method"], estimator=est,
               identifiability=_identify_cached(proc.name, _geometry_key(proc, setup)),
               setup=_json_setup(setup))
    return out


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


def _measurand_rows(proc, setup) -> list:
    return [{"name": m.name, "unit": m.unit, "description": m.description,
             "help": _help(m.name, m.description), "anchor": _anchor(m.name)}
            for m in proc.measurands(setup)]


def _anchor(code: str) -> str | None:
    row = explain(code)
    return row["anchor"] if row else None


def check(design: dict) -> dict:
    """The spot check of a design's first-order numbers: ``{"trust": {measurand: ...}}``
    (:func:`trust`), computed once per set-up (the page asks after the numbers)."""
    design = normalise(design)
    proc, setup = setup_of(design)
    est, _ = proc.estimator(design["estimator"])
    guard_cost(proc, setup, est)
    pred = predict(proc, setup, est)
    return {"trust": trust(pred["u"], spot_check(proc, setup, est),
                           resolution_steps(proc, setup, est))}


def _json_setup(setup) -> dict:
    return {k: _json_value(v) for k, v in setup.as_dict().items()}


# --------------------------------------------------------------------------- sensitivity
def lever_values(proc, setup, field: str, n: int = 9) -> list:
    """Values of a numeric field over its range around the current value (n at most)."""
    info = next(f for f in fields_info(proc.Setup) if f.name == field)
    v = getattr(setup, field)
    kind = info.kind
    if kind not in (int, float) or v is None:
        raise InvalidInput([f"The lever {field!r} of {proc.name} is not a number; a "
                            "sensitivity needs a numeric field."])
    lo, hi = info.low, info.high
    v = float(v)
    a = lo if lo is not None else (0.0 if v >= 0 else 4 * v)
    b = hi if hi is not None else max(4 * abs(v), 1.0)
    # keep the plot around the current value: at most x0.25 .. x4 on ratio-scale fields
    if lo is not None and lo >= 0 and v > 0:
        a, b = max(a, v / 4), min(b, v * 4)
    if info.low_open and a == lo:
        a = a + (b - a) / (4 * n)
    if info.high_open and b == hi:
        b = b - (b - a) / (4 * n)
    if kind is int:
        vals = sorted(set(int(round(x)) for x in np.linspace(a, b, n)) | {int(v)})
    else:
        vals = sorted(set(float(x) for x in np.linspace(a, b, n)) | {v})
    return vals


def _num(v):
    return float(v) if isinstance(v, float) else v


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
    guard_cost(proc, setup, est)
    spot = known_spot(proc, setup, est)
    untrusted = sorted(k for k, v in trust(predict(proc, setup, est)["u"], spot,
                                           resolution_steps(proc, setup, est)).items()
                       if v["trust"] == "no")
    now = _num(getattr(setup, field))
    budget, points = CURVE_SECONDS, {}
    # nearest the current value first: where the budget runs out, the far ends are left
    for x in sorted(lever_values(proc, setup, field, n), key=lambda v: abs(v - now)):
        if stop is not None and stop():
            return {"field": field, "superseded": True}
        try:
            s = setup.replace(**{field: x})
            cost = guard_cost(proc, s, est)
        except InvalidInput:
            continue  # a value the procedure refuses, or beyond the live budget: no point
        if not proc.measurands(s):
            continue  # nothing to draw (and nothing for a first-order budget to give)
        if cost["seconds"] > budget and x != now:
            continue
        budget -= cost["seconds"]
        points[x] = predict(proc, s, est)["u"]
    xs, curves = sorted(points), {}
    for x in xs:
        for name, u in points[x].items():
            curves.setdefault(name, []).append(K * u)
    info = next(f for f in fields_info(proc.Setup) if f.name == field)
    return {"field": field, "unit": info.unit, "x": xs, "U": curves, "untrusted": untrusted,
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
        if _PRIOR_TEXT.match(str(tol.get("prior") or "")):  # an uploaded CSV stays here
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
    if e.get("name") in registry() and isinstance(e.get("setup"), dict):
        _refuse_files(get(e["name"]), e["setup"])
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
    for source, f in source_fields(ps.procedure).items():  # a source at 0 is switched off
        if design["setup"].get(f) in ("0", "0.0"):
            design.setdefault("off", []).append(source)
            del design["setup"][f]  # on again at its default size
    if ps.plan:
        k = float(ps.plan.get("k", 1.0))
        design["targets"] = {m: float(v) * K / k for m, v in ps.plan.get("targets", {}).items()}
        design["vary"] = {f: ",".join(str(x) for x in vs)
                          for f, vs in ps.plan.get("vary", {}).items()}
    return normalise(design)
