"""Is there evidence that the readings do not fit the model? Chi-square and data snooping.

A stated uncertainty holds only for readings that the forward model and its error
budget explain. :func:`fit_check` tests that, whichever way the uncertainty is
evaluated (``mc`` or ``posterior``), with two tests that share the stated significance
level ``alpha`` (default 0.05; ``alpha_chi2 = (1 - W_SHARE) alpha = 0.01``,
``alpha_w = W_SHARE alpha = 0.04``, so that a clean set of readings is flagged with
probability at most ``alpha``):

1. The generalised least-squares fit of every free parameter (the measurands' and
   the pose parameters', every float Truth field) and of the error-source
   elements the posterior samples as nuisance (their set-up distributions as
   priors, one pseudo-reading each), weighted by the readings' covariance under the
   whole error budget: the same fit and the same covariance the posterior starts
   from (:mod:`mtplan.evaluation.posterior`, :mod:`mtplan.fitting.error_model`).
2. The global test: the residuals at that fit, whitened by the covariance: their
   squared norm (with the nuisance elements' prior terms) is chi-square distributed
   with ``dof = readings - fitted parameters`` degrees of freedom when the readings
   fit the model (each nuisance element adds one pseudo-reading and one parameter, so
   it leaves the count alone; parameters the readings do not determine are not
   counted; a free noise takes one more). Its p-value is the upper tail; it fails
   when ``p < alpha_chi2``. It sees misfits spread over many readings.
3. Data snooping (Baarda): each reading's standardised residual, the w-test: the
   generalised residual ``(C^-1 r)_i`` over its standard deviation under the fit,
   ``sqrt(P_ii)`` with ``P = C^-1 - C^-1 J (J^T C^-1 J)^-1 J^T C^-1``. It is standard
   normal for a reading that fits, and the largest for a single reading that does
   not. The largest ``|w|`` over the ``n`` readings that have one fails when it
   exceeds the Bonferroni limit ``Phi^-1(1 - alpha_w / (2 n))``. It sees one bad
   reading, which the chi-square dilutes over all the others.

The worst readings are named, passed or not, by their row in the readings file as a
spreadsheet counts it (the header is row 1) and their column.

The fit is the generalised least squares, not the evaluation's estimator: an
estimator that is not efficient leaves larger residuals, which would not follow
the chi-square distribution. docs/fit_check.md states the method, and per procedure
what the check cannot see.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mtplan._validate import InvalidInput, Problems

# the readings' covariance under the error model: the one place it is imported from
from mtplan.fitting import Gaussian
from mtplan.uncertainty.options import Options

__all__ = ["FitCheck", "FitCheckOptions", "fit_check", "FIT_ALPHA", "N_WORST", "W_SHARE",
           "MDB_POWER", "w_limit", "reading_vector",
           "with_reading_vector"]

#: default significance level of the whole check (both tests together): the 5 % of a
#: metrologist's consistency checks (docs/fit_check.md, "Why alpha 0.05, split 0.04 / 0.01")
FIT_ALPHA = 0.05
#: share of the significance level given to the w-test, the most powerful test against one
#: bad reading; the rest, 0.01 at the default alpha, to the chi-square
W_SHARE = 0.8
#: readings listed in :attr:`FitCheck.worst`
N_WORST = 5
#: power at which :attr:`FitCheck.mdb` is stated
MDB_POWER = 0.8
_LEVERAGE = 1e-9  # a reading whose residual variance P_ii is below this of (C^-1)_ii has none


def reading_vector(readings: dict) -> tuple[list, np.ndarray]:
    """The numeric reading arrays of a batch of one as one vector, in the order of
    :attr:`FitCheck.z`, ``scatter`` and ``mdb`` (which leave missing readings out): the
    arrays' names and the vector (NaN where a reading is missing). With
    :func:`with_reading_vector`, the way to move readings in a power study."""
    keys = [k for k, v in readings.items() if np.asarray(v).dtype.kind in "fiu"]
    return keys, np.concatenate([np.asarray(readings[k], dtype=float).reshape(-1)
                                 for k in keys])


def with_reading_vector(readings: dict, keys: list, values: np.ndarray) -> dict:
    """A copy of `readings` with the arrays `keys` taken from `values` (the vector of
    :func:`reading_vector`, changed)."""
    out, at = dict(readings), 0
    for k in keys:
        a = np.asarray(readings[k], dtype=float)
        out[k] = np.asarray(values[at:at + a.size], dtype=float).reshape(a.shape)
        at += a.size
    return out


def w_limit(alpha_w: float, n: int) -> float:
    """Bonferroni limit of the largest ``|w|`` of `n` standard normal w-tests at `alpha_w`:
    ``Phi^-1(1 - alpha_w / (2 n))``."""
    from scipy import special  # scipy.stats' norm.isf, without importing scipy.stats

    return float(-special.ndtri(alpha_w / (2 * max(int(n), 1))))


@dataclass
class FitCheck:
    """The chi-square test and the data snooping of the readings against the model.

    Attributes
    ----------
    chi2 : float or None
        Squared norm of the whitened residuals at the fit (nuisance prior terms
        included); None where no fit could be made.
    dof : int
        Residual degrees of freedom: readings minus fitted parameters.
    p_value : float or None
        The chi-square test's ``P(chi-square(dof) >= chi2)``; None without residual
        degrees of freedom.
    ok : bool or None
        Both tests pass (:attr:`chi2_ok` and :attr:`w_ok`): no evidence of misfit at
        ``alpha``; None where the check cannot be made (:attr:`reason`).
    alpha : float
        Significance level of the whole check.
    worst : list of dict
        The readings with the largest standardised residuals, largest first:
        ``row`` (row of the readings file as a spreadsheet counts it, the header being
        row 1; None where unknown), ``column``, ``reading`` (the reading array and
        index) and ``z`` (its w-test value).
    reason : str or None
        Why ``ok`` is None.
    n_readings, n_parameters : int
        Readings used, and parameters fitted (free fields the readings determine,
        nuisance elements counted once for their parameter and once for their prior).
    nuisance : list of str
        Error sources fitted as nuisance parameters (non-linear ones).
    z : array (n_readings,) or None
        Standardised residual (w) of every used reading (NaN where the fit leaves it
        none), in the order of the readings' numeric arrays, flattened, missing ones
        left out.
    scatter : array (n_readings,) or None
        Each reading's own scatter under the budget: the standard deviation of what
        touches it alone (reading noise, repeatability) [its internal unit]; its whole
        standard deviation where nothing touches it alone.
    alpha_chi2, alpha_w : float
        The shares of ``alpha`` of the chi-square test and of the w-test.
    chi2_ok : bool or None
        ``p_value >= alpha_chi2``.
    n_tested : int
        Readings that have a w (residual freedom left by the fit): the Bonferroni count.
    w_max : float or None
        The w of the worst reading (signed; ``worst[0]["z"]``); ``w_at`` names it ("row 86
        z_mm").
    w_critical : float or None
        The limit of ``|w_max|``: ``Phi^-1(1 - alpha_w / (2 n_tested))``.
    p_w : float or None
        Bonferroni p-value of the largest ``|w|``: ``min(1, 2 n_tested Phi(-|w_max|))``.
    w_ok : bool or None
        ``|w_max| <= w_critical`` (equivalently ``p_w >= alpha_w``).
    p_overall : float or None
        The smallest ``alpha`` at which the check would flag these readings:
        ``min(1, p_value / (1 - W_SHARE), p_w / W_SHARE)``; ``ok`` is ``p_overall >= alpha``.
    mdb : array (n_readings,) or None
        The minimal detectable bias of every reading [its internal unit]: the error of
        that reading alone that the whole check (the chi-square or any reading's w-test)
        flags with probability ``MDB_POWER`` (0.8) in the linear Gaussian design
        (:mod:`mtplan.evaluation.detectability`); NaN where it has no w. Below Baarda's
        ``(w_critical + Phi^-1(0.8)) / sqrt(P_ii)``, the one w-test's, by up to a few per
        cent. An error smaller than this is likely to pass unseen.
    labels : list of tuple
        ``(row, column, reading)`` of every used reading, in the order of :attr:`z` (as
        :attr:`worst` names them).
    mdb_directions : array (m,) or None
        With ``fit_check(..., directions=D)``: the minimal detectable bias of an error
        ``b D[:, j]`` that moves several readings at once (one bad contact along its
        probing direction) [the size of b], by the whole check as :attr:`mdb`; inf where
        the fit absorbs that error whole.
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
    alpha_chi2: float | None = None
    alpha_w: float | None = None
    chi2_ok: bool | None = None
    n_tested: int = 0
    w_max: float | None = None
    w_critical: float | None = None
    p_w: float | None = None
    w_ok: bool | None = None
    p_overall: float | None = None
    mdb: np.ndarray | None = field(default=None, repr=False)
    w_at: str | None = None
    labels: list = field(default_factory=list, repr=False)
    mdb_directions: np.ndarray | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        """The ``fit`` object of ``mtplan estimate --json``."""
        def num(x):
            return None if x is None else float(x)

        return {"chi2": self.chi2, "dof": int(self.dof), "p_value": self.p_value,
                "ok": self.ok, "alpha": float(self.alpha),
                "worst": [dict(w) for w in self.worst], "reason": self.reason,
                "n_readings": int(self.n_readings), "n_parameters": int(self.n_parameters),
                "alpha_chi2": num(self.alpha_chi2), "chi2_ok": self.chi2_ok,
                "alpha_w": num(self.alpha_w), "n_tested": int(self.n_tested),
                "w_max": num(self.w_max), "w_critical": num(self.w_critical),
                "p_w": num(self.p_w), "w_ok": self.w_ok, "w_at": self.w_at,
                "p_overall": num(self.p_overall)}

    @staticmethod
    def _where(w: dict) -> str:
        return f"row {w['row']} {w['column']}".strip() if w["row"] else w["reading"]

    def worst_text(self, count: int = 3) -> str:
        """The worst readings in words: "row 17 z_mm (z = 31.2), ..."."""
        return ", ".join(f"{self._where(w)} (z = {w['z']:+.1f})" for w in self.worst[:count])

    def _chi2_text(self) -> str:
        limit = self.alpha if self.alpha_chi2 is None else self.alpha_chi2
        sign = ">=" if self.p_value >= limit else "<"
        return (f"chi-square {self.chi2:.4g} with {self.dof} degrees of freedom, "
                f"p = {self.p_value:.3g} {sign} {limit:g}")

    def _w_text(self) -> str:
        if self.w_max is None:
            return "no reading has a w-test (the fit leaves no reading residual freedom)"
        if self.w_critical is None:
            return f"largest |w| {abs(self.w_max):.2f} at {self.w_at} (the w-test not made)"
        sign = "<=" if self.w_ok else ">"
        return (f"largest |w| {abs(self.w_max):.2f} at {self.w_at} "
                f"(w = {self.w_max:+.2f}) {sign} {self.w_critical:.2f}, the limit over "
                f"{self.n_tested} readings at {self.alpha_w:g}")

    def summary(self) -> str:
        """One line: both tests, the worst reading and its row, and the outcome."""
        if self.ok is None:
            return f"fit check: not made: {self.reason}"
        outcome = ("no evidence of misfit" if self.ok
                   else "the readings do not fit the model")
        return (f"fit check at alpha {self.alpha:g}: {outcome} ({self._chi2_text()}; "
                f"{self._w_text()})")

    def failure_text(self) -> str | None:
        """Which test failed and why, in words; None when the check passed or was not made."""
        if self.ok is not False:
            return None
        parts = []  # a check built by hand with ok False alone: its chi-square is the reason
        if self.w_ok is False:
            parts.append(f"the w-test names {self.w_at} "
                         f"(w = {self.w_max:+.2f}, beyond {self.w_critical:.2f}, the limit over "
                         f"{self.n_tested} readings at {self.alpha_w:g})")
        if self.chi2_ok is False or (not parts and self.chi2 is not None):
            parts.append(self._chi2_text())
        return "; ".join(parts)

    def warning(self) -> str | None:
        """The warning printed under a result whose readings do not fit; None otherwise."""
        if self.ok is not False:
            return None
        return (f"WARNING: the readings do not fit the model at alpha {self.alpha:g}: "
                f"{self.failure_text()}, so the stated uncertainty is not valid for them; "
                f"worst readings: {self.worst_text()}")


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

    from mtplan.evaluation.posterior import RANK_TOL

    norms = np.linalg.norm(A, axis=0)
    A = A[:, norms > 0] / norms[norms > 0]
    if A.shape[1] == 0:
        return np.zeros((A.shape[0], 0))
    Q, R, _ = qr(A, mode="economic", pivoting=True)
    return Q[:, :int(np.sum(np.abs(np.diag(R)) > RANK_TOL))]


def _statistics(fwd, fit, g: Gaussian, Q: np.ndarray, prior_res: np.ndarray) -> tuple:
    """(chi2, z, P_ii) at the fit: the whitened residuals with the nuisance priors'
    terms, the w-test of every reading and its residual variance; `Q` (n + q, rank) spans
    the whitened Jacobian of the fitted parameters with the priors' rows."""
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
        has = den > _LEVERAGE * cinv
        z = np.where(has, num / np.sqrt(np.abs(den)), np.nan)
    return chi2, z, np.where(has, den, np.nan)


def _noise_mode(noise):
    """("setup" | "free" | "known", sigma) from the `noise` argument."""
    if noise is None or (isinstance(noise, str) and noise in ("setup", "free")):
        return (noise or "setup"), None
    if isinstance(noise, bool) or not isinstance(noise, int | float) or not noise > 0:
        raise InvalidInput([f"The 'noise' parameter of fit_check must be 'setup', 'free' or a "
                            f"number > 0. Got {noise!r} instead."])
    return "known", float(noise)


@dataclass(frozen=True)
class FitCheckOptions(Options):
    """How strict the fit check is and how much it lists (frozen: change one with
    :meth:`replace`).

    Attributes
    ----------
    alpha : float
        Significance level of the whole check: ``ok`` is False when the chi-square's
        ``p_value < (1 - w_share) alpha`` or the largest ``|w|`` exceeds its Bonferroni
        limit at ``w_share alpha``.
    w_share : float
        Share of `alpha` given to the w-test, in [0, 1] (0: the chi-square alone).
    n_worst : int
        Readings listed in ``worst``.
    directions : array (readings, m), optional
        Errors that move several readings together, one per column over the readings'
        numeric arrays flattened (:func:`reading_vector`'s order, missing ones included):
        their minimal detectable bias, :attr:`FitCheck.mdb_directions`.
    """

    alpha: float = FIT_ALPHA
    w_share: float = W_SHARE
    n_worst: int = N_WORST
    directions: object = None

    WHAT = "fit check option"


def fit_check(procedure, setup, readings, *, noise="setup", estimator: str | None = None,
              origin=None, options: FitCheckOptions | None = None,
              **option_overrides) -> FitCheck:
    """Test the readings against the procedure's model and error budget.

    Parameters
    ----------
    procedure : str or Procedure
    setup : Setup
        The set-up the readings were taken with; its error sources are the budget.
    readings : dict of str to array
        A batch of one (:func:`mtplan.evaluation.readings.read_readings`).
    noise : "setup", "free" or float
        The noise source's standard deviation, as :func:`sample_posterior` takes it
        ("free": fitted, one more degree of freedom used).
    estimator : str, optional
        The estimator whose estimate starts the fit.
    origin : dict, optional
        Row and column of every reading in the file (``Measurement.origin``); default:
        those of the table ``procedure.readings.frame`` writes.
    options : FitCheckOptions, optional
        The significance level, its share for the w-test, the readings listed
        (:class:`FitCheckOptions`); any of its fields may be given as a keyword instead
        (``alpha=0.01``), the errors that move several readings too.

    Returns
    -------
    FitCheck
        ``ok`` None, with the reason, where the readings leave no residual degree of
        freedom or the model cannot be fitted to them.
    """
    from mtplan.evaluation import posterior as post
    from mtplan.evaluation.detectability import CheckLimits, detectable_bias
    from mtplan.evaluation._posterior_model import Forward, TruthBuilder, truth_parameters
    from mtplan.evaluation.readings import reading_origin
    from mtplan._parallel import one_blas_thread
    from mtplan.models import get

    o = FitCheckOptions.of(options, **option_overrides)
    alpha, n_worst, w_share, directions = o.alpha, o.n_worst, o.w_share, o.directions
    proc = get(procedure)
    p_ = Problems(f"fit check {proc.name}")
    p_.number("alpha", alpha, low=0, high=1, low_open=True, high_open=True)
    p_.number("n_worst", n_worst, integer=True, low=0)
    p_.number("w_share", w_share, low=0, high=1)
    p_.raise_if_any()
    mode, sigma = _noise_mode(noise)
    base = proc.Truth()
    builder = TruthBuilder(base, truth_parameters(proc, base))
    fwd = Forward(proc, setup, readings, builder)
    notes: list = []
    try:
        with one_blas_thread():
            theta0 = post.initial_theta(proc, setup, readings, builder, None, estimator, notes)
            fit = post.start_fit(fwd, theta0, mode, sigma, notes)
            g = fit.error_model.gaussian(fit.sigma)
            pri = post.nuisance_priors(fit.error_model)
            p, q = fit.theta.size, pri.shape[0]
            steps = np.concatenate([builder.steps(fit.theta), 1e-3 * pri[:, 1]])
            J = fwd.jacobian(fit.theta, fit.nuis if q else None, steps)
            Jw = g.whiten(J.T).T
            if q:
                Jw = np.vstack([Jw, np.hstack([np.zeros((q, p)), np.diag(1.0 / pri[:, 1])])])
            Q = _basis(Jw)
            rank = Q.shape[1]
            dof = fwd.n + q - rank - (1 if fit.error_model.Dn is not None else 0)
            nuisance = [name for name, _ in fit.error_model.nuisance]
            if dof <= 0:
                return FitCheck(chi2=None, dof=dof, p_value=None, ok=None, alpha=alpha,
                                reason=f"the {fwd.n} readings leave no residual degree of "
                                f"freedom for the {rank - q} fitted parameters",
                                n_readings=fwd.n, n_parameters=rank, nuisance=nuisance)
            prior_res = (fit.nuis - pri[:, 0]) / pri[:, 1] if q else np.zeros(0)
            chi2, z, pii = _statistics(fwd, fit, g, Q, prior_res)
            WD = None if directions is None else np.vstack([
                g.whiten(np.asarray(directions, dtype=float)[fwd.mask].T).T,
                np.zeros((q, np.shape(directions)[1]))])
    except InvalidInput as exc:
        return _not_made("the model cannot be fitted to the readings: "
                         + " ".join(exc.problems), alpha, fwd.n)
    from scipy import special

    pval = float(special.chdtrc(dof, chi2))  # scipy.stats' chi2.sf
    if origin is None:
        try:
            origin = reading_origin(proc, setup, readings)
        except (InvalidInput, ValueError, KeyError, IndexError, TypeError):
            origin = None
    labels = _labels(fwd, {k: np.shape(readings[k])[1:] for k in fwd.keys}, origin)
    order = [i for i in np.argsort(-np.nan_to_num(np.abs(z), nan=-1.0)) if np.isfinite(z[i])]
    worst = [{"row": labels[i][0], "column": labels[i][1], "reading": labels[i][2],
              "z": float(z[i])} for i in order[:max(n_worst, 1)]]
    snoop = _snooping(z, order, pval, alpha, w_share)
    mdb = mdb_dir = None
    if snoop["w_critical"]:
        c2 = special.chdtri(dof, snoop["alpha_chi2"]) if snoop["alpha_chi2"] > 0 else np.inf
        with one_blas_thread():
            limits = CheckLimits(c=snoop["w_critical"], c2=c2, dof=dof,
                                 alpha_w=snoop["alpha_w"], power=MDB_POWER)
            mdb, mdb_dir = detectable_bias(g, Q, pii, WD, limits=limits, wt=_wt)
        mdb = np.where(np.isfinite(pii), mdb, np.nan)
    b = fit.error_model
    own = b.D0 if b.Dn is None else b.D0 + fit.sigma**2 * b.Dn
    every = own + np.sum(b.U0**2, axis=1) + (0 if b.Dn is None else fit.sigma**2 * np.sum(
        b.Un**2, axis=1))
    return FitCheck(chi2=chi2, dof=int(dof), p_value=pval, alpha=alpha,
                    worst=worst[:n_worst], n_readings=fwd.n, n_parameters=rank,
                    nuisance=nuisance, z=z, scatter=np.sqrt(np.where(own > 0, own, every)),
                    mdb=mdb, w_at=FitCheck._where(worst[0]) if worst else None,
                    labels=labels, mdb_directions=mdb_dir, **snoop)


def _snooping(z: np.ndarray, order: list, pval: float, alpha: float, w_share: float) -> dict:
    """The w-test of the largest |w| (Bonferroni over the readings that have one), the
    chi-square's share of alpha, and the verdict of both: FitCheck's fields."""
    from scipy import special

    a_chi2, a_w = (1.0 - w_share) * alpha, w_share * alpha
    n = len(order)
    chi2_ok = bool(pval >= a_chi2) if w_share < 1 else True
    p_chi2 = min(1.0, pval / (1.0 - w_share)) if w_share < 1 else 1.0
    if n == 0 or w_share == 0:
        w_max = float(z[order[0]]) if n else None
        return {"alpha_chi2": a_chi2, "alpha_w": a_w, "chi2_ok": chi2_ok, "n_tested": n,
                "w_max": w_max, "w_critical": None, "p_w": None, "w_ok": None,
                "ok": chi2_ok, "p_overall": p_chi2}
    w_max = float(z[order[0]])
    p_w = float(min(1.0, 2 * n * special.ndtr(-abs(w_max))))
    crit = w_limit(a_w, n)
    w_ok = bool(abs(w_max) <= crit)
    p_all = min(1.0, p_w / w_share, p_chi2)
    return {"alpha_chi2": a_chi2, "alpha_w": a_w, "chi2_ok": chi2_ok, "n_tested": n,
            "w_max": w_max, "w_critical": crit, "p_w": p_w, "w_ok": w_ok,
            "ok": chi2_ok and w_ok, "p_overall": float(p_all)}
