"""Which live numbers may be shown: each first-order u is checked against a small Monte
Carlo of the same set-up (the spot check) and is trusted only within a stated factor of it."""

from __future__ import annotations

import math

import numpy as np

from mtplan._parallel import one_blas_thread
from mtplan._validate import InvalidInput
from mtplan.explore.prediction import guard_cost, predict, trial_seconds
from mtplan.explore.state import normalise, setup_key, setup_of

__all__ = ["SPOT_TRIALS", "SPOT_MIN_TRIALS", "TRUST_FACTOR", "TRUST_Z", "SPOT_BUDGET_S",
           "SPOT_MEMORY", "spot_check", "remember", "resolution_steps", "known_spot", "trust_ratio", "trust", "check"]


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


def spot_check(proc, setup, estimator: str, *, budget_s: float = SPOT_BUDGET_S) -> dict:
    """A small Monte Carlo of the set-up (:data:`SPOT_TRIALS` trials, a fixed seed) that
    the first-order u of every measurand is judged against; cached per set-up.

    Returns ``{"trials": n, "u": {measurand: u}}`` [display unit]; ``trials`` 0 with
    ``reason`` and ``seconds`` (what a check would take) where it would exceed `budget_s`
    or, for a live answer, :data:`SPOT_MEMORY`; ``failed`` (the estimator's message: its
    fits do not converge, for one) where the trials fail, as ``mtplan simulate`` refuses
    such a set-up. A check job (:func:`mtplan.explore.jobs.check_first_order`) gives a
    larger `budget_s` and runs its trials in blocks that fit :data:`SPOT_MEMORY`. A
    quantised estimator's measurand that never left its step is given ``step / sqrt(12)``
    as ``mtplan simulate`` states it.
    """
    key = (proc.name, setup_key(setup), estimator)
    cached = _spots.get(key)  # (one not made within the live budget is made with more)
    if cached is not None and (cached.get("trials") or budget_s <= SPOT_BUDGET_S):
        return cached
    from mtplan.evaluation.simulation import procedure_block
    from mtplan.uncertainty.streams import as_seed_sequence

    floats = sum(src.size for src in proc.active_sources(setup).values())
    per = trial_seconds(proc, setup, estimator)
    by_time, by_memory = budget_s / max(per, 1e-9), SPOT_MEMORY / (80.0 * floats + 1)
    live = budget_s <= SPOT_BUDGET_S
    n = int(min(SPOT_TRIALS, by_time, by_memory if live else math.inf))
    if n < SPOT_MIN_TRIALS:
        reason = (f"a check by {SPOT_MIN_TRIALS} Monte Carlo trials would hold about "
                  f"{SPOT_MIN_TRIALS * 80.0 * floats / 1e6:.0f} MB" if by_memory < by_time
                  else f"a check by {SPOT_MIN_TRIALS} Monte Carlo trials would take about "
                       f"{SPOT_MIN_TRIALS * per:.2g} s")
        out = {"trials": 0, "reason": reason, "seconds": 1.0 + SPOT_TRIALS * per}
        remember(key, out)
        return out
    block = max(1, int(min(n, by_memory)))  # one block live; a job's in memory-sized ones
    try:
        with one_blas_thread():
            parts = [procedure_block(proc, setup, proc.Truth(), estimator,
                                     tuple(proc.active_sources(setup)),
                                     as_seed_sequence(_SPOT_SEED), i, min(block, n - i * block))
                     for i in range(-(-n // block))]
        est = {m.name: np.concatenate([np.asarray(p[m.name], dtype=float) for p in parts])
               for m in proc.measurands(setup)}
    except InvalidInput as exc:  # the estimator refuses the trials (fits that fail)
        out = {"trials": n, "failed": " ".join(exc.problems)}
    else:
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
    remember(key, out)
    return out


def remember(key: tuple, spot: dict) -> None:
    """Keep a spot check made for (procedure, :func:`setup_key`, estimator): by a live
    request or by a check job in its own process."""
    _spots[tuple(key)] = spot
    while len(_spots) > 512:
        _spots.pop(next(iter(_spots)))


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
    """Measurand -> ``{"trust": state, "why": text, "todo": text, "mc_u": u}``, the state
    one of three:

    - ``"ok"``, checked: the spot check's u lies within :func:`trust_ratio` of first order;
    - ``"no"``, failed: first order gives u = 0 while the Monte Carlo does not (a measurand
      the linearisation is blind to, or a quantised one), the estimator's values come in
      steps larger than u, the spot check's u differs by more than :func:`trust_ratio`, or
      the spot check's trials fail (``mtplan simulate`` refuses such a set-up);
    - ``"unchecked"``, not checked: with ``pending`` True until the spot check is made,
      False where it is too costly for a live answer (``check_s``: what a check job takes).

    ``why`` says the reason in words, ``todo`` what to do about it (``whole`` True where the
    reason is the set-up's, the same for every measurand). `steps` (measurand ->
    step [display unit], :func:`resolution_steps`) judge before the check.
    """
    out = {}
    confirm = "confirm the set-up by Monte Carlo, whose u is the one to use"
    for name, u in pred_u.items():
        step = (steps or {}).get(name)
        if spot and spot.get("failed"):
            out[name] = {"trust": "no", "mc_u": None, "whole": True,  # the set-up's, not a cell's
                         "why": f"the check by {spot['trials']} Monte Carlo trials failed: "
                                f"{spot['failed']}",
                         "todo": "change the set-up as the message says (mtplan simulate "
                                 "refuses it too), or choose another estimator"}
            continue
        if step and step > u:
            out[name] = {"trust": "no", "mc_u": None, "todo": confirm,
                         "why": f"the estimator's values come in steps of {step:.3g}, "
                                "more than u"}
            continue
        if u <= 0 and not (spot and spot.get("trials")):
            out[name] = {"trust": "no", "mc_u": None, "todo": confirm,
                         "why": "u = 0 at first order: the linearisation does not see it"}
            continue
        if spot is None:
            out[name] = {"trust": "unchecked", "pending": True, "mc_u": None,
                         "why": "being checked against a small Monte Carlo",
                         "todo": "wait for the check (a second or two)"}
            continue
        if not spot.get("trials"):
            out[name] = {"trust": "unchecked", "pending": False, "mc_u": None,
                         "check_s": spot.get("seconds"),
                         "why": f"not checked: {spot.get('reason')}, too costly for a live "
                                "answer",
                         "todo": f"check it (about {spot.get('seconds', 0):.0f} s in the "
                                 "background)"}
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
        out[name] = ({"trust": "ok", "why": f"agrees with {n} Monte Carlo trials", "mc_u": mc,
                      "todo": ""}
                     if why is None else {"trust": "no", "why": why, "mc_u": mc,
                                          "todo": confirm})
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
