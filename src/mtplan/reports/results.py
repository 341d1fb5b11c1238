"""The results table of a test report, printed so that a reader can redo every verdict.

Per toleranced measurand: the tolerance, the acceptance limits and the guard band w the
plan agreed, the measured value, U achieved (and U predicted) with the coverage each has
(the fraction of its distribution within ± U, :mod:`mtplan.uncertainty.coverage`), and the
verdict, which is the ISO 14253-1 zone the value lies in. w is printed to the step the
plan rounded it to (:func:`~mtplan.plans.acceptance.agreed_resolution`), so the printed
limits are exactly the ones decided with; :func:`rounding_sentence` says how. Formatting
only.
"""

from __future__ import annotations

from mtplan.reports.labels import fmt, fmt_u, tolerance_text
from mtplan.uncertainty.coverage import ASSUMED, common_text, coverage_text
from mtplan.reports.model import Table
from mtplan.reports.wording import measurand_name, verdict_short

__all__ = ["verdict_rows", "verdict_table", "rounding_sentence", "ZONES", "limit_text",
           "w_step", "at_default_truth", "DEFAULT_TRUTH_NOTE", "ASYMMETRIC_NOTE",
           "asymmetric_mark"]

#: the zones a verdict names, as the report states them under its table
ZONES = ("The verdict is the zone of ISO 14253-1 the measured value lies in: pass within "
         "the acceptance limits; conditional pass between an acceptance limit and its "
         "tolerance limit (the guard band inside the tolerance); conditional fail between the "
         "tolerance limit and the tolerance widened by w; fail beyond that. A value exactly "
         "on a limit lies inside it.")


#: the note under a table whose values carry :func:`asymmetric_mark`
ASYMMETRIC_NOTE = ("†: the 95 % interval is not value ± U: it is the interval of the "
                   "values' own distribution (Monte Carlo or posterior, JCGM 101 7.7), "
                   "which is asymmetric or centred away from the bias-corrected value; U is "
                   "2u of the same distribution.")


def asymmetric_mark(value, U, low, high) -> str:
    """"†" where an end of the printed interval differs from value ± U by more than 5 % of
    U (:data:`ASYMMETRIC_NOTE`; a normal distribution's 1.96 u against U = 2 u is 2 %),
    else ""."""
    if value is None or U is None or low is None or high is None or not U > 0:
        return ""
    if abs((value - U) - low) > 0.05 * U or abs((value + U) - high) > 0.05 * U:
        return " †"
    return ""


def w_step(o, v) -> float | None:
    """The step the plan stated w and the acceptance limits to [unit]: the decimal of U
    predicted's second significant digit, or its first where the Monte Carlo does not
    support two (:func:`~mtplan.plans.acceptance.agreed_resolution`)."""
    from mtplan.plans.acceptance import agreed_resolution

    if not v.u:
        return None
    r = None if o is None else (o.results.get(v.estimator) or o.results.get(o.recommended))
    trials = int(getattr(getattr(r, "mc", None), "trials", 0) or 0)
    return agreed_resolution(v.u, trials)


def _at(x, step) -> str:
    """A limit or w printed to the plan's step (:func:`fmt` keeps two significant digits
    of its second argument, so ten steps print to the step itself)."""
    return fmt(x, None if step is None else 10 * step)


def limit_text(v, step) -> str:
    """"[-8.0, 8.0]": the acceptance limits as decided with; "-" without a rule."""
    lo, hi = v.acceptance_limits
    if v.guard_band is None or v.guard_band != v.guard_band:
        return "-"
    return (f"[{'-∞' if lo is None else _at(lo, step)}, "
            f"{'∞' if hi is None else _at(hi, step)}]")


#: the note under a table whose U achieved carries :func:`at_default_truth`'s mark
DEFAULT_TRUTH_NOTE = ("‡: U achieved from a Monte Carlo at the procedure's default truth, not "
                      "at the estimate (the procedure cannot set its truth from an estimate): "
                      "it is the set-up's U, close to the prediction by construction, and not "
                      "evaluated at the measured machine.")


def at_default_truth(o) -> bool:
    """Whether a test's U achieved came from a Monte Carlo at the procedure's default truth
    (a Monte Carlo evaluation of a procedure that builds no truth from an estimate,
    ``Capabilities.builds_truths``)."""
    m = o.measured
    return (m is not None and getattr(m, "uncertainty", "") == "mc"
            and not o.spec.procedure.capabilities.builds_truths)


def verdict_rows(k, o) -> list:
    """One row per toleranced measurand of test ``k``."""
    rows = []
    for v in o.verdicts:
        step = w_step(o, v)
        res = None if v.measured_u is None else 2 * v.measured_u
        measured = "-" if v.measured is None else fmt(v.measured, res)
        measured += asymmetric_mark(v.measured, res, v.measured_low, v.measured_high)
        achieved = "-" if res is None else fmt_u(res)
        w = "-" if v.guard_band is None or v.guard_band != v.guard_band else \
            _at(v.guard_band, step)
        mark = " ‡" if res is not None and at_default_truth(o) else ""
        rows.append([str(k), measurand_name(v.description, v.measurand),
                     tolerance_text(v.lower, v.upper, v.unit, v.zone), limit_text(v, step), w,
                     measured, f"{achieved}{mark} ({fmt_u(2 * v.u)})",
                     f"{covers_text(v)} ({coverage_text(v.U_coverage, se=v.U_coverage_se)})",
                     verdict_short(v.verdict)])
    return rows


def covers_text(v) -> str:
    """The coverage of ± U achieved of a verdict, as its table prints it."""
    if v.measured_u is None:
        return "-"
    return coverage_text(v.measured_U_coverage, assumed=v.measured_U_from == ASSUMED,
                         se=v.measured_U_coverage_se)


def verdict_table(result, tests: list) -> Table:
    """The verdicts of every test, each redone from its own row (:data:`ZONES`); where a
    test states a correction of a measurand, a column before the verdict with the residual
    predicted after compensation (:func:`~mtplan.reports.along.residual_text`)."""
    from mtplan.reports.along import residual_text

    rows = [row[:-1] + [residual_text(o, v)] + row[-1:]
            for k, o in enumerate(result.outcomes, start=1)
            if o.verdicts for row, v in zip(verdict_rows(k, o), o.verdicts, strict=True)]
    header = ["test", "measurand", "tolerance", "acceptance limits", "w", "measured",
              "U achieved (predicted)", "±U covers", "after compensation (predicted)",
              "verdict"]
    corrected = any(row[-2] != "-" for row in rows)
    if not corrected:  # no test states a correction
        rows, header = [row[:-2] + row[-1:] for row in rows], header[:-2] + header[-1:]
    pairs = [pair for o in result.outcomes for v in o.verdicts
             for pair in ((v.measured_U_coverage, v.measured_U_coverage_se),
                          (v.U_coverage, v.U_coverage_se))]
    about = common_text([p for p, _ in pairs], [se for _, se in pairs])
    return Table("Results as found. Tests: " + "; ".join(tests) + ". Acceptance limits and "
                 "w as the plan agreed them; measured value and U achieved (k = 2), U "
                 "predicted in parentheses; ±U covers: the fraction of each value's "
                 "distribution within ± U" + (f" ({about} for every U)" if about else "")
                 + ", achieved (predicted)"
                 + ("; after compensation: the residual's 95 % interval (below)."
                    if corrected else "."),
                 # ten columns: a point smaller, so that a measurand's name still wraps at
                 # most twice
                 header, rows, grow=1, size=6.5 if corrected else 7.0,
                 whole=(len(header) - 1,))


def rounding_sentence(result) -> str:
    """How w was rounded, once for every measurand, with the first measurand whose printed
    w reads above its printed U as the example."""
    pairs = [(o, v) for o in result.outcomes for v in o.verdicts
             if v.guard_band and v.guard_band == v.guard_band and v.u]
    if not pairs:
        return ""
    example = ""
    for o, v in pairs:
        w, big_u = _at(v.guard_band, w_step(o, v)), fmt_u(2 * v.u)
        if w != big_u:
            example = (f" ({v.measurand}: U predicted {2 * v.u:.4g} is printed {big_u}, w "
                       f"{w})")
            break
    return ("How w was rounded: the rule gives w (w = U predicted for the ISO 14253-1 rule); "
            "the plan rounded it up, never down, to the last printed digit of U predicted, so "
            "the acceptance zone is never wider than the rule's and the printed limits are "
            "exactly the ones decided with. U itself is printed rounded to the nearest "
            f"digit, so w may read one digit above U{example}.")
