"""The coverage of ± U (U = 2u) from the Monte Carlo values, against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mtplan.uncertainty import Normal, Rectangular, propagate
from mtplan.uncertainty.coverage import (
    common_text,
    coverage_se,
    coverage_text,
    fraction_within,
    is_about_nominal,
    normal_coverage,
)

M = 200_000


def _tol(p: float, trials: int = M) -> float:
    """Four binomial standard errors of a coverage from `trials` values, and u's own."""
    return 4.0 * math.sqrt(p * (1 - p) / trials) + 2e-3


@pytest.mark.parametrize("keep", [10 * M, 1_000])  # the kept values, and the histogram
def test_coverage_of_2u_against_closed_forms(keep):
    """Normal: erf(sqrt 2) = 95.45 %; the sum of two rectangulars (triangular, u =
    sqrt(2/3)): 1 - (2 - 2u)^2 / 4 = 96.63 %; a rectangular: 100 % (2u = 1.15 half-widths).
    The histogram kept beyond `keep` gives the same fractions."""
    r = propagate(lambda a, b, c: {"normal": a, "triangular": b + c, "rectangular": b},
                  {"a": Normal(0, 1), "b": Rectangular(-1, 1), "c": Rectangular(-1, 1)},
                  trials=M, rng=11, keep=keep, progress=False)
    assert (r.samples("normal") is None) == (keep < M)
    got = dict(zip(r.names, r.U_coverage(), strict=True))
    triangular = 1 - (2 - 2 * math.sqrt(2 / 3)) ** 2 / 4
    assert got["normal"] == pytest.approx(math.erf(math.sqrt(2)), abs=_tol(0.9545))
    assert got["triangular"] == pytest.approx(triangular, abs=_tol(triangular))
    assert got["rectangular"] == 1.0
    # any interval: the middle half of the triangular distribution's values
    assert r.fraction_within("triangular", -(2 - math.sqrt(2)), 2 - math.sqrt(2)) == \
        pytest.approx(0.5, abs=_tol(0.5))


def test_fraction_within_counts_the_ends_and_refuses_nothing():
    x = np.array([-1.0, 0.0, 1.0, 2.0])
    assert fraction_within(x, 0.0, 1.0) == 0.75
    assert np.isnan(fraction_within(x, np.nan, 1.0))
    assert np.allclose(fraction_within(np.column_stack([x, 2 * x]), [0.0, 0.0], [1.0, 1.0]),
                       [0.75, 0.25])


def test_normal_assumed_and_the_words():
    assert normal_coverage() == pytest.approx(0.9545, abs=1e-4)
    assert normal_coverage(2.0, 10.0) == pytest.approx(0.9266, abs=1e-4)  # Student's t
    assert is_about_nominal(0.955) and is_about_nominal(0.94) and not is_about_nominal(0.989)
    assert coverage_text(0.98912) == "98.9 %"
    assert coverage_text(normal_coverage(), assumed=True) == "95.4 % (normal assumed)"
    assert coverage_text(None) == "-"
    assert common_text([0.951, 0.958]) == "about 95 %"
    assert common_text([0.951, 0.989]) is None


# ------------------------------------------------------------ the control variate
def _normal_fraction(low, high) -> float:
    """P(low <= Z <= high) for a standard normal Z."""
    return 0.5 * (math.erf(high / math.sqrt(2)) - math.erf(low / math.sqrt(2)))


def test_controlled_fraction_of_a_linear_estimator_is_its_reference_count():
    """An estimator that is its first-order model (here 3 + 2 l) leaves nothing to sample:
    the count is the reference's, within the reference's own error of the closed form, and
    its standard error is the floor of one differing trial in M and the reference's."""
    from mtplan.uncertainty.coverage import controlled_fraction

    rng = np.random.default_rng(5)
    m, n_ref = 400, 400_000
    lin = rng.standard_normal((m, 1))
    y = 3.0 + 2.0 * lin
    ref = rng.standard_normal((n_ref, 1))
    centre, half = y.mean(axis=0), 2.0 * y.std(axis=0, ddof=1)
    p, se = controlled_fraction(y, lin, ref, centre, half)
    a, s = lin.mean(), 2.0 * lin.std(ddof=1)  # |l - a| <= s in the units of l
    exact = _normal_fraction(a - s, a + s)
    assert p[0] == pytest.approx(exact, abs=_tol(exact, n_ref) - 2e-3)
    assert se[0] == pytest.approx(math.sqrt(1 / m**2 + exact * (1 - exact) / n_ref), rel=0.02)


@pytest.mark.parametrize("curvature", [0.02, 0.3])
def test_controlled_fraction_against_a_large_count(curvature):
    """A skewed estimator y = x + c (x^2 - 1) with x its first-order model: 400 trials with
    the control variate agree with the count of 10**6 values of the same interval within
    four standard errors of the two; close to first order (a departure of 3 % of u) they
    resolve it to about half the plain count's error, far from it (42 %) to no better."""
    from mtplan.uncertainty.coverage import controlled_fraction

    rng = np.random.default_rng(7)
    m = 400

    def model(x):
        return x + curvature * (x**2 - 1.0)

    x = rng.standard_normal((m, 1))
    y = model(x)
    centre, half = y.mean(axis=0), 2.0 * y.std(axis=0, ddof=1)
    p, se = controlled_fraction(y, x, rng.standard_normal((100_000, 1)), centre, half)
    big = model(rng.standard_normal(1_000_000))
    truth = float(np.mean(np.abs(big - centre[0]) <= half[0]))
    assert abs(p[0] - truth) <= 4 * math.hypot(se[0], math.sqrt(truth * (1 - truth) / 1e6))
    plain = float(np.mean(np.abs(y - centre) <= half))
    if curvature < 0.1:
        assert se[0] < 0.6 * coverage_se(plain, m)


def test_controlled_fraction_without_a_useful_control_is_still_unbiased():
    """A first-order output unrelated to the values (a poor control) leaves the count
    unbiased; one that does not vary is not used (the plain count, binomial error)."""
    from mtplan.uncertainty.coverage import controlled_fraction

    rng = np.random.default_rng(9)
    m = 400
    y = rng.standard_normal((m, 2))
    lin = np.column_stack([rng.standard_normal(m), np.zeros(m)])
    ref = np.column_stack([rng.standard_normal(100_000), np.zeros(100_000)])
    centre, half = np.zeros(2), np.full(2, 2.0)
    p, se = controlled_fraction(y, lin, ref, centre, half)
    exact = math.erf(math.sqrt(2))
    assert abs(p[0] - exact) <= 4 * se[0]
    plain = float(np.mean(np.abs(y[:, 1]) <= 2.0))
    assert p[1] == plain and se[1] == pytest.approx(coverage_se(plain, m))
    assert np.isnan(controlled_fraction(y, lin, ref, [np.nan, 0.0], half)[0][0])


def test_the_count_resolution_and_its_words():
    """None or all outside counts as one (100 % of 400 is +-0.25 %, not +-0); a coverage
    resolved less than RESOLUTION is printed with its standard error and is never "about
    95 %"."""
    from mtplan.uncertainty.coverage import RESOLUTION

    assert coverage_se(1.0, 400) == pytest.approx(math.sqrt(399 / 400**3))
    assert coverage_text(0.9512, se=0.011) == "95.1 % ± 1.1 %"
    assert coverage_text(0.9512, se=RESOLUTION) == "95.1 %"
    assert not is_about_nominal(0.951, 0.011) and is_about_nominal(0.951, 0.002)
    assert common_text([0.951, 0.955], [0.002, 0.011]) is None
    assert common_text([0.951, 0.955], [0.002, 0.002]) == "about 95 %"
