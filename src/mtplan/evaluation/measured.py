"""Measured data: read a readings CSV, estimate the measurands with their uncertainty.

Reading and checking a readings file, and completing the set-up from it, is
:mod:`mtplan.evaluation.readings` (:func:`read_readings`, :func:`read_measurement`,
re-exported here).

:func:`estimate_measured` gives the measurands with their uncertainty, by Monte
Carlo around the estimate (``"mc"``: the estimate corrected for the estimator's bias
there, the interval around that value) or by the posterior of the forward model
over the whole error budget (``"posterior"``,
:func:`mtplan.evaluation.posterior.sample_posterior`): one result per measurand, or
"not determinable by this estimator" with the reason, never a number with an
interval of zero width.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from mtplan._validate import InvalidInput, Problems
from mtplan.evaluation.fitcheck import FIT_ALPHA
from mtplan.evaluation.posterior import PosteriorOptions, sample_posterior
from mtplan.evaluation.readings import Measurement, read_measurement, read_readings
from mtplan.evaluation.simulation import (
    Reported,
    ResultDocument,
    measurand_rows,
    undetermined_measurands,
)
from mtplan.models.protocol import Procedure
from mtplan.uncertainty.coverage import MONTE_CARLO, POSTERIOR, K
from mtplan.uncertainty.options import Options

__all__ = ["read_readings", "read_measurement", "Measurement", "estimate_measured",
           "MeasuredOptions", "best_estimator", "MeasuredResult", "UNCERTAINTY_METHODS", "SOURCE_KINDS",
           "source_kinds"]

UNCERTAINTY_METHODS = ("mc", "posterior")
#: Monte Carlo trials per candidate when the best estimator of a set-up is chosen
PILOT_TRIALS = 400
#: ``mc`` without a trial count: the trials of the Monte Carlo that validates the first-order
#: (GUM) result, tried in turn until one validates it (each extends the one before: none
#: of its trials is run again), and of the full Monte Carlo that replaces it where none does
VALIDATION_TRIALS = (256, 512, 1_024, 2_048)
FULL_TRIALS = 10_000
#: trials per block of the validating Monte Carlos, at most (the procedure's own block
#: size where smaller): the blocks a longer run shares with a shorter one
VALIDATION_BLOCK = 256
#: draws of the first-order model against which the normal interval is checked (no
#: forward model or estimator runs for them: the draws and one product)
LINEAR_TRIALS = 2_048
#: the first-order u and interval are validated when the Monte Carlo shows them within
#: their tolerance at this many of its standard errors (JCGM 101 8.2, with the tolerance
#: the Monte Carlo resolves) ...
VALIDATION_SE = 3.0
#: ... the tolerance of u, relative: the Monte Carlo's u (the first-order model as its
#: control variate) within this of first order's, the margin and VALIDATION_SE of its
#: standard errors together
VALIDATION_U_TOL = 0.05
#: an estimator "follows" a measurand when its noise-free response to it is 1 within this
SLOPE_TOL = 0.5


def _normal_quantile(p):
    """The standard normal distribution's quantile at `p` (scipy.stats' ``norm.ppf``, bit for
    bit, without the second it takes to import scipy.stats)."""
    from scipy import special

    return float(special.ndtri(p))


def _normal_pdf(z: float) -> float:
    return math.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)


# --------------------------------------------------------------------------- estimate
#: How the posterior treats each error source, by the first words of its budget entry
#: (:attr:`PosteriorResult.budget`): the kinds ``mtplan estimate`` prints, in this order.
SOURCE_KINDS = ("covariance", "nuisance", "free noise", "absorbed", "no effect", "off")


def source_kinds(budget: dict) -> dict:
    """{kind: [sources]}: the posterior's budget grouped by how each source is treated
    (:data:`SOURCE_KINDS`; an entry of no known kind is its own kind, up to its first
    comma, colon or parenthesis)."""
    import re

    out: dict = {}
    for src, how in budget.items():
        kind = next((k for k in SOURCE_KINDS if how.startswith(k)), None)
        if kind is None:
            kind = re.split(r",|:| \(", how, maxsplit=1)[0].strip()
        out.setdefault(kind, []).append(src)
    order = {k: i for i, k in enumerate(SOURCE_KINDS)}
    return dict(sorted(out.items(), key=lambda kv: order.get(kv[0], len(order))))


@dataclass
class MeasuredResult(ResultDocument):
    """Measurands estimated from measured readings, one result per measurand (display units).

    Attributes
    ----------
    procedure, estimator, uncertainty : str
        ``uncertainty`` is ``"mc"`` or ``"posterior"``.
    setup : the procedure's Setup
    measurands : tuple of Measurand
    estimate : array (n_measurands,)
        The estimator's value from the readings (provenance).
    bias_correction : array (n_measurands,)
        Added to the estimate to give the value: minus the estimator's bias at the
        estimate (``mc``, always applied; 0 for ``posterior``).
    bias_correction_u : array (n_measurands,)
        Standard uncertainty of the correction (``mc``: its Monte Carlo standard error and
        its spread over the truths the readings allow, :mod:`mtplan.evaluation.correction`;
        included in :attr:`std`; 0 for ``posterior``).
    value : array (n_measurands,)
        The result: the bias-corrected estimate (``mc``) or the posterior mean.
    std : array (n_measurands,)
        Standard uncertainty of the value (also :attr:`u`).
    low, high : array (n_measurands,)
        Coverage interval of the value (``mc``: the estimate minus the Monte Carlo
        quantiles of the estimation error; ``posterior``: equal-tailed credible
        interval).
    covariance : array (n_measurands, n_measurands)
        Covariance of the values [display units]; its diagonal is ``std**2`` (NaN rows and
        columns for a measurand that is not determinable).
    U_coverage : array (n_measurands,)
        The fraction of the value's distribution within ``value ± U``, U = 2u
        (:mod:`mtplan.uncertainty.coverage`): ``mc``, of the Monte Carlo's values around
        the estimate; ``posterior``, of the posterior's samples.
    U_from : str
        Where ``U_coverage`` comes from (``U_coverage_from`` in the JSON and CSV).
    U_coverage_se : array (n_measurands,) or None
        Its standard error: ``mc``, of the count with the first-order model as its control
        variate where that resolves it better
        (:meth:`~mtplan.evaluation.simulation.ProcedureResult.coverage_within`);
        ``posterior``, binomial at the samples' effective size.
    determinable : array of bool (n_measurands,)
        False where this estimator cannot give the measurand (its value, u and
        interval are NaN and :attr:`reasons` says why).
    reasons : dict of str to str
        Why each measurand that is not determinable is not.
    coverage : float
    seed : int or list
    details : ProcedureResult or PosteriorResult
    notes : list of str
        What was taken from the readings file (when a :class:`Measurement` was given),
        then what the evaluation found.
    setup_from_file : dict
        Set-up fields whose value the readings file gave (field -> value).
    setup_defaults : tuple of str
        Set-up fields at their defaults: neither stated nor determined by the file.
    undetermined : dict of str to (unit, reason)
        The measurands the procedure can report that this set-up does not determine.
    sections : dict
        Further parts of the result (see :class:`ResultDocument`); ``simultaneous`` where
        the result holds errors along the travel: the sup-t factor of each curve.
    simultaneous : dict of str to (float, float)
        The simultaneous band (``coverage`` for the whole curve) of each measurand that is a
        point of an error along the travel (``EXX@-50``,
        :mod:`mtplan.evaluation.along`); the JSON and CSV give it as
        ``simultaneous_low`` and ``simultaneous_high`` (null off the curves).

    The JSON and CSV (:meth:`to_dict`, :meth:`summary`) are exactly what ``mtplan
    estimate`` prints and writes.
    fit : FitCheck or None
        The fit check of the readings against the model and its error budget
        (:func:`mtplan.evaluation.fitcheck.fit_check`); when ``fit.ok`` is False the
        stated uncertainty is not valid for these readings.
    """

    #: the procedure itself (its ``name`` is what the JSON and the documents print)
    procedure: Procedure
    estimator: str
    uncertainty: str
    setup: object
    measurands: tuple
    estimate: np.ndarray
    value: np.ndarray
    std: np.ndarray
    low: np.ndarray
    high: np.ndarray
    coverage: float
    seed: object
    details: object
    bias_correction: np.ndarray = None
    bias_correction_u: np.ndarray = None
    covariance: np.ndarray = None
    U_coverage: np.ndarray = None
    U_from: str = MONTE_CARLO
    U_coverage_se: np.ndarray = None
    determinable: np.ndarray = None
    reasons: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    fit: object = None
    setup_from_file: dict = field(default_factory=dict)
    setup_defaults: tuple = ()
    undetermined: dict = field(default_factory=dict)
    sections: dict = field(default_factory=dict)
    simultaneous: dict = field(default_factory=dict)

    def __post_init__(self):
        n = len(self.measurands)
        if self.bias_correction is None:
            self.bias_correction = np.zeros(n)
        if self.bias_correction_u is None:
            self.bias_correction_u = np.where(np.isfinite(self.bias_correction), 0.0, np.nan)
        if self.covariance is None:
            self.covariance = np.diag(np.asarray(self.std, dtype=float) ** 2)
        if self.determinable is None:
            self.determinable = np.ones(n, dtype=bool)
        if self.U_coverage is None:
            self.U_coverage = np.full(n, np.nan)

    @property
    def u(self) -> np.ndarray:
        """Standard uncertainty of each value (the same array as :attr:`std`)."""
        return self.std

    def to_dict(self) -> dict:
        """The ``--json`` document of ``mtplan estimate``: the common schema
        (:class:`~mtplan.evaluation.simulation.ResultDocument`), then the fit check and
        the covariance of the measurands."""
        from mtplan.evaluation.covariance import covariance_doc

        doc = super().to_dict()
        if self.fit is not None:
            doc["fit"] = self.fit.to_dict()
        doc["covariance"] = covariance_doc(self.measurands, self.covariance)
        return doc

    @property
    def source_kinds(self) -> dict:
        """``posterior``: {kind: [sources]}, how the posterior treats each error source
        (:func:`source_kinds`); {} for ``mc``."""
        return source_kinds(self.details.budget) if self.uncertainty == "posterior" else {}

    def _head(self) -> dict:
        doc = {"procedure": self.procedure.name, "estimator": self.estimator,
               "uncertainty": self.uncertainty, "setup": self.setup.as_dict(),
               "seed": self.seed,
               "setup_from_file": {k: list(v) if isinstance(v, tuple) else v
                                   for k, v in self.setup_from_file.items()},
               "setup_defaults": list(self.setup_defaults)}
        if self.uncertainty == "posterior":
            doc["posterior"] = self.details.to_dict()
            doc["source_kinds"] = self.source_kinds
        else:
            doc["trials"] = int(self.details.mc.trials)
        return doc

    def _rows(self) -> list[dict]:
        extra = {"estimate": self.estimate, "bias_correction": self.bias_correction,
                 "bias_correction_u": self.bias_correction_u}
        if self.simultaneous:  # errors along the travel: their simultaneous band
            band = [self.simultaneous.get(m.name, (np.nan, np.nan)) for m in self.measurands]
            extra["simultaneous_low"] = np.array([b[0] for b in band], dtype=float)
            extra["simultaneous_high"] = np.array([b[1] for b in band], dtype=float)
        return measurand_rows(self.measurands, Reported(self.value, self.std, self.low,
                                                        self.high, self.coverage,
                                                        self.U_coverage, self.U_from,
                                                        self.U_coverage_se),
                              determinable=self.determinable, reasons=self.reasons,
                              undetermined=self.undetermined, extra=extra)


_BEST: dict = {}


def _best_estimator_cached(proc, setup) -> tuple[tuple[str, float], ...]:
    """The exact estimators, best first, each with its geometric mean of u relative to the
    best's; computed once per set-up."""
    key = (proc.name, tuple(proc.exact_names), setup)
    if key not in _BEST:
        if len(_BEST) > 64:
            _BEST.clear()
        _BEST[key] = _choose_estimator(proc, setup)
    return _BEST[key]


def _choose_estimator(proc, setup) -> tuple[tuple[str, float], ...]:
    from mtplan.evaluation.simulation import simulate_uncertainty

    candidates = list(proc.exact_names) or [proc.default_estimator]
    if len(candidates) == 1:
        return ((candidates[0], 1.0),)

    def score(est, trials):
        try:
            r = simulate_uncertainty(proc, setup, estimator=est, trials=trials, rng=0,
                                     progress=False)
        except (InvalidInput, ValueError, ArithmeticError):
            return None
        std = np.asarray(r.mc.std, dtype=float)
        return float(np.mean(np.log(std))) if np.all(np.isfinite(std) & (std > 0)) else None

    # a sixteenth of the pilot first: an estimator whose u is less than half every other's
    # (line_laser's pattern, 2.7 times) is clear there (the standard error of a log u from
    # 25 trials is 0.15, of a difference of two at most 0.2; log 2 is 3.4 of it); else a
    # quarter of the pilot, and the estimators within 20 % of the best the whole pilot
    first = {e: score(e, PILOT_TRIALS // 16) for e in candidates}
    if None not in first.values():
        ranked = sorted(first, key=first.get)
        if first[ranked[1]] - first[ranked[0]] > math.log(2.0):
            return tuple((e, math.exp(first[e] - first[ranked[0]])) for e in ranked)
    scores = {e: v for e in candidates if (v := score(e, PILOT_TRIALS // 4)) is not None}
    if scores:
        close = [e for e, v in scores.items() if v - min(scores.values()) < math.log(1.2)]
        if len(close) > 1:
            scores.update({e: v for e in close if (v := score(e, PILOT_TRIALS)) is not None})
    if not scores:
        return ((proc.default_estimator, 1.0),)
    ranked = sorted(scores, key=scores.get)
    return tuple((e, math.exp(scores[e] - scores[ranked[0]])) for e in ranked)


def best_estimator(procedure, setup) -> str:
    """The estimator ``estimate`` uses by default: the best one that observes every measurand.

    Among the procedure's exact estimators (those that recover every measurand from
    noise-free readings), the one with the smallest geometric mean of the Monte
    Carlo standard uncertainties at this set-up and the default truth
    (``PILOT_TRIALS`` trials, common random numbers; a sixteenth of them where one's is
    less than half every other's, a quarter where one is more than 20 % better than the
    rest); the procedure's default
    estimator when it has none.
    """
    from mtplan.models import get

    proc = get(procedure)
    proc.check_setup(setup)
    return _best_estimator_cached(proc, setup)[0][0]


def _default_estimate(proc, setup, readings, measurands, notes):
    """The best estimator whose estimate from these readings is finite, and that estimate.

    An estimator that needs readings the file does not hold (circle_centre's
    ``all_contacts`` on a bare point file) gives NaN; the next best is used, noted."""
    ranked = _best_estimator_cached(proc, setup)
    skipped = []
    for name, _ in ranked:
        est = proc.estimate(setup, readings, name)
        if all(np.all(np.isfinite(np.asarray(est[m.name], dtype=float))) for m in measurands):
            break
        skipped.append(name)
    else:
        name, _ = ranked[0]
        est, skipped = proc.estimate(setup, readings, name), []
    others = [(e, r / dict(ranked)[name]) for e, r in ranked if e != name and e not in skipped]
    text = f"estimator {name}: the best of {proc.name}'s at this set-up"
    if others:
        text += (" (geometric mean of u relative to it: "
                 + ", ".join(f"{e} x{r:.2f}" for e, r in others) + ")")
    if skipped:
        text += (f"; {', '.join(skipped)} (better) give no finite estimate from these readings "
                 "(they use readings the file does not hold)")
    if len(ranked) > 1:
        notes.append(text)
    return name, est


def _observes(proc, setup, est_name, est_internal, step):
    """d(estimate)/d(measurand) from noise-free readings at the estimate +- `step` [display]
    (a tenth and a hundredth of it where that leaves the truth's domain), the change of the
    measurand taken from the truth built from the moved estimate.

    None when the procedure cannot build a truth from an estimate. A measurand that no truth
    moves alone (derived from the others, as rotary_axis's ac_offset from the two axis
    lines) gets slope 1 and is listed in the second return value: it follows the estimate
    as the measurands it derives from do."""
    if not proc.capabilities.builds_truths:
        return None, []
    measurands = proc.measurands(setup)
    slopes = np.full(len(measurands), np.nan)
    derived = []
    zero = proc.zero_errors(setup, 1)

    def estimate_at(m, delta):
        moved = _moved(proc, setup, est_internal, m, delta, zero)
        if moved is None:
            return np.nan, np.nan
        true, r = moved
        try:
            return (float(np.asarray(proc.estimate(setup, r, est_name)[m.name]).reshape(-1)[0]),
                    true)
        except (InvalidInput, ValueError, ArithmeticError):
            return np.nan, np.nan

    first = _first_steps(proc, setup, est_name, est_internal, step, zero)
    for i, m in enumerate(measurands):
        for h in (step[i], 0.1 * step[i], 0.01 * step[i]):
            if h == step[i] and first is not None:
                (e_hi, t_hi), (e_lo, t_lo) = first[i]
            else:
                (e_hi, t_hi), (e_lo, t_lo) = estimate_at(m, h), estimate_at(m, -h)
            if np.isfinite(t_hi) and np.isfinite(t_lo) and abs(t_hi - t_lo) * m.scale < 1e-3 * h:
                slopes[i] = 1.0
                derived.append(m.name)
                break
            slopes[i] = (e_hi - e_lo) / (t_hi - t_lo)
            if np.isfinite(slopes[i]):
                break
    return slopes, derived


def _moved(proc, setup, est_internal, m, delta, zero):
    """(true value of measurand ``m``, noise-free readings) of the truth built from the
    estimate with ``m`` moved by ``delta`` [display]; None outside the truth's domain."""
    est = dict(est_internal)
    est[m.name] = est[m.name] + delta / m.scale
    try:
        truth = proc.capabilities.truth_from_estimate(setup, est)
        true = float(np.asarray(proc.true_values(setup, truth)[m.name]).reshape(-1)[0])
        return true, proc.forward(setup, truth, zero)
    except (InvalidInput, ValueError, ArithmeticError):
        return None


def _first_steps(proc, setup, est_name, est_internal, step, zero):
    """:func:`_observes`' first try, every measurand +-``step`` at once: the noise-free
    readings of the 2 M moved truths stacked, one call of the estimator (each row is
    estimated from its own readings; its fixed costs, a weighted fit's gains, are paid
    once). [((estimate, true) at +step, (estimate, true) at -step)] per measurand, or None
    where the rows cannot be stacked or the estimator refuses the batch (then each is
    estimated alone, as on the later tries)."""
    measurands = proc.measurands(setup)
    rows, where, trues = [], [], np.full((len(measurands), 2), np.nan)
    for i, m in enumerate(measurands):
        for j, sign in enumerate((1.0, -1.0)):
            moved = _moved(proc, setup, est_internal, m, sign * step[i], zero)
            if moved is not None:
                trues[i, j] = moved[0]
                rows.append(moved[1])
                where.append((i, j))
    if not rows or any(not isinstance(v, np.ndarray) or v.ndim == 0 or v.shape[0] != 1
                       for r in rows for v in r.values()):
        return None
    try:
        stacked = {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}
        out = proc.estimate(setup, stacked, est_name)
    except (InvalidInput, ValueError, ArithmeticError, KeyError):
        return None
    values = np.full((len(measurands), 2), np.nan)
    for row, (i, j) in enumerate(where):
        values[i, j] = float(np.asarray(out[measurands[i].name]).reshape(-1)[row])
    return [((values[i, 0], trues[i, 0]), (values[i, 1], trues[i, 1]))
            for i in range(len(measurands))]


def _tails(r, coverage):
    """(heavy, robust, k): which measurands' Monte Carlo errors are heavy-tailed (their mean
    outside the coverage interval, or their standard deviation over three times the spread
    the interval implies), the interval's half-width over the normal coverage factor, k."""
    std = np.asarray(r.mc.std, dtype=float)
    err_mean = np.asarray(r.mc.mean - r.true, dtype=float)
    err_low, err_high = np.asarray(r.mc.low - r.true), np.asarray(r.mc.high - r.true)
    k = _normal_quantile(0.5 + coverage / 2)
    robust = (err_high - err_low) / (2 * k)
    inside = (err_low <= err_mean) & (err_mean <= err_high)
    return ~inside | (std > 3 * robust), robust, k


def _corrected(r, estimate, names, notes, coverage):
    """(value, bias correction, u, low, high) from the Monte Carlo around the estimate.

    The interval is the estimate less the quantiles of the estimation error. The bias of
    the estimator at the estimate (the mean error) is always corrected: the Monte Carlo
    mean is an unbiased estimate of it, and its own uncertainty (GUM 3.2.3) is added to u
    by :mod:`mtplan.evaluation.correction`; a rule that corrects only a significant bias
    would make the value jump where the bias crosses the rule's threshold. Where the
    errors are heavy-tailed (:func:`_tails`: rare wild trials dominate the moments), the
    Monte Carlo cannot pin a bias down, so none is corrected (unless the estimate lies
    outside its own interval: then the interval's middle is the value), and the interval's
    half-width over the coverage factor of a normal distribution stands for the standard
    deviation, said in a note: the interval is then the result, the moments are not.
    u here is the Monte Carlo's alone, without the correction's.
    """
    names = np.asarray(names)
    std = np.asarray(r.mc.std, dtype=float)
    err_mean = np.asarray(r.mc.mean - r.true, dtype=float)
    err_low, err_high = np.asarray(r.mc.low - r.true), np.asarray(r.mc.high - r.true)
    heavy, robust, k = _tails(r, coverage)
    u = np.where(heavy, robust, std)
    inside = (err_low <= err_mean) & (err_mean <= err_high)
    bias = np.where(heavy, 0.0, err_mean)
    # no correction must leave the value outside its own interval
    middle = 0.5 * (err_low + err_high)
    bias = np.where((err_low <= bias) & (bias <= err_high), bias,
                    np.where(inside, err_mean, middle))
    wild = heavy & np.isfinite(std)
    if np.any(wild):
        shown = ", ".join(f"{m} (std {s:.3g}, from the interval {v:.3g})"
                          for m, s, v in zip(names[wild], std[wild], robust[wild], strict=True))
        notes.append(f"heavy-tailed Monte Carlo errors of {shown}: rare wild trials dominate "
                     "the mean and the standard deviation, so no bias correction is made and the "
                     f"interval's half-width / {k:.2f} stands for u; the interval is the result")
    return estimate - bias, 0.0 - bias, u, estimate - err_high, estimate - err_low


def _first_order(proc, setup, truth, est_name, sources):
    """The first-order propagation (:func:`~mtplan.evaluation.first_order.first_order`) of
    the estimator at `truth`, or why there is none."""
    from mtplan.evaluation.first_order import first_order

    try:
        return first_order(proc, setup, truth, estimator=est_name, sources=sources)
    except (InvalidInput, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        return (f"first order could not be evaluated ({exc}); a Monte Carlo of "
                f"{FULL_TRIALS} trials gave u and the intervals")


def _familywise_se(checks: int) -> float:
    """Standard errors within which each of `checks` independent normal checks must lie so
    that all of them pass together as often as one check at :data:`VALIDATION_SE` does
    (Bonferroni): 3 for one check, 3.5 for nine, 4 for sixty."""
    alpha = math.erfc(VALIDATION_SE / math.sqrt(2.0))
    return -_normal_quantile(alpha / (2.0 * max(int(checks), 1)))


def _end_se(coverage: float) -> tuple[float, float]:
    """(z, s): the normal coverage factor and the standard error of a coverage interval's
    end from M draws, ``s u / sqrt(M)`` (``sqrt(p (1 - p)) / phi(z_p)``, normal)."""
    p = (1.0 - coverage) / 2
    z = -_normal_quantile(p)
    return z, math.sqrt(p * (1 - p)) / _normal_pdf(z)


def _linear_model_checks(proc, setup, gum, linear, coverage) -> list[str]:
    """The measurands whose first-order model's own draws `linear` (K, n_measurands)
    (:func:`~mtplan.evaluation.simulation.linear_trials`) refuse the first-order u or
    normal interval, each with why: the draws' standard deviation off ``u_fo`` or an end
    of their coverage interval off ``+-z u_fo`` by more than the standard errors K draws
    resolve (:func:`_familywise_se` over every check). A non-normal output (rotary_axis's
    EX0C, dominated by rectangular inputs: its 95 % interval is about +-1.74 u) fails here
    before any Monte Carlo of the estimator runs."""
    from mtplan.uncertainty.montecarlo import coverage_interval

    u_fo = np.asarray(gum.std, dtype=float)
    k = linear.shape[0]
    z, s_end = _end_se(coverage)
    c = _familywise_se(3 * int(np.sum(u_fo > 0)))
    out = []
    for i, m in enumerate(proc.measurands(setup)):
        if not u_fo[i] > 0:
            continue
        x = linear[:, i]
        dev = x - x.mean()
        kurt = float(np.mean(dev**4) / max(np.mean(dev**2) ** 2, 1e-300))
        ratio = float(np.std(x, ddof=1)) / u_fo[i]
        off_u = abs(ratio - 1.0) / math.sqrt(max(kurt - 1.0, 1e-12) / (4.0 * k))
        lo, hi = coverage_interval(x, coverage)
        ends = np.array([lo, hi]) / u_fo[i]
        off_end = float(np.max(np.abs(ends - [-z, z]))) / (s_end / math.sqrt(k))
        if off_u > c or off_end > c:
            out.append(f"{m.name} (its first-order model's {k} draws: u / first order "
                       f"{ratio:.3g}, interval [{ends[0]:.3g}, {ends[1]:.3g}] u against "
                       f"+-{z:.3g} u)")
    return out


def _validated_first_order(proc, setup, gum, r, coverage, linear):
    """(`gum` or None, note): the first-order (GUM) u and interval of `gum` (a
    :class:`~mtplan.uncertainty.gum.GUMResult`) where the Monte Carlo `r` at the same
    truth validates them after JCGM 101 8.2, to the tolerance its trials resolve.

    `linear` (M, n_measurands), M the trials of `r` or more: the first-order model's
    output in the trials of `r` (:func:`~mtplan.evaluation.simulation.linear_trials`),
    paired with them. Every measurand the Monte Carlo resolves (finite, non-zero spread,
    not heavy-tailed) must pass two checks:

    - u: the Monte Carlo's variance with the first-order model as its control variate,
      ``u_fo^2 + s_y^2 - s_L^2`` over the paired trials (only the estimator's departure
      from first order is left to sample: its standard error is a small part of a plain
      Monte Carlo's), its root within :data:`VALIDATION_U_TOL` of ``u_fo``, the margin and
      :data:`VALIDATION_SE` of its standard errors together;
    - each end of the Monte Carlo's coverage interval, about its mean, within the standard
      errors of a quantile from its trials (``sqrt(p (1 - p) / M) / phi(z_p)`` u,
      :func:`_familywise_se` over every end) of the paired first-order outputs' end. That
      those are the normal interval's is checked once, on many more of them
      (:func:`_linear_model_checks`).

    A first-order u of 0 where the Monte Carlo spreads (a quantised or non-linear
    estimator) is never validated.
    """
    from mtplan.uncertainty.montecarlo import coverage_interval

    m = int(r.mc.trials)
    lin_all = np.asarray(linear, dtype=float)[:m]
    u_mc = np.asarray(r.mc.std, dtype=float)
    u_fo = np.asarray(gum.std, dtype=float)
    z, s_end = _end_se(coverage)
    resolved = np.isfinite(u_mc) & (u_mc > 0) & ~_tails(r, coverage)[0]
    c = _familywise_se(2 * int(resolved.sum()))
    names = [mm.name for mm in proc.measurands(setup)]
    ratio, margin = np.full(len(names), np.nan), np.full(len(names), np.inf)
    d_end = np.full(len(names), np.inf)
    for i, n in enumerate(names):
        y = r.mc.samples(n)
        if y is None or not resolved[i] or not u_fo[i] > 0:
            continue
        y, lin = np.asarray(y, dtype=float), lin_all[:, i]
        a = (y - y.mean()) ** 2 - (lin - lin.mean()) ** 2
        ratio[i] = math.sqrt(max(u_fo[i] ** 2 + a.sum() / (m - 1), 0.0)) / u_fo[i]
        se = float(a.std(ddof=1)) / math.sqrt(m) / (2 * u_fo[i] ** 2 * max(ratio[i], 1e-3))
        margin[i] = abs(ratio[i] - 1.0) + VALIDATION_SE * se
        ends_y = np.array(coverage_interval(y, coverage)) - y.mean()
        ends_l = np.array(coverage_interval(lin, coverage)) - lin.mean()
        d_end[i] = float(np.max(np.abs(ends_y - ends_l))) / (s_end * u_fo[i] / math.sqrt(m))
    ok = (u_fo > 0) & (margin <= VALIDATION_U_TOL) & (d_end <= c)
    failed = [n for n, res, good in zip(names, resolved, ok, strict=True) if res and not good]
    if not resolved.any():
        return None, (f"first order not validated (the {m}-trial Monte Carlo resolves no "
                      f"measurand); a Monte Carlo of {FULL_TRIALS} trials gave u and the "
                      "intervals")
    if failed:
        shown = ", ".join(f"{n} (u Monte Carlo / first order {q:.3g}, within {100 * g:.1f} % "
                          f"at {VALIDATION_SE:g} standard errors; an interval end {e:.1f} "
                          "standard errors off the first-order model's)"
                          for n, q, g, e, res, good in zip(names, ratio, margin, d_end, resolved,
                                                           ok, strict=True) if res and not good)
        return None, (f"first order not validated by Monte Carlos of up to {m} trials "
                      f"({shown}); a Monte Carlo of {FULL_TRIALS} trials gave u and the "
                      "intervals")
    worst = float(np.nanmax(np.where(resolved, margin, np.nan)))
    return gum, (f"u and the intervals are first order (GUM law of propagation at the "
                 f"Monte Carlo's truth), validated by a Monte Carlo of {m} trials (JCGM 101 "
                 f"8.2, the first-order model as its control variate: its u within "
                 f"{100 * worst:.1f} % of first order at {VALIDATION_SE:g} standard errors, its "
                 f"interval ends within {c:.2g} standard errors of the first-order model's, "
                 f"whose {LINEAR_TRIALS} own draws agree with the normal interval), which also "
                 "gave the bias correction; --trials N runs a Monte Carlo of N trials instead")


def _validating_runs(proc, setup, truth, est_name, sources, gum, *, coverage, root, progress,
                     n_jobs):
    """(result of the last Monte Carlo or None, validated first order or None, note): the
    first-order model's own draws checked (:func:`_linear_model_checks`), then Monte Carlos
    of :data:`VALIDATION_TRIALS` trials in turn, each one extending the last (blocks of at
    most :data:`VALIDATION_BLOCK` trials, none run twice), until one validates `gum`
    (:func:`_validated_first_order`)."""
    from mtplan.evaluation.simulation import linear_trials, simulate_uncertainty

    block = min(proc.capabilities.block_size, VALIDATION_BLOCK)
    linear = linear_trials(proc, setup, gum, sources=sources, rng=root,
                           trials=max(LINEAR_TRIALS, *VALIDATION_TRIALS), block_size=block)
    refused = _linear_model_checks(proc, setup, gum, linear[:LINEAR_TRIALS], coverage)
    if refused:
        return None, None, (f"first order not validated: {', '.join(refused)}; a Monte Carlo "
                            f"of {FULL_TRIALS} trials gave u and the intervals")
    cache: dict = {}
    for m in VALIDATION_TRIALS:
        r = simulate_uncertainty(proc, setup, truth, estimator=est_name, sources=sources,
                                 trials=m, coverage=coverage, rng=root, progress=progress,
                                 n_jobs=n_jobs, block_size=block, cache=cache)
        first_order, verdict = _validated_first_order(proc, setup, gum, r, coverage, linear)
        if first_order is not None:
            break
    return r, first_order, verdict


def _mc_result(proc, setup, readings, est_name, est_internal, estimate, *, trials, coverage,
               root, seed, notes, progress=False, draws=None, n_jobs=1):
    """Monte Carlo around the estimate: bias-corrected value, its interval, determinability;
    the correction's uncertainty in u, the interval and the covariance."""
    from mtplan.evaluation.correction import NUISANCE_DRAWS, condition_on_readings, correct_mc
    from mtplan.evaluation.simulation import simulate_uncertainty

    measurands = tuple(proc.measurands(setup))
    finite = np.isfinite(estimate)
    if proc.capabilities.builds_truths and finite.all():
        truth = proc.capabilities.truth_from_estimate(setup, est_internal)
    else:
        truth = proc.Truth()
        notes.append(f"the Monte Carlo ran at the default truth of the procedure ({proc.title}), "
                     "not at the "
                     "estimate" + (" (the estimate is not finite)"
                                   if proc.capabilities.builds_truths else ""))
    truth, sources, why = condition_on_readings(proc, setup, readings, truth)
    notes += [why] if why else []
    first_order = None
    if trials is None:  # the first-order result where a short Monte Carlo validates it
        gum = _first_order(proc, setup, truth, est_name, sources)
        if isinstance(gum, str):
            verdict = gum
        else:
            r, first_order, verdict = _validating_runs(
                proc, setup, truth, est_name, sources, gum, coverage=coverage, root=root,
                progress=progress, n_jobs=n_jobs)
        notes.append(verdict)
        if first_order is None:
            r = simulate_uncertainty(proc, setup, truth, estimator=est_name, sources=sources,
                                     trials=FULL_TRIALS, coverage=coverage, rng=root,
                                     progress=progress, n_jobs=n_jobs)
    else:
        r = simulate_uncertainty(proc, setup, truth, estimator=est_name, sources=sources,
                                 trials=trials, coverage=coverage, rng=root, progress=progress,
                                 n_jobs=n_jobs)
    value, correction, std, low, high = _corrected(r, estimate, [m.name for m in measurands],
                                                   notes, coverage)
    if first_order is not None:  # u and the interval from first order, the bias from the MC
        std = first_order.std.copy()
        half = _normal_quantile(0.5 + coverage / 2) * std
        low, high = value - half, value + half
    slopes = None
    if finite.all():  # over two robust standard deviations (the interval's half width / 2)
        spread = np.where(high > low, 0.5 * (high - low) / 1.96, 0.0)
        step = np.where(spread > 0, 2.0 * spread, 1e-6 * np.maximum(np.abs(estimate), 1.0))
        slopes, derived = _observes(proc, setup, est_name, est_internal, step)
        if derived:
            notes.append(f"{', '.join(derived)}: derived from the other measurands (no truth "
                         "moves them alone), so the estimator follows them as it follows those")
    reasons = {}
    for i, m in enumerate(measurands):
        why = None
        if not finite[i]:
            why = "the estimator gives no finite value from these readings"
        elif m.name in getattr(r, "quantised", {}) or not (std[i] > 0 and high[i] > low[i]):
            why = (f"the {est_name} estimator gives the same value in every Monte Carlo trial "
                   "around the estimate (it is quantised or does not see this measurand), so its "
                   "uncertainty is its resolution, which the Monte Carlo cannot give")
        elif slopes is not None and not abs(slopes[i] - 1.0) <= SLOPE_TOL:
            why = (f"the {est_name} estimator does not follow this measurand: a change of it by "
                   f"{step[i]:.3g} {m.unit} changes the noise-free estimate by "
                   f"{slopes[i]:.2f} times that (1 expected), so no bias correction applies")
        if why is not None:
            reasons[m.name] = why + "; not determinable by this estimator: use another estimator "\
                "or --uncertainty posterior"
    bad = np.array([m.name in reasons for m in measurands])
    for arr in (value, std, low, high, correction):
        arr[bad] = np.nan
    # the values before the correction's u: their U's coverage is not known yet (unused)
    c = correct_mc(r, readings, Reported(value, std, low, high, coverage, U_coverage=None),
                   heavy=_tails(r, coverage)[0], rng=root,
                   draws=NUISANCE_DRAWS if draws is None else draws,
                   cov=None if first_order is None else first_order.cov, n_jobs=n_jobs)
    notes += c["notes"]
    within, within_se = _mc_U_coverage(r, estimate, value, K * np.asarray(c["u"], dtype=float))
    return MeasuredResult(
        procedure=proc, estimator=est_name, uncertainty="mc", setup=setup,
        measurands=measurands, estimate=estimate, value=value, std=c["u"], low=c["low"],
        high=c["high"], coverage=float(coverage), seed=seed, details=r,
        U_coverage=within, U_coverage_se=within_se,
        bias_correction=correction, bias_correction_u=c["u_correction"],
        covariance=c["covariance"], determinable=~bad, reasons=reasons, notes=notes)


def _mc_U_coverage(r, estimate, value, big_u) -> tuple:
    """(p, se): the coverage of ``value ± U`` from the Monte Carlo `r` around the estimate:
    its trial t gives the value ``estimate - (y_t - true)``, so the fraction of its
    estimates ``y_t`` within ``true + estimate - value ± U``
    (:meth:`~mtplan.evaluation.simulation.ProcedureResult.coverage_within`)."""
    centre = np.asarray(r.true, dtype=float) + estimate - value
    return r.coverage_within(centre, np.asarray(big_u, dtype=float))


@dataclass(frozen=True)
class MeasuredOptions(Options):
    """How :func:`estimate_measured` evaluates a measurement (frozen: change one with
    :meth:`replace`).

    Attributes
    ----------
    trials : int or None
        Monte Carlo trials (``"mc"``). None: the first-order (GUM) u and interval at the
        estimate where a Monte Carlo of 256 to 2048 trials (:data:`VALIDATION_TRIALS`, each
        extending the last), with the first-order model as its control variate, validates
        them (JCGM 101 8.2, :func:`_validated_first_order`; that Monte Carlo gives the bias
        correction), else a Monte Carlo of :data:`FULL_TRIALS` trials; a note says which.
    coverage : float
    rng : None, int, SeedSequence or Generator
    progress : bool or None
        A progress bar of the ``"mc"`` Monte Carlo on stderr (None: when stderr is a
        terminal).
    n_jobs : int
        ``"mc"``: workers of the Monte Carlo runs (the numbers do not depend on it).
    nuisance_draws : int, optional
        ``"mc"``: truths drawn from the readings' least squares at which the bias is
        evaluated again, for the correction's uncertainty (default
        :data:`mtplan.evaluation.correction.NUISANCE_DRAWS`; 0: none, said in a note).
    fit_alpha : float or None
        Significance level of the fit check (:attr:`MeasuredResult.fit`,
        :func:`mtplan.evaluation.fitcheck.fit_check`; default ``FIT_ALPHA``, 0.05); None:
        no fit check.
    origin : dict, optional
        Row and column of every reading in its file (``Measurement.origin``), to name
        the worst readings of the fit check.
    posterior : PosteriorOptions
        ``"posterior"``: how :func:`sample_posterior` samples (its noise, also that of the
        fit check, its step and time budgets, ...); the estimator, coverage and seed are
        this evaluation's. Its fields may be given to :meth:`of` as keywords too
        (``noise="free", max_seconds=60``).
    """

    trials: int | None = None
    coverage: float = 0.95
    rng: object = None
    progress: object = False
    n_jobs: int = 1
    nuisance_draws: int | None = None
    fit_alpha: float | None = FIT_ALPHA
    origin: dict | None = None
    posterior: PosteriorOptions = field(default_factory=PosteriorOptions)

    WHAT = "estimate option"

    @classmethod
    def of(cls, options=None, /, **overrides):
        """As :meth:`Options.of`; a field of :class:`PosteriorOptions` that is none of these
        options' own changes :attr:`posterior`."""
        own = {f.name for f in dataclasses.fields(cls)}
        sampled = {f.name for f in dataclasses.fields(PosteriorOptions)} - own
        moved = {k: overrides.pop(k) for k in list(overrides) if k in sampled}
        options = super().of(options, **overrides)
        if moved:
            options = dataclasses.replace(options, posterior=options.posterior.replace(**moved))
        return options


def estimate_measured(
    procedure,
    setup,
    readings,
    *,
    estimator: str | None = None,
    uncertainty: str = "mc",
    options: MeasuredOptions | None = None,
    **option_overrides,
) -> MeasuredResult:
    """The measurands of one measurement, with their uncertainty: the values GUM would report.

    Parameters
    ----------
    procedure : str or Procedure
    setup : Setup or None
        None: the set-up of `readings` when that is a :class:`Measurement`.
    readings : Measurement or dict of str to array
        A measured file as :func:`read_measurement` gives it (its notes, the set-up fields
        it gave and those left at their defaults go into the result, so the result is
        what ``mtplan estimate`` prints), or a batch of one (:func:`read_readings`).
    estimator : str, optional
        Default: :func:`best_estimator`, the best estimator that observes every
        measurand; the patent's estimator stays available by its name.
    uncertainty : {"mc", "posterior"}
        ``"mc"``: Monte Carlo of the set-up's error sources around the estimate (at
        ``procedure.capabilities.truth_from_estimate(setup, estimate)`` when the procedure builds
        truths, else its default truth, noted); the value is the estimate corrected for
        the estimator's bias there, with the interval around it. A measurand the
        estimator cannot give (no Monte Carlo spread, or a noise-free estimate that
        does not follow the measurand) is "not determinable", with the reason.
        ``"posterior"``: emcee posterior of the forward model over the whole error
        budget (:func:`mtplan.evaluation.posterior.sample_posterior`).
    options : MeasuredOptions, optional
        Trials, coverage, seed, workers, the fit check's level, the posterior's options
        (:class:`MeasuredOptions`); any of its fields, or of the posterior's, may be given
        as a keyword instead (``trials=2000, rng=0, noise="free"``).

    Returns
    -------
    MeasuredResult
    """
    from mtplan.models import get

    o = MeasuredOptions.of(options, **option_overrides)
    proc = get(procedure)
    measurement = readings if isinstance(readings, Measurement) else Measurement(setup, readings)
    setup = measurement.setup if setup is None else setup
    readings = measurement.readings
    proc.check_setup(setup)
    p = Problems(f"estimate {proc.name}")
    p.choice("uncertainty", uncertainty, UNCERTAINTY_METHODS)
    if o.trials is not None:
        p.number("trials", o.trials, integer=True, low=2)
    p.number("coverage", o.coverage, low=0, high=1, low_open=True, high_open=True)
    if o.fit_alpha is not None:
        p.number("fit_alpha", o.fit_alpha, low=0, high=1, low_open=True, high_open=True)
    p.raise_if_any()
    from mtplan._parallel import one_blas_thread

    if o.origin is None:
        o = o.replace(origin=measurement.origin)
    # one BLAS thread throughout: the products are many and small (an estimator's gain of
    # 15 600 readings took 0.33 s of CPU on one thread and up to 3 s on two spinning ones)
    with one_blas_thread():
        result = _estimate(proc, setup, readings, estimator, uncertainty, o)
    result.notes[:0] = measurement.notes
    result.setup_from_file = dict(measurement.from_file)
    result.setup_defaults = tuple(measurement.defaults)
    result.undetermined = undetermined_measurands(proc, setup)
    _with_simultaneous(result)
    return result


def _with_simultaneous(result: MeasuredResult) -> None:
    """The simultaneous band of the result's errors along the travel, if it holds any
    (:func:`mtplan.evaluation.along.simultaneous_bands`, from the result's covariance and
    seed), and each curve's factor in ``sections["simultaneous"]``."""
    from mtplan.evaluation.along import DRAWS, simultaneous_bands

    names = [m.name for m in result.measurands]
    ok = np.asarray(result.determinable, dtype=bool)
    value = np.where(ok, result.value, np.nan)
    bands, factors = simultaneous_bands(names, value, result.low, result.high,
                                        result.covariance, result.coverage, seed=result.seed)
    if not bands:
        return
    result.simultaneous = bands
    result.sections["simultaneous"] = {
        "coverage": float(result.coverage),
        "method": "sup-t: each point's interval widened about its value by c / z, c the "
                  f"{result.coverage:g} quantile of max |z_i| over the curve's positions, z "
                  "normal with the result's correlation of those points "
                  f"({DRAWS} seeded draws), z the pointwise normal factor",
        "factor": {f: round(c, 4) for f, c in factors.items()}}


def _estimate(proc, setup, readings, estimator, uncertainty, o: MeasuredOptions
              ) -> MeasuredResult:
    """:func:`estimate_measured` on checked arguments: the estimate and its uncertainty."""
    from mtplan.uncertainty.streams import as_seed_sequence

    notes = list(setup.notes())
    measurands = tuple(proc.measurands(setup))
    if estimator is None:
        est_name, est_internal = _default_estimate(proc, setup, readings, measurands, notes)
    else:
        est_name, _ = proc.estimator(estimator)
        est_internal = proc.estimate(setup, readings, est_name)
    est_internal = {m.name: float(np.asarray(est_internal[m.name]).reshape(-1)[0])
                    for m in measurands}
    estimate = np.array([est_internal[m.name] * m.scale for m in measurands])
    root = as_seed_sequence(o.rng)
    seed = root.entropy if isinstance(root.entropy, int) else list(root.entropy)
    coverage = o.coverage
    if uncertainty == "mc":
        result = _mc_result(proc, setup, readings, est_name, est_internal, estimate,
                            trials=o.trials, coverage=coverage, root=root, seed=seed,
                            notes=notes, progress=o.progress, draws=o.nuisance_draws,
                            n_jobs=o.n_jobs)
        # the fit check starts where the readings' least squares that conditioned the Monte
        # Carlo started (correction's, from the first exact estimator's estimate): the same
        # generalised least squares, computed once (posterior.start_fit remembers it)
        return _with_fit(result, proc, readings, o.fit_alpha, noise="setup", origin=o.origin,
                         start=None)
    start_ok = np.all(np.isfinite(estimate))
    post = sample_posterior(proc, setup, readings, options=o.posterior.replace(
        estimator=est_name, coverage=coverage, rng=root))
    if not start_ok:
        notes.append(f"the {est_name} estimate is not finite; the posterior started from the "
                     "default truth")
    names = [m.name for m in measurands]
    notes.extend(post.notes)
    from mtplan.evaluation.covariance import posterior_covariance
    from mtplan.uncertainty.coverage import coverage_se, fraction_within

    within = np.array([fraction_within(post.samples[n], post.mean[n], K * post.std[n])
                       for n in names])
    return _with_fit(MeasuredResult(
        procedure=proc, estimator=est_name, uncertainty="posterior", setup=setup,
        measurands=measurands, estimate=estimate,
        value=np.array([post.mean[n] for n in names]),
        std=np.array([post.std[n] for n in names]),
        low=np.array([post.low[n] for n in names]),
        high=np.array([post.high[n] for n in names]),
        coverage=float(coverage), seed=seed, details=post,
        U_coverage=within, U_coverage_se=coverage_se(within, [post.ess.get(n, math.nan)
                                                                for n in names]),
        U_from=POSTERIOR,
        covariance=posterior_covariance(post, names), notes=notes), proc, readings,
        o.fit_alpha, noise=o.posterior.noise, origin=o.origin, start=est_name)


def _with_fit(result: MeasuredResult, proc, readings, alpha, *, noise, origin,
              start: str | None) -> MeasuredResult:
    """The result with its fit check (:attr:`MeasuredResult.fit`); none when `alpha` is None.
    `start`: the estimator whose estimate starts the check's least squares (None: the first
    exact one's), that of the evaluation's own least squares, so that the fit is shared."""
    if alpha is not None:
        from mtplan.evaluation.fitcheck import fit_check

        result.fit = fit_check(proc, result.setup, readings, alpha=alpha,
                               noise=noise, estimator=start, origin=origin)
    return result
