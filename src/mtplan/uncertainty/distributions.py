"""Probability distributions for input quantities, after JCGM 101:2008 clause 6.4.

Every distribution is a frozen value object with a ``mean``, a ``std`` and a
``draw(rng, shape)`` method that returns an array of shape ``shape + event_shape``
(``event_shape`` is ``()`` for scalar inputs and ``(n,)`` for
:class:`MultivariateNormal`). Draws come only from the ``numpy.random.Generator``
passed in; nothing touches numpy's global random state.

The sampling rules are the ones JCGM 101 prescribes (6.4.2 to 6.4.9): for example
the curvilinear trapezoid draws its half-width first, the trapezoid is the sum of
two rectangular variables, the arcsine is a sine of a uniform phase.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mtplan._validate import Problems, is_real

__all__ = [
    "Distribution",
    "Normal",
    "Rectangular",
    "Triangular",
    "Trapezoidal",
    "CurvilinearTrapezoidal",
    "Arcsine",
    "StudentT",
    "MultivariateNormal",
    "Constant",
    "SHAPES",
    "with_shape",
]


def _shape(shape) -> tuple[int, ...]:
    if shape is None:
        return ()
    if isinstance(shape, int | np.integer):
        return (int(shape),)
    shape = tuple(int(s) for s in shape)
    if any(s < 0 for s in shape):
        raise ValueError(f"The 'shape' parameter of draw must hold ints >= 0. Got {shape} instead.")
    return shape


class Distribution:
    """Base class: a distribution of a scalar (or vector) input quantity."""

    event_shape: tuple[int, ...] = ()
    # Subclasses provide ``mean`` and ``std`` (attributes or properties).

    @property
    def var(self):
        """Variance (the square of :attr:`std`)."""
        return np.square(self.std)

    def draw(self, rng: np.random.Generator, shape=()) -> np.ndarray:
        """Draw values of shape ``shape + event_shape`` from `rng`."""
        if not isinstance(rng, np.random.Generator):
            raise TypeError(
                f"The 'rng' parameter of {type(self).__name__}.draw must be a "
                f"numpy.random.Generator. Got {type(rng).__name__} instead."
            )
        return self._draw(rng, _shape(shape))

    def _draw(self, rng, shape):  # pragma: no cover - abstract
        raise NotImplementedError


class _Bounded(Distribution):
    """Shared checks of distributions on an interval [low, high], symmetric about its middle."""

    def _bounds_problems(self) -> Problems:
        p = Problems(type(self).__name__)
        if p.number("low", self.low) & p.number("high", self.high):
            p.require(self.high >= self.low, "high", self.high, f">= low ({self.low:g})")
        return p

    @property
    def mean(self):
        return (self.low + self.high) / 2


@dataclass(frozen=True)
class Constant(Distribution):
    """A quantity known exactly (no uncertainty)."""

    value: float

    def __post_init__(self):
        p = Problems("Constant")
        p.number("value", self.value)
        p.raise_if_any()

    @property
    def mean(self):
        return float(self.value)

    @property
    def std(self):
        return 0.0

    def _draw(self, rng, shape):
        return np.full(shape, float(self.value))


@dataclass(frozen=True)
class Normal(Distribution):
    """Gaussian N(mean, std^2) (JCGM 101 6.4.7)."""

    mean: float
    std: float

    def __post_init__(self):
        p = Problems("Normal")
        p.number("mean", self.mean)
        p.number("std", self.std, low=0)
        p.raise_if_any()

    def _draw(self, rng, shape):
        out = rng.standard_normal(shape)
        if self.std != 1.0:
            out *= self.std
        if self.mean != 0.0:
            out += self.mean
        return out


@dataclass(frozen=True)
class Rectangular(_Bounded):
    """Uniform on [low, high] (JCGM 101 6.4.2)."""

    low: float
    high: float

    def __post_init__(self):
        p = self._bounds_problems()
        p.raise_if_any()

    @property
    def std(self):
        return (self.high - self.low) / math.sqrt(12)

    def _draw(self, rng, shape):
        return rng.uniform(self.low, self.high, shape)


@dataclass(frozen=True)
class Triangular(Distribution):
    """Triangular on [low, high] with the given mode (symmetric when mode is None; 6.4.5)."""

    low: float
    high: float
    mode: float | None = None

    def __post_init__(self):
        p = Problems("Triangular")
        ok = p.number("low", self.low) & p.number("high", self.high)
        if ok:
            p.require(self.high >= self.low, "high", self.high, f">= low ({self.low:g})")
        if self.mode is not None and p.number("mode", self.mode) and ok:
            p.require(
                self.low <= self.mode <= self.high,
                "mode",
                self.mode,
                f"within [low, high] = [{self.low:g}, {self.high:g}]",
            )
        p.raise_if_any()

    @property
    def _c(self):
        return (self.low + self.high) / 2 if self.mode is None else float(self.mode)

    @property
    def mean(self):
        return (self.low + self.high + self._c) / 3

    @property
    def std(self):
        a, b, c = self.low, self.high, self._c
        return math.sqrt(max(a * a + b * b + c * c - a * b - a * c - b * c, 0.0) / 18)

    def _draw(self, rng, shape):
        if self.high == self.low:
            return np.full(shape, float(self.low))
        if self.mode is None:  # JCGM 101 6.4.5.4: sum of two rectangular variables
            r = rng.random((2, *shape))
            return self.low + (self.high - self.low) / 2 * (r[0] + r[1])
        return rng.triangular(self.low, self._c, self.high, shape)


@dataclass(frozen=True)
class Trapezoidal(_Bounded):
    """Symmetric trapezoid on [low, high]; `beta` is the ratio of top to base width (6.4.4)."""

    low: float
    high: float
    beta: float

    def __post_init__(self):
        p = self._bounds_problems()
        p.number("beta", self.beta, low=0, high=1)
        p.raise_if_any()

    @property
    def std(self):
        return (self.high - self.low) * math.sqrt((1 + self.beta**2) / 24)

    def _draw(self, rng, shape):
        r = rng.random((2, *shape))
        half = (self.high - self.low) / 2
        return self.low + half * ((1 + self.beta) * r[0] + (1 - self.beta) * r[1])


@dataclass(frozen=True)
class CurvilinearTrapezoidal(_Bounded):
    """Rectangular on [low, high] whose limits are each inexact by +-d (6.4.3)."""

    low: float
    high: float
    d: float

    def __post_init__(self):
        p = self._bounds_problems()
        ok = not p
        if p.number("d", self.d, low=0) and ok:
            p.require(
                self.d <= (self.high - self.low) / 2,
                "d",
                self.d,
                f"<= (high - low)/2 = {(self.high - self.low) / 2:g}",
            )
        p.raise_if_any()

    @property
    def std(self):
        return math.sqrt((self.high - self.low) ** 2 / 12 + self.d**2 / 9)

    def _draw(self, rng, shape):
        r = rng.random((2, *shape))
        a_s = (self.low - self.d) + 2 * self.d * r[0]
        b_s = (self.low + self.high) - a_s
        return a_s + (b_s - a_s) * r[1]


@dataclass(frozen=True)
class Arcsine(_Bounded):
    """Arcsine (U-shaped) on [low, high] (6.4.6): a sinusoid at a uniform phase."""

    low: float
    high: float

    def __post_init__(self):
        p = self._bounds_problems()
        p.raise_if_any()

    @property
    def std(self):
        return (self.high - self.low) / math.sqrt(8)

    def _draw(self, rng, shape):
        phase = rng.random(shape)
        return self.mean + (self.high - self.low) / 2 * np.sin(2 * np.pi * phase)


@dataclass(frozen=True)
class StudentT(Distribution):
    """Scaled and shifted t distribution t_dof(loc, scale^2) (6.4.9).

    Its standard deviation is ``scale * sqrt(dof / (dof - 2))``, finite only for dof > 2
    (``inf`` otherwise; the mean is ``nan`` for dof <= 1).
    """

    loc: float
    scale: float
    dof: float

    def __post_init__(self):
        p = Problems("StudentT")
        p.number("loc", self.loc)
        p.number("scale", self.scale, low=0)
        p.number("dof", self.dof, low=0, low_open=True)
        p.raise_if_any()

    @property
    def mean(self):
        return float(self.loc) if self.dof > 1 else math.nan

    @property
    def std(self):
        if self.dof <= 2:
            return math.inf
        return self.scale * math.sqrt(self.dof / (self.dof - 2))

    def _draw(self, rng, shape):
        return self.loc + self.scale * rng.standard_t(self.dof, shape)


@dataclass(frozen=True)
class MultivariateNormal(Distribution):
    """Multivariate Gaussian N(mean, cov) of a vector quantity (6.4.8).

    The covariance must be symmetric positive semidefinite; draws use its Cholesky
    factor, or a symmetric square root when it is singular.
    """

    mu: tuple
    cov: tuple
    _root: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        mean, cov = self.mu, self.cov  # as given: ``MultivariateNormal(mean, cov)``
        p = Problems("MultivariateNormal")
        m = np.asarray(mean, dtype=float) if _is_numeric(mean) else None
        c = np.asarray(cov, dtype=float) if _is_numeric(cov) else None
        if m is None or m.ndim != 1 or m.size == 0 or not np.all(np.isfinite(m)):
            p.add("mean", mean, "a non-empty 1-D array of finite numbers")
            m = None
        if c is None or c.ndim != 2 or c.shape[0] != c.shape[1] or not np.all(np.isfinite(c)):
            p.add("cov", cov, "a square 2-D array of finite numbers")
            c = None
        root = None
        if m is not None and c is not None:
            if c.shape[0] != m.size:
                p.add("cov", cov, f"of shape ({m.size}, {m.size}) to match 'mean'")
            elif not np.allclose(c, c.T, rtol=1e-10, atol=1e-300):
                p.add("cov", cov, "symmetric")
            else:
                try:
                    root = np.linalg.cholesky(c)
                except np.linalg.LinAlgError:
                    w, v = np.linalg.eigh(c)
                    if w.min() < -1e-10 * max(w.max(), 0.0):
                        p.add("cov", cov, "positive semidefinite")
                    else:
                        root = v * np.sqrt(np.clip(w, 0, None))
        p.raise_if_any()
        object.__setattr__(self, "mu", tuple(m.tolist()))
        object.__setattr__(self, "cov", tuple(map(tuple, c.tolist())))
        object.__setattr__(self, "_root", root)

    @property
    def event_shape(self):
        return (len(self.mu),)

    @property
    def mean(self):
        return np.array(self.mu)

    @property
    def covariance(self):
        """Covariance matrix as an array of shape (n, n)."""
        return np.array(self.cov)

    @property
    def std(self):
        return np.sqrt(np.diag(self.covariance))

    def _draw(self, rng, shape):
        z = rng.standard_normal((*shape, len(self.mu)))
        return z @ self._root.T + self.mean


def _is_numeric(x) -> bool:
    try:
        a = np.asarray(x)
    except Exception:  # noqa: BLE001 - anything that is not array-like
        return False
    return a.dtype.kind in "biuf" and a.dtype.kind != "b" or (a.dtype == object and all(map(is_real, a.ravel())))


#: the shapes an input's distribution may be given in place of its own, with the same mean
#: and standard uncertainty (JCGM 101 6.4: normal 6.4.7, rectangular 6.4.2, symmetric
#: triangular 6.4.5, arcsine 6.4.6)
SHAPES = ("normal", "rectangular", "triangular", "arcsine")


def with_shape(dist: Distribution, shape: str) -> Distribution:
    """`dist`'s mean and standard uncertainty with the distribution `shape` (one of
    :data:`SHAPES`): what the GUM, which uses only the two, cannot tell apart and the Monte
    Carlo draws differently (a rectangular of half-width sqrt(3) u, a symmetric triangular
    of sqrt(6) u, an arcsine of sqrt(2) u). A vector input (correlated elements) keeps its
    own."""
    if shape not in SHAPES:
        raise ValueError(f"The 'shape' parameter of with_shape must be one of "
                         f"{', '.join(SHAPES)}. Got {shape!r} instead.")
    if dist.event_shape:
        raise ValueError(f"with_shape takes a scalar input's distribution. Got a "
                         f"{type(dist).__name__} of event shape {dist.event_shape} instead.")
    mean, u = float(dist.mean), float(dist.std)
    half = {"rectangular": math.sqrt(3), "triangular": math.sqrt(6), "arcsine": math.sqrt(2)}
    if shape == "normal":
        return Normal(mean, u)
    low, high = mean - half[shape] * u, mean + half[shape] * u
    return {"rectangular": Rectangular, "triangular": Triangular,
            "arcsine": Arcsine}[shape](low, high)
