"""Batch-first circle fits in the plane: three-point, Kasa (algebraic), geometric.

Every function takes coordinates ``x`` and ``y`` of shape ``(..., m)`` (any leading
batch axes, e.g. Monte Carlo trials) and fits every batch element at once; there is
no Python loop over the batch. Lengths are in whatever unit the points are in (mm in
mtplan). Each returns a :class:`Circle2D` of arrays of the batch shape.

- :func:`three_point_circle`: the circle through three points by the formula of the
  circle-centre patent (docs/glossary.md, *Source methods*):
  ``a = 2(x2 - x1)``, ``b = 2(y2 - y1)``, ``c = x2^2 + y2^2 - x1^2 - y1^2``,
  ``d = 2(x3 - x2)`` (the patent prints ``cd3`` for ``xd3``: a typo),
  ``e = 2(y3 - y2)``, ``f = x3^2 + y3^2 - x2^2 - y2^2``;
  ``xc = (c e - f b) / (a e - b d)``, ``yc = (a f - c d) / (a e - b d)``.
  The formula is evaluated on coordinates taken relative to the mean of the three
  points and the mean is added back: the same circle, without the cancellation of
  ``x^2 + y^2`` of order r^2 (it matters for a 250 mm bore read to 1 nm). The
  radius is the mean distance of the three points from the centre (they are
  equidistant up to rounding).
- :func:`kasa_fit`: the algebraic fit of Kasa (1976): minimise
  ``sum (x^2 + y^2 + D x + E y + F)^2``; linear least squares, solved by a batched QR
  decomposition on centred and scaled coordinates. It is exact for points on a
  circle and biased towards small radii for short arcs.
- :func:`geometric_fit`: the orthogonal-distance (geometric) fit, minimise
  ``sum (|p_i - c| - r)^2``, by Levenberg-Marquardt on the whole batch with the
  analytic Jacobian, each batch element with its own damping, started from Kasa.
  This is the ISO 12181 / GGS 1994 least-squares circle.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from mtplan._validate import InvalidInput

__all__ = ["Circle2D", "three_point_circle", "kasa_fit", "geometric_fit", "circle_residuals"]


class Circle2D(NamedTuple):
    """A fitted circle: centre ``(xc, yc)`` and radius ``r``, each of the batch shape.

    ``iterations`` is the number of iterations used (0 for closed-form fits) and
    ``converged`` a boolean array of the batch shape (all True for closed forms).
    """

    xc: np.ndarray
    yc: np.ndarray
    r: np.ndarray
    iterations: int = 0
    converged: np.ndarray | bool = True


def _as_xy(x, y, min_points: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    problems = []
    if x.shape != y.shape:
        problems.append(f"The 'x' and 'y' parameters of {what} must have the same shape. "
                        f"Got {x.shape} and {y.shape} instead.")
    elif x.ndim < 1 or x.shape[-1] < min_points:
        problems.append(f"The 'x' parameter of {what} must hold at least {min_points} points "
                        f"along its last axis. Got shape {x.shape} instead.")
    elif not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        problems.append(f"The 'x' and 'y' parameters of {what} must be finite (no NaN or inf).")
    if problems:
        raise InvalidInput(problems)
    return x, y


def circle_residuals(x, y, xc, yc, r) -> np.ndarray:
    """Signed orthogonal distances ``|p - c| - r`` of points from circles.

    Parameters
    ----------
    x, y : array (..., m)
        Point coordinates.
    xc, yc, r : array (...)
        Circle centres and radii.

    Returns
    -------
    array (..., m)
    """
    xc = np.asarray(xc, dtype=float)[..., None]
    yc = np.asarray(yc, dtype=float)[..., None]
    return np.hypot(np.asarray(x) - xc, np.asarray(y) - yc) - np.asarray(r, dtype=float)[..., None]


def three_point_circle(x, y) -> Circle2D:
    """The circle through three points, by the patent's a..f formula.

    Parameters
    ----------
    x, y : array (..., 3)
        Coordinates of d1, d2, d3.

    Returns
    -------
    Circle2D
        Centre and radius, each of shape ``(...)``. Collinear points give a zero
        denominator and non-finite values (callers refuse such set-ups beforehand).
    """
    x, y = _as_xy(x, y, 3, "three_point_circle")
    if x.shape[-1] != 3:
        raise InvalidInput([f"The 'x' parameter of three_point_circle must hold exactly 3 points "
                            f"along its last axis. Got shape {x.shape} instead."])
    mx = x.mean(axis=-1, keepdims=True)
    my = y.mean(axis=-1, keepdims=True)
    u, v = x - mx, y - my
    x1, x2, x3 = u[..., 0], u[..., 1], u[..., 2]
    y1, y2, y3 = v[..., 0], v[..., 1], v[..., 2]
    a = 2 * (x2 - x1)
    b = 2 * (y2 - y1)
    c = x2 * x2 + y2 * y2 - x1 * x1 - y1 * y1
    d = 2 * (x3 - x2)  # the patent's "cd3" is xd3
    e = 2 * (y3 - y2)
    f = x3 * x3 + y3 * y3 - x2 * x2 - y2 * y2
    with np.errstate(divide="ignore", invalid="ignore"):
        den = a * e - b * d
        xc = (c * e - f * b) / den
        yc = (a * f - c * d) / den
    r = np.hypot(u - xc[..., None], v - yc[..., None]).mean(axis=-1)
    return Circle2D(xc + mx[..., 0], yc + my[..., 0], r)


def _centre_scale(x, y):
    mx = x.mean(axis=-1, keepdims=True)
    my = y.mean(axis=-1, keepdims=True)
    u, v = x - mx, y - my
    s = np.sqrt(np.mean(u * u + v * v, axis=-1, keepdims=True))
    s = np.where(s > 0, s, 1.0)
    return u / s, v / s, mx[..., 0], my[..., 0], s[..., 0]


def kasa_fit(x, y) -> Circle2D:
    """Algebraic (Kasa) circle: minimise ``sum (x^2 + y^2 + D x + E y + F)^2``.

    Parameters
    ----------
    x, y : array (..., m)
        At least 3 points per batch element, not collinear.

    Returns
    -------
    Circle2D
        ``xc = -D/2``, ``yc = -E/2``, ``r = sqrt(xc^2 + yc^2 - F)``.

    Notes
    -----
    The fit is equivariant under translation and scaling, so it is solved on
    coordinates centred on the points' mean and scaled by their RMS distance from it,
    where the design matrix ``[x, y, 1]`` is well conditioned; a batched QR
    decomposition avoids squaring its condition number.
    """
    x, y = _as_xy(x, y, 3, "kasa_fit")
    u, v, mx, my, s = _centre_scale(x, y)
    a = np.stack([u, v, np.ones_like(u)], axis=-1)
    rhs = -(u * u + v * v)
    q, rr = np.linalg.qr(a)
    qtb = np.einsum("...mi,...m->...i", q, rhs)
    sol = np.linalg.solve(rr, qtb[..., None])[..., 0]
    cx, cy = -sol[..., 0] / 2, -sol[..., 1] / 2
    r = np.sqrt(np.maximum(cx * cx + cy * cy - sol[..., 2], 0.0))
    return Circle2D(mx + cx * s, my + cy * s, r * s)


def geometric_fit(x, y, *, start: Circle2D | None = None, max_iter: int = 100,
                  xtol: float = 1e-15) -> Circle2D:
    """Geometric (orthogonal-distance) circle: minimise ``sum (|p_i - c| - r)^2``.

    Parameters
    ----------
    x, y : array (..., m)
        At least 3 points per batch element, not collinear.
    start : Circle2D, optional
        Start values (default: :func:`kasa_fit`).
    max_iter : int
        Largest number of Levenberg-Marquardt iterations.
    xtol : float
        Convergence when every step is below `xtol` relative to the RMS spread of the
        points.

    Returns
    -------
    Circle2D
        With the number of iterations and a per-element convergence flag.

    Notes
    -----
    With ``d_i = |p_i - c|`` the residuals are ``d_i - r`` and the Jacobian rows
    ``[-(x_i - xc)/d_i, -(y_i - yc)/d_i, -1]``. Each step solves the damped normal
    equations ``(J'J + lambda diag(J'J)) delta = -J'e`` (3 x 3, batched); an element
    whose step does not lower its cost retries with ten times the damping. Steps are
    taken on centred, scaled coordinates (see :func:`kasa_fit`).
    """
    x, y = _as_xy(x, y, 3, "geometric_fit")
    u, v, mx, my, s = _centre_scale(x, y)
    if start is None:
        k = kasa_fit(u, v)
        a, b, r = k.xc, k.yc, k.r
    else:
        a = (np.broadcast_to(np.asarray(start.xc, dtype=float), mx.shape) - mx) / s
        b = (np.broadcast_to(np.asarray(start.yc, dtype=float), mx.shape) - my) / s
        r = np.broadcast_to(np.asarray(start.r, dtype=float), mx.shape) / s
    batch = mx.shape
    tiny = np.finfo(float).tiny

    def cost_of(aa, bb, rr):
        e = np.hypot(u - aa[..., None], v - bb[..., None]) - rr[..., None]
        return np.sum(e * e, axis=-1)

    cost = cost_of(a, b, r)
    lam = np.full(batch, 1e-6)
    converged = np.zeros(batch, dtype=bool)
    eye = np.eye(3)
    it = 0
    for it in range(1, max_iter + 1):
        du, dv = u - a[..., None], v - b[..., None]
        d = np.maximum(np.hypot(du, dv), tiny)
        jac = np.stack([-du / d, -dv / d, -np.ones_like(d)], axis=-1)
        res = d - r[..., None]
        jtj = np.einsum("...ki,...kj->...ij", jac, jac)
        jtr = np.einsum("...ki,...k->...i", jac, res)
        diag = np.einsum("...ii->...i", jtj)
        while True:
            m = jtj + (lam[..., None] * np.maximum(diag, 1e-300))[..., None] * eye
            step = -np.linalg.solve(m, jtr[..., None])[..., 0]
            a_new, b_new, r_new = a + step[..., 0], b + step[..., 1], r + step[..., 2]
            cost_new = cost_of(a_new, b_new, r_new)
            size = np.max(np.abs(step), axis=-1)
            # Near the minimum a step changes the cost by less than its rounding; a tiny
            # Gauss-Newton step is trusted without the cost test.
            better = (cost_new <= cost) | (size < 1e-10) | converged
            if np.all(better) or np.all(lam[~better] > 1e10):
                break
            lam = np.where(better, lam, lam * 10.0)
        accept = better & ~converged
        a = np.where(accept, a_new, a)
        b = np.where(accept, b_new, b)
        r = np.where(accept, r_new, r)
        cost = np.where(accept, cost_new, cost)
        lam = np.where(accept, np.maximum(lam / 10.0, 1e-12), lam)
        converged |= (size <= xtol) | (cost == 0.0) | ~better
        if np.all(converged):
            break
    return Circle2D(mx + a * s, my + b * s, r * s, it, converged)
