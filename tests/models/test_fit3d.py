"""Batch-first orthogonal-distance fits in 3D (mtplan.fitting.fit3d).

Cases are constructed here (the TraCIM comparison is the ad-hoc script
benchmarks/validate_fit3d_tracim.py, which reads ../shared and is not a test):
exact points on known lines, planes and circles; noisy circles checked against an
independent fit (scipy's least_squares with another parametrisation and the
distance written out directly); the circle with known angles (closed form) against
an iterative least-squares fit of the same model; and skew lines with a known common
perpendicular.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from mtplan.fitting.fit3d import (
    _kasa_start,
    circle_residuals,
    common_perpendicular,
    fit_circle_3d,
    fit_circle_3d_angles,
    fit_line_3d,
    fit_plane,
)


def _basis(normal):
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    e = np.eye(3)[np.argmin(np.abs(n))]
    u = np.cross(n, e)
    u /= np.linalg.norm(u)
    return n, u, np.cross(n, u)


def _circle_points(centre, normal, radius, angles_deg):
    n, u, v = _basis(normal)
    t = np.radians(angles_deg)[:, None]
    return np.asarray(centre) + radius * (np.cos(t) * u + np.sin(t) * v)


def _distance_to_circle(p, c, n, r):
    """Orthogonal distance of points to a circle, written out without mtplan.fitting.fit3d."""
    q = p - c
    h = q @ n
    rho = np.linalg.norm(q - np.outer(h, n), axis=1)
    return np.sqrt(h**2 + (rho - r) ** 2)


def test_line_exact_and_batched():
    rng = np.random.default_rng(0)
    point, d = np.array([120.0, -40.0, 800.0]), np.array([0.3, -0.2, 0.93])
    d /= np.linalg.norm(d)
    s = np.linspace(-500, 500, 11)
    pts = point + s[:, None] * d
    fit = fit_line_3d(pts, orient=d)
    np.testing.assert_allclose(fit.direction, d, atol=1e-15)
    np.testing.assert_allclose(fit.point, point, atol=1e-12)
    batch = pts + rng.normal(0, 0.01, (4, 2, 11, 3))
    fit = fit_line_3d(batch, orient=d)
    assert fit.direction.shape == (4, 2, 3) and fit.point.shape == (4, 2, 3)
    # the total-least-squares direction is the first right singular vector
    q = batch[1, 0] - batch[1, 0].mean(axis=0)
    v = np.linalg.svd(q)[2][0]
    np.testing.assert_allclose(fit.direction[1, 0], v * np.sign(v @ d), atol=1e-13)


def test_plane_exact_and_noisy():
    rng = np.random.default_rng(1)
    n, u, v = _basis([0.1, -0.2, 1.0])
    grid = np.array([[a, b] for a in np.linspace(-50, 50, 4) for b in np.linspace(-30, 30, 3)])
    pts = np.array([10.0, 20.0, 30.0]) + grid[:, :1] * u + grid[:, 1:] * v
    fit = fit_plane(pts, orient=n)
    np.testing.assert_allclose(fit.normal, n, atol=1e-15)
    noisy = pts + rng.normal(0, 0.01, (3, *pts.shape))
    fit = fit_plane(noisy, orient=n)
    q = noisy[2] - noisy[2].mean(axis=0)
    w = np.linalg.svd(q)[2][2]
    np.testing.assert_allclose(fit.normal[2], w * np.sign(w @ n), atol=1e-13)


@pytest.mark.parametrize("arc", [360.0, 90.0, 20.0])
def test_circle_exact_points(arc):
    centre, normal, r = np.array([-400.0, 150.0, 900.0]), np.array([0.2, 0.9, -0.3]), 137.0
    n = normal / np.linalg.norm(normal)
    m = 7
    ang = np.linspace(-arc / 2, arc / 2, m, endpoint=arc < 360)
    pts = _circle_points(centre, n, r, ang)
    fit = fit_circle_3d(pts)
    # points are in counter-clockwise order about n: the default orientation
    np.testing.assert_allclose(fit.normal, n, atol=1e-13)
    np.testing.assert_allclose(fit.centre, centre, atol=1e-9)
    np.testing.assert_allclose(fit.radius, r, atol=1e-9)
    assert fit.converged


def test_circle_symmetric_case_known_solution():
    # Even points round a full circle, heights alternately +-d and radii alternately
    # R +- e: by symmetry the best circle is the nominal one.
    ang = np.arange(8) * 45.0
    pts = _circle_points([0, 0, 0], [0, 0, 1], 1.0, ang)
    sign = np.where(np.arange(8) % 2 == 0, 1.0, -1.0)
    pts = pts * (1 + 0.01 * sign)[:, None] * 50.0
    pts[:, 2] = 0.2 * sign
    fit = fit_circle_3d(pts, orient=[0, 0, 1])
    np.testing.assert_allclose(fit.centre, 0.0, atol=1e-12)
    np.testing.assert_allclose(fit.normal, [0, 0, 1], atol=1e-14)
    np.testing.assert_allclose(fit.radius, 50.0, atol=1e-12)


def _scipy_circle(p, start):
    """Independent full-3-D circle fit: normal as spherical angles, distance written out."""
    c0, n0, r0 = start
    th0, ph0 = np.arccos(n0[2]), np.arctan2(n0[1], n0[0])

    def res(x):
        n = np.array([np.sin(x[3]) * np.cos(x[4]), np.sin(x[3]) * np.sin(x[4]), np.cos(x[3])])
        q = p - x[:3]
        h = q @ n
        rho = np.linalg.norm(q - np.outer(h, n), axis=1)
        return np.concatenate([h, rho - x[5]])

    sol = least_squares(res, np.r_[c0, th0, ph0, r0], xtol=1e-15, ftol=1e-15, gtol=1e-15,
                        method="lm")
    x = sol.x
    n = np.array([np.sin(x[3]) * np.cos(x[4]), np.sin(x[3]) * np.sin(x[4]), np.cos(x[3])])
    return x[:3], n, x[5]


@pytest.mark.parametrize("arc,noise", [(300.0, 0.05), (40.0, 0.01)])
def test_circle_noisy_against_independent_fit(arc, noise):
    rng = np.random.default_rng(7)
    centre, normal, r = np.array([30.0, -20.0, 500.0]), np.array([0.3, -0.1, 0.95]), 80.0
    n = normal / np.linalg.norm(normal)
    pts = _circle_points(centre, n, r, np.linspace(-arc / 2, arc / 2, 9))
    batch = pts + rng.normal(0, noise, (6, *pts.shape))
    fit = fit_circle_3d(batch, orient=n)
    assert fit.centre.shape == (6, 3) and fit.radius.shape == (6,) and np.all(fit.converged)
    for i in range(6):
        c, nn, rr = _scipy_circle(batch[i], (centre, n, r))
        nn = nn * np.sign(nn @ n)
        np.testing.assert_allclose(fit.centre[i], c, atol=1e-8)
        np.testing.assert_allclose(fit.normal[i], nn, atol=1e-10)
        np.testing.assert_allclose(fit.radius[i], rr, atol=1e-8)
        # the objective is the sum of squared orthogonal distances to the curve
        h, d = circle_residuals(batch[i], fit.centre[i], fit.normal[i], fit.radius[i])
        np.testing.assert_allclose(
            h**2 + d**2, _distance_to_circle(batch[i], fit.centre[i], fit.normal[i],
                                             fit.radius[i]) ** 2, rtol=1e-9, atol=1e-15)


def test_full_3d_circle_is_not_plane_then_circle():
    # On a short noisy arc the full 3-D fit and plane-then-circle differ, and the
    # full 3-D fit has the smaller sum of squared 3-D distances.
    rng = np.random.default_rng(3)
    pts = _circle_points([0.0, 0.0, 0.0], [0, 0, 1], 100.0, np.linspace(-30, 30, 9))
    pts = pts + rng.normal(0, 0.05, pts.shape)
    fit = fit_circle_3d(pts, orient=[0, 0, 1])
    shift = pts.mean(axis=0)
    c0, n0, r0 = _kasa_start(pts - shift, [0, 0, 1])
    c0 = c0 + shift
    # plane-then-geometric circle: refine the circle within the fitted plane only
    _, u, v = _basis(n0)

    def in_plane(x):
        c = c0 + x[0] * u + x[1] * v
        return _distance_to_circle(pts, c, n0, x[2])

    sol = least_squares(in_plane, [0.0, 0.0, r0], xtol=1e-15, ftol=1e-15, gtol=1e-15)
    c_pc = c0 + sol.x[0] * u + sol.x[1] * v
    ss_3d = np.sum(_distance_to_circle(pts, fit.centre, fit.normal, fit.radius) ** 2)
    ss_pc = np.sum(_distance_to_circle(pts, c_pc, n0, sol.x[2]) ** 2)
    assert ss_3d < ss_pc
    assert np.max(np.abs(fit.centre - c_pc)) > 1e-6


def test_common_perpendicular_known_lines():
    d = 0.25
    pa, a = np.array([5.0, 0.0, d]), np.array([1.0, 0.0, 0.0])
    pb, b = np.array([0.0, -3.0, 0.0]), np.array([0.0, 1.0, 0.0])
    fa, fb, dist, s = common_perpendicular(pa, a, pb, b)
    np.testing.assert_allclose(fa, [0, 0, d], atol=1e-15)
    np.testing.assert_allclose(fb, [0, 0, 0], atol=1e-15)
    # signed along b x a = y x x = -z
    assert dist == pytest.approx(-d) and s == pytest.approx(1.0)
    # batch of two, the second rotated 30 deg about z and shifted
    rot = np.array([[np.cos(0.5), -np.sin(0.5), 0], [np.sin(0.5), np.cos(0.5), 0], [0, 0, 1]])
    fa2, fb2, dist2, _ = common_perpendicular(np.stack([pa, rot @ pa + 1]), np.stack([a, rot @ a]),
                                              np.stack([pb, rot @ pb + 1]), np.stack([b, rot @ b]))
    np.testing.assert_allclose(fb2[1], rot @ fb + 1, atol=1e-14)
    np.testing.assert_allclose(dist2, [-d, -d], atol=1e-15)


def test_common_perpendicular_parallel_lines_flagged():
    fa, fb, dist, s = common_perpendicular([0, 0, 1.0], [0, 0, 1.0], [1.0, 0, 0], [0, 0, 1.0])
    assert s == 0.0 and np.all(np.isnan(fa))


@pytest.mark.parametrize("fn,m", [(fit_line_3d, 1), (fit_plane, 2), (fit_circle_3d, 2)])
def test_too_few_points_or_bad_shape(fn, m):
    with pytest.raises(ValueError, match="points"):
        fn(np.zeros((m, 3)))
    with pytest.raises(ValueError, match="shape"):
        fn(np.zeros((5, 2)))


# --------------------------------------------------------------------------- known angles
@pytest.mark.parametrize("arc", [360.0, 60.0, 5.0])
def test_circle_with_angles_exact_points_and_phase(arc):
    normal, centre, radius, phase = [0.3, -0.5, 0.8], [10.0, -20.0, 5.0], 335.0, 0.7
    n, u, _ = _basis(normal)
    angles = np.linspace(-arc / 2, arc / 2, 7, endpoint=arc < 360)
    p = _circle_points(centre, normal, radius, angles + np.degrees(phase))
    fit = fit_circle_3d_angles(np.stack([p, p[::-1]]), np.radians([angles, angles[::-1]]))
    np.testing.assert_allclose(fit.centre, [centre] * 2, atol=1e-9)
    np.testing.assert_allclose(fit.normal, [n] * 2, atol=1e-12)  # right-handed about +angle
    np.testing.assert_allclose(fit.radius, radius, rtol=1e-13)
    zero = np.cos(phase) * u + np.sin(phase) * np.cross(n, u)
    np.testing.assert_allclose(fit.zero_direction, [zero] * 2, atol=1e-12)
    # the angles decide the handedness: the same points with negated angles turn the normal
    back = fit_circle_3d_angles(p, -np.radians(angles))
    np.testing.assert_allclose(back.normal, -n, atol=1e-12)


def test_circle_with_angles_is_the_least_squares_minimum():
    # an iterative fit of the same model (rotation vector, centre, radius) from a
    # perturbed start reaches the closed form's cost and parameters
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(7)
    th = np.radians(np.linspace(-10.0, 10.0, 7))
    p = _circle_points([1.0, 2.0, 3.0], [0.2, -0.3, 0.9], 335.0, np.degrees(th) + 17.0)
    noisy = p + rng.normal(0.0, 0.01, (4, 7, 3))
    fit = fit_circle_3d_angles(noisy, th)
    u = np.stack([np.cos(th), np.sin(th), 0 * th], axis=-1)
    for b in range(4):
        def res(x, b=b):
            q = Rotation.from_rotvec(x[3:6]).as_matrix()
            return (noisy[b] - x[:3] - x[6] * u @ q.T).ravel()

        q0 = np.stack([fit.zero_direction[b], np.cross(fit.normal[b], fit.zero_direction[b]),
                       fit.normal[b]], axis=-1)
        x0 = np.r_[fit.centre[b], Rotation.from_matrix(q0).as_rotvec(), fit.radius[b]]
        start = x0 + np.r_[0.05, -0.05, 0.05, 1e-3, -1e-3, 1e-3, 0.05]
        ls = least_squares(res, start, xtol=1e-15, ftol=1e-15, gtol=1e-15)
        cost0 = np.sum(res(x0) ** 2)
        assert cost0 <= np.sum(ls.fun**2) * (1 + 1e-9)
        np.testing.assert_allclose(ls.x[[0, 1, 2, 6]], x0[[0, 1, 2, 6]], atol=1e-4)


def test_circle_with_angles_radius_from_the_spacing_on_a_short_arc():
    # two points at a known angle step and one between: the radius follows from the chord,
    # R = chord / (2 sin(dtheta / 2)), even where the sagitta (R dtheta^2 / 8) is tiny
    th = np.radians([-1.0, 0.0, 1.0])
    p = _circle_points([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 100.0, np.degrees(th))
    moved = p.copy()
    moved[1] += 0.01 * (p[1] / 100.0)  # 10 um radial error at the middle point only
    fit = fit_circle_3d_angles(np.stack([p, moved]), th)
    chord = np.linalg.norm(p[2] - p[0])
    assert fit.radius[0] == pytest.approx(chord / (2 * np.sin(np.radians(1.0))), rel=1e-12)
    # the radial error of one point moves R by less than itself; through the sagitta
    # (15 um here) alone it would move R by tens of mm
    assert abs(fit.radius[1] - 100.0) < 0.01
    assert abs(fit_circle_3d(moved).radius - 100.0) > 10.0


def test_circle_with_angles_refuses_too_few_distinct_angles():
    p = _circle_points([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 100.0, np.array([0.0, 10.0, 20.0]))
    with pytest.raises(ValueError, match="3 distinct"):
        fit_circle_3d_angles(p, np.radians([0.0, 10.0, 370.0]))
    with pytest.raises(ValueError, match="shape"):
        fit_circle_3d_angles(p, np.radians([0.0, 10.0]))


def test_circle_with_angles_weights_equal_repeated_points():
    # a point of weight 3 counts as the same point taken three times
    rng = np.random.default_rng(5)
    angles = np.radians(np.linspace(-30, 30, 6))
    p = _circle_points([1.0, 2.0, 3.0], [0.1, 0.2, 1.0], 300.0, np.degrees(angles))
    p = p + rng.normal(0, 0.01, p.shape)
    w = np.array([1.0, 3.0, 1.0, 2.0, 1.0, 1.0])
    rep = np.repeat(np.arange(6), w.astype(int))
    a = fit_circle_3d_angles(p, angles, w)
    b = fit_circle_3d_angles(p[rep], angles[rep])
    for x, y in ((a.centre, b.centre), (a.normal, b.normal), (a.radius, b.radius)):
        np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-9)
    with pytest.raises(ValueError, match="'weights'"):
        fit_circle_3d_angles(p, angles, -w)
