"""geometry21's reading of a measured table's set-up (``ReadingsFormat.setup_from_frame``);
re-exported by :mod:`mtplan.models.geometry21`."""

from __future__ import annotations

import numpy as np
import pandas as pd

from mtplan.models.geometry21 import _TEST_NAMES, PLANES


def setup_from_frame(df: pd.DataFrame) -> dict:
    """The set-up fields a measured plate table determines (see ``Implied``).

    From the rows of the first head position (``head`` 0, or all rows of a table
    without that column) of the XY plane: the points per line pass and per circle pass,
    the line repeats (half the line passes), the line length (the span of the commanded
    X), the circle's radius and arc (its commanded points about the plane's centre: 360
    when they are evenly spaced over a full turn without the repeated end); from each
    plane's rows, the plane's position (Z of the XY rows, Y of the XZ rows, X of the YZ
    rows). Lengths agree within 1e-6 mm, the arc within 1e-6 deg. Where the table is
    not regular enough to tell, the field is left out and the design check names the
    offending row.
    """
    from mtplan.models.protocol import Implied

    tol = 1e-6
    plane = df["plane"].astype(str).str.strip().to_numpy()
    test = df["test"].astype(str).str.strip().to_numpy()
    pss = pd.to_numeric(df["pass"], errors="coerce").to_numpy(dtype=float)
    cmd = df[["x_mm", "y_mm", "z_mm"]].apply(pd.to_numeric, errors="coerce").to_numpy(float)
    keep = np.ones(len(df), dtype=bool)
    if "head" in df.columns:
        keep = pd.to_numeric(df["head"], errors="coerce").to_numpy(dtype=float) == 0
    if not (np.all(np.isfinite(pss)) and np.all(np.isfinite(cmd))):
        return {}
    out = {}
    for k, (name, a, b, c) in enumerate(PLANES):
        rows = keep & (plane == name)
        level = cmd[rows, c]
        if level.size and np.ptp(level) <= tol:
            field = ("xy_plane_z_mm", "xz_plane_y_mm", "yz_plane_x_mm")[k]
            out[field] = Implied(float(level[0]), tol, why=f"the {name} rows' {'XYZ'[c]}")
        if k:
            continue
        line = rows & (test == _TEST_NAMES[0])
        if np.any(line):
            n_pass = np.unique(pss[line]).size
            first = line & (pss == pss[line].min())
            out["line_points"] = Implied(int(first.sum()), why="the points of an XY line pass")
            if n_pass % 2 == 0:
                out["line_repeats"] = Implied(n_pass // 2, why="the XY line passes, there "
                                              "and back")
            out["line_length_mm"] = Implied(float(f"{np.ptp(cmd[first, a]):.12g}"), tol,
                                            why="the span of an XY line pass")
        circle = rows & (test == _TEST_NAMES[2])
        if np.any(circle):
            first = circle & (pss == pss[circle].min())
            n = int(first.sum())
            out["circle_points"] = Implied(n, why="the points of an XY circle pass")
            la, lb = cmd[first, a], cmd[first, b]
            radius = np.hypot(la, lb)
            if n >= 2 and np.ptp(radius) <= 2 * tol:
                out["circle_radius_mm"] = Implied(float(f"{radius.mean():.12g}"), tol,
                                                  why="the XY circle's commanded points")
                th = np.degrees(np.unwrap(np.arctan2(lb, la)))
                th = np.abs(th - th[0])
                full = np.allclose(th, 360.0 * np.arange(n) / n, rtol=0, atol=tol)
                out["circle_arc_deg"] = Implied(360.0 if full else float(f"{th[-1]:.12g}"),
                                                tol, why="the XY circle's commanded points")
    return out
