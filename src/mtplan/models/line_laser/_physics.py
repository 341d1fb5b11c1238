"""line_laser's measurands, error sources and forward model (each scan's rays traced
to the artifact, exactly), true values, the truth of an estimate and the machine time.
"""

from __future__ import annotations

import math

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.models.line_laser._artifact import (
    facet_count,
    facet_element,
    grid_u,
    grid_y,
    height_map,
    lattice_local,
    rot_x,
    rot_y,
    rot_z,
    sensor_rotation,
    standoff,
    x_shift,
)
from mtplan.models.line_laser._setup import LIN_DEGREES, Truth
from mtplan.models.protocol import Measurand, Readings, Source
from mtplan.uncertainty.distributions import Normal, Rectangular


# --------------------------------------------------------------------------- sources
def measurands(setup) -> tuple:
    return (
        Measurand("alpha_z", "urad", "mounting error angle of the sensor about Z"),
        Measurand("alpha_y", "urad", "mounting error angle of the sensor about Y"),
        Measurand("alpha_x", "urad", "mounting error angle of the sensor about X"),
    )


#: the error source whose spread is the readings' noise (posterior, fit checks, weighting)
NOISE_SOURCE = "sensor_noise"


def sources(setup) -> dict:
    """Every error source (inactive ones with zero spread)."""
    shape = (3, setup.lines, setup.points_per_line)
    return {
        "sensor_noise": Source(
            Normal(0.0, setup.sensor_noise_um * 1e-3), shape,
            "Noise of each height reading; default 1 um: single-profile point noise of a "
            "15-25 mm class laser profiler on matte metal (makers quote 0.2-0.5 um "
            "repeatability for averaged profiles).", field="sensor_noise_um"),
        "shift_error": Source(
            Normal(0.0, setup.shift_error_um * 1e-3), (),
            "Machine's positioning error of the X shift w (shared by scans 2 and 3); default "
            "1 um: ISO 230-2 short-travel repeatability of a machining-centre axis.",
            field="shift_error_um"),
        "raise_error": Source(
            Normal(0.0, setup.raise_error_um * 1e-3), (),
            "Machine's positioning error of the raise h of scan 3; default 1 um: ISO 230-2 "
            "short-travel repeatability of a Z axis.", field="raise_error_um"),
        "trigger_y": Source(
            Normal(0.0, setup.trigger_y_um * 1e-3), (3,),
            "Y position of each scan's trigger train; default 0.3 um: interpolation error "
            "of the linear scale plus trigger latency at the scanning feed.", field="trigger_y_um"),
        "linearity": Source(
            Normal(0.0, setup.linearity_um * 1e-3 / math.sqrt(LIN_DEGREES.size)),
            (LIN_DEGREES.size,),
            "Coefficients of the sensor's height error along the line on the orthonormal "
            "Legendre polynomials of degrees 2, 3, 4 (sqrt(2k+1) P_k of 2 x_l / w0), one set "
            "per test, equal shares, so the expected RMS along the line is linearity_um; "
            "degrees 0 and 1 (offset, tilt) are part of the sensor's data frame, not errors. "
            "Default 1 um: Keyence LJ-X8000 +-0.03 % of F.S., Micro-Epsilon scanCONTROL "
            "about +-0.1 % of FSO.", field="linearity_um"),
        "z_scale": Source(
            Normal(0.0, setup.z_scale_ppm * 1e-6), (),
            "Scale (gain) error of the height reading about the middle of the range, one per "
            "test; default 100 ppm (Keyence LJ-X8000: 0.01 % of F.S. per K).", field="z_scale_ppm"),
        "squareness_xy": Source(
            Rectangular(-setup.squareness_xy_urad * 1e-6, setup.squareness_xy_urad * 1e-6), (),
            "Squareness of the X motion (the shift w) to the Y scan motion, toward +Y; "
            "rectangular +-20 urad (ISO 230-1; ISO 10791-2 tolerances are 0.02 mm/500 mm).",
            field="squareness_xy_urad"),
        "squareness_zy": Source(
            Rectangular(-setup.squareness_zy_urad * 1e-6, setup.squareness_zy_urad * 1e-6), (),
            "Squareness of the Z motion (the raise h) to the Y scan motion, toward +Y; "
            "rectangular +-20 urad (ISO 230-1).", field="squareness_zy_urad"),
        "facet_position": Source(
            Normal(0.0, setup.facet_position_um * 1e-3), (facet_count(setup),),
            "Position error of each facet of the artifact's pockets, along its in-plane "
            "normal (outward positive), independent from facet to facet; the errors repeat "
            "with a period wider than the scanned window (:func:`facet_layout`). Default "
            "2 um: an uncalibrated pocket milled on a machining centre (ISO 230-2 "
            "positioning, contouring and tool deflection of a few micrometres).",
            field="facet_position_um"),
        "drift": Source(
            Normal(0.0, setup.drift_um_per_s * 1e-3), (3,),
            "Thermal drift velocity (X, Y, Z) of the sensor relative to the artifact, one per "
            "test; scan k is displaced by it times its start time after scan 1. Default "
            "0.003 um/s, about 10 um/h (ISO 230-3 warm-up drifts of 5-30 um/h).",
            field="drift_um_per_s"),
    }


def source_structure(setup, truth, name: str):
    """The facets' colouring (:attr:`mtplan.models.protocol.Capabilities.source_structure`):
    colour k holds facet k of every pocket. A reading depends only on the facets of the
    pocket its hit lies in (:func:`height_map`: ``offsets`` of that pocket alone; pockets
    are 0.6 mm of land apart, a facet error moves micrometres), and no two scanned
    pockets share an error (:func:`facet_layout`), so facets of one colour never move a
    common reading. The owners are taken at the error-free hits of the truth's traced
    neighbour (:func:`_row`, as :func:`trace` does); `truth` scalar or batched (its
    first row). None for every other source."""
    if name != "facet_position":
        return None
    _, x, y, _, _, _, _ = nominal_trace(setup, _row(truth, 0))
    pocket = lattice_local(setup, x, y)[2]
    colours = np.tile(np.arange(6), facet_count(setup) // 6)
    return colours, 6 * pocket[None, :] + np.arange(6)[:, None]


def linearity_basis(setup) -> np.ndarray:
    """Orthonormal Legendre polynomials along the line, shape (degrees, points_per_line).

    ``sqrt(2k + 1) P_k(xi)`` with ``xi = 2 x_l / w0`` in [-1, 1], k in ``LIN_DEGREES``:
    each has unit mean square over the line, so coefficients of standard deviation
    ``L / sqrt(degrees)`` give an error curve of expected RMS ``L``.
    """
    xi = 2.0 * grid_u(setup) / setup.line_width_mm
    return np.stack([math.sqrt(2 * k + 1) * np.polynomial.legendre.Legendre.basis(k)(xi)
                     for k in LIN_DEGREES])


def scan_times(setup) -> np.ndarray:
    """Start time of scans 1, 2, 3 and the end of the test [s], shape (4,).

    Each scan is preceded by a dwell ``settle_s``; between scans the machine returns
    along Y at rapid feed and makes the X shift (before scan 2) or the raise (before
    scan 3). The last entry is :func:`duration`.
    """
    length = (setup.lines - 1) * setup.step_mm
    scan = length / min(setup.scan_feed_mm_min / 60, setup.step_mm * setup.frame_rate_per_s)
    rapid = setup.rapid_mm_min / 60
    t1 = setup.settle_s
    t2 = t1 + scan + (length + x_shift(setup)) / rapid + setup.settle_s
    t3 = t2 + scan + (length + setup.raise_mm) / rapid + setup.settle_s
    return np.array([t1, t2, t3, t3 + scan])


def displacements(setup, errors) -> np.ndarray:
    """Actual minus nominal position of the sensor in each scan, (n, 3, 3) [mm].

    Axis 1 is the scan, axis 2 the machine coordinate. The frame is the scan's: Y along
    the Y motion, X in the plane of the X and Y motions, Z normal to both. The X shift
    ``w + e_w`` runs along ``(cos g, sin g, 0)`` (g the X-Y squareness) and the raise
    ``h + e_h`` along ``(0, sin e, cos e)`` (e the Z-Y squareness), both exactly; each scan's
    trigger train is offset along Y; the drift velocity moves scan k by ``v (t_k - t_1)``.
    All zero when every source is zero (exactly: ``(w + 0) cos 0 - w == 0``).
    """
    e_w = np.asarray(errors["shift_error"], dtype=float).reshape(-1)
    n = e_w.shape[0]
    e_h = np.asarray(errors["raise_error"], dtype=float).reshape(n)
    e_y = np.asarray(errors["trigger_y"], dtype=float).reshape(n, 3)
    g = np.asarray(errors["squareness_xy"], dtype=float).reshape(n)
    e = np.asarray(errors["squareness_zy"], dtype=float).reshape(n)
    v = np.asarray(errors["drift"], dtype=float).reshape(n, 3)
    w, h = x_shift(setup), setup.raise_mm
    disp = np.zeros((n, 3, 3))
    sx = w + e_w
    disp[:, 1:, 0] = (sx * np.cos(g) - w)[:, None]
    disp[:, 1:, 1] = (sx * np.sin(g))[:, None]
    rz = h + e_h
    disp[:, 2, 1] += rz * np.sin(e)
    disp[:, 2, 2] = rz * np.cos(e) - h
    disp[:, :, 1] += e_y
    times = scan_times(setup)[:3]
    disp += v[:, None, :] * (times - times[0])[None, :, None]
    return disp


# --------------------------------------------------------------------------- forward
def newton(setup, ox, oy, oz, d, t, idx, rays=None, offsets=None, *, rows=None):
    """Solve ``oz + t d_z = height(ox + t d_x, oy + t d_y)`` in place for ``t[idx]``.

    Newton's method on the piecewise-planar height map: inside one plane a step is
    exact; across a kink each step contracts the error by ``tan(facet) |d_xy|``
    (about 1e-2), so it ends at machine precision in a few steps. ``offsets`` (m,
    facets): the facets' position errors of each row of ``rays`` rays (:func:`height_map`);
    ``rows`` (like ``ox``), instead of ``rays``: the batch row of each ray.
    """
    for _ in range(60):
        if idx.size == 0:
            break
        tt = t[idx]
        # one direction (3,), or one per batch row (m, 3)
        row = rows[idx] if rows is not None else (idx // rays if rays else None)
        dx, dy, dz = (d[row].T if row is not None and np.ndim(d) == 2 else d)
        z, gx, gy = height_map(setup, ox[idx] + tt * dx, oy[idx] + tt * dy, offsets=offsets,
                               rows=None if offsets is None else row)
        step = (oz[idx] + tt * dz - z) / (dz - gx * dx - gy * dy)
        t[idx] = tt - step
        idx = idx[np.abs(step) > 1e-15 * (1.0 + np.abs(tt))]
    return t


def frames(setup, truth):
    """Laser-line and measuring directions and artifact pose: (ex, d, q, c0).

    Shapes (3,), (3,), (3, 3), (3,); with a leading axis (m,) for a truth whose fields
    are arrays (m,) (one truth per batch row, a posterior's walkers).
    """
    r = sensor_rotation(np.asarray(truth.alpha_z_mrad) * 1e-3,
                        np.asarray(truth.alpha_y_mrad) * 1e-3,
                        np.asarray(truth.alpha_x_mrad) * 1e-3)
    q = rot_z(np.asarray(truth.artifact_rz_mrad) * 1e-3) @ rot_y(
        np.asarray(truth.artifact_tilt_y_mrad) * 1e-3) @ rot_x(
        np.asarray(truth.artifact_tilt_x_mrad) * 1e-3)
    x, y = np.broadcast_arrays(np.asarray(truth.artifact_x_mm, dtype=float),
                               np.asarray(truth.artifact_y_mm, dtype=float))
    c0 = np.stack([x, y, np.zeros_like(x)], axis=-1)
    qt = np.swapaxes(q, -1, -2)
    return (np.einsum("...ij,...j->...i", qt, r[..., :, 0]),
            np.einsum("...ij,...j->...i", qt, r[..., :, 2]), q, c0)


def _batched(truth) -> bool:
    """Whether the truth holds one set of values per batch row (array fields)."""
    return bool(np.ndim(truth.alpha_z_mrad) or np.ndim(truth.artifact_x_mm))


def _base(setup, disp, q, c0):
    """The rays' origins at ``x_l = 0`` in the artifact frame, (m, 3, lines, 3): the
    sensor's nominal positions moved by ``disp`` (m, 3, 3) [mm]; ``q``, ``c0`` the pose
    (:func:`frames`, one per row or one for all)."""
    m = disp.shape[0]
    pos = np.zeros((m, 3, setup.lines, 3))
    pos[:, 1:, :, 0] = x_shift(setup)
    pos[:, :, :, 1] = grid_y(setup)[None, None, :]
    pos[:, :, :, 2] = standoff(setup)
    pos[:, 2, :, 2] += setup.raise_mm
    pos += disp[:, :, None, :]
    # one pose per row (a batched truth): (m, 3) and (m, 3, 3), the scan axes added
    c0 = c0[:, None, None, :] if c0.ndim == 2 else c0
    q = q[:, None] if q.ndim == 3 else q
    return (pos - c0) @ q  # rows: q.T @ (p - c0)


def origins(setup, truth, disp):
    """Ray origins in the artifact frame, three arrays (m, 3, lines, points) flattened.

    ``disp`` (m, 3, 3): each scan's displacement from its nominal position [mm]
    (:func:`displacements`).
    """
    ex, _, q, c0 = frames(setup, truth)
    m = disp.shape[0]
    ex = ex[:, None, None, None, :] if ex.ndim == 2 else ex
    base = _base(setup, disp, q, c0)
    u = grid_u(setup)
    return tuple((base[..., k : k + 1] + u * ex[..., k]).reshape(m, -1) for k in range(3))


NOMINAL: dict = {}
#: error-free traces kept (about 2 MB each at the default scan)
_CACHED = 48


#: grid [mrad, mm] of the batched truths whose error-free traces are cached (:func:`_row`),
#: so that half a step moves a hit by about a micrometre at most: coarse for the tilts of
#: the measuring direction (0.25 mrad over the 4 mm range), finer for the rotations about
#: Z (0.05 mrad over the line's 8 mm and the scans' 20 mm reach) and the lattice offset
#: (1:1); the plate's tilts, which the walkers hardly move, on the default truth's grid
_KEY_GRID = {"alpha_z_mrad": 0.1, "alpha_y_mrad": 0.5, "alpha_x_mrad": 0.5,
             "artifact_x_mm": 0.002, "artifact_y_mm": 0.002, "artifact_rz_mrad": 0.1,
             "artifact_tilt_x_mrad": 0.1, "artifact_tilt_y_mrad": 0.1}


def _row(truth, i: int, *, own: bool = False):
    """A scalar Truth near row i of a batched one (or near a scalar one): its values rounded
    to :data:`_KEY_GRID`, so that nearby truths (a posterior's walkers, a fit's iterates, a
    Jacobian's steps) share the cached error-free trace; which rays stay on their plane is
    checked ray by ray (:func:`trace`), so the rounding costs no accuracy. A scalar truth
    on that grid, or any with `own`, is returned itself (:func:`trace` asks for its own
    trace where facet errors are NaN: which facet a ray at a kink belongs to, the one whose
    NaN error makes it NaN as the error budget's probes ask, is then the truth's own)."""
    import dataclasses

    if own and not _batched(truth):
        return truth
    values = {}
    for f in dataclasses.fields(truth):
        g = _KEY_GRID.get(f.name, 0.01)
        values[f.name] = float(f"{round(float(np.ravel(getattr(truth, f.name))[i]) / g) * g:.10g}")
    if not _batched(truth) and all(values[k] == getattr(truth, k) for k in values):
        return truth
    return Truth(**values)


def nominal_trace(setup, truth):
    """Error-free trace, cached: hit parameter, plane of the hit and its edge margin."""
    key = (setup, truth)
    if key not in NOMINAL:
        _, d, _, _ = frames(setup, truth)
        ox, oy, oz = (a[0] for a in origins(setup, truth, np.zeros((1, 3, 3))))
        t = -oz / d[2]  # hit of the land plane
        t = newton(setup, ox, oy, oz, d, t, np.arange(t.size))
        x, y = ox + t * d[0], oy + t * d[1]
        z, gx, gy, margin = height_map(setup, x, y, margin=True)
        while len(NOMINAL) >= _CACHED:  # the oldest out
            old = next(iter(NOMINAL))
            del NOMINAL[old]
            FACET_OF.pop(old, None)
            _PLANS.pop(old, None)
        NOMINAL[key] = (t, x, y, z, gx, gy, margin)
        FACET_OF[key] = facet_element(setup, x, y, z)
    return NOMINAL[key]


FACET_OF: dict = {}


def trace(setup, truth, disp, offsets=None):
    """Exact heights t [mm] of the rays, shape (m, 3, lines, points), for m error rows.

    ``disp`` (m, 3, 3): each scan's displacement of the sensor [mm]; ``offsets`` (m,
    facets): the facets' position errors [mm] (:func:`height_map`), None for none. The
    errors move the sensor and the facets by micrometres. A ray whose error-free hit
    lies farther from any kink than that move (bounded generously: twice the sum of the
    components' magnitudes, plus twice the largest facet error) stays on the same
    plane, and its hit is the exact ray-plane intersection (on a facet, the plane moved
    by its error: the height changes by ``-offset tan(facet)``); the others (near
    kinks) are solved by :func:`newton`.

    The ray-plane intersection ``t = (c + g . O) / (-g . d)`` (``g = (gx, gy, -1)`` the
    plane's slopes, ``O`` the ray's origin, ``c`` the plane's height at the artifact's
    origin) is assembled from small tables (:func:`_plan`): the origin is
    ``B[row, scan, line] + x_l e_x[row]``, so ``g . O`` is a table over (row, scan, line,
    plane) plus one over (row, point, plane), the denominator one over (row, plane), and
    each ray looks its entries up. The rays near a kink are found among the prefix of the
    rays sorted by margin that a bound of the move allows (:func:`_move_bound`).
    """
    ex, d, q, c0 = frames(setup, truth)
    m = disp.shape[0]
    # the planes of a nearby truth's error-free hits, checked ray by ray
    key = _row(truth, 0, own=offsets is not None and bool(np.isnan(offsets).any()))
    moved_truth = key is not truth
    _, x0, y0, _, _, _, margin = nominal_trace(setup, key)
    plan = _plan(setup, key)
    pts = setup.points_per_line
    g = np.column_stack([plan["grads"], -np.ones(len(plan["grads"]))])  # (P, 3)
    base = _base(setup, disp, q, c0)  # (m, 3, lines, 3)
    exr, dr = np.atleast_2d(ex), np.atleast_2d(d)  # (1 or m, 3)
    tab_v = (grid_u(setup)[None, :, None] * (exr @ g.T)[:, None, :]).reshape(len(exr), -1)
    den = -(dr @ g.T)  # (1 or m, P)
    t = np.take((base @ g.T).reshape(m, -1), plan["i_t"], axis=1)
    t += np.take(tab_v, plan["i_v"], axis=1)
    t += plan["c"]
    extra = np.zeros(m)
    if offsets is not None and np.any(offsets != 0):
        offsets = np.asarray(offsets, dtype=float).reshape(m, -1)
        elem = FACET_OF[(setup, key)]
        on = np.flatnonzero(elem >= 0)
        t[:, on] -= offsets[:, elem[on]] * math.tan(math.radians(setup.facet_angle_deg))
        extra = 2.0 * np.abs(offsets).max(axis=1)
    else:
        offsets = None
    t /= np.take(den, plan["cls"], axis=1)
    top = np.maximum(t.max(axis=1), -t.min(axis=1))  # |t| per row
    if moved_truth:  # on the same plane while the hit stays within its margin
        bound = _move_bound(setup, key, base, exr, dr, den, top, extra)
        rows, ray = _prefix_rays(plan, 2.0 * bound + extra + 1e-9)
        ox, oy, oz = _ray_origins(setup, base, exr, rows, ray)
        tt = t[rows, ray]
        dxy = dr[rows % len(dr)]
        moved = np.hypot(ox + tt * dxy[:, 0] - x0[ray], oy + tt * dxy[:, 1] - y0[ray])
        sel = np.flatnonzero(2.0 * moved + extra[rows] + 1e-9 >= margin[ray])
    else:
        move = 2.0 * np.abs(disp).sum(axis=2).max(axis=1) + 1e-9
        rows, ray = _prefix_rays(plan, move + extra)
        ox, oy, oz = _ray_origins(setup, base, exr, rows, ray)
        tt = t[rows, ray]
        sel = np.arange(rows.size)
    if sel.size:
        tn = newton(setup, ox[sel], oy[sel], oz[sel], d, tt[sel], np.arange(sel.size),
                     offsets=offsets, rows=rows[sel])
        t[rows[sel], ray[sel]] = tn
        top = max(float(top.max(initial=0.0)), float(np.abs(tn).max()))
    else:
        top = float(top.max(initial=0.0))
    if top > setup.range_mm / 2:
        raise InvalidInput([
            f"line_laser: the profiles leave the sensor's range (|z_l| up to "
            f"{top:.4g} mm > range_mm/2 = {setup.range_mm / 2:g} mm) with these "
            f"truth angles and artifact tilts; enlarge range_mm or lower raise_mm"
        ])
    return t.reshape(m, 3, setup.lines, pts)


_PLANS: dict = {}


def _plan(setup, key):
    """What :func:`trace` needs of the error-free trace of the truth `key`, cached.

    Every error-free hit lies on one of a few planes (land and floor, the six facet
    orientations): ``cls`` (rays,) names it in ``grads`` (P, 2), the planes' slopes;
    ``c`` (rays,) is ``z0 - gx0 x0 - gy0 y0``, the plane's height at the artifact's
    origin; ``i_t`` and ``i_v`` index the tables of :func:`trace`; ``order`` sorts the
    rays by their margin to a kink (``sorted_margin``), so the rays within a distance of
    a kink are a prefix of it; ``base``, ``ex``, ``d`` and ``top`` are the error-free
    origins, directions and largest ``|t|`` that :func:`_move_bound` compares with.
    """
    nominal = nominal_trace(setup, key)
    if _PLANS.get((setup, key), {}).get("nominal") is not nominal:
        t0, x0, y0, z0, gx0, gy0, margin = nominal
        # the planes' slopes (a few distinct pairs), without a sort of the pairs
        ux, ix = np.unique(gx0, return_inverse=True)
        uy, iy = np.unique(gy0, return_inverse=True)
        codes, cls = np.unique(ix.reshape(-1) * len(uy) + iy.reshape(-1), return_inverse=True)
        grads = np.stack([ux[codes // len(uy)], uy[codes % len(uy)]], axis=1)
        cls = np.asarray(cls).reshape(-1)
        pts, n_planes = setup.points_per_line, len(grads)
        ray = np.arange(t0.size)
        order = np.argsort(margin, kind="stable")
        ex, d, q, c0 = frames(setup, key)
        _PLANS[(setup, key)] = {
            "nominal": nominal, "cls": cls, "grads": grads, "c": z0 - gx0 * x0 - gy0 * y0,
            "i_t": (ray // pts) * n_planes + cls, "i_v": (ray % pts) * n_planes + cls,
            "order": order, "sorted_margin": margin[order],
            "base": _base(setup, np.zeros((1, 3, 3)), q, c0)[0], "ex": ex, "d": d,
            "top": float(np.abs(t0).max()),
            "tan": float(np.abs(grads).max(initial=0.0)),
        }
    return _PLANS[(setup, key)]


def _prefix_rays(plan, thr):
    """(row, ray) of every ray whose margin is at most ``thr`` (m,) of its row (none where
    ``thr`` is NaN: a row of NaN errors, whose rays are not solved again)."""
    k = np.searchsorted(plan["sorted_margin"], np.where(np.isnan(thr), -np.inf, thr),
                        side="right")
    rows = np.repeat(np.arange(k.size), k)
    pos = np.arange(int(k.sum())) - np.repeat(np.cumsum(k) - k, k)
    return rows, plan["order"][pos]


def _ray_origins(setup, base, exr, rows, ray):
    """Origins (ox, oy, oz) of the rays ``ray`` of batch rows ``rows`` (:func:`_base`)."""
    pts, lines = setup.points_per_line, setup.lines
    u = grid_u(setup)[ray % pts]
    b = base[rows, ray // (pts * lines), (ray // pts) % lines]
    e = exr[rows % len(exr)]
    return tuple(b[:, k] + u * e[:, k] for k in range(3))


def _move_bound(setup, key, base, exr, dr, den, top, extra):
    """Per row, a bound (m,) of how far any ray's hit moves in the plate's plane from the
    error-free hit of the truth `key` (:func:`_plan`): the origin's move, ``|t|`` times the
    direction's change, and ``|t - t0|`` times the error-free direction's slope, with
    ``t - t0 = (g . dO - t0 (den - den0)) / den`` bounded plane by plane's largest slope."""
    plan = _plan(setup, key)
    dxy0 = abs(plan["d"][0]) + abs(plan["d"][1])
    half = setup.line_width_mm / 2
    d_base = np.abs(base - plan["base"]).max(axis=(1, 2))  # (m, 3)
    d_o = d_base + half * np.abs(exr - plan["ex"])  # (m, 3): the origins' move
    d_d = np.abs(dr - plan["d"])  # (1 or m, 3)
    tan = plan["tan"]
    d_den = d_d[:, 2] + tan * (d_d[:, 0] + d_d[:, 1])
    d_t = (tan * (d_o[:, 0] + d_o[:, 1]) + d_o[:, 2] + plan["top"] * d_den
           + 0.5 * extra * tan) / den.min(axis=1)
    return d_o[:, 0] + d_o[:, 1] + top * (d_d[:, 0] + d_d[:, 1]) + d_t * dxy0


def forward(setup, truth, errors) -> Readings:
    """Simulated profiles: ``{"z_mm": array (n, 3, lines, points_per_line)}``.

    The reported height is ``(1 + z_scale) t + e(x_l) + noise``: ``t`` the exact ray
    parameter of the displaced sensor (:func:`displacements`, :func:`trace`), ``e``
    the linearity curve along the line (:func:`linearity_basis`), the same in the
    three scans.

    Parameters
    ----------
    setup : Setup
    truth : Truth
    errors : dict
        ``sensor_noise`` (n, 3, lines, points) [mm], ``shift_error`` (n,) [mm],
        ``raise_error`` (n,) [mm], ``trigger_y`` (n, 3) [mm], ``linearity`` (n, 3) [mm],
        ``z_scale`` (n,) [1], ``squareness_xy`` and ``squareness_zy`` (n,) [rad],
        ``drift`` (n, 3) [mm/s], ``facet_position`` (n, facets) [mm].
    """
    disp = displacements(setup, errors)
    n = disp.shape[0]
    facets = np.asarray(errors["facet_position"], dtype=float).reshape(n, -1)
    if np.all(disp == disp[:1]) and np.all(facets == facets[:1]) and not _batched(truth):
        # identical trials: trace once
        t = np.broadcast_to(trace(setup, truth, disp[:1], facets[:1]),
                            (n, 3, setup.lines, setup.points_per_line))
    else:
        t = trace(setup, truth, disp, facets)  # a new array: the errors are added in place
    scale = np.asarray(errors["z_scale"], dtype=float).reshape(n)
    coef = np.asarray(errors["linearity"], dtype=float).reshape(n, -1)
    noise = np.asarray(errors["sensor_noise"], dtype=float)
    z = t if t.flags.writeable else np.array(t)
    if not _all_zero(scale):
        z *= (1.0 + scale)[:, None, None, None]
    if not _all_zero(coef):
        z += (coef @ linearity_basis(setup))[:, None, None, :]
    if not _all_zero(noise):
        z += noise
    return Readings({"z_mm": z})


def _all_zero(a: np.ndarray) -> bool:
    """Whether `a` is all zero, reading each broadcast (zero-stride) axis once."""
    return not np.any(a[tuple(slice(None) if st else slice(0, 1) for st in a.strides)])


def true_values(setup, truth) -> dict:
    return {
        "alpha_z": truth.alpha_z_mrad * 1e-3,
        "alpha_y": truth.alpha_y_mrad * 1e-3,
        "alpha_x": truth.alpha_x_mrad * 1e-3,
    }


def truth_from_estimate(setup, estimate) -> Truth:
    """The default Truth with the estimated angles [rad] put in."""
    return Truth().replace(
        **{f"{k}_mrad": float(np.clip(np.asarray(estimate[k]).ravel()[0] * 1e3, -10, 10))
           for k in ("alpha_z", "alpha_y", "alpha_x")})



# --------------------------------------------------------------------------- time, frames
def duration(setup) -> float:
    """Machine time of the three scans [s]: scans at the feed the frame rate allows,
    the moves between them at rapid feed, a dwell before each scan."""
    return float(scan_times(setup)[-1])

