"""geometry21's readings I/O: one measurement as a table of plate readings, the table read
back, and the set-up a measured table implies (``ReadingsFormat.setup_from_frame``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.models.geometry21._layout import geometry
from mtplan.models.geometry21._setup import PLANES, TEST_NAMES, Setup
from mtplan.models.protocol import Readings

if TYPE_CHECKING:  # pandas only where a table is made or read: not in a Monte Carlo's workers
    import pandas as pd



def readings_frame(setup: Setup, readings: dict) -> pd.DataFrame:
    """One measurement (the first trial) as a tidy table, one reading point per row.

    Columns: ``plane`` (XY, XZ, YZ), ``head`` (0: the first head position, 1, 2, ...: the
    plane's extra head positions in the order of the set-up's list), ``test`` (line_a,
    line_b: along the plane's first or second axis; circle), ``pass`` (line: 2*repeat +
    direction; circle: 0 CCW, 1 CW), ``point``, the commanded ``x_mm``, ``y_mm``,
    ``z_mm``, and the plate readings ``u_mm``, ``v_mm`` (head position along the plate's
    first and second axis, relative to the plate's nominal origin). Tables without the
    ``head`` column (written before head positions existed) are read as all head 0.
    """
    import pandas as pd

    geo = geometry(setup)
    r = np.asarray(readings["plate_mm"])[0]
    return pd.DataFrame({
        "plane": np.array([p[0] for p in PLANES])[geo.plane],
        "head": geo.head,
        "test": np.array(TEST_NAMES)[geo.test],
        "pass": geo.pass_,
        "point": geo.point,
        "x_mm": geo.cmd[:, 0], "y_mm": geo.cmd[:, 1], "z_mm": geo.cmd[:, 2],
        "u_mm": r[:, 0], "v_mm": r[:, 1],
    })


def from_frame(setup: Setup, df: pd.DataFrame) -> Readings:
    """Readings (a batch of one) from a table in the format of :func:`readings_frame`."""
    import pandas as pd

    geo = geometry(setup)
    need = ["plane", "test", "pass", "point", "x_mm", "y_mm", "z_mm", "u_mm", "v_mm"]
    missing = [c for c in need if c not in df.columns]
    if missing:
        raise InvalidInput([f"The geometry21 readings table lacks the column(s) "
                            f"{', '.join(missing)}; it needs {', '.join(need)} (and head)."])
    if len(df) != geo.plane.size:
        raise InvalidInput([f"The geometry21 readings table must have {geo.plane.size} rows "
                            f"for this set-up. Got {len(df)} instead."])
    problems = []
    if "head" not in df.columns and geo.n_extra:
        problems.append("The geometry21 readings table needs a 'head' column: this set-up "
                        f"has {geo.n_extra} extra head position(s).")
    for col in need[4:]:
        vals = pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(vals))
        if bad.size:
            problems.append(f"The '{col}' column of the geometry21 readings must be finite "
                            f"numbers. Got {df[col].iloc[bad[0]]!r} in row {int(bad[0])} instead.")
    order = [("plane", np.array([p[0] for p in PLANES])[geo.plane]),
             ("test", np.array(TEST_NAMES)[geo.test])]
    if "head" in df.columns:
        order.append(("head", geo.head.astype(str)))
    for col, expect in order:
        got = df[col].astype(str).to_numpy()
        if col == "head":
            got = np.array([g[:-2] if g.endswith(".0") else g for g in got])
        bad = np.flatnonzero(got != expect)
        if bad.size:
            problems.append(f"The '{col}' column of the geometry21 readings must follow the "
                            f"set-up's order; row {int(bad[0])} has {df[col].iloc[bad[0]]!r}, "
                            f"expected {expect[bad[0]]!r}.")
    if problems:
        raise InvalidInput(problems)
    cmd = df[["x_mm", "y_mm", "z_mm"]].to_numpy(dtype=float)
    bad = np.flatnonzero(np.any(np.abs(cmd - geo.cmd) > 1e-6, axis=1))
    if bad.size:
        raise InvalidInput([f"The commanded positions of the geometry21 readings do not match "
                            f"the set-up; row {int(bad[0])} has {cmd[bad[0]].tolist()}, "
                            f"expected {geo.cmd[bad[0]].tolist()}."])
    r = df[["u_mm", "v_mm"]].to_numpy(dtype=float)
    return Readings({"plate_mm": r[None, :, :]})

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
    import pandas as pd

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
        line = rows & (test == TEST_NAMES[0])
        if np.any(line):
            n_pass = np.unique(pss[line]).size
            first = line & (pss == pss[line].min())
            out["line_points"] = Implied(int(first.sum()), why="the points of an XY line pass")
            if n_pass % 2 == 0:
                out["line_repeats"] = Implied(n_pass // 2, why="the XY line passes, there "
                                              "and back")
            out["line_length_mm"] = Implied(float(f"{np.ptp(cmd[first, a]):.12g}"), tol,
                                            why="the span of an XY line pass")
        circle = rows & (test == TEST_NAMES[2])
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
