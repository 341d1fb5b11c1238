"""Which live numbers may be shown: each first-order u is checked against a small Monte
Carlo of the same set-up (the spot check) and is trusted only within a stated factor of it."""

from __future__ import annotations

import math

import numpy as np

from mtplan._parallel import one_blas_thread
from mtplan.explore.prediction import guard_cost, predict, trial_seconds
from mtplan.explore.state import normalise, setup_key, setup_of

__all__ = ["SPOT_TRIALS", "SPOT_MIN_TRIALS", "TRUST_FACTOR", "TRUST_Z", "SPOT_BUDGET_S",
           "SPOT_MEMORY", "spot_check", "resolution_steps", "known_spot", "trust_ratio", "trust", "check"]


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


def spot_check(proc, setup, estimator: str) -> dict:
    """A small Monte Carlo of the set-up (:data:`SPOT_TRIALS` trials, a fixed seed) that
    the first-order u of every measurand is judged against; cached per set-up.

    Returns ``{"trials": n, "u": {measurand: u}}`` [display unit], with ``trials`` 0 and
    ``reason`` where the check would exceed its time or memory budget. A quantised
    estimator's measurand that never left its step is given ``step / sqrt(12)`` as
    ``mtplan simulate`` states it.
    """
    key = (proc.name, setup_key(setup), estimator)
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
    return _spots.get((proc.name, setup_key(setup), estimator))


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
