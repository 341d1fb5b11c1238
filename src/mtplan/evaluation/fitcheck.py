"""Do the readings fit the model? A chi-square test of every measured evaluation.

A stated uncertainty holds only for readings that the forward model and its error
budget explain. :func:`fit_check` tests that, whichever way the uncertainty is
evaluated (``mc`` or ``posterior``):

1. The generalised least-squares fit of every free parameter (the measurands' and
   the pose parameters', every float Truth field) and of the error-source
   elements the posterior samples as nuisance (their set-up distributions as
   priors, one pseudo-reading each), weighted by the readings' covariance under the
   whole error budget: the same fit and the same covariance the posterior starts
   from (:mod:`mtplan.evaluation.posterior`, :mod:`mtplan.fitting.budget`).
2. The residuals at that fit, whitened by the covariance: their squared norm (with
   the nuisance elements' prior terms) is chi-square distributed with
   ``dof = readings - fitted parameters`` degrees of freedom when the readings fit
   the model (each nuisance element adds one pseudo-reading and one parameter, so
   it leaves the count alone; parameters the readings do not determine are not
   counted; a free noise takes one more). The p-value is its upper tail.
3. Each reading's standardised residual (Baarda's w-test): the generalised residual
   ``(C^-1 r)_i`` over its standard deviation under the fit, ``sqrt(P_ii)`` with
   ``P = C^-1 - C^-1 J (J^T C^-1 J)^-1 J^T C^-1``. It is standard normal for a reading
   that fits, and the largest for a single reading that does not. The worst are
   named by their row in the readings file (1 = the first data row under the
   header; comment and blank lines are not counted) and column.

The fit is the generalised least squares, not the evaluation's estimator: an
estimator that is not efficient leaves larger residuals, which would not follow
the chi-square distribution. docs/fit_check.md states the method.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mtplan._validate import InvalidInput, Problems

# the readings' covariance under the error budget: the one place it is imported from
from mtplan.fitting import Gaussian

__all__ = ["FitCheck", "fit_check", "FIT_ALPHA", "N_WORST"]

#: default significance level: the readings "do not fit" when p < FIT_ALPHA
FIT_ALPHA = 0.01
#: readings listed in :attr:`FitCheck.worst`
N_WORST = 5
_LEVERAGE = 1e-9  # a reading whose residual variance P_ii is below this of (C^-1)_ii has none


@dataclass
class FitCheck:
    """The chi-square test of the readings against the model and its error budget.

    Attributes
    ----------
    chi2 : float or None
        Squared norm of the whitened residuals at the fit (nuisance prior terms
        included); None where no fit could be made.
    dof : int
        Residual degrees of freedom: readings minus fitted parameters.
    p_value : float or None
        ``P(chi-square(dof) >= chi2)``; None without residual degrees of freedom.
    ok : bool or None
        ``p_value >= alpha``; None where the test cannot be made (:attr:`reason`).
    alpha : float
    worst : list of dict
        The readings with the largest standardised residuals, largest first:
        ``row`` (data row of the readings file, 1 = the first under the header; None
        where unknown), ``column``, ``reading`` (the reading array and index) and ``z``.
    reason : str or None
        Why ``ok`` is None.
    n_readings, n_parameters : int
        Readings used, and parameters fitted (free fields the readings determine,
        nuisance elements counted once for their parameter and once for their prior).
    nuisance : list of str
        Error sources fitted as nuisance parameters (non-linear ones).
    z : array (n_readings,) or None
        Standardised residual of every used reading (NaN where the fit leaves it none),
        in the order of the readings' numeric arrays, flattened, missing ones left out.
    scatter : array (n_readings,) or None
        Each reading's own scatter under the budget: the standard deviation of what
        touches it alone (reading noise, repeatability) [its internal unit]; its whole
        standard deviation where nothing touches it alone.
    """

    chi2: float | None
    dof: int
    p_value: float | None
    ok: bool | None
    alpha: float = FIT_ALPHA
    worst: list = field(default_factory=list)
    reason: str | None = None
    n_readings: int = 0
    n_parameters: int = 0
    nuisance: list = field(default_factory=list)
    z: np.ndarray | None = field(default=None, repr=False)
    scatter: np.ndarray | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        """The ``fit`` object of ``mtplan estimate --json``."""
        return {"chi2": self.chi2, "dof": int(self.dof), "p_value": self.p_value,
                "ok": self.ok, "alpha": float(self.alpha),
                "worst": [dict(w) for w in self.worst], "reason": self.reason,
                "n_readings": int(self.n_readings), "n_parameters": int(self.n_parameters)}

    def worst_text(self, count: int = 3) -> str:
        """The worst readings in words: "row 17 z_mm (z = 31.2), ..."."""
        parts = []
        for w in self.worst[:count]:
            where = f"row {w['row']} {w['column']}".strip() if w["row"] else w["reading"]
            parts.append(f"{where} (z = {w['z']:+.1f})")
        return ", ".join(parts)

    def summary(self) -> str:
        """One line: chi-square, dof, p-value and the outcome."""
        if self.ok is None:
            return f"fit check: not made: {self.reason}"
        head = (f"fit check: chi-square {self.chi2:.4g} with {self.dof} degrees of freedom, "
                f"p = {self.p_value:.3g}")
        if self.ok:
            return head + f" >= {self.alpha:g}: the readings fit the model"
        return head + f" < {self.alpha:g}"

    def warning(self) -> str | None:
        """The warning printed under a result whose readings do not fit; None when they do."""
        if self.ok is not False:
            return None
        return (f"WARNING: the readings do not fit the model (chi-square {self.chi2:.4g} with "
                f"{self.dof} degrees of freedom, p = {self.p_value:.2g} < {self.alpha:g}), so "
                f"the stated uncertainty is not valid for them; worst readings: "
                f"{self.worst_text()}")


def _not_made(reason: str, alpha: float, n: int = 0) -> FitCheck:
    return FitCheck(chi2=None, dof=0, p_value=None, ok=None, alpha=alpha, reason=reason,
                    n_readings=n)


def _wt(g: Gaussian, V: np.ndarray) -> np.ndarray:
    """``W^T V`` for the whitening ``W`` of a known Gaussian (``W^T W = C^-1``), V (n, m)."""
    if g.mode == "dense":
        return g.white.T @ V
    return g.base_t(V - g.q @ (g.shrink[:, None] * (g.q.T @ V)))


def _cinv_diag(g: Gaussian) -> np.ndarray:
    """Diagonal of ``C^-1``."""
    if g.mode == "dense":
        return np.sum(g.white**2, axis=0)
    s = g.shrink
    if g.wb is not None:  # a block base B: diag(B^T B) less the low-rank part's
        return (np.asarray(g.wb.multiply(g.wb).sum(axis=0)).ravel()
                - (g.base_t(g.q) ** 2) @ (2.0 * s - s * s))
    return g.rs**2 * (1.0 - (g.q**2) @ (2.0 * s - s * s))


def _labels(fwd, shapes: dict, origin) -> list[tuple]:
    """(row, column, reading) of every used reading, in the order of ``fwd.y``."""
    out = []
    for key in fwd.keys:
        rows, cols = (origin or {}).get(key, (None, None))
        rows = None if rows is None else np.asarray(rows).reshape(-1)
        cols = None if cols is None else np.asarray(cols).reshape(-1)
        for j, idx in enumerate(np.ndindex(*shapes[key])):
            name = f"{key}[{','.join(map(str, idx))}]" if idx else key
            row = int(rows[j]) if rows is not None else 0
            out.append((row or None, "" if cols is None else str(cols[j]), name))
    return [lab for lab, used in zip(out, fwd.mask, strict=True) if used]


def _basis(A: np.ndarray) -> np.ndarray:
    """Orthonormal basis (rows, rank) of the span of A's columns: pivoted QR of the columns
    scaled to unit norm, a column whose part outside the others' span is below the
    posterior's rank tolerance counted as in it (the parameters the readings do not
    determine, which the fit holds)."""
    from scipy.linalg import qr

    from mtplan.evaluation.posterior import _RANK_TOL

    norms = np.linalg.norm(A, axis=0)
    A = A[:, norms > 0] / norms[norms > 0]
    if A.shape[1] == 0:
        return np.zeros((A.shape[0], 0))
    Q, R, _ = qr(A, mode="economic", pivoting=True)
    return Q[:, :int(np.sum(np.abs(np.diag(R)) > _RANK_TOL))]


def _statistics(fwd, fit, g: Gaussian, Q: np.ndarray, prior_res: np.ndarray) -> tuple:
    """(chi2, z per reading) at the fit: the whitened residuals with the nuisance priors'
    terms, and the w-test of every reading; `Q` (n + q, rank) spans the whitened
    Jacobian of the fitted parameters with the priors' rows."""
    q = prior_res.size
    pred, ok = fwd.predict(fit.theta[None], fit.nuis[None] if q else None)
    if not ok[0]:
        raise InvalidInput([f"The forward model of {fwd.proc.name} fails at the fit."])
    w = g.whiten(fwd.y - pred[0] - fit.correction)[0]
    chi2 = float(w @ w + prior_res @ prior_res)
    cinv = _cinv_diag(g)
    num = _wt(g, w[:, None])[:, 0]  # C^-1 r
    den = cinv - np.sum(_wt(g, Q[:fwd.n]) ** 2, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.where(den > _LEVERAGE * cinv, num / np.sqrt(np.abs(den)), np.nan)
    return chi2, z


def _noise_mode(noise):
    """("setup" | "free" | "known", sigma) from the `noise` argument."""
    if noise is None or (isinstance(noise, str) and noise in ("setup", "free")):
        return (noise or "setup"), None
    if isinstance(noise, bool) or not isinstance(noise, int | float) or not noise > 0:
        raise InvalidInput([f"The 'noise' parameter of fit_check must be 'setup', 'free' or a "
                            f"number > 0. Got {noise!r} instead."])
    return "known", float(noise)


def fit_check(procedure, setup, readings, *, alpha: float = FIT_ALPHA, noise="setup",
              estimator: str | None = None, origin=None, n_worst: int = N_WORST) -> FitCheck:
    """Test whether the readings fit the procedure's model and error budget.

    Parameters
    ----------
    procedure : str or Procedure
    setup : Setup
        The set-up the readings were taken with; its error sources are the budget.
    readings : dict of str to array
        A batch of one (:func:`mtplan.evaluation.readings.read_readings`).
    alpha : float
        Significance level: ``ok`` is False when ``p_value < alpha``.
    noise : "setup", "free" or float
        The noise source's standard deviation, as :func:`sample_posterior` takes it
        ("free": fitted, one more degree of freedom used).
    estimator : str, optional
        The estimator whose estimate starts the fit.
    origin : dict, optional
        Row and column of every reading in the file (``Measurement.origin``); default:
        those of the table ``procedure.readings.frame`` writes.
    n_worst : int
        Readings listed in ``worst``.

    Returns
    -------
    FitCheck
        ``ok`` None, with the reason, where the readings leave no residual degree of
        freedom or the model cannot be fitted to them.
    """
    from mtplan.evaluation import posterior as post
    from mtplan.evaluation._posterior_model import Forward, TruthBuilder, truth_parameters
    from mtplan.evaluation.readings import reading_origin
    from mtplan._parallel import one_blas_thread
    from mtplan.models import get

    proc = get(procedure)
    p_ = Problems(f"fit check {proc.name}")
    p_.number("alpha", alpha, low=0, high=1, low_open=True, high_open=True)
    p_.number("n_worst", n_worst, integer=True, low=0)
    p_.raise_if_any()
    mode, sigma = _noise_mode(noise)
    base = proc.Truth()
    builder = TruthBuilder(base, truth_parameters(proc, base))
    fwd = Forward(proc, setup, readings, builder)
    notes: list = []
    try:
        with one_blas_thread():
            theta0 = post._initial_theta(proc, setup, readings, builder, None, estimator, notes)
            fit = post._start(fwd, theta0, mode, sigma, notes)
            g = fit.budget.gaussian(fit.sigma)
            pri = post._nuisance_priors(fit.budget)
            p, q = fit.theta.size, pri.shape[0]
            steps = np.concatenate([builder.steps(fit.theta), 1e-3 * pri[:, 1]])
            J = fwd.jacobian(fit.theta, fit.nuis if q else None, steps)
            Jw = g.whiten(J.T).T
            if q:
                Jw = np.vstack([Jw, np.hstack([np.zeros((q, p)), np.diag(1.0 / pri[:, 1])])])
            Q = _basis(Jw)
            rank = Q.shape[1]
            dof = fwd.n + q - rank - (1 if fit.budget.Dn is not None else 0)
            nuisance = [name for name, _ in fit.budget.nuisance]
            if dof <= 0:
                return FitCheck(chi2=None, dof=dof, p_value=None, ok=None, alpha=alpha,
                                reason=f"the {fwd.n} readings leave no residual degree of "
                                f"freedom for the {rank - q} fitted parameters",
                                n_readings=fwd.n, n_parameters=rank, nuisance=nuisance)
            prior_res = (fit.nuis - pri[:, 0]) / pri[:, 1] if q else np.zeros(0)
            chi2, z = _statistics(fwd, fit, g, Q, prior_res)
    except InvalidInput as exc:
        return _not_made("the model cannot be fitted to the readings: "
                         + " ".join(exc.problems), alpha, fwd.n)
    from scipy import stats

    pval = float(stats.chi2.sf(chi2, dof))
    if origin is None:
        try:
            origin = reading_origin(proc, setup, readings)
        except (InvalidInput, ValueError, KeyError, IndexError, TypeError):
            origin = None
    labels = _labels(fwd, {k: np.shape(readings[k])[1:] for k in fwd.keys}, origin)
    order = [i for i in np.argsort(-np.nan_to_num(np.abs(z), nan=-1.0)) if np.isfinite(z[i])]
    worst = [{"row": labels[i][0], "column": labels[i][1], "reading": labels[i][2],
              "z": float(z[i])} for i in order[:n_worst]]
    b = fit.budget
    own = b.D0 if b.Dn is None else b.D0 + fit.sigma**2 * b.Dn
    every = own + np.sum(b.U0**2, axis=1) + (0 if b.Dn is None else fit.sigma**2 * np.sum(
        b.Un**2, axis=1))
    return FitCheck(chi2=chi2, dof=int(dof), p_value=pval, ok=bool(pval >= alpha), alpha=alpha,
                    worst=worst, n_readings=fwd.n, n_parameters=rank,
                    nuisance=nuisance, z=z, scatter=np.sqrt(np.where(own > 0, own, every)))
