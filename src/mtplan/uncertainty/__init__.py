"""The uncertainty engine: distributions, Monte Carlo (JCGM 101), GUM law of propagation."""

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


def __getattr__(name):
    if name in ("linearize", "validate", "GUMResult"):
        from mtplan.uncertainty import gum

        return getattr(gum, name)
    raise AttributeError(name)
