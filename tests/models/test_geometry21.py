"""Tests of the geometry21 procedure: kinematics, identifiability, noise-free recovery,
large-error bias of the stepwise (patent) method, and Monte Carlo against linearisation."""

from __future__ import annotations

import numpy as np
import pytest

from mtplan._validate import InvalidInput
from mtplan.models import geometry21 as g21
from mtplan.models._kinematics import rotate, rotate_inverse, rotation_matrix
from mtplan.evaluation.simulation import linearize_procedure, simulate_uncertainty

P = g21.PROCEDURE
SMALL = dict(poly_order=2, line_points=5, line_repeats=1, circle_points=12)


# ----------------------------------------------------------------- forward model
def test_rotate_matches_matrix_and_inverse():
    rng = np.random.default_rng(0)
    for _ in range(5):
        a, b, c = rng.normal(size=3)
        v = rng.normal(size=3)
        np.testing.assert_allclose(rotate(a, b, c, v), rotation_matrix(a, b, c) @ v, atol=1e-14)
        np.testing.assert_allclose(rotate_inverse(a, b, c, rotate(a, b, c, v)), v, atol=1e-14)


def test_zero_errors_give_nominal_readings():
    setup = g21.Setup()
    zero = {k: () for k in g21.NAMES if g21._KIND[k] != "sq"}
    truth = g21.Truth(**{f"{k}_{'urad' if g21._KIND[k] == 'ang' else 'um'}": v
                         for k, v in zero.items()}, EC0Y_urad=0, EB0Z_urad=0, EA0Z_urad=0)
    r = P.forward(setup, truth, P.zero_errors(setup, 1))["plate_mm"][0]
    np.testing.assert_allclose(r, g21._geometry(setup).local, atol=1e-12)


@pytest.mark.parametrize("name, plane, comp, lever", [
    ("ECX", 0, 0, lambda c: -c[:, 1]),   # yaw of X, lever y, seen along x in XY
    ("EBX", 1, 0, lambda c: c[:, 2]),    # pitch of X, lever z, seen along x in XZ
    ("EAY", 2, 0, lambda c: -c[:, 2]),   # pitch of Y, lever z, seen along y in YZ
])
def test_jacobian_is_the_first_order_lever_arm(name, plane, comp, lever):
    """The numerical first-order expansion (used for Q) equals eps x lever arm."""
    setup = g21.Setup()
    ji = g21._joint_ident(setup)
    geo = ji["geo"]
    col = geo.layout[name][1].start  # power 1
    sel = geo.plane == plane
    j = ji["jac"].reshape(-1, 2, geo.n_par)[sel, comp, col]
    axis = g21._AXIS[name]
    c = geo.cmd[sel]
    np.testing.assert_allclose(j, lever(c) * c[:, axis], atol=1e-6)


# ----------------------------------------------------------------- identifiability
EXPECTED_JOINT = {
    **{n: "identified" for n in ("EXX", "EYY", "EZZ", "EYX", "EZX", "EXY", "EZY", "EXZ", "EYZ",
                                 "EBX", "ECX", "EAY", "EC0Y", "EB0Z", "EA0Z")},
    "EAX": "unidentifiable",
    **{n: "no effect" for n in ("EBY", "ECY", "EAZ", "EBZ", "ECZ")},
}


def test_identifiability_table_default():
    setup = g21.Setup()
    rep = g21.identifiability_report(setup)
    assert rep["rank"] == 42 and rep["parameters"] == 60
    assert 1e3 < rep["condition_number"] < 1e4
    assert len(rep["null_space"]) == 18
    for est in ("joint", "patent"):
        tab = g21.identifiability(setup, est)
        assert tab["status"].to_dict() == EXPECTED_JOINT
    assert "mounting" in g21.identifiability(setup)["confounded_with"]["EAX"]
    listed = [m.name for m in P.measurands(setup)]
    assert listed == [n for n in g21.NAMES if EXPECTED_JOINT[n] == "identified"]


def test_spindle_reference_makes_z_tilts_unidentifiable_and_biases_patent():
    setup = g21.Setup(reference_tool_mm=0.0)
    joint = g21.identifiability(setup, "joint")["status"]
    assert joint["EBZ"] == joint["EXZ"] == joint["EB0Z"] == "unidentifiable"
    pat = g21.identifiability(setup, "patent")
    assert pat.loc["EXX", "status"] == "biased" and pat.loc["EXX", "confounded_with"] == "EBX"
    # EXX - L EBX: a typical 10 urad EBX times L = 100 mm is 1 um
    assert pat.loc["EXX", "first_order_bias"] == pytest.approx(1.0, rel=1e-4)


def test_unlisted_measurands_are_never_reported():
    setup = g21.Setup()
    out = P.estimate(setup, P.simulate(setup, draws=2, rng=3), "patent")
    assert set(out) == {m.name for m in P.measurands(setup)}
    assert "EAX" not in out and "ECZ" not in out


# ----------------------------------------------------------------- noise-free recovery
def _errors(setup, truth, est):
    readings = P.forward(setup, truth, P.zero_errors(setup, 1))
    out = P.display_estimate(setup, readings, est)
    tv = P.display_truth(setup, truth)
    return {k: out[k][0] - tv[k] for k in tv}


@pytest.mark.parametrize("scale", [1.0, 10.0, 100.0])
def test_joint_is_exact_even_for_large_errors(scale):
    setup = g21.Setup()
    err = _errors(setup, g21.Truth(angular_scale=scale), "joint")
    assert max(abs(v) for v in err.values()) < 1e-6


def test_first_order_estimators_and_large_error_bias():
    """patent and joint_linear are exact to first order: error grows ~ scale**2."""
    setup = g21.Setup()
    e1 = _errors(setup, g21.Truth(), "patent")
    e100 = _errors(setup, g21.Truth(angular_scale=100.0), "patent")
    assert max(abs(v) for v in e1.values()) < 0.01          # first-order residue, um/urad
    assert abs(e100["EA0Z"]) > 1.0                             # 2 mrad errors: ~5 urad bias
    assert e100["EA0Z"] == pytest.approx(-4.958, abs=0.01)
    assert abs(e100["EBX"]) > 0.3
    # translational errors from the lines are unaffected by angular size (exact)
    for name in ("EXX", "EYX", "EZX", "EXY", "EXZ"):
        assert abs(e100[name]) < 1e-6
    lin = _errors(setup, g21.Truth(angular_scale=100.0), "joint_linear")
    assert abs(lin["EA0Z"]) > 1.0


def test_hidden_angular_errors_act_only_at_second_order():
    setup = g21.Setup()
    err = _errors(setup, g21.Truth(**g21.HIDDEN_ANGULAR), "joint")
    worst = max(abs(v) for v in err.values())
    assert 1e-6 < worst < 1e-3


# ----------------------------------------------------------------- set-up and data
def test_refusals_say_why():
    with pytest.raises(InvalidInput, match="line_points.*poly_order"):
        g21.Setup(line_points=4, poly_order=3)
    with pytest.raises(InvalidInput, match="circle_radius_mm"):
        g21.Setup(circle_radius_mm=80.0)


def test_from_frame_names_bad_column_and_row():
    setup = g21.Setup(**SMALL)
    df = P.readings_frame(setup, P.simulate(setup, draws=1, rng=1))
    with pytest.raises(InvalidInput, match="u_mm"):
        P.from_frame(setup, df.drop(columns="u_mm"))
    bad = df.copy()
    bad.loc[7, "v_mm"] = np.nan
    with pytest.raises(InvalidInput, match="row 7"):
        P.from_frame(setup, bad)


def test_duration_counts_three_setups_and_moves():
    setup = g21.Setup()
    moves = 3 * (2 * 5 * 2 * 100 + 2 * (100 + 2 * np.pi * 50)) / (500 / 60)
    assert P.duration(setup) == pytest.approx(3 * 1200 + moves)


# ----------------------------------------------------------------- uncertainty
@pytest.mark.parametrize("est", ["joint", "patent"])
def test_monte_carlo_agrees_with_linearisation_at_small_noise(est):
    setup = g21.Setup(**SMALL, encoder_noise_um=0.01, grid_error_um=0.05, plate_offset_mm=0.005,
                      plate_tilt_urad=10.0)
    n = 2000
    mc = simulate_uncertainty(P, setup, estimator=est, trials=n, rng=5, progress=False)
    gum = linearize_procedure(P, setup, estimator=est)
    tol = 4 / np.sqrt(2 * (n - 1))
    np.testing.assert_allclose(mc.mc.std, gum.std, rtol=tol)


def test_error_bands_agree_with_monte_carlo():
    setup = g21.Setup(**SMALL)
    n = 1500
    mc = simulate_uncertainty(P, setup, estimator="joint", trials=n, rng=9, progress=False)
    bands = g21.error_bands(setup, estimator="joint", positions=3)
    end = bands[(bands.position_mm == 50.0) | (bands.function.isin(["EC0Y", "EB0Z", "EA0Z"]))]
    end = end.set_index("function")["std"]
    names = [m.name for m in mc.measurands]
    np.testing.assert_allclose(mc.mc.std, end[names].to_numpy(), rtol=4 / np.sqrt(2 * (n - 1)))
    # an unidentifiable function has an infinite band, never NaN
    eax = bands[(bands.function == "EAX") & (bands.position_mm != 0)]
    assert np.isinf(eax["std"]).all()  # (at u = 0 every function is 0 by definition)
    assert not bands["std"].isna().any()


def test_coefficients_and_covariance_shapes():
    setup = g21.Setup(**SMALL)
    coefs = g21.coefficients(setup, P.simulate(setup, draws=3, rng=0), estimator="patent")
    assert coefs["EBX"][1].shape == (3, 2) and coefs["EBX"][0] == (1, 2)
    names, cov = g21.coefficient_covariance(setup)
    assert cov.shape == (len(names), len(names)) and "EBX[2]" in names
