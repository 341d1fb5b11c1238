"""Errors along the travel: curves of ``FUNCTION@POSITION`` measurands and their
simultaneous (sup-t) band, which holds the whole curve with the coverage probability and
always holds the pointwise band."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import norm

from mtplan.evaluation.along import (
    curves,
    parse_grid,
    simultaneous_bands,
    simultaneous_factor,
    widen,
)

X = np.arange(-50.0, 50.1, 5.0)


def _cubic_curve(seed=7):
    """A cubic error curve through zero at x = 0 (as geometry21's) with a random
    coefficient covariance: names, values, covariance of its points [um]."""
    rng = np.random.default_rng(seed)
    G = np.stack([X / 50, (X / 50) ** 2, (X / 50) ** 3], axis=1)
    A = rng.normal(size=(3, 3))
    sigma = A @ A.T * 0.05
    cov = G @ sigma @ G.T
    keep = X != 0  # zero there by definition: not a measurand
    names = [f"EXX@{x:g}" for x in X[keep]]
    return names, G[keep] @ rng.normal(size=3), cov[np.ix_(keep, keep)]


def test_simultaneous_band_covers_the_pointwise_one_and_is_wider():
    names, value, cov = _cubic_curve()
    u = np.sqrt(np.diag(cov))
    z = norm.ppf(0.975)
    low, high = value - z * u, value + z * u
    low[3] -= 0.2 * u[3]  # an asymmetric interval stays asymmetric, and held
    bands, factors = simultaneous_bands(names + ["EC0Y"], np.r_[value, 1.0],
                                        np.r_[low, 0.0], np.r_[high, 2.0],
                                        np.pad(cov, ((0, 1), (0, 1))) + np.diag(
                                            np.r_[np.zeros(len(names)), 0.25]), seed=3)
    assert set(bands) == set(names) and set(factors) == {"EXX"}  # EC0Y is no curve
    c = factors["EXX"]
    # wider than pointwise, narrower than Bonferroni over the points (they correlate)
    assert z < c < norm.ppf(1 - 0.025 / len(names))
    lo_s = np.array([bands[n][0] for n in names])
    hi_s = np.array([bands[n][1] for n in names])
    assert np.all(lo_s < low) and np.all(hi_s > high)
    np.testing.assert_allclose(hi_s - value, c / z * (high - value), rtol=1e-12)
    np.testing.assert_allclose(value - lo_s, c / z * (value - low), rtol=1e-12)


def test_simultaneous_band_holds_the_whole_curve_at_its_coverage():
    """Curves drawn from the points' covariance lie wholly inside value +- c u in 95 % of
    draws: 20 000 draws, standard error 0.0015; c's own Monte Carlo error (20 000 draws)
    moves the coverage by about as much: 5 combined standard errors."""
    _, _, cov = _cubic_curve()
    c = simultaneous_factor(cov, 0.95, seed=11, name="EXX")
    u = np.sqrt(np.diag(cov))
    w, v = np.linalg.eigh(cov)
    draws = np.random.default_rng(12).standard_normal((20_000, len(u))) @ (
        v * np.sqrt(np.clip(w, 0, None))).T
    inside = np.mean(np.all(np.abs(draws) <= c * u, axis=1))
    assert abs(inside - 0.95) < 5 * math.hypot(math.sqrt(0.95 * 0.05 / 20_000), 0.0015)
    pointwise = np.mean(np.all(np.abs(draws) <= norm.ppf(0.975) * u, axis=1))
    assert pointwise < 0.93  # the pointwise band does not hold the whole curve


def test_factor_is_seeded_and_pointwise_for_one_point():
    _, _, cov = _cubic_curve()
    assert simultaneous_factor(cov, seed=1, name="EXX") == simultaneous_factor(
        cov, seed=1, name="EXX")
    assert simultaneous_factor(cov[:1, :1], seed=1) == pytest.approx(norm.ppf(0.975))
    # fully correlated points are one point
    assert simultaneous_factor(np.ones((5, 5)), seed=1) == pytest.approx(norm.ppf(0.975),
                                                                           abs=0.01)
    lo, hi = widen(1.0, 0.0, 3.0, 2 * norm.ppf(0.975))
    assert (float(lo), float(hi)) == pytest.approx((-1.0, 5.0))


def test_curves_and_grids():
    got = curves(["EXX", "EXX@10", "EXX@-10", "EYY@5", "EC0Y", "EXX@1e+03"])
    assert list(got) == ["EXX", "EYY"]
    np.testing.assert_array_equal(got["EXX"][0], [2, 1, 5])
    np.testing.assert_array_equal(got["EXX"][1], [-10, 10, 1000])
    assert parse_grid("-50:50:25") == (-50, -25, 0, 25, 50)
    assert parse_grid("0:0.3:0.1") == (0, 0.1, 0.2, 0.3)
    for bad in ("1:2", "5:1:1", "0:10:0", "a:b:c"):
        with pytest.raises(ValueError, match="START:STOP:STEP"):
            parse_grid(bad)
    assert len(parse_grid("0:10000:1")) == 10001
    with pytest.raises(ValueError, match="at most 100 positions"):
        parse_grid("0:100:1", 100)


def test_estimate_json_and_csv_give_the_simultaneous_band():
    """A geometry21 result along the travel (the example of docs/compensation.md) as
    ``mtplan estimate --json`` and ``--out`` write it: simultaneous_low and _high on each
    point of a curve, null elsewhere, and each curve's factor."""
    import json
    from pathlib import Path
    from types import SimpleNamespace

    from mtplan import models
    from mtplan.evaluation.measured import MeasuredResult, _with_simultaneous
    from mtplan.models.protocol import make

    path = Path(__file__).resolve().parents[2] / "examples" / "compensation" / \
        "geometry21_result.json"
    doc = json.loads(path.read_text())
    proc = models.get("geometry21")
    setup = make(proc.Setup, {k: v for k, v in doc["setup"].items()
                              if k in proc.Setup.__dataclass_fields__}, owner="test")
    measurands = proc.measurands(setup)
    rows = {m["name"]: m for m in doc["measurands"]}
    names = doc["covariance"]["names"]
    assert names == [m.name for m in measurands]
    value = np.array([rows[n]["value"] for n in names], dtype=float)
    result = MeasuredResult(
        procedure=proc, estimator=doc["estimator"], uncertainty="mc", setup=setup,
        measurands=measurands, estimate=value, value=value,
        std=np.array([rows[n]["u"] for n in names], dtype=float),
        low=np.array([rows[n]["interval"][0] for n in names], dtype=float),
        high=np.array([rows[n]["interval"][1] for n in names], dtype=float),
        coverage=0.95, seed=0, details=SimpleNamespace(mc=SimpleNamespace(trials=400)),
        covariance=np.array(doc["covariance"]["matrix"], dtype=float))
    _with_simultaneous(result)
    out = result.to_dict()
    got = {m["name"]: m for m in out["measurands"]}
    assert got["EXX"]["simultaneous_low"] is None  # the function at +50 mm: no curve
    for name in ("EXX@-30", "EBX@50", "EZZ@10"):
        lo, hi = got[name]["interval"]
        assert got[name]["simultaneous_low"] < lo < hi < got[name]["simultaneous_high"]
    factors = out["simultaneous"]["factor"]
    assert set(factors) >= {"EXX", "EYY", "EZZ", "EBX"} and all(
        norm.ppf(0.975) < c < 4 for c in factors.values())
    csv = result.summary()
    assert {"simultaneous_low", "simultaneous_high"} <= set(csv.columns)
    assert csv.loc["EXX@-30", "simultaneous_low"] == got["EXX@-30"]["simultaneous_low"]
