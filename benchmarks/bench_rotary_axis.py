"""Speed of the rotary_axis procedure's Monte Carlo (not a test; prints figures).

For the default C set-up (6 positions x 25 points = 150 readings per trial):

- trials per second of ``simulate_uncertainty`` (patent and joint estimators), with every
  default error source and with the probe noise alone;
- the ratio to drawing, with numpy alone, the same normal variates: one per reading
  (the readings' noise) and all the variates the active sources draw;
- where the time goes: drawing the sources, the forward model, each estimator.

With ``--budget`` (instead of the timings): the tables of docs/rotary_axis.md, for the
C, A and combined CA tests at their defaults, u of each measurand before issue 17 (the
A positions in ascending order) and now (the seed's order), the share of each source
in u^2, and the measuring order against the thermal drift alone.

With ``--angles``: the tables of the ``angles`` estimator in docs/rotary_axis.md: u
with ``gls`` (before) and ``angles`` (after) and the shares under ``angles``, for C, A
and CA; u of both against the stated angular positioning error; and the price of
trusting the encoder: the spread of both when the axis really positions to +-30 arcsec
and the set-up (the weight, the Monte Carlo) says +-5.

Run:  .venv/bin/python benchmarks/bench_rotary_axis.py [--trials 20000] [--repeat 5]
      [--axis C|A|CA] [--budget | --angles]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from mtplan.models import get
from mtplan.uncertainty.streams import as_seed_sequence, block_sequence
from mtplan.evaluation.simulation import linearize_procedure, simulate_uncertainty

from _budget import budget_table, mc_std  # benchmarks/ is the script's folder


def best(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=20_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--axis", default="C")
    ap.add_argument("--budget", action="store_true")
    ap.add_argument("--angles", action="store_true")
    args = ap.parse_args()
    proc = get("rotary_axis")
    if args.budget:
        budget(proc, args.trials)
        return
    if args.angles:
        angles(proc, args.trials)
        return
    setup = proc.setup(axis=args.axis)
    n = args.trials
    P, M = setup.n_positions, setup.n_points
    active = proc.active_sources(setup)
    n_all = sum(s.size for s in active.values()) * n
    rng = np.random.default_rng(0)
    t_noise = best(lambda: rng.standard_normal((n, P, M)), args.repeat)
    t_all = best(lambda: rng.standard_normal(n_all), args.repeat)
    print(f"rotary_axis, axis {args.axis}: {P} positions x {M} points = {P * M} readings/trial, "
          f"{n} trials, block {proc.capabilities.block_size}, best of {args.repeat}")
    print(f"numpy standard_normal, one per reading ({n * P * M:.3g}):   {t_noise * 1e3:8.1f} ms")
    print(f"numpy standard_normal, all source draws ({n_all:.3g}): {t_all * 1e3:8.1f} ms")

    for only, label in ((None, "all default sources"), (["probe_noise"], "probe noise only")):
        for est in proc.estimators:
            t = best(lambda: simulate_uncertainty(proc, setup, estimator=est, sources=only,
                                                  trials=n, rng=1, progress=False), args.repeat)
            base = t_noise if only else t_all
            print(f"simulate_uncertainty {est:7s} {label:20s}: {t * 1e3:8.1f} ms, "
                  f"{n / t:10.0f} trials/s, {t / t_noise:5.2f}x one-per-reading draw"
                  + ("" if only else f", {t / base:5.2f}x all-source draw"))

    # where the time goes, per block of the procedure's block size, scaled to n trials
    b = proc.capabilities.block_size
    seq = block_sequence(as_seed_sequence(1), 0)
    truth = proc.Truth()
    t_draw = best(lambda: proc.draw_errors(setup, b, seq), args.repeat)
    errors = proc.draw_errors(setup, b, seq)
    t_fwd = best(lambda: proc.forward(setup, truth, errors), args.repeat)
    readings = proc.forward(setup, truth, errors)
    scale = n / b
    print(f"per {n} trials (from blocks of {b}): draw sources {t_draw * scale * 1e3:7.1f} ms, "
          f"forward {t_fwd * scale * 1e3:7.1f} ms", end="")
    for est, fn in proc.estimators.items():
        t_est = best(lambda: fn(setup, readings), args.repeat)
        print(f", {est} {t_est * scale * 1e3:7.1f} ms", end="")
    print()


def budget(proc, trials: int) -> None:
    """The docs' tables: u before/after and shares per source; order against drift."""
    for axis in ("C", "A", "CA"):
        setup = proc.setup(axis=axis)
        before = None if axis == "CA" else (setup.replace(a_order="ascending"), None)
        print(f"\naxis {axis}, patent, default set-up; u by Monte Carlo ({trials} trials, "
              "rng 3), shares of u^2 by the GUM budget (linearize) [%]")
        print(budget_table(proc, setup, before, trials))
    print("\nA axis, thermal drift alone, u by the GUM (linearize) [um, urad]")
    for order in ("ascending", "seed"):
        setup = proc.setup(axis="A", a_order=order)
        g = linearize_procedure(proc, setup, sources=["thermal_drift"])
        print(f"  {order:9s} {setup.angles().tolist()}: "
              + ", ".join(f"{n} {u:.3f}" for n, u in zip(g.names, g.std, strict=True)))


def angles(proc, trials: int) -> None:
    """The docs' tables of the angles estimator: gain, its dependence on the encoder, price."""
    for axis in ("C", "A", "CA"):
        setup = proc.setup(axis=axis)
        print(f"\naxis {axis}: u before = gls, after = angles (Monte Carlo, {trials} trials, "
              "rng 3), shares of u^2 under angles (GUM) [%]")
        print(budget_table(proc, setup, mc_std(proc, setup, trials, "gls"), trials, "angles"))
    for axis in ("C", "A"):
        print(f"\naxis {axis}: u against angular_positioning_arcsec (gls | angles)")
        for arcsec in (0.0, 5.0, 20.0, 60.0):
            setup = proc.setup(axis=axis, angular_positioning_arcsec=arcsec)
            u = {e: mc_std(proc, setup, trials, e) for e in ("gls", "angles")}
            print(f"  {arcsec:4g}: " + ", ".join(f"{m} {u['gls'][m]:.3g} | {u['angles'][m]:.3g}"
                                                  for m in u["gls"]))
        stated = proc.setup(axis=axis)
        real = stated.replace(angular_positioning_arcsec=30.0)
        readings = proc.simulate(real, proc.Truth(), trials, rng=3)
        for est in ("gls", "angles"):
            out = proc.display_estimate(stated, readings, est)
            print(f"  axis really +-30 arcsec, set-up +-5, {est}: "
                  + ", ".join(f"{m} {np.std(v):.3g}" for m, v in out.items()))


if __name__ == "__main__":
    main()
