"""Distributions after JCGM 101 6.4: moments, sampling rules and argument checking.

Statistical tolerances follow DESIGN.md: a sample mean of N draws is checked to
4 std/sqrt(N), a sample standard deviation to 4/sqrt(2(N-1)) relative (the normal-
theory standard error; every distribution used here has kurtosis <= 4, for which
the true error is at most ~1.2 times that); seeds are fixed.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, stats

from mtplan._validate import InvalidInput
from mtplan.uncertainty import (
    Arcsine,
    Constant,
    CurvilinearTrapezoidal,
    MultivariateNormal,
    Normal,
    Rectangular,
    StudentT,
    Trapezoidal,
    Triangular,
)

N = 200_000


def _curvilinear_var(a, b, d):
    """Variance of the curvilinear trapezoid by quadrature of its construction (6.4.3):
    half-width W ~ R(h - d, h + d) and X | W ~ R(c - W, c + W), so Var = E[W^2] / 3."""
    h = (b - a) / 2
    ew2 = integrate.quad(lambda w: w * w / (2 * d), h - d, h + d)[0] if d > 0 else h * h
    return ew2 / 3


# (distribution, scipy counterpart or None, exact variance)
CASES = {
    "normal": (Normal(1.5, 0.3), stats.norm(1.5, 0.3)),
    "rectangular": (Rectangular(-2.0, 5.0), stats.uniform(-2.0, 7.0)),
    "triangular_symmetric": (Triangular(-1.0, 3.0), stats.triang(0.5, loc=-1.0, scale=4.0)),
    "triangular_skew": (Triangular(0.0, 4.0, mode=1.0), stats.triang(0.25, loc=0.0, scale=4.0)),
    "trapezoidal": (Trapezoidal(-1.0, 1.0, 0.4), stats.trapezoid(0.3, 0.7, loc=-1.0, scale=2.0)),
    "arcsine": (Arcsine(2.0, 6.0), stats.arcsine(loc=2.0, scale=4.0)),
    "student_t": (StudentT(10.0, 2.0, 10), stats.t(10, loc=10.0, scale=2.0)),
    "curvilinear": (CurvilinearTrapezoidal(-0.05, 0.05, 0.025), None),
}


@pytest.mark.parametrize("name", CASES)
def test_mean_and_std_against_theory(name):
    dist, ref = CASES[name]
    if ref is None:  # curvilinear trapezoid: no scipy counterpart
        assert dist.mean == pytest.approx(0.0, abs=1e-15)
        assert dist.std == pytest.approx(math.sqrt(_curvilinear_var(-0.05, 0.05, 0.025)), rel=1e-10)
    else:
        assert dist.mean == pytest.approx(ref.mean(), rel=1e-12, abs=1e-12)
        assert dist.std == pytest.approx(ref.std(), rel=1e-12)


@pytest.mark.parametrize("name", CASES)
def test_sample_moments(name):
    dist, _ = CASES[name]
    x = dist.draw(np.random.default_rng(12345), N)
    assert x.shape == (N,)
    assert abs(x.mean() - dist.mean) <= 4 * dist.std / math.sqrt(N)
    assert abs(x.std(ddof=1) / dist.std - 1) <= 4 / math.sqrt(2 * (N - 1))


@pytest.mark.parametrize("name", [n for n in CASES if CASES[n][1] is not None])
def test_draws_follow_the_distribution(name):
    """Kolmogorov-Smirnov against scipy's CDF (fixed seed)."""
    dist, ref = CASES[name]
    x = dist.draw(np.random.default_rng(7), 50_000)
    assert stats.kstest(x, ref.cdf).pvalue > 1e-3


def test_curvilinear_trapezoid_cdf():
    """The curvilinear trapezoid's CDF (mixture of rectangles over the half-width) by quadrature."""
    a, b, d = -1.0, 1.0, 0.3
    dist = CurvilinearTrapezoidal(a, b, d)

    def cdf(x):
        def given_w(w):
            return np.clip((x + w) / (2 * w), 0.0, 1.0) / (2 * d)
        return integrate.quad(given_w, 1 - d, 1 + d)[0]

    grid = np.linspace(a - d, b + d, 2001)
    table = np.array([cdf(g) for g in grid])  # smooth CDF: interpolate a fine table
    x = dist.draw(np.random.default_rng(3), 50_000)
    assert stats.kstest(x, lambda v: np.interp(v, grid, table)).pvalue > 1e-3
    assert x.min() >= a - d and x.max() <= b + d


# ----------------------------------------------------------------- JCGM 101 sampling rules
def test_rectangular_rule():
    """6.4.2.4: xi = a + (b - a) r, r uniform on [0, 1]."""
    x = Rectangular(2.0, 3.0).draw(np.random.default_rng(1), 1000)
    r = np.random.default_rng(1).uniform(2.0, 3.0, 1000)
    np.testing.assert_array_equal(x, r)


def test_trapezoidal_rule():
    """6.4.4.4: xi = a + (b - a)/2 [(1 + beta) r1 + (1 - beta) r2]."""
    a, b, beta = -1.0, 3.0, 0.25
    x = Trapezoidal(a, b, beta).draw(np.random.default_rng(2), 1000)
    r = np.random.default_rng(2).random((2, 1000))
    np.testing.assert_allclose(x, a + (b - a) / 2 * ((1 + beta) * r[0] + (1 - beta) * r[1]), rtol=1e-15)


def test_symmetric_triangular_rule():
    """6.4.5.4: the symmetric triangle is the trapezoid with beta = 0 (sum of two rectangles)."""
    x = Triangular(-1.0, 1.0).draw(np.random.default_rng(3), 1000)
    r = np.random.default_rng(3).random((2, 1000))
    np.testing.assert_allclose(x, -1.0 + (r[0] + r[1]), rtol=1e-15, atol=1e-15)


def test_curvilinear_trapezoidal_rule():
    """6.4.3.4: a_s = (a - d) + 2 d r1, b_s = (a + b) - a_s, xi = a_s + (b_s - a_s) r2."""
    a, b, d = -0.05, 0.05, 0.025
    x = CurvilinearTrapezoidal(a, b, d).draw(np.random.default_rng(4), 1000)
    r = np.random.default_rng(4).random((2, 1000))
    a_s = (a - d) + 2 * d * r[0]
    b_s = (a + b) - a_s
    np.testing.assert_allclose(x, a_s + (b_s - a_s) * r[1], rtol=1e-15, atol=1e-17)


def test_arcsine_rule():
    """6.4.6.4: xi = (a + b)/2 + (b - a)/2 sin(2 pi r)."""
    x = Arcsine(-0.5, 0.5).draw(np.random.default_rng(5), 1000)
    r = np.random.default_rng(5).random(1000)
    np.testing.assert_allclose(x, 0.5 * np.sin(2 * np.pi * r), rtol=1e-15, atol=1e-16)
    assert np.all(np.abs(x) <= 0.5)


def test_student_t_rule_and_guf_convention():
    """6.4.9.7: xi = mu + s t_nu; the MCM variance is s^2 nu/(nu - 2), not s^2."""
    d = StudentT(3.0, 0.5, 6)
    x = d.draw(np.random.default_rng(6), 1000)
    np.testing.assert_allclose(x, 3.0 + 0.5 * np.random.default_rng(6).standard_t(6, 1000))
    assert d.std == pytest.approx(0.5 * math.sqrt(6 / 4))
    assert StudentT(0.0, 1.0, 2).std == math.inf
    assert math.isnan(StudentT(0.0, 1.0, 1).mean)


def test_multivariate_normal_moments_and_shape():
    mean = [1.0, -2.0, 0.5]
    cov = [[4.0, 1.2, 0.0], [1.2, 1.0, -0.3], [0.0, -0.3, 0.25]]
    d = MultivariateNormal(mean, cov)
    x = d.draw(np.random.default_rng(8), (N // 2,))
    assert x.shape == (N // 2, 3)
    assert d.event_shape == (3,)
    np.testing.assert_allclose(d.std, np.sqrt(np.diag(cov)))
    se = np.sqrt(np.diag(cov) / x.shape[0])
    assert np.all(np.abs(x.mean(axis=0) - mean) <= 4 * se)
    emp = np.cov(x, rowvar=False)
    # sd of a sample covariance entry: sqrt((s_ii s_jj + s_ij^2)/(N-1))
    c = np.asarray(cov)
    sd = np.sqrt((np.outer(np.diag(c), np.diag(c)) + c**2) / (x.shape[0] - 1))
    assert np.all(np.abs(emp - c) <= 4 * sd)


def test_multivariate_normal_singular_covariance():
    d = MultivariateNormal([0.0, 0.0], [[1.0, 1.0], [1.0, 1.0]])
    x = d.draw(np.random.default_rng(9), 1000)
    np.testing.assert_allclose(x[:, 0], x[:, 1], atol=1e-12)


def test_draw_shapes_and_rng_type():
    d = Normal(0.0, 1.0)
    assert d.draw(np.random.default_rng(0), (3, 4)).shape == (3, 4)
    assert d.draw(np.random.default_rng(0)).shape == ()
    assert Constant(2.5).draw(np.random.default_rng(0), 5).tolist() == [2.5] * 5
    with pytest.raises(TypeError, match="rng"):
        d.draw(np.random.RandomState(0), 3)
    with pytest.raises(TypeError, match="rng"):
        d.draw(42, 3)


def test_draws_do_not_touch_global_state():
    np.random.seed(0)
    before = np.random.get_state()[1].copy()
    for dist, _ in CASES.values():
        dist.draw(np.random.default_rng(1), 10)
    np.testing.assert_array_equal(np.random.get_state()[1], before)


# ----------------------------------------------------------------- argument checking
BAD_NUMBERS = st.sampled_from(
    [math.nan, math.inf, -math.inf, "1.0", None, True, [1.0], {"a": 1}, complex(1, 1)]
)
GOOD = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)


def _raises_naming(param, fn, *args, **kwargs):
    with pytest.raises(InvalidInput) as info:
        fn(*args, **kwargs)
    assert f"'{param}'" in str(info.value)
    assert isinstance(info.value, ValueError) and isinstance(info.value, TypeError)


@settings(max_examples=40, deadline=None)
@given(bad=BAD_NUMBERS, good=GOOD)
def test_bad_numbers_name_the_parameter(bad, good):
    _raises_naming("mean", Normal, bad, 1.0)
    _raises_naming("std", Normal, good, bad)
    _raises_naming("low", Rectangular, bad, good)
    _raises_naming("high", Rectangular, good, bad)
    _raises_naming("low", Triangular, bad, good)
    if bad is not None:  # mode=None means the symmetric triangle
        _raises_naming("mode", Triangular, -1.0, 1.0, bad)
    _raises_naming("beta", Trapezoidal, -1.0, 1.0, bad)
    _raises_naming("d", CurvilinearTrapezoidal, -1.0, 1.0, bad)
    _raises_naming("high", Arcsine, good, bad)
    _raises_naming("loc", StudentT, bad, 1.0, 5)
    _raises_naming("scale", StudentT, good, bad, 5)
    _raises_naming("dof", StudentT, good, 1.0, bad)
    _raises_naming("value", Constant, bad)


@settings(max_examples=40, deadline=None)
@given(low=GOOD, gap=st.floats(min_value=1e-6, max_value=1e6))
def test_low_above_high(low, gap):
    high = low - gap
    for cls in (Rectangular, Triangular, Arcsine):
        _raises_naming("high", cls, low, high)
    _raises_naming("high", Trapezoidal, low, high, 0.5)
    _raises_naming("high", CurvilinearTrapezoidal, low, high, 0.0)


@settings(max_examples=40, deadline=None)
@given(neg=st.floats(max_value=-1e-12, min_value=-1e9))
def test_negative_spreads(neg):
    _raises_naming("std", Normal, 0.0, neg)
    _raises_naming("scale", StudentT, 0.0, neg, 3)
    _raises_naming("dof", StudentT, 0.0, 1.0, neg)
    _raises_naming("d", CurvilinearTrapezoidal, -1.0, 1.0, neg)
    _raises_naming("beta", Trapezoidal, -1.0, 1.0, neg)


def test_range_rules():
    _raises_naming("dof", StudentT, 0.0, 1.0, 0)
    _raises_naming("beta", Trapezoidal, 0.0, 1.0, 1.5)
    _raises_naming("d", CurvilinearTrapezoidal, 0.0, 1.0, 0.6)  # d > (b - a)/2
    _raises_naming("mode", Triangular, 0.0, 1.0, 2.0)


def test_every_problem_is_listed_at_once():
    with pytest.raises(InvalidInput) as info:
        Normal(math.nan, -1.0)
    assert len(info.value.problems) == 2


@settings(max_examples=30, deadline=None)
@given(
    cov=st.sampled_from(
        [
            [[1.0, 2.0], [2.0, 1.0]],  # not positive semidefinite
            [[1.0, 0.5], [0.1, 1.0]],  # not symmetric
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],  # wrong size
            [[1.0, math.nan], [math.nan, 1.0]],
            [[1.0, 0.0], [0.0, math.inf]],
            [1.0, 2.0],  # not 2-D
            "cov",
            None,
            [["a", "b"], ["c", "d"]],
        ]
    )
)
def test_bad_covariance(cov):
    _raises_naming("cov", MultivariateNormal, [0.0, 0.0], cov)


@pytest.mark.parametrize("mean", [[], [math.nan, 0.0], [[0.0, 0.0]], "ab", None, [math.inf, 1.0]])
def test_bad_multivariate_mean(mean):
    _raises_naming("mean", MultivariateNormal, mean, [[1.0, 0.0], [0.0, 1.0]])
