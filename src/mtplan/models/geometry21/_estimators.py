"""geometry21's joint estimators (Gauss-Newton on the shared linearisation, and its
linear first step), the estimator table and the coefficients of every error function.
"""

from __future__ import annotations

import functools

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.fitting.linear import gls_pinv, restricted_pinv
from mtplan.models.geometry21._layout import Geometry, geometry, plane_slices
from mtplan.models.geometry21._model import (
    joint_ident,
    model_jacobian,
    mounting_mask,
    nuisance,
    parameter_scales,
    predict_readings,
    readings_matrix,
)
from mtplan.models.geometry21._patent import theta_patent
from mtplan.models.geometry21._path import reading_whitener
from mtplan.models.geometry21._physics import measurand_map
from mtplan.models.geometry21._setup import Setup


_GN_ITERATIONS = 8
_GN_TOL = 1e-5  # step below 1e-5 of a typical error (1 um / 10 urad): 0.01 pm
#: the shared linearisation's neglected term may move a trial by 1e-3 of a typical error,
#: or by 1 % of the batch's spread of that parameter (its Monte Carlo uncertainty), at most
SHARED_TOL = 1e-3
SHARED_SPREAD = 0.01
#: smaller batches (a measurement is a batch of one) are solved trial by trial
SHARED_MIN = 8
#: grid of the shared linearisation point of the coefficients [typical errors]
_GRID_STEP = 10.0


def _grid_step(geo: Geometry) -> np.ndarray:
    """Grid of the shared linearisation points of the coefficients [their units]."""
    return _GRID_STEP * parameter_scales(geo)[: geo.n_coef]


@functools.lru_cache(maxsize=8)
def _linearisation(setup: Setup, key: tuple) -> dict:
    """The Jacobian ``jac`` (2M, P), its pseudo-inverse ``pinv`` and the pieces of
    :class:`_Unmounted` at the coefficients of the grid point `key` (ints, one per
    coefficient) with no mounting error.

    A pure function of the set-up and the grid point, so that a batch's result never
    depends on which batches ran before (the cache only saves time).
    """
    ji = joint_ident(setup)
    geo, s = ji["geo"], ji["scale"]
    if any(key):
        c = np.asarray(key, dtype=float) * _grid_step(geo)
        _, jac = model_jacobian(geo, np.concatenate([c, np.zeros(geo.n_par - geo.n_coef)]), s)
        w = reading_whitener(setup)
        pinv = restricted_pinv(jac, s, ji["vt"], ji["rank"], mounting_mask(geo)) if w is None else \
            gls_pinv(jac, s, ji["vt"], ji["rank"], mounting_mask(geo), w)
    else:
        jac, pinv = ji["jac"], ji["pinv"]
    npar = geo.n_par
    p3 = pinv.reshape(npar, -1, 2)
    split, plate = [], np.empty((npar, 3, 2))
    for k, sl in enumerate(plane_slices(geo)):
        pk = p3[:, sl, :]
        quarter = np.stack([pk[..., 1], -pk[..., 0]], axis=-1)  # P G: G (u, v) = (-v, u)
        split.append(np.ascontiguousarray(np.concatenate([pk, quarter]).reshape(2 * npar, -1)))
        plate[:, k] = pk.sum(axis=1)
    head = np.stack([p3[:, sl, :].sum(axis=1) for _, sl in geo.xslices], axis=1) \
        if geo.n_extra else np.zeros((npar, 0, 2))
    return {"jac": jac, "pinv": pinv, "split": split, "plate": plate.reshape(npar, -1),
            "head": head.reshape(npar, -1), "coef_response": pinv @ jac[:, : geo.n_coef]}


def _plate_model(geo: Geometry, coef: np.ndarray) -> np.ndarray:
    """Exact readings (n, 2M) of coefficients (n, n_coef) with the plates and heads as set."""
    theta = np.zeros((coef.shape[0], geo.n_par))
    theta[:, : geo.n_coef] = coef
    return predict_readings(geo, theta).reshape(coef.shape[0], -1)


class _Unmounted:
    """``pinv @ (R(rotation) r + shift)``: the readings brought back to the nominal plate
    frame with each trial's own mounting estimate and projected on the parameters, for any
    mounting. The rotation is per plane, so ``P R(phi) r = cos(phi) P r + sin(phi) P G r``
    (G the quarter turn): one product for the batch per plane serves every iteration."""

    def __init__(self, geo: Geometry, r: np.ndarray, lin: dict):
        n, npar = r.shape[0], lin["pinv"].shape[0]
        self.geo, self.lin = geo, lin
        self.y = np.empty((n, 3, npar))
        self.z = np.empty((n, 3, npar))
        for k, sl in enumerate(plane_slices(geo)):
            yz = r[:, 2 * sl.start: 2 * sl.stop] @ lin["split"][k].T
            self.y[:, k], self.z[:, k] = yz[:, :npar], yz[:, npar:]

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        offset, turn, head = nuisance(self.geo, theta)
        n = theta.shape[0]
        out = np.einsum("nk,nkp->np", np.cos(turn), self.y)
        out += np.einsum("nk,nkp->np", np.sin(turn), self.z)
        out += offset.reshape(n, -1) @ self.lin["plate"].T
        out -= head.reshape(n, -1) @ self.lin["head"].T
        return out


def theta_joint_per_trial(setup: Setup, readings: dict) -> np.ndarray:
    """The former joint estimate (chord Gauss-Newton with the exact model evaluated for every
    trial in every iteration), kept as the reference of :func:`theta_joint`'s speed-up."""
    ji = joint_ident(setup)
    geo, pinv, s = ji["geo"], ji["pinv"], ji["scale"]
    r = readings_matrix(setup, readings)
    theta = (r - ji["r0"]) @ pinv.T
    for _ in range(_GN_ITERATIONS):
        step = (r - predict_readings(geo, theta).reshape(r.shape)) @ pinv.T
        theta = theta + step
        if np.max(np.abs(step) / s) < _GN_TOL:  # whole batch converged
            break
    return theta


def theta_joint(setup: Setup, readings: dict, iterations: int) -> np.ndarray:
    """Joint least squares; Gauss-Newton with one linearisation for the batch.

    The model is ``r = R(-rotation) (L(c) - shift)`` per plate: a rigid plate transform,
    which each trial undoes exactly with its own estimate (:class:`_Unmounted`), after the
    machine's error model L of the coefficients c, whose non-linearity is weak and is
    shared: L is evaluated exactly at the batch's median coefficients c_m and expanded to
    first order about it (``L(c) = L(c_m) + J_c (c - c_m)``). Chord iterations (the
    Jacobian at the grid point next to c_m towards zero, see :func:`_linearisation`) until every
    trial's step is below 1e-5 of a typical error; then the neglected second-order term
    is evaluated exactly for the trials farthest from c_m, and if its correction exceeds
    both 1e-3 of a typical error and 1 % of the batch's spread of that parameter (or the
    iterations did not converge), the batch is solved again with L evaluated exactly for
    every trial, as are batches of fewer than 8 trials.
    """
    ji = joint_ident(setup)
    geo, s = ji["geo"], ji["scale"]
    nc = geo.n_coef
    r = readings_matrix(setup, readings)
    lin = _linearisation(setup, (0,) * nc)
    unmounted = _Unmounted(geo, r, lin)
    # the linear estimate, (r - r0) @ pinv.T, from the same products
    theta = unmounted.y.sum(axis=1) - ji["pinv"] @ ji["r0"]
    if iterations == 0:
        return theta
    key = tuple(int(k) for k in np.trunc(np.median(theta[:, :nc], axis=0) / _grid_step(geo)))
    if any(key):
        lin = _linearisation(setup, key)
        unmounted = _Unmounted(geo, r, lin)
    jac, pinv, b = lin["jac"], lin["pinv"], lin["coef_response"]

    def solve(theta, shared):
        for _ in range(iterations):
            if shared:  # the exact model once, at the median; first order about it
                c_m = np.median(theta[:, :nc], axis=0)
                model = _plate_model(geo, c_m[None, :])
                step = unmounted(theta) - model @ pinv.T - (theta[:, :nc] - c_m) @ b.T
            else:
                step = unmounted(theta) - _plate_model(geo, theta[:, :nc]) @ pinv.T
            theta = theta + step
            if np.max(np.abs(step) / s) < _GN_TOL:
                return theta, (c_m, model) if shared else None
        return theta, None

    if r.shape[0] < SHARED_MIN:
        return solve(theta, False)[0]
    out, at = solve(theta, True)
    if at is not None:  # the term left out, exactly, where it is largest
        c_m, model = at
        dev = np.abs(out[:, :nc] - c_m) / s[:nc]
        far = np.unique([*np.argsort(dev.max(axis=1))[-3:],
                         int(np.argmax(np.linalg.norm(dev, axis=1)))])
        lin = model + (out[far, :nc] - c_m) @ jac[:, :nc].T
        left = (_plate_model(geo, out[far, :nc]) - lin) @ pinv.T
        allowed = np.maximum(SHARED_TOL * s, SHARED_SPREAD * np.std(out, axis=0))
        if np.all(np.abs(left) <= allowed):
            return out
    return solve(out, False)[0]


def estimate_theta(setup: Setup, readings: dict, estimator: str) -> np.ndarray:
    if estimator == "patent":
        return theta_patent(setup, readings)
    if estimator == "joint":
        return theta_joint(setup, readings, _GN_ITERATIONS)
    if estimator == "joint_linear":
        return theta_joint(setup, readings, 0)
    raise InvalidInput([f"The 'estimator' parameter of geometry21 must be one of 'patent', "
                        f"'joint', 'joint_linear'. Got {estimator!r} instead."])


def measure(setup: Setup, theta: np.ndarray) -> dict:
    ms, g = measurand_map(setup)
    vals = theta @ g.T
    return {m.name: vals[:, i] for i, m in enumerate(ms)}


def estimate_patent(setup: Setup, readings: dict) -> dict:
    """The patent's stepwise estimator (lines, then circles); measurands [mm, rad], (n,)."""
    return measure(setup, theta_patent(setup, readings))


def estimate_joint(setup: Setup, readings: dict) -> dict:
    """Joint least squares of all coefficients, Gauss-Newton refined; [mm, rad], (n,)."""
    return measure(setup, theta_joint(setup, readings, _GN_ITERATIONS))


def estimate_joint_linear(setup: Setup, readings: dict) -> dict:
    """Joint linearised least squares (one matrix product); [mm, rad], (n,)."""
    return measure(setup, theta_joint(setup, readings, 0))


ESTIMATORS = {"patent": estimate_patent, "joint": estimate_joint,
              "joint_linear": estimate_joint_linear}
#: each estimator as the documents describe it (plain words, jargon spelled out)
DESCRIPTIONS = {
    "patent": "The source method's stepwise evaluation: straight lines first, then circles.",
    "joint": "Least squares of all error coefficients at once, refined by Gauss-Newton "
             "iteration.",
    "joint_linear": "Least squares of all error coefficients at once, linearised (one matrix "
                    "product).",
}


# --------------------------------------------------------------------------- reports
def check_estimator(estimator: str) -> None:
    if estimator not in ESTIMATORS:
        raise InvalidInput([f"The 'estimator' parameter of geometry21 must be one of "
                            f"{', '.join(map(repr, ESTIMATORS))}. Got {estimator!r} instead."])


def coefficients(setup: Setup, readings: dict, *, estimator: str = "joint") -> dict:
    """Estimated coefficients of every error function.

    Returns
    -------
    dict of name -> (powers, array (n, K)) [mm/mm^k or rad/mm^k]; unidentifiable
    functions are present with the value the estimator's null-space convention gives them
    (the joint fits: the error coefficients' smallest norm, the mounting taking what it can)
    and must be read with :func:`identifiability` (the data do not determine them).
    """
    check_estimator(estimator)
    theta = estimate_theta(setup, readings, estimator)
    geo = geometry(setup)
    return {name: (pw, theta[:, sl]) for name, (pw, sl) in geo.layout.items()}

