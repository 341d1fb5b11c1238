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

"About 95 %" is said only where the coverage lies within :data:`ABOUT` of 95 %
(:func:`is_about_nominal`, the one test every output applies: :func:`common_text`);
otherwise the percentage is printed (:func:`coverage_text`). Where only a
first-order result exists (no Monte Carlo), the coverage is that of a normal distribution
(Student's t at the effective degrees of freedom where they are finite), said to be
assumed (:func:`normal_coverage`, :data:`ASSUMED`).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["K", "NOMINAL", "ABOUT", "MONTE_CARLO", "POSTERIOR", "ASSUMED", "fraction_within",
           "normal_coverage", "is_about_nominal", "coverage_text", "common_text", "coverage_se"]

#: coverage factor of the expanded uncertainty that decides, U = k u (ISO 14253-1)
K = 2.0
#: the coverage probability a U is conventionally said to have
NOMINAL = 0.95
#: "about 95 %" only where the coverage lies within this of NOMINAL (94 % to 96 %)
ABOUT = 0.01
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
    """The standard error of a coverage `p` estimated from `trials` Monte Carlo values
    (binomial)."""
    p = np.asarray(p, dtype=float)
    return np.sqrt(np.clip(p * (1.0 - p), 0.0, None) / np.maximum(np.asarray(trials), 1))


def is_about_nominal(p) -> bool:
    """Whether a coverage may be called "about 95 %" (within :data:`ABOUT` of it)."""
    return p is not None and math.isfinite(p) and abs(p - NOMINAL) <= ABOUT + 1e-12


def coverage_text(p, *, assumed: bool = False) -> str:
    """A coverage as the documents print it beside U: the percentage to one decimal
    ("98.9 %"); ``assumed`` (a first-order result): "95.4 % (normal assumed)"; "-" where
    there is none."""
    if p is None or not math.isfinite(p):
        return "-"
    return f"{100 * p:.1f} %" + (" (normal assumed)" if assumed else "")


def common_text(ps) -> str | None:
    """"about 95 %" where every coverage of `ps` is (:func:`is_about_nominal`): what a
    caption may say of all the U under it; None where one is not (each U then carries its
    own, :func:`coverage_text`)."""
    ps = [p for p in ps if p is not None and math.isfinite(p)]
    return "about 95 %" if ps and all(is_about_nominal(p) for p in ps) else None
