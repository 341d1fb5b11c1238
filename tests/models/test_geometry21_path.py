"""geometry21: what a real machine's path does that the polynomials do not say.

The repeatability correlates along the path in millimetres (reading a pass more densely adds
readings, not independent information), and a repeatable short-wave residual beyond the
fitted polynomials, the same in every pass, carries the error of truncating the model into u.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mtplan.evaluation.simulation import linearize_procedure, simulate_uncertainty
from mtplan.models import geometry21 as g21

P = g21.PROCEDURE


def test_denser_lines_do_not_raise_u_ebx():
    """Under a correlation counted in readings u(EBX) grew from 8.66 to 9.71 urad as
    line_points went from 11 to 41, which the true covariance cannot do: more readings of the
    same path never lose information. In millimetres it does not grow (first order, the
    joint fit's own weights; every source)."""
    from mtplan.evaluation.first_order import first_order

    u = {n: first_order(P, P.setup(line_points=n), estimator="joint").u()["EBX"]
         for n in (11, 21, 41)}
    assert u[21] <= u[11] * (1 + 1e-3) and u[41] <= u[21] * (1 + 1e-3), u


def test_the_correlation_is_the_same_per_millimetre_at_every_spacing():
    """Readings 10 mm apart correlate by exp(-10 / 50) whether the line has 11 or 41 points:
    the filter's covariance F F^T along one line pass."""
    for n, k in ((11, 1), (41, 4)):  # 10 mm apart: neighbours at 11 points, 4 apart at 41
        setup = P.setup(line_points=n)
        f = g21.repeatability_filter(setup).toarray()
        c = (f @ f.T)[:n, :n]
        assert c[0, 0] == pytest.approx(1.0)
        assert c[3 * k, 4 * k] == pytest.approx(math.exp(-10.0 / 50.0), rel=1e-12)


def test_the_path_residual_is_the_same_in_every_pass_and_a_function_of_position():
    """Every reading at one commanded position sees the same residual, whatever its pass
    (the line repeats, forward and back); X's deviation along y moves the XY plate's v
    reading by the field's value at the reading's x, and readings 5 mm apart correlate by
    about exp(-1) (the field's correlation length)."""
    setup = P.setup(line_repeats=2)
    geo = g21.geometry(setup)
    basis = g21.residual_basis(g21.sizeless(setup)).reshape(geo.plane.size, 2, 3, 3, -1)
    xy = geo.plane == 0
    x_along_y = basis[xy, 1, 0, 1]  # (readings, knots): X's deviation along y on v
    assert np.abs(basis[xy, 0, 0, 1]).max() == 0.0  # nothing on u
    key = np.round(geo.cmd[xy], 9)
    _, inv = np.unique(key, axis=0, return_inverse=True)
    for g in range(inv.max() + 1):
        same = x_along_y[inv.ravel() == g]
        assert np.ptp(same, axis=0).max() < 1e-12
    # the field's covariance between readings on the x line (y = 0 of the XY plate)
    on_line = geo.test[xy] == 0
    x = geo.cmd[xy][on_line, 0]
    cov = x_along_y[on_line] @ x_along_y[on_line].T
    j, k = np.argmin(np.abs(x - 0.0)), np.argmin(np.abs(x - 5.0))
    assert abs(x[k] - x[j]) == pytest.approx(5.0)
    assert cov[j, k] / math.sqrt(cov[j, j] * cov[k, k]) == pytest.approx(math.exp(-1.0), abs=0.05)
    assert cov[j, j] == pytest.approx(1.0, abs=1e-12)  # at a knot: the field's variance


def test_the_path_residual_enters_u_as_stated():
    """The source alone (default 0.3 um RMS per axis and direction): Monte Carlo agrees with
    the first-order budget, and it moves every listed measurand (truncation in u):
    EXX 0.32 um, EXY 0.52 um, EBX 0.72 urad, EC0Y 9.9 urad (the lines' trend)."""
    setup = P.Setup()
    n = 2000
    mc = simulate_uncertainty(P, setup, estimator="joint", sources=["path_residual"],
                              trials=n, rng=3, progress=False)
    gum = linearize_procedure(P, setup, estimator="joint", sources=["path_residual"])
    np.testing.assert_allclose(mc.mc.std, gum.std, rtol=4 / math.sqrt(2 * (n - 1)))
    u = dict(zip([m.name for m in mc.measurands], gum.std))
    assert u["EXX"] == pytest.approx(0.322, rel=0.01)
    assert u["EXY"] == pytest.approx(0.523, rel=0.01)
    assert u["EBX"] == pytest.approx(0.723, rel=0.01)
    assert u["EC0Y"] == pytest.approx(9.93, rel=0.01)
    assert min(u.values()) > 0.2
    off = P.setup(path_residual_um=0.0)
    assert "path_residual" not in P.active_sources(off)


@pytest.mark.parametrize("field", ["path_residual", "medium_wave"])
def test_a_field_at_a_position_is_what_the_readings_see(field):
    """``residual_at`` (a simulated machine's unseen error at a table point, the truth of a
    closed loop of the compensation) is the field the readings carry: on the XY plate's x
    line X's deviation along x is the reading's u, at each reading's x; and the correction
    model's ``realised`` gives it per measurand, in um."""
    setup = P.setup(along_x_mm=(-25.0, 40.0))
    geo = g21.geometry(setup)
    errors = P.draw_errors(setup, 3, np.random.SeedSequence(7), only=[field])
    inn = errors[field]
    basis = g21.residual_basis(g21.sizeless(setup), field).reshape(geo.plane.size, 2, 3, 3, -1)
    line = np.flatnonzero((geo.plane == 0) & (geo.test == 0))
    seen = inn[:, 0, 0] @ basis[line, 0, 0, 0].T  # (trials, readings)
    at = g21.residual_at(setup, inn, 0, geo.cmd[line, 0], field)[:, :, 0]
    np.testing.assert_allclose(at, seen, rtol=0, atol=1e-12 * np.abs(seen).max())
    realised = P.correction.realised(setup, errors)
    x = g21.residual_at(setup, inn, 0, [-25.0, 40.0], field) * 1e3
    np.testing.assert_allclose(realised["EYX@40"], x[:, 1, 1], rtol=1e-12)
    assert "EXX@-25" in realised and "EAY@40" not in realised  # translations only
    with pytest.raises(ValueError, match="outside"):
        g21.residual_at(setup, inn, 0, [1e3], field)


def test_the_path_residual_is_the_error_function_s_own_direction():
    """X's field along x set equal to x on every knot moves the readings exactly as EXX's
    linear coefficient does (the sign and direction of the field's deviation are those of
    the error function it adds to)."""
    from mtplan.models.geometry21._jacobian import zero_jacobian
    from mtplan.models.geometry21._path import RESIDUAL_KNOT_MM, field_filter, residual_knots

    key = g21.sizeless(P.Setup())
    geo = g21.geometry(key)
    first, k = residual_knots(geo)
    inn = np.zeros((3, 3, k))
    inn[0, 0] = np.linalg.solve(field_filter(k), first + RESIDUAL_KNOT_MM * np.arange(k))
    moved = g21.residual_basis(key) @ inn.ravel()
    column = zero_jacobian(geo)[:, geo.layout["EXX"][1].start]
    np.testing.assert_allclose(moved, column, rtol=0, atol=1e-9 * np.abs(column).max())
