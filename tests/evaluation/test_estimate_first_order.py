"""``estimate`` without a trial count: the first-order (GUM) u and interval where a short
Monte Carlo validates them (JCGM 101 8.2), the full Monte Carlo where it does not."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mtplan.evaluation import measured
from mtplan.evaluation.measured import FULL_TRIALS, estimate_measured, read_measurement
from mtplan.models import get

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _measurement(name):
    proc = get(name)
    return proc, read_measurement(proc, EXAMPLES / f"{name}_readings.csv", {})


def _note(result, start):
    found = [n for n in result.notes if n.startswith(start)]
    assert len(found) == 1, result.notes
    return found[0]


def test_validated_first_order_agrees_with_the_full_monte_carlo():
    """circle_centre's gls is linear at the example: first order is validated, and its u
    lies within the full Monte Carlo's own sampling error of the 10 000-trial u (4 standard
    errors of a standard deviation, 4 / sqrt(2 (N - 1)) relative); the interval is
    value +- k u."""
    proc, m = _measurement("circle_centre")
    quick = estimate_measured(proc, None, m, estimator="gls", rng=0, fit_alpha=None)
    full = estimate_measured(proc, None, m, estimator="gls", trials=FULL_TRIALS, rng=0,
                             fit_alpha=None)
    assert _note(quick, "u and the intervals are first order")
    assert quick.details.mc.trials == measured.VALIDATION_TRIALS[0]
    tol = 4 / math.sqrt(2 * (FULL_TRIALS - 1))
    np.testing.assert_allclose(quick.std, full.std, rtol=tol)
    k = 1.959963984540054
    half = 0.5 * (quick.high - quick.low)
    assert np.all(half >= k * quick.std * (1 - 1e-12))  # the correction's u widens it only
    np.testing.assert_allclose(0.5 * (quick.high + quick.low), quick.value, atol=1e-9)
    # the bias correction comes from the validating Monte Carlo, within its standard error
    se = full.std / math.sqrt(measured.VALIDATION_TRIALS[0])
    assert np.all(np.abs(quick.bias_correction - full.bias_correction) <= 4 * se)


def test_a_non_normal_output_is_not_validated():
    """rotary_axis's EB0C under the slides' slope alone follows a rectangular distribution
    (its 95 % interval is +-1.65 u, not +-1.96 u): the interval ends of the validating Monte
    Carlo lie off the normal ones by more than their standard errors, so first order is
    refused and the note names the measurand."""
    from mtplan.evaluation.simulation import simulate_uncertainty

    proc = get("rotary_axis")
    setup, only = proc.Setup(), ["xy_slope_halfwidth"]
    gum = measured._first_order(proc, setup, proc.Truth(), "angles", only)
    r = simulate_uncertainty(proc, setup, None, estimator="angles", sources=only, trials=1000,
                             rng=0)
    got, note = measured._validated_first_order(proc, setup, gum, r, 0.95)
    assert got is None
    assert "EB0C (u Monte Carlo / first order" in note and f"{FULL_TRIALS} trials" in note


def test_without_validation_the_full_monte_carlo_is_the_explicit_one(monkeypatch):
    """Where first order is not validated, the result is the 10 000-trial Monte Carlo's,
    bit for bit (the same as --trials 10000)."""
    monkeypatch.setattr(measured, "_validated_first_order",
                        lambda *a: (None, "first order not validated (forced)"))
    proc, m = _measurement("circle_centre")
    r = estimate_measured(proc, None, m, estimator="gls", rng=0, fit_alpha=None)
    assert _note(r, "first order not validated")
    assert r.details.mc.trials == FULL_TRIALS
    explicit = estimate_measured(proc, None, m, estimator="gls", trials=FULL_TRIALS, rng=0,
                                 fit_alpha=None)
    np.testing.assert_array_equal(r.std, explicit.std)
    np.testing.assert_array_equal(r.low, explicit.low)


def test_validation_rejects_a_first_order_u_off_the_monte_carlo():
    """The same Monte Carlo against a first order 20 % too small is refused, with the
    measurand and the ratio named."""
    proc, m = _measurement("circle_centre")
    setup = m.setup
    gum = measured._first_order(proc, setup, proc.Truth(), "gls", None)
    from mtplan.evaluation.simulation import simulate_uncertainty

    r = simulate_uncertainty(proc, setup, None, estimator="gls", trials=1000, rng=0)
    assert measured._validated_first_order(proc, setup, gum, r, 0.95)[0] is gum
    import dataclasses

    small = dataclasses.replace(gum, input_std=gum.input_std * 0.8)
    got, note = measured._validated_first_order(proc, setup, small, r, 0.95)
    assert got is None
    assert "centre_x (u Monte Carlo / first order 1.2" in note


@pytest.mark.parametrize("trials", [0, -5])
def test_an_explicit_trial_count_is_still_checked(trials):
    proc, m = _measurement("circle_centre")
    with pytest.raises(ValueError, match="trials"):
        estimate_measured(proc, None, m, trials=trials, rng=0)
