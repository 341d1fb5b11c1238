"""Speed of the geometry21 procedure (not a test): trials per second and where the time goes.

Run: ``.venv/bin/python benchmarks/bench_geometry21.py [trials]``
"""

from __future__ import annotations

import sys
import time

import numpy as np

from mtplan.models import geometry21 as g21
from mtplan.evaluation.simulation import simulate_uncertainty

P = g21.PROCEDURE


def _time(fn, repeat=3):
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main(trials: int = 2048) -> None:
    setup = g21.Setup()
    n_read = g21._geometry(setup).plane.size * 2
    print(f"geometry21 default set-up: {n_read} readings per trial, block_size {P.block_size}")
    t0 = time.perf_counter()
    g21._joint_ident(setup), g21._patent_design(setup)
    print(f"set-up precomputation (Jacobian, SVD, pseudo-inverses): {time.perf_counter() - t0:.2f} s")
    rng = np.random.default_rng(0)
    t_draw = _time(lambda: rng.standard_normal((trials, n_read)))
    print(f"numpy alone, {trials} x {n_read} normal variates: {t_draw:.3f} s")
    b = P.block_size
    errors = P.draw_errors(setup, b, np.random.SeedSequence(1))
    t_fw = _time(lambda: P.forward(setup, P.Truth(), errors)) / b
    readings = P.forward(setup, P.Truth(), errors)
    for est in P.estimators:
        t_est = _time(lambda: P.estimate(setup, readings, est)) / b
        t = time.perf_counter()
        simulate_uncertainty(P, setup, estimator=est, trials=trials, rng=1, progress=False)
        dt = time.perf_counter() - t
        print(f"{est:>12}: {trials / dt:8.0f} trials/s  ({dt:.2f} s, {dt / t_draw:.0f}x numpy "
              f"drawing); per trial: forward {t_fw * 1e6:.0f} us, estimator {t_est * 1e6:.0f} us")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 2048)
