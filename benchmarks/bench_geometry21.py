"""Speed of the geometry21 procedure (not a test): trials per second and where the time goes.

Run: ``.venv/bin/python benchmarks/bench_geometry21.py [trials]``; with ``--budget``
instead, the docs' table of EBX, ECX and EAY before and after the error sources of a real
test (``.venv/bin/python benchmarks/bench_geometry21.py --budget [trials]``).

Times every estimator's Monte Carlo at the default set-up (every error source on), the
former ``joint`` (chord Gauss-Newton with the exact model evaluated for every trial in
every iteration, kept as ``_theta_joint_per_trial``) in the same run for the speed-up of
the batch-shared linearisation, and ``joint`` at the all-21 set-up of
``examples/geometry21_all21.toml``.
"""

from __future__ import annotations

import dataclasses
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

from mtplan.evaluation.simulation import simulate_uncertainty
from mtplan.models import geometry21 as g21

P = g21.PROCEDURE
ALL21 = Path(__file__).resolve().parents[1] / "examples" / "geometry21_all21.toml"


def _time(fn, repeat=3):
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def _former_joint(setup, readings):
    """The joint estimator before the batch-shared linearisation."""
    return g21.measure(setup, g21.theta_joint_per_trial(setup, readings))


def _rate(proc, setup, est, trials, truth=None):
    t = time.perf_counter()
    simulate_uncertainty(proc, setup, truth, estimator=est, trials=trials, rng=1, progress=False)
    dt = time.perf_counter() - t
    return trials / dt, dt


def main(trials: int = 2048) -> None:
    proc = dataclasses.replace(P, estimators={**P.estimators, "joint_former": _former_joint})
    setup = g21.Setup()
    n_read = g21.geometry(setup).plane.size * 2
    print(f"geometry21 default set-up: {n_read} readings per trial, "
          f"block_size {P.capabilities.block_size}, "
          f"sources: {', '.join(P.active_sources(setup))}")
    t0 = time.perf_counter()
    g21.joint_ident(setup), g21.patent_design(setup)
    print(f"set-up precomputation (Jacobian, SVD, pseudo-inverses): {time.perf_counter() - t0:.2f} s")
    rng = np.random.default_rng(0)
    t_draw = _time(lambda: rng.standard_normal((trials, n_read)))
    print(f"numpy alone, {trials} x {n_read} normal variates: {t_draw:.3f} s")
    b = P.capabilities.block_size
    errors = P.draw_errors(setup, b, np.random.SeedSequence(1))
    t_fw = _time(lambda: P.forward(setup, P.Truth(), errors)) / b
    readings = P.forward(setup, P.Truth(), errors)
    rates = {}
    for est in proc.estimators:
        t_est = _time(lambda: proc.estimate(setup, readings, est)) / b
        rates[est], dt = _rate(proc, setup, est, trials)
        print(f"{est:>13}: {rates[est]:8.0f} trials/s  ({dt:.2f} s, {dt / t_draw:.0f}x numpy "
              f"drawing); per trial: forward {t_fw * 1e6:.0f} us, estimator {t_est * 1e6:.0f} us")
    print(f"joint speed-up over the former joint (same run): "
          f"{rates['joint'] / rates['joint_former']:.1f}x")
    with open(ALL21, "rb") as fh:
        cfg = tomllib.load(fh)
    all21 = P.setup(cfg["setup"])
    truth = P.truth(cfg["truth"])
    m = g21.geometry(all21).plane.size * 2
    rate, dt = _rate(P, all21, "joint", trials, truth)
    print(f"all-21 set-up ({ALL21.name}: {m} readings per trial, "
          f"{len(P.measurands(all21))} measurands): joint {rate:.0f} trials/s ({dt:.2f} s)")


#: the error sources before issue 16 (a plate test without the machine's own behaviour)
BEFORE = ("encoder_noise", "grid_error", "plate_offset", "plate_tilt")


def budget(trials: int = 4000) -> None:
    """Markdown: u of EBX, ECX, EAY at the default set-up with the sources before issue 16
    and with every source (Monte Carlo, seed 1), and each source's share of u^2 (the
    first-order budget, ``mtplan linearize``'s)."""
    from mtplan.evaluation.first_order import first_order

    setup = g21.Setup()
    names = ("EBX", "ECX", "EAY")
    print("| estimator | measurand | u before [urad] | u after [urad] | largest sources "
          "(share of u^2) |")
    print("|---|---|---:|---:|---|")
    for est in ("patent", "joint"):
        runs = [simulate_uncertainty(P, setup, estimator=est, sources=src, trials=trials, rng=1,
                                     progress=False) for src in (BEFORE, None)]
        shares = first_order(P, setup, estimator=est).budget()
        for n in names:
            u = [r.mc.std[[m.name for m in r.measurands].index(n)] for r in runs]
            top = shares[shares.output == n].sort_values("share", ascending=False).head(3)
            text = ", ".join(f"{r.input} {100 * r.share:.0f} %" for r in top.itertuples())
            print(f"| {est} | {n} | {u[0]:.2f} | {u[1]:.2f} | {text} |")


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--budget"]
    n = int(args[0]) if args else None
    if "--budget" in sys.argv[1:]:
        budget(n or 4000)
    else:
        main(n or 2048)
