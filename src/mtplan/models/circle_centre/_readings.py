"""circle_centre's readings table (the points p1, p2, d1..dn) and the set-up fields a measured
table of bore points determines.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import numpy as np

from mtplan._validate import InvalidInput, Problems
from mtplan.fitting.circle import geometric_fit
from mtplan.models.circle_centre._setup import Setup
from mtplan.models.protocol import Readings

if TYPE_CHECKING:  # pandas only where a table is made or read: not in a Monte Carlo's workers
    import pandas as pd


def _labels(n_points: int) -> list[str]:
    return ["p1", "p2"] + [f"d{k}" for k in range(1, n_points + 1)]


def readings_frame(setup: Setup, readings: dict) -> pd.DataFrame:
    """One measurement as a tidy frame: columns ``point`` (p1, p2, d1..dn), ``x_mm``, ``y_mm``."""
    import pandas as pd

    px = np.asarray(readings["p_x_mm"], dtype=float)[0]
    py = np.asarray(readings["p_y_mm"], dtype=float)[0]
    x = np.asarray(readings["x_mm"], dtype=float)[0]
    y = np.asarray(readings["y_mm"], dtype=float)[0]
    return pd.DataFrame({"point": _labels(x.size), "x_mm": np.concatenate([px, x]),
                         "y_mm": np.concatenate([py, y])})


def from_frame(setup: Setup, df: pd.DataFrame) -> Readings:
    """Readings (batch of one) from a frame with columns ``point``, ``x_mm``, ``y_mm``.

    ``point`` names p1, p2 and d1..dn (n = ``n_points``) in any order. Without a
    ``point`` column every row is a measuring point d1..dn in order, and p1, p2 (which
    only the acceptance check uses) are taken as unknown (NaN).
    """
    import pandas as pd

    p = Problems("circle_centre data")
    for col in ("x_mm", "y_mm"):
        if col not in df.columns:
            p.add_text(f"The circle_centre data must have a column {col!r}; its columns are "
                       f"{', '.join(map(str, df.columns))}")
    p.raise_if_any()
    xs = pd.to_numeric(df["x_mm"], errors="coerce").to_numpy(dtype=float)
    ys = pd.to_numeric(df["y_mm"], errors="coerce").to_numpy(dtype=float)
    bad = np.flatnonzero(~(np.isfinite(xs) & np.isfinite(ys)))
    if bad.size:
        p.add_text(f"The columns 'x_mm' and 'y_mm' of the circle_centre data must hold finite "
                   f"numbers; rows {bad.tolist()} do not")
    n = setup.n_points
    if "point" in df.columns:
        names = df["point"].astype(str).str.strip().tolist()
        want = _labels(n)
        missing = [w for w in want if w not in names]
        extra = [w for w in names if w not in want]
        dup = sorted({w for w in names if names.count(w) > 1})
        if missing or extra or dup:
            p.add_text(f"The 'point' column of the circle_centre data must name p1, p2 and d1..d{n} "
                       f"once each (n_points={n}); missing {missing}, unknown {extra}, "
                       f"repeated {dup}")
        p.raise_if_any()
        order = [names.index(w) for w in want]
        px, py = xs[order[:2]], ys[order[:2]]
        x, y = xs[order[2:]], ys[order[2:]]
    else:
        if len(xs) != n:
            p.add_text(f"The circle_centre data must have n_points={n} rows of measuring points "
                       f"(or a 'point' column naming p1, p2, d1..d{n}); it has {len(xs)}")
        p.raise_if_any()
        px = py = np.full(2, np.nan)
        x, y = xs, ys
    return Readings({"x_mm": x[None, :], "y_mm": y[None, :], "p_x_mm": px[None, :],
                     "p_y_mm": py[None, :]})


# --------------------------------------------------------------------------- set-up from a file
#: the random sources besides the probe's noise; a user who states any of them has set up
#: the noise budget, and the points' scatter no longer raises the probe noise's default
_SCATTER_FIELDS = ("probe_noise_um", "pretravel_variation_um", "roundness_um",
                   "stage_repeatability_um")


def setup_from_frame(df: pd.DataFrame) -> dict:
    """The set-up fields a measured table of bore points determines (see ``Implied``).

    From the measuring points (the ``d`` rows, or every row of a bare point file): their
    number (``n_points``); the nominal radius as the radius of their geometric
    (ISO 12181) circle, agreeing within 5 % of it plus three times the points' scatter
    about it (the ``radius`` measurand is then relative to it: state the drawing's
    radius to measure the deviation from that); the arc they cover (``spread_deg``, 360
    when no gap between neighbours exceeds 1.25 times the even spacing), within 10 %
    plus 2 deg. The bore bounds the fields the set-up requires to fit in it (start
    scatter, clearance, trial displacement, form error; taken at the low end of the
    radius's tolerance). With more than three points, their scatter about the circle
    ``s = sqrt(SSR / (n - 3))`` bounds the probe's noise from below, softly: a default
    whose random sources are too small to give that scatter at 99.9 % confidence is
    raised so that they give ``s``.
    """
    import pandas as pd

    from scipy import special

    from mtplan.models.protocol import Implied

    x = pd.to_numeric(df["x_mm"], errors="coerce").to_numpy(dtype=float)
    y = pd.to_numeric(df["y_mm"], errors="coerce").to_numpy(dtype=float)
    if "point" in df.columns:
        labels = df["point"].astype(str).str.strip()
        keep = labels.str.fullmatch(r"d[1-9][0-9]*").to_numpy()
        x, y = x[keep], y[keep]
    n = x.size
    out = {"n_points": Implied(n, why=f"the file's {n} measuring points")}
    if n < 3 or not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        return out  # from_frame names what is wrong
    try:
        c = geometric_fit(x[None], y[None])
        r = float(c.r[0])
    except np.linalg.LinAlgError:  # collinear points: Kasa's start is singular
        r = math.inf
    span = max(float(np.ptp(x)), float(np.ptp(y)))
    if not (math.isfinite(r) and 0 < r < 1e4 * span):
        raise InvalidInput(["The measuring points lie on a straight line (their circle's "
                            "radius is over 10^4 times their extent): no bore passes through "
                            "them."])
    resid = np.hypot(x - float(c.xc[0]), y - float(c.yc[0])) - r
    s = math.sqrt(float(resid @ resid) / (n - 3)) if n > 3 else 0.0
    tol = 0.05 * r + 3 * s
    out["bore_radius_mm"] = Implied(r, tol, why=f"the geometric circle through the {n} points")
    phi = np.sort(np.mod(np.degrees(np.arctan2(y - float(c.yc[0]), x - float(c.xc[0]))), 360))
    gap = float(np.max(np.diff(np.concatenate([phi, phi[:1] + 360]))))
    spread = 360.0 if gap <= 1.25 * 360.0 / n else 360.0 - gap
    out["spread_deg"] = Implied(spread, 0.1 * spread + 2.0, why="the arc the points cover")
    r_low = max(r - tol, 0.5 * r)
    bounds = (("start_scatter_mm", 0.999 * 0.5 * r_low / math.sqrt(2), "the start within half "
               "the bore radius"), ("clearance_mm", 0.5 * r_low, "within the bore"),
              ("free_test_mm", 0.05 * r_low, "a small part of the bore radius"),
              ("roundness_um", 25.0 * r_low, "a small part of the bore radius"))
    for name, value, why in bounds:
        out[name] = Implied(value, bound="max", why=f"{why}, r >= {r_low:.4g} mm")
    if n > 3:
        d = Setup()
        other = ((d.stage_repeatability_um * 1e-3) ** 2 + (d.pretravel_variation_um * 1e-3) ** 2 / 2
                 + (d.roundness_um * 1e-3 / (2 * math.sqrt(2))) ** 2)
        s_low = s * math.sqrt((n - 3) / (2 * special.gammaincinv((n - 3) / 2, 0.999)))
        need = math.sqrt(max(s * s - other, 0.0)) * 1e3
        need_low = math.sqrt(max(s_low * s_low - other, 0.0)) * 1e3
        high = next(f.metadata["high"] for f in dataclasses.fields(Setup)
                    if f.name == "probe_noise_um")
        out["probe_noise_um"] = Implied(
            min(need, high), need - need_low, bound="min", soft=True,
            unless_given=_SCATTER_FIELDS,
            why=f"the points scatter by {s * 1e3:.3g} um rms about their circle")
    return out
