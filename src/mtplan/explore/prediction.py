"""The live numbers and what they cost: the first-order prediction (the service that
``mtplan linearize`` and the planner call), the identifiability of a set-up, and the cost
guard that estimates a prediction's memory and time from the set-up before it runs."""

from __future__ import annotations

import functools
import json
import math

import numpy as np

from mtplan._parallel import one_blas_thread
from mtplan._validate import InvalidInput
from mtplan.explore.size import size_model, size_problem
from mtplan.explore.state import setup_key, source_fields
from mtplan.models import get, registry
from mtplan.models.protocol import make

__all__ = ["predict", "compute_prediction", "LIVE_MEMORY", "LIVE_SECONDS", "CURVE_SECONDS",
           "TooCostly", "CLOSED_FORM_POWER", "CHAIN_PROBE_SECONDS", "prediction_cost",
           "guard_cost", "trial_seconds", "identify", "identify_cached", "learn_costs"]


@functools.lru_cache(maxsize=512)
def _predict_cached(name: str, key: str, estimator: str):
    proc = get(name)
    setup = make(proc.Setup, json.loads(key), owner=proc.name)
    with one_blas_thread():  # small products: threads only wait on each other
        return compute_prediction(proc, setup, estimator)


def compute_prediction(proc, setup, estimator) -> dict:
    """u per measurand [display unit] and its budget by source (std per source): the
    first-order service's numbers (those of ``mtplan linearize`` and the planner)."""
    from mtplan.evaluation.first_order import first_order

    fo = first_order(proc, setup, estimator=estimator)
    budget = {m: {src: part["u"] for src, part in parts.items()}
              for m, parts in fo.by_source().items()}
    return {"u": fo.u(), "budget": budget, "method": fo.method}


def predict(proc, setup, estimator) -> dict:
    """Cached :func:`compute_prediction` (a set-up seen before answers at once)."""
    return _predict_cached(proc.name, setup_key(setup), estimator)


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
    # the service's closed form alone (no chain rule run); its first answer is the cold
    # computation (it may keep what it computed: a prediction timed after it would be a
    # cache's, 12 ms where geometry21 takes 140), its cost the CPU time, as LIVE_SECONDS says
    closed = first_order(proc, setup, estimator=estimator, chain=False)
    seconds = closed.cost.cpu_seconds if closed is not None else 0.0
    path = "sensitivities" if closed is not None else "chain"
    if not closed:
        # the chain rule at the default set-up: timed when its estimate from single runs
        # (which overstates a batched run many times) allows, else never run here
        chain = _chain_estimate(proc, setup, estimator)
        estimate = chain["seconds"]
        if estimate > CHAIN_PROBE_SECONDS or chain["bytes"] > LIVE_MEMORY:
            return path, None  # (beyond the memory a live answer may use: never run here)
    if closed is None:
        seconds += first_order(proc, setup, estimator=estimator).cost.cpu_seconds
    with one_blas_thread():
        t = time.thread_time()
        identify(proc, setup)
        seconds += time.thread_time() - t
    if path == "chain":  # the measured time over the estimate: scales the estimate elsewhere
        return path, seconds / max(estimate, 1e-9)
    return path, seconds / max(_readings(name, setup_key(setup)), 1) ** CLOSED_FORM_POWER


#: a closed form's time grows as the readings to this power: a little faster than in
#: proportion, as reading noise brings elements with the readings (geometry21: 15 times the
#: readings took 22.6 times as long, a power of 1.15)
CLOSED_FORM_POWER = 1.2


#: CPU seconds per element of a prediction's m x n sensitivities (measurands times error
#: inputs): forming them, their variances and the budget by source. geometry21 with 400 to
#: 3200 measurands along Y (7488 inputs): 3.8e-8 to 6.2e-8 s on one thread of the 2-core
#: test machine; an element costs the same whatever the set-up, so it is not learnt
SENSITIVITY_SECONDS = 6e-8


#: the chain rule is timed at a procedure's default set-up when its estimate from single
#: runs is at most this [s]
CHAIN_PROBE_SECONDS = 60.0


def _chain_estimate(proc, setup, estimator: str, m: int | None = None) -> dict:
    """Memory [bytes] and time [s] of the chain rule from the set-up's size and the time of
    single runs: up to ``WHOLE_MAX`` elements the whole chain, 4 n + 1 runs of forward model
    and estimator; above, the readings' effect of every element (8 r n bytes, twice in
    flight) and the estimator's map, 2 r + 1 runs of the estimator."""
    from mtplan.evaluation.first_order import WHOLE_MAX

    n = int(sum(src.size for src in proc.active_sources(setup).values()))
    m = len(proc.measurands(setup)) if m is None else m
    r = _readings(proc.name, setup_key(setup))
    runs = 4 * n + 1 if n <= WHOLE_MAX else 2 * r + 1
    memory = 8.0 * runs * (r + m) if n <= WHOLE_MAX else 16.0 * r * n
    seconds = runs * trial_seconds(proc, setup, estimator) if memory <= LIVE_MEMORY else 0.0
    return {"bytes": memory, "seconds": seconds}


def prediction_cost(proc, setup, estimator: str, *, measurands: int | None = None) -> dict:
    """Estimated memory [bytes] and time [s] of the live first-order prediction, from the
    set-up alone (its sources' elements n, readings r, measurands m, one timed block of
    trials), along the first-order service's paths:

    - 'sensitivities': the closed form (the procedure's linear maps: the m x n sensitivities
      and r x m maps), its time learnt at the default set-up, grown as the readings to the
      power :data:`CLOSED_FORM_POWER`;
    - 'chain': :func:`_chain_estimate`'s memory and time, the time scaled by what the
      chain rule took at the default set-up over that estimate there, where it was timed
      (never below 1/20 of the estimate);

    and on either path :data:`SENSITIVITY_SECONDS` for each element of the m x n
    sensitivities (their variances and the budget by source: thousands of measurands, a
    set-up's errors at every position along the travel, take seconds at a few readings).

    `measurands`: m as stated (0 gives a lower bound of the cost before the measurands are
    counted: their list may need an analysis of the set-up, geometry21's identifiability).
    """
    n = int(sum(src.size for src in proc.active_sources(setup).values()))
    m = len(proc.measurands(setup)) if measurands is None else measurands
    r = _readings(proc.name, setup_key(setup))
    path, per_reading = _closed_form(proc.name, estimator)
    budget = SENSITIVITY_SECONDS * m * n
    if path == "sensitivities":
        return {"path": path, "inputs": n, "readings": r, "measurands": m,
                "seconds": per_reading * max(r, 1) ** CLOSED_FORM_POWER + budget,
                "bytes": 8.0 * (m + r) * m + 8.0 * m * n}
    chain = _chain_estimate(proc, setup, estimator, m)  # its growth with n and r, not linear
    seconds = chain["seconds"] * (1.0 if per_reading is None else max(per_reading, 0.05))
    return {"path": path, "inputs": n, "readings": r, "measurands": m,
            "bytes": chain["bytes"], "seconds": seconds + budget}


@functools.lru_cache(maxsize=256)
def _readings(name: str, key: str) -> int:
    """Number of readings of a set-up (one noise-free measurement)."""
    proc = get(name)
    setup = make(proc.Setup, json.loads(key), owner=proc.name)
    out = proc.forward(setup, proc.Truth(), proc.zero_errors(setup, 1))
    return int(sum(np.size(v) for v in out.values()))


def guard_cost(proc, setup, estimator: str) -> dict:
    """The cost of a live prediction, or TooCostly with a plain message: first from the
    set-up's size estimated from its count fields alone (:mod:`mtplan.explore.size`, no
    model run), then from the prediction's own estimate: without the measurands (a lower
    bound, from the set-up's sources and one noise-free run), then with them counted."""
    size, problem = size_problem(proc, setup.as_dict())
    if problem:
        raise TooCostly(f"{problem} Make the set-up smaller, or confirm it by Monte Carlo.",
                        {"bytes": None, "seconds": None, **size})
    cost = prediction_cost(proc, setup, estimator, measurands=0)
    if cost["bytes"] <= LIVE_MEMORY and cost["seconds"] <= LIVE_SECONDS:
        cost = prediction_cost(proc, setup, estimator)
    counted = f", {cost['measurands']} measurands" if cost["measurands"] else ""
    what = (f"The first-order prediction of this {proc.name} set-up ({estimator} estimator, "
            f"{cost['readings']} readings, {cost['inputs']} error inputs{counted})")
    if cost["bytes"] > LIVE_MEMORY:
        raise TooCostly(f"{what} would need about {cost['bytes'] / 2**30:.3g} GiB of memory, "
                        f"more than the {LIVE_MEMORY / 2**30:.3g} GiB a live answer may use: "
                        "make the set-up smaller, or confirm it by Monte Carlo.", cost)
    if cost["seconds"] > LIVE_SECONDS:
        minutes = cost["seconds"] / 60
        took = f"{minutes:.0f} min" if minutes >= 1.5 else f"{cost['seconds']:.0f} s"
        raise TooCostly(f"{what} would take about {took} here, more than a live answer may: "
                        "make the set-up smaller (fewer readings or measurands), or confirm it "
                        "by Monte Carlo.", cost)
    return cost


def learn_costs(names=None) -> float:
    """Learn, ahead of the first request, what the cost guard asks of each procedure named
    (default: every one registered): its size model (:func:`mtplan.explore.size.size_model`,
    every model first: they are what refuses a set-up too large to build) and its default
    estimator's path and time (:func:`_closed_form`, 0.4-1.2 s a procedure). The seconds it
    took. The server runs it at start, in the background, so that the guard's first answer
    for a procedure takes milliseconds, not the seconds of learning."""
    import time

    t = time.perf_counter()
    names = list(names or registry())
    for name in names:
        size_model(name)
    for name in names:
        _closed_form(name, get(name).estimator(None)[0])
    return time.perf_counter() - t


def trial_seconds(proc, setup, estimator: str) -> float:
    """Seconds per Monte Carlo trial of a set-up, timed once per size: a trial's work is
    set by the numbers of readings, error elements and measurands, not by the values of
    angles, radii or source sizes, so moving such a lever reuses the time of a set-up of
    the same size (the first one timed) instead of running trials again."""
    key = setup_key(setup)
    elements = int(sum(src.size for src in proc.active_sources(setup).values()))
    size = (_readings(proc.name, key), elements, len(proc.measurands(setup)))
    sized = (proc.name, size, estimator)
    if sized not in _timed:
        while len(_timed) >= 256:
            _timed.pop(next(iter(_timed)))
        _timed[sized] = _trial_seconds(proc.name, key, estimator)
    return _timed[sized]


_timed: dict = {}  # (procedure, (readings, elements, measurands), estimator) -> s per trial


def _trial_seconds(name: str, key: str, estimator: str) -> float:
    """Timed on a block of two trials after one that warms the caches (that one alone
    when it is already slow)."""
    import time

    from mtplan.evaluation.simulation import procedure_block
    from mtplan.uncertainty.streams import as_seed_sequence

    proc = get(name)
    setup = make(proc.Setup, json.loads(key), owner=proc.name)
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


def identify_cached(proc, setup) -> dict:
    """Cached :func:`identify`, per set-up without its sources' sizes."""
    return _identify_cached(proc.name, _geometry_key(proc, setup))


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

    names = [m.name for m in proc.measurands(setup)]
    rep = proc.capabilities.identifiability_report(setup)  # {}: no analysis of its own
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
