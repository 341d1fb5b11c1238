"""circle_centre's estimators: the patent's three-point formula, the algebraic and geometric
least-squares circles, the circle through every contact weighted by the set-up's error budget
(``gls``), each corrected to 20 degC; and the fit of measured points.
"""

from __future__ import annotations

import math

import numpy as np

from mtplan._validate import InvalidInput, Problems
from mtplan.fitting import gls_step
from mtplan.fitting.circle import geometric_fit, kasa_fit, three_point_circle
from mtplan.models.circle_centre._physics import (
    clamp_point as _clamp,
    scale_datum as _datum,
    sources,
)
from mtplan.models.circle_centre._setup import Setup, reference_deviations as _reference_deviations


def _to_20c(setup: Setup, cx, cy, r) -> tuple:
    """A circle read at the test's temperatures, corrected to 20 degC (ISO 1): the read
    coordinates scaled back about the scales' datum by 1 + alpha_scale dT_scale, then the
    part shrunk about its clamping point by 1 + alpha_part dT_part, with the reference
    temperatures (:func:`_reference_deviations`) and the stated alphas. Exact for a circle
    (both are similarities); the identity where nothing was measured."""
    dtp, dts = _reference_deviations(setup)
    if dtp == 0.0 and dts == 0.0:
        return cx, cy, r
    s = 1.0 + setup.scale_expansion_ppm_per_k * 1e-6 * dts
    g = 1.0 + setup.expansion_ppm_per_k * 1e-6 * dtp
    (dx, dy), (kx, ky) = _datum(setup), _clamp(setup)
    ax, ay = dx + s * (np.asarray(cx) - dx), dy + s * (np.asarray(cy) - dy)
    return kx + (ax - kx) / g, ky + (ay - ky) / g, s * np.asarray(r) / g


# --------------------------------------------------------------------------- estimators
def _xy(readings) -> tuple[np.ndarray, np.ndarray]:
    return (np.asarray(readings["x_mm"], dtype=float), np.asarray(readings["y_mm"], dtype=float))


def _three_indices(n: int, spread_deg: float) -> list[int]:
    if spread_deg >= 360.0:
        return [0, n // 3, (2 * n) // 3]
    return [0, (n - 1) // 2, n - 1]


def _result(circle, setup: Setup) -> dict:
    """The measurands of a circle fitted to read points, corrected to 20 degC."""
    cx, cy, r = _to_20c(setup, circle.xc, circle.yc, circle.r)
    return {"centre_x": np.asarray(cx), "centre_y": np.asarray(cy),
            "radius": np.asarray(r) - setup.bore_radius_mm}


def estimate_three_point(setup: Setup, readings: dict) -> dict:
    """The patent's a..f formula on d1, d2, d3 (or the best-spread triple of n points)."""
    x, y = _xy(readings)
    idx = _three_indices(x.shape[-1], setup.spread_deg)
    return _result(three_point_circle(x[..., idx], y[..., idx]), setup)


def estimate_kasa(setup: Setup, readings: dict) -> dict:
    """Algebraic (Kasa) least-squares circle through all measuring points."""
    x, y = _xy(readings)
    return _result(kasa_fit(x, y), setup)


def estimate_geometric(setup: Setup, readings: dict) -> dict:
    """Orthogonal-distance least-squares circle through all measuring points."""
    x, y = _xy(readings)
    return _result(geometric_fit(x, y), setup)


def _contacts(readings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every contact (..., m, 2) with its approach direction (..., m, 2) (NaN: radial): p1
    (along -y) and p2 (along +y) where the readings hold them, then d1..dn; and a mask (...)
    of the rows that hold p1, p2."""
    x, y = _xy(readings)
    d = np.stack([x, y], axis=-1)
    p = np.stack(np.broadcast_arrays(np.asarray(readings["p_x_mm"], dtype=float),
                                     np.asarray(readings["p_y_mm"], dtype=float)), axis=-1)
    p = np.broadcast_to(p, d.shape[:-2] + (2, 2))
    has_p = np.all(np.isfinite(p), axis=(-2, -1))
    pts = np.concatenate([p, d], axis=-2)
    approach = np.full(pts.shape, np.nan)
    approach[..., 0, :] = (0.0, -1.0)
    approach[..., 1, :] = (0.0, 1.0)
    return pts, approach, has_p


def _radial_covariance(setup: Setup, u, approach, radius, centre) -> np.ndarray:
    """Covariance (..., m, m) of the contacts' radial errors under the set-up's error budget.

    The linearised physics of :func:`forward` along each contact's outward unit radial
    `u` (..., m, 2), for a contact approached along `approach` (the radial where NaN), on
    the circle of `radius` (...) about `centre` (..., 2): probe noise and tip-radius error
    along the approach, the pre-travel's three lobes of the approach direction, the stage's
    repeatability (isotropic), scale and squareness errors (read = M^-1 actual, about the
    scales' datum), the bore's lobed form, and the temperatures and expansion coefficients
    (the part grows about its clamping point, the scales about their datum). Tangential
    slip moves contacts along the wall and start scatter moves the path: neither changes a
    contact's distance from the centre to first order.
    """
    src = sources(setup)
    sd = {k: np.asarray(v.distribution.std, dtype=float).reshape(-1)[0] for k, v in src.items()}
    a = np.where(np.isnan(approach), u, approach)
    cos_au = np.sum(a * u, axis=-1)
    c3, s3 = a[..., 0] * (4 * a[..., 0] ** 2 - 3), a[..., 1] * (3 - 4 * a[..., 1] ** 2)
    phi = np.arctan2(u[..., 1], u[..., 0])
    k = setup.lobes
    pts = np.asarray(centre)[..., None, :] + radius[..., None, None] * u
    from_datum = pts - _datum(setup)
    from_clamp = np.sum((pts - _clamp(setup)) * u, axis=-1)  # radial growth per unit strain
    along_datum = np.sum(from_datum * u, axis=-1)
    alpha_p = setup.expansion_ppm_per_k * 1e-6
    alpha_s = setup.scale_expansion_ppm_per_k * 1e-6
    dtp, dts = _reference_deviations(setup)
    sd_p = math.hypot(sd["part_temperature_u"], sd["part_temperature_halfwidth"])
    sd_s = math.hypot(sd["scale_temperature_u"], sd["scale_temperature_halfwidth"])
    follow = 1.0 if setup.scale_temperature_c is None else 0.0  # scales follow the part
    cols = [sd["pretravel_variation"] * c3 * cos_au, sd["pretravel_variation"] * s3 * cos_au,
            sd["tip_radius"] * cos_au,
            sd["roundness"] * np.cos(k * phi), sd["roundness"] * np.sin(k * phi),
            sd["scale_error"] * from_datum[..., 0] * u[..., 0],
            sd["scale_error"] * from_datum[..., 1] * u[..., 1],
            sd["squareness"] * from_datum[..., 1] * u[..., 0],
            sd_p * (alpha_p * from_clamp - follow * alpha_s * along_datum),
            sd_s * alpha_s * along_datum,
            sd["expansion_u"] * dtp * from_clamp,
            sd["scale_expansion_u"] * dts * along_datum]
    v = np.stack(cols, axis=-1)
    diag = (sd["probe_noise"] * cos_au) ** 2 + sd["stage_repeatability"] ** 2
    cov = v @ np.swapaxes(v, -1, -2)
    idx = np.arange(u.shape[-2])
    cov[..., idx, idx] += diag
    return cov


def estimate_gls(setup: Setup, readings: dict, iterations: int = 4) -> dict:
    """Circle through every contact, weighted by the set-up's error budget (generalised
    least squares of the radial residuals).

    Uses the path planner's p1 and p2 too where the readings hold them (a bare point file
    has d1..dn only): they are wall points, probed along -y and +y, and their chord's
    midpoint lies on the bore's centre line; the patent uses them only to plan the path.
    The residuals ``e_i = |p_i - c| - r`` are weighted by the inverse of their covariance
    under every error source of the set-up (:func:`_radial_covariance`, per trial, since
    the contacts' angles follow the start point): the bore's lobed form, the pre-travel
    lobes, the stage's scale and squareness act on several contacts at once, so an
    unweighted fit is not the best one. Gauss-Newton on the whole batch from the
    orthogonal-distance fit (:func:`mtplan.fitting.gls_step`); the weights are taken at
    each iterate.
    """
    pts, approach, has_p = _contacts(readings)
    if not np.all(has_p):  # rows without p1, p2: their measuring points alone
        pts = np.where(has_p[..., None, None], pts, np.concatenate(
            [pts[..., 2:3, :], pts[..., 2:3, :], pts[..., 2:, :]], axis=-2))
        approach = np.where(has_p[..., None, None], approach, np.nan)
    circle = geometric_fit(pts[..., 0], pts[..., 1])
    c = np.stack([circle.xc, circle.yc], axis=-1)
    r = np.asarray(circle.r, dtype=float)
    # a row without p1, p2 repeats d1 in their place: weight them out (no information)
    dup = np.broadcast_to(~has_p[..., None], r.shape + (2,))
    for _ in range(iterations):
        diff = pts - c[..., None, :]
        dist = np.linalg.norm(diff, axis=-1)
        u = diff / dist[..., None]
        e = dist - r[..., None]
        cov = _radial_covariance(setup, u, approach, r, c)
        big = 1e6 * np.max(np.diagonal(cov, axis1=-2, axis2=-1), axis=-1)
        cov[..., 0, 0] += np.where(dup[..., 0], big, 0.0)
        cov[..., 1, 1] += np.where(dup[..., 1], big, 0.0)
        jac = np.concatenate([-u, -np.ones(e.shape + (1,))], axis=-1)  # d e / d(xc, yc, r)
        step, _ = gls_step(jac, -e, cov)
        c = c + step[..., :2]
        r = r + step[..., 2]
    cx, cy, r = _to_20c(setup, c[..., 0], c[..., 1], r)
    return {"centre_x": cx, "centre_y": cy, "radius": r - setup.bore_radius_mm}


def gross_errors(setup, readings):
    """One bad contact of d1..dn (a chip, swarf, a late trigger) moves the point the probe
    reads along its probing direction, the bore's radius there: both of its read
    coordinates at once, in proportion. Of three points such an error is absorbed whole
    by the circle; a single coordinate's error is not, so each reading alone understates
    what a bad contact does unseen. The radius' direction is taken from the algebraic
    circle through the read points (a gross error of micrometres turns it by
    micro-radians)."""
    keys = [k for k, v in readings.items() if np.asarray(v).dtype.kind in "fiu"]
    sizes = {k: np.asarray(readings[k])[0].size for k in keys}
    start = dict(zip(keys, np.cumsum([0] + [sizes[k] for k in keys])[:-1], strict=True))
    x = np.asarray(readings["x_mm"], dtype=float)[0]
    y = np.asarray(readings["y_mm"], dtype=float)[0]
    circle = kasa_fit(x[None], y[None])
    ux, uy = x - float(circle.xc[0]), y - float(circle.yc[0])
    norm = np.hypot(ux, uy)
    D = np.zeros((sum(sizes.values()), x.size))
    on = np.arange(x.size)
    D[start["x_mm"] + on, on] = ux / norm
    D[start["y_mm"] + on, on] = uy / norm
    return "a contact along its probing direction", [f"contact d{i + 1}" for i in on], D


ESTIMATORS = {"three_point": estimate_three_point, "kasa": estimate_kasa,
              "geometric": estimate_geometric, "gls": estimate_gls}


#: each estimator as the documents describe it (plain words, jargon spelled out)
DESCRIPTIONS = {
    "three_point": "The source method's three-point formula on the three probed distances (with "
                   "more points, the triple spread best).",
    "kasa": "Algebraic least-squares circle (Kasa fit) through all measuring points.",
    "geometric": "Geometric least-squares circle (orthogonal distances) through all measuring "
                 "points.",
    "gls": "Circle through every contact, weighted by the set-up's error budget (generalised "
           "least squares, GLS, of the radial residuals).",
}


def fit_points(x_mm, y_mm, estimator: str = "geometric") -> dict:
    """Centre and radius of measured points, for ``mtplan estimate circle_centre``.

    Parameters
    ----------
    x_mm, y_mm : array_like (m,)
        Coordinates of the points on the bore wall [mm], at least 3 (exactly the three
        used points for ``three_point``: with more, the best-spread triple of a full
        circle, indices 0, m//3, 2m//3, is used, as in the simulation).
    estimator : {'geometric', 'kasa', 'three_point'}

    Returns
    -------
    dict
        ``centre_x_mm``, ``centre_y_mm``, ``radius_mm`` (floats).
    """
    p = Problems("fit_points")
    p.choice("estimator", estimator, ("geometric", "kasa", "three_point"))
    x = np.asarray(x_mm, dtype=float)
    y = np.asarray(y_mm, dtype=float)
    if x.ndim != 1 or x.shape != y.shape:
        p.add("x_mm", x.shape, f"a 1-D array of the same length as y_mm {y.shape}")
    elif x.size < 3:
        p.add("x_mm", x.size, "at least 3 points")
    elif not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        bad = np.flatnonzero(~(np.isfinite(x) & np.isfinite(y)))
        p.add_text(f"The points of fit_points must be finite numbers; rows {bad.tolist()} are not")
    p.raise_if_any()
    if estimator == "three_point":
        c = three_point_circle(x[None, _three_indices(x.size, 360.0)],
                               y[None, _three_indices(x.size, 360.0)])
    elif estimator == "kasa":
        c = kasa_fit(x[None], y[None])
    else:
        c = geometric_fit(x[None], y[None])
    out = {"centre_x_mm": float(c.xc[0]), "centre_y_mm": float(c.yc[0]),
           "radius_mm": float(c.r[0])}
    if not all(math.isfinite(v) for v in out.values()):
        raise InvalidInput(["The points of fit_points are collinear: no circle passes through "
                            "them."])
    return out
