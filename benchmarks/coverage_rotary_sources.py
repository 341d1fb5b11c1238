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


def _replicate(proc, setup, seed, trials):
    """One row per measurand: (axis, seed, estimator, measurand, value, u, low, high, true)."""
    from mtplan.evaluation.measured import estimate_measured

    truth = proc.display_truth(setup, proc.Truth())
    readings = proc.simulate(setup, proc.Truth(), 1, rng=seed)
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
    args = ap.parse_args(argv)
    proc = get("rotary_axis")
    fields = dict(kv.split("=", 1) for kv in args.set)
    rows = []
    for axis in args.axes:
        setup = proc.setup({**fields, "axis": axis})
        t0 = time.perf_counter()
        for k in range(args.replicates):
            rows += _replicate(proc, setup, 2000 + k, args.trials)
        print(f"axis {axis}: {args.replicates} replicates in {time.perf_counter() - t0:.0f} s "
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
