"""Conformity assessment: decision rules, guard bands and risks (JCGM 106:2012, ISO 14253-1).

A property of an item (a machine tool, a workpiece) has a true value ``x`` that must lie
in the tolerance interval ``[T_L, T_U]`` (either limit may be absent: a one-sided
tolerance). It is measured once; the measured value is modelled as

    y ~ N(x, u^2),

with ``u`` the standard measurement uncertainty (JCGM 106 clause 7, normal measurement
model). The item is *accepted* when ``y`` lies in the acceptance interval
``[A_L, A_U]``, set by a decision rule. Knowledge of the process that produced the items
is the *prior* (JCGM 106 clause 6.1: the distribution of ``x`` before measuring).
Everything is unit agnostic: limits, ``u``, priors and measured values share one unit.

Quantities (JCGM 106 clause 9)
------------------------------
``pfa``
    Global probability of false accept ``P(x outside [T_L, T_U], y in [A_L, A_U])``
    (the consumer's risk).
``pfr``
    Global probability of false reject ``P(x in [T_L, T_U], y outside [A_L, A_U])``
    (the producer's risk).
``conditional_pfa``
    ``pfa / P(y in [A_L, A_U])``: the fraction of *accepted* items that do not conform.
``specific_risk``
    For a measured value ``y``: ``P(x outside [T_L, T_U] | y)``. With a prior this is the
    posterior probability (Bayes); without one it is computed from the normal likelihood
    alone, ``x | y ~ N(y, u^2)`` (JCGM 106 7.4), so that ``y = 9.8, u = 0.1, [9, 10]``
    gives ``1 - Phi(2) = 0.022750``.
``tur``
    Test uncertainty ratio, ``(T_U - T_L) / (2 U)`` with ``U = 2 u`` (expanded uncertainty,
    coverage factor 2): the tolerance half-width over ``U``, the convention of
    ANSI/NCSL Z540.3 and of Dobbert. ``None`` for a one-sided tolerance.
``cm``
    Measurement capability index of JCGM 106 (clause 7.6), ``(T_U - T_L) / (4 u)``.
    With ``U = 2 u`` it equals ``tur`` numerically; both are reported because users know
    one name or the other. ``None`` for a one-sided tolerance.

Decision rules
--------------
All rules place a guard band ``w`` inside each *finite* tolerance limit,
``A_L = T_L + w`` and ``A_U = T_U - w`` (an absent limit stays absent):

``simple``
    ``w = 0``: acceptance limits are the tolerance limits (JCGM 106 8.3.2, "simple
    acceptance"; shared risk).
``guard:R``
    ``w = R * U`` with ``U = 2 u``, ``R >= 0`` (``guard:1`` is ISO 14253-1).
``iso14253``
    ISO 14253-1:2017 default rule for proving conformity: the acceptance zone is the
    specification zone reduced by the expanded uncertainty ``U = k u``, ``k = 2``, at each
    specified limit, i.e. ``w = 2 u``.
``target-pfa:P``
    The guard band (symmetric for a two-sided tolerance, at the single limit for a
    one-sided one) for which the global false-accept probability equals ``P``, found by
    root finding (Brent) on ``pfa(w)``, which decreases monotonically in ``w``. Needs a
    prior. Guard bands are never negative: when simple acceptance already gives
    ``pfa <= P`` the rule returns ``w = 0`` (no relaxed acceptance, which ISO 14253-1
    does not allow for proving conformity).
``dobbert``
    Dobbert's managed guard band (M. Dobbert, "A guard-band strategy for managing
    false-accept risk", NCSL International Measure 3(4), 2008; also "Understanding
    measurement risk", NCSLI Workshop & Symposium 2007):
    ``w = U * M`` with ``M = 1.04 - exp(0.38 ln(TUR) - 0.54)`` and ``U = 2 u``, which keeps
    the global false-accept probability at or below about 2 % whatever the in-tolerance
    probability of a centred normal population. ``M`` turns negative above
    ``TUR ~ 4.6``; here it is clipped at 0 (acceptance limits never outside the
    tolerance limits), as Dobbert suggests for practice. Two-sided tolerances only.

Priors
------
:class:`NormalPrior` (exact: ``(x, y)`` is bivariate normal, rectangle probabilities
from Owen's T function), :class:`GammaPrior` (adaptive quadrature over the prior,
``scipy.integrate.quad``) and :class:`EmpiricalPrior` (a Gaussian kernel density of
measured process values; a mixture of normals, so again exact through Owen's T; with
``bandwidth=0`` the sample itself, a discrete prior).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
from scipy import integrate, optimize, special, stats

from mtplan._validate import InvalidInput, Problems, is_real

__all__ = [
    "NormalPrior",
    "GammaPrior",
    "EmpiricalPrior",
    "DecisionRule",
    "AcceptanceResult",
    "GlobalRisks",
    "parse_prior",
    "parse_rule",
    "tur",
    "cm",
    "guard_band",
    "acceptance_limits",
    "agreed_resolution",
    "global_risks",
    "specific_risk",
    "plan_acceptance",
    "CURVE_GUARDS",
    "risk_curve",
    "zones",
    "judgement",
]

_TAIL = 1e-16  # prior mass neglected beyond the effective support of a quadrature prior
_DOBBERT_PFA = 0.02


# --------------------------------------------------------------------------------------
# normal building blocks
# --------------------------------------------------------------------------------------


def _std_interval(lo, hi):
    """P(lo < Z < hi) for standard normal Z, without cancellation in the upper tail."""
    lo, hi = np.broadcast_arrays(np.asarray(lo, float), np.asarray(hi, float))
    upper = lo > 0
    p = np.where(
        upper,
        special.ndtr(-lo) - special.ndtr(-hi),
        special.ndtr(hi) - special.ndtr(lo),
    )
    return np.clip(np.where(hi > lo, p, 0.0), 0.0, 1.0)


def _bvn_cdf(h, k, r, q):
    """Standard bivariate normal CDF P(X < h, Y < k), corr(X, Y) = r, q = sqrt(1 - r^2).

    Owen (1956): ``Phi2 = Phi(h)/2 + Phi(k)/2 - T(h, a_h) - T(k, a_k) - beta`` with
    ``a_h = (k - r h) / (h q)``, ``a_k = (h - r k) / (k q)``, and ``beta = 1/2`` unless
    ``h k > 0`` or (``h k = 0`` and ``h + k >= 0``). ``q`` is passed separately so that
    it keeps its precision when ``r`` is close to 1.
    """
    h, k, r, q = np.broadcast_arrays(*(np.asarray(v, float) for v in (h, k, r, q)))
    out = np.zeros(h.shape)
    fin = np.isfinite(h) & np.isfinite(k)
    hinf = np.isposinf(h) & ~np.isneginf(k)
    kinf = np.isposinf(k) & ~np.isneginf(h) & ~hinf
    out[hinf] = special.ndtr(k[hinf])
    out[kinf] = special.ndtr(h[kinf])
    if np.any(fin):
        hf, kf, rf, qf = h[fin], k[fin], r[fin], q[fin]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # tiny h: a = +-inf
            ah = np.where(hf != 0, (kf - rf * hf) / (hf * qf), np.copysign(np.inf, kf))
            ak = np.where(kf != 0, (hf - rf * kf) / (kf * qf), np.copysign(np.inf, hf))
        # T(0, a) with a = 0/0 (h = k = 0) is handled by the closed form below.
        both0 = (hf == 0) & (kf == 0)
        ah = np.where(both0, 0.0, ah)
        ak = np.where(both0, 0.0, ak)
        same_sign = ((hf > 0) & (kf > 0)) | ((hf < 0) & (kf < 0))  # not h*k > 0: underflow
        zero = (hf == 0) | (kf == 0)
        beta = np.where(same_sign | (zero & (hf + kf >= 0)), 0.0, 0.5)
        val = (
            0.5 * special.ndtr(hf)
            + 0.5 * special.ndtr(kf)
            - special.owens_t(hf, ah)
            - special.owens_t(kf, ak)
            - beta
        )
        val = np.where(both0, 0.25 + np.arcsin(rf) / (2 * np.pi), val)
        out[fin] = val
    return np.clip(out, 0.0, 1.0)


def _bvn_rect(x_lo, x_hi, y_lo, y_hi, r, q):
    """P(x_lo < X < x_hi, y_lo < Y < y_hi), standard bivariate normal, corr r.

    An axis whose interval lies in the upper half is reflected first, so that the
    inclusion-exclusion works with small lower-tail CDF values (no cancellation).
    """
    x_lo, x_hi, y_lo, y_hi, r, q = np.broadcast_arrays(
        *(np.asarray(v, float) for v in (x_lo, x_hi, y_lo, y_hi, r, q))
    )
    fx = x_lo > 0
    fy = y_lo > 0
    x_lo, x_hi = np.where(fx, -x_hi, x_lo), np.where(fx, -x_lo, x_hi)
    y_lo, y_hi = np.where(fy, -y_hi, y_lo), np.where(fy, -y_lo, y_hi)
    r = np.where(fx != fy, -r, r)
    p = (
        _bvn_cdf(x_hi, y_hi, r, q)
        - _bvn_cdf(x_lo, y_hi, r, q)
        - _bvn_cdf(x_hi, y_lo, r, q)
        + _bvn_cdf(x_lo, y_lo, r, q)
    )
    empty = (x_hi <= x_lo) | (y_hi <= y_lo)
    return np.clip(np.where(empty, 0.0, p), 0.0, 1.0)


def _as_generator(rng) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    from mtplan.uncertainty.streams import as_seed_sequence

    return np.random.default_rng(as_seed_sequence(rng))


# --------------------------------------------------------------------------------------
# priors
# --------------------------------------------------------------------------------------


class _Prior:
    """Common interface of the process distributions (priors of the true value)."""

    def pdf(self, x):  # pragma: no cover - abstract
        raise NotImplementedError

    def cdf(self, x):  # pragma: no cover - abstract
        raise NotImplementedError

    def sample(self, size, rng=None) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def prob_within(self, lo: float, hi: float) -> float:
        """Prior probability that the true value lies in ``[lo, hi]``."""
        raise NotImplementedError  # pragma: no cover

    def joint(self, x_lo, x_hi, y_lo, y_hi, u) -> float:
        """``P(x_lo < x < x_hi, y_lo < y < y_hi)`` with ``y ~ N(x, u^2)``."""
        raise NotImplementedError  # pragma: no cover

    def posterior_within(self, y, lo, hi, u) -> float:
        """``P(lo <= x <= hi | y)``; returns (inside, outside) probabilities."""
        raise NotImplementedError  # pragma: no cover


class _MixturePrior(_Prior):
    """Equal-weight mixture of normals N(means_i, width^2): exact via Owen's T."""

    _means: np.ndarray
    _width: float

    def pdf(self, x):
        """Probability density of the true value at `x` [1/unit]."""
        x = np.asarray(x, float)
        if self._width == 0:
            raise ValueError("A discrete prior (bandwidth 0) has no density.")
        return stats.norm.pdf(x[..., None], self._means, self._width).mean(axis=-1)

    def cdf(self, x):
        """Cumulative distribution function of the true value at `x`."""
        x = np.asarray(x, float)
        if self._width == 0:
            return (self._means <= x[..., None]).mean(axis=-1)
        return special.ndtr((x[..., None] - self._means) / self._width).mean(axis=-1)

    def sample(self, size, rng=None) -> np.ndarray:
        """Draw `size` true values from the prior using `rng` (None, int, SeedSequence or
        Generator)."""
        g = _as_generator(rng)
        idx = g.integers(0, self._means.size, size=size)
        return self._means[idx] + self._width * g.standard_normal(np.shape(idx))

    def prob_within(self, lo, hi):
        lo, hi = _inf(lo, -1), _inf(hi, +1)
        if self._width == 0:
            return float(np.mean((self._means >= lo) & (self._means <= hi)))
        return float(
            np.mean(
                _std_interval((lo - self._means) / self._width, (hi - self._means) / self._width)
            )
        )

    def joint(self, x_lo, x_hi, y_lo, y_hi, u):
        m, s = self._means, self._width
        if s == 0:
            # tolerance side: [lo, hi] conforms; outside below is x < lo, above is x > hi
            if np.isneginf(x_lo):
                inside = m < x_hi
            elif np.isposinf(x_hi):
                inside = m > x_lo
            else:
                inside = (m >= x_lo) & (m <= x_hi)
            p_acc = _std_interval((y_lo - m) / u, (y_hi - m) / u)
            return float(np.mean(np.where(inside, p_acc, 0.0)))
        sy = math.hypot(s, u)
        r, q = s / sy, u / sy
        return float(
            np.mean(
                _bvn_rect((x_lo - m) / s, (x_hi - m) / s, (y_lo - m) / sy, (y_hi - m) / sy, r, q)
            )
        )

    def posterior_within(self, y, lo, hi, u):
        m, s = self._means, self._width
        lo, hi = _inf(lo, -1), _inf(hi, +1)
        sy = math.hypot(s, u)
        logw = -0.5 * ((y - m) / sy) ** 2
        w = np.exp(logw - logw.max())
        w /= w.sum()
        if s == 0:
            inside = (m >= lo) & (m <= hi)
            return float(w[inside].sum()), float(w[~inside].sum())
        ru, rs = u / sy, s / sy  # ratios <= 1: no overflow for a huge u or s
        pm = m * ru * ru + y * rs * rs
        ps = s * ru
        zl, zh = (lo - pm) / ps, (hi - pm) / ps
        inside = float(np.sum(w * _std_interval(zl, zh)))
        outside = float(np.sum(w * (special.ndtr(zl) + special.ndtr(-zh))))
        return inside, outside


def _inf(v, sign):
    return sign * math.inf if v is None else float(v)


@dataclass(frozen=True)
class NormalPrior(_MixturePrior):
    """Normal process distribution ``x ~ N(mean, sd^2)``.

    Parameters
    ----------
    mean : float
        Process mean [unit of the property].
    sd : float
        Process standard deviation, > 0 [unit of the property].
    """

    mean: float
    sd: float

    def __post_init__(self):
        p = Problems("NormalPrior")
        p.number("mean", self.mean)
        p.number("sd", self.sd, low=0, low_open=True)
        p.raise_if_any()

    @property
    def _means(self):
        return np.array([float(self.mean)])

    @property
    def _width(self):
        return float(self.sd)

    @classmethod
    def from_in_tolerance(cls, probability: float, lower: float, upper: float) -> NormalPrior:
        """The centred normal prior with ``P(lower <= x <= upper) = probability``.

        Parameters
        ----------
        probability : float
            In-tolerance probability, in (0, 1).
        lower, upper : float
            Tolerance limits, ``lower < upper`` [unit].
        """
        p = Problems("NormalPrior.from_in_tolerance")
        p.number("probability", probability, low=0, high=1, low_open=True, high_open=True)
        ok = p.number("lower", lower) & p.number("upper", upper)
        if ok:
            p.require(upper > lower, "upper", upper, f"a number > lower = {lower!r}")
        p.raise_if_any()
        half = 0.5 * (upper - lower)
        return cls(0.5 * (upper + lower), half / stats.norm.ppf(0.5 + 0.5 * probability))


@dataclass(frozen=True)
class GammaPrior(_Prior):
    """Gamma process distribution (shape ``k``, scale ``theta``), support ``x >= 0``.

    Suited to properties that cannot be negative (form errors, runout, the JCGM 106
    bearing example). Risks are integrated over the prior by adaptive quadrature.

    Parameters
    ----------
    shape : float
        Shape parameter ``k > 0``.
    scale : float
        Scale parameter ``theta > 0`` [unit of the property]; mean ``k theta``.
    """

    shape: float
    scale: float

    def __post_init__(self):
        p = Problems("GammaPrior")
        p.number("shape", self.shape, low=0, low_open=True)
        p.number("scale", self.scale, low=0, low_open=True)
        p.raise_if_any()

    @cached_property
    def _dist(self):
        return stats.gamma(float(self.shape), scale=float(self.scale))

    @cached_property
    def _lognorm(self):
        return -special.gammaln(self.shape) - self.shape * math.log(self.scale)

    def _logpdf(self, x):
        k, th = float(self.shape), float(self.scale)
        with np.errstate(divide="ignore", invalid="ignore"):
            v = special.xlogy(k - 1.0, x) - x / th + self._lognorm
        return np.where(np.asarray(x) >= 0, v, -np.inf)

    def _pdf_scalar(self, x):
        if x < 0:
            return 0.0
        if x == 0:
            return float(self._dist.pdf(0.0))
        return math.exp((self.shape - 1.0) * math.log(x) - x / self.scale + self._lognorm)

    def pdf(self, x):
        """Probability density at `x` [1/unit]."""
        return self._dist.pdf(x)

    def cdf(self, x):
        """Cumulative distribution function at `x`."""
        return self._dist.cdf(x)

    def sample(self, size, rng=None) -> np.ndarray:
        """Draw `size` true values using `rng` (None, int, SeedSequence or Generator)."""
        return _as_generator(rng).gamma(float(self.shape), float(self.scale), size=size)

    def prob_within(self, lo, hi):
        lo, hi = max(_inf(lo, -1), 0.0), _inf(hi, +1)
        if hi <= lo:
            return 0.0
        d = self._dist
        if lo > d.median():
            return float(d.sf(lo) - d.sf(hi))
        return float(d.cdf(hi) - d.cdf(lo))

    @cached_property
    def _hi(self):
        return float(self._dist.isf(_TAIL))

    def _support(self):
        return 0.0, self._hi

    def _quad(self, f, a, b, points=()):
        lo, hi = self._support()
        a, b = max(a, lo), min(b, hi)
        if not b > a:
            return 0.0
        mode = max(self.shape - 1, 0) * self.scale
        pts = sorted({p for p in (*points, mode) if a < p < b})
        val, _ = integrate.quad(f, a, b, points=pts or None, limit=400, epsabs=1e-15, epsrel=1e-11)
        return float(val)

    def joint(self, x_lo, x_hi, y_lo, y_hi, u):
        if not (y_hi > y_lo and x_hi > x_lo):
            return 0.0
        pdf = self._pdf_scalar

        def f(x):
            lo_z, hi_z = (y_lo - x) / u, (y_hi - x) / u
            if lo_z > 0:
                acc = special.ndtr(-lo_z) - special.ndtr(-hi_z)
            else:
                acc = special.ndtr(hi_z) - special.ndtr(lo_z)
            return pdf(x) * max(acc, 0.0)

        pts = [p for p in (y_lo, y_hi) if np.isfinite(p)]
        return self._quad(f, x_lo, x_hi, pts)

    def posterior_within(self, y, lo, hi, u):
        s_lo, s_hi = self._support()
        a, b = max(s_lo, y - 40 * u), min(s_hi, y + 40 * u)
        if not b > a:
            a, b = s_lo, s_hi
        grid = np.linspace(a, b, 2001)[1:-1]
        with np.errstate(divide="ignore"):
            logf = self._logpdf(grid) - 0.5 * ((y - grid) / u) ** 2
        c = np.max(logf)
        if not np.isfinite(c):
            raise InvalidInput(
                [
                    f"The measured value {y!r} is incompatible with the prior {self!r}: its "
                    "posterior has no mass."
                ]
            )

        pdf = self._pdf_scalar

        def f(x):
            # prior x likelihood, scaled by exp(-c) against under- and overflow
            px = pdf(x)
            return math.exp(math.log(px) - 0.5 * ((y - x) / u) ** 2 - c) if px > 0 else 0.0

        lo, hi = _inf(lo, -1), _inf(hi, +1)
        pts = [y, lo, hi]
        below = self._quad(f, a, min(lo, b), pts)
        inside = self._quad(f, max(lo, a), min(hi, b), pts)
        above = self._quad(f, max(hi, a), b, pts)
        total = below + inside + above
        if not total > 0:
            raise InvalidInput(
                [f"The measured value {y!r} is incompatible with the prior {self!r}."]
            )
        return inside / total, (below + above) / total


@dataclass(frozen=True, eq=False)
class EmpiricalPrior(_MixturePrior):
    """Process distribution estimated from measured process values.

    The prior is the Gaussian kernel density estimate of the values (an equal-weight
    mixture of ``N(value_i, h^2)``), so risks stay exact (bivariate normal per kernel).
    The default bandwidth is Scott's rule ``h = s n^(-1/5)`` (``s`` the sample standard
    deviation), the default of ``scipy.stats.gaussian_kde``; note that the kernel adds
    ``h^2`` to the process variance. ``bandwidth=0`` uses the sample itself (a discrete
    prior with mass ``1/n`` at each value; no density).

    Parameters
    ----------
    values : array_like of shape (n,)
        Measured process values, ``n >= 2``, finite, not all equal [unit].
    bandwidth : {'scott', 'silverman'} or float, optional
        Kernel standard deviation rule, or its value ``>= 0`` [unit].
    """

    values: np.ndarray
    bandwidth: str | float = "scott"
    _h: float = field(init=False, repr=False, default=0.0)

    def __post_init__(self):
        p = Problems("EmpiricalPrior")
        try:
            v = np.asarray(self.values, dtype=float).ravel()
        except (TypeError, ValueError):
            v = None
            p.add("values", self.values, "an array of finite numbers")
        if v is not None:
            if v.size < 2 or not np.all(np.isfinite(v)) or np.ptp(v) == 0:
                p.add("values", v, "at least 2 finite numbers, not all equal")
        bw = self.bandwidth
        if isinstance(bw, str):
            p.choice("bandwidth", bw, ["scott", "silverman"])
        else:
            p.number("bandwidth", bw, low=0)
        p.raise_if_any()
        v = v.copy()
        v.setflags(write=False)
        n = v.size
        sd = float(np.std(v, ddof=1))
        if bw == "scott":
            h = sd * n ** (-0.2)
        elif bw == "silverman":
            h = sd * (0.75 * n) ** (-0.2)
        else:
            h = float(bw)
        object.__setattr__(self, "values", v)
        object.__setattr__(self, "_h", h)

    @property
    def _means(self):
        return self.values

    @property
    def _width(self):
        return self._h

    def __repr__(self):
        return f"EmpiricalPrior(n={self.values.size}, bandwidth={self._h:.6g})"


Prior = NormalPrior | GammaPrior | EmpiricalPrior


# --------------------------------------------------------------------------------------
# parsing
# --------------------------------------------------------------------------------------

_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


def _bad_text(what: str, text, allowed: str) -> InvalidInput:
    return InvalidInput([f"The '{what}' parameter must be {allowed}. Got {text!r} instead."])


def parse_prior(text: str) -> NormalPrior | GammaPrior | EmpiricalPrior:
    """Read a prior from text: ``'normal:MEAN,SD'``, ``'gamma:SHAPE,SCALE'`` or a CSV path.

    A CSV file holds measured process values: one numeric column (with or without a
    header), or a column named ``value``. Empty cells are dropped.

    Raises
    ------
    InvalidInput
        With a one-line message naming the text and what is allowed.
    """
    allowed = "'normal:MEAN,SD', 'gamma:SHAPE,SCALE' or the path of a CSV file of values"
    if not isinstance(text, str) or not text.strip():
        raise _bad_text("prior", text, allowed)
    s = text.strip()
    m = re.fullmatch(rf"(normal|gamma)\s*:\s*({_NUM})\s*,\s*({_NUM})", s, flags=re.I)
    if m:
        kind, a, b = m.group(1).lower(), float(m.group(2)), float(m.group(3))
        try:
            return NormalPrior(a, b) if kind == "normal" else GammaPrior(a, b)
        except InvalidInput as exc:
            raise InvalidInput([f"Bad prior {text!r}: " + " ".join(exc.problems)]) from None
    if re.match(r"(normal|gamma)\s*:", s, flags=re.I):
        raise _bad_text("prior", text, allowed)
    path = Path(s)
    if not path.is_file():
        raise _bad_text("prior", text, allowed + " (no such file)")
    return prior_from_csv(path)


def prior_from_csv(path: Path) -> EmpiricalPrior:
    """Values of a prior CSV; a cell that is not a finite number is refused, naming its row
    (as a spreadsheet shows it); empty cells are dropped."""
    import math

    import pandas as pd

    try:  # every cell as text: NaN, inf and words are refused below, not read as missing
        df = pd.read_csv(path, dtype=str, keep_default_na=False, header=None,
                         skip_blank_lines=False)
    except Exception as exc:  # noqa: BLE001 - any reader failure is bad user input
        raise InvalidInput([f"Cannot read prior CSV file '{path}': {exc}".replace("\n", " ")])
    header = [str(c).strip().lower() for c in df.iloc[0]] if len(df) else []

    def number(text):
        try:
            return float(text)
        except ValueError:
            return None

    has_header = bool(header) and any(number(h) is None and h for h in header)
    if "value" in header:
        j = header.index("value")
    elif df.shape[1] == 1:
        j = 0
    else:
        raise InvalidInput(
            [
                f"The prior CSV file '{path}' must have one numeric column or a column named "
                f"'value'. Got columns {header} instead."
            ]
        )
    values = []
    for row, cell in enumerate(df.iloc[:, j].str.strip(), start=1):
        if (row == 1 and has_header) or cell == "":
            continue
        v = number(cell)
        if v is None or not math.isfinite(v):
            raise InvalidInput(
                [f"The prior CSV file '{path}' must hold finite numbers; row {row} holds "
                 f"{cell[:40]!r}."]
            )
        values.append(v)
    try:
        return EmpiricalPrior(np.asarray(values, dtype=float))
    except InvalidInput as exc:
        raise InvalidInput([f"Bad prior CSV file '{path}': " + " ".join(exc.problems)]) from None


@dataclass(frozen=True)
class DecisionRule:
    """A decision rule: ``kind`` in {'simple', 'guard', 'target-pfa', 'iso14253', 'dobbert'}
    and its parameter (``R`` for 'guard', ``P`` for 'target-pfa', else None)."""

    kind: str
    value: float | None = None

    _KINDS = ("simple", "guard", "target-pfa", "iso14253", "dobbert")

    def __post_init__(self):
        p = Problems("DecisionRule")
        if p.choice("kind", self.kind, self._KINDS):
            if self.kind == "guard":
                p.number("value", self.value, low=0)
            elif self.kind == "target-pfa":
                p.number("value", self.value, low=0, high=1, low_open=True, high_open=True)
            elif self.value is not None:
                p.add("value", self.value, f"None for the rule '{self.kind}'")
        p.raise_if_any()

    def __str__(self):
        return self.kind if self.value is None else f"{self.kind}:{self.value:g}"


def parse_rule(text: str) -> DecisionRule:
    """Read a decision rule: ``'simple'``, ``'guard:R'``, ``'target-pfa:P'``,
    ``'iso14253'`` or ``'dobbert'`` (``R >= 0``; ``0 < P < 1``).

    Raises
    ------
    InvalidInput
        With a one-line message naming the text and what is allowed.
    """
    allowed = (
        "one of 'simple', 'guard:R' (R >= 0), 'target-pfa:P' (0 < P < 1), 'iso14253', "
        "'dobbert'"
    )
    if not isinstance(text, str):
        raise _bad_text("rule", text, allowed)
    s = text.strip().lower()
    if s in ("simple", "iso14253", "dobbert"):
        return DecisionRule(s)
    m = re.fullmatch(rf"(guard|target-pfa)\s*:\s*({_NUM})", s)
    if m:
        try:
            return DecisionRule(m.group(1), float(m.group(2)))
        except InvalidInput:
            raise _bad_text("rule", text, allowed) from None
    raise _bad_text("rule", text, allowed)


# --------------------------------------------------------------------------------------
# input checking
# --------------------------------------------------------------------------------------


def _check(owner, lower, upper, u, prior=None, measured=None, *, need_prior=False):
    p = Problems(owner)
    lo_ok = lower is None or p.number("lower", lower)
    up_ok = upper is None or p.number("upper", upper)
    p.number("u", u, low=0, low_open=True)
    if lower is None and upper is None:
        p.add_text(
            f"At least one of 'lower' and 'upper' of {owner} must be a number. Got None for both"
        )
    elif lower is not None and upper is not None and lo_ok and up_ok and not upper > lower:
        p.add("upper", upper, f"a number > lower = {lower!r}")
    if prior is not None and not isinstance(prior, NormalPrior | GammaPrior | EmpiricalPrior):
        p.add("prior", prior, "None, a NormalPrior, GammaPrior, EmpiricalPrior or prior text")
    if need_prior and prior is None:
        p.add("prior", prior, "a prior (process distribution) for global risks")
    if measured is not None:
        p.number("measured", measured)
    p.raise_if_any()
    return (
        -math.inf if lower is None else float(lower),
        math.inf if upper is None else float(upper),
        float(u),
    )


def _as_prior(prior):
    return parse_prior(prior) if isinstance(prior, str) else prior


def _as_rule(rule):
    if isinstance(rule, DecisionRule):
        return rule
    return parse_rule(rule)


# --------------------------------------------------------------------------------------
# computations
# --------------------------------------------------------------------------------------


def tur(lower: float | None, upper: float | None, u: float) -> float | None:
    """Test uncertainty ratio ``(T_U - T_L) / (2 U)`` with ``U = 2 u``.

    Returns None for a one-sided tolerance (no width).
    """
    lo, hi, u = _check("tur", lower, upper, u)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return None
    return (hi - lo) / (4.0 * u)


def cm(lower: float | None, upper: float | None, u: float) -> float | None:
    """JCGM 106 measurement capability index ``C_m = (T_U - T_L) / (4 u)``.

    Returns None for a one-sided tolerance.
    """
    lo, hi, u = _check("cm", lower, upper, u)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return None
    return (hi - lo) / (4.0 * u)


@dataclass(frozen=True)
class GlobalRisks:
    """Global risks of an acceptance interval for a prior (JCGM 106 clause 9.5).

    Attributes
    ----------
    pfa, pfr : float
        Probabilities of false accept and false reject.
    p_accept : float
        ``P(y in acceptance interval)``.
    p_conform : float
        Prior probability of conformity ``P(x in tolerance interval)``.
    """

    pfa: float
    pfr: float
    p_accept: float
    p_conform: float

    @property
    def conditional_pfa(self) -> float | None:
        """``pfa / p_accept`` (None when nothing is accepted)."""
        return self.pfa / self.p_accept if self.p_accept > 0 else None


def _risks(lo, hi, a_lo, a_hi, u, prior) -> GlobalRisks:
    if not a_hi > a_lo:
        p_conf = prior.prob_within(lo, hi)
        return GlobalRisks(0.0, p_conf, 0.0, p_conf)
    inf = math.inf
    pfa = prior.joint(-inf, lo, a_lo, a_hi, u) + prior.joint(hi, inf, a_lo, a_hi, u)
    pfr = prior.joint(lo, hi, -inf, a_lo, u) + prior.joint(lo, hi, a_hi, inf, u)
    p_conf = prior.prob_within(lo, hi)
    p_acc = pfa + (p_conf - pfr)
    return GlobalRisks(
        float(min(max(pfa, 0.0), 1.0)),
        float(min(max(pfr, 0.0), 1.0)),
        float(min(max(p_acc, 0.0), 1.0)),
        float(p_conf),
    )


def global_risks(
    lower: float | None,
    upper: float | None,
    u: float,
    prior,
    *,
    acceptance: tuple[float | None, float | None] | None = None,
) -> GlobalRisks:
    """Global false-accept and false-reject probabilities (JCGM 106 9.5).

    Parameters
    ----------
    lower, upper : float or None
        Tolerance limits ``T_L < T_U`` [unit]; None for an absent limit.
    u : float
        Standard measurement uncertainty, > 0 [unit].
    prior : NormalPrior, GammaPrior, EmpiricalPrior or str
        Process distribution of the true value (text as for :func:`parse_prior`).
    acceptance : (float or None, float or None), optional
        Acceptance limits ``(A_L, A_U)``; default the tolerance limits (simple acceptance).

    Returns
    -------
    GlobalRisks
    """
    prior = _as_prior(prior)
    lo, hi, u = _check("global_risks", lower, upper, u, prior, need_prior=True)
    if acceptance is None:
        a_lo, a_hi = lo, hi
    else:
        p = Problems("global_risks")
        ok = isinstance(acceptance, tuple | list) and len(acceptance) == 2
        ok = ok and all(a is None or (is_real(a) and not math.isnan(a)) for a in acceptance)
        p.require(ok, "acceptance", acceptance, "a pair (A_L, A_U) of numbers or None")
        p.raise_if_any()
        a_lo, a_hi = _inf(acceptance[0], -1), _inf(acceptance[1], +1)
    return _risks(lo, hi, a_lo, a_hi, u, prior)


def specific_risk(
    measured: float, lower: float | None, upper: float | None, u: float, *, prior=None
) -> float:
    """Specific false-accept risk ``P(x outside [T_L, T_U] | y)`` of a measured value.

    Without a prior, ``x | y ~ N(y, u^2)`` (JCGM 106 7.4, normal likelihood only); with a
    prior, the posterior ``p(x | y) ~ prior(x) N(y; x, u^2)``.

    Parameters
    ----------
    measured : float
        Measured value ``y`` [unit].
    lower, upper : float or None
        Tolerance limits [unit]; None for an absent limit.
    u : float
        Standard measurement uncertainty, > 0 [unit].
    prior : prior or str, optional
        Process distribution of the true value.

    Returns
    -------
    float
        Probability in [0, 1]; one minus the conformance probability ``p_c``.
    """
    prior = _as_prior(prior)
    lo, hi, u = _check("specific_risk", lower, upper, u, prior, measured)
    if measured is None:
        raise InvalidInput(
            ["The 'measured' parameter of specific_risk must be a finite number. Got None instead."]
        )
    return _specific(float(measured), lo, hi, u, prior)


def _specific(y, lo, hi, u, prior) -> float:
    if prior is None:
        return float(special.ndtr((lo - y) / u) + special.ndtr((y - hi) / u))
    _, outside = prior.posterior_within(y, lo, hi, u)
    return float(min(max(outside, 0.0), 1.0))


def _dobbert_multiplier(t: float) -> float:
    return 1.04 - math.exp(0.38 * math.log(t) - 0.54)


def agreed_resolution(u: float, trials: int | None = None) -> float:
    """The step an agreed U, guard band and acceptance limits are stated to [unit]: the
    decimal of the second significant digit of U = 2u (GUM 7.2.6), or of the first where
    a Monte Carlo of `trials` trials does not support the second (its standard error of U,
    2u / sqrt(2 (N - 1)), over a tenth of that digit's ten)."""
    big_u = 2.0 * u
    se = big_u / math.sqrt(2 * (trials - 1)) if trials and trials > 1 else 0.0
    return 10.0 ** (math.floor(math.log10(max(big_u, 10 * se))) - 1)


def _round_up(w: float, step: float) -> float:
    """`w` rounded up to a multiple of the decimal `step` (float noise of w's own last
    digits aside), as a float that prints as that decimal."""
    decimals = max(0, -math.floor(math.log10(step) + 1e-9))
    return round(math.ceil(w / step - 1e-9) * step, decimals)


def _limits(lo, hi, w):
    return (lo + w if np.isfinite(lo) else lo), (hi - w if np.isfinite(hi) else hi)


def guard_band(rule, lower: float | None, upper: float | None, u: float, *, prior=None) -> float:
    """The guard band ``w`` of a decision rule (see the module notes) [unit].

    Parameters
    ----------
    rule : DecisionRule or str
        'simple', 'guard:R', 'target-pfa:P', 'iso14253' or 'dobbert'.
    lower, upper : float or None
        Tolerance limits [unit].
    u : float
        Standard measurement uncertainty, > 0 [unit].
    prior : prior or str, optional
        Needed for 'target-pfa'.

    Returns
    -------
    float
        Guard band ``w >= 0``; the acceptance limits are ``T_L + w`` and ``T_U - w``.
    """
    rule = _as_rule(rule)
    prior = _as_prior(prior)
    lo, hi, u = _check("guard_band", lower, upper, u, prior, need_prior=rule.kind == "target-pfa")
    return _guard(rule, lo, hi, u, prior)


def _guard(rule, lo, hi, u, prior) -> float:
    big_u = 2.0 * u
    two_sided = np.isfinite(lo) and np.isfinite(hi)
    if rule.kind == "simple":
        return 0.0
    if rule.kind == "guard":
        w = rule.value * big_u
    elif rule.kind == "iso14253":
        w = big_u
    elif rule.kind == "dobbert":
        if not two_sided:
            raise InvalidInput(
                ["The rule 'dobbert' needs a two-sided tolerance (both 'lower' and 'upper'): "
                 "its guard band depends on the TUR."]
            )
        w = big_u * max(_dobbert_multiplier((hi - lo) / (2 * big_u)), 0.0)
    else:  # target-pfa
        return _target_pfa(rule.value, lo, hi, u, prior)
    _check_zone(rule, w, lo, hi, u)
    return float(w)


def _check_zone(rule, w, lo, hi, u) -> None:
    """Refuse a guard band that leaves no acceptance interval inside a two-sided tolerance."""
    if np.isfinite(lo) and np.isfinite(hi) and not w < 0.5 * (hi - lo):
        raise InvalidInput(
            [
                f"The rule '{rule}' gives a guard band {w:.6g} that leaves no acceptance "
                f"interval inside the tolerance [{lo:.6g}, {hi:.6g}] (u = {u:.4g}); allowed "
                f"is a guard band < {0.5 * (hi - lo):.6g}."
            ]
        )


def _target_pfa(target, lo, hi, u, prior) -> float:
    def pfa(w):
        a_lo, a_hi = _limits(lo, hi, w)
        return _risks(lo, hi, a_lo, a_hi, u, prior).pfa

    f0 = pfa(0.0) - target
    if f0 <= 0:
        return 0.0
    if np.isfinite(lo) and np.isfinite(hi):
        w_hi = 0.5 * (hi - lo)  # empty acceptance interval: pfa = 0
    else:
        w_hi = 8.0 * u
        for _ in range(80):
            if pfa(w_hi) < target:
                break
            w_hi *= 2.0
        else:  # pragma: no cover - pfa tends to 0 as the limit moves away
            raise InvalidInput(
                [f"No guard band reaches the target false-accept probability {target!r}."]
            )
    xtol = 1e-13 * max(w_hi, u)
    return float(optimize.brentq(lambda w: pfa(w) - target, 0.0, w_hi, xtol=xtol, rtol=1e-14))


def acceptance_limits(
    rule, lower: float | None, upper: float | None, u: float, *, prior=None
) -> tuple[float | None, float | None]:
    """Acceptance limits ``(A_L, A_U)`` of a decision rule (None where the tolerance has no
    limit) [unit]."""
    w = guard_band(rule, lower, upper, u, prior=prior)
    a_lo, a_hi = _limits(_inf(lower, -1), _inf(upper, +1), w)
    return (None if lower is None else a_lo), (None if upper is None else a_hi)


@dataclass(frozen=True)
class AcceptanceResult:
    """The acceptance plan: limits, risks and capability (see the module notes).

    Attributes
    ----------
    acceptance_limits : (float or None, float or None)
        ``(A_L, A_U)`` [unit]; None where the tolerance has no limit.
    specific_risk : float or None
        ``P(x outside tolerance | measured)``; None without a measured value.
    pfa, pfr, conditional_pfa : float or None
        Global risks; None without a prior.
    tur, cm : float or None
        Test uncertainty ratio and capability index; None for a one-sided tolerance.
    p_conform : float or None
        Conformance probability ``p_c = 1 - specific_risk`` of the measured value.
    rule : str
        The decision rule, as text.
    guard_band : float
        ``w`` [unit].
    p_conform_prior : float or None
        Prior probability that an item conforms.
    p_accept : float or None
        Prior probability that an item is accepted.
    decision : {'accept', 'reject'} or None
        For the measured value.
    """

    acceptance_limits: tuple[float | None, float | None]
    specific_risk: float | None
    pfa: float | None
    pfr: float | None
    conditional_pfa: float | None
    tur: float | None
    cm: float | None
    p_conform: float | None
    rule: str
    guard_band: float
    lower: float | None = None
    upper: float | None = None
    u: float | None = None
    measured: float | None = None
    p_conform_prior: float | None = None
    p_accept: float | None = None
    decision: str | None = None

    def to_dict(self) -> dict:
        """JSON-ready dict with keys acceptance_limits, specific_risk, pfa, pfr,
        conditional_pfa, tur, cm (None becomes JSON null)."""
        return {
            "acceptance_limits": list(self.acceptance_limits),
            "specific_risk": self.specific_risk,
            "pfa": self.pfa,
            "pfr": self.pfr,
            "conditional_pfa": self.conditional_pfa,
            "tur": self.tur,
            "cm": self.cm,
        }


def plan_acceptance(
    lower: float | None,
    upper: float | None,
    u: float,
    *,
    prior=None,
    rule="simple",
    measured: float | None = None,
    resolution: float | None = None,
) -> AcceptanceResult:
    """Plan an acceptance decision after JCGM 106 / ISO 14253-1.

    Parameters
    ----------
    lower, upper : float or None
        Tolerance limits ``T_L < T_U`` [unit]; None for a one-sided tolerance.
    u : float
        Standard measurement uncertainty, > 0 [unit].
    prior : NormalPrior, GammaPrior, EmpiricalPrior or str, optional
        Process distribution of the true value (text as for :func:`parse_prior`). Without
        one, the global risks are None and the specific risk uses the likelihood only.
    rule : DecisionRule or str, optional
        Decision rule (text as for :func:`parse_rule`), default 'simple'.
    measured : float, optional
        A measured value ``y`` [unit], for its specific risk and decision.
    resolution : float, optional
        The step [unit] an agreed guard band is stated to (:func:`agreed_resolution`): ``w``
        is rounded up to a multiple of it, so the acceptance zone is never wider than the
        rule's, the limits a plan prints are the limits decided with, and the risks are
        those of the rounded ``w``. Default: ``w`` as the rule gives it.

    Returns
    -------
    AcceptanceResult

    Examples
    --------
    >>> r = plan_acceptance(9, 10, 0.1, prior=NormalPrior(9.5, 0.3))
    >>> round(r.pfa, 7), round(r.pfr, 7)
    (0.0189422, 0.0372078)
    """
    prior = _as_prior(prior)
    rule = _as_rule(rule)
    lo, hi, u = _check(
        "plan_acceptance", lower, upper, u, prior, measured, need_prior=False
    )
    if rule.kind == "target-pfa" and prior is None:
        raise InvalidInput(
            ["The rule 'target-pfa' of plan_acceptance needs a 'prior' (process distribution). "
             "Got None instead."]
        )
    w = _guard(rule, lo, hi, u, prior)
    if resolution is not None and w > 0:
        w = _round_up(w, resolution)
        _check_zone(rule, w, lo, hi, u)
    a_lo, a_hi = _limits(lo, hi, w)
    limits = (None if lower is None else float(a_lo), None if upper is None else float(a_hi))
    two = np.isfinite(lo) and np.isfinite(hi)
    t = (hi - lo) / (4.0 * u) if two else None
    risks = _risks(lo, hi, a_lo, a_hi, u, prior) if prior is not None else None
    sr = pc = decision = None
    if measured is not None:
        y = float(measured)
        sr = _specific(y, lo, hi, u, prior)
        pc = 1.0 - sr
        decision = "accept" if a_lo <= y <= a_hi else "reject"
    return AcceptanceResult(
        acceptance_limits=limits,
        specific_risk=sr,
        pfa=None if risks is None else risks.pfa,
        pfr=None if risks is None else risks.pfr,
        conditional_pfa=None if risks is None else risks.conditional_pfa,
        tur=t,
        cm=t,
        p_conform=pc,
        rule=str(rule),
        guard_band=float(w),
        lower=None if lower is None else float(lower),
        upper=None if upper is None else float(upper),
        u=u,
        measured=None if measured is None else float(measured),
        p_conform_prior=None if risks is None else risks.p_conform,
        p_accept=None if risks is None else risks.p_accept,
        decision=decision,
    )


# --------------------------------------------------------------------------------------
# what a plan is shown with: its risk curve, its zones and a judgement in words
# --------------------------------------------------------------------------------------

#: guard bands of a risk curve [multiples of U = 2 u]: 0 to 1.5 U
CURVE_GUARDS = tuple(0.125 * i for i in range(13))


def risk_curve(lower: float | None, upper: float | None, u: float, prior, *,
               guards=CURVE_GUARDS) -> dict:
    """PFA and PFR against the guard band (JCGM 106 9.5): for each R of `guards` the risks
    of the guard band ``w = R U`` (``U = 2 u``) placed inside each *finite* limit, as the
    rule ``guard:R`` places it, so a one-sided tolerance has its curve too. A two-sided
    curve stops where no acceptance interval is left.

    Returns
    -------
    dict with ``guard_band`` [unit], ``pfa`` and ``pfr``, lists of one length.
    """
    prior = _as_prior(prior)
    lo, hi, u = _check("risk_curve", lower, upper, u, prior, need_prior=True)
    out = {"guard_band": [], "pfa": [], "pfr": []}
    for r in guards:
        w = float(r) * 2.0 * u
        if np.isfinite(lo) and np.isfinite(hi) and not w < 0.5 * (hi - lo):
            break
        a_lo, a_hi = _limits(lo, hi, w)
        risks = _risks(lo, hi, a_lo, a_hi, u, prior)
        out["guard_band"].append(w)
        out["pfa"].append(risks.pfa)
        out["pfr"].append(risks.pfr)
    return out


def zones(result: AcceptanceResult) -> dict:
    """The zones of ISO 14253-1 on the measured value's axis [unit], None where a zone is
    unbounded: the specification zone (``tolerance``), the conformance zone
    (``acceptance``), the non-conformance zones (``reject``: one beyond each specified
    limit, none on the side a one-sided tolerance leaves open), the uncertainty range
    ``[T - U, T + U]`` about each specified limit (``uncertainty``), and ``view``, a finite
    range that shows them all (a quarter of the tolerance beyond two limits; from 6 U
    inside a single limit to 2 U beyond it)."""
    lower, upper, big_u = result.lower, result.upper, 2.0 * result.u
    a_lo, a_hi = result.acceptance_limits
    reject = ([[None, a_lo]] if lower is not None else []) + \
        ([[a_hi, None]] if upper is not None else [])
    if lower is not None and upper is not None:
        span = upper - lower
        view = [lower - 0.25 * span, upper + 0.25 * span]
    elif upper is not None:
        view = [upper - 6.0 * big_u, upper + 2.0 * big_u]
    else:
        view = [lower - 2.0 * big_u, lower + 6.0 * big_u]
    return {"tolerance": [lower, upper], "acceptance": [a_lo, a_hi], "reject": reject,
            "uncertainty": [[t - big_u, t + big_u] for t in (lower, upper) if t is not None],
            "view": view}


def _share_words(p: float) -> str:
    """A share as an engineer says it."""
    if p < 0.001:
        return "almost none"
    if p > 0.85:
        return "nearly all"
    if p > 0.6:
        return "most"
    if p >= 0.4:
        return "about half"
    if p >= 0.3:
        return "about a third"
    if p >= 0.2:
        return "about a quarter"
    return f"about 1 in {round(1 / p)}"


def judgement(result: AcceptanceResult, *, items: str = "items") -> dict:
    """How well a plan decides, in plain words: one judgement for the designer's verdict,
    ``mtplan accept`` and the reports.

    - *cannot be decided well*: a two-sided TUR under 2, a fifth or more of the good
      (conforming) `items` rejected (PFR over the prior's conforming share), or 5 % or more of the
      accepted ones out of tolerance (the conditional PFA);
    - *is decided well*: a TUR of 4 or more where there is one (a one-sided tolerance has
      none, JCGM 106 defines C_m for an interval), a prior, and both shares under 1 %;
    - else *is decided, at the risks stated*; a one-sided tolerance without a prior is
      *not judged* (neither a TUR nor risks).

    Returns
    -------
    dict with ``quality`` (one of the phrases above), ``risks`` (the shares that matter,
    in words) and ``text`` (both, as one line without the measurand's name).
    """
    r = result
    good = r.pfr / r.p_conform_prior if r.pfr is not None and r.p_conform_prior else None
    bad = r.conditional_pfa
    risks = []
    if good is not None and r.pfr >= 0.01:
        risks.append(f"PFR {100 * r.pfr:.4g} %: {_share_words(good)} of the good {items} "
                     "would be rejected")
    if bad is not None and bad >= 0.01:
        risks.append(f"PFA {100 * r.pfa:.4g} %: {_share_words(bad)} of the accepted {items} "
                     "would be out of tolerance")
    tur_text = f"TUR {r.tur:.3g}" if r.tur is not None else "one-sided: no TUR"
    if r.tur is None and r.pfa is None:
        quality = "is not judged"
        risks.append("enter a population (prior) for its risks")
    else:
        if r.pfa is None:
            risks.append("enter a population (prior) for its PFA and PFR")
        poor = (r.tur is not None and r.tur < 2) or (good is not None and good >= 0.2) or \
            (bad is not None and bad >= 0.05)
        well = r.pfa is not None and (r.tur is None or r.tur >= 4) and not risks
        quality = ("cannot be decided well" if poor else "is decided well" if well
                   else "is decided, at the risks stated")
        if r.tur is None and not risks:
            risks.append(f"PFA {100 * r.pfa:.2g} %, PFR {100 * r.pfr:.2g} %")
    return {"quality": quality, "risks": risks,
            "text": f"{quality} ({'; '.join([tur_text, *risks])})"}
