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
    assert quick.details.mc.trials in measured.VALIDATION_TRIALS
    tol = 4 / math.sqrt(2 * (FULL_TRIALS - 1))
    np.testing.assert_allclose(quick.std, full.std, rtol=tol)
    k = 1.959963984540054
    half = 0.5 * (quick.high - quick.low)
    assert np.all(half >= k * quick.std * (1 - 1e-12))  # the correction's u widens it only
    np.testing.assert_allclose(0.5 * (quick.high + quick.low), quick.value, atol=1e-9)
    # the bias correction comes from the validating Monte Carlo, within its standard error
    se = full.std / math.sqrt(quick.details.mc.trials)
    assert np.all(np.abs(quick.bias_correction - full.bias_correction) <= 4 * se)


def _linear(proc, setup, gum, only=None, trials=measured.LINEAR_TRIALS, block=256):
    from mtplan.evaluation.simulation import linear_trials

    return linear_trials(proc, setup, gum, sources=only, rng=0, trials=trials, block_size=block)


def test_a_non_normal_output_is_not_validated():
    """rotary_axis's EB0C under the slides' slope alone follows a rectangular distribution
    (its 95 % interval is +-1.65 u, not +-1.96 u): the first-order model's own draws lie
    off the normal interval by more than their standard errors, so first order is refused
    before any Monte Carlo of the estimator, and the note names the measurand."""
    proc = get("rotary_axis")
    setup, only = proc.Setup(), ["xy_slope_halfwidth"]
    gum = measured._first_order(proc, setup, proc.Truth(), "angles", only)
    refused = measured._linear_model_checks(proc, setup, gum, _linear(proc, setup, gum, only),
                                            0.95)
    assert any(r.startswith("EB0C (its first-order model's") for r in refused), refused
    r, got, note = measured._validating_runs(proc, setup, proc.Truth(), "angles", only, gum,
                                             coverage=0.95, root=np.random.SeedSequence(0),
                                             progress=False, n_jobs=1)
    assert r is None and got is None
    assert "EB0C (its first-order model's" in note and f"{FULL_TRIALS} trials" in note


def test_the_linear_model_pairs_with_the_monte_carlo_trials():
    """linear_trials redraws the Monte Carlo's errors: at circle_centre's default (the
    probe's start held, as a measured file holds it) its first-order outputs follow the
    Monte Carlo's own trial by trial (the radius departs most from first order), and their covariance is first order's within the
    sampling error of a standard deviation from N trials (4 / sqrt(2 (N - 1)) relative)."""
    from mtplan.evaluation.simulation import simulate_uncertainty

    proc = get("circle_centre")
    setup = proc.Setup()
    only = [k for k in proc.active_sources(setup) if k != "start_scatter"]
    gum = measured._first_order(proc, setup, proc.Truth(), "gls", only)
    r = simulate_uncertainty(proc, setup, None, estimator="gls", sources=only, trials=512,
                             rng=0, block_size=256)
    lin = _linear(proc, setup, gum, only, trials=512)
    for i, m in enumerate(gum.names):
        y = r.mc.samples(m)
        # paired: the correlation is near 1 (unpaired draws would give about 0)
        assert np.corrcoef(y, lin[:, i])[0, 1] > 0.95, m
    big = _linear(proc, setup, gum, only, trials=4096)
    tol = 4 / math.sqrt(2 * (4096 - 1))
    np.testing.assert_allclose(big.std(axis=0, ddof=1), gum.std, rtol=tol)


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
    """The same Monte Carlo against a first order whose sensitivities are 20 % too small is
    refused by the control-variate check of u, with the measurand and the ratio named; one
    whose inputs' standard deviations are 20 % too small (its law of propagation no longer
    that of the draws) by the first-order model's own draws."""
    import dataclasses

    from mtplan.evaluation.simulation import simulate_uncertainty

    proc, m = _measurement("circle_centre")
    setup = m.setup  # the probe's start held, as the estimate holds it
    only = [k for k in proc.active_sources(setup) if k != "start_scatter"]
    gum = measured._first_order(proc, setup, proc.Truth(), "gls", only)
    r = simulate_uncertainty(proc, setup, None, estimator="gls", sources=only, trials=1024,
                             rng=0, block_size=256)
    assert measured._validated_first_order(proc, setup, gum, r, 0.95,
                                           _linear(proc, setup, gum, only))[0] is gum
    small = dataclasses.replace(gum, sensitivity=gum.sensitivity * 0.8)
    got, note = measured._validated_first_order(proc, setup, small, r, 0.95,
                                                _linear(proc, setup, small, only))
    assert got is None
    assert "centre_x (u Monte Carlo / first order 1.2" in note
    narrow = dataclasses.replace(gum, input_std=gum.input_std * 0.8)
    refused = measured._linear_model_checks(proc, setup, narrow,
                                            _linear(proc, setup, narrow, only), 0.95)
    assert any(r.startswith("centre_x (its first-order model's 2048 draws: u / first order "
                            "1.2") for r in refused), refused


def test_a_longer_validation_repeats_no_block():
    """Each validating Monte Carlo extends the one before: with the blocks kept, 512
    trials after 256 run only the two new blocks of 128, and give exactly what 512 trials
    give alone."""
    from mtplan.evaluation import simulation

    proc = get("circle_centre")
    setup, runs = proc.Setup(), []
    real = simulation.procedure_block

    def counting(*args):
        runs.append(args[-2:])
        return real(*args)

    cache = {}
    kw = dict(estimator="gls", rng=3, block_size=128)
    try:
        simulation.procedure_block = counting
        simulation.simulate_uncertainty(proc, setup, None, trials=256, cache=cache, **kw)
        longer = simulation.simulate_uncertainty(proc, setup, None, trials=512, cache=cache,
                                                 **kw)
    finally:
        simulation.procedure_block = real
    assert runs == [(0, 128), (1, 128), (2, 128), (3, 128)]
    alone = simulation.simulate_uncertainty(proc, setup, None, trials=512, **kw)
    np.testing.assert_array_equal(longer.mc.std, alone.mc.std)
    np.testing.assert_array_equal(longer.mc.low, alone.mc.low)
    np.testing.assert_array_equal(longer.mc.mean, alone.mc.mean)


@pytest.mark.parametrize("trials", [0, -5])
def test_an_explicit_trial_count_is_still_checked(trials):
    proc, m = _measurement("circle_centre")
    with pytest.raises(ValueError, match="trials"):
        estimate_measured(proc, None, m, trials=trials, rng=0)


def test_the_correction_spread_does_not_depend_on_the_workers():
    """The truths' Monte Carlos of the bias correction spread over the workers give what
    they give in one process, bit for bit."""
    from mtplan.evaluation.correction import correction_spread
    from mtplan.evaluation.simulation import simulate_uncertainty

    proc, m = _measurement("circle_centre")
    at = simulate_uncertainty(proc, m.setup, proc.Truth(), estimator="gls", trials=40, rng=0,
                              progress=False)
    kw = dict(heavy=np.zeros(3, dtype=bool), rng=np.random.SeedSequence(0), draws=3,
              trials=40)
    one, why = correction_spread(at, m.readings, n_jobs=1, **kw)
    two, _ = correction_spread(at, m.readings, n_jobs=2, **kw)
    assert why is None and one.shape == (3, 3)
    np.testing.assert_array_equal(one, two)
