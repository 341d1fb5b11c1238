"""Speed of the line_laser procedure's Monte Carlo (not a test; prints figures).

Usage: ``python benchmarks/bench_line_laser.py [trials]`` (default 20 000).

Prints trials per second of :func:`simulate_uncertainty` at the default set-up for
each estimator, the ratio to drawing the same number of normal variates (all the
readings' noise) with numpy alone, and where the time goes (drawing the errors,
forward model, estimator) for one block.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from mtplan.models import line_laser as ll
from mtplan.evaluation.simulation import simulate_uncertainty


def main(trials: int = 20_000) -> None:
    proc, setup = ll.PROCEDURE, ll.Setup()
    per_trial = 3 * setup.lines * setup.points_per_line
    print(f"line_laser default set-up: {per_trial} readings per trial, "
          f"block_size {proc.block_size}")
    t0 = time.perf_counter()
    np.random.default_rng(0).standard_normal((trials, per_trial))
    t_draw = time.perf_counter() - t0
    print(f"numpy normal draws for {trials} trials: {t_draw:.2f} s")
    for est in proc.estimators:
        t0 = time.perf_counter()
        simulate_uncertainty(proc, setup, estimator=est, trials=trials, rng=1, progress=False)
        t = time.perf_counter() - t0
        print(f"{est:>13}: {trials / t:8.0f} trials/s ({t:.1f} s), {t / t_draw:.1f} x the draws")
    n = proc.block_size
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


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 20_000)
