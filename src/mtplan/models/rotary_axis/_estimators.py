"""rotary_axis's estimators: the patent's planes and line, the joint, gls and angles fits."""

from __future__ import annotations

import functools

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.fitting import SourceModel, gls_step, source_effects
from mtplan.models.rotary_axis._axes import (
    axis_parts as _parts,
    combined as _combined,
)
from mtplan.models.rotary_axis._layout import NAMES as _NAMES, plan as _plan
from mtplan.models.rotary_axis._physics import forward, sources, zero_errors
from mtplan.models.rotary_axis._setup import NAME, Setup, Truth


# --------------------------------------------------------------------------- estimators
def check_readings(setup: Setup, readings, *, passes: bool = False) -> np.ndarray:
    """The readings z_mm, (n, P, R); unless `passes`, each lattice point's mean over the
    sensor's orientations (n, P, M): with sensor_reversal the mean of the readings at 0
    and 180 deg, in which the odd errors of the sensor (the spot's lateral offset, the
    angle influence's odd part) cancel."""
    if not isinstance(readings, dict) or "z_mm" not in readings:
        raise InvalidInput([f"The 'readings' parameter of {NAME} must be a dict with the key "
                            f"'z_mm'. Got {type(readings).__name__} instead."])
    z = np.asarray(readings["z_mm"], dtype=float)
    shape = (setup.n_positions, setup.n_readings)
    if z.ndim != 3 or z.shape[1:] != shape:
        raise InvalidInput([f"The 'readings' parameter of {NAME} must hold 'z_mm' of shape "
                            f"(n, {shape[0]}, {shape[1]}) for this set-up. Got {z.shape} instead."])
    return z if passes else _pass_mean(setup, _corrected(setup, z))


def _corrected(setup: Setup, z: np.ndarray) -> np.ndarray:
    """The readings less the calibrated characteristic at each reading's nominal tilt
    (sensor_characteristic), or as they are without one."""
    c = _plan(setup).characteristic
    return z if c is None else z - c


def _pass_mean(setup: Setup, z: np.ndarray) -> np.ndarray:
    """Each lattice point's mean over the passes: (n, P, R) -> (n, P, M)."""
    if setup.n_passes == 1:
        return z
    n, P, _ = z.shape
    return z.reshape(n, P, setup.n_passes, setup.n_points).mean(axis=2)


def _each_axis(setup: Setup, readings: dict, estimate_axis) -> dict[str, np.ndarray]:
    """Run a single-axis estimator on each axis's positions; add CA's derived measurands."""
    z = check_readings(setup, readings)
    out = {}
    for part, sl in _parts(setup):
        out.update(estimate_axis(part, z[:, sl]))
    if setup.axis == "CA":
        out.update(_combined(setup, out))
    return out


def _planes(setup: Setup, z: np.ndarray) -> np.ndarray:
    """Least-squares plane of every lattice: (n, P, 3) = (height at centre, dz/dx, dz/dy)."""
    n, P, M = z.shape
    return (z.reshape(n * P, M) @ _plan(setup).fit).reshape(n, P, 3)


def _unit_planes(setup: Setup, coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Upward unit normals (n, P, 3) and offsets D (n, P): n . x + D = 0."""
    g = _plan(setup)
    h, a, b = coef[..., 0], coef[..., 1], coef[..., 2]
    inv = 1.0 / np.sqrt(1.0 + a * a + b * b)
    normal = np.empty(coef.shape)
    normal[..., 0] = -a * inv
    normal[..., 1] = -b * inv
    normal[..., 2] = inv
    offset = -(h - a * g.centres[:, 0] - b * g.centres[:, 1]) * inv
    return normal, offset


def _solve_sym3(sxx, sxy, sxz, syy, syz, szz, rhs: np.ndarray) -> np.ndarray:
    """Solve symmetric 3 x 3 systems by the adjugate, elementwise over the batch.

    The six entries are arrays (n,); `rhs` is (n, 3, k); returns (n, 3, k).
    """
    A = syy * szz - syz * syz
    B = sxz * syz - sxy * szz
    C = sxy * syz - sxz * syy
    D = sxx * szz - sxz * sxz
    E = sxy * sxz - sxx * syz
    F = sxx * syy - sxy * sxy
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_det = 1.0 / (sxx * A + sxy * B + sxz * C)
    r0, r1, r2 = rhs[:, 0], rhs[:, 1], rhs[:, 2]
    out = np.empty_like(rhs)
    out[:, 0] = (A[:, None] * r0 + B[:, None] * r1 + C[:, None] * r2) * inv_det[:, None]
    out[:, 1] = (B[:, None] * r0 + D[:, None] * r1 + E[:, None] * r2) * inv_det[:, None]
    out[:, 2] = (C[:, None] * r0 + E[:, None] * r1 + F[:, None] * r2) * inv_det[:, None]
    return out


def _patent_line(setup: Setup, coef: np.ndarray):
    """The patent's steps 4-5 on fitted planes: pierce point (n,3), unit direction (n,3), normals.

    ``N P = -D`` and ``N v = 1`` share the normal matrix ``N^T N``: one 3 x 3 solve with
    two right-hand sides per trial.
    """
    normal, offset = _unit_planes(setup, coef)
    nx, ny, nz = normal[..., 0], normal[..., 1], normal[..., 2]
    rhs = np.empty((len(coef), 3, 2))
    rhs[..., 0] = -np.einsum("npi,np->ni", normal, offset)
    rhs[..., 1] = normal.sum(axis=1)
    sol = _solve_sym3((nx * nx).sum(1), (nx * ny).sum(1), (nx * nz).sum(1),
                      (ny * ny).sum(1), (ny * nz).sum(1), (nz * nz).sum(1), rhs)
    point, v = sol[..., 0], sol[..., 1]
    ax = _plan(setup).frame.ax
    v = v * np.sign(v @ ax)[:, None]  # the axis points along its nominal direction
    return point, v / np.linalg.norm(v, axis=-1, keepdims=True), normal


def _line_measurands(setup: Setup, point: np.ndarray, direction: np.ndarray) -> dict:
    """Location errors of the line through `point` along `direction`, (n,) each [mm, rad]."""
    f = _plan(setup).frame
    along = direction @ f.ax
    t1, t2 = (direction @ f.p1) / along, (direction @ f.p2) / along
    shift = (setup.reference_height_mm - point @ f.ax) / along
    at_ref = point + shift[:, None] * direction
    n1, n2, a1, a2 = _NAMES[setup.axis]
    return {n1: at_ref @ f.p1, n2: at_ref @ f.p2, a1: -t2, a2: t1}


def estimate_patent(setup: Setup, readings: dict) -> dict[str, np.ndarray]:
    """The patent's method: plane per lattice, LS intersection ``N P = -D``, ``N v = 1``.

    Parameters
    ----------
    setup : Setup
    readings : dict
        ``z_mm``: array (n, positions, points) [mm].

    Returns
    -------
    dict of str to array (n,)
        The measurands of :func:`measurands` [mm, rad].
    """
    return _each_axis(setup, readings, _patent_axis)


def _patent_axis(setup: Setup, z: np.ndarray) -> dict[str, np.ndarray]:
    point, direction, _ = _patent_line(setup, _planes(setup, z))
    return _line_measurands(setup, point, direction)


# joint model: parameters (n, 6) = position along p1, p2 of the axis where it crosses the
# station (a plane normal to the nominal axis, at the patent's pierce point, fixed per
# trial so position and slope are nearly uncorrelated) [mm], slopes along p1, p2 [1], the
# pierce point's position along the axis from the station [mm], cone angle alpha [rad];
# plus one azimuth per position (n, P) [rad]
_STEPS = np.array([1e-3, 1e-3, 1e-6, 1e-6, 1e-3, 1e-6])
_PHI_STEP = 1e-6


def _joint_model(setup: Setup, par: np.ndarray, phi: np.ndarray, station: np.ndarray) -> np.ndarray:
    """Plane coefficients (n, P, 3) predicted by the axis model."""
    g = _plan(setup)
    f = g.frame
    w = f.ax + par[:, 2:3] * f.p1 + par[:, 3:4] * f.p2
    u = w / np.linalg.norm(w, axis=-1, keepdims=True)
    p = station[:, None] * f.ax + par[:, 0:1] * f.p1 + par[:, 1:2] * f.p2 + par[:, 4:5] * w
    e1 = f.p1 - (u @ f.p1)[:, None] * u
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(u, e1)
    ca, sa = np.cos(par[:, 5:6]), np.sin(par[:, 5:6])
    cp, sp = np.cos(phi)[..., None], np.sin(phi)[..., None]
    nrm = (ca * u)[:, None, :] + sa[:, None] * (cp * e1[:, None, :] + sp * e2[:, None, :])
    c1 = -nrm[..., 0] / nrm[..., 2]
    c2 = -nrm[..., 1] / nrm[..., 2]
    h = p[:, 2:3] + c1 * (g.centres[:, 0] - p[:, 0:1]) + c2 * (g.centres[:, 1] - p[:, 1:2])
    return np.stack([h, c1, c2], axis=-1)


def _joint_start(setup: Setup, coef: np.ndarray):
    """Start values from the patent's line: parameters (n, 6), azimuths (n, P), station (n,)."""
    f = _plan(setup).frame
    point, u, normal = _patent_line(setup, coef)
    station = point @ f.ax
    along = u @ f.ax
    par = np.zeros((len(u), 6))
    par[:, 0], par[:, 1] = point @ f.p1, point @ f.p2
    par[:, 2], par[:, 3] = (u @ f.p1) / along, (u @ f.p2) / along
    cos_alpha = np.einsum("npi,ni->np", normal, u).mean(axis=1)
    par[:, 5] = np.arccos(np.clip(cos_alpha, -1.0, 1.0))
    e1 = f.p1 - (u @ f.p1)[:, None] * u
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(u, e1)
    phi = np.arctan2(np.einsum("npi,ni->np", normal, e2), np.einsum("npi,ni->np", normal, e1))
    return par, phi, station


def _block_weight(weights: np.ndarray) -> np.ndarray:
    """The weight (3P, 3P) of all plane coefficients: each position's (P, 3, 3) on the
    block diagonal."""
    P = weights.shape[0]
    w_full = np.zeros((P, 3, P, 3))
    w_full[np.arange(P), :, np.arange(P), :] = weights
    return w_full.reshape(3 * P, 3 * P)


def _joint_fit(setup: Setup, coef: np.ndarray, *, max_iter: int = 30, rtol: float = 1e-9,
               weights: np.ndarray | None = None):
    """Gauss-Newton on the batch over the six line parameters and every position's azimuth
    (:func:`mtplan.fitting.gls_step`).

    A trial has converged when every step is below `rtol` times the parameter's
    standard uncertainty for readings of unit variance (1e-9 of it: 1e-6 of the
    uncertainty at 1 um noise), plus 1e-14 [mm, rad] for round-off.

    `weights` (3P, 3P) weight all plane coefficients (default: each position's lattice
    normal matrix on the block diagonal, i.e. independent reading noise of equal variance).

    Returns
    -------
    par : array (n, 6), phi : array (n, P), station : array (n,), converged : bool array (n,)
    """
    g = _plan(setup)
    w_full = (_block_weight(np.broadcast_to(g.gram, (g.theta.size, 3, 3))) if weights is None
              else weights)
    par, phi, station = _joint_start(setup, coef)
    n, P = phi.shape
    done = np.zeros(n, dtype=bool)
    for _ in range(max_iter):
        todo = np.flatnonzero(~done)
        if todo.size == 0:
            break
        pa, ph, c, st = par[todo], phi[todo], coef[todo], station[todo]
        r = c - _joint_model(setup, pa, ph, st)  # (k, P, 3)
        jg = np.empty((len(pa), P, 3, 6))
        for j, step in enumerate(_STEPS):
            d = np.zeros(6)
            d[j] = step
            jg[..., j] = (_joint_model(setup, pa + d, ph, st)
                          - _joint_model(setup, pa - d, ph, st)) / (2 * step)
        jp = (_joint_model(setup, pa, ph + _PHI_STEP, st)
              - _joint_model(setup, pa, ph - _PHI_STEP, st)) / (2 * _PHI_STEP)  # (k, P, 3)
        jac = np.zeros((len(pa), P, 3, 6 + P))  # azimuth p moves position p's plane only
        jac[..., :6] = jg
        for p in range(P):
            jac[:, p, :, 6 + p] = jp[:, p]
        step, inv = gls_step(jac.reshape(len(pa), 3 * P, 6 + P), r.reshape(len(pa), -1),
                             weight=w_full)
        dg, dp = step[:, :6], step[:, 6:]
        par[todo] = pa + dg
        phi[todo] = ph + dp
        sd = np.sqrt(np.abs(np.diagonal(inv, axis1=1, axis2=2)))
        small = np.all(np.abs(step) <= rtol * sd + 1e-14, axis=1)
        done[todo[small]] = True
    return par, phi, station, done


def estimate_joint(setup: Setup, readings: dict) -> dict[str, np.ndarray]:
    """Joint least squares of the axis model to all readings (maximum likelihood).

    Trials whose Gauss-Newton iteration does not converge are returned as NaN (the
    Monte Carlo engine refuses them), never as a silent number.

    Parameters
    ----------
    setup : Setup
    readings : dict
        ``z_mm``: array (n, positions, points) [mm].

    Returns
    -------
    dict of str to array (n,)
        The measurands of :func:`measurands` [mm, rad].
    """
    return _each_axis(setup, readings, _joint_axis)


def _joint_axis(setup: Setup, z: np.ndarray) -> dict[str, np.ndarray]:
    return _joint_measurands(setup, *_joint_fit(setup, _planes(setup, z)))


def _joint_measurands(setup: Setup, par, phi, station, ok) -> dict[str, np.ndarray]:
    """Measurands from the joint fit's parameters; trials that did not converge are NaN."""
    par = par.copy()
    par[~ok] = np.nan
    lever = setup.reference_height_mm - station  # from the station to the reference
    n1, n2, a1, a2 = _NAMES[setup.axis]
    return {n1: par[:, 0] + lever * par[:, 2], n2: par[:, 1] + lever * par[:, 3],
            a1: -par[:, 3], a2: par[:, 2]}


#: a source whose effect on the plane coefficients lies in the span of the tied fit's
#: Jacobian to within this share of its size is taken up by the fit's parameters (the
#: artifact's pose and height, the spot's offset, the sensor's zero and scale: their
#: secants leave that span by 1e-12-4e-4; the nearest source that does not, flatness,
#: by 9e-3)
_ABSORBED = 1e-3


@functools.lru_cache(maxsize=16)
def _gls_weights(setup: Setup) -> np.ndarray:
    """Inverse covariance (3P, 3P) of all plane coefficients under the set-up's active error
    sources (:func:`mtplan.fitting.source_effects` through forward model and plane fit, at
    the default truth; exact where both stages are linear in the errors).

    The whole covariance, not only each position's block: the errors shared between
    positions (the sensor's angle influence, which on an A axis grows with each position's
    tilt; flatness, the slides' slope and bow, drift) correlate the positions, and a
    weight that leaves that out cannot tell their pattern from a shift of the axis, so
    the estimate is honest but not efficient (A: u(EZ0A) 43.9 um block-diagonal, 13.0 um
    with the whole covariance, the posterior's 12.9).

    A source whose effect lies in the span of the fit's Jacobian (:data:`_ABSORBED`) is
    left out: for a linear model, covariance ``X S X^T`` added to the readings' does not
    move the generalised least-squares estimate, and its directions, weighted almost to
    zero, would leave Gauss-Newton a large residual there (the artifact's 5 mrad tilt),
    on which it does not converge.
    """
    src, truth = sources(setup), Truth()

    def planes_of(errors):
        z = _pass_mean(setup, _corrected(setup, forward(setup, truth, errors)["z_mm"]))
        return _planes(setup, z).reshape(z.shape[0], -1)

    model = SourceModel(NAME, src, planes_of, lambda m: zero_errors(setup, m))
    basis = _fit_span(setup, planes_of(model.errors(1)).reshape(1, -1, 3))
    D, cols = np.zeros(basis.shape[0]), []
    for name in (k for k, v in src.items() if v.active):
        d, u = source_effects(model, [name])
        size = np.linalg.norm(u, axis=0).max(initial=0.0)
        if not np.any(d) and (size == 0 or np.linalg.norm(
                u - basis @ (basis.T @ u), axis=0).max() <= _ABSORBED * size):
            continue
        D, cols = D + d, cols + [u]
    U = np.hstack(cols) if cols else np.zeros((D.size, 0))
    weight = np.linalg.inv(np.diag(D) + U @ U.T)
    weight = 0.5 * (weight + weight.T)
    # a common factor does not move the minimum; scaling to the noise-only weights keeps
    # the fit's convergence test (relative to unit-variance uncertainties) meaningful
    gram = _plan(setup).gram
    return weight * (weight.shape[0] // 3 * np.trace(gram) / np.trace(weight))


def _fit_span(setup: Setup, coef: np.ndarray) -> np.ndarray:
    """Orthonormal basis (3P, 7 x axes) of the span of the tied fit's Jacobian at the plane
    coefficients `coef` (1, P, 3) of noise-free readings (a subspace of the joint fit's,
    whose azimuths are free)."""
    jac = np.zeros((*coef.shape[1:], 0))
    for part, sl in _parts(setup):
        par, station = _angles_start(part, coef[:, sl])
        block = np.zeros((*coef.shape[1:], _ANGLES_STEPS.size))
        block[sl] = _angles_jacobian(part, par, station)[0]
        jac = np.concatenate([jac, block], axis=-1)
    return np.linalg.qr(jac.reshape(coef[0].size, -1))[0]


def estimate_gls(setup: Setup, readings: dict) -> dict[str, np.ndarray]:
    """The joint fit weighted by the set-up's whole error budget (generalised least squares).

    Like :func:`estimate_joint`, but all plane coefficients are weighted by the inverse of
    their covariance under the set-up's active error sources, between positions too
    (:func:`_gls_weights`), computed once per set-up by the law of propagation: one
    (3P, 3P) matrix for every trial. The joint fit's own weighting assumes independent
    reading noise only, which makes it worse than the patent's method when the per-position
    errors dominate, and no weight that leaves the positions' correlations out can tell
    the angle influence's pattern over an A arc from a shift of the axis.
    """
    return _each_axis(setup, readings, _gls_axis)


def _gls_axis(setup: Setup, z: np.ndarray) -> dict[str, np.ndarray]:
    return _joint_measurands(setup, *_joint_fit(setup, _planes(setup, z),
                                                weights=_gls_weights(setup)))


# the tied fit: the joint model's six parameters and the common zero phi0 of the azimuths
# (n, 7); position p's azimuth is phi0 + its commanded angle
_ANGLES_STEPS = np.append(_STEPS, _PHI_STEP)


def _angles_model(setup: Setup, par: np.ndarray, station: np.ndarray) -> np.ndarray:
    """Plane coefficients (n, P, 3) with each azimuth at phi0 + the commanded angle."""
    return _joint_model(setup, par[:, :6], par[:, 6:7] + _plan(setup).theta, station)


def _angles_start(setup: Setup, coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start of the tied fit of one axis from the patent's line, phi0 the circular mean of
    the planes' azimuths less their commanded angles: par (n, 7), station (n,)."""
    par6, phi, station = _joint_start(setup, coef)
    d = phi - _plan(setup).theta
    phi0 = np.arctan2(np.sin(d).mean(axis=1), np.cos(d).mean(axis=1))
    return np.column_stack([par6, phi0]), station


def _angles_jacobian(setup: Setup, par: np.ndarray, station: np.ndarray) -> np.ndarray:
    """Central-difference Jacobian (n, P, 3, 7) of one axis's plane coefficients."""
    jac = np.empty((len(par), _plan(setup).theta.size, 3, _ANGLES_STEPS.size))
    for j, step in enumerate(_ANGLES_STEPS):
        d = np.zeros(_ANGLES_STEPS.size)
        d[j] = step
        jac[..., j] = (_angles_model(setup, par + d, station)
                       - _angles_model(setup, par - d, station)) / (2 * step)
    return jac


def _angles_fit(setup: Setup, coef: np.ndarray, weights: np.ndarray, *, max_iter: int = 30,
                rtol: float = 1e-9):
    """Gauss-Newton on the batch for the seven parameters of the tied fit of every axis of
    the test (7 x 7 per trial and axis, one system for the whole test with the weight
    `weights` (3P, 3P) of all plane coefficients, :func:`mtplan.fitting.gls_step`): on a CA
    test the two axes are fitted at once, so that the errors both parts share (the angle
    influence, the slides' slope and bow, the sensor's zero) weigh in both.

    Each axis started by :func:`_angles_start`; converged as :func:`_joint_fit`.

    Returns
    -------
    list of (part, par (n, 7), station (n,)) per axis; converged : bool array (n,)
    """
    parts = _parts(setup)
    k7 = _ANGLES_STEPS.size
    starts = [_angles_start(part, coef[:, sl]) for part, sl in parts]
    par = np.hstack([p for p, _ in starts])  # (n, 7 x axes)
    done = np.zeros(len(par), dtype=bool)
    for _ in range(max_iter):
        todo = np.flatnonzero(~done)
        if todo.size == 0:
            break
        k = len(todo)
        r = np.empty((k, *coef.shape[1:]))
        jac = np.zeros((k, *coef.shape[1:], par.shape[1]))  # axis i moves its planes only
        for i, (part, sl) in enumerate(parts):
            pa, st = par[todo, k7 * i:k7 * (i + 1)], starts[i][1][todo]
            r[:, sl] = coef[todo, sl] - _angles_model(part, pa, st)
            jac[:, sl, :, k7 * i:k7 * (i + 1)] = _angles_jacobian(part, pa, st)
        step, a_inv = gls_step(jac.reshape(k, -1, par.shape[1]), r.reshape(k, -1),
                               weight=weights)
        par[todo] += step
        small = np.all(np.abs(step) <= rtol * np.sqrt(np.abs(np.diagonal(a_inv, axis1=1, axis2=2)))
                       + 1e-14, axis=1)
        done[todo[small]] = True
    return [(part, par[:, k7 * i:k7 * (i + 1)], starts[i][1])
            for i, (part, _) in enumerate(parts)], done


def estimate_angles(setup: Setup, readings: dict) -> dict[str, np.ndarray]:
    """The weighted joint fit with the planes' azimuths tied to the commanded angles.

    Like :func:`estimate_gls`, but the azimuth of position p's plane normal about the
    axis is ``phi0 + theta_p``: ``theta_p`` the commanded angle (the rotary encoder's),
    ``phi0`` one free common zero. The angular positioning error moves each azimuth off
    ``phi0 + theta_p``; it enters the weight (the plane coefficients' covariance, with
    the other sources). Seven parameters per axis in
    place of 6 + positions: the direction of the axis is better determined, as long as
    the encoder is as good as ``angular_positioning_arcsec`` says (see the module
    docstring for the figures and the price). Arguments and result as
    :func:`estimate_joint` (NaN where the iteration did not converge).
    """
    z = check_readings(setup, readings)
    fits, ok = _angles_fit(setup, _planes(setup, z), _gls_weights(setup))
    out = {}
    for part, par, station in fits:
        out.update(_joint_measurands(part, par[:, :6], None, station, ok))
    if setup.axis == "CA":
        out.update(_combined(setup, out))
    return out
