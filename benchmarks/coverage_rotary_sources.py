"""Coverage of rotary_axis's default estimator with every error source at its default.

For the C and the A axis, `--replicates` simulated measurements at the default set-up and
truth (or with `--set FIELD=VALUE ...`), with every default error source on (the sensor's
tilt-dependent angle influence, the one-to-one sources: spot offset, sensor zero, the
slides' slope and bow, reversal value, short-period positioning, linearity; the smooth
angular positioning error; seeds 2000, 2001, ...), are each evaluated as measured data
the way `mtplan estimate` does (``estimate_measured(..., uncertainty="mc")`` with the
default, best estimator). Per measurand and pooled: the share of 95 % intervals that
contain the true value, with its binomial standard error (replicates are independent; the
measurands of one replicate are not, so the pooled error is a lower bound), and the rms
of (value - true) / u over the replicates. Goals: 92-98 % and 0.8-1.2.

    .venv/bin/python benchmarks/coverage_rotary_sources.py [--axes C A] [--replicates 100]
        [--trials 4000] [--set sensor_reversal=true ...] [--out coverage_rotary.csv]
        [--family own|odd|tau2|flat] [--amplitude 1]

`--family` other than `own` draws the sensor's angle influence from a family the data sheet
allows but the model does not assume, built by this script's own forward path (the
nominal surface's tilt under the sensor at each position and pass, from the set-up's
fields, and the data sheet's table), not by the model's draw: every other source is the
model's. Each family is ``range g(tau) (c0 + c1 cos phi + c2 cos 2 phi)``, phi the tilt's
direction from the triangulation plane (+pi in the reversed pass), with

- ``odd``: g = B(tau), c1 uniform within +-2/3, c0 and c2 within +-1/6 (mostly odd);
- ``tau2``: g = B(tau_top) (tau / tau_top)^2, scaled down where it would pass B at a
  tilt of the set-up, c0 within +-2/3, c1 and c2 within +-1/6 (mostly even);
- ``flat``: g = B(tau_low) + max(0, B(tau) - B(30 deg)): flat to the table's last row and
  rising beyond it, the split of ``tau2``;

times `--amplitude` (1: the coefficients' bounds sum to the whole bound). Every drawn
error is checked to lie within range B(tau) at every reading.

Not a test: about 1-2 s per replicate and axis on one core.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
import warnings
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))


#: the data sheet's angle influence table: tilt [deg] -> bound [fraction of the range]
#: (laser triangulation on diffuse surfaces), on along the last row's slope beyond 30 deg
TABLE_DEG, TABLE = (0.0, 5.0, 15.0, 30.0), (0.0, 0.0012, 0.002, 0.005)


def _bound(setup, tau):
    """The data sheet's bound at tilts `tau` [deg], scaled to the set-up's field [mm]."""
    import numpy as np

    slope = (TABLE[-1] - TABLE[-2]) / (TABLE_DEG[-1] - TABLE_DEG[-2])
    b = np.where(tau > TABLE_DEG[-1], TABLE[-1] + slope * (tau - TABLE_DEG[-1]),
                 np.interp(tau, TABLE_DEG, TABLE))
    return setup.sensor_range_mm * b * setup.angle_influence_halfwidth_ppm * 1e-6 / TABLE[-1]


def _surface_tilts(setup):
    """Tilt magnitude [deg] and direction from the triangulation plane [rad] of the nominal
    surface under the sensor at each position (P,), from the set-up's fields alone: the
    incline's upward normal turned about the nominal axis (Z for C, X for A) by each
    commanded angle (Rodrigues' formula)."""
    import numpy as np

    i, az = np.radians(setup.incline), np.radians(setup.incline_azimuth_deg)
    n = np.array([np.sin(i) * np.cos(az), np.sin(i) * np.sin(az), np.cos(i)])
    k = np.array([0.0, 0.0, 1.0]) if setup.axis == "C" else np.array([1.0, 0.0, 0.0])
    t = np.radians(np.asarray(setup.angles(), dtype=float))[:, None]
    rotated = (n * np.cos(t) + np.cross(k, n) * np.sin(t) + k * (k @ n) * (1 - np.cos(t)))
    tau = np.degrees(np.arccos(np.clip(rotated[:, 2], -1, 1)))
    return tau, np.arctan2(rotated[:, 1], rotated[:, 0]) - np.radians(setup.sensor_azimuth_deg)


def _family_error(setup, family, amplitude, rng):
    """The angle influence of one sensor drawn from `family`, at every reading (1, P, R) [mm]."""
    import numpy as np

    tau, phi = _surface_tilts(setup)
    bound = _bound(setup, tau)
    if family == "odd":
        g, split = bound, (1 / 6, 2 / 3, 1 / 6)
    elif family == "tau2":
        top = tau.max()
        g = _bound(setup, np.array([top])) * (tau / top) ** 2
        g = g * min(1.0, float(np.min(np.where(g > 0, bound / np.where(g > 0, g, 1), np.inf))))
        split = (2 / 3, 1 / 6, 1 / 6)
    elif family == "flat":
        g = _bound(setup, np.array([tau.min()])) + np.maximum(
            0.0, bound - _bound(setup, np.array([TABLE_DEG[-1]])))
        split = (2 / 3, 1 / 6, 1 / 6)
    else:
        raise ValueError(f"unknown family {family!r}")
    c = rng.uniform(-1, 1, 3) * np.array(split) * amplitude
    e = []
    for k in range(setup.n_passes):  # the reversed pass sees the tilt's direction + pi
        p = phi + np.pi * k
        e.append(np.repeat((g * (c[0] + c[1] * np.cos(p) + c[2] * np.cos(2 * p)))[:, None],
                           setup.n_points, axis=1))
    e = np.concatenate(e, axis=1)
    if np.any(np.abs(e) > bound[:, None] * (1 + 1e-9)):
        raise AssertionError(f"family {family} left the data sheet's bound")
    return e[None]


def _replicate(proc, setup, seed, trials, family="own", amplitude=1.0):
    """One row per measurand: (axis, seed, estimator, measurand, value, u, low, high, true)."""
    import numpy as np

    from mtplan.evaluation.measured import estimate_measured

    truth = proc.display_truth(setup, proc.Truth())
    if family == "own":
        readings = proc.simulate(setup, proc.Truth(), 1, rng=seed)
    else:
        others = [k for k in proc.active_sources(setup) if k != "angle_influence_halfwidth"]
        readings = proc.simulate(setup, proc.Truth(), 1, rng=seed, sources=others)
        readings = {"z_mm": readings["z_mm"] + _family_error(
            setup, family, amplitude, np.random.default_rng([seed, 77]))}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = estimate_measured(proc, setup, readings, uncertainty="mc", trials=trials,
                                rng=seed)
    return [{"axis": setup.axis, "seed": seed, "estimator": res.estimator, "measurand": m.name,
             "value": res.value[i], "u": res.std[i], "low": res.low[i], "high": res.high[i],
             "true": truth[m.name]} for i, m in enumerate(res.measurands)]


def main(argv=None):
    import numpy as np
    import pandas as pd

    from mtplan.models import get

    ap = argparse.ArgumentParser()
    ap.add_argument("--axes", nargs="*", default=["C", "A"])
    ap.add_argument("--replicates", type=int, default=100)
    ap.add_argument("--trials", type=int, default=4000)
    ap.add_argument("--set", nargs="*", default=[], metavar="FIELD=VALUE")
    ap.add_argument("--out", default=None)
    ap.add_argument("--family", default="own", choices=["own", "odd", "tau2", "flat"])
    ap.add_argument("--amplitude", type=float, default=1.0)
    ap.add_argument("--first-seed", type=int, default=2000)
    args = ap.parse_args(argv)
    proc = get("rotary_axis")
    fields = dict(kv.split("=", 1) for kv in args.set)
    rows = []
    for axis in args.axes:
        setup = proc.setup({**fields, "axis": axis})
        t0 = time.perf_counter()
        for k in range(args.replicates):
            rows += _replicate(proc, setup, args.first_seed + k, args.trials, args.family,
                               args.amplitude)
        print(f"axis {axis}, family {args.family}: {args.replicates} replicates in "
              f"{time.perf_counter() - t0:.0f} s "
              f"(sources: {', '.join(proc.active_sources(setup))})", flush=True)
    df = pd.DataFrame(rows)
    df["covered"] = (df["low"] <= df["true"]) & (df["true"] <= df["high"])
    df["error"] = df["value"] - df["true"]
    df["z"] = df["error"] / df["u"]
    print(f"{'axis':4} {'estimator':9} {'measurand':9} {'coverage':>8} {'+-':>5} "
          f"{'rms err':>9} {'mean u':>9} {'rms e/u':>7}")
    for (axis, est, name), g in df.groupby(["axis", "estimator", "measurand"], sort=False):
        p, n = g["covered"].mean(), len(g)
        rms, u = math.sqrt(float(np.mean(g["error"] ** 2))), float(g["u"].mean())
        print(f"{axis:4} {est:9} {name:9} {100 * p:7.1f}% {100 * math.sqrt(p * (1 - p) / n):4.1f}"
              f" {rms:9.3g} {u:9.3g} {math.sqrt(float(np.mean(g['z'] ** 2))):7.2f}")
    for axis, g in df.groupby("axis", sort=False):
        p, n = g["covered"].mean(), g["seed"].nunique()
        rz = math.sqrt(float(np.mean(g["z"] ** 2)))
        verdict = "within" if 0.92 <= p <= 0.98 else "OUTSIDE"
        print(f"axis {axis} pooled: {100 * p:.1f} % (+-{100 * math.sqrt(p * (1 - p) / n):.1f}, "
              f"{n} replicates): {verdict} 92-98 %; rms error/u {rz:.2f}: "
              f"{'within' if 0.8 <= rz <= 1.2 else 'OUTSIDE'} 0.8-1.2")
    if args.out:
        df.to_csv(args.out, index=False)


if __name__ == "__main__":
    main()
