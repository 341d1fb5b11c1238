"""Where a set-up measures: the points of its readings table, for the page's picture.

The picture is drawn from the readings the procedure's own forward model gives for the
set-up without errors (the table a spreadsheet of the test would show), so it is the
set-up's positions whatever the procedure: no procedure is drawn by hand. The table's
coordinates are taken as it states them:

- ``x_mm``, ``y_mm`` (and ``z_mm``): points in the procedure's frame (circle_centre's
  contacts, geometry21's paths, line_laser's scanned lines, rotary_axis's lattice);
- ``distance_mm``, ``azimuth_rad``, ``elevation_rad``: a tracker's spherical readings,
  turned into x, y, z about the tracker;
- with ``axis`` and ``angle_deg`` (a rotary axis and its positions): each point turned
  about that axis (A about x, B about y, C about z) by its position's angle, so the
  picture shows where the points are at each position, not the part's lattice once.

Points are grouped by the table's first grouping column (a rotary position, a plane, a
scan, a group of marks) and at most :data:`MAX_POINTS` are kept, evenly spaced.
"""

from __future__ import annotations

import functools
import json

import numpy as np

from mtplan.explore.prediction import guard_cost
from mtplan.explore.state import normalise, setup_of, source_fields
from mtplan.models import get
from mtplan.models.protocol import make

__all__ = ["MAX_POINTS", "measuring_positions", "positions_of_frame"]

#: the most points a picture holds (line_laser scans 15 600 at its defaults)
MAX_POINTS = 4000
#: the table's columns that group its points, first found first
GROUPS = ("position", "plane", "scan", "group", "test", "submachine")
_AXES = {"A": 0, "B": 1, "C": 2}


def positions_of_frame(frame) -> dict:
    """x, y, z [mm] and the group of each row of a readings table (see the module notes).

    Returns
    -------
    dict with ``x``, ``y``, ``z`` (lists; ``z`` None for a plane), ``group`` (list of
    labels), ``group_by`` (the column, or None), ``n`` (rows of the table) and ``how``
    (the columns the coordinates come from, in words).
    """
    cols = set(frame.columns)
    if {"distance_mm", "azimuth_rad", "elevation_rad"} <= cols:
        d, az, el = (frame[c].to_numpy(float) for c in
                     ("distance_mm", "azimuth_rad", "elevation_rad"))
        xyz = np.stack([d * np.cos(el) * np.cos(az), d * np.cos(el) * np.sin(az),
                        d * np.sin(el)], axis=1)
        how = "the tracker's distance, azimuth and elevation, about the tracker"
    elif {"x_mm", "y_mm"} <= cols:
        z = frame["z_mm"].to_numpy(float) if "z_mm" in cols else None
        xyz = np.stack([frame["x_mm"].to_numpy(float), frame["y_mm"].to_numpy(float),
                        z if z is not None else np.zeros(len(frame))], axis=1)
        how = "x, y" + (", z" if z is not None else "") + " of the readings table"
        if {"axis", "angle_deg"} <= cols:
            xyz = _turned(xyz, frame["axis"].astype(str).to_numpy(),
                          np.radians(frame["angle_deg"].to_numpy(float)))
            how += ", turned about the rotary axis by each position's angle"
        if z is None:
            xyz = xyz[:, :2]
    else:
        raise ValueError("The readings table states no coordinates (x_mm and y_mm, or "
                         f"distance_mm, azimuth_rad and elevation_rad). Got {sorted(cols)}.")
    group_by = next((c for c in GROUPS if c in cols), None)
    groups = (frame[group_by].astype(str).to_numpy() if group_by
              else np.full(len(frame), "point"))
    keep = np.unique(np.linspace(0, len(frame) - 1, min(len(frame), MAX_POINTS)).astype(int))
    out = {"x": xyz[keep, 0].tolist(), "y": xyz[keep, 1].tolist(),
           "z": xyz[keep, 2].tolist() if xyz.shape[1] == 3 else None,
           "group": groups[keep].tolist(), "group_by": group_by, "n": int(len(frame)),
           "how": how}
    return out


def _turned(xyz: np.ndarray, axes: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Each point turned about its row's axis (A: x, B: y, C: z) by its angle [rad]."""
    out = xyz.copy()
    c, s = np.cos(angles), np.sin(angles)
    for name, k in _AXES.items():
        rows = axes == name
        i, j = [(1, 2), (2, 0), (0, 1)][k]  # the plane the axis turns
        a, b = xyz[rows, i], xyz[rows, j]
        out[rows, i] = c[rows] * a - s[rows] * b
        out[rows, j] = s[rows] * a + c[rows] * b
    return out


@functools.lru_cache(maxsize=64)
def _positions(name: str, key: str) -> dict:
    proc = get(name)
    setup = make(proc.Setup, json.loads(key), owner=proc.name)
    readings = proc.forward(setup, proc.Truth(), proc.zero_errors(setup, 1))
    return positions_of_frame(proc.readings.frame(setup, readings))


def measuring_positions(design: dict) -> dict:
    """The measuring positions of a design's set-up (:func:`positions_of_frame`), once the
    set-up passes the live cost guard (its forward model is then affordable); cached per
    set-up without its sources' sizes. Raises InvalidInput for a refused or too costly set-up."""
    design = normalise(design)
    proc, setup = setup_of(design)
    est, _ = proc.estimator(design["estimator"])
    guard_cost(proc, setup, est)
    # the noise-free readings do not depend on the sources' sizes: resizing one reuses them
    sized = set(source_fields(proc).values())
    key = json.dumps({k: v for k, v in setup.as_dict().items() if k not in sized},
                     sort_keys=True)
    return {"procedure": proc.name, **_positions(proc.name, key)}
