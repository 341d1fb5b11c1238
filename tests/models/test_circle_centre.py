"""circle_centre (circle-centre patent): path planner, forward model, estimators, known behaviour.

Statistical tolerances from the Monte Carlo error: a standard deviation from N trials
is within 4/sqrt(2(N-1)) relative of the true one (about 4 sigma).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from mtplan._validate import InvalidInput
from mtplan.models import circle_centre as cc
from mtplan.models.circle_centre import _estimators as cc_estimators
from mtplan.models.circle_centre import _physics as cc_physics
from mtplan.evaluation.first_order import first_order
from mtplan.evaluation.simulation import linearize_procedure, simulate_uncertainty
from tests.models.first_order_check import assert_chain_rule_is_the_linearisation as _assert_chain_rule_is_the_linearisation  # noqa: E501

P = cc.PROCEDURE
N = 4000
REL = 4 / math.sqrt(2 * (N - 1))


def _std(setup, estimator, sources, trials=N, rng=1, truth=None):
    r = simulate_uncertainty(P, setup, truth, estimator=estimator, sources=sources,
                             trials=trials, rng=rng, progress=False)
    return dict(zip([m.name for m in r.measurands], r.mc.std))


# --------------------------------------------------------------------------- planner
R = 250.0
CASES = [  # start (centre at 0), seed case, rotation about o1, about o2/o3
    ((-175.0, 0.0), 1, "ccw", "ccw"),   # centre to the right, theta1 < 120: theta2 > 0
    ((-175.0, 120.0), 1, "ccw", "ccw"),
    ((175.0, -100.0), 2, "cw", "cw"),   # centre to the left, theta2 > 0
    ((-50.0, 0.0), 3, "cw", "ccw"),     # centre to the right, theta1 > 120: theta2 < 0
    ((-50.0, -200.0), 3, "cw", "ccw"),
    ((50.0, 180.0), 4, "ccw", "cw"),    # centre to the left, theta2 < 0
    ((0.0, 0.0), 3, "cw", "ccw"),       # at the centre: no free direction, grouped with 3
    ((0.0, 248.0), 3, "cw", "ccw"),     # near the wall, on the centre's x
    ((-248.0, 0.0), 1, "ccw", "ccw"),   # near the wall
    ((248.0, 10.0), 2, "cw", "cw"),
    ((120.0, -215.0), 4, "ccw", "cw"),  # near the wall, below
]


@pytest.mark.parametrize("start, case, first, later", CASES)
def test_planner_cases_and_geometry(start, case, first, later):
    sx, sy = start
    plan = cc.plan_for_bore((sx, sy), bore_radius_mm=R, centre=(0.0, 0.0))
    assert (plan.case, plan.first_rotation, plan.later_rotation) == (case, first, later)
    assert plan.free_direction == int(np.sign(-sx))
    # theta1 from the chord, theta2 = 120 - theta1
    assert plan.theta1_deg == pytest.approx(2 * math.degrees(math.acos(abs(sx) / R)), abs=1e-9)
    assert plan.theta2_deg == pytest.approx(120 - plan.theta1_deg, abs=1e-9)
    # the planner's centre is the true one for a round bore without errors
    np.testing.assert_allclose(plan.centre, (0.0, 0.0), atol=1e-9)
    # d1, d2, d3 on the bore, 120 deg apart, d3 on p1 (the patent's check passes)
    np.testing.assert_allclose(np.hypot(*plan.targets.T), R, atol=1e-9)
    ang = np.angle(plan.targets[:, 0] + 1j * plan.targets[:, 1])
    gaps = np.degrees(np.angle(np.exp(1j * np.diff(np.r_[ang, ang[0]]))))
    np.testing.assert_allclose(np.abs(gaps), 120.0, atol=1e-9)
    np.testing.assert_allclose(plan.targets[-1], plan.p1, atol=1e-9)
    assert max(plan.miss_mm) < 1e-9
    # every arc: tangent to the radius at both ends, turning as the patent's cases say
    arcs = [s for s in plan.segments if s.kind == "arc"]
    assert arcs[0].start == plan.p2 or math.dist(arcs[0].start, plan.p2) < 1e-9
    for s in arcs:
        for end in (s.start, s.end):
            radial = np.asarray(end)
            to_centre = np.asarray(s.centre) - radial
            assert abs(np.dot(radial, to_centre)) < 1e-6 * R * s.radius
        assert s.radius == pytest.approx(R * abs(math.tan(math.radians(
            (np.degrees(np.angle(complex(*s.end) / complex(*s.start))))) / 2)), rel=1e-9)
    assert ("ccw" if arcs[0].ccw else "cw") == first
    assert all(("ccw" if s.ccw else "cw") == later for s in arcs[1:])
    # the first leg turns theta2 about o, the later ones 120 deg
    p2, e1 = plan.p2, arcs[0].end
    turn1 = math.degrees(math.atan2(p2[0] * e1[1] - p2[1] * e1[0], np.dot(p2, e1)))
    assert abs(turn1) == pytest.approx(abs(plan.theta2_deg), abs=1e-9)
    # the path stays inside the bore and is continuous
    pts = plan.polyline(100)
    assert np.all(np.hypot(*pts.T) <= R + 1e-9)
    for a, b in zip(plan.segments[:-1], plan.segments[1:]):
        np.testing.assert_allclose(a.polyline(3)[-1], b.start, atol=1e-9)
    assert plan.length_mm > 0


def test_seed_case_table_agrees_with_the_geometry_for_random_starts():
    rng = np.random.default_rng(5)
    for _ in range(200):
        r = rng.uniform(0, 0.98) * R
        a = rng.uniform(0, 2 * np.pi)
        plan = cc.plan_for_bore((r * np.cos(a) + 3, r * np.sin(a) - 2), bore_radius_mm=R,
                                centre=(3.0, -2.0))
        arcs = [s for s in plan.segments if s.kind == "arc"]
        if abs(plan.theta2_deg) > 1e-6:
            assert ("ccw" if arcs[0].ccw else "cw") == plan.first_rotation
        np.testing.assert_allclose(plan.targets[-1], plan.p1, atol=1e-8)


@pytest.mark.parametrize("n, spread", [(6, 360), (4, 90), (3, 10), (12, 300)])
def test_planner_generalised_points(n, spread):
    plan = cc.plan_for_bore((30.0, -20.0), bore_radius_mm=R, n_points=n, spread_deg=spread)
    assert plan.targets.shape == (n, 2)
    ends = [s.end for s in plan.segments if s.probing][-n:]
    np.testing.assert_allclose(ends, plan.targets, atol=1e-9)
    step = 360 / n if spread == 360 else spread / (n - 1)
    d = np.degrees(np.abs(np.angle(np.exp(1j * np.radians(np.diff(plan.target_angles_deg))))))
    np.testing.assert_allclose(d, step, atol=1e-9)
    np.testing.assert_allclose(plan.targets[-1], plan.p1, atol=1e-9)
    assert np.all(np.hypot(*plan.polyline(50).T) <= R + 1e-9)


@pytest.mark.parametrize("kwargs, match", [
    (dict(start=(260.0, 0.0), bore_radius_mm=R), "inside the bore"),
    (dict(start=(0.0, 250.0), bore_radius_mm=R), "inside the bore"),
    (dict(start=(0.0, 0.0), bore_radius_mm=0.0), "bore_radius_mm"),
    (dict(start=(0.0, 0.0), bore_radius_mm=-5.0), "bore_radius_mm"),
    (dict(start=(0.0, 0.0), bore_radius_mm=math.nan), "bore_radius_mm"),
    (dict(start=(math.nan, 0.0), bore_radius_mm=R), "start"),
    (dict(start=(0.0, 0.0), bore_radius_mm=R, centre=(0.0, math.inf)), "centre"),
    (dict(start="here", bore_radius_mm=R), "start"),
])
def test_planner_refuses_impossible_input(kwargs, match):
    with pytest.raises(InvalidInput, match=match):
        cc.plan_for_bore(**kwargs)


def test_plan_path_refuses_bad_contacts():
    with pytest.raises(InvalidInput, match="apart"):
        cc.plan_path((0.0, -300.0), (0.0, 300.0), R, 1)
    with pytest.raises(InvalidInput, match="free_direction"):
        cc.plan_path((0.0, -200.0), (0.0, 200.0), R, 2)
    with pytest.raises(InvalidInput, match="p1"):
        cc.plan_path((np.nan, -200.0), (0.0, 200.0), R, 1)


def test_forward_refuses_a_start_outside_the_bore():
    setup = P.setup(start_scatter_mm=0)
    truth = P.truth(start_x_mm=300.0)
    with pytest.raises(InvalidInput, match="inside the bore"):
        P.forward(setup, truth, P.zero_errors(setup, 1))
    with pytest.raises(InvalidInput, match="start_scatter_mm"):
        P.setup(bore_radius_mm=20.0)  # default scatter 25 mm cannot fit


def test_acceptance_check_fixes_the_seed_typo():
    out = cc.acceptance_check((10.0, -200.0), (10.02, -200.01), 0.015)
    assert out["dx_mm"] == pytest.approx(0.02) and out["dy_mm"] == pytest.approx(0.01)
    assert not out["accepted"]
    assert cc.acceptance_check((10.0, -200.0), (10.01, -200.01), 0.015)["accepted"]


def test_simulated_miss_is_small_and_accepted_at_the_defaults():
    setup = P.Setup()
    readings = P.simulate(setup, draws=500, rng=3)
    m = cc.miss(setup, readings)
    assert np.all(m["accepted"])
    assert np.max(m["dy_mm"]) < 0.02


# --------------------------------------------------------------------------- forward model
@pytest.mark.parametrize("sx", [-180.0, 180.0, -40.0, 40.0, 0.0])
@pytest.mark.parametrize("n, spread", [(3, 360), (7, 45), (10, 360)])
def test_noise_free_recovery_in_every_case(sx, n, spread):
    setup = P.setup(n_points=n, spread_deg=spread, start_scatter_mm=0)
    truth = P.truth(start_x_mm=sx, start_y_mm=15.0, centre_x_mm=-0.8, centre_y_mm=0.4,
                    radius_deviation_mm=-0.03)
    readings = P.forward(setup, truth, P.zero_errors(setup, 2))
    tv = P.display_truth(setup, truth)
    for est in P.estimators:
        out = P.display_estimate(setup, readings, est)
        for name in tv:
            np.testing.assert_allclose(out[name], tv[name], atol=1e-6, rtol=0,
                                       err_msg=f"{est} {name}")


def test_contact_lies_on_the_lobed_wall():
    rng = np.random.default_rng(6)
    n, k = 50, 5
    centre = np.tile([0.3, -0.1], (n, 1))
    radius = np.full(n, 100.0)
    form = rng.normal(0, 0.01, (n, 2))
    origin = rng.uniform(-20, 20, (n, k, 2))
    ang = rng.uniform(0, 2 * np.pi, (n, k))
    direction = np.stack([np.cos(ang), np.sin(ang)], axis=-1)
    q, normal = cc_physics._contact(origin, direction, centre, radius, form, 3)
    rel = q - centre[:, None, :]
    phi = np.arctan2(rel[..., 1], rel[..., 0])
    rho = 100.0 + form[:, :1] * np.cos(3 * phi) + form[:, 1:] * np.sin(3 * phi)
    np.testing.assert_allclose(np.hypot(rel[..., 0], rel[..., 1]), rho, atol=1e-12)
    # q is on the line, ahead of the origin
    t = np.einsum("nki,nki->nk", q - origin, direction)
    np.testing.assert_allclose(q, origin + t[..., None] * direction, atol=1e-12)
    assert np.all(t > 0)
    np.testing.assert_allclose(np.linalg.norm(normal, axis=-1), 1.0)


def test_straight_final_approach_against_the_exact_helper_arc():
    """The documented approximation: the contact on the arc vs on its tangent line."""
    r, delta, alpha = 250.0, 0.1, math.radians(30)
    theta = math.radians(120)  # a 120 deg leg ending at alpha
    mid = alpha - theta / 2
    pole = r / math.cos(theta / 2) * np.array([math.cos(mid), math.sin(mid)])
    ro = r * math.tan(theta / 2)
    rt = r + delta  # the actual wall is delta beyond the planned target
    # exact intersection of the helper circle with the wall (both about known centres)
    d = np.linalg.norm(pole)
    a = (rt**2 - ro**2 + d**2) / (2 * d)
    h = math.sqrt(rt**2 - a**2)
    base = a * pole / d
    perp = np.array([-pole[1], pole[0]]) / d
    cands = [base + h * perp, base - h * perp]
    target = r * np.array([math.cos(alpha), math.sin(alpha)])
    exact = min(cands, key=lambda p: np.linalg.norm(p - target))
    straight = rt * np.array([math.cos(alpha), math.sin(alpha)])
    sag = delta**2 / (2 * ro)
    assert np.linalg.norm(exact - straight) == pytest.approx(sag, rel=0.02)
    assert np.linalg.norm(exact - straight) < 15e-6  # 15 nm: both lie on the wall


# --------------------------------------------------------------------------- known behaviour
@pytest.mark.parametrize("bore, noise, n, source", [
    (250.0, 0.5, 3, "probe_noise"),
    (50.0, 2.0, 4, "probe_noise"),
    (1000.0, 1.0, 8, "probe_noise"),
    (250.0, 0.5, 24, "probe_noise"),
    (250.0, 0.0, 12, "stage_repeatability"),
])
@pytest.mark.parametrize("estimator", ["kasa", "geometric"])
def test_centre_uncertainty_is_sqrt_2_over_n_times_the_radial_noise(bore, noise, n, source,
                                                                     estimator):
    setup = P.setup(bore_radius_mm=bore, probe_noise_um=noise, n_points=n,
                    start_scatter_mm=min(25.0, bore / 4))
    sigma = noise if source == "probe_noise" else setup.stage_repeatability_um
    std = _std(setup, estimator, [source])
    for axis in ("centre_x", "centre_y"):
        assert std[axis] == pytest.approx(sigma * math.sqrt(2 / n), rel=REL), axis
    assert std["radius"] == pytest.approx(sigma / math.sqrt(n), rel=REL)


def test_three_point_estimator_with_more_points_uses_an_equilateral_triple():
    std3 = _std(P.setup(n_points=3), "three_point", ["probe_noise"])
    std9 = _std(P.setup(n_points=9), "three_point", ["probe_noise"])
    stdg = _std(P.setup(n_points=9), "geometric", ["probe_noise"])
    for axis in ("centre_x", "centre_y"):
        assert std9[axis] == pytest.approx(std3[axis], rel=2 * REL)
        assert stdg[axis] == pytest.approx(std3[axis] / math.sqrt(3), rel=2 * REL)


def test_three_points_bunched_into_a_short_arc_lose_orders_of_magnitude():
    law = 0.5 * math.sqrt(2 / 3)
    worst = {}
    for spread in (360, 90, 30, 10):
        std = _std(P.setup(n_points=3, spread_deg=spread), "three_point", ["probe_noise"])
        worst[spread] = max(std["centre_x"], std["centre_y"])
    assert worst[360] == pytest.approx(law, rel=REL)
    assert worst[90] > 3 * law
    assert worst[10] > 100 * law  # orders of magnitude
    # the along-bisector error grows as 1/spread^2: 30 -> 10 deg is about 9 times
    assert 7 < worst[10] / worst[30] < 11


@pytest.mark.parametrize("n, source, centre_moves", [
    (3, "pretravel_variation", False),  # 3 lobes repeat at 120 deg: radius only
    (4, "pretravel_variation", True),   # 3 = -1 mod 4: into the centre
    (3, "roundness", True),             # ovality (2 = -1 mod 3) moves the 3-point centre
    (4, "roundness", False),            # ... but not a 4-point centre
    (3, "tangential_slip", False),      # the arcs meet the wall along the radius
])
def test_which_systematic_errors_reach_the_centre(n, source, centre_moves):
    std = _std(P.setup(n_points=n), "geometric", [source], trials=1000)
    moved = max(std["centre_x"], std["centre_y"])
    if centre_moves:
        assert moved > 0.3
    else:
        assert moved < 0.01


@pytest.mark.parametrize("n, lobes, aliased", [
    (3, 2, True),    # an oval: 2 = -1 (mod 3)
    (3, 4, True),    # 4 = +1 (mod 3)
    (3, 3, False),   # repeats at every point: radius only
    (4, 2, False),
    (4, 3, True),    # 3 = -1 (mod 4)
    (5, 4, True),
    (5, 2, False),
])
def test_form_error_aliases_into_the_centre_by_its_full_amplitude(n, lobes, aliased):
    """n equally spaced points see a k-lobed form A cos(k phi - psi) as an eccentricity
    of size A when k = +-1 (mod n), whatever its orientation psi; otherwise not at all
    (to first order). Three points (the patent's rule) thus put the whole amplitude of an
    oval bore into the centre."""
    setup = P.setup(n_points=n, lobes=lobes)
    truth = cc.Truth()
    m, amp = 16, 5e-3  # orientations, amplitude A [mm]
    psi = np.linspace(0.0, 2 * math.pi, m, endpoint=False)
    errors = P.zero_errors(setup, m)
    errors["roundness"] = amp * np.stack([np.cos(psi), np.sin(psi)], axis=-1)
    est = P.estimate(setup, P.forward(setup, truth, errors),
                     "three_point" if n == 3 else "geometric")
    shift = np.hypot(est["centre_x"] - truth.centre_x_mm, est["centre_y"] - truth.centre_y_mm)
    if aliased:
        np.testing.assert_allclose(shift / amp, 1.0, atol=1e-2)
    else:
        assert np.all(shift / amp < 1e-2)


def test_part_and_scale_temperatures_move_the_radius_by_alpha_part_dt_minus_alpha_scale_dt():
    """A bore at 20 degC + dT_part is the 20 degC bore scaled by 1 + alpha_part dT_part about
    the part's clamping point (the nominal centre by default); the scales at 20 degC +
    dT_part + dT_scale read every length from their datum short by 1 + alpha_scale
    dT_total: three points give the radius r (1 + alpha_part dT_part) / (1 + alpha_scale
    dT_total) and the centre D + (c grow - D) / (1 + alpha_scale dT_total), D the datum
    (300 mm off per axis by default). Unmeasured, nothing is corrected. Part and machine at
    one temperature: (11.5 - 10) ppm/K of the radius only."""
    setup = P.Setup()
    truth = cc.Truth()
    dt_part = np.array([-2.0, 0.0, 1.5, 2.0])
    dt_scale = np.array([0.0, 1.0, -0.5, 0.0])
    errors = P.zero_errors(setup, 4)
    errors["part_temperature_halfwidth"] = dt_part
    errors["scale_temperature_halfwidth"] = dt_scale
    r20 = setup.bore_radius_mm + truth.radius_deviation_mm
    grow = 1 + 11.5e-6 * dt_part
    read = 1 / (1 + 10e-6 * (dt_part + dt_scale))
    d = np.array([setup.scale_datum_x_mm, setup.scale_datum_y_mm])
    for name in P.estimators:
        est = P.estimate(setup, P.forward(setup, truth, errors), name)
        np.testing.assert_allclose(est["radius"] + setup.bore_radius_mm, r20 * grow * read,
                                   rtol=0, atol=1e-10)
        np.testing.assert_allclose(est["centre_x"], d[0] + (truth.centre_x_mm * grow - d[0])
                                   * read, rtol=0, atol=1e-10)
        np.testing.assert_allclose(est["centre_y"], d[1] + (truth.centre_y_mm * grow - d[1])
                                   * read, rtol=0, atol=1e-10)
    # one temperature for part and machine (the first and last): 1.5 ppm/K of the radius
    est = P.estimate(setup, P.forward(setup, truth, errors), "three_point")["radius"]
    np.testing.assert_allclose(est[[0, 3]] - truth.radius_deviation_mm,
                               r20 * 1.5e-6 * dt_part[[0, 3]], rtol=2e-4, atol=0)
    src = P.sources(setup)
    assert src["part_temperature_halfwidth"].distribution.std == pytest.approx(2.0 / math.sqrt(3))
    assert src["scale_temperature_halfwidth"].distribution.std == pytest.approx(1.0 / math.sqrt(3))
    assert not src["part_temperature_u"].active and not src["scale_temperature_u"].active


def test_tip_radius_error_moves_the_radius_and_not_the_centre():
    """Every point lies delta beyond the wall along an approach that is radial from the
    planner's centre: the radius grows by delta, the centre moves by about delta (e/r)^2."""
    setup = P.Setup()
    truth = cc.Truth()
    delta = np.array([-1e-3, 5e-4])
    errors = P.zero_errors(setup, 2)
    errors["tip_radius"] = delta
    est = P.estimate(setup, P.forward(setup, truth, errors), "three_point")
    np.testing.assert_allclose(est["radius"] - truth.radius_deviation_mm, delta, rtol=1e-5)
    np.testing.assert_allclose(est["centre_x"], truth.centre_x_mm, rtol=0, atol=1e-9)
    np.testing.assert_allclose(est["centre_y"], truth.centre_y_mm, rtol=0, atol=1e-9)


def test_monte_carlo_agrees_with_the_linearised_prediction():
    """Every source but the expansion coefficients' errors: at an assumed (unmeasured)
    temperature they act only as a product with the temperature's zero-mean deviation, a
    second-order term the first-order law cannot see (u(radius) 1.90 um by Monte Carlo
    against 1.86 without them)."""
    setup = P.Setup()
    trials = 20000
    first_order = [s for s in P.active_sources(setup) if not s.endswith("expansion_u")]
    r = simulate_uncertainty(P, setup, estimator="geometric", trials=trials, rng=4,
                             progress=False, sources=first_order)
    g = linearize_procedure(P, setup, estimator="geometric", sources=first_order)
    np.testing.assert_allclose(r.mc.std, np.sqrt(np.diag(g.cov)),
                               rtol=4 / math.sqrt(2 * (trials - 1)))
    np.testing.assert_allclose(r.bias, 0, atol=4 * r.mc.std.max() / math.sqrt(trials))


def test_duration_grows_with_the_points():
    d3 = P.duration(P.setup(n_points=3))
    d12 = P.duration(P.setup(n_points=12))
    assert 0 < d3 < d12


# --------------------------------------------------------------------------- data
def test_frame_without_point_column_and_bad_frames():
    setup = P.Setup()
    readings = P.simulate(setup, draws=1, rng=1)
    frame = P.readings.frame(setup, readings)
    shuffled = frame.iloc[::-1].reset_index(drop=True)
    back = P.readings.from_frame(setup, shuffled)
    np.testing.assert_array_equal(back["x_mm"], readings["x_mm"])
    only = frame[frame["point"].str.startswith("d")][["x_mm", "y_mm"]]
    est = P.display_estimate(setup, P.readings.from_frame(setup, only), "geometric")
    ref = P.display_estimate(setup, readings, "geometric")
    np.testing.assert_array_equal(est["centre_x"], ref["centre_x"])
    with pytest.raises(InvalidInput, match="'y_mm'"):
        P.readings.from_frame(setup, frame.drop(columns="y_mm"))
    bad = frame.copy()
    bad.loc[3, "x_mm"] = np.nan
    with pytest.raises(InvalidInput, match=r"rows \[3\]"):
        P.readings.from_frame(setup, bad)
    with pytest.raises(InvalidInput, match="d3"):
        P.readings.from_frame(setup, frame.iloc[:-1])
    with pytest.raises(InvalidInput, match="n_points=3"):
        P.readings.from_frame(setup, pd.DataFrame({"x_mm": [1.0, 2.0], "y_mm": [0.0, 1.0]}))


def test_fit_points_refuses_bad_points():
    with pytest.raises(InvalidInput, match="estimator"):
        cc.fit_points([0, 1, 0], [0, 0, 1], "best")
    with pytest.raises(InvalidInput, match="at least 3"):
        cc.fit_points([0, 1], [0, 0], "kasa")
    with pytest.raises(InvalidInput, match="finite"):
        cc.fit_points([0, np.nan, 1], [0, 0, 1], "kasa")
    with pytest.raises(InvalidInput, match="collinear"):
        cc.fit_points([0, 1, 2], [0, 1, 2], "three_point")
    out = cc.fit_points([0, 2, 0], [0, 0, 2], "three_point")
    assert out == pytest.approx({"centre_x_mm": 1, "centre_y_mm": 1, "radius_mm": math.sqrt(2)})


# --------------------------------------------------------------------------- gls
@pytest.mark.parametrize("changes", [
    {}, {"part_temperature_c": 25.0, "scale_temperature_c": 23.5, "clamp_x_mm": 120.0,
         "clamp_y_mm": -80.0, "expansion_u_ppm_per_k": 2.0},
    {"part_temperature_c": 15.0, "clamp_x_mm": -200.0}])
def test_gls_weights_are_the_forward_models_radial_covariance(changes):
    """The analytic radial covariance of the contacts (the weights of ``gls``) against a
    Monte Carlo of the forward model with every default source on (start fixed), each
    element within 5 of its standard errors ``sqrt((s_ii s_jj + s_ij^2) / N)``; with
    temperatures assumed, measured (part and scales, a clamping point off the bore) and
    the part's alone measured (the scales following it)."""
    n_trials = 20_000
    setup = P.setup(start_scatter_mm=0.0, **changes)
    truth = P.truth(start_x_mm=-60.0, start_y_mm=30.0)
    readings = P.simulate(setup, truth, draws=n_trials, rng=11)
    pts, approach, has_p = cc_estimators._contacts(readings)
    assert has_p.all()
    centre = np.array([truth.centre_x_mm, truth.centre_y_mm])
    r = setup.bore_radius_mm + truth.radius_deviation_mm
    diff = pts - centre
    e = np.linalg.norm(diff, axis=-1) - r
    u = diff / np.linalg.norm(diff, axis=-1, keepdims=True)
    empirical = np.cov(e, rowvar=False)
    # the contacts' directions barely move from trial to trial: the mean covariance
    analytic = cc_estimators._radial_covariance(setup, u, approach, np.full(n_trials, r),
                                     np.broadcast_to(centre, (n_trials, 2))).mean(axis=0)
    sd = np.sqrt(np.diag(analytic))
    se = np.sqrt((np.outer(sd, sd) ** 2 + analytic**2) / n_trials)
    assert np.all(np.abs(empirical - analytic) <= 5 * se), (empirical - analytic) / se


def test_gls_without_p1_p2_fits_the_measuring_points_alone():
    setup = P.setup(n_points=6, start_scatter_mm=0)
    truth = P.truth(centre_x_mm=0.3, centre_y_mm=-0.2, radius_deviation_mm=0.01)
    readings = dict(P.forward(setup, truth, P.zero_errors(setup, 1)))
    readings["p_x_mm"] = np.full((1, 2), np.nan)
    readings["p_y_mm"] = np.full((1, 2), np.nan)
    out = cc.estimate_gls(setup, readings)
    for k, v in {"centre_x": 0.3, "centre_y": -0.2, "radius": 0.01}.items():
        assert out[k][0] == pytest.approx(v, abs=1e-9), k


def test_gls_uses_p1_p2_and_beats_the_unweighted_fits():
    """p1 and p2 carry centre_y; the weights take the shared errors (form, pre-travel lobes,
    scale) into account: gls is the best of the exact estimators at the default set-up.
    The temperatures are left out: the scales' strain about their datum moves every point
    alike, a shift of the centre that no fit separates from it (it dominates u(centre) at
    an assumed +-2 K, and is the same for every estimator)."""
    setup = P.setup()
    some = [s for s in P.active_sources(setup) if "temperature" not in s
            and "expansion" not in s]
    std = {e: _std(setup, e, some, trials=2000) for e in ("kasa", "gls")}
    rel = 4 / math.sqrt(2 * 1999)
    assert std["gls"]["centre_y"] < 0.6 * std["kasa"]["centre_y"] * (1 + rel)
    assert std["gls"]["radius"] < std["kasa"]["radius"] * (1 + rel)


# --------------------------------------------------------------------------- first order


@pytest.mark.parametrize("estimator,changes", [("three_point", {}), ("kasa", {"n_points": 24}),
                                               ("geometric", {"n_points": 24, "spread_deg": 90.0}),
                                               ("gls", {"n_points": 8})])
def test_chain_rule_in_two_parts_is_the_whole_chain(estimator, changes):
    _assert_chain_rule_is_the_linearisation(P, P.setup(changes), estimator)


def test_first_order_without_any_source_gives_zero():
    setup = P.setup({f: 0.0 for f in (
        "probe_noise_um", "pretravel_variation_um", "tangential_slip_um_per_deg",
        "roundness_um", "scale_error_ppm", "squareness_urad", "stage_repeatability_um",
        "tip_radius_um", "part_temperature_halfwidth_k", "scale_temperature_halfwidth_k",
        "expansion_u_ppm_per_k", "scale_expansion_u_ppm_per_k", "start_scatter_mm")})
    assert not P.active_sources(setup)
    assert set(first_order(P, setup).u().values()) == {0.0}
    assert first_order(P, setup, estimator="kasa").budget().empty
