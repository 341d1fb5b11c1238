"""rotary_axis's calibrated angle characteristic: the sensor's error against the tilt of
the surface, as a laboratory measures it on a tilt table (a CSV file), and its bilinear
interpolation at the set-up's tilts.

The file has one row per calibrated tilt and the columns ``tilt_x_deg``, ``tilt_y_deg``
(the tilt in the sensor's frame: tau cos phi and tau sin phi, tau the angle of the
surface's normal from the beam, phi the direction of the fall line from the triangulation
plane), ``error_um`` (the sensor's reading minus the true distance) and ``u_um`` (the
standard uncertainty of that point's error). The tilts form a full rectangular grid:
every tilt_x with every tilt_y (other columns are ignored).
"""

from __future__ import annotations

import csv
from typing import NamedTuple

import numpy as np

from mtplan._validate import InvalidInput

COLUMNS = ("tilt_x_deg", "tilt_y_deg", "error_um", "u_um")
_SHOWN = 5  # bad rows named per column (then their count)


class Characteristic(NamedTuple):
    """A calibrated characteristic on its grid."""

    path: str
    tilt_x: np.ndarray  # (nx,) ascending [deg]
    tilt_y: np.ndarray  # (ny,) ascending [deg]
    error: np.ndarray  # (nx, ny) [mm]
    u: np.ndarray  # (nx, ny) standard uncertainty [mm]


def read_characteristic(path: str) -> Characteristic:
    """Read and check a characteristic CSV, refusing it with every problem at once
    (:class:`InvalidInput` naming the file, the row as a spreadsheet shows it, header = row
    1, and the column)."""
    where = f"The angle characteristic {path!r}"
    with open(path, newline="", encoding="utf-8-sig") as fh:
        try:
            rows = list(csv.reader(fh))
        except (csv.Error, UnicodeDecodeError) as exc:
            raise InvalidInput([f"{where} is not a CSV file: {exc}."]) from None
    if not rows:
        raise InvalidInput([f"{where} is empty; it needs a header row with the columns "
                            f"{', '.join(COLUMNS)}."])
    header = [h.strip() for h in rows[0]]
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise InvalidInput([f"{where} lacks the column(s) {', '.join(missing)}; its columns "
                            f"are {', '.join(header)}, the required ones {', '.join(COLUMNS)}."])
    problems = []
    cols = [header.index(c) for c in COLUMNS]
    data = np.full((len(rows) - 1, 4), np.nan)
    bad = {name: [] for name in COLUMNS}
    for i, row in enumerate(rows[1:]):
        for j, (col, name) in enumerate(zip(cols, COLUMNS, strict=True)):
            text = row[col].strip() if col < len(row) else ""
            try:
                value = float(text)
            except ValueError:
                value = np.nan
            if not np.isfinite(value) or (name == "u_um" and value < 0):
                bad[name].append((i + 2, text))
            data[i, j] = value
    for name, found in bad.items():  # the first few of each column, and how many in all
        allowed = "a finite number >= 0" if name == "u_um" else "a finite number"
        problems += [f"{where}, row {row}, column {name}: must be {allowed}, got {text!r}."
                     for row, text in found[:_SHOWN]]
        if len(found) > _SHOWN:
            problems.append(f"{where}, column {name}: {len(found)} rows in all are not "
                            f"{allowed}.")
    if len(data) == 0:
        problems.append(f"{where} has no data rows.")
    rows_ok = np.all(np.isfinite(data[:, :2]), axis=1)
    if problems:  # the tilts that are numbers are still checked for repeats
        _grid_problems(where, data[rows_ok], np.flatnonzero(rows_ok) + 2, problems,
                       complete=False)
        raise InvalidInput(problems)
    xs, ys, flat = _grid_problems(where, data, np.arange(len(data)) + 2, problems)
    if problems:
        raise InvalidInput(problems)
    error, u = np.empty(xs.size * ys.size), np.empty(xs.size * ys.size)
    error[flat], u[flat] = data[:, 2] * 1e-3, data[:, 3] * 1e-3
    out = Characteristic(str(path), xs, ys, error.reshape(xs.size, ys.size),
                         u.reshape(xs.size, ys.size))
    for arr in out[1:]:
        arr.setflags(write=False)
    return out


def _grid_problems(where: str, data: np.ndarray, rows: np.ndarray, problems: list, *,
                   complete: bool = True):
    """The grid of the tilts in `data` (columns tilt_x, tilt_y first; `rows` their rows in
    the file): (tilt_x values, tilt_y values, each row's flat index), recording a tilt given
    twice and, when `complete`, fewer than two values of a component or a missing tilt."""
    xs, ys = np.unique(data[:, 0]), np.unique(data[:, 1])
    for grid, name in ((xs, "tilt_x_deg"), (ys, "tilt_y_deg")):
        if complete and grid.size < 2:
            problems.append(f"{where} must calibrate at least two values of {name}; it has "
                            f"{grid.size}.")
    ix, iy = np.searchsorted(xs, data[:, 0]), np.searchsorted(ys, data[:, 1])
    flat = ix * ys.size + iy
    seen = np.zeros(xs.size * ys.size, dtype=int)
    np.add.at(seen, flat, 1)
    for k in np.flatnonzero(seen > 1)[:_SHOWN]:
        dup = rows[flat == k]
        problems.append(f"{where} gives the tilt ({xs[k // ys.size]:g}, {ys[k % ys.size]:g}) deg "
                        f"more than once (rows {', '.join(map(str, dup))}).")
    absent = np.flatnonzero(seen == 0)
    if complete and absent.size:
        shown = ", ".join(f"({xs[k // ys.size]:g}, {ys[k % ys.size]:g})"
                          for k in absent[:_SHOWN])
        problems.append(f"{where} must hold a full grid (every tilt_x_deg with every "
                        f"tilt_y_deg); {absent.size} tilt(s) are missing: {shown}"
                        + (" ..." if absent.size > _SHOWN else "") + ".")
    return xs, ys, flat


def outside(ch: Characteristic, tx: np.ndarray, ty: np.ndarray) -> np.ndarray:
    """Where the tilts (tx, ty) [deg] lie outside the calibrated grid: bool, same shape."""
    tol = 1e-9
    return ((tx < ch.tilt_x[0] - tol) | (tx > ch.tilt_x[-1] + tol)
            | (ty < ch.tilt_y[0] - tol) | (ty > ch.tilt_y[-1] + tol))


def bilinear(ch: Characteristic, tx: np.ndarray, ty: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The grid points (flat indices into the (nx, ny) grid) and weights of the bilinear
    interpolation at tilts (tx, ty) [deg] inside the grid: arrays (*tx.shape, 4) each."""
    nx, ny = ch.tilt_x.size, ch.tilt_y.size
    ix = np.clip(np.searchsorted(ch.tilt_x, tx, side="right") - 1, 0, nx - 2)
    iy = np.clip(np.searchsorted(ch.tilt_y, ty, side="right") - 1, 0, ny - 2)
    fx = np.clip((tx - ch.tilt_x[ix]) / (ch.tilt_x[ix + 1] - ch.tilt_x[ix]), 0.0, 1.0)
    fy = np.clip((ty - ch.tilt_y[iy]) / (ch.tilt_y[iy + 1] - ch.tilt_y[iy]), 0.0, 1.0)
    index = np.stack([ix * ny + iy, (ix + 1) * ny + iy, ix * ny + iy + 1,
                      (ix + 1) * ny + iy + 1], axis=-1)
    weight = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], axis=-1)
    return index, weight
