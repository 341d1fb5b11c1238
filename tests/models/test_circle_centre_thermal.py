"""circle_centre: measured temperatures correct the result to 20 degC (ISO 1).

The part grows about its clamping point, the scales about their datum; a measured
temperature is corrected for, its thermometer's u and the expansion coefficients' u are
sources; an unmeasured one is a zero-mean half-width, and the result says so.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import mtplan
from mtplan import cli
from mtplan.models import circle_centre as cc

P = cc.PROCEDURE
EXAMPLES = Path(mtplan.__file__).parent / "examples"
WARM = dict(part_temperature_c=25.0, scale_temperature_c=23.0, clamp_x_mm=-150.0,
            clamp_y_mm=100.0, scale_datum_x_mm=-300.0, scale_datum_y_mm=250.0)


def _cli_json(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out)


@pytest.mark.parametrize("estimator", list(P.estimators))
def test_measured_temperatures_are_corrected_exactly_without_errors(estimator):
    """Noise-free readings at 25 degC (scales 23 degC), the part clamped off the bore and
    the scales' datum elsewhere: every estimator gives the 20 degC bore to round-off."""
    setup = P.setup(WARM)
    truth = cc.Truth()
    est = P.display_estimate(setup, P.forward(setup, truth, P.zero_errors(setup, 2)), estimator)
    for name, value in P.display_truth(setup, truth).items():
        np.testing.assert_allclose(est[name], value, rtol=0, atol=1e-6, err_msg=name)


# the first-order effect of one unit of each thermal source on the corrected result, with
# c the bore's centre, r its radius, K the clamping point, D the scales' datum and
# dT = T - 20 degC at the reference (measured) temperatures of WARM
def _expected(name, setup, truth):
    c = np.array([truth.centre_x_mm, truth.centre_y_mm])
    r = setup.bore_radius_mm + truth.radius_deviation_mm
    k = np.array([setup.clamp_x_mm, setup.clamp_y_mm])
    d = np.array([setup.scale_datum_x_mm, setup.scale_datum_y_mm])
    a_p, a_s = setup.expansion_ppm_per_k * 1e-6, setup.scale_expansion_ppm_per_k * 1e-6
    dtp, dts = setup.part_temperature_c - 20, setup.scale_temperature_c - 20
    part = np.append(c - k, r)  # growth of (centre, radius) per unit strain of the part
    scale = -np.append(c - d, r)  # the read (centre, radius) per unit strain of the scales
    return {"part_temperature_u": a_p * part, "scale_temperature_u": a_s * scale,
            "expansion_u": dtp * part, "scale_expansion_u": dts * scale}[name]


@pytest.mark.parametrize("name,unit", [("part_temperature_u", 0.5), ("scale_temperature_u", 0.5),
                                       ("expansion_u", 1e-6), ("scale_expansion_u", 1e-6)])
def test_each_thermal_source_moves_the_corrected_result_as_its_physics_says(name, unit):
    """One unit of a source (0.5 K of a thermometer's error, 1e-6/K of an expansion
    coefficient's) moves centre_x, centre_y and radius by its first-order effect: the
    part's growth about the clamping point, the scales' about their datum (to 1e-4
    relative: second order)."""
    setup = P.setup(WARM)
    truth = cc.Truth()
    errors = P.zero_errors(setup, 1)
    base = P.estimate(setup, P.forward(setup, truth, errors), "geometric")
    errors[name] = np.full_like(errors[name], unit)
    moved = P.estimate(setup, P.forward(setup, truth, errors), "geometric")
    got = np.array([float(moved[m][0] - base[m][0]) for m in ("centre_x", "centre_y", "radius")])
    want = unit * _expected(name, setup, truth)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-12)
    assert np.all(np.abs(want) > 1e-4)  # each moves all three by 0.1 um or more here


def test_a_measured_temperature_switches_its_half_width_off_and_its_thermometer_on():
    src = P.sources(P.setup(WARM))
    assert src["part_temperature_u"].active and src["scale_temperature_u"].active
    assert not src["part_temperature_halfwidth"].active
    assert not src["scale_temperature_halfwidth"].active
    assert src["part_temperature_u"].distribution.std == pytest.approx(0.2)
    src = P.sources(P.setup(part_temperature_c=25.0))  # scales assumed at the part's
    assert src["scale_temperature_halfwidth"].active and not src["scale_temperature_u"].active


def test_an_old_half_width_in_the_measured_field_is_refused_naming_the_field():
    """part_temperature_c was once a half-width (2.0); now it is a measured temperature,
    and 2 degC lies outside the workshop range it accepts."""
    with pytest.raises(mtplan._validate.InvalidInput, match="part_temperature_c"):
        P.setup(part_temperature_c=2.0)


def test_the_warm_example_covers_the_truth_only_when_corrected(capsys):
    """The example measured at 25 degC (part and scales): evaluated with its measured
    temperatures every 95 % interval covers the truth; evaluated as if at 20 +- 2 degC
    (nothing measured), the centre's does not (the scales grew by 50 ppm about their datum
    300 mm away: 15 um), and the result says the temperature was assumed."""
    readings = EXAMPLES / "circle_centre_warm_readings.csv"
    truth = P.display_truth(P.Setup())
    warm = _cli_json(capsys, "estimate", "circle_centre", readings, "--config",
                     EXAMPLES / "circle_centre_warm.toml", "--trials", "2000", "--json")
    for m in warm["measurands"]:
        low, high = m["interval"]
        assert low <= truth[m["name"]] <= high, m
    assert any("corrected to 20 degC" in n for n in warm["notes"])
    assert not any("assumed" in n for n in warm["notes"])
    cold = _cli_json(capsys, "estimate", "circle_centre", readings, "--trials", "2000", "--json")
    missed = [m["name"] for m in cold["measurands"]
              if not m["interval"][0] <= truth[m["name"]] <= m["interval"][1]]
    assert "centre_y" in missed
    off = {m["name"]: m["value"] - truth[m["name"]] for m in cold["measurands"]}
    assert math.hypot(off["centre_x"], off["centre_y"]) > 12.0
    assert any("assumed" in n and "not measured" in n for n in cold["notes"])


@pytest.mark.parametrize("changes", [
    {"part_temperature_c": 20.0, "scale_temperature_c": 20.0},
    {"part_temperature_c": 25.0, "scale_temperature_c": 25.0, "scale_datum_x_mm": 0.0,
     "scale_datum_y_mm": 0.0},
    {"part_temperature_c": 25.0, "scale_temperature_c": 25.0, "scale_datum_x_mm": -300.0,
     "scale_datum_y_mm": -300.0}])
def test_the_thermometers_sources_have_their_place_in_the_posterior(changes):
    """With both temperatures measured the thermometers' sources (and, 5 K off 20 degC, the
    expansion coefficients') are in the posterior's covariance, and its u agrees with the mc
    u within 0.85-1.15 widened by four standard errors of the ratio (0.058 at 4000 trials
    and the posterior's effective sample size), as for every procedure, with the scales'
    datum at the bore or 300 mm off it."""
    from mtplan.evaluation.measured import estimate_measured, read_readings

    setup = P.setup(changes)
    readings = read_readings(P, setup, EXAMPLES / "circle_centre_readings.csv")
    post = estimate_measured(P, setup, readings, uncertainty="posterior", rng=0)
    mc = estimate_measured(P, setup, readings, trials=4000, rng=0)
    how = post.details.budget  # source -> how the likelihood holds it
    held = ("part_temperature_u", "scale_temperature_u")
    held += ("expansion_u", "scale_expansion_u") if changes["part_temperature_c"] != 20 else ()
    for name in held:
        assert how[name] in ("covariance", "nuisance"), (name, how[name])
    ratio = post.std / mc.std
    assert np.all((0.85 - 0.058 <= ratio) & (ratio <= 1.15 + 0.058)), ratio


@pytest.mark.parametrize("changes, seed", [
    ({"n_points": 6}, 4),
    ({"n_points": 4, "part_temperature_c": 25.0, "scale_temperature_c": 25.0}, 2)])
def test_a_far_datum_with_more_points_keeps_the_fit_check_and_the_posterior(changes, seed):
    """The scales' datum 300 mm off the bore per axis and four or more points (where the
    least squares once ran away to a chi-square of 1e11: a start off the readings' branch
    of the planned path, and an element whose only effect was round-off taken for a
    reading's own scatter): the fit check's chi-square is that of clean readings (p above
    0.001 for these seeded readings, chi-square per degree of freedom below 3) and the
    posterior's u agrees with the mc u within 0.85-1.15 widened by four standard errors of
    the ratio (0.058 at 4000 trials). The seeds are readings that broke it (a chi-square of
    8e11, and a covariance refused as singular)."""
    from mtplan.evaluation.measured import estimate_measured

    setup = P.setup({"scale_datum_x_mm": -300.0, "scale_datum_y_mm": -300.0, **changes})
    readings = P.simulate(setup, cc.Truth(), 1, rng=seed)
    post = estimate_measured(P, setup, readings, uncertainty="posterior", rng=0)
    mc = estimate_measured(P, setup, readings, trials=4000, rng=0)
    fit = post.fit
    assert fit.ok is not None and fit.p_value > 1e-3 and fit.chi2 / fit.dof < 3, fit.summary()
    # the budget is linearised where each least squares starts (the mc evaluation's first
    # exact estimator, the posterior's own): the two chi-squares agree to that, not to 1e-6
    assert mc.fit.chi2 == pytest.approx(fit.chi2, rel=1e-4)
    ratio = post.std / mc.std
    assert np.all((0.85 - 0.058 <= ratio) & (ratio <= 1.15 + 0.058)), ratio
