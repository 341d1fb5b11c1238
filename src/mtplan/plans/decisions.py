"""What a study concludes, as numbers the reports only phrase and draw.

- :func:`recommend_estimator`: the estimator with the smallest root-mean-square error
  (standard uncertainty and bias together) over the measurands that matter, the one
  listed first (the patent's method) unless another is better beyond the Monte Carlo error.
- :func:`conformity`: the verdict of every toleranced measurand, its acceptance plan
  (guard band, global risks, TUR; JCGM 106, ISO 14253-1) applied to the measured value.
- :func:`lever_effects`: the set-up's own levers (``Procedure.levers``) ranked by how much
  their swept values lower the uncertainty: the advice an engineer can act on.
- :func:`dominant_sources`: the error sources that dominate a measurand's variance, each
  marked as a lever or as a property of the machine, workpiece or instrument.
- :func:`summary_rows`: one row per procedure and measurand that matters, for the one-page
  summary and ``results/verdicts.csv``.

Verdicts follow ISO 14253-1's zones with the rule's guard band ``w`` on both sides of each
tolerance limit, in the words of ILAC-G8:09/2019 4.2.3 that the plan agrees: *pass* inside
the tolerance reduced by ``w``, *fail* outside the tolerance widened by ``w``, and in the
guard band *conditional pass* (the value inside the tolerance) or *conditional fail* (outside
it): neither party has proved its case there (ISO 14253-1: the supplier proves conformity,
the customer non-conformity). With ``w = 0`` (simple acceptance) every value passes or fails.
A measured value whose readings do not fit the model (its fit check failed,
:func:`fit_verdict`) gets no decision at all: its uncertainty is not valid.
The acceptance limits are those of the plan (set before measuring, from the planned set-up's
uncertainty); the measured value's own interval is reported beside them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.uncertainty.coverage import K as COVERAGE_K

__all__ = ["K", "VERDICTS", "PASS", "CONDITIONAL_PASS", "CONDITIONAL_FAIL", "FAIL", "Verdict",
           "LeverEffect", "SummaryRow", "recommend_estimator", "key_measurands", "conformity",
           "position_verdict", "decide", "fit_verdict", "lever_effects", "dominant_sources",
           "estimator_comparison", "u_targets", "shown_setup", "summary_rows",
           "RANDOM_ON_REPEAT", "random_share", "repeats_needed", "repeated_U"]

#: coverage factor of the expanded uncertainty U = k u that decides (ISO 14253-1, JCGM 106;
#: the coverage each U really has is printed beside it, :mod:`mtplan.uncertainty.coverage`)
K = COVERAGE_K
#: the four outcomes of ILAC-G8:09/2019 4.2.3 with a guard band (pass and fail alone
#: with simple acceptance)
PASS = "pass"
CONDITIONAL_PASS = "conditional pass"
CONDITIONAL_FAIL = "conditional fail"
FAIL = "fail"
CONFORMS, DOES_NOT_CONFORM = PASS, FAIL  # the older names
NOT_DETERMINABLE = "not determinable"
NOT_MEASURED = "not measured"
NO_FIT = "no decision: the readings do not fit the model"
VERDICTS = (PASS, CONDITIONAL_PASS, CONDITIONAL_FAIL, FAIL, NOT_DETERMINABLE, NOT_MEASURED,
            NO_FIT)


@dataclass
class Verdict:
    """The conformity decision for one toleranced measurand (display units).

    Attributes
    ----------
    procedure, label, measurand, unit, description, estimator : str
    lower, upper : float or None
        Tolerance limits [unit]; None for an absent limit.
    u : float
        Standard uncertainty of the planned set-up with ``estimator`` [unit].
    k : float
        Coverage factor of ``U = k u``.
    rule : str
        Decision rule (``simple``, ``guard:R``, ``iso14253``, ``target-pfa:P``, ``dobbert``).
    guard_band : float
        ``w`` [unit]; nan when the plan could not be made.
    acceptance_limits : (float or None, float or None)
        ``(T_L + w, T_U - w)`` [unit].
    prior : prior object or None
        Process distribution of the true value (``plans.acceptance`` priors).
    pfa, pfr, conditional_pfa, tur : float or None
        Global false accept and false reject, ``pfa / P(accept)``, test uncertainty ratio.
    measured, measured_u, measured_low, measured_high : float or None
        Measured value, its standard uncertainty and coverage interval [unit].
    measured_source : str
        Where the measured value comes from ("" when none).
    p_conform : float or None
        Probability that the true value lies within the tolerance given the measured value
        (from the population when there is one; the report's :func:`~mtplan.plans.agreement.
        apply_plan` sets it from the measurement alone and keeps this one in
        ``p_conform_population``).
    population_source : str
        Where the population of items (the prior) comes from, as the study states it.
    verdict : str
        One of :data:`VERDICTS`.
    reason : str
        Why a verdict is "not determinable", or a caution about the decision.
    p_conform_samples : float or None
        The probability of conformity from the measured value's own samples (a position
        zone, whose deviation is not normal); used instead of the normal one.
    zone : dict or None
        For a position tolerance as a diameter zone (ISO 1101): ``position`` (the two
        coordinate measurands), ``nominal`` and ``diameter``; the measurand is then the
        position deviation ``2 sqrt(dx^2 + dy^2)`` with the tolerance 0 to ``diameter``.
    U_coverage, measured_U_coverage : float or None
        The coverage of ``± U`` (the fraction of the distribution within it,
        :mod:`mtplan.uncertainty.coverage`) of U predicted (the planned set-up's Monte
        Carlo) and of U achieved (the measured value's distribution); None where there is
        none.
    U_coverage_se, measured_U_coverage_se : float or None
        Their standard errors (None where the coverage is assumed or there is none).
    measured_U_from : str
        Where ``measured_U_coverage`` comes from (``U_coverage_from`` of the result).
    """

    procedure: str
    label: str
    measurand: str
    unit: str
    description: str
    estimator: str
    lower: float | None
    upper: float | None
    u: float
    rule: str
    k: float = K
    guard_band: float = math.nan
    acceptance_limits: tuple = (None, None)
    prior: object = None
    prior_text: str | None = None
    pfa: float | None = None
    pfr: float | None = None
    conditional_pfa: float | None = None
    tur: float | None = None
    measured: float | None = None
    measured_u: float | None = None
    measured_low: float | None = None
    measured_high: float | None = None
    measured_source: str = ""
    p_conform: float | None = None
    p_conform_population: float | None = None
    population_source: str = ""
    verdict: str = NOT_MEASURED
    reason: str = ""
    p_conform_samples: float | None = None
    zone: dict | None = None
    U_coverage: float | None = None
    measured_U_coverage: float | None = None
    measured_U_from: str = ""
    U_coverage_se: float | None = None
    measured_U_coverage_se: float | None = None

    @property
    def U(self) -> float:  # noqa: N802 - the symbol of ISO 14253-1
        """Expanded uncertainty of the planned set-up, ``k u`` [unit]."""
        return self.k * self.u

    def row(self) -> dict:
        """One row of ``results/verdicts.csv``."""
        a_lo, a_hi = self.acceptance_limits
        return {"procedure": self.procedure, "test": self.label, "measurand": self.measurand,
                "unit": self.unit, "estimator": self.estimator, "lower": self.lower,
                "upper": self.upper, "u": self.u, "k": self.k, "U": self.U,
                "U_coverage": self.U_coverage, "U_coverage_se": self.U_coverage_se,
                "rule": self.rule,
                "guard_band": self.guard_band, "acceptance_lower": a_lo,
                "acceptance_upper": a_hi, "tur": self.tur, "pfa": self.pfa, "pfr": self.pfr,
                "measured": self.measured, "measured_u": self.measured_u,
                "measured_low": self.measured_low, "measured_high": self.measured_high,
                "measured_U": None if self.measured_u is None else self.k * self.measured_u,
                "measured_U_coverage": self.measured_U_coverage,
                "measured_U_coverage_se": self.measured_U_coverage_se,
                "measured_U_coverage_from": self.measured_U_from,
                "measured_source": self.measured_source, "p_conform": self.p_conform,
                "p_conform_population": self.p_conform_population,
                "population_source": self.population_source,
                "verdict": self.verdict, "reason": self.reason}


@dataclass
class LeverEffect:
    """What one swept lever does to the uncertainty of one measurand (display units).

    ``gain`` is u at the study's value over the smallest u in the sweep (>= 1), or the
    largest over the smallest when the study's value is not in the sweep; ``significant``
    says whether it exceeds three Monte Carlo standard errors of the ratio.
    """

    field: str
    measurand: str
    unit: str
    estimator: str
    sweep: int                    # index of the sweep in the procedure's list
    base_value: object
    u_base: float                 # nan when the study's value is not in the sweep
    ref_value: object             # the value compared with: the study's, else the worst
    best_value: object
    u_best: float
    duration_base_s: float
    duration_best_s: float
    gain: float
    significant: bool


@dataclass
class SummaryRow:
    """One row of the summary page: a measurand that matters, with its verdict."""

    section: int
    procedure: str
    label: str
    measurand: str
    unit: str
    description: str
    estimator: str
    setup: dict
    u: float
    k: float
    U: float  # noqa: N815
    duration_s: float
    lower: float | None = None
    upper: float | None = None
    tur: float | None = None
    measured: float | None = None
    measured_u: float | None = None
    measured_low: float | None = None
    measured_high: float | None = None
    verdict: str = ""
    reason: str = ""
    #: the coverage of ± U and of ± U achieved, and their standard errors (:class:`Verdict`)
    U_coverage: float | None = None  # noqa: N815
    measured_U_coverage: float | None = None  # noqa: N815
    U_coverage_se: float | None = None  # noqa: N815
    measured_U_coverage_se: float | None = None  # noqa: N815


# ----------------------------------------------------------------------- estimators
def _rmse(result, names) -> dict:
    """Root-mean-square error sqrt(u^2 + bias^2) per measurand; inf where u == 0 (an
    estimator that gives one value in every trial has an uncertainty the Monte Carlo
    cannot see)."""
    index = {m.name: i for i, m in enumerate(result.measurands)}
    out = {}
    for n in names:
        if n not in index:
            continue
        s, b = float(result.mc.std[index[n]]), float(result.bias[index[n]])
        out[n] = math.hypot(s, b) if s > 0 and math.isfinite(s) else math.inf
    return out


def recommend_estimator(results: dict, names: list) -> str:
    """The estimator to recommend for the measurands ``names``.

    Each estimator's score is its mean ratio of root-mean-square error to the best
    estimator's, over ``names``. The first estimator listed wins unless another scores
    lower by more than three Monte Carlo standard errors of a standard deviation.
    """
    ests = list(results)
    if len(ests) == 1:
        return ests[0]
    errors = {e: _rmse(r, names) for e, r in results.items()}
    best = {n: min(errors[e].get(n, math.inf) for e in ests) for n in names}
    usable = [n for n in names if 0 < best[n] < math.inf]
    if not usable:
        return ests[0]
    score = {e: float(np.mean([errors[e].get(n, math.inf) / best[n] for n in usable]))
             for e in ests}
    trials = min(int(r.mc.trials) for r in results.values())
    tol = 3.0 / math.sqrt(2.0 * max(trials - 1, 1))
    top = min(score.values())
    return next(e for e in ests if score[e] <= top * (1 + tol))


def key_measurands(measurands, toleranced, targeted, limit: int = 4) -> list:
    """The measurands a summary shows: toleranced and targeted ones in the procedure's
    order, else the first ``limit``."""
    names = [m.name for m in measurands]
    chosen = [n for n in names if n in set(toleranced) | set(targeted)]
    return chosen or names[:limit]


def estimator_comparison(results: dict, *, ratio: float = 1.2) -> dict:
    """Significant biases and uncertainty ratios between estimators.

    Returns ``{"bias": [(estimator, measurand, bias, u)], "better": [(better, worse,
    [(measurand, factor)])]}``: a bias counts when it exceeds four Monte Carlo standard
    errors and a tenth of u (any bias when u = 0); an estimator is better for a measurand
    when the other's u is ``ratio`` times larger.
    """
    ests = list(results)
    biases, better = [], []
    for est, r in results.items():
        for i, m in enumerate(r.measurands):
            s, b = float(r.mc.std[i]), float(r.bias[i])
            # with s = 0 (every trial the same value: a quantised estimate) any bias counts
            if abs(b) > 4 * s / math.sqrt(r.mc.trials) and abs(b) > 0.1 * s:
                biases.append((est, m.name, b, s))
    first = results[ests[0]]
    for est in ests[1:]:
        r = results[est]
        for a_name, a, b_name, b in ((est, r, ests[0], first), (ests[0], first, est, r)):
            factors = [(m.name, float(b.mc.std[i] / a.mc.std[i]))
                       for i, m in enumerate(a.measurands)
                       if a.mc.std[i] > 0 and b.mc.std[i] / a.mc.std[i] > ratio]
            if factors:
                better.append((a_name, b_name, factors))
    return {"bias": biases, "better": better}


# ----------------------------------------------------------------------- conformity
def decide(value: float, lower, upper, guard: float) -> str:
    """The ISO 14253-1 zone of a measured value in ILAC-G8 words (see the module notes)."""
    lo = -math.inf if lower is None else float(lower)
    hi = math.inf if upper is None else float(upper)
    if lo + guard <= value <= hi - guard:
        return PASS
    if value < lo - guard or value > hi + guard:
        return FAIL
    return CONDITIONAL_PASS if lo <= value <= hi else CONDITIONAL_FAIL


def fit_verdict(fit) -> tuple[str, str] | None:
    """(:data:`NO_FIT`, why) when the readings failed their fit check, else None.

    A measured value whose readings do not fit the model and its error budget
    (``fit.ok`` False, :func:`mtplan.evaluation.fitcheck.fit_check`) has no valid
    uncertainty, so no conformity decision is made from it; a check that could not be
    made (``ok`` None) or that passed leaves the decision to the zones.
    """
    if fit is None or getattr(fit, "ok", None) is not False:
        return None
    why = (f"{fit.failure_text()}: the stated uncertainty is not valid for these "
           f"readings; worst readings {fit.worst_text()}; find the cause (an outlier, an "
           "effect the set-up's error sources do not have) and measure again")
    return NO_FIT, why


def _coverage_at(result, j) -> tuple[float | None, float | None]:
    """(coverage of ± U, its standard error) of measurand `j` of a result (its
    ``U_coverage`` and ``U_coverage_se``); None for what it gives none of."""
    within = getattr(result, "U_coverage", None)
    if within is None or not math.isfinite(float(within[j])):
        return None, None
    se = getattr(result, "U_coverage_se", None)
    se = None if se is None or not math.isfinite(float(se[j])) else float(se[j])
    return float(within[j]), se


def _measured_coverage(spec, name, measured, predicted) -> tuple:
    """(coverage of ± U achieved, its standard error, where it comes from) of one
    measurand: the measured result's (``U_coverage``), the prediction's (p, se) for a
    value stated in the study (its u is the predicted one)."""
    from mtplan.uncertainty.coverage import MONTE_CARLO

    if spec.get("measured") is not None:
        return (*predicted, MONTE_CARLO)
    if getattr(measured, "U_coverage", None) is None:
        return None, None, ""
    j = [m.name for m in measured.measurands].index(name)
    return (*_coverage_at(measured, j), getattr(measured, "U_from", ""))


def _measured_value(spec, name, measured, u):
    """(value, u, low, high, source, verdict-or-None, reason) of one measurand."""
    if spec.get("measured") is not None:
        y = float(spec["measured"])
        return y, u, y - K * u, y + K * u, "stated in the study", None, ""
    if measured is None:
        return None, None, None, None, "", NOT_MEASURED, "no readings and no measured value"
    names = [m.name for m in measured.measurands]
    j = names.index(name)
    determinable = np.asarray(getattr(measured, "determinable", None)
                              if getattr(measured, "determinable", None) is not None
                              else np.ones(len(names), dtype=bool))
    value = float(measured.value[j])
    how = "posterior" if measured.uncertainty == "posterior" else "Monte Carlo"
    source = f"readings, {measured.estimator} estimator, {how}"
    if not bool(determinable[j]) or not math.isfinite(value):
        reason = (getattr(measured, "reasons", None) or {}).get(
            name, "the estimator gives no finite value from these readings")
        return None, None, None, None, source, NOT_DETERMINABLE, reason
    verdict, reason = fit_verdict(getattr(measured, "fit", None)) or (None, "")
    return (value, float(measured.std[j]), float(measured.low[j]), float(measured.high[j]),
            source, verdict, reason)


def conformity(procedure: str, label: str, specs: list, result, measured=None) -> list:
    """The verdict of every toleranced measurand of one procedure.

    Parameters
    ----------
    procedure, label : str
        The procedure's name and the study's label for the test.
    specs : list of dict
        Acceptance tables of the study: ``measurand``, ``lower``, ``upper``, ``prior``,
        ``rule``, optionally ``measured`` (a value stated instead of readings).
    result : ProcedureResult
        Monte Carlo of the planned set-up with the estimator that decides.
    measured : MeasuredResult, optional
        The readings' evaluation.

    Returns
    -------
    list of Verdict
    """
    from mtplan.plans import acceptance as acc

    out = []
    for spec in specs:
        if "position" in spec:
            out.append(position_verdict(procedure, label, spec, result, measured))
            continue
        name = spec["measurand"]
        i = [m.name for m in result.measurands].index(name)
        m = result.measurands[i]
        u = float(result.mc.std[i])
        prior = acc.parse_prior(spec["prior"]) if spec.get("prior") else None
        rule = spec.get("rule", "simple")
        y, uy, low, high, source, verdict, reason = _measured_value(spec, name, measured, u)
        predicted = _coverage_at(result, i)
        achieved, achieved_se, achieved_from = (
            _measured_coverage(spec, name, measured, predicted) if y is not None
            else (None, None, ""))
        v = Verdict(procedure=procedure, label=label, measurand=name, unit=m.unit,
                    description=m.description, estimator=result.estimator,
                    lower=spec.get("lower"), upper=spec.get("upper"), u=u, rule=str(rule),
                    prior=prior, prior_text=spec.get("prior"),
                    population_source=str(spec.get("population_source", "")),
                    measured=y, measured_u=uy,
                    measured_low=low, measured_high=high, measured_source=source,
                    reason=reason, U_coverage=predicted[0], U_coverage_se=predicted[1],
                    measured_U_coverage=achieved, measured_U_coverage_se=achieved_se,
                    measured_U_from=achieved_from)
        if not (u > 0 and math.isfinite(u)):
            v.verdict = NOT_DETERMINABLE
            v.reason = (f"the {result.estimator} estimator gives the same value in every "
                        "Monte Carlo trial: its uncertainty is its resolution, which the "
                        "simulation cannot see")
            out.append(v)
            continue
        try:
            plan = acc.plan_acceptance(v.lower, v.upper, u, prior=prior,
                                       rule=acc.parse_rule(rule), measured=y,
                                       resolution=acc.agreed_resolution(u, result.mc.trials))
        except InvalidInput as exc:  # a guard band wider than the tolerance: a finding
            v.verdict = NOT_DETERMINABLE
            v.reason = " ".join(exc.problems)
            out.append(v)
            continue
        v.guard_band, v.acceptance_limits = plan.guard_band, tuple(plan.acceptance_limits)
        v.pfa, v.pfr, v.conditional_pfa = plan.pfa, plan.pfr, plan.conditional_pfa
        v.tur, v.p_conform = plan.tur, plan.p_conform
        if verdict is not None:
            v.verdict = verdict
        else:
            v.verdict = decide(y, v.lower, v.upper, v.guard_band)
            if uy is not None and uy > 1.1 * u:
                v.reason = (f"the measurement's u ({uy:.3g} {m.unit}) exceeds the planned "
                            f"u ({u:.3g} {m.unit}) that set the guard band")
        out.append(v)
    return out


# ----------------------------------------------------------------------- position (ISO 1101)
def _joint_samples(measured, names) -> tuple[np.ndarray, str]:
    """Samples (n, 2) of the measured values of two measurands [display unit] and how they
    were drawn: the posterior's draws, or the Monte Carlo's estimation errors about the
    value (the bias correction's own uncertainty added as an independent normal term), or,
    where the Monte Carlo kept no values, a normal distribution with the covariance."""
    index = [[m.name for m in measured.measurands].index(n) for n in names]
    value = np.asarray(measured.value, dtype=float)[index]
    std = np.asarray(measured.std, dtype=float)[index]
    rng = np.random.default_rng(np.random.SeedSequence(
        measured.seed if measured.seed is not None else 0, spawn_key=(1101,)))
    details = measured.details
    if measured.uncertainty == "posterior":
        return (np.column_stack([np.asarray(details.samples[n], dtype=float) for n in names]),
                "posterior draws")
    kept = [details.mc.samples(n) for n in names]
    if any(k is None for k in kept):
        cov = np.asarray(measured.covariance, dtype=float)[np.ix_(index, index)]
        return (rng.multivariate_normal(value, cov, size=200_000),
                "a normal distribution with the measured covariance")
    s = np.column_stack(kept)
    y = value - (s - s.mean(axis=0))
    extra = np.sqrt(np.maximum(std**2 - y.var(axis=0, ddof=1), 0.0))
    return y + rng.standard_normal(y.shape) * extra, "Monte Carlo samples"


def _shortest(x: np.ndarray, coverage: float) -> tuple[float, float]:
    """Shortest interval holding ``coverage`` of the samples ``x`` (JCGM 101 7.7.2)."""
    x = np.sort(x)
    n = x.size
    m = max(1, min(n - 1, int(round(coverage * n))))
    widths = x[m:] - x[:-m]
    j = int(np.argmin(widths))
    return float(x[j]), float(x[j + m])


def position_verdict(procedure, label, spec, result, measured=None) -> Verdict:
    """The verdict of a position tolerance as a diameter zone (ISO 1101).

    The measurand is the position deviation ``P = 2 sqrt(dx^2 + dy^2)`` of the two
    coordinates ``spec["position"]`` from ``spec["nominal"]``, toleranced from 0 to
    ``spec["diameter"]``. Its distribution is not normal (Rice-like near zero): value,
    u, the shortest 95 % interval and the probability of conformity come from the measured
    coordinates' joint samples (:func:`_joint_samples`). The planned u, which sets the
    guard band, is that of P at the zone's edge, where P moves with the coordinates'
    radial error: twice the standard deviation along the planned covariance's major axis.
    """
    from mtplan.plans import acceptance as acc

    names, nominal = list(spec["position"]), np.asarray(spec["nominal"], dtype=float)
    d = float(spec["diameter"])
    idx = [[m.name for m in result.measurands].index(n) for n in names]
    unit_ = result.measurands[idx[0]].unit
    cov = np.asarray(result.mc.cov, dtype=float)[np.ix_(idx, idx)]
    u = 2.0 * math.sqrt(max(float(np.linalg.eigvalsh(cov)[-1]), 0.0))
    prior = acc.parse_prior(spec["prior"]) if spec.get("prior") else None
    rule = str(spec.get("rule", "simple"))
    v = Verdict(procedure=procedure, label=label, measurand=spec["measurand"], unit=unit_,
                description=f"position of ({', '.join(names)}), diameter zone",
                estimator=result.estimator, lower=None, upper=d, u=u, rule=rule, prior=prior,
                prior_text=spec.get("prior"),
                population_source=str(spec.get("population_source", "")),
                zone={"position": names, "nominal": [float(x) for x in nominal],
                      "diameter": d})
    verdict, reason = None, ""
    if measured is None:
        v.verdict, v.reason = NOT_MEASURED, "no readings"
    else:
        det = np.asarray(measured.determinable)
        j = [[m.name for m in measured.measurands].index(n) for n in names]
        value = np.asarray(measured.value, dtype=float)[j]
        how = "posterior" if measured.uncertainty == "posterior" else "Monte Carlo"
        v.measured_source = f"readings, {measured.estimator} estimator, {how}"
        if not (det[j].all() and np.isfinite(value).all()):
            v.verdict, v.reason = NOT_DETERMINABLE, "a coordinate is not determinable"
        else:
            xy, drawn = _joint_samples(measured, names)
            p = 2.0 * np.hypot(xy[:, 0] - nominal[0], xy[:, 1] - nominal[1])
            v.measured = float(2.0 * np.hypot(*(value - nominal)))
            v.measured_u = float(p.std(ddof=1))
            v.measured_low, v.measured_high = _shortest(p, measured.coverage)
            v.p_conform_samples = float(np.mean(p <= d))
            v.measured_source += f"; P from {p.size} {drawn}"
            verdict, reason = fit_verdict(getattr(measured, "fit", None)) or (None, "")
    if not u > 0:
        v.verdict, v.reason = NOT_DETERMINABLE, "the planned coordinates have no uncertainty"
        return v
    try:
        plan = acc.plan_acceptance(None, d, u, prior=prior, rule=acc.parse_rule(rule),
                                   measured=v.measured,
                                   resolution=acc.agreed_resolution(u, result.mc.trials))
    except InvalidInput as exc:
        v.verdict, v.reason = NOT_DETERMINABLE, " ".join(exc.problems)
        return v
    v.guard_band, v.acceptance_limits = plan.guard_band, tuple(plan.acceptance_limits)
    v.pfa, v.pfr, v.conditional_pfa = plan.pfa, plan.pfr, plan.conditional_pfa
    v.tur, v.p_conform = plan.tur, v.p_conform_samples
    if v.measured is not None:
        v.verdict = verdict or decide(v.measured, None, d, v.guard_band)
        v.reason = reason
    return v


# ----------------------------------------------------------------------- levers
def _same(a, b) -> bool:
    try:
        return bool(np.isclose(float(a), float(b), rtol=1e-9, atol=1e-12))
    except (TypeError, ValueError):
        return str(a) == str(b)


def lever_effects(levers, setup, sweeps, names, estimator) -> list:
    """The swept levers ranked by their largest effect on the measurands ``names``.

    Parameters
    ----------
    levers : tuple of str
        The procedure's levers (``Procedure.levers``).
    setup : Setup
        The study's set-up (its values are the "base" of each sweep).
    sweeps : list of (dict, DataFrame or str)
        The study's sweeps and their tables (a string: a sweep that could not run).
    names : list of str
        The measurands that matter.
    estimator : str
        Preferred estimator (the sweep's first one when it did not run this one).

    Returns
    -------
    list of LeverEffect
        One per lever (its largest effect over ``names``), largest gain first.
    """
    base = setup.as_dict()
    found = {}
    for j, (spec, table) in enumerate(sweeps):
        vary = list(spec["vary"])
        if isinstance(table, str) or len(vary) != 1 or vary[0] not in levers:
            continue
        f = vary[0]
        ok = table[table["error"].astype(str) == ""] if "error" in table else table
        est = estimator if estimator in set(ok["estimator"]) else ok["estimator"].iloc[0]
        for name in names:
            g = ok[(ok["estimator"] == est) & (ok["measurand"] == name)]
            g = g[np.isfinite(g["u"]) & (g["u"] > 0)]
            if len(g) < 2:
                continue
            at = g[[_same(v, base.get(f)) for v in g[f]]]
            b = g.loc[g["u"].idxmin()]
            ref = at.iloc[0] if len(at) else g.loc[g["u"].idxmax()]
            gain = float(ref["u"] / b["u"])
            n = float(g["trials"].min())
            significant = gain > 1 + 3 * math.sqrt(2) / math.sqrt(2 * (n - 1))
            effect = LeverEffect(field=f, measurand=name, unit=str(g["unit"].iloc[0]),
                                 estimator=est, sweep=j, base_value=base.get(f),
                                 u_base=float(at["u"].iloc[0]) if len(at) else math.nan,
                                 ref_value=ref[f], best_value=b[f], u_best=float(b["u"]),
                                 duration_base_s=float(ref["duration_s"]),
                                 duration_best_s=float(b["duration_s"]), gain=gain,
                                 significant=bool(significant))
            if f not in found or gain > found[f].gain:
                found[f] = effect
    return sorted(found.values(), key=lambda e: -e.gain)


def dominant_sources(budget, levers, fields, *, share: float = 0.5) -> list:
    """Error sources that carry at least ``share`` of some measurand's variance.

    `fields` maps each error source to the set-up field that sizes it (``Source.field``).

    Returns a list of dicts: ``source``, ``field`` (the set-up field that sizes it),
    ``lever`` (whether that field is one of the set-up's levers) and ``measurands``
    (list of (name, share)), largest share first.
    """
    if budget is None or not len(budget):
        return []
    top = budget.sort_values("share", ascending=False).groupby("output", sort=False).head(1)
    top = top[top["share"] >= share]
    out = []
    for source, group in top.groupby("input", sort=False):
        f = fields.get(source)
        out.append({"source": source, "field": f, "lever": f in levers,
                    "measurands": [(r.output, float(r.share)) for r in group.itertuples()]})
    return sorted(out, key=lambda d: -max(s for _, s in d["measurands"]))


# ----------------------------------------------------------------------- repeats
#: error sources drawn anew at every reading (their names contain one of these): an
#: average of repeated tests of the same set-up, not re-mounted, reduces their share of
#: u^2 by the number of repeats; every other source (an instrument's or artefact's own
#: error, the mounting, the thermal state) stays the same in every repeat
RANDOM_ON_REPEAT = ("noise", "repeatability", "pretravel_variation")


def random_share(budget, measurand: str) -> tuple[float, str, float] | None:
    """(share of u^2 that repeats average, the largest other source, its share) of one
    measurand from the study's budget (columns ``input``, ``output``, ``share``); None
    without a budget row for it."""
    if budget is None or not len(budget):
        return None
    rows = budget[budget["output"] == measurand]
    if not len(rows):
        return None
    total = float(rows["share"].sum())
    if not total > 0:
        return None
    random = rows["input"].astype(str).map(lambda n: any(w in n for w in RANDOM_ON_REPEAT))
    fixed = rows[~random].sort_values("share", ascending=False)
    top = (str(fixed["input"].iloc[0]), float(fixed["share"].iloc[0]) / total) if len(fixed) \
        else ("", 0.0)
    return float(rows.loc[random, "share"].sum()) / total, top[0], top[1]


def repeats_needed(U: float, needed: float, share: float, *, limit: int = 50) -> int | None:
    """The fewest repeats n whose average reaches ``U_n = U sqrt(1 - r + r / n) < needed``
    with ``r`` the random ``share`` of u^2; None where no number up to ``limit`` does (the
    share that repeats leave, ``1 - r``, alone exceeds it)."""
    if not (U > 0 and needed > 0):
        return None
    ratio = (needed / U) ** 2
    if ratio > 1:
        return 1
    if ratio <= 1 - share or share <= 0:
        return None
    n = math.ceil(share / (ratio - (1 - share)) - 1e-12)
    return n if n <= limit else None


def repeated_U(U: float, share: float, n: int) -> float:
    """The expanded uncertainty of an average of ``n`` repeats (see :func:`repeats_needed`)."""
    return U * math.sqrt(1 - share + share / n)


# ----------------------------------------------------------------------- summary
def u_targets(plan_spec, verdicts) -> dict:
    """Target standard uncertainty per measurand for the sweep figures: a plan target
    (``target / k``) or, for a two-sided tolerance, the u that gives TUR = 4.

    Returns ``{measurand: (u, what)}`` [display unit].
    """
    out = {}
    for v in verdicts:
        if v.lower is not None and v.upper is not None:
            out[v.measurand] = ((v.upper - v.lower) / 16.0, "u for TUR = 4")
    if plan_spec:
        k = float(plan_spec.get("k", 1.0))
        for name, target in plan_spec.get("targets", {}).items():
            out[name] = (float(target) / k, "plan target")
    return out


def shown_setup(setup, defaults, levers, varied) -> dict:
    """The set-up fields a reader needs: levers that were swept or planned, and levers
    that differ from the defaults (study order)."""
    values = setup.as_dict()
    base = defaults.as_dict()
    return {f: v for f, v in values.items()
            if f in levers and (f in varied or v != base.get(f)) and v is not None}


def summary_rows(section, procedure, label, result, names, verdicts, measured, setup,
                 duration_s) -> list:
    """Summary rows of one procedure: ``names`` with the recommended estimator's ``result``."""
    by_name = {v.measurand: v for v in verdicts}
    index = {m.name: i for i, m in enumerate(result.measurands)}
    rows = []
    for name in names:
        i = index[name]
        m = result.measurands[i]
        u = float(result.mc.std[i])
        row = SummaryRow(section=section, procedure=procedure, label=label, measurand=name,
                         unit=m.unit, description=m.description, estimator=result.estimator,
                         setup=setup, u=u if u > 0 else math.nan, k=K,
                         U=K * u if u > 0 else math.nan, duration_s=float(duration_s),
                         **dict(zip(("U_coverage", "U_coverage_se"),
                                    _coverage_at(result, i) if u > 0 else (None, None),
                                    strict=True)))
        v = by_name.get(name)
        if v is not None:
            row.lower, row.upper, row.tur = v.lower, v.upper, v.tur
            row.measured, row.measured_u = v.measured, v.measured_u
            row.measured_U_coverage = v.measured_U_coverage
            row.measured_U_coverage_se = v.measured_U_coverage_se
            row.measured_low, row.measured_high = v.measured_low, v.measured_high
            row.verdict, row.reason = v.verdict, v.reason
            if v.estimator != result.estimator:  # the readings' estimator decides
                row.estimator, row.u, row.U = v.estimator, v.u, v.U
                row.U_coverage, row.U_coverage_se = v.U_coverage, v.U_coverage_se
        elif measured is not None:
            y, uy, low, high, _, verdict, reason = _measured_value({}, name, measured, u)
            row.measured, row.measured_u, row.measured_low, row.measured_high = y, uy, low, high
            if y is not None:
                row.measured_U_coverage, row.measured_U_coverage_se = _measured_coverage(
                    {}, name, measured, None)[:2]
            row.verdict = verdict or ""
            row.reason = reason
        if not u > 0 and not row.reason:
            row.reason = (f"the {result.estimator} estimator gives the same value in every "
                          "trial: below its resolution")
        rows.append(row)
    return rows

