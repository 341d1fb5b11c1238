"""Write examples/angle_characteristic.csv: a tilt-table calibration of a 10 mm laser
triangulation sensor, simulated from the data-sheet model of docs/rotary_axis.md.

The sensor's true angle influence is range * B(tau) * (c0 + c1 cos phi + c2 cos 2 phi)
with range 10 mm, B the data sheet's bound at the tilt relative to 30 deg (0.5 % of the
range there), c0 = 0.20, c1 = 0.25, c2 = -0.10 (inside the model's +-1/3). The laboratory
reads it on a grid of tilts from -50 to 50 deg in steps of 5 deg in both components,
each point with a standard uncertainty of 0.5 um (its reference and repeatability), and
the file holds its readings: the true error plus a normal error of 0.5 um (seed 32).

    PYTHONPATH=src python benchmarks/make_angle_characteristic.py
"""

from pathlib import Path

import numpy as np

from mtplan._io import atomic_write_text
from mtplan.models.rotary_axis._layout import _tilt_bound

RANGE_UM, BOUND_30 = 10_000.0, 0.005
C0, C1, C2 = 0.20, 0.25, -0.10
U_UM = 0.5


def true_error_um(tx, ty):
    """The simulated sensor's angle influence at tilts (tx, ty) [deg] in its frame [um]."""
    tau, phi = np.hypot(tx, ty), np.arctan2(ty, tx)
    return RANGE_UM * BOUND_30 * _tilt_bound(tau) * (C0 + C1 * np.cos(phi) + C2 * np.cos(2 * phi))


def main():
    grid = np.arange(-50.0, 50.1, 5.0)
    tx, ty = (a.ravel() for a in np.meshgrid(grid, grid, indexing="ij"))
    measured = true_error_um(tx, ty) + np.random.default_rng(32).normal(0.0, U_UM, tx.size)
    lines = ["tilt_x_deg,tilt_y_deg,error_um,u_um"]
    lines += [f"{x:g},{y:g},{e:.3f},{U_UM:g}" for x, y, e in zip(tx, ty, measured, strict=True)]
    out = Path(__file__).resolve().parents[1] / "examples" / "angle_characteristic.csv"
    atomic_write_text(out, "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
