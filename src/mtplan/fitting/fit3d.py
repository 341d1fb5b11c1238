"""Batch-first orthogonal-distance fits in 3D: line, plane, circle; common perpendicular.

Every function takes points of shape ``(..., m, 3)`` (any leading batch axes, e.g.
Monte Carlo trials) and fits all batches at once; there is no Python loop over the
batch. Lengths are in whatever unit the points are in (mm in mtplan).

- :func:`fit_line_3d`: the line minimising the sum of squared orthogonal distances
  (the centroid and the principal direction of the scatter matrix), as in the PTB
  TraCIM ``LINE_3D`` test.
- :func:`fit_plane`: the plane minimising the sum of squared orthogonal distances
  (the centroid and the direction of least scatter), as TraCIM ``PLANE``.
- :func:`fit_circle_3d`: the circle in space minimising the sum of squared **full 3-D
  orthogonal distances** from the points to the circle (a curve), as TraCIM
  ``CIRCLE``. The squared distance of a point p to the circle (centre c, unit normal
  n, radius r) is ``h**2 + (rho - r)**2`` with ``h = n.(p - c)`` its height over the
  circle's plane and ``rho`` its distance from the axis. This is *not* the same as
  fitting a plane first and a circle in that plane (which minimises ``h**2`` and
  ``(rho - r)**2`` in two separate problems); the two differ at second order in the
  residuals. The fit starts from plane-then-Kasa and iterates Levenberg-Marquardt
  on the whole batch with the analytic Jacobian, each batch element with its own
  damping.
- :func:`fit_circle_3d_angles`: the circle in space through points whose angles on
  it are known (a rotary axis's commanded positions): the least-squares fit of
  ``p_i = c + R (cos(theta_i + phi0) e1 + sin(theta_i + phi0) e2)`` over the centre
  c, the radius R and the orientation (normal ``n = e1 x e2`` and phase phi0). With
  ``Q = [e1', e2', n]`` (e1' the direction of angle 0) in SO(3) this is
  ``p_i = c + R Q (cos theta_i, sin theta_i, 0)``: a similarity transform of known
  planar points, solved in closed form (Umeyama 1991), exactly the least-squares
  minimum, with no iteration and no start value. The tangential spacing of the
  points gives R to first order in the arc (for two points, R = chord /
  (2 sin(dtheta/2))); a circle fit without the angles has only the sagitta.
- :func:`common_perpendicular`: feet and signed length of the common perpendicular
  of two skew lines.

The direction of a line, the normal of a plane or circle are returned as unit
vectors; their sign is fixed by an `orient` vector when given (positive dot product)
and is otherwise arbitrary.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = [
    "Line3D",
    "Plane",
    "Circle3D",
    "fit_line_3d",
    "fit_plane",
    "fit_circle_3d",
    "Circle3DAngles",
    "fit_circle_3d_angles",
    "circle_residuals",
    "common_perpendicular",
]


class Line3D(NamedTuple):
    """A fitted line: `point` (the centroid) ``(..., 3)`` and unit `direction` ``(..., 3)``."""

    point: np.ndarray
    direction: np.ndarray


class Plane(NamedTuple):
    """A fitted plane: `point` (the centroid) ``(..., 3)`` and unit `normal` ``(..., 3)``."""

    point: np.ndarray
    normal: np.ndarray


class Circle3D(NamedTuple):
    """A fitted circle in space.

    Attributes
    ----------
    centre : array (..., 3)
    normal : array (..., 3)
        Unit normal of the circle's plane (the axis direction).
    radius : array (...)
    iterations : int
        Levenberg-Marquardt iterations used (the largest over the batch).
    converged : array of bool (...)
        Whether each fit met the step tolerance.
    """

    centre: np.ndarray
    normal: np.ndarray
    radius: np.ndarray
    iterations: int
    converged: np.ndarray


def _as_points(points, min_points: int, what: str) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if p.ndim < 2 or p.shape[-1] != 3:
        raise ValueError(
            f"The 'points' parameter of {what} must be an array of shape (..., m, 3). "
            f"Got shape {p.shape} instead."
        )
    if p.shape[-2] < min_points:
        raise ValueError(
            f"The 'points' parameter of {what} must hold at least {min_points} points. "
            f"Got {p.shape[-2]} instead."
        )
    return p


def _scatter(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centroid (..., 3), centred points (..., m, 3) and their scatter eigen-decomposition."""
    centroid = points.mean(axis=-2)
    q = points - centroid[..., None, :]
    s = np.einsum("...mi,...mj->...ij", q, q)
    w, v = np.linalg.eigh(s)  # ascending eigenvalues; eigenvectors in columns
    return centroid, q, (w, v)


def _orient(vec: np.ndarray, ref) -> np.ndarray:
    if ref is None:
        return vec
    sign = np.where(np.einsum("...i,...i->...", vec, np.asarray(ref, dtype=float)) < 0, -1.0, 1.0)
    return vec * sign[..., None]


def fit_line_3d(points, *, orient=None) -> Line3D:
    """Orthogonal-distance (total least squares) line through points in space.

    Parameters
    ----------
    points : array (..., m, 3)
        At least 2 points per batch element.
    orient : array (..., 3) or (3,), optional
        The direction is returned with a positive dot product with `orient`.

    Returns
    -------
    Line3D
        The centroid and the unit eigenvector of the largest eigenvalue of the scatter
        matrix.
    """
    p = _as_points(points, 2, "fit_line_3d")
    centroid, _, (_, v) = _scatter(p)
    return Line3D(centroid, _orient(v[..., :, 2], orient))


def fit_plane(points, *, orient=None) -> Plane:
    """Orthogonal-distance (total least squares) plane through points in space.

    Parameters
    ----------
    points : array (..., m, 3)
        At least 3 points per batch element.
    orient : array (..., 3) or (3,), optional
        The normal is returned with a positive dot product with `orient`.

    Returns
    -------
    Plane
        The centroid and the unit eigenvector of the smallest eigenvalue of the scatter
        matrix.
    """
    p = _as_points(points, 3, "fit_plane")
    centroid, _, (_, v) = _scatter(p)
    return Plane(centroid, _orient(v[..., :, 0], orient))


def _tangent_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (..., 3) completing the unit vector `n` to a right-handed basis."""
    # Pick the coordinate axis least aligned with n, per batch element.
    idx = np.argmin(np.abs(n), axis=-1)
    e = np.zeros_like(n)
    np.put_along_axis(e, idx[..., None], 1.0, axis=-1)
    u = np.cross(n, e)
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    v = np.cross(n, u)
    return u, v


def circle_residuals(points, centre, normal, radius) -> tuple[np.ndarray, np.ndarray]:
    """Axial and radial residuals of points against circles in space.

    Parameters
    ----------
    points : array (..., m, 3)
    centre : array (..., 3)
    normal : array (..., 3)
        Unit normals.
    radius : array (...)

    Returns
    -------
    h : array (..., m)
        Height of each point over the circle's plane.
    d : array (..., m)
        Distance from the axis minus the radius. ``h**2 + d**2`` is the squared
        orthogonal distance from the point to the circle.
    """
    q = np.asarray(points, dtype=float) - np.asarray(centre)[..., None, :]
    normal = np.asarray(normal, dtype=float)
    h = np.einsum("...mi,...i->...m", q, normal)
    w = q - h[..., None] * normal[..., None, :]
    rho = np.linalg.norm(w, axis=-1)
    return h, rho - np.asarray(radius)[..., None]


def _kasa_start(p: np.ndarray, orient) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Plane fit, then the algebraic (Kasa) circle in that plane: the start values."""
    centroid, q, (_, v) = _scatter(p)
    n = v[..., :, 0]
    if orient is None:
        # Orient by the order of the points: right-handed about n when going round.
        turn = np.cross(q[..., :-1, :], q[..., 1:, :]).sum(axis=-2)
        n = _orient(n, turn)
    else:
        n = _orient(n, orient)
    e1, e2 = v[..., :, 2], np.cross(n, v[..., :, 2])
    x = np.einsum("...mi,...i->...m", q, e1)
    y = np.einsum("...mi,...i->...m", q, e2)
    scale = np.sqrt(np.mean(x * x + y * y, axis=-1))[..., None]
    xs, ys = x / scale, y / scale
    a = np.stack([xs, ys, np.ones_like(xs)], axis=-1)  # x^2 + y^2 = 2 a x + 2 b y + c
    rhs = xs * xs + ys * ys
    ata = np.einsum("...mi,...mj->...ij", a, a)
    atb = np.einsum("...mi,...m->...i", a, rhs)
    sol = np.linalg.solve(ata, atb[..., None])[..., 0]
    cx, cy = sol[..., 0] / 2, sol[..., 1] / 2
    r = np.sqrt(np.maximum(sol[..., 2] + cx * cx + cy * cy, 0.0)) * scale[..., 0]
    centre = centroid + (cx * scale[..., 0])[..., None] * e1 + (cy * scale[..., 0])[..., None] * e2
    return centre, n, r


def fit_circle_3d(points, *, orient=None, max_iter: int = 100, xtol: float = 1e-14) -> Circle3D:
    """Circle in space minimising the sum of squared full 3-D orthogonal distances.

    Parameters
    ----------
    points : array (..., m, 3)
        At least 3 points per batch element, not collinear.
    orient : array (..., 3) or (3,), optional
        The normal is returned with a positive dot product with `orient`; by default
        it is right-handed about the order of the points (the points go round the
        normal counter-clockwise).
    max_iter : int
        Largest number of Levenberg-Marquardt iterations.
    xtol : float
        Convergence when every step is below ``xtol`` relative to the radius, or
        when a step below 1e-8 (relative) lowers the cost by less than 1e-13 of it.

    Returns
    -------
    Circle3D

    Notes
    -----
    Parameters: centre c (3), normal n (2, as a rotation of the current n in its
    tangent plane) and radius r. With ``q = p - c``, ``h = n.q``, ``w = q - h n``,
    ``rho = |w|`` and ``e = w / rho``, the residuals are ``h`` and ``rho - r``, and
    ``dh/dc = -n``, ``dh/dn = q``; ``drho/dc = -e``, ``drho/dn = -h e``;
    ``d(rho - r)/dr = -1``.
    """
    p0 = _as_points(points, 3, "fit_circle_3d")
    shift = p0.mean(axis=-2)
    p = p0 - shift[..., None, :]  # work about the centroid: better conditioned sums
    centre, n, r = _kasa_start(p, orient)
    batch = p.shape[:-2]
    lam = np.full(batch, 1e-6)
    scale = np.maximum(r, np.finfo(float).tiny)

    def cost_of(c, nn, rr):
        h, d = circle_residuals(p, c, nn, rr)
        return np.sum(h * h, axis=-1) + np.sum(d * d, axis=-1)

    cost = cost_of(centre, n, r)
    converged = np.zeros(batch, dtype=bool)
    it = 0
    for it in range(1, max_iter + 1):
        u, v = _tangent_basis(n)
        q = p - centre[..., None, :]
        h = np.einsum("...mi,...i->...m", q, n)
        w = q - h[..., None] * n[..., None, :]
        rho = np.linalg.norm(w, axis=-1)
        e = w / np.maximum(rho, np.finfo(float).tiny)[..., None]
        m = p.shape[-2]
        jac = np.empty((*batch, 2 * m, 6))
        jac[..., :m, 0:3] = -n[..., None, :]
        jac[..., :m, 3] = np.einsum("...mi,...i->...m", q, u)
        jac[..., :m, 4] = np.einsum("...mi,...i->...m", q, v)
        jac[..., :m, 5] = 0.0
        jac[..., m:, 0:3] = -e
        jac[..., m:, 3] = -h * np.einsum("...mi,...i->...m", e, u)
        jac[..., m:, 4] = -h * np.einsum("...mi,...i->...m", e, v)
        jac[..., m:, 5] = -1.0
        res = np.concatenate([h, rho - r[..., None]], axis=-1)
        jtj = np.einsum("...ki,...kj->...ij", jac, jac)
        jtr = np.einsum("...ki,...k->...i", jac, res)
        diag = np.einsum("...ii->...i", jtj)
        while True:
            a = jtj + (lam[..., None] * np.maximum(diag, 1e-300))[..., None] * np.eye(6)
            step = -np.linalg.solve(a, jtr[..., None])[..., 0]
            c_new = centre + step[..., 0:3]
            n_new = n + step[..., 3:4] * u + step[..., 4:5] * v
            n_new /= np.linalg.norm(n_new, axis=-1, keepdims=True)
            r_new = r + step[..., 5]
            cost_new = cost_of(c_new, n_new, r_new)
            size = np.max(np.abs(step[..., 0:3]), axis=-1) / scale
            size = np.maximum(size, np.max(np.abs(step[..., 3:5]), axis=-1))
            size = np.maximum(size, np.abs(step[..., 5]) / scale)
            # Near the minimum a step changes the cost by less than its rounding: there
            # the Gauss-Newton step is trusted without the cost test.
            better = (cost_new <= cost) | (size < 1e-9) | converged
            # elements whose step did not lower the cost retry with more damping
            if np.all(better) or np.all(lam[~better] > 1e10):
                break
            lam = np.where(better, lam, lam * 10.0)
        accept = better & ~converged
        # stalled: a small step that no longer lowers the cost beyond rounding
        stalled = accept & (size <= 1e-8) & (cost - cost_new <= 1e-13 * cost)
        centre = np.where(accept[..., None], c_new, centre)
        n = np.where(accept[..., None], n_new, n)
        r = np.where(accept, r_new, r)
        cost = np.where(accept, cost_new, cost)
        lam = np.where(accept, np.maximum(lam / 10.0, 1e-12), lam)
        converged |= (size <= xtol) | (cost == 0.0) | ~better | stalled
        if np.all(converged):
            break
    if orient is not None:
        n = _orient(n, orient)
    return Circle3D(centre + shift, n, r, it, converged)


class Circle3DAngles(NamedTuple):
    """A circle in space fitted with the points' known angles.

    Attributes
    ----------
    centre : array (..., 3)
    normal : array (..., 3)
        Unit normal, right-handed about increasing angle (the rotation axis).
    radius : array (...)
    zero_direction : array (..., 3)
        Unit vector from the centre toward angle 0 (``e1`` rotated by the phase phi0).
    """

    centre: np.ndarray
    normal: np.ndarray
    radius: np.ndarray
    zero_direction: np.ndarray


def fit_circle_3d_angles(points, angles, weights=None) -> Circle3DAngles:
    """Least-squares circle in space through points at known angles.

    Parameters
    ----------
    points : array (..., m, 3)
    angles : array (..., m) or (m,)
        Angle of each point on the circle [rad] (positive right-handed about the
        normal), known up to one common phase; at least 3 distinct angles (mod 2 pi).
    weights : array (m,), optional
        Weight of each point's squared residual (> 0; default all 1): a point that
        stands for the mean of w equally scattered readings has weight w.

    Returns
    -------
    Circle3DAngles
        Minimiser of ``sum_i w_i |p_i - c - R (cos(theta_i + phi0) e1 + sin(theta_i +
        phi0) e2)|**2`` over c, R >= 0 and the orthonormal pair (e1, e2); normal ``e1 x e2``.

    Notes
    -----
    With ``u_i = (cos theta_i, sin theta_i, 0)`` the model is the similarity transform
    ``p_i = c + R Q u_i``, Q in SO(3). Eliminating c (``c = mean p - R Q mean u``) and
    with ``H = sum (p_i - mean p)(u_i - mean u)^T = U S V^T`` (SVD), the minimiser is
    ``Q = U D V^T``, ``D = diag(1, 1, sign(det U det V))``, ``R = tr(S D) / sum |u_i -
    mean u|**2`` (Umeyama 1991, IEEE PAMI 13, 376). Since the u_i are planar, H has
    rank 2 and D fixes the third column of Q (the normal) to make Q a rotation.
    """
    p = _as_points(points, 3, "fit_circle_3d_angles")
    th = np.asarray(angles, dtype=float)
    try:
        th = np.broadcast_to(th, p.shape[:-1])
    except ValueError:
        raise ValueError(
            "The 'angles' parameter of fit_circle_3d_angles must have the shape of the "
            f"points without their last axis, {p.shape[:-1]}. Got {th.shape} instead."
        ) from None
    m = p.shape[-2]
    w = np.ones(m) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (m,) or not np.all(w > 0):
        raise ValueError("The 'weights' parameter of fit_circle_3d_angles must hold one "
                         f"positive number per point ({m}). Got {w!r} instead.")
    w = w / w.mean()
    u = np.stack([np.cos(th), np.sin(th), np.zeros_like(th)], axis=-1)
    mu_p = np.einsum("m,...mi->...i", w, p) / m
    mu_u = np.einsum("m,...mi->...i", w, u) / m
    pc, uc = p - mu_p[..., None, :], (u - mu_u[..., None, :]) * w[:, None]
    su = np.einsum("...mi,...mj->...ij", uc[..., :2], u[..., :2] - mu_u[..., None, :2])
    if np.any(np.linalg.eigvalsh(su)[..., 0] <= 1e-12 * m):
        raise ValueError(
            "The 'angles' parameter of fit_circle_3d_angles must hold at least 3 distinct "
            "angles (mod 2 pi) per circle: with fewer the points fix no circle."
        )
    h = np.einsum("...mi,...mj->...ij", pc, uc)
    uu, s, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(uu) * np.linalg.det(vt))
    d = np.where(d == 0, 1.0, d)
    q = (uu * np.stack([np.ones_like(d), np.ones_like(d), d], axis=-1)[..., None, :]) @ vt
    radius = (s[..., 0] + s[..., 1] + d * s[..., 2]) / np.trace(su, axis1=-2, axis2=-1)
    centre = mu_p - radius[..., None] * np.einsum("...ij,...j->...i", q, mu_u)
    return Circle3DAngles(centre, q[..., :, 2], radius, q[..., :, 0])


def common_perpendicular(point_a, dir_a, point_b, dir_b):
    """Common perpendicular of two lines in space.

    Parameters
    ----------
    point_a, dir_a : array (..., 3)
        A point on line a and its unit direction.
    point_b, dir_b : array (..., 3)
        A point on line b and its unit direction.

    Returns
    -------
    foot_a : array (..., 3)
        Foot of the common perpendicular on line a.
    foot_b : array (..., 3)
        Foot on line b.
    distance : array (...)
        Signed length: ``(foot_a - foot_b) . (b x a) / |b x a|``.
    sin_angle : array (...)
        ``|a x b|``, the sine of the angle between the lines (0 for parallel lines,
        where the common perpendicular is not unique and the feet are NaN).
    """
    pa, a = np.asarray(point_a, dtype=float), np.asarray(dir_a, dtype=float)
    pb, b = np.asarray(point_b, dtype=float), np.asarray(dir_b, dtype=float)
    w = pa - pb
    ab = np.einsum("...i,...i->...", a, b)
    aw = np.einsum("...i,...i->...", a, w)
    bw = np.einsum("...i,...i->...", b, w)
    cross = np.cross(b, a)
    sin2 = np.einsum("...i,...i->...", cross, cross)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (ab * bw - aw) / sin2  # parameter on a
        t = (bw - ab * aw) / sin2  # parameter on b
        foot_a = pa + s[..., None] * a
        foot_b = pb + t[..., None] * b
        distance = np.einsum("...i,...i->...", foot_a - foot_b, cross) / np.sqrt(sin2)
    return foot_a, foot_b, distance, np.sqrt(sin2)
