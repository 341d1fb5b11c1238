"""What the line_laser posterior learns from the artifact's pattern (not a test; prints figures).

Usage: ``python benchmarks/line_laser_artifact_information.py`` (about 10 s).

The linearised posterior: the standard uncertainty of the three angles from the Fisher
information ``J^T C^-1 J`` of the readings (``J``: the forward model's Jacobian over the
angles and the artifact's pose, central differences at the default truth; ``C``: sensor
noise plus the secant effect of every other active error source at one standard
deviation) - what ``sample_posterior`` reports, to a few per cent, in a second. Then the
same with one more imperfection of the artifact in ``C`` (its effect at one standard
deviation), to tell which of the pattern's stated dimensions the posterior (and the
``pattern`` estimator) rely on:

- errors common to the whole pattern (depth, facet angle, land width, pitch, a scale of
  the lattice along X or Y), and a free height of the plate;
- a shear of the lattice (the X-Y squareness of the machine that cut it);
- a lean of the pockets along Y (their floors displaced from their openings by the depth
  times the lean: the Z-Y squareness of that machine, or unequal draft of opposite walls);
- the position of each facet, independent from facet to facet (the source
  ``facet_position``, here switched off in the base and added alone).

The imperfections that are not sources of the set-up are made by wrapping
``line_laser.height_map`` (coordinates mapped before the lattice is evaluated).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from mtplan.models import line_laser as ll
from mtplan.models.line_laser import _estimators as ll_estimators

PROC = ll.PROCEDURE
FIELDS = ll_estimators.FIT_FIELDS
STEPS = ll_estimators.FIT_STEPS
_HEIGHT_MAP = ll.height_map


def _perturbed(setup, pert):
    """A height map with the artifact imperfection `pert` (dict), the set-up's otherwise."""
    geom = {k: v for k, v in pert.items() if k in ("cell_depth_mm", "facet_angle_deg",
                                                    "wall_mm", "cell_size_mm")}

    def height_map(s, x, y, **kw):
        s = dataclasses.replace(s, **{k: getattr(s, k) + v for k, v in geom.items()})
        x2 = x * (1 + pert.get("scale_x", 0.0)) + pert.get("shear", 0.0) * y
        y2 = y * (1 + pert.get("scale_y", 0.0))
        out = _HEIGHT_MAP(s, x2, y2, **kw)
        if pert.get("lean_y"):  # deeper points seen displaced along Y by depth x lean
            out = _HEIGHT_MAP(s, x2, y2 + pert["lean_y"] * out[0], **kw)
        return (out[0] + pert.get("height", 0.0), *out[1:])

    return height_map


def _readings(setup, theta, pert=None, errors=None):
    ll.NOMINAL.clear()
    ll.FACET_OF.clear()
    if pert:
        ll.height_map = _perturbed(setup, pert)
    try:
        errors = errors if errors is not None else PROC.zero_errors(setup, 1)
        truth = ll_estimators._truth_rows(theta[None, :])
        return ll.forward(setup, truth, errors)["z_mm"].ravel()
    finally:
        ll.height_map = _HEIGHT_MAP
        ll.NOMINAL.clear()
        ll.FACET_OF.clear()


def linearised_u(setup, extra=()) -> np.ndarray:
    """u of (alpha_z, alpha_y, alpha_x) [urad]; `extra`: (pert at +1 sd, pert at -1 sd)."""
    theta = np.array([getattr(ll.Truth(), f) for f in FIELDS])
    jac = np.stack([(_readings(setup, theta + h * e) - _readings(setup, theta - h * e)) / (2 * h)
                    for h, e in zip(STEPS, np.eye(len(FIELDS)))], axis=1)
    cols = []
    for name, src in PROC.sources(setup).items():
        if name == PROC.readings.noise_source or not src.active:
            continue
        sd = float(np.max(src.distribution.std))
        for k in range(src.size):
            err = [PROC.zero_errors(setup, 1) for _ in range(2)]
            err[0][name].reshape(-1)[k], err[1][name].reshape(-1)[k] = sd, -sd
            cols.append((_readings(setup, theta, errors=err[0])
                         - _readings(setup, theta, errors=err[1])) / 2)
    cols += [(_readings(setup, theta, p) - _readings(setup, theta, m)) / 2 for p, m in extra]
    sigma = setup.sensor_noise_um * 1e-3
    u = np.stack(cols, axis=1) / sigma
    wj = jac - u @ np.linalg.solve(np.eye(u.shape[1]) + u.T @ u, u.T @ jac)
    cov = np.linalg.inv(jac.T @ wj) * sigma**2
    return np.sqrt(np.diag(cov)[:3]) * 1e3  # mrad -> urad


def main() -> None:
    base = ll.Setup(facet_position_um=0.0)
    rows = [("exact pattern (facet_position off)", base, ())]

    def one(label, **pert):
        rows.append((label, base, [(pert, {k: -v for k, v in pert.items()})]))

    one("+ pocket depth 10 um", cell_depth_mm=0.01)
    one("+ facet angle 0.2 deg", facet_angle_deg=0.2)
    one("+ land width 10 um", wall_mm=0.01)
    one("+ pitch 5 um", cell_size_mm=0.005)
    one("+ lattice scale X 1000 ppm", scale_x=1e-3)
    one("+ lattice scale Y 1000 ppm", scale_y=1e-3)
    one("+ plate height 1 mm (free)", height=1.0)
    for sd in (20e-6, 100e-6):
        one(f"+ lattice shear {sd * 1e6:g} urad", shear=sd)
    for sd in (50e-6, 500e-6, 5e-3):
        one(f"+ pocket lean along Y {sd * 1e6:g} urad", lean_y=sd)
    for um in (1.0, 2.0, 5.0):
        rows.append((f"+ facet_position {um:g} um (the source)", ll.Setup(facet_position_um=um),
                     ()))
    print("linearised posterior u [urad] at the default truth and set-up")
    print(f"{'':44s} {'alpha_z':>8s} {'alpha_y':>8s} {'alpha_x':>8s}")
    for label, setup, extra in rows:
        u = linearised_u(setup, extra)
        print(f"{label:44s} {u[0]:8.1f} {u[1]:8.2f} {u[2]:8.1f}")


if __name__ == "__main__":
    main()
