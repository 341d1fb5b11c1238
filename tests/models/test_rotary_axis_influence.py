"""rotary_axis's angle influence as an unknown function within the data sheet's bound.

The data sheet bounds the influence at each tilt, |e| <= range B(tau), and states neither
a shape in tilt nor a split into even, odd and anisotropic parts. The source's draws stay
within that bound at every reading, each part reaches the whole bound, and the weight of
gls and angles (and with it the first-order budget) is the covariance of those draws and
nothing else.
"""

from __future__ import annotations

import numpy as np
import pytest

from mtplan.models import get
from mtplan.models.rotary_axis._layout import INFLUENCE_PARTS, _tilt_bound, plan

PROC = get("rotary_axis")
BOUND = 5000e-6  # the default bound at 30 deg, a fraction of the range


def _influence(setup, elements):
    """The influence's height error of every reading (n, P, R) [mm] for elements (n, K, 4)."""
    err = PROC.zero_errors(setup, len(elements))
    base = PROC.forward(setup, PROC.Truth(), err)["z_mm"]
    err["angle_influence_halfwidth"] = np.asarray(elements, dtype=float)
    return PROC.forward(setup, PROC.Truth(), err)["z_mm"] - base


@pytest.mark.parametrize("values", [dict(axis="A"), dict(axis="CA", sensor_reversal=True)])
def test_draws_stay_within_the_bound_and_each_part_reaches_it(values):
    from mtplan.models.rotary_axis import tilts

    setup = PROC.setup(**values)
    src = PROC.sources(setup)["angle_influence_halfwidth"]
    bound = setup.sensor_range_mm * _tilt_bound(tilts(setup)[0])[:, None] * BOUND  # (P, 1) [mm]
    # 2000 draws and every corner of the elements' box along each knot: never beyond
    draws = src.distribution.draw(np.random.default_rng(5), (2000, *src.shape))
    corners = np.sign(np.random.default_rng(6).standard_normal((200, *src.shape))) * BOUND
    for e in (_influence(setup, draws), _influence(setup, corners)):
        assert np.all(np.abs(e) <= bound * (1 + 1e-9))
    # the even part, the odd part and the anisotropy each alone at the whole bound:
    # B(tau) (1, cos phi, cos 2 phi) at every reading (B's own shape is one of the spans)
    k = src.shape[0]
    tau, azimuth = tilts(setup)
    phi = azimuth - np.radians(setup.sensor_azimuth_deg)
    sign = plan(setup).sensor_sign
    shapes = [np.ones_like(phi)[:, None] + 0 * sign, np.cos(phi)[:, None] * sign,
              np.cos(2 * phi)[:, None] + 0 * sign]
    for part, shape in enumerate(shapes):
        e = _influence(setup, np.outer(np.ones(k), INFLUENCE_PARTS[part] * BOUND)[None])[0]
        np.testing.assert_allclose(e, bound * shape, rtol=1e-9, atol=1e-15)


def test_the_weight_is_the_covariance_of_the_draws():
    # the planes' covariance from the source's effects (what the gls/angles weight and the
    # first-order budget take) equals the covariance of the drawn errors through the plane
    # fit: 4000 draws, each entry within 5 standard errors of a sample covariance
    from mtplan.fitting import SourceModel, source_effects
    from mtplan.models.rotary_axis._estimators import _pass_mean, _planes

    setup = PROC.setup(axis="A")
    src = PROC.sources(setup)

    def planes(errors):
        z = _pass_mean(setup, PROC.forward(setup, PROC.Truth(), errors)["z_mm"])
        return _planes(setup, z).reshape(len(z), -1)

    model = SourceModel("rotary_axis", src, planes, lambda m: PROC.zero_errors(setup, m))
    _, U = source_effects(model, ["angle_influence_halfwidth"])
    cov = U @ U.T
    n = 4000
    err = PROC.zero_errors(setup, n)
    s = src["angle_influence_halfwidth"]
    err["angle_influence_halfwidth"] = s.distribution.draw(np.random.default_rng(11),
                                                           (n, *s.shape))
    x = planes(err) - planes(PROC.zero_errors(setup, 1))
    sample = x.T @ x / n  # the mean is zero by symmetry
    se = np.sqrt((np.outer(np.diag(cov), np.diag(cov)) + cov**2) / n)
    assert np.all(np.abs(sample - cov) <= 5 * se + 1e-9 * cov.diagonal().max())


def test_a_tilt_beyond_the_data_sheet_is_noted_in_every_output():
    # the data sheet's table ends at 30 deg; the patent's A test (+-45 deg at a 20 deg
    # incline) tilts the surface to 48.4 deg, where the bound is the last segment's slope
    # run on, accepted with sensor_extrapolate_table: the set-up says so, and the
    # linearisation's notes carry it (simulate's findings and estimate's notes start from
    # the set-up's notes; tests/test_datasheet.py checks every output)
    from mtplan.evaluation.simulation import linearize_result
    from mtplan.models.protocol import DATASHEET_NOTE

    wide = dict(axis="A", incline_deg=20.0, range_deg=90.0, sensor_max_tilt_deg=50.0,
                sensor_extrapolate_table=True)
    note = PROC.setup(wide).notes()
    assert len(note) == 1 and note[0].startswith(DATASHEET_NOTE)
    assert "48.4 deg" in note[0] and "A = -45 deg" in note[0] and "4 of 7 positions" in note[0]
    assert "extrapolated" in note[0] and "8672 ppm" in note[0] and "200 ppm" in note[0]
    assert note[0] in linearize_result(PROC, PROC.setup(wide), estimator="patent").notes
    for axis in ("C", "A", "CA"):
        assert PROC.setup(axis=axis).notes() == []  # the defaults stay within the table
    assert PROC.setup(wide, angle_influence_halfwidth_ppm=0.0).notes() == []