"""Warnings before signing: the agreed decisions that are unlikely to be reachable.

A plan whose rule leaves a conforming machine a large chance of not passing (its global
probability of false reject, PFR), whose test uncertainty ratio is small, or whose
acceptance zone is a small share of the tolerance, will most likely end without a
decision; the party that carries the burden of proof should know before it signs.
:func:`signing_warnings` flags each such measurand against stated bounds and computes what
would fix it: the cheapest swept set-up of the study whose U brings PFR under its bound,
else the largest guard band (``guard:R``, R = 0.75, 0.5, 0.25, then simple acceptance) that
does, with the false-accept risk the customer then carries. Numbers only; the plan phrases
them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mtplan._validate import InvalidInput

__all__ = ["PFR_BOUND", "TUR_BOUND", "ZONE_SHARE", "RULE_LADDER", "SigningWarning",
           "signing_warnings"]

#: a conforming machine's chance of not passing above which the decision is unlikely
PFR_BOUND = 0.25
#: the test uncertainty ratio below which U takes too much of the tolerance
TUR_BOUND = 2.0
#: the share of the tolerance's width under which the acceptance zone is too narrow
ZONE_SHARE = 0.5
#: the rules tried, narrowest guard band last
RULE_LADDER = ("guard:0.75", "guard:0.5", "guard:0.25", "simple")


@dataclass
class SigningWarning:
    """One measurand whose agreed decision is unlikely to be reachable (display units).

    ``why``: the bounds it breaks, each (name, value, bound); ``setup``: (field, value, U,
    PFR, duration_s) of the cheapest swept set-up that brings PFR under the bound, or None;
    ``rule``: (rule, w, PFR, PFA) of the widest rule of :data:`RULE_LADDER` that does, or
    None."""

    procedure: str
    label: str
    measurand: str
    unit: str
    why: list
    setup: tuple | None = None
    rule: tuple | None = None


def _plan(v, u, rule, trials):
    from mtplan.plans import acceptance as acc

    try:
        return acc.plan_acceptance(v.lower, v.upper, u, prior=v.prior,
                                   rule=acc.parse_rule(rule),
                                   resolution=acc.agreed_resolution(u, trials))
    except InvalidInput:
        return None


def _setup_fix(o, v, trials, pfr_bound):
    """The cheapest swept value of a lever whose U (the agreed U scaled by the sweep's
    ratio to its value at the agreed set-up) brings PFR under the bound, with the agreed
    rule."""
    best = None
    base = o.spec.setup.as_dict()
    for spec, table in o.sweeps:
        if isinstance(table, str) or len(spec["vary"]) != 1:
            continue
        f = next(iter(spec["vary"]))
        if f not in o.spec.procedure.levers:
            continue
        rows = table[(table["measurand"] == v.measurand) & (table["estimator"] == v.estimator)]
        ref = rows[[_same(x, base.get(f)) for x in rows[f]]]
        if not len(ref) or not float(ref["u"].iloc[0]) > 0:
            continue
        for r in rows.itertuples():
            u = v.u * float(r.u) / float(ref["u"].iloc[0])
            if not u > 0 or _same(getattr(r, f), base.get(f)):
                continue
            p = _plan(v, u, v.rule, trials)
            if p is None or p.pfr is None or p.pfr > pfr_bound:
                continue
            cand = (f, getattr(r, f), 2 * u, p.pfr, float(getattr(r, "duration_s", math.nan)))
            if best is None or cand[4] < best[4]:
                best = cand
    return best


def _same(a, b) -> bool:
    try:
        return math.isclose(float(a), float(b), rel_tol=1e-9, abs_tol=1e-12)
    except (TypeError, ValueError):
        return str(a) == str(b)


def signing_warnings(result, *, pfr_bound: float = PFR_BOUND, tur_bound: float = TUR_BOUND,
                     zone_share: float = ZONE_SHARE) -> list:
    """The measurands of a computed study whose agreed decision is unlikely to be
    reachable, each with its fixes (see the module notes)."""
    out = []
    for o in result.outcomes:
        for v in o.verdicts:
            if v.lower is None or v.upper is None or not (v.u and v.u > 0) \
                    or v.guard_band != v.guard_band:
                continue
            width = v.upper - v.lower
            lo, hi = v.acceptance_limits
            zone = (hi - lo) / width if lo is not None and hi is not None else 1.0
            why = []
            if v.pfr is not None and v.pfr > pfr_bound:
                why.append(("PFR", v.pfr, pfr_bound))
            if v.tur is not None and v.tur < tur_bound:
                why.append(("TUR", v.tur, tur_bound))
            if zone < zone_share:
                why.append(("acceptance zone", zone, zone_share))
            if not why:
                continue
            r = o.results.get(v.estimator) or o.results.get(o.recommended)
            trials = int(getattr(getattr(r, "mc", None), "trials", 0) or 0)
            w = SigningWarning(v.procedure, v.label, v.measurand, v.unit, why)
            w.setup = _setup_fix(o, v, trials, pfr_bound)
            for rule in RULE_LADDER:
                p = _plan(v, v.u, rule, trials)
                if p is not None and p.pfr is not None and p.pfr <= pfr_bound:
                    w.rule = (rule, p.guard_band, p.pfr, p.pfa)
                    break
            out.append(w)
    return out
