"""Is the coverage printed beside each U of the demo the Monte Carlo's coverage of that ± U,
within 1 %? (docs/uncertainty.md, "The coverage of U").

The demo's plan prints, for each test, every measurand's U of the recommended estimator
with "±U covers" (``results/PROC_k_uncertainty.csv``: ``value``, ``U``, ``U_coverage`` and
its standard error ``U_coverage_se``). This script counts, plainly and without any control
variate, the fraction of `TRIALS` new Monte Carlo values of the same set-up, truth and
estimator (another seed) within the printed ``value ± U``, and prints per measurand the
printed coverage, the count, their difference and whether it is within 1 %, then the
largest difference per test.

The measured results the report prints (``results/measured.csv``) are checked the same way
where they come from a Monte Carlo around the estimate: the readings are evaluated again as
the study does, with `TRIALS` trials and another seed, and the fraction of that Monte
Carlo's estimates ``y_t`` within ``true + estimate - value ± U`` (its trial t gives the
value ``estimate - (y_t - true)``) is counted plainly for the printed value and U. A
posterior's coverage is its samples' own (not checked here).

Usage: ``python benchmarks/bench_coverage_demo.py [DEMO_FOLDER] [--trials N] [--jobs J]
[--measured-only]``
(DEMO_FOLDER: the output of ``mtplan demo --out DEMO_FOLDER``; made in a temporary folder
when left out. N default 20 000: the count's own standard error at 95 % is 0.15 %; the
line_laser pattern fit takes about 10 ms a trial, so some 4 minutes on two cores).
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from mtplan.cli import main as cli
from mtplan.cli.report import demo_study_path
from mtplan.evaluation import measured
from mtplan.evaluation.simulation import simulate_uncertainty
from mtplan.models.fields import with_conditions
from mtplan.plans.study import load_study
from mtplan.plans.study.runner import _along_setup


def _recommended(folder: Path, k: int) -> str:
    """The estimator of test k whose table the plan prints (results/summary.csv)."""
    summary = pd.read_csv(folder / "results" / "summary.csv")
    return str(summary.loc[summary["section"] == k, "estimator"].mode().iloc[0])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", nargs="?", type=Path)
    ap.add_argument("--trials", type=int, default=20_000)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--measured-only", action="store_true",
                    help="only the measured results (results/measured.csv)")
    args = ap.parse_args()
    folder = args.folder
    if folder is None:
        folder = Path(tempfile.mkdtemp()) / "demo"
        assert cli(["demo", "--out", str(folder), "--jobs", str(args.jobs), "--no-cache"]) == 0
    study = load_study(demo_study_path())
    worst = []
    for k, ps in enumerate([] if args.measured_only else study.procedures, start=1):
        est = _recommended(folder, k)
        csv = pd.read_csv(folder / "results" / f"{ps.name}_{k}_uncertainty.csv")
        csv = csv[(csv["estimator"] == est) & (csv["u"] > 0)].set_index("measurand")
        start = time.perf_counter()
        r = simulate_uncertainty(ps.procedure, ps.setup, ps.truth, estimator=est,
                                 trials=args.trials, rng=study.seed + 1000, n_jobs=args.jobs,
                                 progress=False)
        seconds = time.perf_counter() - start
        print(f"\n{ps.name} ({est}, printed from {int(csv['trials'].iloc[0])} trials; "
              f"counted in {args.trials} trials, {seconds:.0f} s)")
        print(f"  {'measurand':12s} {'printed':>8s} {'+-se':>6s} {'count':>8s} {'+-se':>6s} "
              f"{'diff':>7s}  within 1 %")
        diffs = []
        for name, row in csv.iterrows():
            y = r.mc.samples(name)
            p = float(np.mean(np.abs(y - row["value"]) <= row["U"]))
            se = math.sqrt(p * (1 - p) / y.size)
            d = row["U_coverage"] - p
            diffs.append(abs(d))
            print(f"  {name:12s} {100 * row['U_coverage']:7.2f}% {100 * row['U_coverage_se']:5.2f}% "
                  f"{100 * p:7.2f}% {100 * se:5.2f}% {100 * d:+6.2f}%  "
                  f"{'yes' if abs(d) <= 0.01 else 'NO'}")
        worst.append((ps.name, max(diffs)))
    if worst:
        print("\nlargest |printed - count| per test: "
              + ", ".join(f"{n} {100 * w:.2f} %" for n, w in worst))
    worst_m = _measured(folder, study, args)
    print("largest |printed - count| per measured test: "
          + ", ".join(f"{n} {100 * w:.2f} %" for n, w in worst_m))
    return 0 if all(w <= 0.01 for _, w in worst + worst_m) else 1


def _measured(folder: Path, study, args) -> list:
    """The measured results' printed coverage against a plain count (module notes)."""
    printed = pd.read_csv(folder / "results" / "measured.csv")
    printed = printed[(printed["state"] == "as found") & printed["determinable"]]
    worst = []
    for ps in study.procedures:
        spec = ps.readings
        rows = printed[printed["procedure"] == ps.name].set_index("measurand")
        if spec is None or rows.empty or spec.get("uncertainty", "mc") != "mc":
            continue
        proc = ps.procedure
        setup = with_conditions(_along_setup(proc, ps.setup, spec), study.conditions)
        readings = measured.read_readings(proc, setup, spec["file"])
        start = time.perf_counter()
        res = measured.estimate_measured(
            proc, setup, readings, estimator=str(rows["estimator"].iloc[0]), uncertainty="mc",
            options=measured.MeasuredOptions(trials=args.trials, rng=study.seed + 1000,
                                             n_jobs=args.jobs, fit_alpha=None))
        r = res.details
        print(f"\n{ps.name}, measured ({res.estimator}, counted in {args.trials} trials, "
              f"{time.perf_counter() - start:.0f} s)")
        diffs = []
        for i, m in enumerate(r.measurands):
            if m.name not in rows.index:
                continue
            row = rows.loc[m.name]
            y = r.mc.samples(m.name)
            centre = float(r.true[i]) + float(res.estimate[i]) - row["value"]
            p = float(np.mean(np.abs(y - centre) <= row["U"]))
            d = row["U_coverage"] - p
            diffs.append(abs(d))
            if len(diffs) <= 20 or abs(d) > 0.01:
                print(f"  {m.name:12s} printed {100 * row['U_coverage']:6.2f}% "
                      f"+-{100 * row['U_coverage_se']:4.2f}%  count {100 * p:6.2f}%  "
                      f"diff {100 * d:+5.2f}%  {'yes' if abs(d) <= 0.01 else 'NO'}")
        print(f"  {len(diffs)} measurands, largest difference {100 * max(diffs):.2f} %")
        worst.append((ps.name, max(diffs)))
    return worst


if __name__ == "__main__":
    raise SystemExit(main())
