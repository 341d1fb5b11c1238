"""Closed loop of the compensation: known machine, simulated test, estimate, correction, the
true residual after it, and whether the predicted 95 % interval covers it.

For each procedure, `--machines` simulated machines (seeds 5000, 5001, ...). Each machine's
true measurands are its procedure's default truth moved by a random amount (normal, the
size of `--spread` times each measurand's u at the default set-up, through the procedure's
``truth_from_estimate``; geometry21 and line_laser, whose truths have no such hook for
every field, keep their default truth and differ by their error sources' draws only). A
test of it is simulated with every default error source, evaluated as measured data the
way ``mtplan estimate`` does (``estimate_measured``, default estimator, its first-order u
validated by a short Monte Carlo), turned into a correction (``mtplan.compensation``,
with the procedure's controller format: its rounding is in the residual), and the true
residual ``true - written`` is compared with the predicted 95 % interval of every term.
The truth is what the machine really has: the measurand's true value plus what the test
cannot see of it as this simulated test drew it (the correction model's ``realised``:
geometry21's short-wave path residual and medium wave at each table point, the same fields
its readings saw).

Coverage is reported per procedure, pooled over the terms with its binomial standard error,
and for each scalar term and each table point over the machines (its lowest and highest).
The goal: 92-98 %, pooled and per point.

    .venv/bin/python benchmarks/bench_compensation_closed_loop.py [--machines 200] [--first 0]
        [--procedures circle_centre rotary_axis ...] [--jobs 2] [--out closed_loop.csv]

Not a test: 2-20 s per machine on one core, depending on the procedure.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
import warnings
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

#: the format each procedure's correction is written in, and set-up fields of the test
PLAN = {
    "circle_centre": ("fanuc-g10", {}),
    "rotary_axis": ("isg-csv", {}),
    "tracker_frame": ("siemens-frame", {}),
    "line_laser": ("neutral", {}),
    "geometry21": ("isg-csv", {"along_x_mm": "-50,-25,25,50", "along_y_mm": "-50,-25,25,50",
                               "along_z_mm": "-50,-25,25,50"}),
}


def _truth(proc, setup, rng, spread):
    """The machine's truth: the default moved by `spread` x each measurand's scale."""
    truth = proc.Truth()
    if not proc.capabilities.builds_truths or proc.name in ("geometry21", "line_laser"):
        return truth
    base = proc.true_values(setup, truth)
    moved = {m.name: base[m.name] + spread * rng.normal() * (
        1e-3 if m.unit == "um" else 1e-5) for m in proc.measurands(setup)}
    return proc.capabilities.truth_from_estimate(setup, moved)


def _machine(name, seed, spread):
    """Rows (procedure, seed, term, covered, true residual, low, high) of one machine."""
    import numpy as np

    from mtplan import models
    from mtplan.compensation import compensate
    from mtplan.evaluation.measured import estimate_measured
    from mtplan.uncertainty.streams import as_seed_sequence, block_sequence

    proc = models.get(name)
    fmt, fields = PLAN[name]
    setup = proc.setup(fields)
    truth = _truth(proc, setup, np.random.default_rng(seed), spread)
    # the draws `proc.simulate(setup, truth, 1, rng=seed)` makes, kept: what the test cannot
    # see of them (the procedure's correction model, ``realised``) is part of the machine
    errors = proc.draw_errors(setup, 1, block_sequence(as_seed_sequence(seed), 0))
    readings = proc.forward(setup, truth, errors)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = estimate_measured(proc, setup, readings, rng=seed + 10_000)
    doc = result.to_dict()
    doc["file"] = f"machine-{seed}"
    _files, corr, res = compensate(doc, fmt)
    true = proc.display_truth(setup, truth)
    for m, value in proc.correction.realised(setup, errors).items():
        if m in true:  # a function the test does not determine is not corrected
            true[m] = true[m] + float(np.asarray(value).ravel()[0])
    rows = []
    model_terms = {t.name: t for t in proc.correction.terms(doc["setup"], tuple(true))}
    for i, term in enumerate(corr.names):
        weights = model_terms[term].weights
        true_term = sum(w * true[m] for m, w in weights.items())
        written = corr.value[i] - res.shift[i]
        r = true_term - written
        rows.append((name, seed, term, bool(res.low[i] <= r <= res.high[i]), r, res.low[i],
                     res.high[i], bool(corr.arguments[i])))
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--machines", type=int, default=200)
    parser.add_argument("--first", type=int, default=0,
                        help="the first machine's number (seed 5000 + it): run in chunks")
    parser.add_argument("--procedures", nargs="+", default=list(PLAN), choices=list(PLAN))
    parser.add_argument("--spread", type=float, default=3.0,
                        help="the machines' spread in units of 1 um or 10 urad (default 3)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", help="write every term's row (CSV)")
    args = parser.parse_args(argv)

    import numpy as np
    import pandas as pd
    from joblib import Parallel, delayed

    frames = []
    for name in args.procedures:
        t0 = time.perf_counter()
        runs = Parallel(n_jobs=args.jobs)(delayed(_machine)(name, 5000 + i, args.spread)
                                          for i in range(args.first,
                                                         args.first + args.machines))
        df = pd.DataFrame([r for rows in runs for r in rows],
                          columns=["procedure", "seed", "term", "covered", "residual", "low",
                                   "high", "table"])
        frames.append(df)
        share = df["covered"].mean()
        se = math.sqrt(share * (1 - share) / len(df))
        scalar = df[~df["table"]]
        line = (f"{name}: {len(df)} terms of {args.machines} machines, covered "
                f"{100 * share:.1f} % (+-{100 * se:.1f})")
        if len(scalar):
            per_term = scalar.groupby("term")["covered"].mean()
            line += (f"; each scalar term over the machines {100 * per_term.min():.1f}-"
                     f"{100 * per_term.max():.1f} %")
        tables = df[df["table"]]
        if len(tables):
            per_point = tables.groupby("term")["covered"].mean()
            line += (f"; table points {100 * tables['covered'].mean():.1f} % (each point "
                     f"over the machines {100 * per_point.min():.1f}-"
                     f"{100 * per_point.max():.1f} %)")
        print(line + f" ({time.perf_counter() - t0:.0f} s)", flush=True)
    if args.out:
        pd.concat(frames).to_csv(args.out, index=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
