"""tracker_frame: forward model checked first, then the estimators (patent, angles).

Forward model against hand-computed readings and geometry; the true values against
cases whose frame is known without the construction; noise-free recovery over
several set-ups; Monte Carlo against the GUM linearisation at small noise with
tolerances from the Monte Carlo error; degenerate set-ups refused; the readings
table round trip and its errors; the rotary positioning error leaves patent alone;
angles beats patent on the origin and A-C offset at short A arcs.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mtplan._validate import InvalidInput
from mtplan.models import get
from mtplan.models import tracker_frame as tf
from mtplan.models.tracker_frame import _estimators as tf_estimators
from mtplan.models.tracker_frame import _geometry as tf_geometry
from mtplan.models.tracker_frame import _layout as tf_layout
from mtplan.models.tracker_frame import _physics as tf_physics
from mtplan.fitting.fit3d import circle_residuals, fit_circle_3d
from mtplan.evaluation.first_order import first_order
from mtplan.evaluation.simulation import linearize_procedure, simulate_uncertainty
from tests.models.first_order_check import assert_chain_rule_is_the_linearisation as _assert_chain_rule_is_the_linearisation  # noqa: E501

PROC = get("tracker_frame")

ZERO_HEAD = dict(wrist_dx_um=(0.0,), wrist_dy_um=(0.0,), wrist_dz_um=(0.0,),
                 frame_rx_urad=(0.0,), frame_ry_urad=(0.0,), frame_rz_urad=(0.0,),
                 sq_xy_urad=(0.0,), sq_yz_urad=(0.0,), sq_zx_urad=(0.0,),
                 c_tilt_x_urad=(0.0,), c_tilt_y_urad=(0.0,), a_tilt_y_urad=(0.0,),
                 a_tilt_z_urad=(0.0,), ac_offset_um=(0.0,))

NOISE_FIELDS = ("distance_fixed_um", "distance_per_length_um_per_m", "transverse_fixed_um",
                "transverse_per_length_um_per_m", "machine_repeatability_um",
                "rotary_positioning_arcsec", "angular_systematic_um_per_m", "smr_centring_um",
                "air_refraction_ppm", "thermal_drift_um_per_s", "straightness_um")
ESTIMATORS = list(PROC.estimators)


def _noise_free(setup, truth):
    return PROC.forward(setup, truth, PROC.zero_errors(setup, 1))


# --------------------------------------------------------------------------- forward
def test_forward_marks_match_hand_computed_spherical_coordinates():
    setup = PROC.Setup()
    truth = PROC.Truth(tracker_tilt_x_urad=0.0, tracker_tilt_y_urad=0.0, tracker_yaw_deg=30.0)
    r = _noise_free(setup, truth)
    tracker = np.array([-setup.tracker_distance_mm, 0.0, setup.tracker_height_mm])
    for i, mark in enumerate(tf_layout.bed_marks(setup)):
        v = mark - tracker
        assert r["distance_mm"][0, i] == pytest.approx(np.linalg.norm(v), abs=1e-9)
        az = math.atan2(v[1], v[0]) - math.radians(30.0)
        daz = math.remainder(r["azimuth_rad"][0, i] - az, 2 * math.pi)
        assert daz == pytest.approx(0, abs=1e-14)
        el = math.atan2(v[2], math.hypot(v[0], v[1]))
        assert r["elevation_rad"][0, i] == pytest.approx(el, abs=1e-14)


def test_forward_geometry_of_the_machine_points():
    setup = PROC.Setup()
    truth = PROC.Truth()
    pts = tf_physics._machine_points(setup, truth)
    sl = tf_layout.slices(setup)
    h = tf_physics._head(setup, truth, 0)
    # linear travel: evenly spaced along the true X direction, total length = travel
    x = pts[sl[("X", 1)].start - 4: sl[("X", 1)].stop - 4]
    steps = np.diff(x, axis=0)
    np.testing.assert_allclose(steps, np.full_like(steps, setup.travel_x_mm / 10) * h.axes[0],
                               atol=1e-11)
    # C arc: constant distance r from the true C line, in a plane normal to it
    c = pts[sl[("C", 1)].start - 4: sl[("C", 1)].stop - 4]
    q = c - h.wrist
    along = q @ h.c_dir
    radial = np.linalg.norm(q - np.outer(along, h.c_dir), axis=1)
    np.testing.assert_allclose(radial, setup.reflector_offset_mm, atol=1e-11)
    np.testing.assert_allclose(along, along[0], atol=1e-11)
    # successive C-arc points are one angular step apart
    w = q - np.outer(along, h.c_dir)
    cosang = np.sum(w[1:] * w[:-1], axis=1) / radial[0] ** 2
    step = setup.c_arc_deg / (setup.points_per_arc - 1)
    np.testing.assert_allclose(np.degrees(np.arccos(cosang)), step, atol=1e-6)
    # the wrist centre is the foot of the common perpendicular; the offset is the truth's
    assert abs((h.a_point - h.wrist) @ h.a_dir) < 1e-15
    assert (h.a_point - h.wrist) @ h.perp == pytest.approx(truth.ac_offset_um[0] * 1e-3, abs=1e-12)


def test_noise_enters_readings_as_specified():
    # one trial with unit errors in each source, checked against the spherical model
    setup = PROC.Setup()
    truth = PROC.Truth()
    base = _noise_free(setup, truth)
    errs = PROC.zero_errors(setup, 1)
    errs["distance_fixed"][:] = 1e-3
    errs["distance_per_length"][:] = 2e-6
    errs["transverse_fixed"][..., 1] = 5e-3
    r = PROC.forward(setup, truth, errs)
    d0 = base["distance_mm"][0]
    np.testing.assert_allclose(r["distance_mm"][0] - d0, 1e-3 + 2e-6 * d0, rtol=1e-7)
    np.testing.assert_allclose(r["elevation_rad"][0] - base["elevation_rad"][0], 5e-3 / d0,
                               rtol=1e-7)
    np.testing.assert_array_equal(r["azimuth_rad"], base["azimuth_rad"])


def test_rotary_positioning_error_moves_the_reflector_round_the_axis():
    # the actual angle is the commanded one plus the error: the A point moves round the
    # true A line by that angle; the linear points and the marks do not move
    setup = PROC.Setup()
    truth = PROC.Truth()
    q = setup.points_per_arc
    err = np.zeros((1, 2 * setup.n_submachines * q))
    err[0, q + 2] = 1e-3  # sub-machine 1, A arc, third point
    moved = tf_physics._machine_points(setup, truth, err)[0]
    base = tf_physics._machine_points(setup, truth)
    changed = np.flatnonzero(np.any(moved != base, axis=1))
    sl = tf_layout.slices(setup)
    assert changed.tolist() == [sl[("A", 1)].start + 2 - 4]
    h = tf_physics._head(setup, truth, 0)
    a_ang = np.radians(tf_layout.arc_angles(setup.a_arc_deg, q)[2]) + 1e-3
    expect = h.a_point + tf_geometry.rot(h.a_dir, a_ang) @ (h.reflector - h.a_point)
    np.testing.assert_allclose(moved[changed[0]], expect, atol=1e-12)
    assert PROC.sources(setup)["rotary_positioning"].distribution.std == pytest.approx(
        5 * math.pi / 648000)


def test_new_sources_enter_readings_as_specified():
    # SMR centring: along the beam a distance, across it a transverse length; air: a
    # scale of every distance; drift: every point moves by rate x its time
    setup = PROC.Setup()
    truth = PROC.Truth()
    base = _noise_free(setup, truth)
    d0, el0 = base["distance_mm"][0], base["elevation_rad"][0]
    errs = PROC.zero_errors(setup, 1)
    errs["smr_centring"][..., 0] = 2e-3
    errs["smr_centring"][..., 2] = 3e-3
    errs["air_refraction"][:] = 1e-6
    r = PROC.forward(setup, truth, errs)
    np.testing.assert_allclose(r["distance_mm"][0] - d0, 1e-6 * d0 + 2e-3, rtol=1e-6)
    np.testing.assert_allclose(r["elevation_rad"][0] - el0, 3e-3 / d0, rtol=1e-7)
    errs = PROC.zero_errors(setup, 1)
    errs["thermal_drift"][0] = (0.0, 0.0, 1e-5)  # 10 nm/s up
    times, total = tf_layout.reading_times(setup)
    assert total == PROC.duration(setup) and np.all(np.diff(times) > 0)
    cartesian = tf_estimators._cartesian
    moved = cartesian(PROC.forward(setup, truth, errs)) - cartesian(base)
    r_tr, _ = tf_physics._tracker_pose(setup, truth)
    np.testing.assert_allclose(moved[0] @ r_tr.T, np.outer(1e-5 * times, [0, 0, 1]), atol=1e-9)


def test_straightness_is_orthogonal_to_the_reference_line():
    # each term is orthogonal to a straight line over the continuous travel: with its
    # two end points only, the cubic term tilts the fitted direction by P3(1) c /
    # (travel / 2); sampled densely, the tilt falls toward zero (as 1 / points)
    truth = PROC.Truth()
    slope = {}
    for points in (2, 1000):
        setup = PROC.Setup(points_per_axis=points, n_submachines=1)
        coef = np.zeros((1, 1, 3, 2, 3))
        coef[0, 0, 0, 0, 1] = 1e-3  # X travel, first direction across, P3, 1 um
        start = tf_layout.slices(setup)[("X", 1)].start - 4
        dev = tf_physics._straightness(setup, truth, coef)[0, start:start + points]
        pos = tf_layout.linear_positions(setup)["X"]
        slope[points] = np.linalg.norm(np.polyfit(pos, dev, 1)[0])
    assert slope[2] == pytest.approx(1e-3 / 500.0, rel=1e-9)
    assert slope[1000] < 1e-2 * slope[2]


def test_mpe_conversion():
    k2 = PROC.sources(PROC.Setup())
    rect = PROC.sources(PROC.Setup(mpe_model="rectangular"))
    assert k2["transverse_fixed"].distribution.std == pytest.approx(15e-3 / 2)
    assert rect["transverse_fixed"].distribution.std == pytest.approx(15e-3 / math.sqrt(3))
    assert k2["distance_per_length"].distribution.std == pytest.approx(0.3e-6 / 2)


# --------------------------------------------------------------------------- truth
def test_true_values_in_cases_known_without_the_construction():
    setup = PROC.Setup()
    # only a frame rotation: the measured rotation is the truth's, origin = wrist offset
    truth = PROC.Truth(**{**ZERO_HEAD, "frame_rx_urad": (20.0,), "frame_ry_urad": (-12.0,),
                          "frame_rz_urad": (35.0,)})
    tv = PROC.display_truth(setup, truth)
    assert (tv["rot_x_1"], tv["rot_y_1"], tv["rot_z_1"]) == pytest.approx((20, -12, 35), abs=1e-9)
    # only offsets and a pivot-length error: the origin moves by them, down along C
    truth = PROC.Truth(**{**ZERO_HEAD, "wrist_dx_um": (7.0,), "wrist_dy_um": (-3.0,),
                          "wrist_dz_um": (5.0,), "pivot_length_error_um": (2.0,),
                          "ac_offset_um": (12.0,)})
    tv = PROC.display_truth(setup, truth)
    assert (tv["origin_x_2"], tv["origin_y_2"], tv["origin_z_2"]) == pytest.approx((7, -3, 3),
                                                                                   abs=1e-9)
    assert tv["ac_offset_2"] == pytest.approx(12.0, abs=1e-12)
    # squareness Z-X only: X kept (longest) -> frame unrotated; Z kept -> rot_y = sq_zx
    truth = PROC.Truth(**{**ZERO_HEAD, "sq_zx_urad": (8.0,)})
    tv = PROC.display_truth(setup, truth)
    assert tv["rot_y_1"] == pytest.approx(0.0, abs=1e-9) and tv["sq_zx_1"] == pytest.approx(8.0)
    tall = setup.replace(travel_z_mm=1500.0)
    tv = PROC.display_truth(tall, truth)
    assert tv["rot_y_1"] == pytest.approx(8.0, abs=1e-6)
    assert tv["rot_x_1"] == pytest.approx(0, abs=1e-9)


# --------------------------------------------------------------------------- recovery
@pytest.mark.parametrize("changes,truth_changes", [
    ({}, {}),
    ({"travel_y_mm": 1200.0}, {}),
    ({"travel_z_mm": 1500.0, "travel_x_mm": 300.0}, {}),
    ({"c_arc_deg": 360.0, "a_arc_deg": 10.0, "points_per_arc": 3}, {}),
    ({"n_submachines": 3, "mpe_model": "rectangular", "pivot_length_mm": 0.0}, {}),
    ({"tracker_distance_mm": 15000.0, "points_per_axis": 2}, {"ac_angle_deg": 45.0,
                                                              "tracker_yaw_deg": -170.0}),
])
def test_noise_free_recovery(changes, truth_changes):
    setup = PROC.Setup(**changes)
    truth = PROC.Truth(**truth_changes)
    tv = PROC.display_truth(setup, truth)
    for est_name in ESTIMATORS:
        est = PROC.display_estimate(setup, _noise_free(setup, truth), est_name)
        for name, value in tv.items():
            np.testing.assert_allclose(est[name], value, rtol=0, atol=1e-6,
                                       err_msg=(est_name, name))


# --------------------------------------------------------------------------- Monte Carlo
@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_monte_carlo_matches_linearisation_at_small_noise(estimator):
    setup = PROC.Setup(**{f: getattr(PROC.Setup(), f) * 0.1 for f in NOISE_FIELDS})
    n = 2000
    mc = simulate_uncertainty(PROC, setup, trials=n, rng=20240601, estimator=estimator,
                              progress=False)
    gum = linearize_procedure(PROC, setup, estimator=estimator)
    rel = 4 / math.sqrt(2 * (n - 1))
    np.testing.assert_allclose(mc.mc.std, gum.std, rtol=rel)
    # unbiased to first order about the sources' means: the mean is within 4 standard errors
    # of the estimate at those means (the unmeasured air gradient's is +0.5 K/m, warm air
    # above: the beams bend by its mean, a bias of up to 4 um here)
    errors = PROC.zero_errors(setup, 1)
    errors["air_gradient_range"] = np.full_like(errors["air_gradient_range"],
                                                setup.air_gradient_range_k_per_m / 2)
    at_means = PROC.display_estimate(setup, PROC.forward(setup, PROC.Truth(), errors), estimator)
    expected = np.array([at_means[m.name][0] for m in mc.measurands]) - mc.true
    assert np.all(np.abs(mc.bias - expected) < 4 * gum.std / math.sqrt(n))
    assert np.max(np.abs(expected)) > 1.0  # the gradient's mean does bias the frames


def test_short_a_arc_drives_origin_and_offset():
    # The A arc fixes the height of the A line and so of T along C: a longer arc
    # lowers the uncertainty of origin_z and of the A-C offset (GUM, all sources).
    u = {}
    for arc in (20.0, 60.0, 180.0):
        # the first-order service: mtplan linearize's numbers
        u[arc] = first_order(PROC, PROC.Setup(a_arc_deg=arc)).u()
    assert u[20.0]["origin_z_1"] > u[60.0]["origin_z_1"] > u[180.0]["origin_z_1"]
    assert u[20.0]["ac_offset_1"] > u[60.0]["ac_offset_1"] > u[180.0]["ac_offset_1"]
    # the linear axes' squareness does not depend on the arcs
    assert u[20.0]["sq_xy_1"] == pytest.approx(u[180.0]["sq_xy_1"], rel=1e-6)


@pytest.mark.parametrize("arc,factor_z,factor_offset", [(20.0, 10.0, 5.0), (60.0, 2.5, 1.5)])
def test_angles_beats_patent_on_short_a_arcs(arc, factor_z, factor_offset):
    # Monte Carlo, all default sources (the rotary positioning error included, which only
    # angles feels; the structure's temperature adds the same 13.5 um to origin_z of both,
    # which narrows the ratio at 60 deg from 3.3 to 3.1): the std of origin_z and
    # ac_offset of patent over that of angles
    # exceeds the stated factor by more than 4 standard errors of the ratio (common
    # random numbers make the ratio's error smaller than 1 / sqrt(n - 1); taken as that).
    setup = PROC.Setup(a_arc_deg=arc)
    n = 2000
    std = {}
    for est in ("patent", "angles"):
        r = simulate_uncertainty(PROC, setup, trials=n, rng=77, estimator=est, progress=False)
        std[est] = dict(zip([m.name for m in r.measurands], r.mc.std, strict=True))
    margin = 1 + 4 / math.sqrt(n - 1)
    for name, factor in (("origin_z_1", factor_z), ("ac_offset_1", factor_offset),
                         ("origin_z_2", factor_z), ("ac_offset_2", factor_offset)):
        assert std["patent"][name] > factor * margin * std["angles"][name], name
    # the linear axes and the orientation do not use the arcs: the same for both
    for name in ("sq_xy_1", "rot_x_1", "rot_z_1"):
        assert std["patent"][name] == pytest.approx(std["angles"][name], rel=1e-9), name


@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_rotary_positioning_error_leaves_patent_alone(estimator):
    # the points stay on the true circles, only their angles change: the 3D circle fit
    # does not see it (even at 1 deg); angles, which trusts the commanded angles, does
    setup = PROC.Setup()
    truth = PROC.Truth()
    errs = PROC.zero_errors(setup, 1)
    q = errs["rotary_positioning"].shape[1]
    errs["rotary_positioning"][0] = np.radians(np.linspace(-1.0, 1.0, q))
    out = PROC.display_estimate(setup, PROC.forward(setup, truth, errs), estimator)
    exact = PROC.display_truth(setup, truth)
    worst = max(abs(out[name][0] - value) for name, value in exact.items())
    res = simulate_uncertainty(PROC, setup, sources=["rotary_positioning"], trials=200, rng=4,
                               estimator=estimator, progress=False)
    if estimator == "patent":
        assert worst < 1e-6
        assert np.all(res.mc.std < 1e-6)
    else:
        assert worst > 100.0  # um or urad: a 1 deg error is far beyond the tracker's
        assert np.max(res.mc.std) > 1.0


def _registered_points(setup, readings):
    """Machine points (n, points - 4, 3) in the global frame, as the estimators see them."""
    xyz = tf_estimators._cartesian(readings)
    rot, t = tf_estimators._register(setup, xyz[:, :4])
    return (np.einsum("nij,npj->npi", rot, xyz) + t[:, None, :])[:, 4:]


def test_systematic_angle_error_moves_the_frame_consistently_within_a_trial():
    # A per-test angle error displaces all points of a sub-machine together (they lie
    # within a few degrees as the tracker sees them): the arcs stay circles, the fits'
    # residuals stay small, and the origin moves with the common displacement. The
    # same error drawn per point scatters the arc points: residuals of the displacement's
    # size and, through the sagitta of a 20 deg arc, an origin error many times larger.
    # The limits are a factor of 3 or more from the values at this seed and set-up.
    setup = PROC.Setup(a_arc_deg=20.0, transverse_per_length_um_per_m=5.0)
    truth = PROC.Truth()
    true_pts = tf_physics._machine_points(setup, truth)
    tv = PROC.true_values(setup, truth)
    groups = tf_layout.slices(setup)
    sl = {g: slice(groups[(g, 1)].start - 4, groups[(g, 1)].stop - 4) for g in "CA"}
    n = 300
    out = {}
    for source in ("angular_systematic", "transverse_per_length"):
        readings = PROC.simulate(setup, truth, draws=n, rng=11, sources=[source])
        pts = _registered_points(setup, readings)
        est = PROC.estimate(setup, readings)
        origin = np.stack([est[f"origin_{a}_1"] - tv[f"origin_{a}_1"] for a in "xyz"], -1)
        common, spread, resid = [], [], []
        for g in "CA":
            disp = pts[:, sl[g]] - true_pts[sl[g]]  # (n, m, 3)
            mean = disp.mean(axis=1)
            common.append(mean)
            spread.append(np.sqrt(np.mean(np.sum((disp - mean[:, None]) ** 2, -1))))
            fit = fit_circle_3d(pts[:, sl[g]])
            h, d = circle_residuals(pts[:, sl[g]], fit.centre, fit.normal, fit.radius)
            resid.append(np.sqrt(np.mean(h**2 + d**2)))
        rms = lambda v: float(np.sqrt(np.mean(np.sum(v**2, axis=-1))))  # noqa: E731
        out[source] = dict(common=max(rms(c) for c in common), spread=max(spread),
                           resid=max(resid), origin=rms(origin),
                           follow=rms(origin[:, :2] - (common[0] + common[1])[:, :2] / 2))
    sys, pp = out["angular_systematic"], out["transverse_per_length"]
    assert sys["common"] > 2e-3  # micrometres: the error does displace the points
    assert sys["spread"] < 0.1 * sys["common"]  # ... all of them together
    assert sys["resid"] < 0.05 * sys["origin"]  # the circles stay circles
    assert sys["follow"] < 0.1 * sys["origin"]  # the origin moves with them across
    assert sys["origin"] < 3 * sys["common"]  # ... and the short arc does not amplify it
    assert pp["resid"] > 0.3 * pp["spread"]  # per point: the fit sees the scatter
    assert pp["origin"] > 30 * sys["origin"]  # and the 20 deg arc amplifies it


# --------------------------------------------------------------------------- refusals
@pytest.mark.parametrize("field,value,why", [
    ("travel_x_mm", 0.0, "zero travel"),
    ("travel_z_mm", 0.0, "zero travel"),
    ("a_arc_deg", 0.0, "one angle"),
    ("c_arc_deg", 0.0, "one angle"),
    ("points_per_arc", 2, "points_per_arc"),
    ("points_per_axis", 1, "points_per_axis"),
])
def test_degenerate_setups_refused(field, value, why):
    with pytest.raises(InvalidInput, match=why) as exc:
        PROC.setup(**{field: value})
    assert field in str(exc.value)


@pytest.mark.parametrize("angle", [0.0, 2.0, 180.0])
def test_parallel_a_and_c_refused(angle):
    with pytest.raises(InvalidInput, match="parallel") as exc:
        PROC.truth(ac_angle_deg=angle)
    assert "ac_angle_deg" in str(exc.value)


def test_parallel_fitted_axes_refused_by_the_estimator():
    # measured data whose "A arc" went round C: the fitted A and C lines coincide
    setup = PROC.Setup()
    r = _noise_free(setup, PROC.Truth())
    sl = tf_layout.slices(setup)
    for key in r:
        r[key][:, sl[("A", 2)]] = r[key][:, sl[("C", 2)]]
    with pytest.raises(InvalidInput, match="sub-machine 2 are parallel"):
        PROC.estimate(setup, r)


# --------------------------------------------------------------------------- data
def test_readings_frame_round_trip_in_any_row_order():
    setup = PROC.Setup(n_submachines=3)
    r = PROC.simulate(setup, draws=2, rng=5)
    df = tf.readings_frame(setup, r)
    assert len(df) == tf_layout.n_points(setup)
    assert {"group", "submachine", "index", "position_mm", "angle_deg", "distance_mm",
            "azimuth_rad", "elevation_rad"} <= set(df.columns)
    back = tf.from_frame(setup, df.sample(frac=1.0, random_state=1))
    for key in r:
        np.testing.assert_array_equal(back[key][0], r[key][0])


def test_from_frame_errors_name_the_problem():
    setup = PROC.Setup()
    df = tf.readings_frame(setup, _noise_free(setup, PROC.Truth()))
    with pytest.raises(InvalidInput, match="distance_mm"):
        tf.from_frame(setup, df.drop(columns="distance_mm"))
    bad = df.copy()
    bad.loc[7, "azimuth_rad"] = np.nan
    with pytest.raises(InvalidInput, match="'azimuth_rad'.*row.*7"):
        tf.from_frame(setup, bad)
    with pytest.raises(InvalidInput, match="rows"):
        tf.from_frame(setup, df.iloc[:-1])
    dup = df.copy()
    dup.loc[5, "index"] = 4
    with pytest.raises(InvalidInput, match="repeats"):
        tf.from_frame(setup, dup)


def test_from_frame_refuses_arc_angles_other_than_the_setups():
    setup = PROC.Setup()
    df = tf.readings_frame(setup, _noise_free(setup, PROC.Truth()))
    bad = df.copy()
    row = df.index[(df.group == "A") & (df.submachine == 2) & (df["index"] == 1)][0]
    bad.loc[row, "angle_deg"] += 0.5
    with pytest.raises(InvalidInput, match="angle_deg.*'A', 2, 1.*a_arc_deg"):
        tf.from_frame(setup, bad)
    tf.from_frame(setup, df.drop(columns="angle_deg"))  # no column: the set-up's angles


def test_duration_grows_with_points_and_submachines():
    base = PROC.duration(PROC.Setup())
    assert PROC.duration(PROC.Setup(points_per_axis=21)) > base
    assert PROC.duration(PROC.Setup(points_per_arc=13)) > base
    assert PROC.duration(PROC.Setup(n_submachines=4)) > base


@pytest.mark.parametrize("changes", [{}, {"travel_z_mm": 1500.0, "n_submachines": 3}])
def test_truth_from_estimate_reproduces_the_estimate(changes):
    setup = PROC.Setup(**changes)
    est = PROC.estimate(setup, PROC.simulate(setup, draws=1, rng=9))
    tv = PROC.true_values(setup, PROC.capabilities.truth_from_estimate(setup, est))
    for m in PROC.measurands(setup):
        assert (tv[m.name] - est[m.name][0]) * m.scale == pytest.approx(0.0, abs=1e-6), m.name


@pytest.mark.parametrize("changes", [{}, {"n_submachines": 3, "a_arc_deg": 20.0}])
def test_truths_from_estimates_are_truth_from_estimate_row_by_row(changes):
    """The batch form gives each row's truth: its readings are those of the row's
    truth_from_estimate (bit for bit), and its measurands those of the row."""
    setup = PROC.Setup(**changes)
    est = PROC.estimate(setup, PROC.simulate(setup, draws=3, rng=5))
    rows = PROC.forward(setup, PROC.capabilities.truths_from_estimates(setup, est),
                        PROC.zero_errors(setup, 3))
    for i in range(3):
        one = PROC.capabilities.truth_from_estimate(setup, {k: v[i:i + 1] for k, v in est.items()})
        r = PROC.forward(setup, one, PROC.zero_errors(setup, 1))
        for k, v in r.items():
            np.testing.assert_array_equal(rows[k][i], v[0])
        tv = PROC.true_values(setup, one)
        for m in PROC.measurands(setup):
            assert (tv[m.name] - est[m.name][i]) * m.scale == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("changes", [{}, {"a_arc_deg": 12.0, "n_submachines": 3}])
def test_readings_jacobian_in_one_run_is_the_step_by_step_one(changes):
    """The readings' sensitivities to the measurands with every step in one forward run
    (truths_from_estimates) are those of one truth_from_estimate and forward run per
    step: the same central differences (held to 1e-9 of the largest entry; they agree
    bit for bit on this machine)."""
    import dataclasses

    import mtplan.models
    from mtplan.plans.planner import readings_jacobian

    setup = PROC.Setup(**changes)
    j, names = readings_jacobian(PROC, setup)
    step_by_step = dataclasses.replace(PROC, capabilities=PROC.capabilities.generic(
        "truths_from_estimates"))
    get_ = mtplan.models.get
    try:  # readings_jacobian looks its procedure up: hand it the one without the hook
        mtplan.models.get = lambda p: p if p is step_by_step else get_(p)
        j0, names0 = readings_jacobian(step_by_step, setup)
    finally:
        mtplan.models.get = get_
    assert names == names0 == [m.name for m in PROC.measurands(setup)]
    np.testing.assert_allclose(j, j0, rtol=0, atol=1e-9 * np.abs(j0).max())


@pytest.mark.parametrize("estimator", ["patent", "angles", "home"])
def test_fits_shared_by_identical_rows_give_each_rows_estimate(estimator, monkeypatch):
    """The rows of the first-order map move one reading each: their groups of points are
    mostly the error-free ones, fitted once (``_on_distinct``). The estimates equal
    those with every row fitted (patent and home bit for bit; angles' closed form,
    batched, to 1e-12 mm and rad); a Monte Carlo batch is fitted whole."""
    setup = PROC.Setup(a_arc_deg=30.0)
    f0 = PROC.forward(setup, PROC.Truth(), PROC.zero_errors(setup, 1))
    y0 = np.concatenate([f0[k][0] for k in tf.READING_COLUMNS])
    n, p = y0.size, y0.size // 3
    rows = np.repeat(y0[None], 2 * n, axis=0)
    rows[np.arange(2 * n), np.tile(np.arange(n), 2)] += np.repeat([1e-6, -1e-6], n)
    readings = {k: rows[:, i * p:(i + 1) * p] for i, k in enumerate(tf.READING_COLUMNS)}
    shared = PROC.estimators[estimator](setup, readings)
    calls = []
    monkeypatch.setattr(tf_estimators, "_on_distinct",
                        lambda fit, pts: calls.append(1) or fit(pts))
    whole = PROC.estimators[estimator](setup, readings)
    assert calls
    for k, v in whole.items():
        np.testing.assert_allclose(shared[k], v, rtol=0, atol=0 if estimator != "angles"
                                   else 1e-12)



def test_fits_are_shared_only_by_identical_rows():
    import collections

    seen, Fit = [], collections.namedtuple("Fit", "total iterations")

    def fit(q):
        seen.append(q.shape[0])
        return Fit(q.sum(axis=(1, 2)), 7)

    pts = np.arange(4 * 7 * 3, dtype=float).reshape(4, 7, 3)
    pts[3] = pts[0]
    pts[3, 2, 1] += 1e-9  # alike but for one number: its own fit
    assert tf_estimators._on_distinct(fit, pts)[0].tolist() == pts.sum(axis=(1, 2)).tolist()
    rows = pts[[0, 1, 0, 0, 1, 0, 3]]
    got = tf_estimators._on_distinct(fit, rows)
    assert seen == [4, 3]  # none alike: the batch whole; then each distinct row once
    np.testing.assert_array_equal(got[0], rows.sum(axis=(1, 2)))
    assert got[1] == 7


def test_an_arc_too_short_for_the_noise_is_refused_not_estimated():
    # 1 deg of A over 335 mm: a sagitta of 13 um against tens of um of tracker noise
    setup = PROC.Setup(a_arc_deg=1.0, points_per_arc=25)
    readings = PROC.simulate(setup, draws=50, rng=4)
    with pytest.raises(InvalidInput, match="A arc of sub-machine 1 did not converge"):
        PROC.estimate(setup, readings)


def test_reflector_fixture_moves_the_reflector_in_the_heads_directions():
    # across C away from it, along C, round C: each moves every point of that sub-machine
    # (lines and arcs alike) as the reflector itself, the arcs turning it round their axes
    setup = PROC.Setup()
    truth = PROC.Truth()
    q = setup.points_per_arc
    zero = np.zeros((1, 2 * setup.n_submachines * q))
    fixture = np.zeros((1, setup.n_submachines, 3))
    fixture[0, 0] = (0.05, -0.02, 0.03)
    moved = tf_physics._machine_points(setup, truth, zero, fixture)[0]
    h = tf_physics._head(setup, truth, 0)
    shift = 0.05 * h.perp - 0.02 * h.c_dir + 0.03 * np.cross(h.perp, h.c_dir)
    moved_head = tf_physics._Head(**{**h.__dict__, "reflector": h.reflector + shift})
    sl = tf_layout.slices(setup)
    lin = tf_layout.linear_positions(setup)["Y"]
    s = sl[("Y", 1)]
    np.testing.assert_allclose(moved[s.start - 4:s.stop - 4],
                               moved_head.reflector + lin[:, None] * h.axes[1], atol=1e-12)
    a_ang = np.radians(tf_layout.arc_angles(setup.a_arc_deg, q))
    s = sl[("A", 1)]
    expect = h.a_point + tf_geometry.mv(tf_geometry.rot(h.a_dir, a_ang),
                                        moved_head.reflector - h.a_point)
    np.testing.assert_allclose(moved[s.start - 4:s.stop - 4], expect, atol=1e-12)
    base = tf_physics._machine_points(setup, truth)
    s = sl[("X", 2)]
    np.testing.assert_array_equal(moved[s.start - 4:], base[s.start - 4:])  # sub-machine 2
    src = PROC.sources(setup)["reflector_fixture"]
    assert src.shape == (setup.n_submachines, 3)
    assert src.distribution.std == pytest.approx(0.05 / math.sqrt(3))


@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_tracker_position_is_found_by_the_registration(estimator):
    # a tracker placed 3 cm off its stated place reads other numbers, but the
    # registration on the marks finds it: the estimate does not move
    setup = PROC.Setup()
    truth = PROC.Truth()
    moved = tf.Truth(**{**truth.__dict__, "tracker_dx_um": 3e4, "tracker_dy_um": -2e4,
                        "tracker_dz_um": 1e4})
    base, r = _noise_free(setup, truth), _noise_free(setup, moved)
    assert np.max(np.abs(r["distance_mm"] - base["distance_mm"])) > 1.0
    a = PROC.display_estimate(setup, base, estimator)
    b = PROC.display_estimate(setup, r, estimator)
    assert max(abs(a[k][0] - b[k][0]) for k in a) < 1e-6


# --------------------------------------------------------------------------- gls
def test_gls_without_any_source_recovers_the_truth():
    off = {f: 0.0 for f in NOISE_FIELDS} | {"reflector_fixture_um": 0.0}
    setup = PROC.Setup(**off)
    truth = PROC.Truth(tracker_yaw_deg=-40.0, tracker_dx_um=20000.0, c_tilt_x_urad=(300.0,))
    est = PROC.display_estimate(setup, _noise_free(setup, truth), "gls")
    for name, value in PROC.display_truth(setup, truth).items():
        np.testing.assert_allclose(est[name], value, rtol=0, atol=1e-6, err_msg=name)


def test_gls_is_efficient_home_scatters_about_it():
    """An efficient estimator is uncorrelated with its difference to any other unbiased
    one (Hausman): corr(gls, home - gls) ~ 0 within 4 / sqrt(n); and gls is narrower."""
    n = 400
    setup = PROC.Setup()
    r = PROC.simulate(setup, PROC.Truth(), draws=n, rng=np.random.default_rng(31))
    gls, home = PROC.estimators["gls"](setup, r), PROC.estimators["home"](setup, r)
    for k in range(1, setup.n_submachines + 1):
        for name in (f"origin_{a}_{k}" for a in "xyz"):
            corr = np.corrcoef(gls[name], home[name] - gls[name])[0, 1]
            assert abs(corr) < 4 / math.sqrt(n), (name, corr)
            assert np.std(gls[name]) < np.std(home[name]), name


# --------------------------------------------------------------------------- first order


@pytest.mark.parametrize("estimator,changes", [("patent", {}), ("angles", {"a_arc_deg": 20.0}),
                                               ("home", {"n_submachines": 1})])
def test_chain_rule_in_two_parts_is_the_whole_chain(estimator, changes):
    _assert_chain_rule_is_the_linearisation(PROC, PROC.setup(changes), estimator)


def test_reading_effects_with_groups_kept_from_another_setup_are_those_found_afresh(
        monkeypatch):
    """The designer's next lever position reuses the groups of the last (same sources'
    shapes): the effects are those of groups found afresh, bit for bit; kept groups that
    do not fit (here every reading said to depend on one element) are found again."""
    from mtplan.fitting import effects as fo

    a, b = PROC.Setup(a_arc_deg=30.0), PROC.Setup(a_arc_deg=45.0, points_per_axis=11)
    truth = PROC.Truth()

    def effects(setup):
        stats = {name: fo.element_moments(src) for name, src in PROC.active_sources(setup).items()}
        base = PROC.zero_errors(setup, 1)
        for name, (mean, _std, shape) in stats.items():
            base[name] = mean.reshape((1, *shape))

        def readings(errors):
            r = PROC.forward(setup, truth, errors)
            m = next(iter(r.values())).shape[0]
            return np.concatenate([np.asarray(v).reshape(m, -1) for v in r.values()], axis=1)

        return fo.reading_effects(readings, base, stats, key=PROC.name)

    monkeypatch.setattr(fo, "_EFFECT_GROUPS", {})
    f0, fresh = effects(b)
    fo._EFFECT_GROUPS.clear()
    effects(a)
    (key, kept), = fo._EFFECT_GROUPS.items()
    assert "machine_repeatability" in kept
    for groups in (kept, {**kept, "machine_repeatability": (
            fo.Grouping(np.zeros(94 * 3, dtype=int)), np.zeros((1, f0.size), dtype=int))}):
        fo._EFFECT_GROUPS.clear()
        fo._EFFECT_GROUPS[key] = groups
        got_f0, got = effects(b)
        np.testing.assert_array_equal(got_f0, f0)
        assert list(got) == list(fresh)
        for name, eff in fresh.items():
            np.testing.assert_array_equal(got[name], eff, err_msg=name)
        assert fo._EFFECT_GROUPS[key]["machine_repeatability"][0].count > 1


@pytest.mark.parametrize("changes", [{}, {"n_submachines": 3, "points_per_arc": 9},
                                     {"straightness_um": 0.0, "a_arc_deg": 20.0}])
def test_gls_covariance_from_grouped_rows_is_the_budgets(changes):
    """The gls weights' secant effects from grouped rows are source_effects' numbers,
    bit for bit (each reading of a group's rows depends on one of its elements)."""
    from mtplan.fitting import SourceModel, source_effects
    from mtplan.fitting.effects import secant_effects

    setup = PROC.setup(changes)
    other = ("test", str(changes))  # groups kept for another set-up: used where they fit
    secant_effects(SourceModel(PROC.name, tf.sources(PROC.Setup(straightness_um=0.0)),
                               lambda e: tf_estimators._gls_vector(tf.forward(
                                   PROC.Setup(straightness_um=0.0), tf.Truth(), e)),
                               lambda m: PROC.zero_errors(PROC.Setup(straightness_um=0.0), m)),
                   key=other)
    for seed, key in ((1, None), (2, ("test", setup)), (3, ("test", setup)), (4, other)):
        est = tf_estimators
        theta = est._gls_start(setup, PROC.simulate(setup, draws=1, rng=seed))[1][None, :]
        model = SourceModel(PROC.name, tf.sources(setup), lambda e, th=theta: est._gls_vector(
            tf.forward(setup, est._gls_truth(setup, tf.Truth(), np.repeat(
                th, len(e["air_refraction"]), 0)), e)), lambda m: PROC.zero_errors(setup, m))
        for want, got in zip(source_effects(model), secant_effects(model, key=key),
                             strict=True):
            assert want.shape == got.shape and np.array_equal(want, got)
