"""rotary_axis's estimators: the patent's planes and line, the joint, gls and angles fits."""

from __future__ import annotations

import functools

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.fitting import SourceModel, gls_step, source_effects
from mtplan.models.rotary_axis._axes import (
    POSITION_AXIS as _POSITION_AXIS,
    axis_parts as _parts,
    combined as _combined,
)
from mtplan.models.rotary_axis._layout import NAMES as _NAMES, plan as _plan
from mtplan.models.rotary_axis._physics import forward, sources
from mtplan.models.rotary_axis._setup import NAME, Setup, Truth


# --------------------------------------------------------------------------- estimators
def _check_readings(setup: Setup, readings, *, passes: bool = False) -> np.ndarray:
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
    return z if passes else _pass_mean(setup, z)


def _pass_mean(setup: Setup, z: np.ndarray) -> np.ndarray:
    """Each lattice point's mean over the passes: (n, P, R) -> (n, P, M)."""
    if setup.n_passes == 1:
        return z
    n, P, _ = z.shape
    return z.reshape(n, P, setup.n_passes, setup.n_points).mean(axis=2)


def _each_axis(setup: Setup, readings: dict, estimate_axis) -> dict[str, np.ndarray]:
    """Run a single-axis estimator on each axis's positions; add CA's derived measurands."""
    z = _check_readings(setup, readings)
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
    (:func:`mtplan.fitting.gls_step`, the positions' weights on the block diagonal).

    A trial has converged when every step is below `rtol` times the parameter's
    standard uncertainty for readings of unit variance (1e-9 of it: 1e-6 of the
    uncertainty at 1 um noise), plus 1e-14 [mm, rad] for round-off.

    `weights` (P, 3, 3) weight each position's plane coefficients (default: the lattice's
    normal matrix, i.e. independent reading noise of equal variance).

    Returns
    -------
    par : array (n, 6), phi : array (n, P), station : array (n,), converged : bool array (n,)
    """
    g = _plan(setup)
    W = np.broadcast_to(g.gram, (g.theta.size, 3, 3)) if weights is None else weights
    w_full = _block_weight(W)
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


@functools.lru_cache(maxsize=16)
def _gls_weights(setup: Setup) -> np.ndarray:
    """Inverse covariance (P, 3, 3) of each position's plane coefficients under every active
    error source of the set-up (:func:`mtplan.fitting.source_effects` through forward model
    and plane fit, at the default truth; exact, since both stages are linear in the errors)."""
    # the per-position sources only: a per-test error (flatness, scale, drift, the
    # artifact's pose) is shared by every position, which a block-diagonal weight cannot
    # say (the artifact's pose is taken up exactly by the fit's free cone and pierce point)
    src, truth = sources(setup), Truth()

    def planes_of(errors):
        z = _pass_mean(setup, forward(setup, truth, errors)["z_mm"])
        return _planes(setup, z).reshape(z.shape[0], -1)

    model = SourceModel(NAME, src, planes_of,
                        lambda m: {k: np.zeros((m, *v.shape)) for k, v in src.items()})
    D, U = source_effects(model, [k for k, v in src.items() if v.active and k in _POSITION_AXIS])
    P = _plan(setup).theta.size
    cov = (np.diag(D) + U @ U.T).reshape(P, 3, P, 3)
    blocks = np.stack([cov[p, :, p, :] for p in range(P)])  # (P, 3, 3)
    weights = np.linalg.inv(blocks)
    # a common factor does not move the minimum; scaling to the noise-only weights keeps
    # the fit's convergence test (relative to unit-variance uncertainties) meaningful
    gram = _plan(setup).gram
    return weights * (P * np.trace(gram) / np.trace(weights, axis1=1, axis2=2).sum())


def estimate_gls(setup: Setup, readings: dict) -> dict[str, np.ndarray]:
    """The joint fit weighted by the set-up's whole error budget (generalised least squares).

    Like :func:`estimate_joint`, but each position's plane coefficients are weighted by the
    inverse of their covariance under every active per-position error source (reading
    noise, X/Y/Z positioning, error motions, angular positioning), computed once per
    set-up by the law of propagation. The joint fit's own weighting assumes independent
    reading noise only, which makes it worse than the patent's method when the per-position
    errors dominate; the weighting restores the balance. Correlations between positions
    (flatness, scale, drift, the artifact's pose) are left out of the weight
    (block-diagonal).
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


def _angles_fit(setup: Setup, coef: np.ndarray, weights: np.ndarray, *, max_iter: int = 30,
                rtol: float = 1e-9):
    """Gauss-Newton on the batch for the seven parameters of the tied fit (7 x 7 per trial,
    :func:`mtplan.fitting.gls_step` with the positions' weights on the block diagonal).

    Started from the patent's line, with phi0 the circular mean of the planes' azimuths
    less their commanded angles; converged as :func:`_joint_fit`.

    Returns
    -------
    par : array (n, 7), station : array (n,), converged : bool array (n,)
    """
    theta = _plan(setup).theta
    par6, phi, station = _joint_start(setup, coef)
    d = phi - theta
    par = np.column_stack([par6, np.arctan2(np.sin(d).mean(axis=1), np.cos(d).mean(axis=1))])
    done = np.zeros(len(par), dtype=bool)
    w_full = _block_weight(weights)
    for _ in range(max_iter):
        todo = np.flatnonzero(~done)
        if todo.size == 0:
            break
        pa, st = par[todo], station[todo]
        r = coef[todo] - _angles_model(setup, pa, st)  # (k, P, 3)
        jac = np.empty((*r.shape, _ANGLES_STEPS.size))
        for j, step in enumerate(_ANGLES_STEPS):
            d = np.zeros(_ANGLES_STEPS.size)
            d[j] = step
            jac[..., j] = (_angles_model(setup, pa + d, st)
                           - _angles_model(setup, pa - d, st)) / (2 * step)
        k = len(todo)
        step, a_inv = gls_step(jac.reshape(k, -1, _ANGLES_STEPS.size), r.reshape(k, -1),
                               weight=w_full)
        par[todo] = pa + step
        small = np.all(np.abs(step) <= rtol * np.sqrt(np.abs(np.diagonal(a_inv, axis1=1, axis2=2)))
                       + 1e-14, axis=1)
        done[todo[small]] = True
    return par, station, done


def estimate_angles(setup: Setup, readings: dict) -> dict[str, np.ndarray]:
    """The weighted joint fit with the planes' azimuths tied to the commanded angles.

    Like :func:`estimate_gls`, but the azimuth of position p's plane normal about the
    axis is ``phi0 + theta_p``: ``theta_p`` the commanded angle (the rotary encoder's),
    ``phi0`` one free common zero. The angular positioning error moves each azimuth off
    ``phi0 + theta_p``; it enters the weight (each position's plane-coefficient
    covariance, with the other per-position sources). Seven parameters per axis in
    place of 6 + positions: the direction of the axis is better determined, as long as
    the encoder is as good as ``angular_positioning_arcsec`` says (see the module
    docstring for the figures and the price). Arguments and result as
    :func:`estimate_joint` (NaN where the iteration did not converge).
    """
    return _each_axis(setup, readings, _angles_axis)


def _angles_axis(setup: Setup, z: np.ndarray) -> dict[str, np.ndarray]:
    par, station, ok = _angles_fit(setup, _planes(setup, z), _gls_weights(setup))
    return _joint_measurands(setup, par[:, :6], None, station, ok)
