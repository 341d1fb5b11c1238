"""Fit check on clean simulated readings: false-alarm rate and uniform p-values, per procedure.

Not part of the test suite (minutes per procedure). For every procedure, REPLICATES
measurements are simulated with every default error source of the set-up at the
default truth (one seed, a SeedSequence stream per replicate) and checked with
:func:`mtplan.evaluation.fitcheck.fit_check`. When the readings fit the model, the
p-value is uniform on [0, 1], so:

- the share of replicates flagged (p < ALPHA) lies within the binomial interval of
  ALPHA (two-sided 99 %, Clopper-Pearson);
- the p-values pass a Kolmogorov-Smirnov test of uniformity (its p-value printed);
- chi2 / dof: its median (about 1 - 2 / (3 dof)) and the standard error of its mean
  (printed; the mean itself is left out, one diverged fit would own it).

geometry21, line_laser and tracker_frame run on smaller set-ups than their defaults (fewer
points, one sub-machine)
to keep the run to minutes on a small machine; the check's statistics do not depend on
the number of readings. Replicates whose fit fails are counted and reported apart.

Usage: ``python benchmarks/bench_fitcheck.py [REPLICATES] [PROCEDURE ...]``
"""

from __future__ import annotations

import sys
import time

import numpy as np
from scipy import stats

from mtplan.evaluation.fitcheck import fit_check
from mtplan.models import get, registry

ALPHA = 0.01
REPLICATES = 200
SEED = 2024
#: smaller set-ups for the heavy procedures (their defaults take 3-20 s per fit)
SETUPS = {"geometry21": {"line_repeats": 1, "line_points": 7, "circle_points": 12},
          "line_laser": {"lines": 16, "points_per_line": 9},
          "tracker_frame": {"n_submachines": 1, "points_per_axis": 5, "points_per_arc": 4}}


def run(name: str, replicates: int) -> dict:
    proc = get(name)
    setup = proc.Setup(**SETUPS.get(name, {}))
    truth = proc.Truth()
    streams = np.random.SeedSequence([SEED, sorted(registry()).index(name)]).spawn(replicates)
    p, chi2, dof, failed = [], [], [], []
    t0 = time.perf_counter()
    for i, ss in enumerate(streams):
        readings = proc.simulate(setup, truth, 1, rng=np.random.default_rng(ss))
        fc = fit_check(proc, setup, readings, alpha=ALPHA, origin={})
        if fc.ok is None:
            failed.append(f"{i}: {fc.reason}")
            continue
        p.append(fc.p_value)
        chi2.append(fc.chi2)
        dof.append(fc.dof)
    p, chi2, dof = np.array(p), np.array(chi2), np.array(dof)
    n = p.size
    k = int(np.sum(p < ALPHA))
    ci = stats.binomtest(int(round(ALPHA * n)), n).proportion_ci(0.99) if n else None
    lo = float(stats.binom.ppf(0.005, n, ALPHA)) / n if n else float("nan")
    hi = float(stats.binom.ppf(0.995, n, ALPHA)) / n if n else float("nan")
    ratio = chi2 / dof
    return {"procedure": name, "replicates": replicates, "checked": n, "failed": failed,
            "flagged": k, "rate": k / n if n else float("nan"), "band": (lo, hi),
            "ci_rate": ci, "ks_p": float(stats.kstest(p, "uniform").pvalue) if n else float("nan"),
            "chi2_dof": float(np.median(ratio)) if n else float("nan"),
            "chi2_dof_se": float(np.std(ratio, ddof=1) / np.sqrt(n)) if n > 1 else float("nan"),
            "dof": int(np.median(dof)) if n else 0, "s_per_fit": (time.perf_counter() - t0) / replicates}


def main(argv) -> int:
    replicates = int(argv[0]) if argv else REPLICATES
    names = argv[1:] or sorted(registry())
    print(f"fit check on clean readings: alpha {ALPHA}, {replicates} replicates per procedure")
    print("procedure      checked  flagged  rate    99% band of alpha   KS p    chi2/dof med (se)  "
          " dof  s/fit  failed")
    bad = False
    for name in names:
        r = run(name, replicates)
        lo, hi = r["band"]
        inside = lo <= r["rate"] <= hi
        bad |= not inside or r["ks_p"] < 0.01
        print(f"{name:14s} {r['checked']:7d}  {r['flagged']:7d}  {r['rate']:.3f}   "
              f"[{lo:.3f}, {hi:.3f}] {'ok ' if inside else 'OUT'}  {r['ks_p']:.3f}  "
              f"{r['chi2_dof']:.3f} ({r['chi2_dof_se']:.3f})  {r['dof']:4d}  "
              f"{r['s_per_fit']:.2f}  {len(r['failed'])}", flush=True)
        for f in r["failed"][:5]:
            print(f"    fit failed: replicate {f}", flush=True)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
