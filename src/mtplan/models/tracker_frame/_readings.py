"""tracker_frame's readings table: one tracker reading per row, keyed by group, sub-machine
and index, and the set-up fields a measured table determines.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from mtplan._validate import InvalidInput, Problems
from mtplan.models.protocol import Readings, frame_columns
from mtplan.models.tracker_frame._layout import arc_angles as _arc_angles, layout as _layout
from mtplan.models.tracker_frame._setup import AXES, NAME, Setup


READING_COLUMNS = ("distance_mm", "azimuth_rad", "elevation_rad")


KEY_COLUMNS = ("group", "submachine", "index")


def readings_frame(setup: Setup, readings: dict) -> pd.DataFrame:
    """Tidy table of one measurement (the first trial): one tracker reading per row.

    Columns: ``point`` (0..), ``group`` (``mark``, ``X``, ``Y``, ``Z``, ``C``, ``A``),
    ``submachine`` (0 for the bed marks), ``index`` (within the group), the commanded
    ``position_mm`` (linear travels) and ``angle_deg`` (arcs), and the readings
    ``distance_mm``, ``azimuth_rad``, ``elevation_rad``.
    """
    rows = _layout(setup)
    df = pd.DataFrame(rows, columns=["group", "submachine", "index", "position_mm", "angle_deg"])
    df.insert(0, "point", np.arange(len(rows)))
    for col in READING_COLUMNS:
        df[col] = np.asarray(readings[col], dtype=float)[0]
    return df


def from_frame(setup: Setup, df: pd.DataFrame) -> Readings:
    """Readings (batch of one) from a table in the format of :func:`readings_frame`.

    Rows are matched to the set-up's layout by (group, submachine, index); their
    order in the table does not matter. The commanded positions are not used (the
    estimators orient lines by the order of the points along each travel). The
    commanded angles of the arcs, which the ``angles`` estimator uses, come from the
    set-up; an ``angle_deg`` column, when present, must agree with them (1e-6 deg).
    """
    p = Problems(f"{NAME} readings")
    values = frame_columns(df, (*KEY_COLUMNS, *READING_COLUMNS), f"{NAME} readings",
                           numeric=READING_COLUMNS, problems=p)
    layout = _layout(setup)
    if len(df) != len(layout):
        p.add_text(f"The readings of {NAME} must have {len(layout)} rows for this set-up "
                   f"(4 marks + {setup.n_submachines} x (3 x {setup.points_per_axis} + 2 x "
                   f"{setup.points_per_arc})). Got {len(df)} instead")
    p.raise_if_any()
    try:
        keys = list(zip(df["group"].astype(str),
                        pd.to_numeric(df["submachine"]).astype(int),
                        pd.to_numeric(df["index"]).astype(int), strict=True))
    except (ValueError, TypeError):
        raise InvalidInput([f"Columns 'submachine' and 'index' of the {NAME} readings must "
                            "hold integers."]) from None
    where = {}
    for row, key in enumerate(keys):
        if key in where:
            p.add_text(f"Row {row} of the {NAME} readings repeats {key} (first at row "
                       f"{where[key]})")
        where[key] = row
    expected = [r[:3] for r in layout]
    absent = [key for key in expected if key not in where]
    if absent:
        p.add_text(f"The {NAME} readings lack the point(s) (group, submachine, index) "
                   f"{', '.join(map(str, absent[:5]))}" + (" ..." if len(absent) > 5 else ""))
    extra = sorted(set(where) - set(expected))
    if extra:
        p.add_text(f"The {NAME} readings hold point(s) this set-up does not have: "
                   f"{', '.join(map(str, extra[:5]))}")
    p.raise_if_any()
    order = np.array([where[key] for key in expected])
    if "angle_deg" in df.columns:
        # the angles estimator takes the commanded angles from the set-up: a table whose
        # arcs were run at other angles would be fitted against the wrong ones
        got = pd.to_numeric(df["angle_deg"], errors="coerce").to_numpy(dtype=float)[order]
        want = np.array([r[4] for r in layout])
        arc = np.array([r[0] in ("C", "A") for r in layout])
        off = np.flatnonzero(arc & ~(np.abs(got - want) <= 1e-6))
        if off.size:
            rows = ", ".join(f"{layout[i][:3]} {got[i]:g} deg, set-up {want[i]:g} deg"
                             for i in off[:3])
            raise InvalidInput([
                f"The 'angle_deg' of {off.size} arc point(s) of the {NAME} readings differ "
                f"from the set-up's commanded angles ({rows}"
                f"{' ...' if off.size > 3 else ''}); arcs are centred on home with "
                "c_arc_deg / a_arc_deg and points_per_arc: set these to match the data."])
    return Readings({col: values[col][order][None, :] for col in READING_COLUMNS})


def setup_from_frame(df: pd.DataFrame) -> dict:
    """The set-up fields a measured tracker table determines (see ``Implied``).

    The number of sub-machines (the largest ``submachine``), of points per linear travel
    (the X rows of the first sub-machine) and per arc (its C rows), the travels (the
    span of ``position_mm`` of its X, Y and Z rows, within 1e-6 mm) and the arcs of C
    and A (from ``angle_deg``: the span, or 360 when the points are evenly spaced over a
    full turn without its repeated end, within 1e-6 deg). Where the table is not regular
    enough to tell, the field is left out and the design check names the offending row.
    """
    from mtplan.models.protocol import Implied

    group = df["group"].astype(str).str.strip().to_numpy()
    sub = pd.to_numeric(df["submachine"], errors="coerce").to_numpy(dtype=float)
    pos = pd.to_numeric(df["position_mm"], errors="coerce").to_numpy(dtype=float)
    ang = pd.to_numeric(df["angle_deg"], errors="coerce").to_numpy(dtype=float)
    if not all(np.all(np.isfinite(a)) for a in (sub, pos, ang)) or not np.any(sub >= 1):
        return {}
    n_sub = int(sub.max())
    out = {"n_submachines": Implied(n_sub, why=f"the file's sub-machines 1..{n_sub}")}
    first = sub == 1
    for g, field, what in (("X", "points_per_axis", "X"), ("C", "points_per_arc", "C")):
        m = int(np.sum(first & (group == g)))
        if m:
            out[field] = Implied(m, why=f"the {what} rows of sub-machine 1")
    for g in AXES:
        p = pos[first & (group == g)]
        if p.size >= 2:
            out[f"travel_{g.lower()}_mm"] = Implied(float(np.ptp(p)), 1e-6,
                                                  why=f"the {g} positions of sub-machine 1")
    for g in ("C", "A"):
        a = np.sort(ang[first & (group == g)])
        if a.size >= 2:
            full = np.allclose(_arc_angles(360.0, a.size), a, rtol=0, atol=1e-6)
            out[f"{g.lower()}_arc_deg"] = Implied(360.0 if full else float(np.ptp(a)), 1e-6,
                                                  why=f"the {g} angles of sub-machine 1")
    return out
