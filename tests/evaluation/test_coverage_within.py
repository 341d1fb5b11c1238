"""The coverage of ± U counted with the first-order model as its control variate
(:meth:`ProcedureResult.coverage_within`), against plain counts of many more trials."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mtplan.evaluation.first_order import first_order
from mtplan.evaluation.simulation import linear_reference, linear_trials, simulate_uncertainty
from mtplan.models import get


def test_the_reference_draws_the_monte_carlos_distribution_of_the_first_order_model():
    """The normal elements summed exactly into one normal vector, the others drawn: with
    a rectangular source made dominant (the set-up's ``distributions``) the reference's
    fractions within ± 1, 1.5 and 2 standard deviations match those of the Monte Carlo's
    own draws through the same sensitivities (200 000 of each), and its covariance
    the first-order one, within their sampling errors."""
    proc = get("circle_centre")
    setup = proc.Setup(distributions="probe_noise=arcsine")
    fo = first_order(proc, setup, estimator="kasa")
    ref = linear_reference(proc, setup, fo, rng=3, trials=200_000)
    own = linear_trials(proc, setup, fo, rng=4, trials=200_000, block_size=4096)
    n = ref.shape[0]
    c = fo.cov  # the sampling error of a covariance: sqrt((C_ii C_jj + C_ij^2) / n)
    assert np.all(np.abs(np.cov(ref.T) - c)
                  <= 5 * np.sqrt((np.outer(np.diag(c), np.diag(c)) + c**2) / n))
    for k in (1.0, 1.5, 2.0):
        a = np.mean(np.abs(ref) <= k * fo.std, axis=0)
        b = np.mean(np.abs(own) <= k * fo.std, axis=0)
        assert np.all(np.abs(a - b) <= 4 * np.sqrt(2 * a * (1 - a) / n) + 1e-12), (k, a, b)


@pytest.mark.parametrize("estimator", ["three_point", "gls"])
def test_coverage_within_agrees_with_a_count_of_many_more_trials(estimator):
    """400 trials of circle_centre (rectangular and normal sources; the three-point rule
    far from first order, gls nearer): the coverage of their own value ± U agrees
    with the plain count of 200 000 trials from another seed within four standard errors
    of the two, and is counted no coarser than the 400 trials' plain count."""
    from mtplan.uncertainty.coverage import coverage_se

    r = simulate_uncertainty("circle_centre", estimator=estimator, trials=400, rng=21,
                             progress=False)
    p, se = r.coverage_of_U()
    plain = r.mc.U_coverage(2.0)
    big = simulate_uncertainty("circle_centre", estimator=estimator, trials=200_000, rng=22,
                               progress=False)
    for i, name in enumerate(r.mc.names):
        y = big.mc.samples(name)
        truth = float(np.mean(np.abs(y - r.mc.mean[i]) <= 2 * r.mc.std[i]))
        tol = 4 * math.hypot(se[i], math.sqrt(truth * (1 - truth) / y.size))
        assert abs(p[i] - truth) <= tol, (name, p[i], truth, tol)
        assert se[i] <= coverage_se(plain[i], 400) + 1e-12


def test_coverage_within_any_interval_and_a_resolved_count_is_plain():
    """Any centre and half width (what a measured result asks: its value ± its U); a Monte
    Carlo whose plain count already resolves the coverage is counted plainly."""
    from mtplan.uncertainty.coverage import RESOLUTION

    r = simulate_uncertainty("circle_centre", estimator="gls", trials=400, rng=21,
                             progress=False)
    centre, half = r.mc.mean + 0.3 * r.mc.std, 1.5 * r.mc.std
    p, se = r.coverage_within(centre, half)
    y = simulate_uncertainty("circle_centre", estimator="gls", trials=100_000, rng=23,
                             progress=False)
    for i, name in enumerate(r.mc.names):
        truth = float(np.mean(np.abs(y.mc.samples(name) - centre[i]) <= half[i]))
        assert abs(p[i] - truth) <= 4 * math.hypot(se[i], math.sqrt(truth * (1 - truth) / 1e5))
    many = simulate_uncertainty("circle_centre", estimator="gls", trials=8192, rng=21,
                                progress=False)
    p, se = many.coverage_of_U()
    assert np.all(se <= RESOLUTION)
    assert np.array_equal(p, many.mc.U_coverage(2.0))


def test_first_order_refuses_a_chain_rule_dearer_than_asked():
    """``max_runs``: the chain rule only where it runs the estimator at most that often
    (rotary_axis: two runs per reading)."""
    proc = get("rotary_axis")
    setup = proc.Setup()
    assert first_order(proc, setup, max_runs=10) is None
    fo = first_order(proc, setup, max_runs=10**6)
    assert fo is not None and fo.path == "chain rule"
