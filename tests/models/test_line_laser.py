"""Tests of the line-laser mounting-angle procedure (line-laser patent application of 2019).

Forward model first (exact ray-surface intersection, flat-surface height relation),
then the estimators: exact noise-free recovery of the registration and pattern
estimators with sign, the patent estimator's quantisation and sign loss against their analytic size,
refusals, observability flags, Monte Carlo against GUM, the data format.
"""

from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from mtplan._validate import InvalidInput
from mtplan.models import line_laser as ll
from mtplan.evaluation.first_order import first_order
from mtplan.evaluation.simulation import linearize_procedure, simulate_uncertainty

PROC = ll.PROCEDURE
SETUP = ll.Setup()
#: one cell pitch along Y as the default scan covers it (16 x 0.25 mm), a fifth of its readings:
#: where a claim does not depend on the scan's size (the pattern fit costs seconds per trial
#: at the default)
PITCH_SCAN = ll.Setup(lines=16, step_mm=0.25)
#: the procedure without its closed-form sensitivities: the generic linearisation
GENERIC = dataclasses.replace(PROC, capabilities=PROC.capabilities.generic(
    "first_order_sensitivities"))


def _noise_free(setup, truth, n=1):
    return PROC.forward(setup, truth, PROC.zero_errors(setup, n))


# --------------------------------------------------------------------------- forward
def test_trace_is_the_exact_first_intersection():
    truth = ll.Truth(alpha_x_mrad=-7.0, artifact_rz_mrad=-30.0)
    rng = np.random.default_rng(3)
    m = 20
    errors = PROC.zero_errors(SETUP, m)
    for name, size in (("shift_error", 5e-3), ("raise_error", 5e-3), ("trigger_y", 5e-3),
                       ("squareness_xy", 1e-3), ("squareness_zy", 1e-3), ("drift", 2e-3),
                       ("facet_position", 5e-3)):
        errors[name] = rng.normal(0, size, errors[name].shape)
    disp = ll.displacements(SETUP, errors)
    facets = errors["facet_position"]
    t = ll.trace(SETUP, truth, disp, facets).ravel()
    _, d, _, _ = ll.frames(SETUP, truth)
    ox, oy, oz = (a.ravel() for a in ll.origins(SETUP, truth, disp))
    rays = ox.size // m
    rows = np.arange(ox.size) // rays
    # the hit lies on the surface with its facets moved ...
    z, _, _ = ll.height_map(SETUP, ox + t * d[0], oy + t * d[1], offsets=facets, rows=rows)
    np.testing.assert_allclose(oz + t * d[2], z, rtol=0, atol=1e-12)
    # ... and equals a full Newton solve from the land plane for every ray
    full = ll.newton(SETUP, ox, oy, oz, d, -oz / d[2], np.arange(ox.size), rays, facets)
    np.testing.assert_allclose(t, full, rtol=0, atol=1e-12)
    # the facets did move the heights: by up to tan(25 deg) x 5 um x a few sigma
    plain = ll.trace(SETUP, truth, disp).ravel()
    assert 5e-3 < np.abs(t - plain).max() < 0.1


def test_facet_errors_repeat_only_beyond_the_scanned_window():
    """No two pockets the scans touch share a facet error (the errors' period is wider
    than the window), even at the Truth's largest rotation."""
    for rz in (8.0, 100.0, -100.0):
        truth = ll.Truth(artifact_rz_mrad=rz)
        _, x, y, _, _, _, _ = ll.nominal_trace(SETUP, truth)
        dx, dy, _ = ll.lattice_local(SETUP, x, y)
        centres = np.unique(np.round(np.stack([x - dx, y - dy], axis=1), 6), axis=0)
        ids = ll.lattice_local(SETUP, centres[:, 0], centres[:, 1])[2]
        assert np.unique(ids).size == len(centres), rz
    assert ll.facet_count(SETUP) == 6 * np.prod(ll.facet_layout(SETUP)) // 2


@pytest.mark.parametrize("ref", [(0.0,) * 8, (1.2, -0.5, 3.0, 0.4, -0.7, 80.0, 1.0, -1.5)])
def test_the_facets_colouring_gives_the_element_by_element_covariance(ref, monkeypatch):
    """Facet k of every pocket in one row (:func:`source_structure`): the facets' part of
    the readings' covariance, as the pattern fit's gain weights with it, is the one of
    360 rows of one facet each, to round-off (a reading's value in a colour's row is the
    one it has with its own facet moved alone)."""
    from mtplan.models.line_laser import _estimators as est

    D1, U1 = est._source_effects(SETUP, ref, ("facet_position",))
    monkeypatch.setattr(est, "source_structure", lambda *args: None)
    D0, U0 = est._source_effects(SETUP, ref, ("facet_position",))
    assert np.array_equal(D1, D0)
    # U U^T (15 600 square) against random directions
    v = np.random.default_rng(1).normal(size=(D0.size, 16))
    c1, c0 = U1 @ (U1.T @ v), U0 @ (U0.T @ v)
    np.testing.assert_allclose(c1, c0, rtol=0, atol=1e-12 * np.abs(c0).max())
    assert np.abs(U0).max() > 2e-3 * math.tan(math.radians(25)) / 2  # the facets move readings


def test_the_pattern_fit_reuses_a_registration_of_the_same_readings_only():
    """The registration just computed for the same readings is the pattern fit's start
    (a sweep's set-up evaluates both); readings that differ in one value are registered
    again: the pattern fit gives what it gives with no registration before it."""
    from mtplan.models.line_laser import _estimators as est

    rng = np.random.default_rng(8)
    z = _noise_free(SETUP, ll.Truth(), 2)["z_mm"] + rng.normal(0, 1e-3, (2, 3, SETUP.lines,
                                                                       SETUP.points_per_line))
    other = z.copy()
    other[1, 2, 40, 30] += 2e-3
    est._LAST_REGISTRATION.clear()
    alone = est.estimate_pattern(SETUP, {"z_mm": other})
    est.estimate_registration(SETUP, {"z_mm": z})
    after = est.estimate_pattern(SETUP, {"z_mm": other})
    for k in alone:
        np.testing.assert_array_equal(after[k], alone[k])
    again = est.estimate_registration(SETUP, {"z_mm": other})
    assert est._LAST_REGISTRATION[0][1] is not other  # a copy: the caller may change its own
    np.testing.assert_array_equal(again["alpha_z"],
                                  est._registration_uncached(SETUP, other)["alpha_z"])


def test_land_heights_follow_the_exact_raise_relation():
    """On the land, scans 2 and 3 differ by h n_z / (n . e_zl) exactly (n: plate normal)."""
    truth = ll.Truth()
    z = _noise_free(SETUP, truth)["z_mm"][0]
    r = ll.sensor_rotation(1.5e-3, -2e-3, 1e-3)
    q = ll.rot_z(8e-3) @ ll.rot_y(-0.2e-3) @ ll.rot_x(0.3e-3)
    normal = q[:, 2]
    expected = SETUP.raise_mm * normal[2] / (normal @ r[:, 2])
    _, _, _, height, _, _, _ = ll.nominal_trace(SETUP, truth)
    on_land = (height == 0.0).reshape(3, SETUP.lines, SETUP.points_per_line)
    both = on_land[1] & on_land[2]
    assert both.sum() > 100
    np.testing.assert_allclose((z[1] - z[2])[both], expected, rtol=0, atol=1e-12)


def _raise_split(setup, truth):
    """Scans 2 and 3 noise-free: (height change z2 - z3, its per-plane prediction
    h (n . a)/(n . d), rays whose hits stay on one plane, rays on the flat parts)."""
    z = _noise_free(setup, truth)["z_mm"][0]
    _, d, q, _ = ll.frames(setup, truth)
    a = q.T @ np.array([0.0, 0.0, 1.0])  # the raise, in the artifact's frame
    _, _, _, _, gx, gy, _ = ll.nominal_trace(setup, truth)
    gx = gx.reshape(3, setup.lines, setup.points_per_line)
    gy = gy.reshape(3, setup.lines, setup.points_per_line)
    normal = np.stack([-gx[1], -gy[1], np.ones_like(gx[1])], axis=-1)
    predicted = setup.raise_mm * (normal @ a) / (normal @ d)
    same = (gx[1] == gx[2]) & (gy[1] == gy[2])
    flat = same & (gx[1] == 0) & (gy[1] == 0)
    return z[1] - z[2], predicted, same, flat


def test_raise_changes_the_height_on_each_plane_by_h_n_a_over_n_d():
    """Raising by h along a changes the reading on a plane of normal n by exactly
    h (n . a) / (n . d), on the facets as on the land: h' is the point-weighted mean of
    that over the planes in the window (the docstring's account of the patent's h')."""
    dz, predicted, same, _ = _raise_split(SETUP, ll.Truth())
    assert same.mean() > 0.99  # few hits cross a kink between scans 2 and 3
    np.testing.assert_allclose(dz[same], predicted[same], rtol=0, atol=1e-12)


def test_patent_alpha_x_reads_the_balance_of_the_facets():
    """Noise-free at the default set-up the flat parts alone would give the angle between
    the measuring direction and the plate's normal (1.90 mrad; arccos(cos ax cos ay) =
    2.24 mrad for a level plate); the facets, +-2 um each, cancel only in part and leave
    +56 nm in h' - h, so the patent reads 7.58 mrad for a true 1 mrad. At the former
    default (40 lines, beta 0.6) they left -16 nm and the estimate was 0."""
    truth = ll.Truth()
    h = SETUP.raise_mm
    _, d, q, _ = ll.frames(SETUP, truth)
    a = q.T @ np.array([0.0, 0.0, 1.0])
    for setup, facets_nm, estimate in ((SETUP, 55.8, 7578.1),
                                       (SETUP.replace(lines=40, shift_fraction=0.6), -15.7, 0.0)):
        dz, _, _, flat = _raise_split(setup, truth)
        flat_only = math.acos(h / dz[flat].mean())
        assert flat_only == pytest.approx(math.acos(d[2] / a[2]), rel=1e-9)
        assert flat_only * 1e6 == pytest.approx(1899.1, abs=0.1)
        assert ((dz - h) * ~flat).mean() * 1e6 == pytest.approx(facets_nm, abs=0.1)
        est = PROC.display_estimate(setup, _noise_free(setup, truth), "patent")["alpha_x"][0]
        assert est == pytest.approx(estimate, abs=0.1)
        if est > 0:
            assert est * 1e-6 == pytest.approx(math.acos(h / dz.mean()), rel=1e-12)


# --------------------------------------------------------------------------- new sources
def _one_source(name, value, setup=SETUP, truth=None):
    """Noise-free readings with one error source set to `value` (internal units)."""
    errors = PROC.zero_errors(setup, 1)
    errors[name][...] = value
    return PROC.forward(setup, truth or ll.Truth(), errors)


_T = ll.scan_times(SETUP)
_W, _H = ll.x_shift(SETUP), SETUP.raise_mm


@pytest.mark.parametrize(
    "source, value, estimator, measurand, expected_urad",
    [
        # the shift runs along (cos g, sin g, 0): scan 2 moves by w g along Y
        ("squareness_xy", 2e-5, "registration", "alpha_z", -20.0),
        # the raise runs along (0, sin e, cos e): scan 3 moves by h e along Y
        ("squareness_zy", 2e-5, "registration", "alpha_x", 20.0),
        # drift along Z between scans 1 and 2 is a height difference over w
        ("drift", (0.0, 0.0, 1e-4), "patent", "alpha_y", 1e-4 * (_T[1] - _T[0]) / _W * 1e6),
        # drift along Y: a row shift between scans 1-2 (alpha_z) and 2-3 (alpha_x)
        ("drift", (0.0, 1e-4, 0.0), "registration", "alpha_z", -1e-4 * (_T[1] - _T[0]) / _W * 1e6),
        ("drift", (0.0, 1e-4, 0.0), "registration", "alpha_x", 1e-4 * (_T[2] - _T[1]) / _H * 1e6),
        # a gain error scales the height difference that carries alpha_y
        ("z_scale", 1e-4, "patent", "alpha_y", 1e-4 * ll.Truth().alpha_y_mrad * 1e3),
    ],
)
def test_first_order_effect_of_the_new_sources(source, value, estimator, measurand,
                                               expected_urad):
    base = PROC.display_estimate(SETUP, _noise_free(SETUP, ll.Truth()), estimator)[measurand]
    out = PROC.display_estimate(SETUP, _one_source(source, value), estimator)[measurand]
    # first order: the neglected terms are the source times a mounting angle (1e-3)
    assert (out - base)[0] == pytest.approx(expected_urad, rel=3e-3)


def test_z_scale_reads_as_the_patents_alpha_x():
    """z = (1 + s) t scales h' exactly: 100 ppm adds s h = 200 nm to h' - h, which the
    arccos turns into 14 mrad (noise-free patent alpha_x from 7.6 to 16 mrad)."""
    s, h = 1e-4, SETUP.raise_mm
    z0 = _noise_free(SETUP, ll.Truth())["z_mm"][0]
    h0 = (z0[1] - z0[2]).mean()
    est = PROC.estimate(SETUP, _one_source("z_scale", s), "patent")["alpha_x"][0]
    assert est == pytest.approx(math.acos(h / ((1 + s) * h0)), rel=1e-9)
    assert est > math.acos(h / (h + s * h)) * 0.9  # the scale term dominates


def test_linearity_alone_gives_u_alpha_y_of_the_linearity_over_w():
    """The patent's l_y is the mean over the common part of z1(x_l + w) - z2(x_l); the
    linearity curve e adds mean(e(x_l + w) - e(x_l)) (w = 40 point spacings: no
    interpolation), linear in its coefficients c_k (std L/sqrt 3 each):
    u(alpha_y) = (L / sqrt 3) |g| / w, g_k the mean difference of basis k. Over the
    mirror-symmetric common part only the odd degree (3) survives: u = 0.27 L/w,
    27 urad for 1 um, of the order of L/w = 100 urad. alpha_z (integer rows) and
    alpha_x (same x_l in scans 2 and 3) do not move."""
    n = 300
    big_l, w, pts = SETUP.linearity_um * 1e-3, _W, SETUP.points_per_line
    k = round(w / ll.pitch(SETUP))
    assert k * ll.pitch(SETUP) == pytest.approx(w, abs=1e-12)
    xi = np.linspace(-1.0, 1.0, pts)
    basis = np.stack([math.sqrt(2 * deg + 1) * np.polynomial.legendre.legval(xi, np.eye(5)[deg])
                      for deg in (2, 3, 4)])
    g = basis[:, k:].mean(axis=1) - basis[:, : pts - k].mean(axis=1)
    np.testing.assert_allclose(g[[0, 2]], 0.0, atol=1e-12)  # even degrees cancel
    u_pred = big_l / math.sqrt(3) * np.linalg.norm(g) / w * 1e6
    assert 0.2 < u_pred / (big_l / w * 1e6) < 0.5
    mc = simulate_uncertainty(PROC, SETUP, sources=["linearity"], trials=n, rng=4,
                              progress=False)
    assert mc.mc.std[1] == pytest.approx(u_pred, rel=4 / math.sqrt(2 * (n - 1)))
    # alpha_z never leaves its whole row: simulate states the rounding, step / sqrt(12)
    step = PROC.estimators["patent"].steps(SETUP)["alpha_z"] * 1e6
    assert mc.mc.std[0] == pytest.approx(step / math.sqrt(12), rel=1e-12)
    assert mc.mc.high[0] - mc.mc.low[0] == pytest.approx(0.95 * step, rel=1e-12)
    assert mc.mc.std[2] < 1e-6
    gum = linearize_procedure(PROC, SETUP, sources=["linearity"])
    assert math.sqrt(gum.cov[1, 1]) == pytest.approx(u_pred, rel=1e-3)


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


@pytest.mark.parametrize("estimator, setup", [("registration", SETUP), ("pattern", PITCH_SCAN)])
def test_exact_estimators_recover_all_angles_with_sign_each_trial_on_its_own(estimator, setup):
    """Both exact estimators, any pose of the artifact (the pattern fit finds a pose far
    from the default truth's by its grid search of the lattice offset), each pose alone
    and the five as one batch: a trial's result does not depend on the trials beside it
    (the pattern fit once started every trial from the batch's first fit, and so missed
    the poses unlike the first). Batch and alone run the same iterations; they may differ
    by the floating-point order of the batch's products, bounded by the fit's stopping
    rule (a step within 1e-9 mrad = 1e-6 urad): 2e-6 urad. The pattern fit on the scan of
    one pitch (:data:`PITCH_SCAN`): its grid search and its per-trial starts are the same
    code at any scan length, and at the default scan it costs half a minute here."""
    truths = [ll.Truth(**values) for values in TRUTHS]
    readings = {"z_mm": np.concatenate([_noise_free(setup, t)["z_mm"] for t in truths])}
    batch = PROC.display_estimate(setup, readings, estimator)
    for k, truth in enumerate(truths):
        alone = PROC.display_estimate(setup, {"z_mm": readings["z_mm"][k:k + 1]}, estimator)
        for name, value in PROC.display_truth(setup, truth).items():
            msg = f"pose {k}, {name}"
            np.testing.assert_allclose(alone[name][0], value, rtol=0, atol=1e-6, err_msg=msg)
            np.testing.assert_allclose(batch[name][k], alone[name][0], rtol=0, atol=2e-6,
                                       err_msg=msg)


def test_pattern_fit_of_a_noisy_trial_does_not_depend_on_its_batch():
    """With every error source drawn, each trial's gains are its own (taken at its start
    and its fit, rounded): four trials as one batch, as two of two and one by one give the
    same estimates, to the fit's stopping rule (2e-6 urad, as above). On the scan of one
    pitch, as above."""
    readings = PROC.simulate(PITCH_SCAN, draws=4, rng=11)
    batch = PROC.display_estimate(PITCH_SCAN, readings, "pattern")
    for part in (slice(0, 2), slice(2, 4), slice(1, 2), slice(3, 4)):
        some = PROC.display_estimate(PITCH_SCAN, {"z_mm": readings["z_mm"][part]}, "pattern")
        for name, values in some.items():
            np.testing.assert_allclose(values, batch[name][part], rtol=0, atol=2e-6,
                                       err_msg=f"{part}, {name}")


def test_registration_is_blind_to_positioning_errors_of_w_and_h():
    """w and h come from the data (vector lengths), so their positioning errors drop out."""
    setup = SETUP.replace(shift_error_um=20.0, raise_error_um=20.0)
    readings = PROC.simulate(setup, draws=4, rng=5, sources=["shift_error", "raise_error"])
    out = PROC.display_estimate(setup, readings, "registration")
    for name, value in PROC.display_truth(setup).items():
        np.testing.assert_allclose(out[name], value, rtol=0, atol=1e-6, err_msg=name)
    patent = PROC.display_estimate(setup, readings, "patent")["alpha_x"]
    assert np.ptp(patent) > 1000  # the patent's arccos(h/h') swings by mrad


# --------------------------------------------------------------------------- patent traps
def test_patent_alpha_z_is_quantised_to_dy_over_w():
    w, dy = ll.x_shift(SETUP), SETUP.step_mm
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


@pytest.mark.parametrize("artifact_y", [-0.21, 0.5, 1.3, 2.2])
def test_patent_alpha_z_switches_half_way_between_steps_wherever_the_artifact_lies(artifact_y):
    # the nearest whole row shift, as the seed means: alpha_z switches from step k to k+1
    # at (k + 1/2) steps (to 0.05 step), whatever the artifact's Y position; the noise-free
    # readings of a fine sweep of alpha_z in one batch (array-valued truth fields)
    w, dy = ll.x_shift(SETUP), SETUP.step_mm
    step = math.atan(dy / w)
    az = np.linspace(-1.9, 1.9, 153) * step  # 0.025 step apart
    base = dataclasses.replace(ll.Truth(), artifact_y_mm=artifact_y)
    fields = {f.name: np.full(az.size, getattr(base, f.name)) for f in dataclasses.fields(base)}
    truth = copy.copy(base)
    for name, value in {**fields, "alpha_z_mrad": az * 1e3}.items():
        object.__setattr__(truth, name, value)
    readings = PROC.forward(SETUP, truth, PROC.zero_errors(SETUP, az.size))
    est = PROC.estimate(SETUP, readings, "patent")["alpha_z"]
    rows = np.round(np.tan(est) * w / dy).astype(int)
    switch = np.flatnonzero(np.diff(rows))
    assert rows[0] == -2 and rows[-1] == 2 and np.all(np.diff(rows) >= 0)
    at = (az[switch] + az[switch + 1]) / 2 / step  # switch points [steps]
    np.testing.assert_allclose(at, [-1.5, -0.5, 0.5, 1.5], rtol=0, atol=0.05)


@pytest.mark.parametrize("ax, ay", [(3.0, 0.0), (3.0, 2.0), (8.0, 0.0), (8.0, -2.0)])
def test_patent_alpha_x_is_sign_blind_and_absorbs_alpha_y(ax, ay):
    """Symmetric placement (a cell centre under the middle of scans 2 and 3, no pose
    errors): the mirror y -> -y maps alpha_x to -alpha_x and leaves the data's mean
    height difference unchanged, so arccos(h/h') must give the same number for both
    signs; its size is that of arccos(cos ax cos ay) ~ sqrt(ax^2 + ay^2) (to the few
    per cent that the facets add), while the registration returns the signed alpha_x."""
    base = dict(alpha_z_mrad=0.0, alpha_y_mrad=ay, artifact_x_mm=ll.x_shift(SETUP),
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
        (dict(max_shift_rows=40), "max_shift_rows"),
    ],
)
def test_unworkable_setups_are_refused(values, field):
    with pytest.raises(InvalidInput, match=field):
        ll.Setup(**values)


def test_observability_flags():
    obs = ll.observability(SETUP)
    w, dy = ll.x_shift(SETUP), SETUP.step_mm
    assert obs["patent"]["alpha_z"].quantum_urad == pytest.approx(math.atan(dy / w) * 1e6)
    assert obs["patent"]["alpha_x"].signed is False
    assert "|alpha_x|" in obs["patent"]["alpha_x"].reason
    # the default scan: a whole cell pitch along Y, w a whole number of point spacings
    assert "whole number" not in obs["patent"]["alpha_y"].reason
    assert "pitch" not in obs["patent"]["alpha_y"].reason
    former = ll.observability(SETUP.replace(lines=40, shift_fraction=0.6))["patent"]["alpha_y"]
    assert "38.4 point spacings" in former.reason and "less than one cell pitch" in former.reason
    assert all(o.observable and o.signed for o in obs["registration"].values())
    assert all(o.observable and o.signed for o in obs["pattern"].values())
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
    # the pattern fit starts from the registration: refused with it
    assert not any(o.observable for o in ll.observability(coarse)["pattern"].values())
    with pytest.raises(InvalidInput, match="'pattern'"):
        PROC.estimate(coarse, readings, "pattern")
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
    assert u[0] == pytest.approx(s / ll.x_shift(SETUP) * 1e6, rel=0.05)
    assert u[2] == pytest.approx(s / SETUP.raise_mm * 1e6, rel=0.05)


def test_monte_carlo_std_matches_gum_for_sensor_noise_on_a_small_setup():
    setup = ll.Setup(line_width_mm=12.0, points_per_line=41, lines=20, cell_depth_mm=0.6,
                     max_shift_rows=3, sensor_noise_um=0.1, shift_fraction=0.6)
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


def test_registration_beats_the_patent_on_alpha_z_and_alpha_x():
    """At the default set-up the registration wins where the patent quantises (alpha_z)
    or reads a second-order, sign-blind quantity (alpha_x). For alpha_y the patent's mean
    height difference is the better one: unbiased once the scan covers a cell pitch and
    w is a whole number of point spacings, it averages every point, and over the
    mirror-symmetric common part it rejects the even degrees of the linearity curve,
    which the registration's planar-cell weighting does not."""
    n = 256
    kw = dict(trials=n, rng=2, progress=False)
    pat = simulate_uncertainty(PROC, SETUP, estimator="patent", **kw)
    reg = simulate_uncertainty(PROC, SETUP, estimator="registration", **kw)
    rms_p = np.hypot(pat.bias, pat.mc.std)
    rms_r = np.hypot(reg.bias, reg.mc.std)
    assert rms_r[0] < rms_p[0] and rms_r[2] < rms_p[2]
    assert rms_p[1] < rms_r[1]
    assert np.all(np.abs(reg.bias) < 4 * reg.mc.std / math.sqrt(n))


def test_pattern_separates_the_linearity_from_alpha_y():
    """The sensor's linearity curve moves the registration's alpha_y by about 0.4 um / w
    (the mean of e(x_l + w) - e(x_l) over its cells, 40 urad), but not the pattern
    fit's: on the known pattern a height error fixed along the line is not a rotation of
    the line, and the fit's weight (the readings' covariance, which holds the three
    Legendre shapes) projects it out (0.001 urad RMS here, noise-free apart from the
    linearity)."""
    n = 48
    readings = PROC.simulate(SETUP, draws=n, rng=4, sources=["linearity"])
    truth = PROC.display_truth(SETUP)["alpha_y"]
    reg = PROC.display_estimate(SETUP, readings, "registration")["alpha_y"] - truth
    pat = PROC.display_estimate(SETUP, readings, "pattern")["alpha_y"] - truth
    # chi-square bounds on n draws (4 sigma): the registration's u is 40 urad
    assert np.sqrt(np.mean(reg**2)) > 40 * (1 - 4 / math.sqrt(2 * n))
    assert np.sqrt(np.mean(pat**2)) < 1.0


def _patent_alpha_y_error(setup, artifact_y_mm):
    truth = ll.Truth(artifact_y_mm=float(artifact_y_mm))
    est = PROC.display_estimate(setup, _noise_free(setup, truth), "patent")["alpha_y"][0]
    return est - truth.alpha_y_mrad * 1e3


def test_default_scan_makes_the_patent_alpha_y_independent_of_the_artifact_position():
    """The default scan covers one cell pitch along Y with w a whole number of point
    spacings: the noise-free patent alpha_y is within 1 urad for every Y position of
    the artifact. The former default (40 lines, half a pitch, w = 38.4 spacings) gave
    errors spread over more than 50 urad with the (unknown) position."""
    positions = np.arange(0.0, SETUP.cell_size_mm, 0.5)
    assert SETUP.lines * SETUP.step_mm == pytest.approx(SETUP.cell_size_mm)
    new = [_patent_alpha_y_error(SETUP, y) for y in positions]
    old = [_patent_alpha_y_error(SETUP.replace(lines=40, shift_fraction=0.6), y)
           for y in positions]
    assert np.max(np.abs(new)) < 1.0
    assert np.ptp(old) > 50.0


# --------------------------------------------------------------------------- data format
def test_frame_round_trip_and_bad_frames():
    readings = PROC.simulate(SETUP, draws=2, rng=1)
    frame = PROC.readings.frame(SETUP, readings)
    assert list(frame.columns) == ["scan", "line", "point", "x_mm", "y_mm", "z_mm"]
    back = PROC.readings.from_frame(SETUP, frame.sample(frac=1.0, random_state=0))  # any row order
    np.testing.assert_array_equal(back["z_mm"][0], readings["z_mm"][0])
    bad = frame.copy()
    bad.loc[5, "z_mm"] = np.nan
    with pytest.raises(InvalidInput, match="z_mm"):
        PROC.readings.from_frame(SETUP, bad)
    with pytest.raises(InvalidInput, match="y_mm"):
        PROC.readings.from_frame(SETUP, frame.drop(columns="y_mm"))
    dup = frame.copy()
    dup.loc[1, "point"] = 0
    with pytest.raises(InvalidInput, match="once"):
        PROC.readings.from_frame(SETUP, dup)
    moved = frame.copy()
    moved["x_mm"] += 0.01
    with pytest.raises(InvalidInput, match="x_mm"):
        PROC.readings.from_frame(SETUP, moved)
    with pytest.raises(InvalidInput, match="rows"):
        PROC.readings.from_frame(SETUP, frame.iloc[:-1])
    assert isinstance(frame, pd.DataFrame)


def test_duration_grows_with_the_scan():
    assert PROC.duration(SETUP.replace(lines=160)) > PROC.duration(SETUP) > 0


# --------------------------------------------------------------------------- first-order budget
#: 16 profiles 0.25 mm apart: 3 120 readings, where the patent's alpha_x is not clipped
FIRST_ORDER_SETUP = PITCH_SCAN


def test_first_order_budget_of_the_patent_is_the_gum_linearisation():
    """The budget through the patent's linear map equals the generic GUM linearisation
    (every reading's noise an input of a finite-difference Jacobian) source by source, to
    1e-4 of u: the generic one's own round-off (its steps move the readings by
    nanometres) is 3e-5 here; alpha_z, a whole row shift, has u = 0 in both."""
    setup = FIRST_ORDER_SETUP
    table = first_order(PROC, setup, estimator="patent").budget()
    gum = linearize_procedure(GENERIC, setup, estimator="patent")
    groups, var = gum.group_variance()
    assert set(table.input) == set(groups)
    for i, name in enumerate(gum.names):
        rows = table[table.output == name].set_index("input")
        ours = rows.loc[list(groups), "contribution"].to_numpy()
        np.testing.assert_allclose(ours, np.sqrt(np.maximum(var[i], 0.0)), rtol=0,
                                   atol=1e-4 * gum.std[i], err_msg=name)
        assert rows["share"].sum() == pytest.approx(1.0 if gum.std[i] > 0 else 0.0)
    assert gum.std[0] == 0.0 and gum.std[1] > 0 and gum.std[2] > 0


def test_pattern_linear_map_is_the_estimators_derivative():
    """The pattern fit's map ``(K J)^-1 K`` times the sources' exact effects gives each
    source's part of u; a secant of the estimator itself (errors at +-0.1 standard
    deviation: the estimate is linear there to 1e-8) along each scalar source, and along a
    random direction of the readings' noise, gives the same to 1e-5."""
    from mtplan.models.line_laser import _first_order as fo

    setup = FIRST_ORDER_SETUP
    scale = np.array([m.scale for m in PROC.measurands(setup)])
    lmap = fo._pattern_map(setup, ll.Truth()) * scale[:, None]
    fast = first_order(PROC, setup, estimator="pattern")
    var = dict(zip(fast.sources, fast.group_variance()[1].T, strict=True))
    srcs = PROC.sources(setup)
    names = ("shift_error", "raise_error", "z_scale", "squareness_xy", "squareness_zy")
    errors = PROC.zero_errors(setup, 2 * len(names) + 2)
    for k, name in enumerate(names):
        sd = float(srcs[name].distribution.std)
        errors[name][2 * k: 2 * k + 2] = [0.1 * sd, -0.1 * sd]
    direction = np.random.default_rng(4).standard_normal(errors["sensor_noise"].shape[1:])
    errors["sensor_noise"][-2:] = [0.1e-3 * direction, -0.1e-3 * direction]
    est = PROC.estimators["pattern"](setup, PROC.forward(setup, ll.Truth(), errors))
    got = np.stack([est[m.name] for m in PROC.measurands(setup)], axis=1) * scale
    secant = (got[0::2] - got[1::2]) / 0.2  # per standard deviation (per 1 um of noise)
    for k, name in enumerate(names):
        np.testing.assert_allclose(np.abs(secant[k]), np.sqrt(var[name]), rtol=1e-5,
                                   err_msg=name)
    np.testing.assert_allclose(secant[-1], lmap @ direction.ravel() * 1e-3, rtol=1e-5)
    np.testing.assert_allclose(np.sqrt(var["sensor_noise"]),
                               np.sqrt((lmap**2).sum(axis=1)) * setup.sensor_noise_um * 1e-3,
                               rtol=1e-12)


def test_sensitivities_leave_the_registration_to_the_generic_linearisation():
    assert ll.sensitivities(FIRST_ORDER_SETUP, estimator="registration") is None


def _same_linearisation(fast, gum, rtol=1e-5):
    """Same inputs and values, u per measurand to `rtol`, each source's part of it to
    `rtol` of the measurand's u."""
    assert fast.inputs == gum.inputs and fast.groups == gum.groups
    # round-off (the patent's alpha_x, an arccos near 1, amplifies a mean's by 1e4)
    np.testing.assert_allclose(fast.value, gum.value, rtol=1e-9, atol=1e-8)
    np.testing.assert_allclose(fast.std, gum.std, rtol=rtol)
    groups, var = gum.group_variance()
    assert fast.group_variance()[0] == groups
    dev = np.abs(np.sqrt(np.maximum(fast.group_variance()[1], 0.0))
                 - np.sqrt(np.maximum(var, 0.0)))
    assert np.all(dev <= rtol * gum.std[:, None]), dev / gum.std[:, None]


#: every source but the readings' noise (whose 15 600 inputs would cost the generic
#: linearisation half a minute at the default scan; at 16 profiles they are compared)
NOT_NOISE = [name for name in PROC.sources(SETUP) if name != "sensor_noise"]


@pytest.mark.parametrize("estimator, setup, only", [
    ("patent", SETUP, NOT_NOISE), ("patent", FIRST_ORDER_SETUP, None),
    ("pattern", FIRST_ORDER_SETUP, NOT_NOISE)])
def test_linearize_uses_the_closed_form_with_the_generic_numbers(estimator, setup, only):
    """``linearize`` through the sensitivities hook (each estimator's linear map times the
    sources' exact effects) gives the generic linearisation's numbers (central differences
    of the forward model and the estimator per element): the value to round-off, u and
    every source's part of it to 1e-5 of the measurand's u (they agree to 4e-7: the
    generic one's finite-difference error); sensitivities perturbed by 0.1 % fail that.
    The pattern fit's at the scan of one pitch only: its map is the same code at any scan
    length, and the generic linearisation of the fit at the default scan takes 4 E + 1 fits
    of 15 600 readings (12 to 30 s here; the first-order fixture pins its numbers there)."""
    fast = linearize_procedure(PROC, setup, estimator=estimator, sources=only)
    gum = linearize_procedure(GENERIC, setup, estimator=estimator, sources=only)
    _same_linearisation(fast, gum)

    def off(*args, **kw):
        return ll.sensitivities(*args, **kw) * 1.001

    bad = dataclasses.replace(PROC, capabilities=PROC.capabilities.overriding(
        first_order_sensitivities=off))
    with pytest.raises(AssertionError):
        _same_linearisation(linearize_procedure(bad, setup, estimator=estimator,
                                                sources=only), gum)


def test_linearize_leaves_the_registration_to_the_generic_linearisation():
    assert ll.sensitivities(FIRST_ORDER_SETUP, estimator="registration") is None
