"""Wall time of the emcee posterior on each procedure's example readings, on one core.

Prints, per procedure: the sampled parameters, walkers x ensembles x steps, the largest
tau, R-hat, the smallest ESS, whether it converged, whether the walkers went through
the forward model in one call (batched) or one by one, the wall time, and (with
``--budget``) what became of every error source of the set-up. Then the posterior u of
every measurand against the ``mc`` one (``--compare``, the best estimator, 4000 trials).

    .venv/bin/python benchmarks/bench_posterior.py [PROC ...] [--budget] [--compare]

The readings are the shipped examples (``examples/PROC_readings.csv``, the set-up's
defaults) and, for ``toy_line``, simulated ones. Goal (issue 13): every default-example
posterior under 30 s on one core; ``estimate circle_centre ... --noise free`` refused
in under 2 s (timed last).
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
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))


def _readings(proc, setup):
    from mtplan.evaluation.measured import read_readings

    path = ROOT / "examples" / f"{proc.name}_readings.csv"
    if path.exists():
        return read_readings(proc, setup, path), path.name
    return proc.simulate(setup, proc.Truth(), 1, rng=2024), "simulated (seed 2024)"


def _compare(proc, setup, readings, post):
    from mtplan.evaluation.measured import estimate_measured

    mc = estimate_measured(proc, setup, readings, uncertainty="mc", trials=4000, rng=1)
    print(f"  u(posterior) / u(mc, {mc.estimator}):")
    for i, m in enumerate(post.measurands):
        ratio = post.std[m.name] / mc.std[i]
        diff = (post.mean[m.name] - mc.value[i]) / mc.std[i]
        print(f"    {m.name:14s} {post.std[m.name]:10.4g} / {mc.std[i]:<10.4g} = {ratio:5.2f}; "
              f"mean - mc value = {diff:+.2f} u(mc)")


def main(argv=None):
    from mtplan.evaluation.posterior import NotConvergedError, sample_posterior
    from mtplan.models import registry
    from mtplan.testing import template as toy_line

    ap = argparse.ArgumentParser()
    ap.add_argument("procedures", nargs="*",
                    default=["toy_line", "rotary_axis", "circle_centre", "line_laser",
                             "geometry21", "tracker_frame"])
    ap.add_argument("--max-steps", type=int, default=20000)
    ap.add_argument("--budget", action="store_true", help="print what became of each source")
    ap.add_argument("--compare", action="store_true", help="posterior u against the mc one")
    args = ap.parse_args(argv)
    procs = {"toy_line": toy_line.PROCEDURE, **registry()}
    for name in args.procedures:
        proc = procs[name]
        setup = proc.Setup()
        readings, source = _readings(proc, setup)
        t0 = time.perf_counter()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                r = sample_posterior(proc, setup, readings, rng=0, max_steps=args.max_steps,
                                     progress=False)
        except NotConvergedError as exc:
            r = exc.result
        wall = time.perf_counter() - t0
        print(f"{name} ({source}): {len(r.parameters)} parameters, {r.chains.shape[0]} "
              f"ensembles x {r.n_walkers} walkers x {r.n_steps} steps, tau max "
              f"{max(r.tau.values()):.1f}, R-hat max {max(r.rhat.values()):.4f}, ESS min "
              f"{min(r.ess.values()):.0f}, {'converged' if r.converged else 'NOT converged'}, "
              f"{wall:.1f} s")
        for note in r.notes:
            print(f"  note: {note}")
        if args.budget:
            for src, how in r.budget.items():
                print(f"  {src:24s} {how}")
        if args.compare:
            _compare(proc, setup, readings, r)
    if "circle_centre" in args.procedures:
        from mtplan import cli

        t0 = time.perf_counter()
        code = cli.main(["estimate", "circle_centre", str(ROOT / "examples" /
                                                          "circle_centre_readings.csv"),
                         "--uncertainty", "posterior", "--noise", "free"])
        print(f"circle_centre --noise free: exit {code} in {time.perf_counter() - t0:.2f} s")


if __name__ == "__main__":
    main()
