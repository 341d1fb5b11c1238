"""The `mc` bias correction's uncertainty and the results' covariance on the example readings.

Per procedure (the shipped example readings, the default set-up and estimator): the `mc`
evaluation with and without the correction's truth draws (wall time of each, the largest
share of the correction's u in u), and the largest difference between the correlations of
the measurands from the posterior's samples and from the `mc` covariance, with the Monte
Carlo standard error of that difference ((1 - rho^2) / sqrt(n), n the posterior's smallest
effective sample size and the `mc` trials).

    .venv/bin/python benchmarks/bench_covariance.py [PROC ...] [--trials N]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))


def main(argv=None) -> int:
    import numpy as np

    from mtplan.evaluation import correction
    from mtplan.evaluation.covariance import correlation
    from mtplan.evaluation.measured import best_estimator, estimate_measured, read_readings
    from mtplan.models import registry

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("procedures", nargs="*", default=sorted(registry()))
    ap.add_argument("--trials", type=int, default=4000)
    args = ap.parse_args(argv)
    print("procedure | estimator | mc s (no draws) | mc s | max u_c/u | max |d rho| | "
          "its MC s.e. | pair")
    for name in args.procedures:
        proc = registry()[name]
        setup = proc.Setup()
        readings = read_readings(proc, setup, ROOT / "examples" / f"{name}_readings.csv")
        best_estimator(proc, setup)  # the default estimator's pilot, once, outside the timing
        times = []
        for draws in (0, None):
            correction._CACHE.clear()  # each pays the readings' least squares
            t = time.perf_counter()
            mc = estimate_measured(proc, setup, readings, trials=args.trials, rng=1,
                                   nuisance_draws=draws)
            times.append(time.perf_counter() - t)
        t0, t1 = times
        post = estimate_measured(proc, setup, readings, uncertainty="posterior", rng=0)
        names = [m.name for m in mc.measurands]
        r_mc, r_post = correlation(mc.covariance), correlation(post.covariance)
        diff = np.abs(r_mc - r_post)
        i, j = np.unravel_index(np.nanargmax(diff), diff.shape)
        ess = min(post.details.ess[n] for n in names)
        se = math.hypot((1 - r_post[i, j] ** 2) / math.sqrt(ess),
                        (1 - r_mc[i, j] ** 2) / math.sqrt(args.trials))
        share = np.nanmax(mc.bias_correction_u / mc.std)
        print(f"{name} | {mc.estimator} | {t0:.1f} | {t1:.1f} | {share:.3f} | "
              f"{diff[i, j]:.3f} | {se:.3f} | {names[i]}-{names[j]} "
              f"({r_post[i, j]:+.3f} vs {r_mc[i, j]:+.3f})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
