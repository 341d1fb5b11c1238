"""Covariance of measured and simulated results, in the measurands' display units.

:func:`mc_covariance`: the covariance of `mc` values, the Monte Carlo estimates' plus the bias
correction's part (:mod:`mtplan.evaluation.correction`); :func:`posterior_covariance`: of the
posterior samples. Both are consistent with the reported u: the diagonal is u^2.
:func:`covariance_doc` is the ``covariance`` object of the ``--json`` documents of
``estimate`` and ``simulate``, :func:`covariance_frame` a report's
``results/covariance_<procedure>_<k>.csv``. Formatting and arithmetic only: nothing here runs a
model.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["correction_u", "mc_covariance", "posterior_covariance", "correlation",
           "covariance_doc", "covariance_frame"]


def correction_u(std, trials: int, d) -> tuple[np.ndarray, np.ndarray]:
    """(u of the correction's Monte Carlo standard error, u of its truth dependence).

    ``std / sqrt(trials)`` and the root mean square of `d` (zero when `d` has no rows)."""
    se = np.asarray(std, dtype=float) / math.sqrt(max(int(trials), 1))
    d = np.asarray(d, dtype=float)
    nuis = np.sqrt(np.mean(d**2, axis=0)) if d.shape[0] else np.zeros_like(se)
    return se, nuis


def mc_covariance(cov_mc, trials: int, d, u) -> np.ndarray:
    """Covariance of the `mc` values: Monte Carlo estimates plus the correction's part.

    ``C = C_mc (1 + 1/N) + (1/K) sum_k d_k d_k^T``, rescaled so that its diagonal is `u`^2
    (where heavy tails make u the interval's half-width over the coverage factor, the
    correlations are kept). Rows and columns of a measurand with u NaN are NaN.
    """
    cov_mc = np.atleast_2d(np.asarray(cov_mc, dtype=float))
    d = np.asarray(d, dtype=float)
    c = cov_mc * (1.0 + 1.0 / max(int(trials), 1))
    if d.shape[0]:
        c = c + d.T @ d / d.shape[0]
    return _with_diagonal(c, np.asarray(u, dtype=float))


def posterior_covariance(post, names) -> np.ndarray:
    """Covariance of the posterior samples of the measurands `names` (ddof 1, as the
    posterior's u), diagonal set to the reported u^2."""
    x = np.vstack([np.asarray(post.samples[n], dtype=float) for n in names])
    c = np.atleast_2d(np.cov(x, ddof=1))
    return _with_diagonal(c, np.array([post.std[n] for n in names], dtype=float))


def _with_diagonal(c, u) -> np.ndarray:
    s = np.sqrt(np.diag(c))
    with np.errstate(invalid="ignore", divide="ignore"):
        r = c / np.outer(s, s)
    r[np.diag_indices_from(r)] = 1.0
    out = r * np.outer(u, u)
    bad = ~np.isfinite(u)
    out[bad, :] = np.nan
    out[:, bad] = np.nan
    return out


def correlation(cov) -> np.ndarray:
    """Correlation matrix of a covariance (NaN where a variance is 0 or NaN)."""
    cov = np.asarray(cov, dtype=float)
    s = np.sqrt(np.diag(cov))
    with np.errstate(invalid="ignore", divide="ignore"):
        return cov / np.outer(s, s)


def covariance_doc(measurands, cov) -> dict:
    """The ``covariance`` object of a ``--json`` document.

    ``names`` and ``units`` of the measurands in order, and ``matrix``: element [i][j] in
    units[i] x units[j] (um, urad), null where a measurand has no value."""
    cov = np.asarray(cov, dtype=float)
    return {"names": [m.name for m in measurands], "units": [m.unit for m in measurands],
            "matrix": [[float(v) if math.isfinite(v) else None for v in row] for row in cov]}


def covariance_frame(measurands, cov):
    """The covariance as a table: one row per measurand (name, unit), one column per
    measurand (element [i][j] in unit_i x unit_j)."""
    import pandas as pd

    names = [m.name for m in measurands]
    frame = pd.DataFrame(np.asarray(cov, dtype=float), columns=names)
    frame.insert(0, "unit", [m.unit for m in measurands])
    frame.insert(0, "measurand", names)
    return frame
