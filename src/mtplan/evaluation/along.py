"""Errors along the travel: curves of measurands, and their simultaneous band.

A procedure whose errors are functions of position states each at a grid of positions as a
measurand of its own, named ``FUNCTION@POSITION`` (geometry21's ``EXX@-50``: EXX at
x = -50 mm). :func:`curves` groups a result's measurands into those curves.

The 95 % interval of each point is *pointwise*: each point alone lies in its interval with
probability 0.95, but the whole curve lies inside the band of all its points with a
smaller one. A decision on the whole curve (the largest error over the travel, a
compensation table's worst point) needs a *simultaneous* band, which holds the whole curve
with probability 0.95. :func:`simultaneous_factor` gives it as the sup-t (max-|t|) band:
``c`` is the 95 % quantile of ``max_i |z_i|`` over the curve's points, ``z`` a normal
vector with the points' correlation (from the result's covariance, whatever method
gave it), and the band is each point's interval widened about its value by ``c / 1.96``
(:func:`widen`). Since ``max_i |z_i| >= |z_j|`` for every point, ``c >= 1.96`` and the
band always holds the pointwise one; ``c`` is larger the less the points are correlated (a
polynomial curve of a few coefficients: about 2.2 to 2.5).
"""

from __future__ import annotations

import math
import re

import numpy as np

from mtplan.uncertainty.streams import named_generator

__all__ = ["SEP", "curves", "parse_grid", "simultaneous_factor", "widen", "simultaneous_bands"]

#: the separator of a function's name and its position in a measurand's name
SEP = "@"
#: Monte Carlo draws of the sup-t quantile: its standard error is below 0.01 in c
DRAWS = 20_000
_POSITION = re.compile(r"^(?P<function>[^@]+)@(?P<position>[-+]?[0-9.]+(?:e[-+]?[0-9]+)?)$")


def curves(names) -> dict:
    """``{function: (indices, positions [mm])}`` of the measurands named
    ``FUNCTION@POSITION`` in `names`, each curve ordered by position; {} where there are
    none."""
    out: dict = {}
    for i, name in enumerate(names):
        m = _POSITION.match(str(name))
        if m:
            out.setdefault(m["function"], []).append((float(m["position"]), i))
    return {f: (np.array([i for _, i in sorted(pts)], dtype=int),
                np.array([p for p, _ in sorted(pts)], dtype=float)) for f, pts in out.items()}


def parse_grid(text: str, most: int | None = None) -> tuple:
    """``"START:STOP:STEP"`` [mm] -> the positions START to STOP inclusive, every STEP.

    Raises
    ------
    ValueError
        Not three numbers, STEP <= 0, STOP < START, or more than `most` positions (None:
        no limit).
    """
    try:
        start, stop, step = (float(v) for v in str(text).split(":"))
    except ValueError:
        start = stop = step = math.nan
    n = (stop - start) / step + 1 if step > 0 and stop >= start else math.nan
    if not (math.isfinite(n) and (most is None or n <= most)):
        raise ValueError(f"{text!r}: expected START:STOP:STEP [mm] with STEP > 0, STOP >= "
                         "START" + (f" and at most {most} positions" if most is not None
                                    else ""))
    return tuple(round(start + i * step, 9) for i in range(int(math.floor(n + 1e-9))))


def _seed_sequence(seed):
    if isinstance(seed, np.random.SeedSequence):
        return seed
    if isinstance(seed, list | tuple):
        return np.random.SeedSequence([int(s) for s in seed])
    return np.random.SeedSequence(0 if seed is None else int(seed))


def simultaneous_factor(covariance, coverage: float = 0.95, *, seed=0, name: str = "",
                        draws: int = DRAWS) -> float:
    """The sup-t factor ``c`` of a curve: the `coverage` quantile of ``max_i |z_i|``,
    ``z ~ N(0, R)`` with ``R`` the correlation of `covariance` (points of zero variance
    left out), drawn in one seeded batch (the stream of `name` under `seed`). Never below
    the pointwise normal factor, which it equals for a single point."""
    cov = np.asarray(covariance, dtype=float)
    z_point = float(_normal_quantile(0.5 + coverage / 2))
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    keep = sd > 0
    if keep.sum() <= 1:
        return z_point
    corr = cov[np.ix_(keep, keep)] / np.outer(sd[keep], sd[keep])
    w, v = np.linalg.eigh(0.5 * (corr + corr.T))
    root = v * np.sqrt(np.clip(w, 0.0, None))  # R = root @ root.T, also where R is singular
    rng = named_generator(_seed_sequence(seed), f"simultaneous band {name}")
    z = rng.standard_normal((draws, root.shape[1])) @ root.T
    c = float(np.quantile(np.max(np.abs(z), axis=1), coverage))
    return max(c, z_point)


def widen(centre, low, high, factor: float, coverage: float = 0.95):
    """(low, high) of the interval [low, high] widened about `centre` by ``factor / z``
    (``z`` the pointwise normal factor of `coverage`): an asymmetric interval stays as
    asymmetric."""
    scale = factor / float(_normal_quantile(0.5 + coverage / 2))
    centre, low, high = (np.asarray(a, dtype=float) for a in (centre, low, high))
    return centre - scale * (centre - low), centre + scale * (high - centre)


def simultaneous_bands(names, value, low, high, covariance, coverage: float = 0.95, *,
                       seed=0) -> tuple[dict, dict]:
    """The simultaneous band of every curve among `names` (:func:`curves`).

    Returns
    -------
    (bands, factors)
        ``{measurand: (low, high)}`` for each point of a curve, and ``{function: c}``.
    """
    cov = np.asarray(covariance, dtype=float)
    bands, factors = {}, {}
    for function, (idx, _) in curves(names).items():
        sub = cov[np.ix_(idx, idx)]
        ok = np.isfinite(np.asarray(value, float)[idx]) & np.all(np.isfinite(sub), axis=1)
        if not ok.any():
            continue
        idx = idx[ok]
        c = simultaneous_factor(cov[np.ix_(idx, idx)], coverage, seed=seed, name=function)
        lo, hi = widen(np.asarray(value, float)[idx], np.asarray(low, float)[idx],
                       np.asarray(high, float)[idx], c, coverage)
        factors[function] = c
        bands.update({names[i]: (float(a), float(b)) for i, a, b in zip(idx, lo, hi)})
    return bands, factors


def _normal_quantile(p: float) -> float:
    from scipy.stats import norm

    return float(norm.ppf(p))
