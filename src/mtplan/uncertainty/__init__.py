"""The uncertainty engine: distributions, Monte Carlo (JCGM 101), GUM law of propagation.

Imports: at module level, in every module of the package; a function imports a module
itself only where that saves a real cost (scipy, pandas, emcee, tqdm: loaded where a
coverage factor, a table, a sampler or a progress bar is made, never in a Monte Carlo's
workers). ``tests/test_import_policy.py`` keeps it so.
"""

from mtplan.uncertainty.distributions import (
    Arcsine,
    Constant,
    CurvilinearTrapezoidal,
    Distribution,
    MultivariateNormal,
    Normal,
    Rectangular,
    StudentT,
    Trapezoidal,
    Triangular,
)
from mtplan.uncertainty.gum import GUMResult, linearize, validate
from mtplan.uncertainty.montecarlo import MCResult, ModelError, coverage_interval, propagate

__all__ = [
    "Arcsine",
    "Constant",
    "CurvilinearTrapezoidal",
    "Distribution",
    "MultivariateNormal",
    "Normal",
    "Rectangular",
    "StudentT",
    "Trapezoidal",
    "Triangular",
    "MCResult",
    "ModelError",
    "coverage_interval",
    "propagate",
    "linearize",
    "validate",
    "GUMResult",
]
