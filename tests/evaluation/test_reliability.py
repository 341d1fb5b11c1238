"""What one bad reading can do unseen (mtplan.evaluation.reliability): the minimal
detectable bias against a Monte Carlo of the fit check's detection rate, and the external
reliability against the estimator run again with the bias added."""

import numpy as np
import pytest
from scipy import stats

from mtplan.evaluation import posterior as post
from mtplan.evaluation._posterior_model import Forward, TruthBuilder, truth_parameters
from mtplan.evaluation.fitcheck import (FIT_ALPHA, MDB_POWER, W_SHARE, reading_vector,
                                        w_limit, with_reading_vector)
from mtplan.evaluation.reliability import design_readings, reliability
from mtplan.models import get

N_MC = 20_000


def _dense_design(proc, setup, readings):
    """The fit check's whitened design rebuilt densely: the whitening W of the readings'
    covariance, the residual projector R of the whitened observations (readings and the
    nuisance priors' pseudo-readings) and the residual degrees of freedom."""
    base = proc.Truth()
    builder = TruthBuilder(base, truth_parameters(proc, base))
    fwd = Forward(proc, setup, readings, builder)
    theta0 = post.initial_theta(proc, setup, readings, builder, None, None, [])
    fit = post.start_fit(fwd, theta0, "setup", None, [])
    g = fit.error_model.gaussian(fit.sigma)
    pri = post.nuisance_priors(fit.error_model)
    n, p, q = fwd.n, fit.theta.size, pri.shape[0]
    J = fwd.jacobian(fit.theta, fit.nuis if q else None,
                     np.concatenate([builder.steps(fit.theta), 1e-3 * pri[:, 1]]))
    W = g.whiten(np.eye(n)).T  # W x = whiten(x): W^T W = C^-1
    A = W @ J
    if q:
        A = np.vstack([A, np.hstack([np.zeros((q, p)), np.diag(1.0 / pri[:, 1])])])
    U, s, _ = np.linalg.svd(A, full_matrices=False)
    U = U[:, s > 1e-4 * s[0]]
    R = np.eye(n + q) - U @ U.T
    Wt = np.vstack([W, np.zeros((q, n))])
    return Wt, R, n + q - U.shape[1]


#: bound of the stated MDB's own Monte Carlo error in its flag probability (the
#: detectability module's draws; about 0.0013-0.0022 on circle_centre)
SE_STATED = 0.003


def test_mdb_is_detected_with_its_power_in_a_monte_carlo():
    """circle_centre: an error of its stated MDB, on every single reading and as every bad
    contact (along its probing direction), drawn over the whitened linear design with
    Gaussian noise, is flagged by the whole check (any w beyond its Bonferroni limit, or
    the chi-square beyond its own) in 0.80 of the draws; clean readings in at most alpha.
    The design is rebuilt densely and the check applied draw by draw, independently of the
    detectability module's algebra. Tolerance: 4 standard errors of the N_MC draws and of
    the stated MDB's own Monte Carlo."""
    proc = get("circle_centre")
    setup, truth = proc.Setup(), proc.Truth()
    readings = design_readings(proc, setup, truth)
    rel = reliability(proc, setup, truth, readings=readings)
    Wt, R, dof = _dense_design(proc, setup, readings)
    P = Wt.T @ R @ Wt
    sd = np.sqrt(np.diag(P))
    crit = w_limit(W_SHARE * FIT_ALPHA, P.shape[0])
    limit = stats.chi2.isf((1 - W_SHARE) * FIT_ALPHA, dof)
    u = np.random.default_rng(20261207).standard_normal((N_MC, Wt.shape[0]))
    tol = 4 * np.sqrt(MDB_POWER * (1 - MDB_POWER) / N_MC + SE_STATED**2)

    def flagged(error):
        rho = (u + Wt @ error) @ R
        w = (rho @ Wt) / sd
        return (np.sum(rho**2, axis=1) > limit) | np.any(np.abs(w) > crit, axis=1)

    assert np.all(np.isfinite(rel.sizes))
    for j in range(rel.sizes.size):
        rate = flagged(rel.sizes[j] * rel.effect(j)).mean()
        assert abs(rate - MDB_POWER) < tol, (j, rate)
    n = rel.mdb_values.size
    clean = flagged(np.zeros(n))
    assert clean.mean() < FIT_ALPHA + 4 * np.sqrt(FIT_ALPHA * (1 - FIT_ALPHA) / N_MC)


def test_large_designs_approximation_is_within_a_percent_of_the_joint_law(monkeypatch):
    """rotary_axis (150 readings): the large designs' MDB (every other reading's w clean and
    independent) against the check's whole joint law (taken with fewer draws here): within
    1 % (they differ by about 0.3 %)."""
    from mtplan.evaluation import detectability

    proc = get("rotary_axis")
    setup = proc.Setup()
    large = reliability(proc, setup).sizes
    monkeypatch.setattr(detectability, "EXACT_READINGS", 10_000)
    monkeypatch.setattr(detectability, "N_DRAWS", 1024)
    whole = reliability(proc, setup).sizes
    np.testing.assert_allclose(large, whole, rtol=0.01)


@pytest.mark.parametrize("name", ["rotary_axis", "circle_centre"])
def test_external_reliability_is_the_estimators_response(name):
    """The largest undetected shift of each measurand is what the estimator, run again with
    the worst gross error of MDB size added (and taken away), gives: the central difference
    to 1e-6 (the estimator's linear response), either sign alone to its second-order
    term. circle_centre's worst is a bad contact, moving two readings."""
    proc = get(name)
    setup, truth = proc.Setup(), proc.Truth()
    readings = design_readings(proc, setup, truth)
    rel = reliability(proc, setup, truth, readings=readings)
    keys, vec = reading_vector(readings)
    est = proc.estimators[proc.default_estimator]
    names = [m.name for m in proc.measurands(setup)]
    scale = {m.name: m.scale for m in proc.measurands(setup)}

    def estimate(v, m):
        out = est(setup, with_reading_vector(readings, keys, v))
        return float(np.asarray(out[m]).reshape(-1)[0]) * scale[m]

    for k, m in enumerate(names):
        row = rel.measurands[m]
        j = int(np.argmax(np.abs(rel.moved()[k]) * rel.sizes))
        error = rel.sizes[j] * rel.effect(j)
        plus, minus, zero = estimate(vec + error, m), estimate(vec - error, m), estimate(vec, m)
        assert abs((plus - minus) / 2) == pytest.approx(row["shift"], rel=1e-6)
        assert abs(plus - zero) == pytest.approx(row["shift"], rel=1e-3)
        assert row["mdb"] == pytest.approx(rel.sizes[j] * 1e3, rel=1e-12)
        assert row["in_u"] is None and row["u"] is None  # no u given
    if name == "circle_centre":
        assert rel.measurands["centre_x"]["at"].startswith("contact d")


def test_json_names_every_measurand_and_reading_array():
    """The linearize document's section: an MDB per reading array in its display unit,
    each measurand's shift in its own unit and in units of its u."""
    from mtplan.evaluation.simulation import linearize_result

    res = linearize_result("tracker_frame")
    doc = res.to_dict()["reliability"]
    assert {m["readings"]: m["unit"] for m in doc["mdb"]} == {
        "distance_mm": "um", "azimuth_rad": "urad", "elevation_rad": "urad"}
    assert set(doc["measurands"]) == {m.name for m in res.measurands}
    for name, row in doc["measurands"].items():
        u = float(res.u[[m.name for m in res.measurands].index(name)])
        assert row["in_u"] == pytest.approx(row["shift"] / u, rel=1e-12)
    assert doc["n_tested"] == doc["n_readings"] == 294 and not doc["unchecked"]


def test_an_error_no_test_sees_is_null_in_the_json_and_without_limit_in_words():
    """An error the fit absorbs whole has no MDB (inf) and moves a measurand without limit:
    the JSON writes null, never Infinity, and the text says so."""
    import json

    from mtplan.evaluation.reliability import Reliability

    inf = float("inf")
    rel = Reliability(alpha=0.05, w_critical=2.9, n_readings=4, n_tested=3,
                      mdb=[{"readings": "x_mm", "unit": "um", "largest": inf, "at": "row 3 x_mm",
                            "smallest": 1.5, "median": 2.0, "undetectable": 1}],
                      unchecked=["row 3 x_mm"],
                      measurands={"centre_x": {"shift": inf, "unit": "um", "u": 2.0,
                                               "in_u": inf, "at": "row 3 x_mm", "mdb": inf,
                                               "mdb_unit": "um"}})
    doc = json.loads(json.dumps(rel.to_dict(), allow_nan=False))
    assert doc["mdb"][0]["largest"] is None and doc["mdb"][0]["smallest"] == 1.5
    assert doc["measurands"]["centre_x"]["shift"] is None
    assert doc["measurands"]["centre_x"]["mdb"] is None
    assert "centre_x without limit (row 3 x_mm has no test)" in " ".join(rel.lines())


@pytest.mark.parametrize("estimator", ["patent", "pattern"])
def test_line_laser_response_is_its_estimators_closed_form_map(estimator):
    """line_laser's response to one reading comes from its derivative hook (the readings'
    own noise source adds itself to each reading; 15 600 readings would otherwise take
    31 200 runs of the estimator): on 40 readings drawn at random and on the worst
    reading of each measurand it is the estimator's own central difference, to 1e-4 of the
    measurand's largest response (the closed form's agreement with the secants)."""
    from mtplan.evaluation import reliability as rel_module

    proc = get("line_laser")
    setup, truth = proc.setup({"lines": 16, "step_mm": 0.25}), proc.Truth()
    readings = design_readings(proc, setup, truth)
    rel = reliability(proc, setup, truth, readings=readings, estimator=estimator)
    used = np.isfinite(reading_vector(readings)[1])
    mapped = rel_module._mapped_response(proc, setup, truth, estimator,
                                         tuple(proc.measurands(setup)), used)
    assert mapped is not None and np.array_equal(mapped, rel.response)
    keys, vec = reading_vector(readings)
    est, ms = proc.estimators[estimator], list(proc.measurands(setup))
    worst = [int(np.argmax(np.abs(row) * np.where(np.isfinite(rel.sizes), rel.sizes, 0)))
             for row in rel.response]
    cols = np.unique(np.concatenate([np.random.default_rng(5).choice(vec.size, 40, False),
                                     worst]))
    step = 1e-6  # mm: far below any reading's scatter, far above round-off
    rows = np.repeat(vec[None, :], 2 * cols.size, axis=0)
    rows[np.arange(cols.size), cols] += step
    rows[cols.size + np.arange(cols.size), cols] -= step
    batch = {k: np.repeat(np.asarray(v), rows.shape[0], axis=0) for k, v in readings.items()}
    batch[keys[0]] = rows.reshape((rows.shape[0], *np.asarray(readings[keys[0]]).shape[1:]))
    out = est(setup, batch)
    for k, m in enumerate(ms):
        values = np.asarray(out[m.name], dtype=float).reshape(-1) * m.scale
        secant = (values[:cols.size] - values[cols.size:]) / (2 * step)
        largest = np.max(np.abs(rel.response[k]))
        np.testing.assert_allclose(rel.response[k, cols], secant, rtol=0,
                                   atol=1e-4 * largest + 1e-12, err_msg=m.name)


def test_a_quantised_measurand_is_not_said_to_move_by_zero():
    """line_laser's patent alpha_z comes in steps (no first-order response to any reading):
    the text says so, not 'moves alpha_z by up to 0 urad'."""
    proc = get("line_laser")
    setup = proc.setup({"lines": 16, "step_mm": 0.25})
    rel = reliability(proc, setup, estimator="patent")
    assert rel.measurands["alpha_z"]["shift"] == 0.0
    text = " ".join(rel.lines())
    assert "alpha_z not at first order" in text and "alpha_z by up to 0 " not in text
