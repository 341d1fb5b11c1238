"""Fit check: false alarms on clean readings, and the power against one bad reading.

Not part of the test suite (seconds per replicate and procedure). For every procedure,
REPLICATES measurements are simulated with every default error source of the set-up at
the default truth (one seed, a SeedSequence stream per replicate) and checked with
:func:`mtplan.evaluation.fitcheck.fit_check`. Then one reading of the same file, drawn
at random among those the fit leaves a w-test, is moved by SIGMAS times its own scatter
(``FitCheck.scatter``: what touches that reading alone) with a random sign, and the
moved file is checked again (a new fit, as a user's file would be).

Each check's statistics are kept (the chi-square's p-value, the largest |w| and the number
of readings tested), so every significance level in ALPHAS (the default, 0.05, and 0.01),
and every split of it between the two tests (``--splits``), is evaluated from the same fits
(the check flags at alpha exactly when ``p_overall < alpha``):

- false alarms: the share of clean files flagged, against the two-sided 99 %
  binomial band of alpha (the check is built to flag at most alpha: Bonferroni's
  bound is conservative, so a rate below alpha is expected), and per test (chi-square
  alone at its share of alpha, largest |w| alone at its share);
- the chi-square p-values' uniformity (Kolmogorov-Smirnov p);
- power: the share of moved files flagged, with its 95 % Clopper-Pearson interval,
  and the share whose worst reading (``worst[0]``) is the moved one;
- the median minimal detectable bias (``FitCheck.mdb``, 80 % power at the default alpha)
  in units of the reading's scatter.

geometry21, line_laser and tracker_frame run on smaller set-ups than their defaults
(fewer points, one sub-machine) to keep the run to minutes; a replicate whose fit fails
is counted and reported apart.

Usage: ``python benchmarks/bench_fitcheck.py [REPLICATES] [PROCEDURE ...] [--jobs N]
[--save PREFIX | --load PREFIX] [--splits]`` (default 200 replicates of every procedure;
``--jobs`` runs replicates in parallel processes, the result does not depend on it;
``--save`` writes every replicate's statistics to ``PREFIX.PROCEDURE.json`` and ``--load``
evaluates such a file again without fitting; ``--splits`` adds the false alarms and the
power at alpha 0.01, 0.02 and 0.05 with the w-test's share 0.5, 0.8 and 1).
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np
from scipy import stats

from mtplan.evaluation.fitcheck import (FIT_ALPHA, W_SHARE, fit_check, reading_vector,
                                        with_reading_vector)
from mtplan.models import get, registry

ALPHAS = (FIT_ALPHA, 0.01)
SPLITS = [(a, share) for a in (0.01, 0.02, 0.05) for share in (0.5, 0.8, 1.0)]
REPLICATES = 200
SIGMAS = 5.0
SEED = 2024
#: smaller set-ups for the heavy procedures (their defaults take 3-20 s per fit)
SETUPS = {"geometry21": {"line_repeats": 1, "line_points": 7, "circle_points": 12},
          "line_laser": {"lines": 16, "points_per_line": 9},
          "tracker_frame": {"n_submachines": 1, "points_per_axis": 5, "points_per_arc": 4}}


def _stats(fc) -> dict:
    return {"p_chi2": fc.p_value, "chi2": fc.chi2, "dof": fc.dof, "w_max": fc.w_max,
            "n_tested": fc.n_tested}


def _flags(st: dict, alpha: float, share: float) -> bool:
    """Whether the check flags a file at `alpha` with the w-test's `share` of it."""
    p_w = min(1.0, 2 * st["n_tested"] * stats.norm.sf(abs(st["w_max"])))
    return bool(st["p_chi2"] < (1 - share) * alpha or p_w < share * alpha)


def replicate(name: str, ss: np.random.SeedSequence) -> dict:
    """One clean file and the same file with one reading moved: both checks' statistics."""
    proc = get(name)
    setup = proc.Setup(**SETUPS.get(name, {}))
    rng = np.random.default_rng(ss)
    readings = proc.simulate(setup, proc.Truth(), 1, rng=rng)
    fc = fit_check(proc, setup, readings, origin={})
    if fc.ok is None:
        return {"failed": fc.reason}
    out = {"clean": _stats(fc), "mdb": float(np.nanmedian(fc.mdb / fc.scatter))}
    keys, y = reading_vector(readings)
    if y.size != fc.n_readings:  # readings left out by the check: cannot map z to them
        return out
    i = int(rng.choice(np.flatnonzero(np.isfinite(fc.z))))
    y = y.copy()
    y[i] += rng.choice([-1.0, 1.0]) * SIGMAS * fc.scatter[i]
    moved = fit_check(proc, setup, with_reading_vector(readings, keys, y), origin={})
    if moved.ok is None:
        out["moved_failed"] = moved.reason
        return out
    out["moved"] = _stats(moved)
    out["named"] = bool(np.nanargmax(np.abs(moved.z)) == i)
    return out


def run(name: str, replicates: int, jobs: int = 1, load: str | None = None,
        save: str | None = None) -> dict:
    """Every replicate's statistics (fitted, or read from `load`; written to `save` after
    each replicate, so that an interrupted run keeps what it did) and their summary."""
    t0 = time.perf_counter()
    streams = np.random.SeedSequence([SEED, sorted(registry()).index(name)]).spawn(replicates)
    if load:
        with open(f"{load}.{name}.json") as f:
            reps = json.load(f)[:replicates]
    elif jobs > 1:
        from joblib import Parallel, delayed

        reps = Parallel(n_jobs=jobs)(delayed(replicate)(name, ss) for ss in streams)
    else:
        reps = []
        for ss in streams:
            reps.append(replicate(name, ss))
            if save:
                with open(f"{save}.{name}.json", "w") as f:
                    json.dump(reps, f)
    if save:
        with open(f"{save}.{name}.json", "w") as f:
            json.dump(reps, f)
    replicates = len(reps)
    wall = np.nan if load else time.perf_counter() - t0
    failed = [f"{i}: {r['failed']}" for i, r in enumerate(reps) if "failed" in r]
    clean = [r["clean"] for r in reps if "clean" in r]
    moved = [r for r in reps if "moved" in r]

    def col(rows, key):
        return np.array([r[key] for r in rows], dtype=float)

    n, m = len(clean), len(moved)
    out = {"procedure": name, "replicates": replicates, "checked": n, "failed": failed,
           "moved": m, "s_per_replicate": wall / replicates * jobs,
           "ks_p": float(stats.kstest(col(clean, "p_chi2"), "uniform").pvalue) if n else np.nan,
           "chi2_dof": float(np.median(col(clean, "chi2") / col(clean, "dof"))) if n else np.nan,
           "dof": int(np.median(col(clean, "dof"))) if n else 0,
           "mdb": float(np.median([r["mdb"] for r in reps if "mdb" in r])) if n else np.nan,
           "named": float(np.mean([r["named"] for r in moved])) if m else np.nan,
           "by_alpha": {}}
    for a in ALPHAS:
        k = sum(_flags(c, a, W_SHARE) for c in clean)
        k_chi2 = sum(_flags(c, (1 - W_SHARE) * a, 0.0) for c in clean)
        k_w = sum(_flags(c, W_SHARE * a, 1.0) for c in clean)
        hit = sum(_flags(r["moved"], a, W_SHARE) for r in moved)
        named = sum(r["named"] and _flags(r["moved"], a, W_SHARE) for r in moved)
        ci = stats.binomtest(hit, m).proportion_ci(0.95) if m else None
        out["by_alpha"][a] = {
            "flagged": k, "rate": k / n if n else np.nan,
            "band": (stats.binom.ppf(0.005, n, a) / n, stats.binom.ppf(0.995, n, a) / n)
            if n else (np.nan, np.nan),
            "chi2_only": k_chi2, "w_only": k_w, "power": hit / m if m else np.nan,
            "power_ci": (ci.low, ci.high) if ci else (np.nan, np.nan),
            "flagged_and_named": named / m if m else np.nan}
    out["splits"] = {(a, share): (np.mean([_flags(c, a, share) for c in clean]) if n else np.nan,
                                  np.mean([_flags(r["moved"], a, share) for r in moved])
                                  if m else np.nan) for a, share in SPLITS}
    return out


def _option(argv: list, flag: str):
    """(value of `flag`, argv without it); None where absent."""
    if flag not in argv:
        return None, argv
    j = argv.index(flag)
    return argv[j + 1], argv[:j] + argv[j + 2:]


def main(argv) -> int:
    splits = "--splits" in argv
    argv = [a for a in argv if a != "--splits"]
    save, argv = _option(argv, "--save")
    load, argv = _option(argv, "--load")
    jobs, argv = _option(argv, "--jobs")
    jobs = int(jobs or 1)
    replicates = int(argv[0]) if argv and argv[0].isdigit() else REPLICATES
    names = [a for a in argv if not a.isdigit()] or sorted(registry())
    print(f"fit check: {replicates} clean files per procedure, each also with one reading moved "
          f"by {SIGMAS:g} times its scatter; alpha split {1 - W_SHARE:g} chi-square / "
          f"{W_SHARE:g} largest |w| (Bonferroni)")
    print("procedure      alpha  checked  false alarms (99% band)     chi2|w alone  power "
          "(95% CI)          named  flagged+named  KS p   chi2/dof  dof  MDB/sigma  s/rep  failed")
    bad = False
    for name in names:
        r = run(name, replicates, jobs, load, save)
        for a, b in r["by_alpha"].items():
            lo, hi = b["band"]
            inside = b["rate"] <= hi
            bad |= not inside
            print(f"{name:14s} {a:5g}  {r['checked']:7d}  {b['flagged']:3d} ({b['rate']:.3f}) "
                  f"[{lo:.3f}, {hi:.3f}] {'ok ' if inside else 'OUT'}  {b['chi2_only']:3d}|"
                  f"{b['w_only']:<3d}      {b['power']:.3f} [{b['power_ci'][0]:.3f}, "
                  f"{b['power_ci'][1]:.3f}]  {r['named']:.3f}  {b['flagged_and_named']:.3f}"
                  f"          {r['ks_p']:.3f}  {r['chi2_dof']:.3f}  {r['dof']:4d}  "
                  f"{r['mdb']:.2f}       {r['s_per_replicate']:.1f}  {len(r['failed'])}",
                  flush=True)
        for f in r["failed"][:5]:
            print(f"    fit failed: replicate {f}", flush=True)
        if splits:
            print("    alpha, w-test's share: false alarms / power  " + "  ".join(
                f"{a:g},{share:g}: {fa:.3f}/{pw:.3f}" for (a, share), (fa, pw)
                in r["splits"].items()), flush=True)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
