"""The expanded uncertainty U and the coverage it really has.

The decision rule (ISO 14253-1:2017, JCGM 106:2012) uses ``U = k u`` with ``k = 2``
(:data:`K`): the plan's guard bands and acceptance limits are stated from it before
measuring, so that both parties know the number they agreed. JCGM 101 does not give U a
coverage probability by convention: the probability that ``value ± U`` holds the value is
a property of the output's distribution, which the Monte Carlo gives. So every U is
printed with that coverage beside it, the fraction of the Monte Carlo's values within
``value ± U`` (:func:`fraction_within`), never "about 95 %" by convention:

- a normal distribution gives 95.4 % at k = 2;
- an output dominated by rectangular inputs more (rotary_axis's EX0C: 98.9 %; its 95 %
  factor is 1.74);
- a heavy-tailed one less.

A coverage is counted to :data:`RESOLUTION` where it can be: plainly from enough trials,
else with the first-order model's output in the same trials as the count's control
variate (:func:`controlled_fraction`); one counted less finely is printed with its
standard error (:func:`coverage_se`, :func:`coverage_text`). "About 95 %" is said only
where the coverage lies within :data:`ABOUT` of 95 % and is so counted
(:func:`is_about_nominal`, the one test every output applies: :func:`common_text`);
otherwise the percentage is printed (:func:`coverage_text`). Where only a
first-order result exists (no Monte Carlo), the coverage is that of a normal distribution
(Student's t at the effective degrees of freedom where they are finite), said to be
assumed (:func:`normal_coverage`, :data:`ASSUMED`).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["K", "NOMINAL", "ABOUT", "RESOLUTION", "MONTE_CARLO", "POSTERIOR", "ASSUMED",
           "fraction_within", "normal_coverage", "is_about_nominal", "coverage_text",
           "common_text", "coverage_se", "controlled_fraction"]

#: coverage factor of the expanded uncertainty that decides, U = k u (ISO 14253-1)
K = 2.0
#: the coverage probability a U is conventionally said to have
NOMINAL = 0.95
#: "about 95 %" only where the coverage lies within this of NOMINAL (94 % to 96 %)
ABOUT = 0.01
#: the standard error to which a coverage is resolved where it can be (3.3 of them make
#: 1 %, so a coverage printed without one is within 1 % of the Monte Carlo's with 99.9 %
#: confidence): a plain count of more than about 5 300 values, else with the first-order
#: model as its control variate (:func:`controlled_fraction`); a coverage resolved less is
#: printed with its standard error (:func:`coverage_text`)
RESOLUTION = 0.003
#: where a coverage comes from (``U_coverage_from`` in the JSON and CSV)
MONTE_CARLO = "monte carlo"
POSTERIOR = "posterior samples"
ASSUMED = "normal distribution assumed (first order, no Monte Carlo)"


def fraction_within(samples: np.ndarray, centre, half_width) -> np.ndarray:
    """The fraction of `samples` within ``centre ± half_width`` (ends included).

    Parameters
    ----------
    samples : array (M,) or (M, n)
        Monte Carlo values, trials along the first axis.
    centre, half_width : float or array (n,)

    Returns
    -------
    float or array (n,); NaN where `half_width` or `centre` is not finite or there are no
    samples.
    """
    x = np.asarray(samples, dtype=float)
    c = np.asarray(centre, dtype=float)
    h = np.asarray(half_width, dtype=float)
    if x.shape[0] == 0:
        return np.full(np.broadcast(c, h).shape, np.nan)[()]
    inside = np.abs(x - c) <= h
    out = inside.mean(axis=0)
    return np.where(np.isfinite(c) & np.isfinite(h), out, np.nan)[()]


def normal_coverage(k: float = K, dof=math.inf):
    """The coverage of ``value ± k u`` for a normal distribution (Student's t at `dof`
    where finite): what a first-order result assumes."""
    from scipy import special

    dof = np.asarray(dof, dtype=float)
    normal = float(special.erf(k / math.sqrt(2.0)))
    finite = np.isfinite(dof) & (dof > 0)
    out = np.full(dof.shape, normal)
    if finite.any():
        out[finite] = 1.0 - special.stdtr(dof[finite], -k) * 2.0
    return out[()]


def coverage_se(p, trials) -> np.ndarray:
    """The standard error of a coverage `p` counted among `trials` independent values
    (binomial; `trials` may be an effective sample size). A count of none or all outside
    is taken as one, so that 100 % of 400 values says +-0.25 %, not +-0."""
    n = np.maximum(np.asarray(trials, dtype=float), 1.0)
    p = np.clip(np.asarray(p, dtype=float), 1.0 / n, 1.0 - 1.0 / n)
    return np.sqrt(np.clip(p * (1.0 - p), 0.0, None) / n)


def controlled_fraction(samples, linear, reference, centre, half_width):
    """The fraction of a Monte Carlo's values within ``centre ± half_width``, with the
    first-order model's output as its control variate, and its standard error.

    In trial t the Monte Carlo gave ``y_t`` and the first-order model, from the same
    draws, ``l_t`` (paired); ``reference`` holds many more first-order outputs, drawn
    apart, whose own fraction is cheap to count to any resolution. Per column, ``y`` is
    regressed on ``l`` (slope b) and the linear stand-in ``ȳ + b (l - l̄)`` is counted in
    the reference (``P_ref``) and in the paired trials; the estimate is

        p = P_ref + mean_t (1[y_t inside] - 1[stand-in_t inside]),

    unbiased whatever b is. Only the trials in which the estimator and its stand-in fall
    on different sides of an end remain to be sampled, so where the estimator is close to
    first order its standard error,
    ``sqrt(var(difference) / M + P_ref (1 - P_ref) / N)``, is a small part of the plain
    count's (that of a plain count of M values is :func:`coverage_se`). A difference seen
    in no trial is taken as seen in one. A column whose first-order output does not vary
    (an estimator that does not see it at first order) is counted plainly.

    Parameters
    ----------
    samples, linear : array (M, n)
        The Monte Carlo's values and the paired first-order outputs.
    reference : array (N, n), or an iterable of such arrays (blocks of rows)
        First-order outputs drawn independently of both (expectation 0, as ``linear``'s).
    centre, half_width : array (n,)

    Returns
    -------
    (p, se) : arrays (n,); NaN where `centre` or `half_width` is not finite.
    """
    y = np.asarray(samples, dtype=float)
    lin = np.asarray(linear, dtype=float)
    c = np.asarray(centre, dtype=float)
    h = np.asarray(half_width, dtype=float)
    m = y.shape[0]
    inside = np.abs(y - c) <= h
    plain = inside.mean(axis=0)
    dl = lin - lin.mean(axis=0)
    var_l = (dl**2).mean(axis=0)
    seen = var_l > 0
    slope = np.where(seen, ((y - y.mean(axis=0)) * dl).mean(axis=0) / np.where(seen, var_l, 1.0),
                     0.0)
    start = y.mean(axis=0) - c
    paired = np.abs(start + slope * dl) <= h
    blocks = [reference] if isinstance(reference, np.ndarray) else reference
    count, n_ref = np.zeros(y.shape[1:]), 0
    for ref in blocks:
        ref = np.asarray(ref, dtype=float)
        count += np.count_nonzero(np.abs(start + slope * (ref - lin.mean(axis=0))) <= h,
                                  axis=0)
        n_ref += ref.shape[0]
    p_ref = count / max(n_ref, 1)
    diff = inside.astype(float) - paired
    var_d = np.maximum(diff.var(axis=0, ddof=1) if m > 1 else 1.0, 1.0 / m)
    p = np.where(seen, np.clip(p_ref + diff.mean(axis=0), 0.0, 1.0), plain)
    se = np.where(seen, np.sqrt(var_d / m + p_ref * (1.0 - p_ref) / max(n_ref, 1)),
                  coverage_se(plain, m))
    ok = np.isfinite(c) & np.isfinite(h)
    return np.where(ok, p, np.nan), np.where(ok, se, np.nan)


def is_about_nominal(p, se=None) -> bool:
    """Whether a coverage may be called "about 95 %": within :data:`ABOUT` of it, and
    counted to :data:`RESOLUTION` where its standard error `se` is given."""
    return (p is not None and math.isfinite(p) and abs(p - NOMINAL) <= ABOUT + 1e-12
            and (se is None or not math.isfinite(se) or se <= RESOLUTION + 1e-12))


def coverage_text(p, *, assumed: bool = False, se=None) -> str:
    """A coverage as the documents print it beside U: the percentage to one decimal
    ("98.9 %"), with its standard error where that is above :data:`RESOLUTION` ("95.0 % ±
    1.1 %", the count's own resolution); ``assumed`` (a first-order result): "95.4 %
    (normal assumed)"; "-" where there is none."""
    if p is None or not math.isfinite(p):
        return "-"
    spread = (f" ± {100 * se:.1f} %" if se is not None and math.isfinite(se)
              and se > RESOLUTION + 1e-12 else "")
    return f"{100 * p:.1f} %" + spread + (" (normal assumed)" if assumed else "")


def common_text(ps, ses=None) -> str | None:
    """"about 95 %" where every coverage of `ps` is (:func:`is_about_nominal`, with its
    standard error of `ses` where given): what a caption may say of all the U under it;
    None where one is not (each U then carries its own, :func:`coverage_text`)."""
    ses = [None] * len(ps) if ses is None else list(ses)
    pairs = [(p, se) for p, se in zip(ps, ses, strict=True)
             if p is not None and math.isfinite(p)]
    return "about 95 %" if pairs and all(is_about_nominal(p, se) for p, se in pairs) \
        else None
