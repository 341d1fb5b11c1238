"""rotary_axis's one-to-one sources and the sensor model: what each moves, and by how much.

Each row sets one source to a stated value, every other source at zero (noise-free
readings), and compares the estimate with the noise-free one. The expected changes are
the geometry's: a lateral spot offset d moves the axis by -d (C: EX0C, EY0C; A: EY0A
only, X runs along the A axis); the sensor's zero e moves every plane along Z, so A's
EZ0A by e and nothing of C; a slope s of the X/Y motion tilts every plane and the axis
by about s (0.88 s with the patent's method, 0.93 s with angles: the axis is fitted to
normals tilted by the incline as well); the reversal value moves angles only where the
order approaches some positions from the other side (the patent's A order: 5 arcsec ->
EB0A 22 urad; 44 urad when angles weighted each position by its own errors only). A measurand not listed changes by less than :data:`STILL`.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mtplan.models import get

PROC = get("rotary_axis")
ARCSEC = math.pi / 648000
STILL = 0.01  # um, urad: second-order couplings (the spot along the A axis: 3e-4)
TOL = 0.05  # um, urad: on the expected change
#: the A test of the patent's example, +-45 deg at a 20 deg incline: beyond the sensor's
#: 30 deg table (48.4 deg at A = +-45), accepted with its extrapolated bound; the figures
#: below (and docs/rotary_axis.md's) were derived on it
A45 = dict(axis="A", incline_deg=20.0, range_deg=90.0, sensor_max_tilt_deg=50.0,
           sensor_extrapolate_table=True)

CASES = [
    # (set-up, estimator, source, value [mm, rad, 1], expected changes [um, urad])
    (dict(axis="C"), "patent", "spot_offset_u", (0.010, 0.0), {"EX0C": -10.0}),
    (dict(axis="C"), "angles", "spot_offset_u", (0.0, 0.010), {"EY0C": -10.0}),
    (dict(A45), "angles", "spot_offset_u", (0.0, 0.010), {"EY0A": -10.0}),
    (dict(A45), "angles", "spot_offset_u", (0.010, 0.0), {}),
    (dict(axis="C"), "angles", "sensor_zero_u", 0.005, {}),
    (dict(A45), "angles", "sensor_zero_u", 0.005, {"EZ0A": 5.0}),
    (dict(axis="C"), "patent", "xy_slope_halfwidth", (25e-6, 0.0), {"EB0C": 22.08, "EX0C": -1.10}),
    (dict(axis="C"), "angles", "xy_slope_halfwidth", (25e-6, 0.0), {"EB0C": 23.18, "EX0C": -1.16}),
    (dict(axis="C"), "angles", "xy_slope_halfwidth", (0.0, 25e-6), {"EA0C": -23.18, "EY0C": -1.16}),
    (dict(A45), "angles", "xy_slope_halfwidth", (0.0, 25e-6), {"EC0A": 6.10, "EY0A": -0.79}),
    (dict(A45), "angles", "xy_straightness_halfwidth", (0.001, 0.0), {"EZ0A": -0.08}),
    (dict(axis="C"), "angles", "xy_straightness_halfwidth", (0.001, 0.001), {}),
    (dict(A45), "angles", "reversal_halfwidth", (5 * ARCSEC,), {}),
    (dict(A45, a_order="patent"), "patent", "reversal_halfwidth", (5 * ARCSEC,), {}),
    (dict(A45, a_order="patent"), "angles", "reversal_halfwidth", (5 * ARCSEC,),
     {"EB0A": -21.96, "EZ0A": 0.55, "EC0A": 0.06, "EY0A": 0.02}),
    (dict(axis="C"), "angles", "reversal_halfwidth", (5 * ARCSEC,), {}),
    (dict(A45), "patent", "angular_short_period_halfwidth", 5 * ARCSEC, {}),
    (dict(axis="C", z_follows_surface=False, sensor_range_mm=25.0), "angles",
     "sensor_linearity_halfwidth", (3.2e-4, 3.2e-4), {"EA0C": 0.11, "EB0C": 0.14}),
]


def _estimate(setup, estimator, **errors):
    err = PROC.zero_errors(setup, 1)
    for name, value in errors.items():
        err[name] = np.broadcast_to(np.asarray(value, dtype=float), err[name].shape[1:])[None].copy()
    return PROC.display_estimate(setup, PROC.forward(setup, PROC.Truth(), err), estimator)


@pytest.mark.parametrize("values, estimator, source, value, expected", CASES)
def test_one_to_one_source_moves_what_it_should(values, estimator, source, value, expected):
    setup = PROC.setup(**values)
    base = _estimate(setup, estimator)
    moved = _estimate(setup, estimator, **{source: value})
    for name in base:
        change = float(moved[name][0] - base[name][0])
        if name in expected:
            assert change == pytest.approx(expected[name], abs=TOL), (name, change)
        else:
            assert abs(change) < STILL, (name, change)


def test_short_period_positioning_moves_the_angles_estimator_only():
    # per position and repeatable: the tie to the encoder's angles feels it, the patent's
    # method (which never uses the angles) does not (the row above)
    setup = PROC.setup(axis="A")
    P = setup.n_positions
    value = 5 * ARCSEC * np.sin(np.arange(P))
    base = _estimate(setup, "angles")
    moved = _estimate(setup, "angles", angular_short_period_halfwidth=value)
    assert abs(float(moved["EB0A"][0] - base["EB0A"][0])) > 5.0


def test_linearity_is_negligible_when_z_follows_the_surface():
    # the sensor then works within tens of micrometres of mid-range, where the curve is flat
    setup = PROC.setup()
    base = _estimate(setup, "angles")
    moved = _estimate(setup, "angles", sensor_linearity_halfwidth=(3.2e-4, 3.2e-4))
    assert max(abs(float(moved[k][0] - base[k][0])) for k in base) < 0.05


def test_every_new_source_is_listed_with_its_reference():
    # the set-up field sizes it (its name + the unit) and the description names a source
    fields = {f.name for f in __import__("dataclasses").fields(PROC.Setup)}
    src = PROC.sources(PROC.Setup())
    for name, unit in (("spot_offset_u", "um"), ("sensor_zero_u", "um"),
                       ("xy_slope_halfwidth", "urad"), ("xy_straightness_halfwidth", "um"),
                       ("reversal_halfwidth", "arcsec"),
                       ("angular_short_period_halfwidth", "arcsec"),
                       ("sensor_linearity_halfwidth", "ppm")):
        assert f"{name}_{unit}" in fields
        assert "default" in src[name].description.lower() and src[name].active


# --------------------------------------------------------------------------- angle influence
THIRD = 5000e-6 / 3  # a third of the default bound (0.5 % at 30 deg)


def _parts(setup, c0=0.0, c1=0.0, c2=0.0):
    """The angle influence's elements (K, 4) of range B(tau) (c0 + c1 cos phi + c2 cos 2 phi)
    at every tilt (B's own shape: the model the source had before it spanned others)."""
    from mtplan.models.rotary_axis._layout import INFLUENCE_PARTS

    k = PROC.sources(setup)["angle_influence_halfwidth"].shape[0]
    return np.outer(np.ones(k), np.array([c0, c1, c2]) @ INFLUENCE_PARTS)


def test_angle_influence_bound_follows_the_data_sheet_at_the_actual_tilt():
    # the table: 0.12 % at 5 deg, 0.2 % at 15, 0.5 % at 30, linear between and on beyond;
    # on the A axis the plane's slope is 48.4, 35.5, 24.8, 20 deg at |A| = 45, 30, 15, 0
    from mtplan.models import rotary_axis as ra

    setup = PROC.setup(A45)
    tau, _ = ra.tilts(setup)
    np.testing.assert_allclose(tau, [48.4, 35.5, 24.8, 20.0, 24.8, 35.5, 48.4], atol=0.05)
    bound = ra.plan(setup).tilt_bound  # [mm] for the default 10 mm range
    expected = 10.0 * np.interp(tau, [0, 5, 15, 30, 60], [0, 0.0012, 0.002, 0.005, 0.011])
    np.testing.assert_allclose(bound * THIRD * 3 / 5000e-6 * 5000e-6, expected, rtol=1e-12)
    # every sign of the three parts stays within the bound at every position, and the
    # corner of all three at + reaches it where the tilt lies along the triangulation plane
    base = _noise_free_z(setup)
    for signs in np.array(np.meshgrid(*[[-1, 1]] * 3)).reshape(3, -1).T:
        z = _noise_free_z(setup, angle_influence_halfwidth=_parts(setup, *(signs * THIRD)))
        err = (z - base).mean(axis=-1)
        assert np.all(np.abs(err) <= expected * (1 + 1e-9)), (signs, err, expected)
    c = PROC.setup(axis="C")
    err = (_noise_free_z(c, angle_influence_halfwidth=_parts(c, *(THIRD,) * 3))
           - _noise_free_z(c))[:, 0]
    assert err[0] == pytest.approx(0.030, rel=1e-9)  # 0.3 % of 10 mm at 20 deg, phi = 0


def _noise_free_z(setup, **errors):
    err = PROC.zero_errors(setup, 1)
    for name, value in errors.items():
        err[name] = np.asarray(value, dtype=float)[None]
    return PROC.forward(setup, PROC.Truth(), err)["z_mm"][0]


@pytest.mark.parametrize("values, estimator, part, expected", [
    # C: the odd part along the triangulation plane (XZ) is a first harmonic of the fall
    # line's azimuth: EX0C moves by about e / tan(incline) = 10 um / tan 20 deg; the sensor's
    # mirror symmetry leaves EY0C; the even part and the anisotropy are the same at, or a
    # second harmonic over, the full turn: nothing moves
    (dict(axis="C"), "angles", 1, {"EX0C": 27.47}),
    (dict(axis="C"), "angles", 0, {}),
    (dict(axis="C"), "angles", 2, {}),
    # the triangulation plane turned to YZ: the odd part moves EY0C instead
    (dict(axis="C", sensor_azimuth_deg=90.0), "angles", 1, {"EY0C": 27.47}),
    # A: the even part grows with the tilt, 10 um at 20 deg to 28.9 um at 48.4 deg here
    # (c0 at its largest): a bow over the arc that reads as EZ0A with the patent's method,
    # which weights the positions alike (a common offset would move it by its own size, as
    # the sensor's zero; the bow moves it by -32 um); the anisotropy, cos 2 phi of the fall
    # line's azimuth (-70 ... 70 deg over the arc), by 68 um (the values this model gives,
    # kept so that a change shows)
    (dict(A45), "patent", 0, {"EZ0A": -32.38}),
    (dict(A45), "patent", 2, {"EZ0A": 67.76}),
])
def test_angle_influence_moves_what_the_geometry_says(values, estimator, part, expected):
    setup = PROC.setup(**values)
    coef = np.zeros(3)
    coef[part] = THIRD
    base = _estimate(setup, estimator)
    moved = _estimate(setup, estimator, angle_influence_halfwidth=_parts(setup, *coef))
    for name in base:
        change = float(moved[name][0] - base[name][0])
        if name in expected:
            assert change == pytest.approx(expected[name], rel=0.01), (name, change)
        else:
            assert abs(change) < 0.01 * max([1.0, *map(abs, expected.values())]), (name, change)


@pytest.mark.parametrize("estimator", ["angles", "gls"])
def test_the_whole_budget_weight_does_not_assume_the_data_sheets_shape(estimator):
    # the data sheet bounds the angle influence at each tilt but states no shape: the
    # weight holds only the covariance of the source's draws, which span many shapes in
    # tilt, so the even part shaped as B(tau) itself is no longer subtracted (an earlier
    # weight that knew that shape moved EZ0A by 0.01 um): it moves EZ0A as the patent's
    # method does (-32 um), and an even part shaped as tau^2 by -53 um (the values this
    # model gives, kept so that a change shows)
    from mtplan.models.rotary_axis._layout import INFLUENCE_PARTS, _tilt_bound, influence_knots
    from mtplan.models.rotary_axis import tilts

    setup = PROC.setup(A45)
    base = _estimate(setup, estimator)["EZ0A"][0]
    moved = [_estimate(setup, estimator,
                       angle_influence_halfwidth=_parts(setup, *np.eye(3)[k] * THIRD))["EZ0A"][0]
             - base for k in range(3)]
    np.testing.assert_allclose(moved, [-33.50, 3.26, 68.95], atol=0.05)
    knots = influence_knots(tilts(setup)[0])
    square = (knots / knots[-1]) ** 2 * _tilt_bound(knots[-1:]) / _tilt_bound(knots)
    moved = _estimate(setup, estimator, angle_influence_halfwidth=np.outer(
        square * THIRD, INFLUENCE_PARTS[0]))["EZ0A"][0] - base
    assert moved == pytest.approx(-52.63, abs=0.05)


def test_a_tilt_beyond_the_sensor_range_is_refused_naming_the_field():
    from mtplan._validate import InvalidInput

    # beyond the data sheet's 30 deg: refused, naming the tilt, the position and the way
    # to accept the extrapolation
    with pytest.raises(InvalidInput, match="sensor_max_tilt_deg.*48.4 deg at A = -45.*"
                       "sensor_extrapolate_table = true and sensor_max_tilt_deg >= 48.4"):
        PROC.setup(axis="A", incline_deg=20.0, range_deg=90.0)
    # the range above the table only with the extrapolation accepted
    with pytest.raises(InvalidInput, match="sensor_max_tilt_deg.*<= 30 deg.*"
                       "sensor_extrapolate_table"):
        PROC.setup(axis="A", sensor_max_tilt_deg=50.0)
    # accepted, still refused beyond the range stated
    with pytest.raises(InvalidInput, match="sensor_max_tilt_deg.*52.2 deg at A = -45"):
        PROC.setup(A45, incline_deg=30.0)
    PROC.setup(axis="A", range_deg=30.0)  # 16.2 deg: inside
    assert PROC.setup(A45).datasheet_notes()
    # a specular face: the data sheet states nothing, a calibrated characteristic is needed
    with pytest.raises(InvalidInput, match="artifact_surface.*'diffuse', or a "
                       "sensor_characteristic"):
        PROC.setup(artifact_surface="specular")


# --------------------------------------------------------------------------- the reversal
@pytest.mark.parametrize("axis", ["C", "A", "CA"])
def test_reversal_cancels_the_odd_errors_exactly(axis):
    # the spot's lateral offset and the angle influence's odd part change sign with the
    # sensor turned by 180 deg about the spindle: the two passes' mean holds neither
    setup = PROC.setup(axis=axis, sensor_reversal=True)
    base = _estimate(setup, "angles")
    moved = _estimate(setup, "angles", spot_offset_u=(0.010, -0.007),
                      angle_influence_halfwidth=_parts(setup, c1=THIRD))
    for name in base:
        assert float(moved[name][0] - base[name][0]) == pytest.approx(0.0, abs=1e-6), name


def test_reversal_takes_the_odd_part_out_of_u_ex0c():
    # u^2(EX0C) at the default C set-up (GUM, angles) is the angle influence's (95 %: on C
    # its odd part along the triangulation plane, and the product term's cos 3 phi) and the
    # spot offset's (4 %); with the sensor reversed both are out of the budget (the
    # two passes' mean holds neither), whatever their shape: 24.4 um -> 1.27 um
    from mtplan.evaluation.simulation import linearize_result

    def budget(setup):
        r = linearize_result(PROC, setup, estimator="angles")
        parts = r.gum.by_source()[r.gum.names[0]]
        return r.u[0] ** 2, {k: v["share"] for k, v in parts.items()}

    u2, share = budget(PROC.setup())
    u2_rev, share_rev = budget(PROC.setup(sensor_reversal=True))
    assert share["angle_influence_halfwidth"] + share["spot_offset_u"] > 0.95
    for name in ("angle_influence_halfwidth", "spot_offset_u"):
        assert share_rev.get(name, 0.0) < 1e-5, name  # second order: 2e-7
    assert math.sqrt(u2_rev) < 0.06 * math.sqrt(u2)


def test_reversal_costs_a_second_pass_and_the_spindle_turns():
    from mtplan.models import rotary_axis as ra

    setup = PROC.setup()
    rev = setup.replace(sensor_reversal=True)
    sched = ra.schedule(rev)
    assert len(sched) == 2 * len(ra.schedule(setup))
    # per position a second pass: the dwell at every point, the serpentine's 24 moves of 10 mm,
    # the move back from its last point to its first (40 mm in X and Y), the spindle's turn
    speed = setup.feed_mm_min / 60
    second = (setup.n_points * setup.dwell_s + 240.0 / speed + math.hypot(40.0, 40.0) / speed
              + setup.spindle_orient_s)
    assert PROC.duration(rev) == pytest.approx(PROC.duration(setup) + 6 * second, rel=1e-9)
    assert PROC.duration(rev.replace(spindle_orient_s=15.0)) == pytest.approx(
        PROC.duration(rev) + 10.0 * setup.n_positions)


def test_reversal_readings_round_trip_and_the_file_says_so():
    # the pass at 180 deg numbers its points on from the lattice's count, over the same
    # points: a readings file says by itself that the sensor was reversed
    from mtplan.models import rotary_axis as ra

    setup = PROC.setup(axis="A", sensor_reversal=True)
    readings = PROC.simulate(setup, draws=1, rng=3)
    df = PROC.readings.frame(setup, readings)
    assert len(df) == 2 * setup.n_positions * setup.n_points
    back = PROC.readings.from_frame(setup, df.sample(frac=1.0, random_state=1))
    np.testing.assert_array_equal(back["z_mm"], readings["z_mm"])
    implied = ra.setup_from_frame(df)
    assert implied["sensor_reversal"].value is True and implied["lattice_nx"].value == 5
    once = PROC.readings.frame(PROC.setup(axis="A"), PROC.simulate(PROC.setup(axis="A"), rng=3))
    assert ra.setup_from_frame(once)["sensor_reversal"].value is False
    assert set(ra.schedule(setup)["sensor_deg"]) == {0.0, 180.0}
