"""Parallel speed-up of a sweep (not a test; prints figures).

The sweep of issue 18: rotary_axis, 6 incline angles x 3 position counts, 100 000 trials
per set-up, with 1 and with 2 jobs (loky). Prints the wall times, the speed-up and whether
the two tables are bit-identical (they must be: results never depend on n_jobs).

Run on a quiet machine:  .venv/bin/python benchmarks/bench_sweep_parallel.py [--trials 100000]
"""

from __future__ import annotations

import argparse
import time

import pandas as pd

from mtplan.plans.sweep import sweep

VARY = {"incline_deg": [10, 15, 20, 25, 30, 35], "positions": [3, 6, 12]}


def timed(jobs: int, trials: int):
    t0 = time.perf_counter()
    table = sweep("rotary_axis", vary=VARY, trials=trials, n_jobs=jobs, seed=1, progress=False)
    return time.perf_counter() - t0, table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=2, help="best of this many runs per job count")
    args = ap.parse_args()
    print(f"rotary_axis sweep: {len(VARY['incline_deg'])} x {len(VARY['positions'])} set-ups, "
          f"{args.trials} trials each")
    results = {}
    for jobs in (1, 2):
        runs = [timed(jobs, args.trials) for _ in range(args.repeat)]
        results[jobs] = (min(t for t, _ in runs), runs[0][1])
        print(f"  {jobs} job(s): {results[jobs][0]:.2f} s (best of {args.repeat}: "
              + ", ".join(f"{t:.2f}" for t, _ in runs) + ")")
    same = results[1][1].equals(results[2][1])
    pd.testing.assert_frame_equal(results[1][1], results[2][1])
    print(f"  speed-up 2 jobs / 1 job: {results[1][0] / results[2][0]:.2f}x; tables "
          f"{'bit-identical' if same else 'DIFFER'}")


if __name__ == "__main__":
    main()
