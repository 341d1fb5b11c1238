"""The coverage of ± U (U = 2u) from the Monte Carlo values, against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mtplan.uncertainty import Normal, Rectangular, propagate
from mtplan.uncertainty.coverage import (
    common_text,
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
