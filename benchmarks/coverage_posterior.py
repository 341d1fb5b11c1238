"""Coverage study: do the 95 % intervals of `mc` and `posterior` cover the truth?

For each procedure asked for (default rotary_axis and circle_centre), `--replicates`
simulated measurements at the default set-up and truth with every default error source
on (seeds 1000, 1001, ...); each is evaluated as measured data by
``estimate_measured(..., uncertainty="mc")`` and ``(..., uncertainty="posterior")``, and
the fraction of intervals that contain the true value is counted, per measurand and
pooled, with its binomial standard error (replicates are independent; the measurands
of one replicate are not, so the pooled error is a lower bound). Goal (issue 13): both
methods cover in 92-98 % of replicates.

    .venv/bin/python benchmarks/coverage_posterior.py [PROC ...] [--replicates 100]
        [--trials 4000] [--out coverage.csv]

Not a test: it takes minutes (about 5 s per replicate and procedure on one core).
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


def _one(proc, setup, seed, trials):
    """(measurand, method, low, high, value, u, true) rows of one replicate."""
    from mtplan.evaluation.measured import estimate_measured

    truth = proc.display_truth(setup, proc.Truth())
    readings = proc.simulate(setup, proc.Truth(), 1, rng=seed)
    rows = []
    for method in ("mc", "posterior"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = estimate_measured(proc, setup, readings, uncertainty=method, trials=trials,
                                    rng=seed, allow_unconverged=True)
        for i, m in enumerate(res.measurands):
            rows.append({"procedure": proc.name, "seed": seed, "measurand": m.name,
                         "method": method, "low": res.low[i], "high": res.high[i],
                         "value": res.value[i], "u": res.std[i], "true": truth[m.name],
                         "converged": getattr(res.details, "converged", True)})
    return rows


def main(argv=None):
    import numpy as np
    import pandas as pd

    from mtplan.models import get

    ap = argparse.ArgumentParser()
    ap.add_argument("procedures", nargs="*", default=["rotary_axis", "circle_centre"])
    ap.add_argument("--replicates", type=int, default=100)
    ap.add_argument("--trials", type=int, default=4000, help="mc trials per replicate")
    ap.add_argument("--out", help="write every interval to this CSV")
    args = ap.parse_args(argv)
    frames = []
    for name in args.procedures:
        proc = get(name)
        setup = proc.Setup()
        t0 = time.perf_counter()
        rows = []
        for k in range(args.replicates):
            rows += _one(proc, setup, 1000 + k, args.trials)
        df = pd.DataFrame(rows)
        df["covered"] = (df["low"] <= df["true"]) & (df["true"] <= df["high"])
        frames.append(df)
        wall = time.perf_counter() - t0
        print(f"{name}: {args.replicates} replicates in {wall:.0f} s "
              f"({wall / args.replicates:.1f} s each, mc and posterior)")
        table = df.groupby(["method", "measurand"], sort=False)["covered"].agg(["mean", "size"])
        for (method, measurand), r in table.iterrows():
            se = math.sqrt(max(r["mean"] * (1 - r["mean"]), 1e-12) / r["size"])
            print(f"  {method:9s} {measurand:14s} coverage {100 * r['mean']:5.1f} % "
                  f"+- {100 * se:.1f} (n = {int(r['size'])})")
        for method, g in df.groupby("method", sort=False):
            p, n = g["covered"].mean(), len(g)
            ratio = g.pivot(index="seed", columns="measurand", values="u")
            print(f"  {method:9s} pooled         coverage {100 * p:5.1f} % "
                  f"+- {100 * math.sqrt(p * (1 - p) / n):.1f} (n = {n}); "
                  f"unconverged: {int((~g['converged']).sum())}")
            if method == "posterior":
                mc = df[df.method == "mc"].pivot(index="seed", columns="measurand", values="u")
                print("  median u(posterior)/u(mc): " + ", ".join(
                    f"{c} {np.median(ratio[c] / mc[c]):.2f}" for c in ratio.columns))
    if args.out:
        pd.concat(frames).to_csv(args.out, index=False)


if __name__ == "__main__":
    main()
