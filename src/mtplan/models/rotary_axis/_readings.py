"""rotary_axis's readings as a table: the CSV format of measured data, and the set-up a
measured table determines."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from mtplan._validate import InvalidInput, Problems
from mtplan.models.protocol import Readings, frame_columns
from mtplan.models.rotary_axis._estimators import check_readings
from mtplan.models.rotary_axis._layout import plan, position_axes
from mtplan.models.rotary_axis._physics import forward, zero_errors
from mtplan.models.rotary_axis._setup import NAME, Setup, Truth, axis_grid

_COLUMNS = ("position", "angle_deg", "point", "x_mm", "y_mm", "z_mm")


def readings_frame(setup: Setup, readings: dict) -> pd.DataFrame:
    """The first trial's readings as a tidy table, one reading per row in measuring order.

    Columns: ``axis`` (the axis turned: C or A; both in a CA test), ``position``
    (0-based over the whole test), ``angle_deg`` (commanded angle of that axis),
    ``point`` (0-based, in measuring order; with sensor_reversal the pass at 180 deg goes
    on from the lattice's point count, over the same points in the same order), ``x_mm``,
    ``y_mm`` (commanded lattice point), ``z_mm`` (Z position + sensor value). (The
    schedule has the sensor's orientation as ``sensor_deg``.)
    """
    z = check_readings(setup, readings, passes=True)[0]
    g = plan(setup)
    P, M = z.shape
    return pd.DataFrame({
        "axis": np.repeat(position_axes(setup), M),
        "position": np.repeat(np.arange(P), M),
        "angle_deg": np.repeat(setup.angles(), M),
        "point": np.tile(np.arange(M), P),
        "x_mm": g.xy[..., 0].ravel(),
        "y_mm": g.xy[..., 1].ravel(),
        "z_mm": z.ravel(),
    })


def from_frame(setup: Setup, df: pd.DataFrame) -> Readings:
    """Readings (a batch of one) from a table in the format of :func:`readings_frame`.

    Rows may come in any order. The positions, angles and lattice points must be the
    set-up's (x, y within 1 um, angles within 1e-6 deg), and so must the ``axis``
    column where the table has one.

    Raises
    ------
    InvalidInput
        Naming the missing column, the row with a missing or non-numeric value, a
        duplicate or missing reading, or a point that is not the set-up's.
    """
    data = frame_columns(df, _COLUMNS, f"{NAME} readings")
    p = Problems(f"{NAME} readings")
    P, M = setup.n_positions, setup.n_readings
    if len(df) != P * M:
        p.add_text(f"The {NAME} readings must have {P * M} rows ({P} positions x {M} readings"
                   f"{' over two sensor orientations' if setup.sensor_reversal else ''}) for "
                   f"this set-up; got {len(df)}")
        p.raise_if_any()
    pos, pt = data["position"], data["point"]
    for col, v, top in (("position", pos, P), ("point", pt, M)):
        bad = np.flatnonzero((v != np.round(v)) | (v < 0) | (v >= top))
        if bad.size:
            p.add_text(f"The column {col!r} of the {NAME} readings must hold ints 0..{top - 1}; "
                       f"row {int(bad[0])} holds {v[bad[0]]!r}")
    p.raise_if_any()
    flat = pos.astype(int) * M + pt.astype(int)
    counts = np.bincount(flat, minlength=P * M)
    if np.any(counts != 1):
        k = int(np.flatnonzero(counts != 1)[0])
        what = "is missing" if counts[k] == 0 else f"appears {counts[k]} times"
        p.add_text(f"The {NAME} reading of position {k // M}, point {k % M} {what}")
        p.raise_if_any()
    order = np.argsort(flat, kind="stable")
    g = plan(setup)
    checks = (("angle_deg", np.repeat(setup.angles(), M), 1e-6),
              ("x_mm", g.xy[..., 0].ravel(), 1e-3), ("y_mm", g.xy[..., 1].ravel(), 1e-3))
    for col, expected, tol in checks:
        got = data[col][order]
        bad = np.flatnonzero(~(np.abs(got - expected) <= tol))
        if bad.size:
            row = int(order[bad[0]])
            p.add_text(f"The column {col!r} of the {NAME} readings must match the set-up "
                       f"(within {tol:g}); row {row} holds {got[bad[0]]!r} where the set-up "
                       f"has {expected[bad[0]]!r}")
    if "axis" in df.columns:
        got = df["axis"].astype(str).str.strip().str.upper().to_numpy()[order]
        expected = np.repeat(position_axes(setup), M)
        bad = np.flatnonzero(got != expected)
        if bad.size:
            row = int(order[bad[0]])
            p.add_text(f"The column 'axis' of the {NAME} readings must match the set-up "
                       f"(axis={setup.axis!r}); row {row} holds {got[bad[0]]!r} where the "
                       f"set-up turns {expected[bad[0]]!r}")
    p.raise_if_any()
    return Readings({"z_mm": data["z_mm"][order].reshape(1, P, M)})


def reading_limits(setup: Setup) -> dict:
    """The distance sensor's measuring range around the nominal surface at each point [mm]."""
    nominal = readings_frame(setup, forward(setup, Truth(), zero_errors(setup, 1)))
    half = setup.sensor_range_mm / 2
    return {"z_mm": (nominal["z_mm"].to_numpy() - half, nominal["z_mm"].to_numpy() + half,
                     f"the sensor's measuring range (sensor_range_mm = {setup.sensor_range_mm:g} "
                     "about the nominal surface)")}


# --------------------------------------------------------------------------- set-up from a file
_ANGLE_TOL_DEG = 1e-6  # as from_frame: commanded angles agree to 1e-6 deg
_LATTICE_TOL_MM = 1e-6


def _angle_fields(axis: str, angles: np.ndarray) -> dict:
    """positions, range_deg and a_order that give `angles` of `axis`, where some do."""
    from mtplan.models.protocol import Implied

    n = angles.size
    if axis == "C":
        candidates = [(360.0, "patent"), (float(angles[-1]), "patent")]
    else:
        candidates = [(float(angles.max() - angles.min()), o) for o in ("patent", "ascending")]
    for span, order in candidates:
        if not 0 < span <= 360 or n < 3:
            continue
        grid = axis_grid(axis, n, span, order)
        if grid.shape == angles.shape and np.allclose(grid, angles, rtol=0, atol=_ANGLE_TOL_DEG):
            out = {"range_deg": Implied(span, _ANGLE_TOL_DEG, why=f"the file's {n} {axis} angles")}
            if axis == "A":
                out["a_order"] = Implied(order, why="the order of the file's A angles")
            return out
    return {"range_deg": Implied(None, why=f"the file's {axis} angles are not an evenly "
                                 "spaced range: they are angles_deg")}


def _lattice_fields(x: np.ndarray, y: np.ndarray, axis: str, angle_deg: float) -> dict:
    """Lattice counts, side and offset from the commanded points of one position."""
    from mtplan.models.protocol import Implied

    xs = np.unique(np.round(x / _LATTICE_TOL_MM)) * _LATTICE_TOL_MM
    ys = np.unique(np.round(y / _LATTICE_TOL_MM)) * _LATTICE_TOL_MM
    nx, ny = xs.size, ys.size
    if nx < 2 or ny < 2 or nx * ny != x.size:
        return {}
    why = "the commanded points of the file's first position"
    out = {"lattice_nx": Implied(nx, why=why), "lattice_ny": Implied(ny, why=why)}
    size = float(xs[-1] - xs[0])
    if abs(size - float(ys[-1] - ys[0])) > 2 * _LATTICE_TOL_MM:
        return out  # not a square lattice: the design check names the rows
    out["lattice_size_mm"] = Implied(size, _LATTICE_TOL_MM, why=why)
    cx, cy = float(xs[0] + xs[-1]) / 2, float(ys[0] + ys[-1]) / 2
    t = math.radians(angle_deg)
    if axis == "C":  # the lattice turns with the table about Z
        ox, oy = math.cos(t) * cx + math.sin(t) * cy, -math.sin(t) * cx + math.cos(t) * cy
    elif abs(angle_deg) <= _ANGLE_TOL_DEG:  # A: X stays; Y only at the zero position
        ox, oy = cx, cy
    else:
        ox, oy = cx, None
    out["lattice_offset_x_mm"] = Implied(ox, _LATTICE_TOL_MM, why=why)
    if oy is not None:
        out["lattice_offset_y_mm"] = Implied(oy, _LATTICE_TOL_MM, why=why)
    return out


def setup_from_frame(df: pd.DataFrame) -> dict:
    """The set-up fields a measured readings table determines (see ``Implied``).

    The axis (the ``axis`` column: C, A, or both for CA); per axis part the commanded
    angles in measuring order (``angles_deg``, for CA ``c_angles_deg`` and the A part's
    ``angles_deg``), their number (``positions``) and, where they are an evenly spaced
    range, ``range_deg`` and ``a_order`` (so that stated ones are checked); the lattice
    (``lattice_nx``, ``lattice_ny``, ``lattice_size_mm`` and its offset at the zero
    position) from the commanded points of the first position (of the first position at
    A = 0 for the Y offset of an A test). Angles agree within 1e-6 deg, lattice
    coordinates within 1e-6 mm. Where the table is not regular enough to tell, the
    field is left out and the design check names the offending row.
    """
    from mtplan.models.protocol import Implied

    axes = df["axis"].astype(str).str.strip().str.upper().to_numpy()
    position = pd.to_numeric(df["position"], errors="coerce").to_numpy(dtype=float)
    angle = pd.to_numeric(df["angle_deg"], errors="coerce").to_numpy(dtype=float)
    kinds = set(axes)
    axis = {frozenset("C"): "C", frozenset("A"): "A", frozenset("CA"): "CA"}.get(frozenset(kinds))
    if axis is None or not np.all(np.isfinite(position)) or not np.all(np.isfinite(angle)):
        return {}
    out = {"axis": Implied(axis, why="the file's axis column")}
    order = np.unique(position)
    per_position = {}
    for p in order:
        rows = position == p
        if np.ptp(angle[rows]) > _ANGLE_TOL_DEG or len(set(axes[rows])) != 1:
            return out  # one position, one angle of one axis: else from_frame names it
        per_position[p] = (axes[rows][0], float(angle[rows][0]))
    parts = {a: np.array([ang for ax, ang in per_position.values() if ax == a])
             for a in ("C", "A")}
    main = "A" if axis == "CA" else axis
    angles = parts[main]
    if angles.size < 3:
        return out
    why = f"the file's {angles.size} {main} positions"
    out["angles_deg"] = Implied(tuple(float(a) for a in angles), _ANGLE_TOL_DEG, why=why)
    out["positions"] = Implied(int(angles.size), why=why)
    out.update(_angle_fields(main, angles))
    if axis == "CA":
        c = parts["C"]
        out["c_angles_deg"] = Implied(tuple(float(a) for a in c), _ANGLE_TOL_DEG,
                                      why=f"the file's {c.size} C positions")
    first_axis = "C" if axis == "CA" else axis
    lattice_at = next(p for p in order if per_position[p][0] == first_axis)
    if axis == "A":  # the Y offset shows only at A = 0
        lattice_at = next((p for p in order if abs(per_position[p][1]) <= _ANGLE_TOL_DEG),
                          lattice_at)
    rows = position == lattice_at
    x = pd.to_numeric(df["x_mm"], errors="coerce").to_numpy(dtype=float)[rows]
    y = pd.to_numeric(df["y_mm"], errors="coerce").to_numpy(dtype=float)[rows]
    point = pd.to_numeric(df["point"], errors="coerce").to_numpy(dtype=float)[rows]
    if np.all(np.isfinite(point)):  # a second pass over the same points: the sensor reversed
        order = np.argsort(point, kind="stable")
        x, y, h = x[order], y[order], x.size // 2
        twice = (x.size % 2 == 0 and h >= 4 and np.allclose(x[:h], x[h:], atol=_LATTICE_TOL_MM)
                 and np.allclose(y[:h], y[h:], atol=_LATTICE_TOL_MM))
        out["sensor_reversal"] = Implied(bool(twice), why="the file's points per position: "
                                         + ("each lattice point twice" if twice else "once"))
        if twice:
            x, y = x[:h], y[:h]
    if np.all(np.isfinite(x)) and np.all(np.isfinite(y)):
        out.update(_lattice_fields(x, y, first_axis, per_position[lattice_at][1]))
    return out
