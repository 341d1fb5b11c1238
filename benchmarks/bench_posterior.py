"""Wall time of the emcee posterior for default readings, on one core.

Prints, per procedure (toy_line and every registered one that is asked for): the
number of free parameters, walkers x ensembles x steps, the largest tau, R-hat, the
smallest ESS, whether it converged, the wall time, and whether the forward model
took all walkers in one call (batched) or per walker.

    .venv/bin/python benchmarks/bench_posterior.py [PROC ...] [--max-steps N]

Goal (issue 9): the default rotary_axis readings converge in under 30 s on one core.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None):
    from mtplan.models import registry
    from mtplan.evaluation.posterior import NotConvergedError, sample_posterior
    from tests.models import toy_line

    ap = argparse.ArgumentParser()
    ap.add_argument("procedures", nargs="*", default=["toy_line", "rotary_axis"])
    ap.add_argument("--max-steps", type=int, default=20000)
    ap.add_argument("--noise", choices=["free", "setup"], default="free")
    args = ap.parse_args(argv)
    procs = {"toy_line": toy_line.PROCEDURE, **registry()}
    for name in args.procedures:
        if name not in procs:
            print(f"{name}: not registered, skipped")
            continue
        proc = procs[name]
        setup = proc.Setup()
        readings = proc.simulate(setup, proc.Truth(), 1, rng=2024)
        noise = None if args.noise == "free" else "setup"
        t0 = time.perf_counter()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                r = sample_posterior(proc, setup, readings, rng=0, noise=noise,
                                     max_steps=args.max_steps)
        except NotConvergedError as exc:
            r = exc.value.result if hasattr(exc, "value") else exc.result
        wall = time.perf_counter() - t0
        print(f"{name}: {len(r.parameters)} parameters, {r.chains.shape[0]} ensembles x "
              f"{r.n_walkers} walkers x {r.n_steps} steps, tau max {max(r.tau.values()):.1f}, "
              f"R-hat max {max(r.rhat.values()):.4f}, ESS min {min(r.ess.values()):.0f}, "
              f"{'converged' if r.converged else 'NOT converged'}, {wall:.1f} s")


if __name__ == "__main__":
    main()
