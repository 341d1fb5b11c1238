"""The fitting machinery every procedure shares: the readings' covariance, GLS, fit checks.

Below the procedures (:mod:`mtplan.models`), above the generic engine
(:mod:`mtplan.uncertainty`); it knows no procedure, only the shape of one (a forward
model from parameters and error sources to readings).

- :mod:`~mtplan.fitting.error_model`: how a posterior's likelihood holds each of a set-up's
  error sources, and the readings' covariance that follows (:func:`error_model`,
  :class:`ErrorModel`, :class:`Gaussian`).
- :mod:`~mtplan.fitting.gls`: the same covariance for a fit (:func:`readings_covariance`,
  :func:`source_effects`, :class:`SourceModel`), the generalised least-squares
  Gauss-Newton fitter over it (:func:`central_jacobian`, :func:`gls_gain`,
  :func:`gauss_newton`, :func:`gls_step`) and the residuals whitened by it
  (:func:`whitened_residuals`).
- :mod:`~mtplan.fitting.effects`: how each element of each error source moves each
  reading (NaN probes, grouped rows, secants and derivatives), and an estimate's
  first-order response by central differences, written once for the error model, the
  fits' covariance and the first-order linearisation.
- :mod:`~mtplan.fitting.linear`: rank-truncated pseudo-inverses with a convention for
  the null space, and which functions of the parameters the readings determine.

Imports: at module level; a function imports a module itself only where that saves a real
cost (scipy, pandas), as in :mod:`mtplan.uncertainty`.
"""

from mtplan.fitting.error_model import (
    DENSE_MAX,
    MAX_NUISANCE,
    NONLINEAR,
    ErrorModel,
    Gaussian,
    error_model,
)
from mtplan.fitting.gls import (
    GaussNewtonResult,
    SourceModel,
    WhitenedResiduals,
    central_jacobian,
    gauss_newton,
    gls_gain,
    gls_step,
    readings_covariance,
    source_effects,
    whitened_residuals,
)

__all__ = [
    "ErrorModel",
    "Gaussian",
    "error_model",
    "DENSE_MAX",
    "NONLINEAR",
    "MAX_NUISANCE",
    "SourceModel",
    "source_effects",
    "readings_covariance",
    "central_jacobian",
    "gls_gain",
    "gauss_newton",
    "GaussNewtonResult",
    "gls_step",
    "whitened_residuals",
    "WhitenedResiduals",
]
