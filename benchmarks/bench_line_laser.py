"""Speed of the line_laser procedure's Monte Carlo (not a test; prints figures).

Usage: ``python benchmarks/bench_line_laser.py [trials] [--budget [--budget-trials N]
[--estimators NAME ...]]``
(default 20 000 trials).

Prints trials per second of :func:`simulate_uncertainty` at the default set-up for
each estimator, the ratio to drawing the same number of normal variates (all the
readings' noise) with numpy alone, and where the time goes (drawing the errors,
forward model, estimator) for one block.

With ``--budget`` (instead of the timings): the tables of docs/line_laser.md, per
estimator: u of each measurand with the error sources before issue 17 at the former
default scan (40 lines, beta 0.6) and at the default set-up, with all sources, and the
share of each source in u^2 from the Monte Carlo, each source alone (the patent's whole
rows and arccos are far from linear; about 5 min at 2000 trials). For ``pattern`` u
before is with the pattern taken as exact (``facet_position_um = 0``, issue 13).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from mtplan.models import line_laser as ll
from mtplan.evaluation.simulation import simulate_uncertainty

from _budget import budget_table, mc_std  # benchmarks/ is the script's folder

#: the sources issue 17 added
NEW = ("linearity", "z_scale", "squareness_xy", "squareness_zy", "drift")
#: the source issue 13 added (the pattern estimator's view of the artifact)
ISSUE13 = ("facet_position",)


def main(trials: int = 20_000) -> None:
    proc, setup = ll.PROCEDURE, ll.Setup()
    per_trial = 3 * setup.lines * setup.points_per_line
    print(f"line_laser default set-up: {per_trial} readings per trial, "
          f"block_size {proc.capabilities.block_size}")
    t0 = time.perf_counter()
    np.random.default_rng(0).standard_normal((trials, per_trial))
    t_draw = time.perf_counter() - t0
    print(f"numpy normal draws for {trials} trials: {t_draw:.2f} s")
    for est in proc.estimators:
        t0 = time.perf_counter()
        simulate_uncertainty(proc, setup, estimator=est, trials=trials, rng=1, progress=False)
        t = time.perf_counter() - t0
        print(f"{est:>13}: {trials / t:8.0f} trials/s ({t:.1f} s), {t / t_draw:.1f} x the draws")
    n = proc.capabilities.block_size
    seq = np.random.SeedSequence(1)
    t0 = time.perf_counter()
    errors = proc.draw_errors(setup, n, seq)
    t1 = time.perf_counter()
    readings = proc.forward(setup, proc.Truth(), errors)
    t2 = time.perf_counter()
    times = {}
    for est, fn in proc.estimators.items():
        s = time.perf_counter()
        fn(setup, readings)
        times[est] = time.perf_counter() - s
    print(f"one block of {n}: draw {1e3 * (t1 - t0) / n:.3f} ms/trial, forward "
          f"{1e3 * (t2 - t1) / n:.3f} ms/trial, "
          + ", ".join(f"{k} {1e3 * v / n:.3f} ms/trial" for k, v in times.items()))


def budget(trials: int, estimators=None) -> None:
    """The docs' tables (see the module docstring)."""
    proc, setup = ll.PROCEDURE, ll.Setup()
    old = [s for s in proc.active_sources(setup) if s not in NEW + ISSUE13]
    former = setup.replace(lines=40, shift_fraction=0.6)
    for est in estimators or proc.estimators:
        if est == "pattern":  # issue 13: u before: the pattern taken as exact
            exact = setup.replace(facet_position_um=0.0)
            print(f"\n{est}, default set-up; u before: facet_position_um = 0 (the pattern "
                  f"exact, in the data and the fit's weight); u by Monte Carlo ({trials} "
                  "trials, rng 3), shares of u^2 by the Monte Carlo, each source alone [%]")
            print(budget_table(proc, setup, (exact, list(proc.active_sources(exact))), trials,
                               est, shares="mc"))
            continue
        u_former = mc_std(proc, former, trials, est, old)
        print(f"\n{est}: u at the former default scan, former sources: "
              + ", ".join(f"{k} {v:.3g}" for k, v in u_former.items()))
        print(f"{est}, default set-up; u by Monte Carlo ({trials} trials, rng 3), shares of "
              "u^2 by the Monte Carlo, each source alone [%]")
        print(budget_table(proc, setup, (setup, old), trials, est, shares="mc"))


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("trials", type=int, nargs="?", default=20_000)
    ap.add_argument("--budget", action="store_true")
    ap.add_argument("--budget-trials", type=int, default=2000)
    ap.add_argument("--estimators", nargs="*", help="budget only these (default: all)")
    args = ap.parse_args()
    if args.budget:
        budget(args.budget_trials, args.estimators)
    else:
        main(args.trials)
