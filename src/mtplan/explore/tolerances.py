"""The acceptance figures of a toleranced measurand (``mtplan accept``'s numbers for the
live u) and the population (prior) a tolerance row states."""

from __future__ import annotations

import io
import re

from mtplan._validate import InvalidInput
from mtplan.explore.state import K

__all__ = ["acceptance_figures", "GUARDS", "risk_curve", "PRIOR_TEXT", "tolerance_prior"]


def acceptance_figures(tol: dict, u: float) -> dict:
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
    try:  # a value measured on a machine: its specific risk (JCGM 106: 1 - p_c) and decision
        measured = num("measured")
    except (TypeError, ValueError):
        return {"error": f"The 'measured' value must be a number. Got {tol.get('measured')!r} "
                         "instead."}
    rule = (tol.get("rule") or "simple").strip()
    try:
        prior, prior_text = tolerance_prior(tol)
        r = plan_acceptance(lower, upper, u, prior=prior, rule=rule, measured=measured)
    except InvalidInput as exc:
        return {"error": " ".join(exc.problems)}
    out = r.to_dict()
    out["measured"], out["decision"] = measured, r.decision
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


PRIOR_TEXT = re.compile(r"\s*(normal|gamma)\s*:", flags=re.I)


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
    if not PRIOR_TEXT.match(text):
        raise InvalidInput([f"The 'prior' (population) must be 'normal:MEAN,SD', "
                            f"'gamma:SHAPE,SCALE' or a CSV file uploaded with its button; the "
                            f"designer reads no file on the server. Got {text[:60]!r} instead."])
    return parse_prior(text), text


def _renamed(problems, name: str) -> list:
    """The CSV reader's messages with the uploaded file's name for the in-memory one."""
    return [re.sub(r"'<_io\.StringIO object at 0x[0-9a-f]+>'", repr(name), m) for m in problems]
