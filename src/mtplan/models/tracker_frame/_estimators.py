"""tracker_frame's estimators: the registration on the bed marks, the line and circle fits
and the patent's construction (``patent``, ``angles``, ``home``), and the generalised
least-squares fit of the whole forward model (``gls``).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from mtplan._parallel import one_blas_thread
from mtplan._validate import InvalidInput
from mtplan.fitting import Gaussian, SourceModel, central_jacobian, gauss_newton, gls_gain
from mtplan.fitting.effects import secant_effects
from mtplan.fitting.fit3d import (
    common_perpendicular,
    fit_circle_3d,
    fit_circle_3d_angles,
    fit_line_3d,
)
from mtplan.models import _temperature as temperature
from mtplan.models.tracker_frame._geometry import (
    angles as _angles,
    cyc as _cyc,
    orthonormal as _orthonormal,
)
from mtplan.models.tracker_frame._layout import (
    arc_angles as _arc_angles,
    bed_marks as _marks,
    n_points as _n_points,
    nominal_origins as _nominal_origins,
    slices as _slices,
)
from mtplan.models.tracker_frame._physics import (
    forward,
    sources,
    true_values,
    truth_from_estimate,
)
from mtplan.models.tracker_frame._setup import AXES, NAME, PARALLEL_SIN, Setup, Truth
from mtplan.models.protocol import zero_errors


def _cartesian(readings: dict) -> np.ndarray:
    d = np.asarray(readings["distance_mm"], dtype=float)
    az = np.asarray(readings["azimuth_rad"], dtype=float)
    el = np.asarray(readings["elevation_rad"], dtype=float)
    ce = np.cos(el)
    return np.stack([d * ce * np.cos(az), d * ce * np.sin(az), d * np.sin(el)], axis=-1)


def _corrected_readings(setup: Setup, readings: dict) -> dict:
    """The readings with the elevations and azimuths corrected for the measured air
    gradients, vertical and horizontal (unchanged where they were not measured)."""
    g = temperature.gradient(setup, "air_gradient")
    gx, gy = temperature.horizontal_gradient(setup, "air_gradient")
    if not (g or gx or gy):
        return readings
    d = np.asarray(readings["distance_mm"], dtype=float)
    el = temperature.unbend(readings["elevation_rad"], d, g) if g else readings["elevation_rad"]
    out = {**readings, "elevation_rad": el}
    if gx or gy:
        out["azimuth_rad"] = temperature.unswerve(readings["azimuth_rad"], d,
                                                  d * np.cos(np.asarray(el)), gx, gy)
    return out


def _register(setup: Setup, tracker_marks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid transform (R (n,3,3), t (n,3)) with global = R v + t (Kabsch)."""
    stated = _marks(setup)
    sc = stated.mean(axis=0)
    mc = tracker_marks.mean(axis=-2)
    h = np.einsum("nmi,mj->nij", tracker_marks - mc[:, None, :], stated - sc)
    u, _, vt = np.linalg.svd(h)
    det = np.linalg.det(vt.transpose(0, 2, 1) @ u.transpose(0, 2, 1))
    dm = np.broadcast_to(np.eye(3), h.shape).copy()
    dm[:, 2, 2] = np.sign(det)
    rot = vt.transpose(0, 2, 1) @ dm @ u.transpose(0, 2, 1)
    return rot, sc - np.einsum("nij,nj->ni", rot, mc)


def _on_distinct(fit, points: np.ndarray):
    """``fit(points)`` for points (n, m, 3), each distinct row of points fitted once.

    The rows of a linearisation (the estimator map of the first-order prediction) differ
    from the error-free readings in one reading each, so most rows of a group of points are the same
    points: a circle of 7 points sees 42 of 588 rows moved, plus those of the bed marks
    (which move every point through the registration). Rows are matched by a weighted sum
    of their coordinates and then checked equal number for number, so a fit is only ever
    shared by identical points (each row is fitted on its own: the same numbers). A
    Monte Carlo batch, with no two rows alike, is fitted as it is.
    """
    n = points.shape[0]
    flat = points.reshape(n, -1)
    _, first, inverse = np.unique(flat @ np.linspace(1.0, 2.0, flat.shape[1]),
                                  return_index=True, return_inverse=True)
    if 2 * first.size > n or not np.array_equal(flat[first][inverse], flat):
        return fit(points)
    out = fit(points[first])
    return type(out)(*(v[inverse] if np.ndim(v) and np.shape(v)[0] == first.size else v
                       for v in out))


def _fit_arcs_patent(setup: Setup, pts: dict, k: int) -> dict:
    """The patent's 3D circles (no angles); refuses arcs whose fit does not converge."""
    fits = {}
    for g, arc in (("C", setup.c_arc_deg), ("A", setup.a_arc_deg)):
        fit = _on_distinct(fit_circle_3d, pts[g])
        fail = ~np.asarray(fit.converged)
        if np.any(fail):
            raise InvalidInput([
                f"The 3D circle fit of the {g} arc of sub-machine {k} did not converge in "
                f"{int(fail.sum())} of {fail.size} measurement(s): over {arc:g} deg the "
                "points lie nearly on a straight line for their noise, so the circle and "
                f"the {g} axis are not determined. Use a longer arc ({g.lower()}_arc_deg) "
                "or more points."])
        fits[g] = fit
    return fits


def _fit_arcs_angles(setup: Setup, pts: dict, k: int) -> dict:
    """Circles fitted with the commanded angles of the arc points (closed form)."""
    q = setup.points_per_arc
    return {g: _on_distinct(functools.partial(
        fit_circle_3d_angles, angles=np.radians(_arc_angles(arc, q))), pts[g])
            for g, arc in (("C", setup.c_arc_deg), ("A", setup.a_arc_deg))}


def _fit_arcs_home(setup: Setup, pts: dict, k: int) -> dict:
    """Circles with the commanded angles through the arc points and the home position.

    The linear travels run symmetrically about home, so the mean of their points is the
    reflector at home, the point at angle 0 of both arcs: it joins each arc's fit with
    the weight of the number of linear points it averages.
    """
    q = setup.points_per_arc
    home = np.concatenate([pts[ax] for ax in AXES], axis=1)
    weights = np.r_[np.ones(q), home.shape[1]]
    home = home.mean(axis=1, keepdims=True)
    return {g: _on_distinct(functools.partial(
        fit_circle_3d_angles, angles=np.r_[np.radians(_arc_angles(arc, q)), 0.0],
        weights=weights), np.concatenate([pts[g], home], axis=1))
            for g, arc in (("C", setup.c_arc_deg), ("A", setup.a_arc_deg))}


def _estimate(setup: Setup, readings: dict, fit_arcs) -> dict[str, np.ndarray]:
    """Registration, lines, the arcs by `fit_arcs`, then the patent's construction."""
    xyz = _cartesian(_corrected_readings(setup, readings))
    rot, t = _register(setup, xyz[:, :4])
    glob = xyz @ np.swapaxes(rot, -1, -2) + t[:, None, :]  # R v + t (a product: einsum's
    # loop over the batch took 20 times as long)
    dt_ref = temperature.deviation(setup, "structure_temperature")
    if dt_ref:  # to 20 degC: the structure shrunk back about the marks' centroid
        centroid = _marks(setup).mean(axis=0)
        glob = centroid + (glob - centroid) / (1.0 + setup.structure_expansion_ppm_per_k
                                               * 1e-6 * dt_ref)
    sl = _slices(setup)
    nominal = _nominal_origins(setup)
    dot = lambda a, b: np.einsum("ni,ni->n", a, b)  # noqa: E731
    out = {}
    for k in range(1, setup.n_submachines + 1):
        pts = {g: glob[:, sl[(g, k)]] for g in ("X", "Y", "Z", "C", "A")}
        ux, uy, uz = (_on_distinct(lambda p: fit_line_3d(p, orient=p[:, -1] - p[:, 0]),
                                   pts[ax]).direction for ax in AXES)
        arcs = fit_arcs(setup, pts, k)
        c_fit, a_fit = arcs["C"], arcs["A"]
        _, wrist, offset, sin_ac = common_perpendicular(a_fit.centre, a_fit.normal,
                                                        c_fit.centre, c_fit.normal)
        bad = sin_ac < PARALLEL_SIN
        if np.any(bad):
            raise InvalidInput([
                f"The fitted A and C axes of sub-machine {k} are parallel (angle "
                f"{np.min(sin_ac) * 1e6:.3g} urad) in {int(bad.sum())} of {bad.size} "
                "measurement(s): their common perpendicular, and so the wrist centre, is "
                "undefined."])
        origin = wrist - setup.pivot_length_mm * c_fit.normal - nominal[k - 1]
        rx, ry, rz = _angles(_orthonormal(setup, ux, uy, uz))
        out.update({
            f"origin_x_{k}": origin[:, 0], f"origin_y_{k}": origin[:, 1],
            f"origin_z_{k}": origin[:, 2],
            f"rot_x_{k}": rx, f"rot_y_{k}": ry, f"rot_z_{k}": rz,
            f"ac_offset_{k}": offset,
            f"sq_xy_{k}": np.arcsin(dot(ux, uy)), f"sq_yz_{k}": np.arcsin(dot(uy, uz)),
            f"sq_zx_{k}": np.arcsin(dot(uz, ux)),
        })
    return out


def estimate_patent(setup: Setup, readings: dict) -> dict[str, np.ndarray]:
    """The source method: lines, 3D circles, common perpendicular, cross-product frame.

    Parameters
    ----------
    setup : Setup
    readings : dict
        ``distance_mm``, ``azimuth_rad``, ``elevation_rad``, each (n, points).

    Returns
    -------
    dict of measurand name -> array (n,) in mm and rad.
    """
    return _estimate(setup, readings, _fit_arcs_patent)


def estimate_angles(setup: Setup, readings: dict) -> dict[str, np.ndarray]:
    """The source method, with the A and C circles fitted at the commanded angles.

    Each arc is fitted as ``p_i = c + R (cos(theta_i + phi0) e1 + sin(theta_i + phi0)
    e2)`` with the commanded angles theta_i of the set-up (the ``angle_deg`` column of
    the readings table), in closed form (:func:`fit_circle_3d_angles`); the axis line
    is the normal ``e1 x e2`` through c. Everything after the axis lines is the patent's.
    """
    return _estimate(setup, readings, _fit_arcs_angles)


def estimate_home(setup: Setup, readings: dict) -> dict[str, np.ndarray]:
    """The source method, with the circles fitted at the commanded angles and through the
    home position that every group of points shares.

    The reflector at home is on every group of points: the middle of each linear
    travel and angle 0 of each arc. The mean of the linear points (symmetric about
    home) estimates it from 3 ``points_per_axis`` readings; it joins each arc's fit as
    a point at angle 0 of that weight (:func:`_fit_arcs_home`).
    """
    return _estimate(setup, readings, _fit_arcs_home)


# --------------------------------------------------------------------------- gls
#: Truth fields of each sub-machine that the ``gls`` fit estimates (tuples, one per head)
_GLS_HEAD = ("wrist_dx_um", "wrist_dy_um", "wrist_dz_um", "frame_rx_urad", "frame_ry_urad",
             "frame_rz_urad", "sq_xy_urad", "sq_yz_urad", "sq_zx_urad", "c_tilt_x_urad",
             "c_tilt_y_urad", "a_tilt_y_urad", "a_tilt_z_urad", "ac_offset_um")


#: the tracker's pose fields it estimates
_GLS_TRACKER = ("tracker_dx_um", "tracker_dy_um", "tracker_dz_um", "tracker_tilt_x_urad",
                "tracker_tilt_y_urad", "tracker_yaw_deg")


#: central-difference steps [um, urad, deg]: 0.1 um, 0.1 urad, 0.1 urad of yaw
_GLS_STEP = {"deg": math.degrees(1e-7), "um": 0.1, "urad": 0.1}


def _gls_names(setup: Setup) -> list[tuple[str, int | None]]:
    """The fitted parameters in order: (field, sub-machine index or None)."""
    return ([(f, k) for k in range(setup.n_submachines) for f in _GLS_HEAD]
            + [(f, None) for f in _GLS_TRACKER])


def _gls_truth(setup: Setup, base: Truth, theta: np.ndarray) -> Truth:
    """``base`` with the fitted fields set from parameter rows ``theta`` (m, p): a batch of
    truths (``Truth.batch``, arrays (m,), one truth per row; no validation)."""
    n = setup.n_submachines
    changes: dict = {}
    heads: dict[str, list] = {f: [None] * n for f in _GLS_HEAD}
    for j, (f, k) in enumerate(_gls_names(setup)):
        if k is None:
            changes[f] = np.ascontiguousarray(theta[:, j])
        else:
            heads[f][k] = np.ascontiguousarray(theta[:, j])
    return Truth.batch(base, **changes, **{f: tuple(v) for f, v in heads.items()})


def _gls_vector(readings: dict) -> np.ndarray:
    """Readings as rows (n, 3 points): distance [mm], azimuth, elevation [rad]."""
    return np.concatenate([np.asarray(readings[k], dtype=float)
                           for k in ("distance_mm", "azimuth_rad", "elevation_rad")], axis=-1)


def _gls_predict(setup: Setup, base: Truth, theta: np.ndarray) -> np.ndarray:
    """Error-free readings (m, 3 points) for parameter rows ``theta`` (m, p)."""
    errors = zero_errors(sources(setup), theta.shape[0])
    return _gls_vector(forward(setup, _gls_truth(setup, base, theta), errors))


def _gls_residual(setup: Setup, y: np.ndarray, pred: np.ndarray) -> np.ndarray:
    r = y - pred
    p = _n_points(setup)
    r[:, p:] = (r[:, p:] + np.pi) % (2 * np.pi) - np.pi  # angles: wrap
    return r


@functools.lru_cache(maxsize=16)
def _gls_gain(setup: Setup, base: Truth, ref: tuple) -> np.ndarray:
    """Gain K (p, 3 points) of the generalised least squares at the parameters ``ref``.

    ``K = (J^T C^-1 J)^-1 J^T C^-1`` (:func:`mtplan.fitting.gls_gain`) with ``J`` the
    readings' Jacobian (central differences) and ``C`` (plus a floor of 1 nm and
    0.1 nrad) their covariance under every active error source of the set-up, by the
    secant effect of each element of a source at the same parameters
    (:func:`mtplan.fitting.readings_covariance`'s numbers, from grouped rows:
    :func:`mtplan.fitting.effects.secant_effects`). The readings are few (3 per point), so
    ``C`` is formed and factorised, scaled to unit diagonal.
    """
    theta = np.asarray(ref, dtype=float)[None, :]
    steps = np.array([_GLS_STEP[f.rsplit("_", 1)[1]] for f, _ in _gls_names(setup)])
    jac = central_jacobian(lambda rows: _gls_predict(setup, base, rows), theta[0], steps)
    model = SourceModel(
        NAME, sources(setup),
        lambda errors: _gls_vector(forward(setup, _gls_truth(setup, base, np.repeat(
            theta, next(iter(errors.values())).shape[0], axis=0)), errors)),
        lambda m: zero_errors(sources(setup), m))
    # a floor far below any source's effect (1 nm, 0.1 nrad), so that readings no source
    # moves (or a set-up without sources) keep a weight and C stays regular
    floor = np.repeat([1e-6, 1e-10, 1e-10], _n_points(setup))
    D, U = secant_effects(model, key=(NAME, setup))  # readings_covariance's numbers
    return gls_gain(jac, Gaussian.known(D + floor**2, U))


def _gls_start(setup: Setup, readings: dict) -> tuple[Truth, np.ndarray]:
    """The start of the fit: the ``home`` estimate of the first trial as a Truth (head
    tilts zero), the tracker's pose from the registration on the marks; (truth, theta (p,))."""
    home = estimate_home(setup, {k: np.asarray(v)[:1] for k, v in readings.items()})
    base = truth_from_estimate(setup, home)
    rot, t = _register(setup, _cartesian({k: np.asarray(v)[:1] for k, v in
                                          readings.items()})[:, :4])
    tx, ty, yaw = _angles(rot[0])
    d = (t[0] - np.array([-setup.tracker_distance_mm, 0.0, setup.tracker_height_mm])) * 1e3
    base = dataclasses.replace(base, tracker_dx_um=float(d[0]), tracker_dy_um=float(d[1]),
                               tracker_dz_um=float(d[2]), tracker_tilt_x_urad=float(tx) * 1e6,
                               tracker_tilt_y_urad=float(ty) * 1e6,
                               tracker_yaw_deg=float(np.degrees(yaw)))
    theta = np.array([float(_cyc(getattr(base, f), k)) if k is not None
                      else float(getattr(base, f)) for f, k in _gls_names(setup)])
    return base, theta


def _gls_key(setup: Setup, theta: np.ndarray) -> tuple:
    """Parameters rounded to 10 um, 10 urad and 1e-3 deg (17 urad): where the gain is
    taken (its cache key, so that a Monte Carlo's blocks, whose starts scatter by a few
    micrometres, share it). Noise-free the fit's fixed point does not depend on where
    the gain was taken; with noise the weighting changes by second-order amounts."""
    grid = np.array([1e-3 if f.endswith("_deg") else 10.0 for f, _ in _gls_names(setup)])
    return tuple(float(f"{v:.10g}") for v in np.round(np.asarray(theta) / grid) * grid)


def estimate_gls(setup: Setup, readings: dict, *, iterations: int = 30) -> dict[str, np.ndarray]:
    """Generalised least squares (GLS) of the whole forward model to all readings.

    The parameters are the head's geometry of every sub-machine (:data:`_GLS_HEAD`) and
    the tracker's pose; the pivot-length error and the A-C angle are held. The weights
    are the inverse covariance of the readings under every active error source
    (:func:`_gls_gain`). Gauss-Newton with one gain for the whole batch
    (:func:`mtplan.fitting.gauss_newton`), taken at the start (:func:`_gls_start`) and
    re-taken once at the batch's median; the measurands
    are the construction applied to the fitted geometry (:func:`true_values`).
    """
    # matrices of a few hundred rows: a team of BLAS threads costs more than it gains
    # (3 times, on a busy machine), so the fit runs on one
    with one_blas_thread():
        return _estimate_gls(setup, readings, iterations)


def _estimate_gls(setup: Setup, readings: dict, iterations: int) -> dict[str, np.ndarray]:
    y = _gls_vector(readings)
    start_truth, start = _gls_start(setup, readings)
    # the gain depends on the held fields only (the fitted ones come from theta)
    base = Truth(pivot_length_error_um=start_truth.pivot_length_error_um,
                 ac_angle_deg=start_truth.ac_angle_deg)
    fit = gauss_newton(lambda th: _gls_residual(setup, y, _gls_predict(setup, base, th)),
                       np.repeat(start[None, :], y.shape[0], axis=0),
                       _gls_gain(setup, base, _gls_key(setup, start)),
                       iterations=iterations, tol=1e-7,  # [um, urad]
                       regain_after=(2,), regain=lambda th: _gls_gain(
                           setup, base, _gls_key(setup, np.median(th, axis=0))))
    theta = np.where(fit.ok[:, None], fit.theta, np.nan)
    return true_values(setup, _gls_truth(setup, base, theta))
