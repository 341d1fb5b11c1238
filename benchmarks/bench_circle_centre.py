"""Speed of the circle_centre procedure (a benchmark that prints figures; not a test).

1. ``simulate_uncertainty`` at the default set-up, 20 000 trials, for each estimator,
   against drawing the same number of normal variates (every reading's noise: probe
   noise and stage repeatability of all contacts) with numpy alone.
2. Where the time goes: drawing the sources, the forward model (probing p1, p2,
   planning, probing d1..dn) and each estimator, on one block of 20 000 trials.
3. The same for 12 points.

With ``--budget`` (instead of the timings): the tables of docs/circle_centre.md, u of each
measurand before and after the sources issue 17 added (tip radius, bore temperature) and
the share of each source in u^2 (GUM budget), and u of the centre against the number of
points (three_point for 3, geometric for more).

Run: ``.venv/bin/python benchmarks/bench_circle_centre.py [--budget [--trials N]]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from mtplan.models import get
from mtplan.uncertainty.streams import as_seed_sequence, block_sequence
from mtplan.evaluation.simulation import simulate_uncertainty

from _budget import budget_table, mc_std  # benchmarks/ is the script's folder

TRIALS = 20_000


def best(fn, repeat=5):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def run(n_points: int) -> None:
    proc = get("circle_centre")
    setup = proc.setup(n_points=n_points)
    srcs = proc.sources(setup)
    n_normal = TRIALS * (srcs["probe_noise"].size + srcs["stage_repeatability"].size)
    rng = np.random.default_rng(1)
    t_bare = best(lambda: rng.standard_normal(n_normal))
    print(f"--- n_points = {n_points}: {n_points + 2} contacts per trial")
    print(f"numpy alone, {n_normal:.2e} normal variates: {t_bare * 1e3:8.1f} ms")
    for est in proc.estimators:
        t = best(lambda: simulate_uncertainty(proc, setup, estimator=est, trials=TRIALS, rng=1,
                                              progress=False), repeat=3)
        print(f"simulate_uncertainty {est:11s} {TRIALS} trials: {t * 1e3:8.1f} ms "
              f"= {TRIALS / t:9.0f} trials/s, ratio to numpy alone {t / t_bare:6.1f}")
    seq = block_sequence(as_seed_sequence(1), 0)
    t_draw = best(lambda: proc.draw_errors(setup, TRIALS, seq))
    errors = proc.draw_errors(setup, TRIALS, seq)
    t_fwd = best(lambda: proc.forward(setup, proc.Truth(), errors))
    readings = proc.forward(setup, proc.Truth(), errors)
    print(f"  draw sources {t_draw * 1e3:7.1f} ms, forward {t_fwd * 1e3:7.1f} ms", end="")
    for est, fn in proc.estimators.items():
        t_est = best(lambda: fn(setup, readings))
        print(f", {est} {t_est * 1e3:6.1f} ms", end="")
    print()


def budget(trials: int) -> None:
    """The docs' tables (see the module docstring)."""
    proc = get("circle_centre")
    setup = proc.Setup()
    old = [s for s in proc.active_sources(setup)
           if s != "tip_radius" and "temperature" not in s and "expansion" not in s]
    print(f"three_point, default set-up; u by Monte Carlo ({trials} trials, rng 3), shares of "
          "u^2 by the GUM budget (linearize) [%]")
    print(budget_table(proc, setup, (setup, old), trials, "three_point"))
    print(f"\nu against the number of points, all sources ({trials} trials, rng 3) [um]")
    print("| points | estimator | u(centre_x) | u(centre_y) | u(radius) | duration s |")
    print("|---:|---|---:|---:|---:|---:|")
    for n in (3, 4, 5, 6, 8):
        s = proc.setup(n_points=n)
        est = "three_point" if n == 3 else "geometric"
        u = mc_std(proc, s, trials, est)
        print(f"| {n} | {est} | {u['centre_x']:.2f} | {u['centre_y']:.2f} | "
              f"{u['radius']:.2f} | {proc.duration(s):.0f} |")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", action="store_true")
    ap.add_argument("--trials", type=int, default=20_000)
    args = ap.parse_args()
    if args.budget:
        budget(args.trials)
    else:
        run(3)
        run(12)
