"""Generalised least squares over the readings' covariance: one fitter for every procedure.

A procedure states three things: its readings as a function of its parameters (a
batch-first ``predict``), its error sources, and where to start. This module does
the rest, the way astropy.modeling's fitters serve any model that declares its
parameters:

- :func:`source_effects` and :func:`readings_covariance`: the covariance
  ``C = D + U U^T`` of the readings under every active error source, from the forward
  model itself (each element of each source set to plus and minus one standard
  deviation: half the difference is its secant effect, a column of ``U``, or a term
  of ``D`` where it touches one reading alone). The same secants as the posterior's
  likelihood (:func:`mtplan.fitting.error_model`), through the same code.
- :func:`central_jacobian`: the readings' Jacobian over the parameters by central
  differences, all columns one batched call, one-sided at a parameter's limit.
- :func:`gls_gain`: the gain ``K = (J^T C^-1 J)^-1 J^T C^-1`` of the linearised fit.
- :func:`gauss_newton`: Gauss-Newton over a batch of trials with one gain shared by
  the batch (a fixed design: one matrix product per iteration for all trials), the
  gain re-taken where the caller asks.
- :func:`gls_step`: one generalised least-squares step for rows with their own
  Jacobian and covariance (batched normal equations).
- :func:`whitened_residuals`: residuals whitened by the covariance, their chi-square
  and degrees of freedom (a fit check).

Units are the caller's; nothing here knows millimetres from radians, which is why
dense covariances are scaled to unit diagonal before they are factored.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.fitting.error_model import ErrorModel, Gaussian
from mtplan.fitting.effects import effect

__all__ = ["SourceModel", "source_effects", "readings_covariance", "central_jacobian",
           "gls_gain", "gauss_newton", "GaussNewtonResult", "gls_step", "whitened_residuals",
           "WhitenedResiduals"]


# --------------------------------------------------------------------------- covariance
class SourceModel:
    """The readings as a function of the error sources, at fixed parameters.

    Parameters
    ----------
    name : str
        The procedure's name (for messages).
    sources : dict of str to Source
        Every error source of the set-up (objects with ``distribution`` and ``shape``).
    readings : callable
        ``readings(errors) -> array (m, n)``: the readings, flattened, for error rows
        ``errors`` (dict of str to array (m, *shape)).
    zero_errors : callable
        ``zero_errors(m) -> dict``: fresh, writable error rows of every source at zero
        (or at the value the effects are taken about).
    structure : callable, optional
        ``structure(name) -> (colours, owners)`` or None: a colouring of the source's
        elements (elements of one colour never move a common reading; ``owners``
        (colours, n) the element of each colour each reading depends on, -1 none), so
        that its effects take two forward rows per colour, not per element (a
        procedure's ``source_structure``).
    """

    def __init__(self, name: str, sources: Mapping, readings: Callable, zero_errors: Callable,
                 structure: Callable | None = None):
        self.name, self.sources = name, dict(sources)
        self._readings, self._zero, self._structure = readings, zero_errors, structure
        self._n = None

    def structure(self, truth, name: str):
        """The colouring of source `name` (see the class), or None."""
        return None if self._structure is None else self._structure(name)

    def errors(self, m: int, copy_of=()) -> dict:
        return self._zero(m)

    def at(self, truth, errors) -> np.ndarray:
        m = next(iter(errors.values())).shape[0]
        with np.errstate(all="ignore"):
            return np.asarray(self._readings(errors), dtype=float).reshape(m, -1)

    @property
    def n(self) -> int:
        if self._n is None:
            self._n = self.at(None, self.errors(1)).shape[1]
        return self._n


def source_effects(model: SourceModel, names=None) -> tuple[np.ndarray, np.ndarray]:
    """Secant effects of every element of the named (default: every active) sources.

    Each element is set to its value in ``model.zero_errors`` plus and minus one
    standard deviation of its distribution, all others held; half the difference of
    the readings is its effect (exact for an effect linear over +-1 sigma, the best
    linear one otherwise). An element that touches one reading alone adds its square
    to ``D``; one that touches several is a column of ``U``. Sources of many elements
    whose readings each depend on one element (reading noise) cost a few forward rows,
    not two per element (see :mod:`mtplan.fitting.effects`).

    Returns
    -------
    D : array (n,)
        Variance of each reading from the elements that touch it alone.
    U : array (n, k)
        Effects of the elements that touch several readings: ``C = diag(D) + U U^T``.
    """
    if names is None:
        names = [k for k, s in model.sources.items() if np.any(np.asarray(s.distribution.std) > 0)]
    f0 = model.at(None, model.errors(1))[0]
    n = f0.size
    D, cols = np.zeros(n), [np.zeros((n, 0))]
    for name in names:
        eff = effect(model, None, name, np.asarray(model.sources[name].distribution.std,
                                                     dtype=float), f0)
        D = D + eff.diag(n)
        cols.append(eff.S)
    return D, np.hstack(cols)


def readings_covariance(model: SourceModel, names=None, *, floor=None) -> Gaussian:
    """The readings' covariance under the named (default: every active) error sources.

    Parameters
    ----------
    model : SourceModel
    names : iterable of str, optional
    floor : float or array (n,), optional
        A standard deviation added to every reading independently (its unit): a weight
        for readings no source moves, so that ``C`` stays regular.

    Returns
    -------
    Gaussian
        ``C = diag(D) + U U^T`` factored (dense, Cholesky, up to
        :data:`~mtplan.fitting.error_model.DENSE_MAX` readings; above, diagonal plus low rank,
        Woodbury): ``whiten``, ``inverse_times``, ``loglike``.
    """
    D, U = source_effects(model, names)
    if floor is not None:
        D = D + np.broadcast_to(np.asarray(floor, dtype=float) ** 2, D.shape)
    return Gaussian.known(D, U)


def _as_gaussian(covariance, sigma=None) -> Gaussian:
    if isinstance(covariance, Gaussian):
        return covariance
    if isinstance(covariance, ErrorModel):
        return covariance.gaussian(sigma)
    if isinstance(covariance, tuple) and len(covariance) == 2:
        return Gaussian.known(np.asarray(covariance[0], dtype=float),
                              np.asarray(covariance[1], dtype=float))
    cov = np.asarray(covariance, dtype=float)
    if cov.ndim == 1:
        return Gaussian.known(cov, np.zeros((cov.size, 0)))
    if cov.ndim == 2 and cov.shape[0] == cov.shape[1]:
        return Gaussian.dense(cov)
    raise InvalidInput(["The covariance given to the fit must be a Gaussian, a ErrorModel, a pair "
                        "(D, U), variances (n,) or a matrix (n, n). Got an array of shape "
                        f"{cov.shape} instead."])


# --------------------------------------------------------------------------- jacobian, gain
def central_jacobian(predict: Callable, theta, steps, *, low=None, high=None) -> np.ndarray:
    """Jacobian (n, p) of ``predict`` at ``theta`` (p,) by central differences.

    ``predict(rows (m, p)) -> readings (m, n)`` is called once, for the 2 p rows
    ``theta +- steps`` (a step that would cross ``low`` or ``high`` stops there: one-sided
    at a limit).
    """
    theta = np.asarray(theta, dtype=float).reshape(1, -1)
    h = np.diag(np.broadcast_to(np.asarray(steps, dtype=float), theta.shape[1:]))
    up, down = theta + h, theta - h
    if high is not None:
        up = np.minimum(up, high)
    if low is not None:
        down = np.maximum(down, low)
    p = theta.shape[1]
    pred = np.asarray(predict(np.concatenate([up, down])), dtype=float).reshape(2 * p, -1)
    return ((pred[:p] - pred[p:]) / np.diag(up - down)[:, None]).T


def gls_gain(jacobian: np.ndarray, covariance) -> np.ndarray:
    """Gain ``K = (J^T C^-1 J)^-1 J^T C^-1`` (p, n): a step is ``residual @ K.T``.

    Parameters
    ----------
    jacobian : array (n, p)
    covariance : Gaussian, ErrorModel, (D, U), variances (n,) or matrix (n, n)
    """
    g = _as_gaussian(covariance)
    jt = np.asarray(jacobian, dtype=float).T
    jw = g.whiten(jt)
    return np.linalg.solve(jw @ jw.T, g.inverse_times(jt))


# --------------------------------------------------------------------------- gauss-newton
@dataclass
class GaussNewtonResult:
    """A batch's Gauss-Newton fit.

    Attributes
    ----------
    theta : array (m, p)
    residual : array (m, n)
        The residuals at the last evaluation (at ``theta`` when the fit converged, one
        step before otherwise).
    ok : bool array (m,)
        Rows whose residuals could be evaluated at the last iteration.
    converged : bool
        Every ok row's last step was within ``tol``.
    iterations : int
    """

    theta: np.ndarray
    residual: np.ndarray
    ok: np.ndarray
    converged: bool
    iterations: int


def gauss_newton(residuals: Callable, theta, gain, *, iterations: int = 30, tol=0.0,
                 bounds=None, regain: Callable | None = None, regain_after=()) -> GaussNewtonResult:
    """Gauss-Newton for a batch of trials with one gain shared by the batch.

    Every iteration is one call of ``residuals`` for the whole batch and one matrix
    product: ``theta += r @ gain.T``.

    Parameters
    ----------
    residuals : callable
        ``residuals(theta (k, p)) -> (k, n)``: data minus prediction; a row that cannot
        be evaluated is NaN (or the call raises :class:`~mtplan._validate.InvalidInput`:
        every row is then stopped).
    theta : array (m, p)
        Start rows (copied).
    gain : array (p, n)
        From :func:`gls_gain`.
    iterations : int
    tol : float or array (p,)
        The fit has converged when every evaluated row's step is within it.
    bounds : (low, high), optional
        Each step is clipped to them.
    regain : callable, optional
        ``regain(theta of the evaluated rows) -> gain``, called after each iteration
        listed in `regain_after` (0-based).
    """
    theta = np.array(theta, dtype=float, copy=True)
    ok = np.ones(theta.shape[0], dtype=bool)
    r, converged, it = None, False, 0
    for it in range(iterations):
        try:
            r = residuals(theta)
        except InvalidInput:
            r = np.full((theta.shape[0], gain.shape[1]), np.nan)
        ok = np.all(np.isfinite(r), axis=1)
        if not ok.any():
            break
        step = np.zeros_like(theta)
        step[ok] = r[ok] @ gain.T
        new = theta[ok] + step[ok]
        theta[ok] = new if bounds is None else np.clip(new, *bounds)
        if np.all(np.abs(step[ok]) <= tol):
            r, converged = residuals(theta), True
            ok = np.all(np.isfinite(r), axis=1)
            break
        if regain is not None and it in regain_after:
            gain = regain(theta[ok])
    if r is None:
        r = np.full((theta.shape[0], gain.shape[1]), np.nan)
    return GaussNewtonResult(theta, r, ok, converged, it + 1)


def gls_step(jacobian, residual, covariance=None, *, weight=None):
    """One generalised least-squares step for rows with their own Jacobian.

    Solves ``(J^T W J) dx = J^T W r`` for every row, ``W = C^-1``.

    Parameters
    ----------
    jacobian : array (..., n, p)
    residual : array (..., n)
        Data minus prediction.
    covariance : array (..., n, n), optional
        The readings' covariance per row (or shared); factored by Cholesky.
    weight : array (..., n, n), optional
        ``C^-1`` given instead (a shared weight is formed once).

    Returns
    -------
    step : array (..., p)
    inverse : array (..., p, p)
        ``(J^T W J)^-1``: the step's covariance when ``C`` is the readings' covariance.
    """
    jac = np.asarray(jacobian, dtype=float)
    r = np.asarray(residual, dtype=float)[..., None]
    if weight is None:
        cov = np.asarray(covariance, dtype=float)
        wj = np.linalg.solve(cov, jac)
        wr = np.linalg.solve(cov, r)
    else:
        w = np.asarray(weight, dtype=float)
        wj, wr = w @ jac, w @ r
    jt = np.swapaxes(jac, -1, -2)
    inverse = np.linalg.inv(jt @ wj)
    return (inverse @ (jt @ wr))[..., 0], inverse


# --------------------------------------------------------------------------- fit check
class WhitenedResiduals(NamedTuple):
    """Residuals whitened by the readings' covariance.

    Attributes
    ----------
    whitened : array (m, n)
        ``W r`` with ``W^T W = C^-1``: independent, unit-variance under the model.
    chi2 : array (m,)
        ``r^T C^-1 r``, the sum of squares of `whitened`.
    dof : int
        Degrees of freedom: readings less fitted parameters.
    """

    whitened: np.ndarray
    chi2: np.ndarray
    dof: int


def whitened_residuals(residuals, covariance, *, n_params: int = 0,
                       sigma=None) -> WhitenedResiduals:
    """Residuals whitened by the readings' covariance, with chi-square and degrees of freedom.

    The check of a fit: when the readings are Gaussian about the fitted model with
    covariance ``C``, and the model is linear enough over the fit's scatter, ``chi2``
    follows a chi-square distribution with ``dof = n - n_params`` degrees of freedom
    (mean ``dof``, standard deviation ``sqrt(2 dof)``) and every element of
    ``whitened`` is standard normal (no longer independent after the fit: ``n_params``
    directions are used by it). A chi-square far above ``dof`` says the readings
    scatter more than the error budget allows (a source too small, one missing, or
    the model wrong); far below, a budget larger than the readings show.

    Parameters
    ----------
    residuals : array (n,) or (m, n)
        Readings minus the fitted prediction (the same units as the covariance).
    covariance : Gaussian, ErrorModel, (D, U), variances (n,) or matrix (n, n)
        The readings' covariance: a :class:`~mtplan.fitting.error_model.Gaussian` from
        :func:`readings_covariance` or ``ErrorModel.gaussian()``, a
        :class:`~mtplan.fitting.error_model.ErrorModel` (a free noise at `sigma`), a pair
        ``(D, U)`` with ``C = diag(D) + U U^T``, independent variances, or a dense matrix.
    n_params : int
        Parameters the fit determined (the Jacobian's rank).
    sigma : float, optional
        The noise's standard deviation, for a :class:`ErrorModel` whose noise is free.

    Returns
    -------
    WhitenedResiduals
        ``(whitened (m, n), chi2 (m,), dof)``; a single residual vector gives m = 1.
    """
    r = np.atleast_2d(np.asarray(residuals, dtype=float))
    g = _as_gaussian(covariance, sigma)
    if g.free:
        raise InvalidInput(["whitened_residuals needs the noise's standard deviation when the "
                            "error model leaves it free: pass sigma."])
    if r.shape[1] != g.n:
        raise InvalidInput([f"The residuals hold {r.shape[1]} readings but the covariance is "
                            f"of {g.n}."])
    n_params = int(n_params)
    if not 0 <= n_params <= g.n:
        raise InvalidInput([f"The 'n_params' parameter of whitened_residuals must be an int "
                            f"from 0 to the {g.n} readings. Got {n_params} instead."])
    w = g.whiten(r)
    return WhitenedResiduals(w, np.einsum("ij,ij->i", w, w), g.n - n_params)
