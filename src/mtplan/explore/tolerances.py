"""The acceptance figures of a toleranced measurand (``mtplan accept``'s numbers for the
live u) and the population (prior) a tolerance row states."""

from __future__ import annotations

import io
import re

from mtplan._validate import InvalidInput

__all__ = ["acceptance_figures", "input_problem", "PRIOR_TEXT", "tolerance_prior"]


def acceptance_figures(tol: dict, u: float) -> dict:
    """``mtplan accept``'s figures of a tolerance row for the live u, with what the page
    shows them with: the risk curve, the zones and the judgement (one-sided tolerances
    included), all from :mod:`mtplan.plans.acceptance`; ``{"error": text}`` for a row it
    refuses."""
    from mtplan.plans import acceptance as acc

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
        r = acc.plan_acceptance(lower, upper, u, prior=prior, rule=rule, measured=measured)
    except InvalidInput as exc:
        return {"error": " ".join(exc.problems)}
    out = r.to_dict()
    out["measured"], out["decision"] = measured, r.decision
    out["guard_band"] = r.guard_band
    out["rule"] = rule
    out["prior"] = prior_text
    out["lower"], out["upper"], out["u"] = lower, upper, u
    out["p_conform"] = r.p_conform_prior  # the share of good machines (for the verdict)
    out["zones"] = acc.zones(r)
    out["judgement"] = acc.judgement(r, items="machines")
    out["curve"] = acc.risk_curve(lower, upper, u, prior) if prior is not None else None
    return out


def input_problem(tol: dict) -> str | None:
    """What is wrong with a tolerance row as entered, whatever the u (limits that are not
    numbers, a prior or a rule that is refused), or None: said beside the row even where
    its u is not a checked number and no figures are given."""
    from mtplan.plans.acceptance import parse_rule

    for key in ("lower", "upper", "measured"):
        v = tol.get(key)
        if v is None or (isinstance(v, str) and not v.strip()):
            continue
        try:
            float(v)
        except (TypeError, ValueError):
            return (f"The 'measured' value must be a number. Got {v!r} instead."
                    if key == "measured" else
                    f"The tolerance limits must be numbers. Got {tol.get('lower')!r} "
                    f"and {tol.get('upper')!r} instead.")
    try:
        tolerance_prior(tol)
        parse_rule((tol.get("rule") or "simple").strip())
    except InvalidInput as exc:
        return " ".join(exc.problems)
    return None


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
