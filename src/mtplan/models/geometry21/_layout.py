"""geometry21's measuring layout: where each reading is taken (plates, heads, line and
circle passes, their timing) and how a head position maps to a plate's reading.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mtplan._cache import array_cache
from mtplan.models.geometry21._setup import (
    AXIS,
    GRID_POWERS,
    KIND,
    NAMES,
    PLANES,
    PLATE_RADIUS_MM,
    Setup,
    extra_heads,
    function_powers,
    sizeless,
)
from mtplan.models.kinematics import chain, polyval, rotate_inverse


# --------------------------------------------------------------------------- geometry
@dataclass(frozen=True)
class Geometry:
    plane: np.ndarray      # (M,) plane index
    head: np.ndarray       # (M,) head index within its plane (0: the first head)
    xhead: np.ndarray      # (M,) global index of an extra head, -1 for the first head
    test: np.ndarray       # (M,) 0 line along a, 1 line along b, 2 circle
    pass_: np.ndarray      # (M,)
    point: np.ndarray      # (M,)
    cmd: np.ndarray        # (M, 3) commanded x, y, z [mm]
    local: np.ndarray      # (M, 2) nominal in-plane position relative to the centre [mm]
    hvec: np.ndarray       # (M, 3) head offset of each reading [mm]
    time_s: np.ndarray     # (M,) time of each reading from the test's start [s]
    basis: np.ndarray      # (3, 3, 3) plate axes (columns u, v, n) per plane
    centre: np.ndarray     # (3, 3) commanded centre of each plane's tests, first head [mm]
    origin: np.ndarray     # (3, 3) the plates' nominal origins (centre + first head) [mm]
    ref: np.ndarray        # (3,) functional point
    pattern: np.ndarray    # (15, M, 3) plate-frame effect of the drift/reversal/servo features
    powers: np.ndarray     # (3, poly_order + 1, M) powers of each axis's commanded position
    distinct: tuple        # per axis: (index (M,) into its distinct positions, their powers)
    layout: dict           # function -> (powers, slice into coefficients)
    n_coef: int
    n_extra: int           # extra head positions, all planes
    xslices: tuple         # (plane, slice of its readings) of each extra head position
    n_par: int             # coefficients + 3 per plane + 2 per extra head
    u_end: float
    duration_s: float
    # the readings' distinct points (plane, commanded position, head offset) as a geometry
    # of their own (its per-reading arrays only), and the point of every reading: the rigid-
    # body chain is evaluated once per point and spread (repeated passes, forward and back)
    points: tuple | None = None


def _plane_centre(setup, k):
    c = np.zeros(3)
    c[PLANES[k][3]] = (setup.xy_plane_z_mm, setup.xz_plane_y_mm, setup.yz_plane_x_mm)[k]
    return c


def _passes(setup):
    """The passes of one plane's program: (test, pass, local a, local b, path length to
    each point [mm], pass length [mm], velocity sign (a, b) per point, circle angle, sense)."""
    half = setup.line_length_mm / 2
    u = np.linspace(-half, half, setup.line_points)
    R = setup.circle_radius_mm
    arc = math.radians(setup.circle_arc_deg)
    full = setup.circle_arc_deg >= 360.0
    th = np.linspace(0.0, arc, setup.circle_points, endpoint=not full)
    out = []
    for t in (0, 1):
        for rep in range(setup.line_repeats):
            for d, uu in enumerate((u, u[::-1])):
                z = np.zeros(uu.size)
                sign = np.full(uu.size, 1.0 if d == 0 else -1.0)
                vel = (sign, z) if t == 0 else (z, sign)
                out.append((t, 2 * rep + d, uu if t == 0 else z, uu if t == 1 else z,
                            np.abs(uu - uu[0]), setup.line_length_mm, vel, z, 0.0))
    for d, s in enumerate((1.0, -1.0)):  # CCW, then CW back along the same arc (the patent)
        phi = th if s > 0 else arc - th
        va, vb = -s * np.sin(phi), s * np.cos(phi)
        vel = tuple(np.where(np.abs(v) > 1e-12, np.sign(v), 0.0) for v in (va, vb))
        out.append((2, d, R * np.cos(phi), R * np.sin(phi), R + R * th, 2 * R + R * arc, vel,
                    phi, s))
    return out


@array_cache(maxsize=16)
def geometry(setup: Setup) -> Geometry:
    if (key := sizeless(setup)) != setup:  # one geometry for every size of the sources
        return geometry(key)
    heads = extra_heads(setup)
    passes = _passes(setup)
    v = setup.feed_mm_min / 60.0  # [mm/s]
    cols = {k: [] for k in ("plane", "head", "xhead", "test", "pass", "point", "la", "lb", "time",
                            "va", "vb", "phi", "sense", "h")}
    clock, xh = 0.0, 0
    for k in range(3):
        clock += setup.setup_change_s
        for j, h in enumerate(heads[k]):
            if j:
                clock += setup.head_change_s
            for test, pss, la, lb, dist, length, vel, phi, sense in passes:
                if j and test == 2 and setup.extra_head_tests == "lines":
                    continue
                n = la.size
                for key, val in (("plane", k), ("head", j), ("xhead", xh if j else -1),
                                 ("test", test), ("pass", pss), ("sense", sense)):
                    cols[key].append(np.full(n, val))
                cols["point"].append(np.arange(n))
                cols["la"].append(la)
                cols["lb"].append(lb)
                cols["time"].append(clock + dist / v)
                cols["va"].append(vel[0])
                cols["vb"].append(vel[1])
                cols["phi"].append(phi)
                cols["h"].append(np.broadcast_to(h, (n, 3)))
                clock += length / v
            xh += 1 if j else 0
    c = {key: np.concatenate(val) for key, val in cols.items()}
    plane = c["plane"].astype(int)
    local = np.column_stack([c["la"], c["lb"]])
    cmd = np.zeros((plane.size, 3))
    vdir = np.zeros((plane.size, 3))
    hvec = np.asarray(c["h"], dtype=float)
    basis = np.zeros((3, 3, 3))
    centre = np.stack([_plane_centre(setup, k) for k in range(3)])
    for k, (_, a, b, _c) in enumerate(PLANES):
        sel = plane == k
        # the head follows the plate's path: the machine moves by the head's change of offset
        cmd[sel] = centre[k] + heads[k][0] - hvec[sel]
        cmd[sel, a] += local[sel, 0]
        cmd[sel, b] += local[sel, 1]
        vdir[sel, a] = c["va"][sel]
        vdir[sel, b] = c["vb"][sel]
        ea, eb = np.eye(3)[a], np.eye(3)[b]
        basis[k] = np.column_stack([ea, eb, np.cross(ea, eb)])
    layout, pos = {}, 0
    for name in NAMES:
        pw = function_powers(name, setup.poly_order)
        layout[name] = (pw, slice(pos, pos + len(pw)))
        pos += len(pw)
    n_extra = int(c["xhead"].max()) + 1 if c["xhead"].size else 0
    xslices = []
    for e in range(n_extra):
        idx = np.flatnonzero(c["xhead"] == e)
        xslices.append((int(plane[idx[0]]), slice(int(idx[0]), int(idx[-1]) + 1)))
    geo = dict(plane=plane, head=c["head"].astype(int), xhead=c["xhead"].astype(int),
               test=c["test"].astype(int), pass_=c["pass"].astype(int),
               point=c["point"].astype(int), cmd=cmd, local=local, hvec=hvec,
               time_s=c["time"], basis=basis, centre=centre,
               origin=centre + np.stack([h[0] for h in heads]),
               ref=np.array([0.0, 0.0, -setup.reference_tool_mm]), layout=layout, n_coef=pos,
               n_extra=n_extra, xslices=tuple(xslices), n_par=pos + 9 + 2 * n_extra, u_end=setup.line_length_mm / 2,
               duration_s=float(clock))
    pat = _feature_patterns(setup, plane, cmd, local, vdir, c["time"], c["phi"], c["sense"],
                            c["test"])
    geo["pattern"] = _to_plate_frame(plane, basis, pat)
    geo["powers"] = cmd.T[:, None, :] ** np.arange(setup.poly_order + 1)[None, :, None]
    geo["distinct"] = tuple((inv, u[None, :] ** np.arange(setup.poly_order + 1)[:, None])
                            for u, inv in (np.unique(x, return_inverse=True) for x in cmd.T))
    geo["points"] = _points(geo)
    return Geometry(**geo)


def _points(geo: dict) -> tuple:
    """(geometry of the distinct points, index (M,) of each reading's point).

    A reading's position in its plate's nominal frame (:func:`truth_positions`) depends on
    its plane, commanded position and head offset only; the line passes repeat their points
    (``line_repeats``, forward and back), so about a quarter of the readings are distinct.
    The points keep the planes' order (plane first), so each plane's are contiguous, as
    :func:`_local3` needs; only the per-reading arrays are taken (no extra-head slices).
    """
    key = np.column_stack([geo["plane"], geo["cmd"], geo["hvec"]])
    _, rep, spread = np.unique(key, axis=0, return_index=True, return_inverse=True)
    sub = {k: v for k, v in geo.items() if k != "points"}
    for k in ("plane", "head", "xhead", "test", "pass_", "point", "cmd", "local", "hvec",
              "time_s"):
        sub[k] = geo[k][rep]
    sub["pattern"] = geo["pattern"][:, rep]
    sub["powers"] = geo["powers"][..., rep]
    sub["distinct"] = tuple((inv[rep], at) for inv, at in geo["distinct"])
    sub["xslices"], sub["n_extra"] = (), 0
    return Geometry(**sub), np.asarray(spread).reshape(-1)


def _feature_patterns(setup, plane, cmd, local, vdir, time_s, phi, sense, test):
    """Machine-frame displacement of each reading per unit of the 15 drift/reversal/servo
    features (g_x, g_y, g_z [1/h], d_x, d_y, d_z [mm/h], B_x, B_y, B_z [mm],
    T_x, T_y, T_z [s], T_x^2, T_y^2, T_z^2 [s^2]), shape (15, M, 3).

    Thermal growth of axis U: ``g_U (t / 1 h) u_U`` along U; drift: ``d (t / 1 h)``;
    reversal (lost motion) of axis U: ``-B_U / 2 * sign(velocity_U)`` (an axis at rest
    or at a turning point of a circle: 0, the mean of its two states); servo contouring
    error of a circle in the plane of axes (a, b), radial, from first-order position loops
    with following times T (steady state, to second order in omega T, omega = s v / R,
    s = +1 counter-clockwise):
    ``dR = -v^2 / (2 R) (T_a^2 cos^2 phi + T_b^2 sin^2 phi) - s v / 2 (T_b - T_a) sin 2 phi``:
    a radius reduction growing with v^2 / R and the 45-deg ellipse of a gain mismatch
    growing with v. Lines (one axis at constant speed) have no contouring error.
    """
    m = plane.size
    pat = np.zeros((15, m, 3))
    hours = time_s / 3600.0
    eye = np.eye(3)
    for u in range(3):
        pat[u] = (hours * cmd[:, u])[:, None] * eye[u]
        pat[3 + u] = hours[:, None] * eye[u]
        pat[6 + u] = (-0.5 * vdir[:, u])[:, None] * eye[u]
    v = setup.feed_mm_min / 60.0
    R = setup.circle_radius_mm
    circ = test == 2
    for k, (_, a, b, _c) in enumerate(PLANES):
        sel = circ & (plane == k)
        p, s = phi[sel], sense[sel]
        er = np.cos(p)[:, None] * eye[a] + np.sin(p)[:, None] * eye[b]  # radial, machine frame
        quad = -v * v / (2 * R)
        pat[12 + a][sel] += (quad * np.cos(p) ** 2)[:, None] * er
        pat[12 + b][sel] += (quad * np.sin(p) ** 2)[:, None] * er
        pat[9 + a][sel] += (s * v / 2 * np.sin(2 * p))[:, None] * er
        pat[9 + b][sel] += (-s * v / 2 * np.sin(2 * p))[:, None] * er
    return pat


def _to_plate_frame(plane, basis, vec):
    """Machine-frame vectors (..., M, 3) in the plate coordinates of each reading's plane."""
    out = np.empty_like(vec)
    for k in range(3):
        sel = plane == k
        out[..., sel, :] = vec[..., sel, :] @ basis[k]
    return out


def _values(geo: Geometry, coefs: dict, trig: dict | None = None) -> dict:
    """Function values at the points: name -> (n, M) ((n, 1) for squareness); into `trig`
    the angular ones' (cos, sin): each at its axis's distinct positions, then spread."""
    out = {}
    for name in NAMES:
        powers, coef = coefs[name]
        if KIND[name] == "sq":
            out[name] = coef[:, :1] * np.ones((1, 1))
        elif powers and max(powers) < geo.powers.shape[1]:
            inv, at = geo.distinct[AXIS[name]]
            vals = coef @ at[list(powers)]
            out[name] = vals[:, inv]
            if trig is not None and KIND[name] == "ang" and np.any(vals):
                trig[name] = (np.cos(vals)[:, inv], np.sin(vals)[:, inv])
        else:
            out[name] = polyval(coef, powers, geo.cmd[:, AXIS[name]])
    return out


def plane_slices(geo: Geometry) -> list[slice]:
    bounds = [0, *np.searchsorted(geo.plane, [1, 2]).tolist(), geo.plane.size]
    return [slice(bounds[k], bounds[k + 1]) for k in range(3)]


def _local3(geo: Geometry, p: np.ndarray) -> np.ndarray:
    """Head positions (n, M, 3) [machine frame] in each plate's nominal frame (n, M, 3)."""
    out = np.empty(p.shape)
    for k, sl in enumerate(plane_slices(geo)):  # the planes' readings are contiguous
        np.matmul(p[..., sl, :] - geo.origin[k], geo.basis[k], out=out[..., sl, :])
    return out


def _rotation_rows(rot: np.ndarray) -> np.ndarray:
    """First two rows of ``Rinv = (Rx(a) Ry(b) Rz(c))^-1`` per trial: (n, 2, 3) for rot (n, 3)."""
    cols = rotate_inverse(rot[:, None, 0], rot[:, None, 1], rot[:, None, 2], np.eye(3)[None])
    return np.swapaxes(cols, 1, 2)[:, :2, :]


def mount(geo: Geometry, loc: np.ndarray, offset: np.ndarray, head: np.ndarray,
           rot: np.ndarray) -> np.ndarray:
    """Plate readings from plate-frame positions, exactly: ``Rinv(rot) (loc - (shift, 0))``
    with the shift the plate's offset less an extra head's setting error, (n, M, 2).

    Parameters
    ----------
    loc : array (n or 1, M, 3)
        Head position in the plate's nominal frame [mm].
    offset : array (n, 3, 2)
        In-plane offset of each plate [mm].
    head : array (n, n_extra, 2)
        In-plane setting error of each extra head position [mm].
    rot : array (n, 3, 3)
        Rotation of each plate [rad]: tilt about its u axis, tilt about its v axis,
        rotation about its normal (applied as Rx Ry Rz in plate coordinates).
    """
    n = max(loc.shape[0], rot.shape[0])
    if not np.any(rot):  # Rinv's rows are exactly (1, 0, 0), (0, 1, 0): the shifts alone
        out = np.array(np.broadcast_to(loc[:, :, :2], (n, loc.shape[1], 2)))
        for k, sl in enumerate(plane_slices(geo)):
            out[:, sl, :] -= offset[:, None, k, :]
        for e, (_k, sl) in enumerate(geo.xslices):
            out[:, sl, :] += head[:, None, e, :]
        return out
    out = np.empty((n, loc.shape[1], 2))
    rows = []
    for k, sl in enumerate(plane_slices(geo)):
        m = _rotation_rows(rot[:, k])  # (n, 2, 3)
        rows.append(m)
        np.matmul(loc[:, sl, :], np.swapaxes(m, 1, 2), out=out[:, sl, :])
        out[:, sl, :] -= (m[:, :, :2] @ offset[:, k, :, None])[:, None, :, 0]
    for e, (k, sl) in enumerate(geo.xslices):
        out[:, sl, :] += (rows[k][:, :, :2] @ head[:, e, :, None])[:, None, :, 0]
    return out


def grid_basis(geo: Geometry) -> np.ndarray:
    """Basis of the plates' grid-error field at the nominal readings, shape (M, K)."""
    u, v = geo.local[:, 0] / PLATE_RADIUS_MM, geo.local[:, 1] / PLATE_RADIUS_MM
    return np.column_stack([u**i * v**j for i, j in GRID_POWERS])


def truth_positions(geo: Geometry, coefs: dict) -> np.ndarray:
    """Head positions (n, M, 3) in the plates' frames for coefficients (n, L) per function,
    exact: the chain evaluated once per distinct point (:func:`_points`), the same numbers
    spread to every reading."""
    sub, spread = geo.points
    trig: dict = {}
    p = chain(_values(sub, coefs, trig), *sub.cmd.T, sub.hvec, sub.ref, trig)
    return np.take(_local3(sub, p), spread, axis=1)
