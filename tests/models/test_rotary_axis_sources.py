"""rotary_axis's one-to-one sources and the sensor model: what each moves, and by how much.

Each row sets one source to a stated value, every other source at zero (noise-free
readings), and compares the estimate with the noise-free one. The expected changes are
the geometry's: a lateral spot offset d moves the axis by -d (C: EX0C, EY0C; A: EY0A
only, X runs along the A axis); the sensor's zero e moves every plane along Z, so A's
EZ0A by e and nothing of C; a slope s of the X/Y motion tilts every plane and the axis
by about s (0.88 s with the patent's method, 0.93 s with angles: the axis is fitted to
normals tilted by the incline as well); the reversal value moves angles only where the
order approaches some positions from the other side (the patent's A order: 5 arcsec ->
EB0A 44 urad). A measurand not listed changes by less than :data:`STILL`.
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

CASES = [
    # (set-up, estimator, source, value [mm, rad, 1], expected changes [um, urad])
    (dict(axis="C"), "patent", "spot_offset_u", (0.010, 0.0), {"EX0C": -10.0}),
    (dict(axis="C"), "angles", "spot_offset_u", (0.0, 0.010), {"EY0C": -10.0}),
    (dict(axis="A"), "angles", "spot_offset_u", (0.0, 0.010), {"EY0A": -10.0}),
    (dict(axis="A"), "angles", "spot_offset_u", (0.010, 0.0), {}),
    (dict(axis="C"), "angles", "sensor_zero_u", 0.005, {}),
    (dict(axis="A"), "angles", "sensor_zero_u", 0.005, {"EZ0A": 5.0}),
    (dict(axis="C"), "patent", "xy_slope_halfwidth", (25e-6, 0.0), {"EB0C": 22.08, "EX0C": -1.10}),
    (dict(axis="C"), "angles", "xy_slope_halfwidth", (25e-6, 0.0), {"EB0C": 23.35, "EX0C": -1.17}),
    (dict(axis="C"), "angles", "xy_slope_halfwidth", (0.0, 25e-6), {"EA0C": -23.35, "EY0C": -1.17}),
    (dict(axis="A"), "angles", "xy_slope_halfwidth", (0.0, 25e-6), {"EC0A": 7.89, "EY0A": -0.83}),
    (dict(axis="A"), "angles", "xy_straightness_halfwidth", (0.001, 0.0), {"EZ0A": -0.08}),
    (dict(axis="C"), "angles", "xy_straightness_halfwidth", (0.001, 0.001), {}),
    (dict(axis="A"), "angles", "reversal_halfwidth", (5 * ARCSEC,), {}),
    (dict(axis="A", a_order="patent"), "patent", "reversal_halfwidth", (5 * ARCSEC,), {}),
    (dict(axis="A", a_order="patent"), "angles", "reversal_halfwidth", (5 * ARCSEC,),
     {"EB0A": -44.27, "EZ0A": 0.78, "EC0A": 0.67, "EY0A": 0.01}),
    (dict(axis="C"), "angles", "reversal_halfwidth", (5 * ARCSEC,), {}),
    (dict(axis="A"), "patent", "angular_short_period_halfwidth", 5 * ARCSEC, {}),
    (dict(axis="C", z_follows_surface=False, sensor_range_mm=25.0), "angles",
     "sensor_linearity_halfwidth", (3.2e-4, 3.2e-4), {"EA0C": 0.08, "EB0C": 0.08}),
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
