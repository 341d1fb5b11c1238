"""Tests of the line-laser mounting-angle procedure (seed 004).

Forward model first (exact ray-surface intersection, flat-surface height relation),
then the estimators: exact noise-free recovery of the registration estimator with
sign, the patent estimator's quantisation and sign loss against their analytic size,
refusals, observability flags, Monte Carlo against GUM, the data format.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from mtplan._validate import InvalidInput
from mtplan.models import line_laser as ll
from mtplan.evaluation.simulation import linearize_procedure, simulate_uncertainty

PROC = ll.PROCEDURE
SETUP = ll.Setup()


def _noise_free(setup, truth, n=1):
    return PROC.forward(setup, truth, PROC.zero_errors(setup, n))


# --------------------------------------------------------------------------- forward
def test_trace_is_the_exact_first_intersection():
    truth = ll.Truth(alpha_x_mrad=-7.0, artifact_rz_mrad=-30.0)
    rng = np.random.default_rng(3)
    m = 20
    e_w, e_h = rng.normal(0, 5e-3, m), rng.normal(0, 5e-3, m)
    e_y = rng.normal(0, 5e-3, (m, 3))
    t = ll._trace(SETUP, truth, e_w, e_h, e_y).ravel()
    _, d, _, _ = ll._frames(SETUP, truth)
    ox, oy, oz = (a.ravel() for a in ll._origins(SETUP, truth, e_w, e_h, e_y))
    # the hit lies on the surface ...
    z, _, _ = ll.height_map(SETUP, ox + t * d[0], oy + t * d[1])
    np.testing.assert_allclose(oz + t * d[2], z, rtol=0, atol=1e-12)
    # ... and equals a full Newton solve from the land plane for every ray
    full = ll._newton(SETUP, ox, oy, oz, d, -oz / d[2], np.arange(ox.size))
    np.testing.assert_allclose(t, full, rtol=0, atol=1e-12)


def test_land_heights_follow_the_exact_raise_relation():
    """On the land, scans 2 and 3 differ by h n_z / (n . e_zl) exactly (n: plate normal)."""
    truth = ll.Truth()
    z = _noise_free(SETUP, truth)["z_mm"][0]
    r = ll.sensor_rotation(1.5e-3, -2e-3, 1e-3)
    q = ll._rz(8e-3) @ ll._ry(-0.2e-3) @ ll._rx(0.3e-3)
    normal = q[:, 2]
    expected = SETUP.raise_mm * normal[2] / (normal @ r[:, 2])
    _, _, _, height, _, _, _ = ll._nominal(SETUP, truth)
    on_land = (height == 0.0).reshape(3, SETUP.lines, SETUP.points_per_line)
    both = on_land[1] & on_land[2]
    assert both.sum() > 100
    np.testing.assert_allclose((z[1] - z[2])[both], expected, rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- registration
TRUTHS = [
    dict(),
    dict(alpha_z_mrad=-9.9, alpha_y_mrad=9.9, alpha_x_mrad=-9.9, artifact_rz_mrad=100),
    dict(alpha_z_mrad=9.9, alpha_y_mrad=-9.9, alpha_x_mrad=9.9, artifact_tilt_x_mrad=-5,
         artifact_tilt_y_mrad=5),
    dict(alpha_z_mrad=0.0, alpha_y_mrad=0.0, alpha_x_mrad=-0.3, artifact_x_mm=1.1),
    dict(alpha_z_mrad=-0.02, alpha_y_mrad=4.0, alpha_x_mrad=-6.0, artifact_rz_mrad=-60,
         artifact_y_mm=2.0),
]


@pytest.mark.parametrize("values", TRUTHS)
def test_registration_recovers_all_angles_with_sign(values):
    truth = ll.Truth(**values)
    out = PROC.display_estimate(SETUP, _noise_free(SETUP, truth), "registration")
    for name, value in PROC.display_truth(SETUP, truth).items():
        np.testing.assert_allclose(out[name], value, rtol=0, atol=1e-6, err_msg=name)


def test_registration_is_blind_to_positioning_errors_of_w_and_h():
    """w and h come from the data (vector lengths), so their positioning errors drop out."""
    setup = SETUP.replace(sensor_noise_um=0.0, trigger_y_um=0.0, shift_error_um=20.0,
                          raise_error_um=20.0)
    readings = PROC.simulate(setup, draws=4, rng=5)
    out = PROC.display_estimate(setup, readings, "registration")
    for name, value in PROC.display_truth(setup).items():
        np.testing.assert_allclose(out[name], value, rtol=0, atol=1e-6, err_msg=name)
    patent = PROC.display_estimate(setup, readings, "patent")["alpha_x"]
    assert np.ptp(patent) > 1000  # the patent's arccos(h/h') swings by mrad


# --------------------------------------------------------------------------- patent traps
def test_patent_alpha_z_is_quantised_to_dy_over_w():
    w, dy = ll._shift(SETUP), SETUP.step_mm
    quantum = math.atan(dy / w)
    errors = []
    for az in np.linspace(-8.0, 8.0, 9):
        truth = ll.Truth(alpha_z_mrad=float(az))
        est = PROC.estimate(SETUP, _noise_free(SETUP, truth), "patent")["alpha_z"][0]
        steps = math.tan(est) * w / dy
        assert abs(steps - round(steps)) < 1e-9  # a whole number of rows
        errors.append(est - az * 1e-3)
    errors = np.abs(errors)
    assert errors.max() <= quantum  # never off by more than one step ...
    assert errors.max() > quantum / 4  # ... and visibly off between steps
    # the default truth (1.5 mrad) is below one step (5.2 mrad): the patent reads 0
    assert PROC.estimate(SETUP, _noise_free(SETUP, ll.Truth()), "patent")["alpha_z"][0] == 0.0


@pytest.mark.parametrize("ax, ay", [(3.0, 0.0), (3.0, 2.0), (8.0, 0.0), (8.0, -2.0)])
def test_patent_alpha_x_is_sign_blind_and_absorbs_alpha_y(ax, ay):
    """Symmetric placement (a cell centre under the middle of scans 2 and 3, no pose
    errors): the mirror y -> -y maps alpha_x to -alpha_x and leaves the data's mean
    height difference unchanged, so arccos(h/h') must give the same number for both
    signs; its size is that of arccos(cos ax cos ay) ~ sqrt(ax^2 + ay^2) (to the few
    per cent that the facets add), while the registration returns the signed alpha_x."""
    base = dict(alpha_z_mrad=0.0, alpha_y_mrad=ay, artifact_x_mm=ll._shift(SETUP),
                artifact_y_mm=0.0, artifact_rz_mrad=0.0, artifact_tilt_x_mrad=0.0,
                artifact_tilt_y_mrad=0.0)
    res = {}
    for sign in (1, -1):
        readings = _noise_free(SETUP, ll.Truth(alpha_x_mrad=sign * ax, **base))
        res[sign] = (PROC.display_estimate(SETUP, readings, "patent")["alpha_x"][0],
                     PROC.display_estimate(SETUP, readings, "registration")["alpha_x"][0])
    assert res[1][0] == pytest.approx(res[-1][0], rel=1e-7)
    assert res[1][0] == pytest.approx(math.hypot(ax, ay) * 1e3, rel=0.05)
    assert res[1][1] == pytest.approx(ax * 1e3, abs=1e-6)
    assert res[-1][1] == pytest.approx(-ax * 1e3, abs=1e-6)


def test_patent_alpha_x_drowns_in_the_raise_error():
    """With the raise error alone, h' = h'_0 + e_h, so the patent returns 0 with
    probability Phi(-(h'_0 - h)/u_h) and otherwise arccos(h/(h'_0 + e_h))."""
    setup = SETUP.replace(sensor_noise_um=0.0, trigger_y_um=0.0, shift_error_um=0.0)
    z0 = _noise_free(setup, ll.Truth())["z_mm"][0]
    h0 = (z0[1] - z0[2]).mean()
    n = 400
    readings = PROC.simulate(setup, draws=n, rng=21)
    est = PROC.estimate(setup, readings, "patent")["alpha_x"]
    u_h = setup.raise_error_um * 1e-3
    p_zero = stats.norm.cdf(-(h0 - setup.raise_mm) / u_h)
    frac = np.mean(est == 0.0)
    assert abs(frac - p_zero) < 4 * math.sqrt(p_zero * (1 - p_zero) / n)
    # the positive ones are as large as the arccos of the raise error allows
    e_h = np.sort(np.abs(np.random.default_rng(0).normal(0, u_h, 100_000)))
    typical = math.sqrt(2 * np.median(e_h) / setup.raise_mm)  # ~ 2.6e-2 rad
    assert np.median(est[est > 0]) == pytest.approx(typical, rel=0.3)
    assert ll.observability(setup)["patent"]["alpha_x"].observable is False


# --------------------------------------------------------------------------- refusals
@pytest.mark.parametrize(
    "values, field",
    [
        (dict(shift_fraction=1.0), "shift_fraction"),  # w >= w0
        (dict(shift_fraction=1.2), "shift_fraction"),
        (dict(raise_mm=7.5), "range"),  # h beyond the sensor's range
        (dict(step_mm=0.0), "step_mm"),
        (dict(step_mm=-0.05), "step_mm"),
        (dict(cell_depth_mm=0.0), "cell_depth_mm"),  # an artifact with no pattern
        (dict(wall_mm=4.0), "wall_mm"),
        (dict(shift_fraction=0.8), "common part"),
        (dict(cell_depth_mm=1.0), "no floor"),
        (dict(max_shift_rows=1), "max_shift_rows"),
        (dict(max_shift_rows=30), "max_shift_rows"),
    ],
)
def test_unworkable_setups_are_refused(values, field):
    with pytest.raises(InvalidInput, match=field):
        ll.Setup(**values)


def test_observability_flags():
    obs = ll.observability(SETUP)
    w, dy = ll._shift(SETUP), SETUP.step_mm
    assert obs["patent"]["alpha_z"].quantum_urad == pytest.approx(math.atan(dy / w) * 1e6)
    assert obs["patent"]["alpha_x"].signed is False
    assert "|alpha_x|" in obs["patent"]["alpha_x"].reason
    assert all(o.observable and o.signed for o in obs["registration"].values())
    # a finer raise error makes the patent's alpha_x usable (floor below 10 mrad)
    fine = SETUP.replace(raise_error_um=0.01, sensor_noise_um=0.1)
    assert ll.observability(fine)["patent"]["alpha_x"].observable
    # facets narrower than three samples: the registration says so and refuses
    coarse = SETUP.replace(points_per_line=33, facet_angle_deg=40.0)
    flags = ll.observability(coarse)["registration"]
    assert not any(o.observable for o in flags.values())
    readings = _noise_free(coarse, ll.Truth())
    with pytest.raises(InvalidInput, match="registration"):
        PROC.estimate(coarse, readings, "registration")
    assert np.all(np.isfinite(PROC.estimate(coarse, readings, "patent")["alpha_z"]))
    # resolved facets but too short a scan: found on the noise-free data, refused
    short = ll.Setup(line_width_mm=12.0, points_per_line=41, lines=16, cell_depth_mm=0.6,
                     max_shift_rows=3)
    flags = ll.observability(short)["registration"]
    assert not flags["alpha_z"].observable and "singular" in flags["alpha_z"].reason


# --------------------------------------------------------------------------- Monte Carlo
def test_monte_carlo_std_matches_gum_for_the_trigger_offsets():
    """The trigger offsets shift whole scans along Y: the registration is linear in them."""
    n = 300
    mc = simulate_uncertainty(PROC, SETUP, estimator="registration", sources=["trigger_y"],
                              trials=n, rng=7, progress=False)
    gum = linearize_procedure(PROC, SETUP, estimator="registration", sources=["trigger_y"])
    u = np.sqrt(np.diag(gum.cov))
    tol = 4 / math.sqrt(2 * (n - 1))
    np.testing.assert_allclose(mc.mc.std, u, rtol=tol)
    # alpha_z ~ (e_y2 - e_y1)/w and alpha_x ~ -(e_y3 - e_y2)/h: first-order sizes
    s = SETUP.trigger_y_um * 1e-3 * math.sqrt(2)
    assert u[0] == pytest.approx(s / ll._shift(SETUP) * 1e6, rel=0.05)
    assert u[2] == pytest.approx(s / SETUP.raise_mm * 1e6, rel=0.05)


def test_monte_carlo_std_matches_gum_for_sensor_noise_on_a_small_setup():
    setup = ll.Setup(line_width_mm=12.0, points_per_line=41, lines=20, cell_depth_mm=0.6,
                     max_shift_rows=3, sensor_noise_um=0.1)
    n = 300
    mc = simulate_uncertainty(PROC, setup, estimator="registration", sources=["sensor_noise"],
                              trials=n, rng=3, progress=False)
    gum = linearize_procedure(PROC, setup, estimator="registration", sources=["sensor_noise"])
    u = np.sqrt(np.diag(gum.cov))
    # the Jacobian of the registration is taken from the noisy data, which adds a little
    # spread beyond the linear prediction; allow 10 % on top of the Monte Carlo error
    tol = 4 / math.sqrt(2 * (n - 1)) + 0.10
    np.testing.assert_allclose(mc.mc.std, u, rtol=tol)
    assert np.all(np.abs(mc.bias) < 4 * mc.mc.std / math.sqrt(n))


def test_registration_beats_the_patent_at_the_default_setup():
    n = 256
    kw = dict(trials=n, rng=2, progress=False)
    pat = simulate_uncertainty(PROC, SETUP, estimator="patent", **kw)
    reg = simulate_uncertainty(PROC, SETUP, estimator="registration", **kw)
    rms_p = np.hypot(pat.bias, pat.mc.std)
    rms_r = np.hypot(reg.bias, reg.mc.std)
    assert np.all(rms_r < rms_p)
    assert np.all(np.abs(reg.bias) < 4 * reg.mc.std / math.sqrt(n))


# --------------------------------------------------------------------------- data format
def test_frame_round_trip_and_bad_frames():
    readings = PROC.simulate(SETUP, draws=2, rng=1)
    frame = PROC.readings_frame(SETUP, readings)
    assert list(frame.columns) == ["scan", "line", "point", "x_mm", "y_mm", "z_mm"]
    back = PROC.from_frame(SETUP, frame.sample(frac=1.0, random_state=0))  # any row order
    np.testing.assert_array_equal(back["z_mm"][0], readings["z_mm"][0])
    bad = frame.copy()
    bad.loc[5, "z_mm"] = np.nan
    with pytest.raises(InvalidInput, match="z_mm"):
        PROC.from_frame(SETUP, bad)
    with pytest.raises(InvalidInput, match="y_mm"):
        PROC.from_frame(SETUP, frame.drop(columns="y_mm"))
    dup = frame.copy()
    dup.loc[1, "point"] = 0
    with pytest.raises(InvalidInput, match="once"):
        PROC.from_frame(SETUP, dup)
    moved = frame.copy()
    moved["x_mm"] += 0.01
    with pytest.raises(InvalidInput, match="x_mm"):
        PROC.from_frame(SETUP, moved)
    with pytest.raises(InvalidInput, match="rows"):
        PROC.from_frame(SETUP, frame.iloc[:-1])
    assert isinstance(frame, pd.DataFrame)


def test_duration_grows_with_the_scan():
    assert PROC.duration(SETUP.replace(lines=80)) > PROC.duration(SETUP) > 0
