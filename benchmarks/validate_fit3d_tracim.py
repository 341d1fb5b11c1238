"""Check the 3D line, plane and circle fits of ``mtplan.fitting.fit3d`` against TraCIM data.

Reads the PTB TraCIM "Gauss" package kept outside the project
(``../shared/refdata/tracim_gauss/``, see its README section 3): LINE_3D b01-b04,
PLANE b05-b08, CIRCLE b09-b15, and compares each fit with the
``recomputed_50digit`` row of ``reference_results.csv`` (50-digit least-squares
solutions; CIRCLE with full 3-D orthogonal distances). Prints the largest
differences per element and per kind, and the plane-then-circle (Kasa in the
best-fit plane) result beside the full 3-D circle fit, to show that the two differ.
This is a validation script, not a test: the test suite does not read ../shared.

Usage::

    .venv/bin/python benchmarks/validate_fit3d_tracim.py [--data DIR] [--tol 1e-7]

Exit status 1 when a difference exceeds the tolerance (default 1e-7, the README's).
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from mtplan.fitting.fit3d import _kasa_start, fit_circle_3d, fit_line_3d, fit_plane

DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "refdata" / "tracim_gauss"
if not DEFAULT.is_dir():
    DEFAULT = Path("/work/shared/refdata/tracim_gauss")

KINDS = {"LINE_3D": range(1, 5), "PLANE": range(5, 9), "CIRCLE": range(9, 16)}


def _points(folder: Path, bid: str) -> np.ndarray:
    with open(folder / f"{bid}.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    return np.array([[float(r["x"]), float(r["y"]), float(r["z"])] for r in rows])


def _reference(folder: Path) -> dict:
    out = {}
    with open(folder / "reference_results.csv", newline="") as fh:
        for r in csv.DictReader(fh):
            if r["source"] == "recomputed_50digit":
                vals = [float(r[f"p{i}"]) for i in range(1, 9) if r.get(f"p{i}") not in (None, "")]
                out[r["id"]] = (r["kind"], np.array(vals))
    return out


def _distance_to_line(point, direction, ref_point) -> float:
    """Distance of the reference point from the fitted line (the point is any point on it)."""
    d = ref_point - point
    return float(np.linalg.norm(d - np.dot(d, direction) * direction))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT)
    ap.add_argument("--tol", type=float, default=1e-7)
    args = ap.parse_args(argv)
    ref = _reference(args.data)
    worst: dict[str, float] = {}
    print(f"TraCIM gauss reference: {args.data}")
    print(f"{'id':4} {'kind':8} {'m':>3} {'point/centre [mm]':>18} {'direction [1]':>14} "
          f"{'radius [mm]':>12}  notes")
    for kind, ids in KINDS.items():
        for i in ids:
            bid = f"b{i:02d}"
            k, p = ref[bid]
            assert k == kind, (bid, k, kind)
            pts = _points(args.data, bid)
            note = ""
            if kind == "LINE_3D":
                fit = fit_line_3d(pts, orient=p[3:6])
                dpos = float(np.max(np.abs(fit.point - p[:3])))
                ddir = float(np.max(np.abs(fit.direction - p[3:6])))
                drad = float("nan")
            elif kind == "PLANE":
                fit = fit_plane(pts, orient=p[3:6])
                dpos = float(np.max(np.abs(fit.point - p[:3])))
                ddir = float(np.max(np.abs(fit.normal - p[3:6])))
                drad = float("nan")
            else:
                fit = fit_circle_3d(pts, orient=p[3:6])
                dpos = float(np.max(np.abs(fit.centre - p[:3])))
                ddir = float(np.max(np.abs(fit.normal - p[3:6])))
                drad = float(abs(fit.radius - p[6]))
                c0, n0, r0 = _kasa_start(pts - pts.mean(0), p[3:6])
                c0 = c0 + pts.mean(0)
                note = (f"iter {fit.iterations}; plane-then-Kasa differs by "
                        f"{np.max(np.abs(c0 - p[:3])):.1e} mm (centre), "
                        f"{abs(r0 - p[6]):.1e} mm (r)")
            worst[kind] = max(worst.get(kind, 0.0), dpos, ddir, 0.0 if np.isnan(drad) else drad)
            print(f"{bid:4} {kind:8} {len(pts):3d} {dpos:18.2e} {ddir:14.2e} {drad:12.2e}  "
                  f"{note}")
    print()
    for kind, w in worst.items():
        flag = "ok" if w <= args.tol else "EXCEEDS TOLERANCE"
        print(f"largest difference {kind:8}: {w:.2e}  ({flag}, tolerance {args.tol:g})")
    return 0 if all(w <= args.tol for w in worst.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
