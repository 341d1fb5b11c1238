"""line_laser's estimators: the patent's, the registration and the pattern fit.

The pattern fit is the generalised least squares of the shared machinery
(:mod:`mtplan.fitting`); every name here is re-exported by :mod:`mtplan.models.line_laser`.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.fitting import Gaussian, SourceModel, central_jacobian, gls_gain, source_effects
from mtplan.models.line_laser._artifact import (
    angles_from_rotation as _angles_from_rotation,
    grid_u as _grid_u,
    grid_y as _grid_y,
    height_map,
    pitch as _pitch,
    x_shift as _shift,
)
from mtplan.models.line_laser._physics import (
    NOISE_SOURCE,
    forward,
    source_structure,
    sources,
    true_values,
)
from mtplan.models.line_laser._setup import NAME, SQ3 as _SQ3, TOL_FLOOR as _TOL_FLOOR, Truth
from mtplan.models.protocol import zero_errors


# --------------------------------------------------------------------------- patent
def interp_along_line(setup, z, shift):
    """Values of ``z`` (..., points) at ``x_l + shift``; (values, valid columns)."""
    p = _pitch(setup)
    k = int(math.floor(shift / p))
    f = shift / p - k
    n = setup.points_per_line
    cols = np.arange(n)
    valid = cols + k + 1 <= n - 1 if f > 0 else cols + k <= n - 1
    valid &= cols + k >= 0
    i0 = np.clip(cols + k, 0, n - 1)
    i1 = np.clip(cols + k + 1, 0, n - 1)
    return (1 - f) * z[..., i0] + f * z[..., i1], valid


def row_search(setup, a, b, cols):
    """Overlap fraction and mean difference (a - b) for row shifts -n_max..n_max.

    ``b`` row j is compared with ``a`` row j - n. Returns arrays (n_trials, 2 n_max + 1).
    """
    ac, bc = a[:, :, cols], b[:, :, cols]  # thresholds from the same part of the artifact
    thr_a = (ac.max(axis=(1, 2)) + ac.min(axis=(1, 2)))[:, None, None] / 2
    thr_b = (bc.max(axis=(1, 2)) + bc.min(axis=(1, 2)))[:, None, None] / 2
    ca, cb = a < thr_a, b < thr_b
    nmax, lines = setup.max_shift_rows, setup.lines
    fracs, diffs = [], []
    for s in range(-nmax, nmax + 1):
        jb = slice(max(0, s), lines + min(0, s))
        ja = slice(max(0, -s), lines - max(0, s))
        agree = ca[:, ja][:, :, cols] == cb[:, jb][:, :, cols]
        fracs.append(agree.mean(axis=(1, 2)))
        diffs.append((a[:, ja][:, :, cols] - b[:, jb][:, :, cols]).mean(axis=(1, 2)))
    return np.stack(fracs, axis=1), np.stack(diffs, axis=1)


def _coarse(setup, a, b, shift):
    """Start of the registration of ``b`` on ``a`` (b moved by ``shift`` in +X): the
    patent's integer row search and the mean height difference at that row shift.

    Returns
    -------
    array (n, 3): (du, dy, dt) [mm].
    """
    moved, cols = interp_along_line(setup, a, shift)
    fracs, diffs = row_search(setup, moved, b, cols)
    best = np.argmax(fracs, axis=1)
    out = np.empty((a.shape[0], 3))
    out[:, 0] = -shift
    out[:, 1] = (best - setup.max_shift_rows) * setup.step_mm
    out[:, 2] = -np.take_along_axis(diffs, best[:, None], axis=1)[:, 0]
    return out


def nearest_row(setup, a, b, cols, coarse):
    """The whole row shift nearest the true one, (n,) int, near the overlap's best `coarse`.

    The overlap of binarised scans is a staircase in the true shift: its steps lie where
    the facets' edges cross the rows, so which whole shift scores best depends on where
    the artifact lies (the switch points sat up to 0.64 step off the half-way points).
    The patent wants the nearest step (``l_z = n1 dy``). So the shift is located within the
    two row intervals beside `coarse`: scan 1's rows interpolated linearly to a shift
    ``k + f`` (0 <= f <= 1) make the centred sum of squared height differences a quadratic
    in f, minimised in closed form; the better interval's ``k + f``, rounded, is n1.
    Symmetric interpolation is unbiased at f = 1/2, so the switch points sit at half a
    step wherever the artifact lies.
    """
    nmax, lines = setup.max_shift_rows, setup.lines
    n = a.shape[0]
    best_cost = np.full(n, np.inf)
    best_shift = coarse.astype(float)
    for lo in (-1, 0):
        k = np.clip(coarse + lo, -nmax, nmax - 1)
        for kk in np.unique(k):
            rows = np.flatnonzero(k == kk)
            # b row j against a rows j - kk (f = 0) and j - kk - 1 (f = 1)
            jb = slice(max(0, kk + 1), lines + min(0, kk))
            j0 = slice(jb.start - kk, jb.stop - kk)
            j1 = slice(jb.start - kk - 1, jb.stop - kk - 1)
            d = (a[rows][:, j0][:, :, cols] - b[rows][:, jb][:, :, cols]).reshape(len(rows), -1)
            e = (a[rows][:, j1][:, :, cols] - a[rows][:, j0][:, :, cols]).reshape(len(rows), -1)
            d = d - d.mean(axis=1, keepdims=True)
            e = e - e.mean(axis=1, keepdims=True)
            s0, s1, s2 = (d * d).sum(1), (d * e).sum(1), (e * e).sum(1)
            with np.errstate(divide="ignore", invalid="ignore"):
                f = np.clip(np.where(s2 > 0, -s1 / s2, 0.0), 0.0, 1.0)
            cost = (s0 + 2 * f * s1 + f * f * s2) / d.shape[1]
            better = cost < best_cost[rows]
            best_cost[rows[better]] = cost[better]
            best_shift[rows[better]] = kk + f[better]
    return np.clip(np.floor(best_shift + 0.5), -nmax, nmax).astype(int)


def estimate_patent(setup, readings) -> dict:
    """The patent's estimator: integer row shift, mean differences, arccos(h/h').

    Parameters
    ----------
    setup : Setup
    readings : dict
        ``z_mm`` array (n, 3, lines, points) [mm].

    Returns
    -------
    dict of arrays (n,)
        ``alpha_z`` and ``alpha_y`` [rad]; ``alpha_x`` [rad] is ``|alpha_x|`` (sign-blind).
    """
    z = np.asarray(readings["z_mm"], dtype=float)
    w, h = _shift(setup), setup.raise_mm
    a, cols = interp_along_line(setup, z[:, 0], w)  # scan 1 at x_l + w
    b = z[:, 1]
    fracs, diffs = row_search(setup, a, b, cols)
    best = np.argmax(fracs, axis=1)
    n1 = nearest_row(setup, a, b, cols, best - setup.max_shift_rows)
    l_z = n1 * setup.step_mm
    l_y = np.take_along_axis(diffs, (n1 + setup.max_shift_rows)[:, None], axis=1)[:, 0]
    h_prime = (z[:, 1] - z[:, 2]).mean(axis=(1, 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.clip(h / h_prime, -1.0, 1.0)
    return {
        "alpha_z": np.arctan(l_z / w),
        "alpha_y": np.arctan(l_y / w),
        "alpha_x": np.arccos(ratio),
    }


# --------------------------------------------------------------------------- registration
def _robust_sigma(x, axis):
    return 1.4826 * np.median(np.abs(x), axis=axis)


def _tolerance(setup, z, tol_scale=6.0):
    """Tolerance on second differences [mm], per trial, shape (n, 1, 1).

    ``tol_scale`` standard deviations of a second difference of the noise (estimated
    robustly from the second differences along Y, where few straddle a kink), but at
    least a floor: a tenth of the smallest second difference a kink leaves
    (``0.25 tan(facet) min(pitch, dy)``, :func:`_planar_cells`; 0.58 um at the default),
    and never below ``_TOL_FLOOR``. So noise-free data are segmented exactly, a smooth
    calibration curve along the line (second differences of 0.08 um for a 1 um linearity
    error) is not taken for a kink, and a perturbation far below the noise changes no mask.
    """
    kink = 0.25 * math.tan(math.radians(setup.facet_angle_deg)) * min(_pitch(setup),
                                                                      setup.step_mm)
    floor = max(_TOL_FLOOR, 0.1 * kink)
    d2y = z[:, :-2, :] - 2 * z[:, 1:-1, :] + z[:, 2:, :]
    sig = _robust_sigma(d2y.reshape(d2y.shape[0], -1), axis=1)  # = sqrt(6) sigma
    return np.maximum(tol_scale * sig, floor)[:, None, None]


def _planar_nodes(z, tol, ky=1):
    """Nodes whose neighbours (+-1 along the line, +-1 and +-ky along Y) lie on one plane."""
    ok = np.zeros(z.shape, dtype=bool)
    ok[:, :, 1:-1] = np.abs(z[:, :, :-2] - 2 * z[:, :, 1:-1] + z[:, :, 2:]) <= tol
    oky = np.zeros(z.shape, dtype=bool)
    oky[:, 1:-1, :] = np.abs(z[:, :-2, :] - 2 * z[:, 1:-1, :] + z[:, 2:, :]) <= tol
    ok &= oky
    if ky > 1:
        okw = np.zeros(z.shape, dtype=bool)
        okw[:, ky:-ky, :] = np.abs(z[:, : -2 * ky, :] - 2 * z[:, ky:-ky, :]
                                   + z[:, 2 * ky :, :]) <= tol
        ok &= okw
    return ok


def _planar_cells(z, tol, ky=1):
    """Cells (n, lines-1, points-1) whose four corners are planar nodes.

    A kink crossing a cell crosses one of its edges, and then the second difference
    at one of that edge's ends is at least half the slope change times the spacing,
    so such a cell is rejected (features wider than two samples assumed).
    """
    ok = _planar_nodes(z, tol, ky)
    return ok[:, :-1, :-1] & ok[:, :-1, 1:] & ok[:, 1:, :-1] & ok[:, 1:, 1:]


def _register(setup, a, b, start, *, iterations=12):
    """Translation (du, dy, dt) with ``b(x, y) = a(x - du, y - dy) + dt``, per trial.

    Gauss-Newton on the residuals ``b - a_interp - dt`` over the cells of ``a`` that lie
    on one plane (bilinear interpolation is exact there). The Jacobian is the slope of
    ``b`` at its own node from central differences that leave the node out (over
    +-1 point along the line and +-ky lines along Y): its noise is then independent of
    the residual's, so the fixed point is unbiased (a slope taken from the interpolated
    cell of ``a`` shares its noise with the interpolated value and biases the shift by
    about sigma^2 / (dy * slope^2), a micrometre at the default set-up).

    Parameters
    ----------
    a, b : arrays (n, lines, points)
        Reference and moved scan [mm].
    start : array (n, 3)
        Starting translation [mm].

    Each row stops at its own convergence (every step within 1e-10 mm, from the fifth
    iteration): its result is the one it has alone, and the batch's later iterations
    cost only the rows still moving.

    Returns
    -------
    array (n, 3) [mm]; NaN where the normal equations are singular.
    """
    n, lines, pts = a.shape
    p, dy = _pitch(setup), setup.step_mm
    ky = int(max(1, min(round(p / dy / 2), (lines - 1) // 4)))
    cells = _planar_cells(a, _tolerance(setup, a), ky).reshape(n, -1)
    okb = _planar_nodes(b, _tolerance(setup, b), ky).reshape(n, -1)
    gub = np.zeros_like(b)
    gyb = np.zeros_like(b)
    gub[:, :, 1:-1] = (b[:, :, 2:] - b[:, :, :-2]) / (2 * p)
    gyb[:, ky:-ky, :] = (b[:, 2 * ky :, :] - b[:, : -2 * ky, :]) / (2 * ky * dy)
    gub, gyb = gub.reshape(n, -1), gyb.reshape(n, -1)
    af_flat = a.reshape(-1)
    bf = b.reshape(n, -1)
    jj, ii = np.meshgrid(np.arange(lines), np.arange(pts), indexing="ij")
    jj, ii = jj.ravel(), ii.ravel()
    delta = np.array(start, dtype=float)
    cells_flat = cells.ravel()
    scale = None
    act = np.arange(n)  # rows still iterating: a row stops at its own convergence
    # per active row: its whole shift (ku, kv) and what depends on that alone (the cells
    # gathered from a, the mask of usable nodes), kept while the shift stays (after the
    # first steps, the rows move within one cell)
    shift = np.full((n, 2), np.nan)
    held = None
    for it in range(iterations):
        if it == 0 or act.size < g_u.shape[0]:
            g_u, g_y, ok_b, b_f = gub[act], gyb[act], okb[act], bf[act]
            node_base = act[:, None] * (lines * pts)
            cell_base = act[:, None] * ((lines - 1) * (pts - 1))
            sc = None if scale is None else scale[act]
            if held is not None:
                held = [h[keep] for h in held]
        d = delta[act]
        su = -d[:, 0] / p
        sy = -d[:, 1] / dy
        ok_row = np.isfinite(su) & np.isfinite(sy)
        su, sy = np.where(ok_row, su, 0.0), np.where(ok_row, sy, 0.0)
        ku, kv = np.floor(su), np.floor(sy)
        fu, fy = (su - ku)[:, None], (sy - kv)[:, None]
        moved = np.flatnonzero((ku != shift[act, 0]) | (kv != shift[act, 1]))
        shift[act, 0], shift[act, 1] = ku, kv
        if held is None:
            held = [np.empty((act.size, lines * pts)) for _ in range(4)]
            held.append(np.empty((act.size, lines * pts), dtype=bool))
        if moved.size:
            ic = ii[None, :] + ku[moved].astype(int)[:, None]
            jc = jj[None, :] + kv[moved].astype(int)[:, None]
            inside = (ic >= 0) & (ic <= pts - 2) & (jc >= 0) & (jc <= lines - 2)
            icc = np.clip(ic, 0, pts - 2)
            jcc = np.clip(jc, 0, lines - 2)
            # gathers from the flattened batch (a 1-D take: faster than 2-D fancy indexing)
            held[4][moved] = inside & ok_b[moved] & cells_flat.take(
                cell_base[moved] + jcc * (pts - 1) + icc)
            k00 = node_base[moved] + jcc * pts + icc
            for h, off in zip(held[:4], (0, 1, pts, pts + 1), strict=True):
                h[moved] = af_flat.take(k00 + off)
        a00, a01, a10, a11, valid = held
        valid = valid.copy()
        r = b_f - ((1 - fy) * ((1 - fu) * a00 + fu * a01) + fy * ((1 - fu) * a10 + fu * a11))
        r -= d[:, 2:3]
        if it >= 3:  # robust trim once the fit has settled
            if sc is None:  # 1.4826 x median |r| over the valid points, per trial
                srt = np.sort(np.where(valid, np.abs(r), np.inf), axis=1)
                cnt = valid.sum(axis=1)
                mid = np.take_along_axis(srt, np.maximum(cnt - 1, 0)[:, None] // 2, axis=1)
                scale = np.maximum(5 * 1.4826 * mid, _TOL_FLOOR)
                sc = scale
            valid &= np.abs(r) <= sc
        wg = np.where(valid, 1.0, 0.0)
        ju, jy = g_u * wg, g_y * wg
        s_uu, s_uy, s_yy = (ju * g_u).sum(1), (ju * g_y).sum(1), (jy * g_y).sum(1)
        s_u, s_y, s_1 = ju.sum(1), jy.sum(1), wg.sum(1)
        mat = np.stack([np.stack([s_uu, s_uy, -s_u], -1), np.stack([s_uy, s_yy, -s_y], -1),
                        np.stack([-s_u, -s_y, s_1], -1)], -2)
        rw = r * wg
        rhs = np.stack([(ju * r).sum(1), (jy * r).sum(1), -rw.sum(1)], -1)
        # conditioning of the normal equations with unit diagonal
        diag = np.sqrt(np.maximum(np.einsum("nii->ni", mat), 1e-300))
        unit = mat / diag[:, :, None] / diag[:, None, :]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            eig = np.linalg.eigvalsh(unit)
            bad = ~(eig[:, 0] > 1e-8 * eig[:, -1]) | ~ok_row | (s_1 < 10)
            unit[bad] = np.eye(3)
            step = -np.linalg.solve(unit, (rhs / diag)[..., None])[..., 0] / diag
        step[bad] = np.nan
        delta[act] = d + step
        if it >= 4:
            keep = ~np.all(np.abs(step) <= 1e-10, axis=1) & ~bad
            act = act[keep]
            if act.size == 0:
                break
    return delta


def _kabsch(a_vecs, b_vecs):
    """Rotations R (n, 3, 3) minimising sum |R b - a|^2 over the pairs (n, k, 3)."""
    hmat = np.einsum("nki,nkj->nij", b_vecs, a_vecs)
    u, _, vt = np.linalg.svd(hmat)
    v = np.swapaxes(vt, -1, -2)
    d = np.sign(np.linalg.det(v @ np.swapaxes(u, -1, -2)))
    fix = np.ones((hmat.shape[0], 3))
    fix[:, 2] = d
    return (v * fix[:, None, :]) @ np.swapaxes(u, -1, -2)


def estimate_registration(setup, readings) -> dict:
    """Least-squares registration of the three scans and an exact rotation fit.

    Parameters
    ----------
    setup : Setup
    readings : dict
        ``z_mm`` array (n, 3, lines, points) [mm].

    Returns
    -------
    dict of arrays (n,)
        ``alpha_z``, ``alpha_y``, ``alpha_x`` [rad], with sign.

    Raises
    ------
    InvalidInput
        Where :func:`observability` says the set-up does not allow it.
    """
    ok, why = registration_check(setup)
    if not ok:
        raise InvalidInput([f"line_laser estimator 'registration' cannot determine the "
                            f"angles at this set-up: {why}"])
    return _registration_core(setup, np.asarray(readings["z_mm"], dtype=float))


#: the last registration of this process: (set-up, its readings, its result). The pattern
#: fit starts from the registration of the same readings, which a Monte Carlo of both
#: estimators (a sweep's set-up) has just computed: the same numbers, found again
_LAST_REGISTRATION: list = []


def _registration_core(setup, z) -> dict:
    """The registration estimator without the set-up check; ``z`` (n, 3, lines, points)."""
    if _LAST_REGISTRATION:
        last_setup, last_z, last = _LAST_REGISTRATION[0]
        if last_setup == setup and last_z.shape == z.shape and np.array_equal(last_z, z):
            return {k: v.copy() for k, v in last.items()}
    out = _registration_uncached(setup, z)
    _LAST_REGISTRATION[:] = [(setup, np.array(z, dtype=float), {k: v.copy() for k, v in
                                                                 out.items()})]
    return out


def _registration_uncached(setup, z) -> dict:
    n = z.shape[0]
    w = _shift(setup)
    d1 = _register(setup, z[:, 0], z[:, 1], _coarse(setup, z[:, 0], z[:, 1], w))
    d2 = _register(setup, z[:, 1], z[:, 2], _coarse(setup, z[:, 1], z[:, 2], 0.0))
    with np.errstate(invalid="ignore"):
        w_est = np.sqrt(d1[:, 0] ** 2 + d1[:, 2] ** 2 - d1[:, 1] ** 2)
        h_est = np.sqrt(d2[:, 0] ** 2 + d2[:, 2] ** 2 - d2[:, 1] ** 2)
    zeros = np.zeros(n)
    a_vecs = np.stack([np.stack([w_est, d1[:, 1], zeros], -1),
                       np.stack([zeros, d2[:, 1], h_est], -1)], axis=1)
    b_vecs = -np.stack([np.stack([d1[:, 0], zeros, d1[:, 2]], -1),
                        np.stack([d2[:, 0], zeros, d2[:, 2]], -1)], axis=1)
    finite = np.all(np.isfinite(a_vecs), axis=(1, 2)) & np.all(np.isfinite(b_vecs), axis=(1, 2))
    rot = np.full((n, 3, 3), np.nan)
    if finite.any():
        rot[finite] = _kabsch(a_vecs[finite], b_vecs[finite])
    az, ay, ax = _angles_from_rotation(rot)
    return {"alpha_z": az, "alpha_y": ay, "alpha_x": ax}


@functools.lru_cache(maxsize=64)
def registration_check(setup) -> tuple[bool, str]:
    """Whether the registration works at `setup`: the facets must be resolved (three
    samples across), and on the noise-free data of the default truth the fit must be
    well conditioned and recover the angles."""
    p, dy = _pitch(setup), setup.step_mm
    facet = setup.cell_depth_mm / math.tan(math.radians(setup.facet_angle_deg))
    if facet < 3 * max(p, dy):
        return False, (
            f"the facets ({facet:.3g} mm wide) are narrower than three samples "
            f"(3 x {max(p, dy):.3g} mm): the registration has no sloped surface to work on; "
            f"use more points per line, a finer step or shallower facets")
    truth = Truth()
    try:
        z = forward(setup, truth, zero_errors(sources(setup), 1))["z_mm"]
    except InvalidInput as exc:
        return False, f"the default truth cannot be scanned at this set-up ({exc})"
    est = _registration_core(setup, z)
    err = max(abs(float(est[k][0]) - v) for k, v in true_values(setup, truth).items())
    if not err < 1e-9:
        return False, (
            "too few planar samples on the facets (a narrow scan, few points per line or "
            "few lines): on noise-free data of the default truth the registration's normal "
            "equations are singular or it misses the angles; scan more lines or use more "
            "points per line")
    return True, ("sub-step least-squares registration of the sloped facets, exact rotation "
                  "fit; the raise shifts the pattern by -h*tan(alpha_x) along Y, which gives "
                  "the sign")


# --------------------------------------------------------------------------- pattern
#: Truth fields the pattern fit estimates: the three angles and the artifact's pose
FIT_FIELDS = ("alpha_z_mrad", "alpha_y_mrad", "alpha_x_mrad", "artifact_x_mm", "artifact_y_mm",
              "artifact_rz_mrad", "artifact_tilt_x_mrad", "artifact_tilt_y_mrad")
#: finite-difference steps of the fit's Jacobian [mrad or mm]: 10 urad, 1 um
FIT_STEPS = np.array([1e-2, 1e-2, 1e-2, 1e-3, 1e-3, 1e-2, 1e-2, 1e-2])
#: RMS residual [mm] above which a fit sits in the wrong lattice cell (the pattern's
#: heights are then off by a good part of the 0.4 mm depth; errors give micrometres)
_FIT_RMS_MAX = 0.02


@functools.lru_cache(maxsize=1)
def fit_limits() -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper limits (8,) of the fitted Truth fields (a step stops there)."""
    from mtplan.models.protocol import fields_info

    info = {i.name: i for i in fields_info(Truth)}
    return (np.array([info[f].low for f in FIT_FIELDS], dtype=float),
            np.array([info[f].high for f in FIT_FIELDS], dtype=float))


def _truth_rows(theta: np.ndarray) -> Truth:
    """A batch of truths whose fitted fields are arrays (n,) from ``theta`` (n, 8) (no
    validation: the forward model refuses what it cannot trace)."""
    return Truth.batch(**{name: np.ascontiguousarray(theta[:, k])
                          for k, name in enumerate(FIT_FIELDS)})


def predict_profiles(setup, theta: np.ndarray) -> np.ndarray:
    """Error-free readings (n, 3 * lines * points) [mm] for parameter rows (n, 8)."""
    n = theta.shape[0]
    z = forward(setup, _truth_rows(theta), zero_errors(sources(setup), n))["z_mm"]
    return np.asarray(z).reshape(n, -1)


@functools.lru_cache(maxsize=64)
def pattern_gain(setup, ref: tuple) -> np.ndarray:
    """Gain K (8, readings) of the generalised least squares at the parameters ``ref``.

    ``K = (J^T C^-1 J)^-1 J^T C^-1`` (:func:`mtplan.fitting.gls_gain`) with ``J`` the
    readings' Jacobian (central differences, :data:`FIT_STEPS`, one-sided at the Truth's
    limits) and ``C = sigma^2 I + U U^T`` their covariance under every active error
    source of the set-up (:func:`mtplan.fitting.readings_covariance`): ``sigma`` the
    sensor noise, the other sources by the secant effect of each of their elements at
    the same parameters, those of :data:`_COARSE_SOURCES` at the parameters rounded to
    :data:`_COVARIANCE_GRID` instead. Solved by Woodbury (``C`` is never formed: 15 600
    readings, about 200 columns).
    """
    theta = np.asarray(ref, dtype=float)
    low, high = fit_limits()
    jac = central_jacobian(lambda rows: predict_profiles(setup, rows), theta, FIT_STEPS,
                           low=low, high=high)
    others = [k for k, src in sources(setup).items()
              if k != NOISE_SOURCE and src.active]
    fine = tuple(k for k in others if k not in _COARSE_SOURCES)
    coarse = tuple(k for k in others if k in _COARSE_SOURCES)
    D, U = _source_effects(setup, ref, fine)
    sigma = setup.sensor_noise_um * 1e-3
    if coarse:
        # rounded within the Truth's limits (the coarse grid's points may lie beyond)
        at = tuple(np.clip(gain_reference(theta, _COVARIANCE_GRID), low, high).tolist())
        big, g_c = _coarse_covariance(setup, at, coarse)
        if not np.any(D) and sigma >= 1e-6 * max(big, float(np.abs(U).max(initial=0.0))):
            return _updated_gain(jac, g_c, U)
        d_c, u_c = _source_effects(setup, at, coarse)
        D, U = D + d_c, np.hstack([U, u_c])
    # without reading noise the weight is that of a noise far below any source's effect
    scale = max(sigma, 1e-6 * max(float(np.abs(U).max(initial=0.0)),
                                  float(np.sqrt(D.max(initial=0.0))), 1e-3))
    return gls_gain(jac, (D + scale**2, U))


@functools.lru_cache(maxsize=4)
def _coarse_covariance(setup, at: tuple, names: tuple) -> tuple[float, Gaussian]:
    """``sigma^2 I + U U^T`` of the sources `names` at the parameters ``at``, factored
    (:class:`mtplan.fitting.Gaussian`), and the largest of their effects and of 1 um [mm]
    (a few points are kept: the artifact's 180 facets give a U of 15 600 x 180, 22 MB)."""
    D, U = _source_effects(setup, at, names)
    big = max(float(np.abs(U).max(initial=0.0)), float(np.sqrt(D.max(initial=0.0))), 1e-3)
    return big, Gaussian.known(D + (setup.sensor_noise_um * 1e-3) ** 2, U)


def _updated_gain(jac: np.ndarray, g: Gaussian, U: np.ndarray) -> np.ndarray:
    """:func:`mtplan.fitting.gls_gain` for the covariance ``G + U U^T``, ``G`` factored:
    by Woodbury, ``C^-1 = G^-1 - G^-1 U (I + U^T G^-1 U)^-1 U^T G^-1`` (a few columns U:
    G's factorisation, most of a gain's cost, is shared by the gains at one coarse point)."""
    jt = jac.T
    p = jt.shape[0]
    rows = g.inverse_times(np.vstack([jt, U.T]))  # J^T G^-1 and U^T G^-1
    a, b = rows[:p], rows[p:]
    inner = np.eye(U.shape[1]) + b @ U
    cj = a - np.linalg.solve(inner, b @ jt.T).T @ b  # J^T C^-1
    return np.linalg.solve(cj @ jt.T, cj)


def _source_effects(setup, ref: tuple, names: tuple) -> tuple[np.ndarray, np.ndarray]:
    """``D, U`` of :func:`mtplan.fitting.source_effects` for the sources `names` at the
    parameters ``ref`` (8,)."""
    theta = np.asarray(ref, dtype=float)[None, :]
    model = SourceModel(
        NAME, sources(setup),
        lambda errors: forward(setup, _truth_rows(np.repeat(
            theta, next(iter(errors.values())).shape[0], axis=0)), errors)["z_mm"],
        lambda m: zero_errors(sources(setup), m),
        lambda name: source_structure(setup, _truth_rows(theta), name))
    return source_effects(model, list(names))


#: grid of the parameters at which gains are taken [mrad, mm]. Noise-free, the fit's fixed
#: point does not depend on where its gain was taken; with noise the gain's Jacobian is the
#: fit's weighting, best taken where the kinks of the pattern lie: the lattice offset to
#: 2 um, the line's and the artifact's rotation about Z to 0.1 mrad (under 1 um at the
#: line's ends); the angles about X and Y and the tilts (smooth height changes) to 0.5 mrad.
#: A trial's gain is taken at its own start rounded to the grid, and again at its fit so
#: rounded where the fit lies farther from the gain's point (:func:`_pattern_iterate`): the
#: trials of a Monte Carlo share the gains of the few grid points their starts round to
#: (9 for 256 trials at the default set-up)
_GAIN_GRID = np.array([0.1, 0.5, 0.5, 0.002, 0.002, 0.1, 0.5, 0.5])
#: steps of the grid [1] a converged fit may lie from its gain's point before the gain is
#: taken again at the fit
_GAIN_FAR = 1.5
#: the error sources whose part of a gain's covariance is taken on :data:`_COVARIANCE_GRID`:
#: the artifact's facets, 180 columns of the covariance's low-rank part (its factorisation
#: is most of a gain's cost; the facets' effects take 12 forward rows, one per colour and
#: sign, :func:`mtplan.models.line_laser.source_structure`; they took 360, one pair per facet)
_COARSE_SOURCES = ("facet_position",)
#: grid of the parameters at which :data:`_COARSE_SOURCES` are taken [mrad, mm]: as
#: :data:`_GAIN_GRID`, but 0.3 mrad about Z and 1.5 mrad about X (where the trials of a
#: Monte Carlo scatter). A weighting only, yet not a free one: against the facets taken at
#: the gain's own point, 1024 paired trials at the default set-up moved each alpha_z by
#: 1.4 urad RMS and alpha_x by 3.6 (3 % and 2 % of their u), u(alpha_z) up 0.9 +- 0.1 %,
#: u(alpha_x) 0.1 +- 0.1 %; a grid 5 times the gain's moved them by 2.1 and 5.5 urad. A
#: Monte Carlo of 256 trials: 2 or 3 facet points instead of 8 or 9 gains' (each a
#: factorisation of 15 600 readings, :func:`_coarse_covariance`)
_COVARIANCE_GRID = _GAIN_GRID * np.array([3.0, 1.0, 3.0, 1.0, 1.0, 1.0, 1.0, 1.0])


def gain_reference(theta: np.ndarray, grid: np.ndarray = _GAIN_GRID) -> tuple:
    """Parameters rounded to `grid` (:data:`_GAIN_GRID`), at which a gain is computed and
    cached."""
    g = np.round(np.asarray(theta, dtype=float) / grid) * grid
    return tuple(float(f"{v:.10g}") for v in g)


def _residuals(setup, y, theta) -> np.ndarray:
    """``y - prediction`` (k, readings) for parameter rows (k, 8); NaN for a row the
    model cannot trace. The forward model refuses a whole batch when one row leaves the
    sensor's range, so a refused batch is split in halves until each row is judged alone
    (a row's residual never depends on the rows beside it)."""
    try:
        return y - predict_profiles(setup, theta)
    except InvalidInput:
        if theta.shape[0] == 1:
            return np.full_like(y, np.nan)
        h = theta.shape[0] // 2
        return np.concatenate([_residuals(setup, y[:h], theta[:h]),
                               _residuals(setup, y[h:], theta[h:])])


def _pattern_iterate(setup, y, theta, *, iterations=60, relinearise=(12, 24, 36), tol=1e-9,
                     refs=None, polish=True):
    """Gauss-Newton row by row, batched: returns (theta, rms residual [mm], inf for rows
    the model could not trace).

    Each row's gain is taken at its own parameters rounded to :data:`_GAIN_GRID`: at its
    start, after the iterations in `relinearise` while it has not converged, and where it
    converges more than :data:`_GAIN_FAR` steps from its gain's point, at its fit's (at
    most twice: a fit could hop between two points), so that its weighting is taken near
    its own estimate. Rows whose gains share a point share one matrix product.
    A row stops when its own step is within `tol` [mrad, mm] (1e-6 urad, 1 pm) in every
    parameter: its iterations, gains and result are those it would have alone.
    `refs` (rows, 8) gives the start's gain points instead; `polish` False keeps them at
    convergence.
    """
    theta = np.array(theta, dtype=float, copy=True)
    low, high = fit_limits()
    refs = np.round((theta if refs is None else refs) / _GAIN_GRID) * _GAIN_GRID
    moves = np.zeros(theta.shape[0], dtype=int)
    active = np.ones(theta.shape[0], dtype=bool)
    rms = np.full(theta.shape[0], np.inf)
    for it in range(iterations):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        r = _residuals(setup, y[idx], theta[idx])
        fin = np.all(np.isfinite(r), axis=1)
        active[idx[~fin]] = False
        rms[idx[~fin]] = np.inf
        idx, r = idx[fin], r[fin]
        rms[idx] = np.sqrt(np.mean(r**2, axis=1))
        uniq, which = np.unique(refs[idx], axis=0, return_inverse=True)
        step = np.empty((idx.size, theta.shape[1]))
        for g, ref in enumerate(uniq):
            sel = np.flatnonzero(which.ravel() == g)
            step[sel] = r[sel] @ pattern_gain(setup, gain_reference(ref)).T
        theta[idx] = np.clip(theta[idx] + step, low, high)
        done = np.all(np.abs(step) <= tol, axis=1)
        far = np.any(np.abs(theta[idx] - refs[idx]) > _GAIN_FAR * _GAIN_GRID, axis=1)
        move = done & far & (moves[idx] < 2) & polish
        refs[idx[move]] = np.round(theta[idx[move]] / _GAIN_GRID[None, :]) * _GAIN_GRID
        moves[idx[move]] += 1
        active[idx[done & ~move]] = False
        if it in relinearise:
            refs[active] = np.round(theta[active] / _GAIN_GRID) * _GAIN_GRID
    return theta, rms


def _pose_search(setup, z, az_mrad) -> np.ndarray:
    """Start poses (k, 3) (lattice offset [mm], rotation about Z [mrad]) for the scans
    ``z`` (k, 3, lines, points): per row, the lattice offset and rotation that best match
    its scan 1, by the least-squares misfit after removing the mean height, over a grid:
    0.1 mm over one cell of the lattice and 20 mrad over the Truth's +-100 mrad of
    rotation (every fourth profile, vertical rays, no tilt, the row's angle about Z
    ``az_mrad`` (k,) rounded to 1 mrad applied to the line: under 0.02 mm at the line's
    ends, a fifth of the grid). Rows with one rounded angle share the candidates' heights:
    their misfits are one matrix product."""
    s = setup.cell_size_mm
    gx, gy, grz = np.meshgrid(np.arange(0, s * _SQ3 / 2, 0.1), np.arange(0, s, 0.1),
                              np.arange(-100.0, 100.1, 20.0), indexing="ij")
    gx, gy, grz = gx.ravel(), gy.ravel(), grz.ravel() * 1e-3
    data = z[:, 0, ::4].reshape(z.shape[0], -1)
    data = data - data.mean(axis=1, keepdims=True)
    best = np.zeros(z.shape[0], dtype=int)
    az_round = np.round(np.asarray(az_mrad, dtype=float))
    for az in np.unique(az_round):
        rows = np.flatnonzero(az_round == az)
        u, yl = _grid_u(setup)[None, :], _grid_y(setup)[::4, None]
        px = (u * math.cos(az * 1e-3) + 0 * yl).ravel()
        py = (u * math.sin(az * 1e-3) + yl).ravel()
        best_cost = np.full(rows.size, np.inf)
        for start in range(0, gx.size, 256):  # memory bounded: 256 candidates at a time
            sl = slice(start, start + 256)
            c, si = np.cos(grz[sl])[:, None], np.sin(grz[sl])[:, None]
            dx, dy = px[None, :] - gx[sl, None], py[None, :] - gy[sl, None]
            h = height_map(setup, c * dx + si * dy, -si * dx + c * dy)[0]
            h = h - h.mean(axis=1, keepdims=True)  # a reading is the height plus the stand-off
            # |h - d|^2 without |d|^2 (the same for every candidate of a row)
            cost = (h * h).sum(axis=1)[:, None] - 2 * h @ data[rows].T
            k = np.argmin(cost, axis=0)
            better = cost[k, np.arange(rows.size)] < best_cost
            best_cost[better] = cost[k[better], np.flatnonzero(better)]
            best[rows[better]] = start + k[better]
    return np.column_stack([gx[best], gy[best], grz[best] * 1e3])


def _pattern_rows(setup, z) -> np.ndarray:
    """The fit of each row's scans ``z`` (k, 3, lines, points): parameters (k, 8), NaN
    where it misses the pattern. Every step is a function of the row alone.

    Starts from the row's registration angles and the default truth's pose; where that
    lands in the wrong cell of the lattice, from :func:`_pose_search`. The pose names a
    cell centre, and the artifact's tilts pivot about it, so the cells' centres are not
    quite equivalent (the plate's height at the pivot is the set-up's): after a pose
    search the fit is repeated from the six neighbouring cells and the best kept.
    """
    k = z.shape[0]
    y = z.reshape(k, -1)
    reg = _registration_core(setup, z)
    angles = np.column_stack([reg[a] for a in ("alpha_z", "alpha_y", "alpha_x")]) * 1e3
    out = np.full((k, len(FIT_FIELDS)), np.nan)
    todo = np.flatnonzero(np.all(np.isfinite(angles), axis=1))
    pose = np.array([getattr(Truth(), f) for f in FIT_FIELDS[3:]])
    start = np.column_stack([angles[todo], np.broadcast_to(pose, (todo.size, pose.size))])
    th, rms = _pattern_iterate(setup, y[todo], start)
    hit = rms <= _FIT_RMS_MAX
    out[todo[hit]] = th[hit]
    miss = todo[~hit]
    if miss.size == 0:
        return out
    start = np.column_stack([angles[miss], _pose_search(setup, z[miss], angles[miss, 0]),
                             np.zeros((miss.size, 2))])
    th, rms = _pattern_iterate(setup, y[miss], start)
    hit = rms <= _FIT_RMS_MAX
    found, th, rms = miss[hit], th[hit], rms[hit]
    if found.size == 0:
        return out
    s = setup.cell_size_mm
    cells = np.array([[0, s], [0, -s], [s * _SQ3 / 2, s / 2], [-s * _SQ3 / 2, -s / 2],
                      [s * _SQ3 / 2, -s / 2], [-s * _SQ3 / 2, s / 2]])
    rz = th[:, 5] * 1e-3
    c, si = np.cos(rz)[:, None], np.sin(rz)[:, None]
    moved = np.stack([cells[None, :, 0] * c - cells[None, :, 1] * si,
                      cells[None, :, 0] * si + cells[None, :, 1] * c], axis=-1)  # (f, 6, 2)
    starts = np.repeat(th, len(cells), axis=0)
    starts[:, 3:5] += moved.reshape(-1, 2)
    # the neighbours are compared under the trial's own gain (a lattice step away: the
    # same kinks); the one kept is then weighted at its own fit
    others, rms_o = _pattern_iterate(setup, np.repeat(y[found], len(cells), axis=0), starts,
                                     refs=np.repeat(th, len(cells), axis=0), polish=False)
    others, rms_o = others.reshape(found.size, len(cells), -1), rms_o.reshape(found.size, -1)
    kbest = np.argmin(rms_o, axis=1)
    pick = np.arange(found.size)
    better = rms_o[pick, kbest] < rms
    out[found] = th
    if better.any():
        out[found[better]] = _pattern_iterate(setup, y[found[better]],
                                              others[pick[better], kbest[better]])[0]
    return out


def estimate_pattern(setup, readings) -> dict:
    """Generalised least squares of the forward model: angles and artifact pose.

    Uses what the registration leaves out: the artifact's pattern as the set-up states
    it (the hexagonal pockets' pitch, land, depth and facet angle) and the model of every
    error source. The readings of all three scans are fitted at once over the three
    angles and the artifact's pose (lattice offset, rotation about Z, two tilts), weighted
    by the inverse of their covariance under every active error source of the set-up
    (:func:`pattern_gain`), by Gauss-Newton (:func:`_pattern_rows`). Each trial is
    fitted from its own data alone (its result does not depend on the other trials of
    the batch); trials whose gains are taken at one rounded point share its matrix
    product. Trials whose fit misses the pattern (an RMS residual above 20 um: the wrong
    cell of the lattice) are NaN.

    Arguments, result (angles with sign [rad]) and refusal as
    :func:`estimate_registration`, from which it starts.
    """
    ok, why = registration_check(setup)
    if not ok:
        raise InvalidInput([f"line_laser estimator 'pattern' cannot determine the angles at "
                            f"this set-up (it starts from the registration): {why}"])
    z = np.asarray(readings["z_mm"], dtype=float)
    theta = np.full((z.shape[0], len(FIT_FIELDS)), np.nan)
    rows = np.flatnonzero(np.all(np.isfinite(z.reshape(z.shape[0], -1)), axis=1))
    if rows.size:
        theta[rows] = _pattern_rows(setup, z[rows])
    return {"alpha_z": theta[:, 0] * 1e-3, "alpha_y": theta[:, 1] * 1e-3,
            "alpha_x": theta[:, 2] * 1e-3}
