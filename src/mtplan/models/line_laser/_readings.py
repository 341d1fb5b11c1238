"""line_laser's readings I/O: the readings as a table of heights, the table read
back, the range a reading must lie in, and the set-up a measured table implies.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from mtplan._validate import Problems
from mtplan.models.line_laser._artifact import grid_u, grid_y
from mtplan.models.line_laser._setup import Setup
from mtplan.models.protocol import Readings, frame_columns

if TYPE_CHECKING:  # pandas only where a table is made or read: not in a Monte Carlo's workers
    import pandas as pd


_COLUMNS = ("scan", "line", "point", "x_mm", "y_mm", "z_mm")


def readings_frame(setup, readings) -> pd.DataFrame:
    """One measurement (the first trial) as a tidy table, one height per row.

    Columns: ``scan`` (1, 2, 3), ``line`` (0..lines-1), ``point``
    (0..points_per_line-1), ``x_mm`` (position along the laser line), ``y_mm``
    (nominal machine Y of the trigger), ``z_mm`` (reported height).
    """
    import pandas as pd

    z = np.asarray(readings["z_mm"], dtype=float)[0]
    k, j, i = np.meshgrid(np.arange(3), np.arange(setup.lines), np.arange(setup.points_per_line),
                          indexing="ij")
    return pd.DataFrame({
        "scan": k.ravel() + 1,
        "line": j.ravel(),
        "point": i.ravel(),
        "x_mm": grid_u(setup)[i.ravel()],
        "y_mm": grid_y(setup)[j.ravel()],
        "z_mm": z.ravel(),
    })


def from_frame(setup, df) -> Readings:
    """Readings (a batch of one) from a table in the format of :func:`readings_frame`.

    Raises
    ------
    InvalidInput
        Missing columns, non-numeric or missing values, indices out of range or
        repeated, or positions that do not match the set-up's line and step.
    """
    vals = frame_columns(df, _COLUMNS, "line_laser data")
    p = Problems("line_laser data")
    expected = 3 * setup.lines * setup.points_per_line
    if len(df) != expected:
        p.add_text(f"The line_laser data have {len(df)} rows; the set-up (3 scans x {setup.lines} "
                   f"lines x {setup.points_per_line} points) needs {expected}")
        p.raise_if_any()
    for c, hi in (("scan", 3), ("line", setup.lines - 1), ("point", setup.points_per_line - 1)):
        lo = 1 if c == "scan" else 0
        col = vals[c]
        bad = np.flatnonzero((col != np.round(col)) | (col < lo) | (col > hi))
        if bad.size:
            p.add_text(f"Column {c!r} of the line_laser data must hold whole numbers {lo}..{hi}; "
                       f"row {int(bad[0])} has {col[bad[0]]:g}")
    p.raise_if_any()
    k = vals["scan"].astype(int) - 1
    j = vals["line"].astype(int)
    i = vals["point"].astype(int)
    flat = (k * setup.lines + j) * setup.points_per_line + i
    counts = np.bincount(flat, minlength=expected)
    if np.any(counts != 1):
        first = int(np.flatnonzero(counts != 1)[0])
        kk, rest = divmod(first, setup.lines * setup.points_per_line)
        jj, ii = divmod(rest, setup.points_per_line)
        p.add_text(f"The line_laser data must hold each (scan, line, point) once; "
                   f"({kk + 1}, {jj}, {ii}) occurs {int(counts[first])} times")
        p.raise_if_any()
    for c, grid, idx in (("x_mm", grid_u(setup), i), ("y_mm", grid_y(setup), j)):
        dev = np.abs(vals[c] - grid[idx])
        bad = np.flatnonzero(dev > 1e-6 * (1 + np.abs(grid[idx])))
        if bad.size:
            p.add_text(f"Column {c!r} of the line_laser data does not match the set-up's grid "
                       f"(line_width_mm, points_per_line, step_mm, lines): row {int(bad[0])} "
                       f"has {vals[c][bad[0]]:g}, expected {grid[idx[bad[0]]]:g}")
    p.raise_if_any()
    z = np.empty(expected)
    z[flat] = vals["z_mm"]
    return Readings({"z_mm": z.reshape(1, 3, setup.lines, setup.points_per_line)})


def reading_limits(setup: Setup) -> dict:
    """Heights the sensor can report: its measuring range about the middle (z_l = 0) [mm]."""
    half = setup.range_mm / 2
    return {"z_mm": (-half, half, f"the sensor's measuring range (range_mm = {setup.range_mm:g})")}


def setup_from_frame(df: pd.DataFrame) -> dict:
    """The set-up fields a measured table of scans determines (see ``Implied``).

    The number of profiles per scan (``lines``, the distinct ``line`` indices) and of
    points per profile (``points_per_line``), the line's width (the span of ``x_mm``)
    and the scan step (the spacing of the trigger positions ``y_mm``, which must be even),
    each within 1e-6 mm. Where the table is not regular enough to tell, the field is left
    out and the design check names the offending row.
    """
    import pandas as pd

    from mtplan.models.protocol import Implied

    tol = 1e-6
    line = pd.to_numeric(df["line"], errors="coerce").to_numpy(dtype=float)
    point = pd.to_numeric(df["point"], errors="coerce").to_numpy(dtype=float)
    x = pd.to_numeric(df["x_mm"], errors="coerce").to_numpy(dtype=float)
    y = pd.to_numeric(df["y_mm"], errors="coerce").to_numpy(dtype=float)
    if not all(np.all(np.isfinite(a)) for a in (line, point, x, y)):
        return {}
    lines, points = np.unique(line).size, np.unique(point).size
    out = {"lines": Implied(lines, why=f"the file's {lines} profiles per scan"),
           "points_per_line": Implied(points, why=f"the file's {points} points per profile")}
    xs = np.unique(np.round(x / tol)) * tol
    if xs.size == points:
        out["line_width_mm"] = Implied(float(f"{xs[-1] - xs[0]:.12g}"), tol,
                                       why="the span of x_mm")
    ys = np.unique(np.round(y / tol)) * tol
    steps = np.diff(ys)
    if ys.size == lines and lines > 1 and np.ptp(steps) <= 2 * tol:
        step = float(f"{(ys[-1] - ys[0]) / (lines - 1):.12g}")  # as written, not as summed
        out["step_mm"] = Implied(step, tol, why="the spacing of y_mm")
    return out

