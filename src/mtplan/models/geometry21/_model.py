"""geometry21's linear model of the readings in the parameters (the error coefficients, the
plates' mounting and the extra heads' settings): scales, the exact prediction, the
Jacobian at zero error, its SVD and the joint fit's pseudo-inverses.
"""

from __future__ import annotations

import functools

import numpy as np

from mtplan._cache import array_cache
from mtplan._validate import InvalidInput
from mtplan.fitting import central_jacobian
from mtplan.fitting.linear import gls_pinv, truncated_pinv
from mtplan.models.geometry21._jacobian import zero_jacobian
from mtplan.models.geometry21._layout import Geometry, geometry, mount, truth_positions
from mtplan.models.geometry21._path import reading_whitener, weight_ratios, whitening
from mtplan.models.geometry21._setup import KIND, NAMES, PLANES, Setup, sizeless


# --------------------------------------------------------------------------- linear model
RANK_TOL = 1e-7


def parameter_scales(geo: Geometry) -> np.ndarray:
    """Typical size of each parameter: 1 um or 10 urad at the end of the travel;
    1 um and 10 urad for the plates' offsets and rotations, 1 um for the heads' settings."""
    s = np.empty(geo.n_par)
    t = geo.u_end
    for name in NAMES:
        powers, sl = geo.layout[name]
        typ = 1e-5 if KIND[name] in ("ang", "sq") else 1e-3
        s[sl] = [typ / t**k for k in powers]
    s[geo.n_coef: geo.n_coef + 9] = np.tile([1e-3, 1e-3, 1e-5], 3)
    s[geo.n_coef + 9:] = 1e-3
    return s


def nuisance(geo: Geometry, theta: np.ndarray):
    """(plate offsets (n, 3, 2), plate rotations (n, 3), head settings (n, n_extra, 2))."""
    n = theta.shape[0]
    plate = theta[:, geo.n_coef: geo.n_coef + 9].reshape(n, 3, 3)
    return plate[:, :, :2], plate[:, :, 2], theta[:, geo.n_coef + 9:].reshape(n, -1, 2)


def predict_readings(geo: Geometry, theta: np.ndarray) -> np.ndarray:
    """Noise-free readings (n, M, 2) for parameters theta (n, n_par), exact model."""
    n = theta.shape[0]
    coefs = {name: (pw, theta[:, sl]) for name, (pw, sl) in geo.layout.items()}
    offset, turn, head = nuisance(geo, theta)
    rot = np.zeros((n, 3, 3))
    rot[:, :, 2] = turn
    return mount(geo, truth_positions(geo, coefs), offset, head, rot)


def _measurand_map(geo: Geometry) -> np.ndarray:
    """g (21, n_par): measurand = g @ theta (function at u = +line_length/2)."""
    g = np.zeros((len(NAMES), geo.n_par))
    for i, name in enumerate(NAMES):
        powers, sl = geo.layout[name]
        g[i, sl] = [geo.u_end**k for k in powers]
    return g


def param_names(geo: Geometry) -> list[str]:
    names = [None] * geo.n_par
    for name, (powers, sl) in geo.layout.items():
        for j, k in zip(range(sl.start, sl.stop), powers):
            names[j] = f"{name}[{k}]"
    for k, (pl, *_rest) in enumerate(PLANES):
        for j, what in enumerate(("offset_u", "offset_v", "rotation")):
            names[geo.n_coef + 3 * k + j] = f"{pl}.{what}"
    for e in range(geo.n_extra):
        sel = np.flatnonzero(geo.xhead == e)[0]
        pl, j = PLANES[geo.plane[sel]][0], geo.head[sel]
        names[geo.n_coef + 9 + 2 * e] = f"{pl}.head{j}.offset_u"
        names[geo.n_coef + 10 + 2 * e] = f"{pl}.head{j}.offset_v"
    return names


def tpinv(a: np.ndarray, scale: np.ndarray, free: np.ndarray | None = None):
    """:func:`mtplan.fitting.linear.truncated_pinv` at this module's rank tolerance: the
    mounting (`free`) takes what it can absorb, which keeps unseen errors (the X roll EAX,
    seen only as a rotation of the YZ pattern) from growing to the size of the mounting
    errors in the exact, non-linear model."""
    return truncated_pinv(a, scale, free, rank_tol=RANK_TOL)


def mounting_mask(geo: Geometry) -> np.ndarray:
    """Mask of the nuisance (mounting) parameters."""
    return np.arange(geo.n_par) >= geo.n_coef


def model_jacobian(geo: Geometry, theta0: np.ndarray, s: np.ndarray):
    """(f(theta0) (2M,), J (2M, P)) by central differences of the exact model, steps 0.1 s."""
    def predict(rows):
        return predict_readings(geo, rows).reshape(rows.shape[0], -1)

    return predict(theta0[None, :])[0], central_jacobian(predict, theta0, 0.1 * s)


@array_cache(maxsize=16)
def joint_ident(setup: Setup) -> dict:
    """Jacobian of the readings at zero error, its SVD, pseudo-inverse and estimability:
    the geometry's (:func:`_joint_geometry`) with the fit's weights (``pinv``)."""
    return _Ident(_joint_geometry(sizeless(setup)), setup)


class _Ident(dict):
    """:func:`_joint_geometry`'s dict; the pseudo-inverses ``pinv0`` (unweighted) and
    ``pinv`` (the joint fit's: generalised least squares where the readings correlate along
    each pass) are computed when first asked for (the patent's first order needs neither)."""

    def __init__(self, base: dict, setup: Setup):
        super().__init__(base)
        self.setup = setup

    def __missing__(self, key):
        s = self.setup
        if key == "pinv0":
            self[key] = tpinv(self["jac"], self["scale"], mounting_mask(self["geo"]))[0]
        elif key == "pinv" and reading_whitener(s) is None:
            self[key] = self["pinv0"]
        elif key == "pinv":
            self[key] = _gls(sizeless(s), weight_ratios(s))
        else:
            raise KeyError(key)
        return self[key]


@array_cache(maxsize=8)
def _joint_geometry(key: Setup) -> dict:
    """What does not depend on the sources' sizes: the Jacobian (closed form,
    :func:`._jacobian.zero_jacobian`), its SVD, null space and the measurands' estimability."""
    geo = geometry(key)
    s = parameter_scales(geo)
    r0, jac = predict_readings(geo, np.zeros((1, geo.n_par))).reshape(-1), zero_jacobian(geo)
    a_s = jac * s  # the SVD as truncated_pinv's (tall: of the QR's R)
    _, sv, vt = np.linalg.svd(np.linalg.qr(a_s, mode="r")) if a_s.shape[0] > a_s.shape[1] \
        else np.linalg.svd(a_s, full_matrices=False)
    rank = int(np.sum(sv > RANK_TOL * sv[0])) if sv.size and sv[0] > 0 else 0
    null = vt[rank:]  # scaled null space (k, P)
    colnorm = np.linalg.norm(a_s, axis=0)
    dead = colnorm <= RANK_TOL * sv[0]
    if null.size and np.any(dead):  # the null space's basis: each parameter without effect
        rest = np.where(dead, 0.0, null)  # alone (its column is exactly 0), then the others
        _, sv_r, vt_r = np.linalg.svd(rest, full_matrices=False)
        null = np.concatenate([vt_r[sv_r > 1e-8], np.eye(geo.n_par)[dead]])
    g = _measurand_map(geo)
    gs = g * s
    resid = np.linalg.norm(gs @ null.T, axis=1) / np.linalg.norm(gs, axis=1) if null.size else \
        np.zeros(len(NAMES))
    no_effect = {name: bool(np.all(colnorm[sl] <= RANK_TOL * sv[0]))
                 for name, (_, sl) in geo.layout.items()}
    return {"geo": geo, "jac": jac, "scale": s, "rank": rank, "sv": sv,
            "null": null, "vt": vt, "g": g, "no_effect": no_effect, "r0": r0,
            "estimable": {n: bool(r < 1e-6) for n, r in zip(NAMES, resid)}}


@functools.lru_cache(maxsize=16)
def _gls(key: Setup, ratios: tuple) -> np.ndarray:
    ji = _joint_geometry(key)
    return gls_pinv(ji["jac"], ji["scale"], ji["vt"], ji["rank"], mounting_mask(ji["geo"]),
                    whitening(key, *ratios))


def readings_matrix(setup: Setup, readings: dict) -> np.ndarray:
    geo = geometry(setup)
    r = np.asarray(readings["plate_mm"], dtype=float)
    if r.ndim != 3 or r.shape[1:] != (geo.plane.size, 2):
        raise InvalidInput([f"The 'plate_mm' readings of geometry21 must have shape "
                            f"(trials, {geo.plane.size}, 2) for this set-up. Got {r.shape} instead."])
    return r.reshape(r.shape[0], -1)
