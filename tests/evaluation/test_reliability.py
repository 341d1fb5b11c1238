"""What one bad reading can do unseen (mtplan.evaluation.reliability): the minimal
detectable bias against a Monte Carlo of the fit check's detection rate, and the external
reliability against the estimator run again with the bias added."""

import numpy as np
import pytest
from scipy import optimize, special, stats

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


def test_mdb_is_detected_with_its_power_in_a_monte_carlo():
    """circle_centre: an error of its MDB, on the worst single reading or as the worst bad
    contact (along its probing direction), drawn over the whitened linear design with
    Gaussian noise, is flagged by the test it is stated for (the w of the reading it moves
    most, or the chi-square, whichever flags the smaller error) in 0.80 of the draws and by
    the whole check (any w beyond the limit, or the chi-square) in 0.80-0.90; clean
    readings in at most alpha. Tolerance: 4 binomial standard errors of N_MC draws."""
    proc = get("circle_centre")
    setup, truth = proc.Setup(), proc.Truth()
    readings = design_readings(proc, setup, truth)
    rel = reliability(proc, setup, truth, readings=readings)
    Wt, R, dof = _dense_design(proc, setup, readings)
    P = Wt.T @ R @ Wt
    sd = np.sqrt(np.diag(P))
    crit = w_limit(W_SHARE * FIT_ALPHA, P.shape[0])
    # the MDBs from the dense design, independent of the check's sparse algebra: of each
    # reading and of each error the procedure declares, by the w it moves most or by the
    # chi-square (its non-centrality from scipy.stats' noncentral chi-square)
    lam0 = optimize.brentq(lambda lam: stats.ncx2.sf(stats.chi2.isf(
        (1 - W_SHARE) * FIT_ALPHA, dof), dof, lam) - MDB_POWER, 1e-3, 1e3)
    PE = P @ rel.effects
    by_w = (crit + stats.norm.ppf(MDB_POWER)) / np.max(np.abs(PE) / sd[:, None], axis=0)
    by_chi2 = np.sqrt(lam0 / np.sum(rel.effects * PE, axis=0))
    np.testing.assert_allclose(rel.sizes, np.minimum(by_w, by_chi2), rtol=1e-6)
    u = np.random.default_rng(20261207).standard_normal((N_MC, Wt.shape[0]))
    se = 4 * np.sqrt(MDB_POWER * (1 - MDB_POWER) / N_MC)

    def flagged(error):
        rho = (u + Wt @ error) @ R
        w = (rho @ Wt) / sd
        chi2 = special.chdtrc(dof, np.sum(rho**2, axis=1)) < (1 - W_SHARE) * FIT_ALPHA
        return np.abs(w) > crit, chi2, chi2 | np.any(np.abs(w) > crit, axis=1)

    n = rel.mdb_values.size
    for j in (int(np.argmax(rel.sizes[:n])), n + int(np.argmax(rel.sizes[n:]))):
        error = rel.sizes[j] * rel.effects[:, j]
        each, chi2, whole = flagged(error)
        stated = chi2 if by_chi2[j] < by_w[j] else each[:, np.argmax(np.abs(P @ error) / sd)]
        assert abs(stated.mean() - MDB_POWER) < se, j
        assert MDB_POWER - se < whole.mean() < 0.9, (j, whole.mean())
    _, _, clean = flagged(np.zeros(n))
    assert clean.mean() < FIT_ALPHA + 4 * np.sqrt(FIT_ALPHA * (1 - FIT_ALPHA) / N_MC)


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
        j = int(np.argmax(np.abs(rel.response[k] @ rel.effects) * rel.sizes))
        error = rel.sizes[j] * rel.effects[:, j]
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
