"""Batch-first planar circle fits: three-point (seed formula), Kasa, geometric."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from mtplan._validate import InvalidInput
from mtplan.fitting.circle import (
    circle_residuals,
    geometric_fit,
    kasa_fit,
    three_point_circle,
)

FITS = [kasa_fit, geometric_fit]


def _arcs(rng, batch, m, spread_deg, radius=250.0, centre=(0.3, -0.2)):
    start = rng.uniform(0, 2 * np.pi, (batch, 1))
    t = start + np.radians(spread_deg) * np.linspace(0, 1, m)
    return centre[0] + radius * np.cos(t), centre[1] + radius * np.sin(t)


def test_three_point_by_hand():
    c = three_point_circle([0.0, 2.0, 0.0], [0.0, 0.0, 2.0])
    assert (c.xc, c.yc) == (1.0, 1.0)
    assert c.r == pytest.approx(np.sqrt(2), abs=1e-15)


def test_three_point_equals_the_seed_formula_on_raw_coordinates():
    rng = np.random.default_rng(4)
    x, y = _arcs(rng, 50, 3, 240, radius=20.0)
    x1, x2, x3 = x.T
    y1, y2, y3 = y.T
    a, b = 2 * (x2 - x1), 2 * (y2 - y1)
    c = x2**2 + y2**2 - x1**2 - y1**2
    d, e = 2 * (x3 - x2), 2 * (y3 - y2)
    f = x3**2 + y3**2 - x2**2 - y2**2
    got = three_point_circle(x, y)
    np.testing.assert_allclose(got.xc, (c * e - f * b) / (a * e - b * d), atol=1e-12)
    np.testing.assert_allclose(got.yc, (a * f - c * d) / (a * e - b * d), atol=1e-12)


@pytest.mark.parametrize("m, spread", [(3, 240), (5, 360 * 4 / 5), (12, 330), (7, 10), (4, 2)])
def test_exact_for_points_on_a_circle(m, spread):
    rng = np.random.default_rng(m)
    x, y = _arcs(rng, 200, m, spread)
    fits = FITS + ([three_point_circle] if m == 3 else [])
    # a short arc amplifies rounding by about (1/spread)^2
    tol = 1e-10 * max(1.0, (60.0 / spread) ** 2)
    for fit in fits:
        c = fit(x, y)
        assert c.xc.shape == (200,)
        np.testing.assert_allclose(c.xc, 0.3, atol=tol, rtol=0, err_msg=fit.__name__)
        np.testing.assert_allclose(c.yc, -0.2, atol=tol, rtol=0, err_msg=fit.__name__)
        np.testing.assert_allclose(c.r, 250.0, atol=tol, rtol=0, err_msg=fit.__name__)


def test_geometric_fit_is_the_least_squares_minimum():
    rng = np.random.default_rng(7)
    x, y = _arcs(rng, 6, 9, 120, radius=10.0)
    x = x + rng.normal(0, 0.05, x.shape)
    y = y + rng.normal(0, 0.05, y.shape)
    c = geometric_fit(x, y)
    assert np.all(c.converged)
    for i in range(6):
        ref = least_squares(lambda p: np.hypot(x[i] - p[0], y[i] - p[1]) - p[2],
                            [c.xc[i] + 0.1, c.yc[i] - 0.1, c.r[i]], xtol=1e-15, ftol=1e-15,
                            gtol=1e-15)
        np.testing.assert_allclose([c.xc[i], c.yc[i], c.r[i]], ref.x, atol=1e-9)
    # the normal equations hold: sum of residuals (d r) and of residual * direction vanish
    res = circle_residuals(x, y, c.xc, c.yc, c.r)
    np.testing.assert_allclose(res.sum(axis=-1), 0, atol=1e-12)


def test_kasa_matches_a_plain_least_squares_solution():
    rng = np.random.default_rng(8)
    x, y = _arcs(rng, 4, 8, 200, radius=30.0)
    x = x + rng.normal(0, 0.1, x.shape)
    c = kasa_fit(x, y)
    for i in range(4):
        a = np.column_stack([x[i], y[i], np.ones(8)])
        d, e, f = np.linalg.lstsq(a, -(x[i] ** 2 + y[i] ** 2), rcond=None)[0]
        np.testing.assert_allclose([c.xc[i], c.yc[i]], [-d / 2, -e / 2], rtol=1e-12)
        np.testing.assert_allclose(c.r[i], np.sqrt(d * d / 4 + e * e / 4 - f), rtol=1e-12)


@pytest.mark.parametrize("fit", FITS)
def test_equivariant_under_translation_and_rotation(fit):
    rng = np.random.default_rng(9)
    x, y = _arcs(rng, 3, 10, 300, radius=5.0)
    x, y = x + rng.normal(0, 0.02, x.shape), y + rng.normal(0, 0.02, y.shape)
    c0 = fit(x, y)
    phi, tx, ty = 0.7, 100.0, -40.0
    xr = np.cos(phi) * x - np.sin(phi) * y + tx
    yr = np.sin(phi) * x + np.cos(phi) * y + ty
    c1 = fit(xr, yr)
    np.testing.assert_allclose(c1.xc, np.cos(phi) * c0.xc - np.sin(phi) * c0.yc + tx, atol=1e-9)
    np.testing.assert_allclose(c1.yc, np.sin(phi) * c0.xc + np.cos(phi) * c0.yc + ty, atol=1e-9)
    np.testing.assert_allclose(c1.r, c0.r, atol=1e-9)


def test_kasa_underestimates_the_radius_of_a_short_noisy_arc():
    rng = np.random.default_rng(10)
    x, y = _arcs(rng, 4000, 10, 60, radius=10.0, centre=(0, 0))
    x, y = x + rng.normal(0, 0.05, x.shape), y + rng.normal(0, 0.05, y.shape)
    assert np.mean(kasa_fit(x, y).r) < np.mean(geometric_fit(x, y).r)


def test_collinear_three_points_give_non_finite_values():
    c = three_point_circle([0.0, 1.0, 2.0], [0.0, 1.0, 2.0])
    assert not np.isfinite(c.xc)


@pytest.mark.parametrize("fit", [three_point_circle, kasa_fit, geometric_fit])
@pytest.mark.parametrize("x, y, match", [
    ([0.0, 1.0], [0.0, 1.0], "at least 3"),
    ([0.0, 1.0, 2.0], [0.0, 1.0], "same shape"),
    ([0.0, np.nan, 2.0], [0.0, 1.0, 0.0], "finite"),
])
def test_bad_input_is_refused(fit, x, y, match):
    with pytest.raises(InvalidInput, match=match):
        fit(x, y)
