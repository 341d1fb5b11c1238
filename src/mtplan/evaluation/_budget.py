"""The readings' error budget of a posterior's likelihood, now in :mod:`mtplan.fitting`.

Kept so that ``from mtplan.evaluation._budget import error_budget`` goes on working;
new code imports from :mod:`mtplan.fitting`.
"""

from mtplan.fitting import DENSE_MAX, MAX_NUISANCE, NONLINEAR, Budget, Gaussian, error_budget

__all__ = ["Budget", "Gaussian", "error_budget", "DENSE_MAX", "NONLINEAR", "MAX_NUISANCE"]
