"""Words a customer reads: the methods' sources, plain measurand names, probabilities and
decision rules in the wording of ILAC-G8, and the glossary. Formatting only."""

from __future__ import annotations

import math

__all__ = ["method_citation", "customer_words", "measurand_name",
           "probability_text", "p_text", "rule_wording", "rules_text", "population_text",
           "value_warnings", "VERDICT_SHORT", "verdict_short", "BURDEN_OF_PROOF",
           "OVERALL_RULE", "GLOSSARY"]


def method_citation(procedure) -> str:
    """The source method of a procedure, cited once from its record
    (``Procedure.source_method``): the document that publishes it (a patent number, a
    standard) and its title, or, where the copies it was built from state no number, by
    title, applicant and date (the test itself is identified by mtplan procedure and version,
    :func:`method_id`)."""
    source = procedure.source_method
    if not source.title:
        return "no published source method"
    if source.document:
        return (f"{source.document}, \u201c{source.title}\u201d"
                + (f" ({source.who})" if source.who else ""))
    return f"\u201c{source.title}\u201d ({source.who}; cited by title)"


def customer_words(text: str) -> str:
    """Developer wording in a model's documentation as a customer reads it: "the patent's
    method" is the source method, cited once by its number and title elsewhere; um and
    urad as µm and µrad."""
    import re

    text = re.sub(r"\b([Tt])he patent's method\b", r"\1he source method", text)
    text = re.sub(r"\b([Tt])he patent's own\b", r"\1he source method's own", text)
    text = re.sub(r"\b([Tt])he patent's\b", r"\1he source method's", text)
    # units as printed: "um" and "urad" stand alone (never inside a field name such as
    # probe_noise_um)
    text = re.sub(r"(?<![A-Za-z_])u(m|rad)(?![A-Za-z_])", "\u00b5\\1", text)
    # degrees Celsius and plus-minus as printed
    return re.sub(r"(?<![A-Za-z_])degC\b", "\u00b0C", text).replace("+-", "\u00b1")


def measurand_name(description: str, code: str) -> str:
    """A measurand's plain name with its code in parentheses: "X position of the C axis at
    the reference height (EX0C)"."""
    text = description.strip().rstrip(".")
    if not text:
        return code
    return f"{text[:1].upper()}{text[1:]} ({code})"


def probability_text(p, low=None, high=None, lower=None, upper=None) -> str:
    """A probability of conformity in per cent, consistent with the measured interval
    [low, high]: never "100 %" or "0 %" (a Monte Carlo or normal tail is never exactly
    zero) and, where the interval overlaps a tolerance limit, at most "> 99.9 %" and at
    least "< 0.1 %" so the figure cannot read as certain."""
    if p is None or not math.isfinite(p):
        return "-"
    p = min(max(float(p), 0.0), 1.0)
    if p > 0.999:
        return "> 99.9 %"
    if p < 0.001:
        return "< 0.1 %"
    x = 100 * p
    if x >= 99.5 or x < 0.5:
        return f"{x:.1f} %"
    return f"{x:.0f} %" if x >= 10 else f"{x:.1f} %"


def p_text(p) -> str:
    """A p-value with the precision it has: "< 0.001", "0.042", "0.42", "> 0.99" (a
    p-value clipped at 1 by a Bonferroni bound is "> 0.99", never "1"); "-" for none."""
    if p is None or not math.isfinite(p):
        return "-"
    if p < 0.001:
        return "< 0.001"
    if p > 0.99:
        return "> 0.99"
    return f"{p:.2g}" if p < 0.1 else f"{p:.2f}"


def population_text(prior_words: str, source: str) -> str:
    """The population of items a risk assumes, with its stated source."""
    if not prior_words:
        return "no population stated (risks not evaluated)"
    return f"{prior_words}; source: {source or 'not stated in the study'}"


def rule_wording(rule: str, guard_band: float) -> str:
    """The decision rule in the words of ILAC-G8:09/2019 (w itself is in the tables)."""
    kind, _, value = str(rule).partition(":")
    if kind == "simple" or not guard_band:
        return ("simple acceptance (ILAC-G8 4.2.1, binary, no guard band): pass if the "
                "measured value lies within the tolerance, fail otherwise")
    how = {"iso14253": "w = U, the ISO 14253-1 default rule, rounded up to the last printed "
                       "digit of U (so w may read one digit above U)",
           "guard": f"w = {value or '1'} U, rounded up to the last printed digit of U",
           "target-pfa": f"w set for a global false-accept risk of {value}",
           "dobbert": "w from Dobbert's managed guard band"}.get(kind, kind)
    return (f"non-binary with guard band (ILAC-G8 4.2.3; {how}, U predicted): pass within "
            "the tolerance reduced by w; fail beyond the tolerance widened by w; in the guard "
            "band conditional pass (inside the tolerance) or conditional fail (outside it)")


#: who carries the uncertainty (ISO 14253-1:2017 5), as both documents state it
BURDEN_OF_PROOF = (
    "Burden of proof (ISO 14253-1): the machine builder (supplier) proves conformity, so the "
    "uncertainty counts against a pass: a pass needs the measured value inside the tolerance "
    "reduced by the guard band w; the customer proves non-conformity, so a fail needs it "
    "beyond the tolerance widened by w. In the guard band (conditional pass, conditional "
    "fail) neither party has proved its case. With simple acceptance (w = 0) both share the "
    "risk at the limit.")

#: how the verdicts of one machine combine into its overall result, as both documents state it
OVERALL_RULE = (
    "Overall acceptance rule, per machine: accepted when every toleranced measurand of its "
    "tests passes; not accepted when any fails; otherwise (a conditional pass or conditional "
    "fail, or a measurand without a decision, and no fail) no decision, and the clause for a "
    "conditional result applies.")


def rules_text(verdicts) -> list:
    """Each distinct decision rule of a list of verdicts once, naming its measurands."""
    groups: dict = {}
    for v in verdicts:
        key = rule_wording(v.rule, v.guard_band)
        groups.setdefault(key, []).append(v.measurand)
    return [f"Decision rule for {', '.join(names)}: {text}." for text, names in groups.items()]


#: a verdict as a table column or a panel title shows it (the full wording stays in the
#: CSV and the rules)
VERDICT_SHORT = {"no decision: the readings do not fit the model":
                     "no decision (readings do not fit)",
                 "no statement: an instrument was not calibrated on the test date":
                     "no statement (instrument)",
                 "no decision: the achieved U exceeds the agreed U": "no decision (U too large)",
                 "no statement: a test condition was outside the agreement or not recorded":
                     "no statement (conditions)"}


def verdict_short(verdict: str) -> str:
    """A verdict short enough for a table column or a figure panel's title."""
    return VERDICT_SHORT.get(verdict, verdict)


def value_warnings(items, *, bound: bool = True, resolution: bool = True) -> tuple[list, set]:
    """The warnings a reader must see under a table of values: ``items`` holds (label,
    value, u, low, high) per row; returns (sentences, labels warned about). ``bound`` and
    ``resolution`` switch the two checks:

    - An interval that ends exactly at zero while the value does not: the estimator
      cannot pass that physical bound (an angle from an arccos), so the value and u are
      pushed away from it and the interval is cut by it: not a valid result.
    - The interval [low, high] holds zero (value ± 2u where no interval is given): the
      value is not resolved (it does not differ from zero), decided by the interval printed.
    """
    check_bound, at_bound, unresolved = bound, [], []
    for label, value, u, low, high in items:
        if value is None or u is None or not (math.isfinite(value) and math.isfinite(u)
                                              and u > 0 and value != 0):
            continue
        scale = max(abs(value), u)
        if check_bound and any(end is not None and math.isfinite(end)
                               and abs(end) <= 1e-9 * scale for end in (low, high)):
            at_bound.append(label)
        # decided by the interval printed beside it where there is one, else by value ± U
        inside = (low <= 0 <= high if low is not None and high is not None
                  and math.isfinite(low) and math.isfinite(high) else 2 * u >= abs(value))
        if resolution and inside:
            unresolved.append(label)
    out = []
    if at_bound:
        out.append(f"{', '.join(at_bound)}: the interval ends at the physical bound 0, which "
                   "the estimator cannot pass: the value and u are pushed away from it and "
                   "the interval is cut by it; not a valid result.")
    if unresolved:
        out.append(f"{', '.join(unresolved)}: the 95 % interval includes zero: the value is "
                   "not resolved (it does not differ from zero).")
    return out, set(at_bound) | set(unresolved)


GLOSSARY = [
    ["U, k", "expanded uncertainty U = k u with coverage factor k = 2, the U the decision "
             "rules use; the coverage it has is printed beside it"],
    ["±U covers", "the fraction of a value's distribution (Monte Carlo or posterior) within "
                  "± U: the coverage probability U really has (95.4 % for a normal "
                  "distribution, more or less for others), counted to a standard error of "
                  "0.3 % or better (with the first-order model as the count's control "
                  "variate where the trials alone do not), else printed with its standard "
                  "error (95.0 % ± 1.1 %)"],
    ["U predicted", "U of the planned set-up from a Monte Carlo simulation of every error "
                    "source (JCGM 101), fixed in the test plan"],
    ["U achieved", "U of the measurement's own evaluation of its readings"],
    ["TUR", "test uncertainty ratio: the tolerance width divided by 2U (predicted)"],
    ["guard band w", "the distance between a tolerance limit and its acceptance limit; the "
                     "decision rule of the test plan fixes it before measuring"],
    ["PFA", "probability of false accept: the global risk (JCGM 106 9.5) that an item of the "
            "stated population is accepted although it does not conform"],
    ["PFR", "probability of false reject: the global risk that an item of the stated "
            "population that conforms gets no pass (a conditional pass, conditional fail or "
            "fail)"],
    ["probability of conformity", "the probability that the true value lies within the "
                                  "tolerance, given the measured value and its U "
                                  "(JCGM 106 7.4); from the measurement alone unless "
                                  "stated otherwise"],
    ["population", "the distribution of the true values over the items of this kind (the "
                   "prior of the risks), with the source the study states"],
    ["pass, conditional pass, conditional fail, fail", "the outcomes of ILAC-G8:09/2019 "
     "4.2.3 agreed in the test plan: pass within the acceptance limits (the tolerance reduced "
     "by w), fail beyond the tolerance widened by w; in the guard band a conditional pass "
     "(the value inside the tolerance) or a conditional fail (outside it)"],
    ["no decision", "this tool's words, not ILAC-G8's: no statement of conformity is made "
                    "(the readings do not fit the model, an instrument was not valid on the "
                    "test date, or a machine's verdicts are conditional)"],
    ["O1-O5", "observability indices of a set-up from the singular values s1 >= ... >= sL "
              "of the readings' scaled sensitivity matrix over m poses: O1 their geometric "
              "mean over the square root of m, O2 = sL/s1 (inverse condition number), O3 = sL "
              "(the smallest), O4 = sL²/s1 (noise amplification), O5 = 1/(1/s1 + ... + "
              "1/sL); larger is better, all are 0 when a parameter cannot be determined"],
    ["identifiability", "whether the readings determine every parameter of the model (full "
                        "rank) and how well (condition number)"],
    ["estimator", "the calculation that turns readings into results: patent (the source "
                  "method's own steps), three_point (the three-point rule), kasa and geometric "
                  "(least-squares circles, algebraic and geometric), joint and joint_linear (fits "
                  "of all readings at once, Gauss-Newton and linearised), angles and home (fits "
                  "that use the commanded angles "
                  "or the shared home point), gls (generalised least squares of the whole "
                  "model), registration and pattern (fits of the scans to each other or to "
                  "the artefact's known pattern)"],
    ["as found / as left", "results before / after any adjustment made during the visit"],
    ["lever", "a set-up choice of the test engineer (counts, geometry, order, dwell)"],
    ["MDB", "minimal detectable bias: the smallest gross error of one reading (or one "
            "contact) that the fit check detects with 80 % probability; a smaller one passes "
            "more often than not"],
]
