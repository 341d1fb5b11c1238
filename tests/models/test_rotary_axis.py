"""Tests of the inclined-plane rotary-axis procedure (rotary_axis).

Order after lmfit's NIST habit: the forward model against an independent reference
first, then exact recovery of the truth, then the statistics (Monte Carlo against the
GUM/Fisher linearisation), then the claims the issue asks to show, then refusals.
Statistical tolerances: a standard deviation from N trials is checked to within
4/sqrt(2(N-1)) relative.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from mtplan._validate import InvalidInput
from mtplan.models import get
from mtplan.models import rotary_axis as ra
from mtplan.evaluation.simulation import linearize_procedure, simulate_uncertainty

PROC = get("rotary_axis")

CASES = {
    "C default": {},
    "C offset lattice, 3x4, ref 100": dict(lattice_offset_x_mm=35.0, lattice_offset_y_mm=-20.0,
                                           lattice_nx=3, lattice_ny=4, reference_height_mm=100.0),
    "C 3 uneven angles, incline 10": dict(angles_deg=(0.0, 40.0, 200.0), incline_deg=10.0),
    "C short arc, azimuth 30": dict(range_deg=120.0, positions=5, incline_azimuth_deg=30.0),
    "C Z fixed per lattice": dict(z_follows_surface=False, sensor_range_mm=25.0),
    "A default": dict(axis="A"),
    "A azimuth 150, ref -80": dict(axis="A", incline_azimuth_deg=150.0, reference_height_mm=-80.0),
    "A seed order, h 0": dict(axis="A", angles_deg=(0, 15, 30, 45, -15, -30, -45),
                              artifact_height_mm=0.0),
}
BIG_TRUTH = dict(EX0C_um=-400.0, EY0C_um=250.0, EA0C_urad=900.0, EB0C_urad=-700.0,
                 EY0A_um=300.0, EZ0A_um=-450.0, EB0A_urad=-800.0, EC0A_urad=600.0)


def _noise_free(setup, truth=None, **errors):
    err = PROC.zero_errors(setup, 1)
    for k, v in errors.items():
        err[k] = np.asarray(v, dtype=float)[None]
    return PROC.forward(setup, truth or PROC.Truth(), err)


# --------------------------------------------------------------------------- forward model
def _reference_heights(setup, truth, dtheta, tilt, radial, axial):
    """Heights by an independent route: scipy rotations and a ray-plane intersection."""
    g = ra._plan(setup)
    frame = ra._FRAMES[setup.axis]
    point, u = ra._true_line(setup, truth)
    out = np.empty((setup.n_positions, setup.n_points))
    for k, theta in enumerate(g.theta):
        rot = Rotation.from_rotvec(u * (theta + dtheta[k]))
        wob = Rotation.from_rotvec(tilt[k, 0] * frame.p1 + tilt[k, 1] * frame.p2)
        shift = radial[k, 0] * frame.p1 + radial[k, 1] * frame.p2 + axial[k] * frame.ax

        def move(p):
            return point + wob.apply(rot.apply(p - point)) + shift

        normal = wob.apply(rot.apply(np.array(g.n0)))
        q = move(np.array(g.q0))
        for j, (x, y) in enumerate(g.xy[k]):
            # ray (x, y, z) for all z meets the plane normal . (p - q) = 0
            out[k, j] = q[2] - (normal[0] * (x - q[0]) + normal[1] * (y - q[1])) / normal[2]
    return out


@pytest.mark.parametrize("case", ["C default", "A azimuth 150, ref -80"])
def test_forward_matches_an_independent_rigid_body_reference(case):
    setup = PROC.setup(**CASES[case])
    truth = PROC.truth(**BIG_TRUTH)
    rng = np.random.default_rng(7)
    P = setup.n_positions
    errs = dict(angular_positioning=rng.normal(0, 1e-3, P), tilt_motion=rng.normal(0, 1e-3, (P, 2)),
                radial_motion=rng.normal(0, 0.01, (P, 2)), axial_motion=rng.normal(0, 0.01, P))
    z = _noise_free(setup, truth, **errs)["z_mm"][0]
    ref = _reference_heights(setup, truth, errs["angular_positioning"], errs["tilt_motion"],
                             errs["radial_motion"], errs["axial_motion"])
    np.testing.assert_allclose(z, ref, rtol=0, atol=1e-11)


def test_nominal_readings_are_the_commanded_surface():
    # with a perfect axis, Z following the nominal surface reads exactly the command
    setup = PROC.Setup()
    zero = PROC.truth(EX0C_um=0, EY0C_um=0, EA0C_urad=0, EB0C_urad=0)
    z = _noise_free(setup, zero)["z_mm"][0]
    np.testing.assert_allclose(z, ra._plan(setup).z_cmd, rtol=0, atol=1e-12)


def test_sensor_sees_only_the_residual_when_z_follows():
    # a scale error of 10 % changes a following reading by 10 % of the residual (um),
    # a fixed-Z reading by 10 % of the lattice's height span (mm)
    truth = PROC.Truth()
    for follow, limit in ((True, 5e-3), (False, None)):
        setup = PROC.setup(z_follows_surface=follow, sensor_range_mm=25.0)
        base = _noise_free(setup, truth)["z_mm"]
        scaled = _noise_free(setup, truth, sensor_scale=0.1)["z_mm"]
        diff = np.max(np.abs(scaled - base))
        if follow:
            assert diff < limit
        else:
            span = np.ptp(ra._plan(setup).xy[0, :, 0]) * math.tan(math.radians(setup.incline_deg))
            assert diff > 0.1 * span / 2 * 0.9


# --------------------------------------------------------------------------- recovery
@pytest.mark.parametrize("estimator", ["patent", "joint"])
@pytest.mark.parametrize("case", list(CASES))
def test_noise_free_recovery(case, estimator):
    setup = PROC.setup(**CASES[case])
    truth = PROC.truth(**BIG_TRUTH)
    out = PROC.display_estimate(setup, _noise_free(setup, truth), estimator)
    for name, value in PROC.display_truth(setup, truth).items():
        np.testing.assert_allclose(out[name], value, rtol=0, atol=1e-6, err_msg=name)


def test_axis_line_is_the_true_line():
    setup = PROC.setup(axis="A", reference_height_mm=25.0)
    truth = PROC.Truth()
    point, direction = ra.axis_line(setup, _noise_free(setup, truth), estimator="joint")
    p_true, u_true = ra._true_line(setup, truth)
    np.testing.assert_allclose(point[0], p_true, atol=1e-12)
    np.testing.assert_allclose(direction[0], u_true, atol=1e-15)


def test_estimators_coincide_with_three_positions():
    # 3 planes: both solve the same square system exactly, noise or not
    setup = PROC.setup(positions=3)
    readings = PROC.simulate(setup, draws=50, rng=3)
    a = PROC.display_estimate(setup, readings, "patent")
    b = PROC.display_estimate(setup, readings, "joint")
    for name in a:
        np.testing.assert_allclose(a[name], b[name], rtol=0, atol=1e-6)


# --------------------------------------------------------------------------- statistics
@pytest.mark.parametrize("estimator", ["patent", "joint"])
@pytest.mark.parametrize("axis", ["C", "A"])
def test_monte_carlo_agrees_with_linearisation(axis, estimator):
    # every source at its default size: micrometres are small for this geometry
    setup = PROC.setup(axis=axis)
    n = 4000
    mc = simulate_uncertainty(PROC, setup, estimator=estimator, trials=n, rng=21, progress=False)
    gum = linearize_procedure(PROC, setup, estimator=estimator)
    tol = 4 / math.sqrt(2 * (n - 1))
    np.testing.assert_allclose(mc.mc.std, gum.std, rtol=tol)
    # unbiased to first order: the mean is within 4 sigma/sqrt(n) of the truth
    assert np.all(np.abs(mc.bias) < 4 * mc.mc.std / math.sqrt(n))


def test_probe_noise_alone_scales_linearly():
    setup = PROC.Setup()
    one = linearize_procedure(PROC, setup, sources=["probe_noise"]).std
    two = linearize_procedure(PROC, setup.replace(probe_noise_um=2.0), sources=["probe_noise"]).std
    np.testing.assert_allclose(two, 2 * one, rtol=1e-6)


def test_joint_is_never_worse_than_patent_for_reading_noise():
    # the joint fit is the maximum-likelihood estimate for independent reading errors,
    # so its linearised uncertainty is at most the patent's (equal within 1e-3 for C)
    for kw in ({}, dict(axis="A"), dict(axis="A", incline_azimuth_deg=60.0)):
        setup = PROC.setup(**kw)
        pat = linearize_procedure(PROC, setup, estimator="patent", sources=["probe_noise"]).std
        joint = linearize_procedure(PROC, setup, estimator="joint", sources=["probe_noise"]).std
        assert np.all(joint <= pat * (1 + 1e-6)), (kw, pat, joint)


def test_gls_recovers_what_the_joint_fit_loses_to_per_position_errors():
    # with every default source on, the per-position errors (error motions, Z positioning)
    # dominate and the joint fit's noise-only weighting makes it worse than the seed's
    # method; weighting by the whole error budget (gls) restores it (linearised, exact)
    setup = PROC.setup(axis="A", incline_azimuth_deg=60.0)
    u = {e: linearize_procedure(PROC, setup, estimator=e).std for e in ("patent", "joint", "gls")}
    assert np.all(u["gls"] <= u["joint"] * (1 + 1e-9))
    assert u["joint"][1] > 1.1 * u["gls"][1]  # EZ0A: the joint fit loses more than 10 %
    np.testing.assert_allclose(u["gls"], u["patent"], rtol=0.02)  # the seed's method is efficient


def test_lateral_position_worsens_with_a_small_incline():
    # a lateral shift d changes the heights by d tan(incline) only
    std = [linearize_procedure(PROC, PROC.setup(incline_deg=i), sources=["probe_noise"]).std[0]
           for i in (10.0, 20.0, 30.0)]
    assert std[0] > std[1] > std[2]


# --------------------------------------------------------------------------- claims
@pytest.mark.parametrize("axis", ["C", "A"])
def test_angular_positioning_error_does_not_change_the_result(axis):
    setup = PROC.setup(axis=axis)
    truth = PROC.truth(**BIG_TRUTH)
    P = setup.n_positions
    big = np.deg2rad(np.linspace(-1.0, 1.0, P))  # up to 1 deg, far beyond any real axis
    exact = PROC.display_truth(setup, truth)
    for est in PROC.estimators:
        out = PROC.display_estimate(setup, _noise_free(setup, truth, angular_positioning=big), est)
        for name, value in exact.items():
            np.testing.assert_allclose(out[name], value, rtol=0, atol=1e-6, err_msg=(est, name))
    # and in the Monte Carlo at the default +-5 arcsec: no spread at all
    res = simulate_uncertainty(PROC, setup, sources=["angular_positioning"], trials=200, rng=4,
                               progress=False)
    assert np.all(res.mc.std < 1e-6)


def test_axial_motion_appears_as_lateral_error_through_the_incline():
    # an axial shift of one plane moves it by d along Z, which the intersection reads as a
    # lateral shift of d / tan(incline): the std scales with 1 / tan(incline)
    std = {i: linearize_procedure(PROC, PROC.setup(incline_deg=i), sources=["axial_motion"]).std[0]
           for i in (15.0, 30.0)}
    ratio = math.tan(math.radians(30.0)) / math.tan(math.radians(15.0))
    np.testing.assert_allclose(std[15.0] / std[30.0], ratio, rtol=0.02)


# --------------------------------------------------------------------------- refusals
@pytest.mark.parametrize(
    "values, field",
    [
        (dict(axis="A", incline_azimuth_deg=90.0), "incline_azimuth_deg"),
        (dict(angles_deg=(0.0, 360.0, 720.0, 10.0)), "angles_deg"),
        (dict(angles_deg=(0.0, 10.0, 20.0), positions=4), "positions"),
        (dict(positions=2), "positions"),
        (dict(incline_deg=0.0), "incline_deg"),
        (dict(lattice_nx=1), "lattice_nx"),
        (dict(lattice_ny=1), "lattice_ny"),
        (dict(axis="A", range_deg=150.0), "steep"),
        (dict(z_follows_surface=False, sensor_range_mm=5.0), "sensor_range_mm"),
        (dict(axis="B"), "axis"),
    ],
)
def test_degenerate_setups_are_refused_with_a_reason(values, field):
    with pytest.raises(InvalidInput, match=field):
        PROC.setup(**values)


def test_unobservable_a_axis_message_says_why():
    with pytest.raises(InvalidInput, match="unobservable"):
        PROC.setup(axis="A", incline_azimuth_deg=270.0)


def test_wrong_readings_shape_is_refused():
    with pytest.raises(InvalidInput, match="z_mm"):
        PROC.estimate(PROC.Setup(), {"z_mm": np.zeros((2, 5, 25))})


# --------------------------------------------------------------------------- data
def _frame():
    setup = PROC.Setup()
    return setup, PROC.readings_frame(setup, PROC.simulate(setup, draws=2, rng=1))


def test_from_frame_accepts_any_row_order():
    setup, df = _frame()
    back = PROC.from_frame(setup, df.sample(frac=1.0, random_state=0))
    np.testing.assert_array_equal(back["z_mm"][0].ravel(), df["z_mm"].to_numpy())


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda df: df.drop(columns="z_mm"), "z_mm"),
        (lambda df: df.assign(z_mm=df["z_mm"].where(df.index != 7)), "row 7"),
        (lambda df: df.assign(x_mm=df["x_mm"] + (df.index == 3) * 0.5), "x_mm"),
        (lambda df: df.iloc[1:], "rows"),
        (lambda df: pd.concat([df.iloc[:1], df.iloc[:-1]], ignore_index=True), "appears 2 times"),
        (lambda df: df.assign(position=df["position"] + (df.index == 0) * 9), "position"),
    ],
)
def test_from_frame_names_what_is_wrong(edit, message):
    setup, df = _frame()
    with pytest.raises(InvalidInput, match=message):
        PROC.from_frame(setup, edit(df))


def test_schedule_and_duration():
    setup = PROC.Setup()
    sched = ra.schedule(setup)
    assert len(sched) == setup.n_positions * setup.n_points
    assert np.all(np.diff(sched["time_s"]) > 0)
    assert PROC.duration(setup) == pytest.approx(sched["time_s"].iloc[-1])
    # more positions cost more time
    assert PROC.duration(setup.replace(positions=12)) > PROC.duration(setup)
