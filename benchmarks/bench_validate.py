"""validate: how often it calls right uncertainties wrong, and wrong ones right.

Not part of the test suite. The test is about statistics, so no model runs: each replicate
draws N synthetic results of one measurand (true value 0, stated u = 1, errors from the
case's distribution, a 95 % interval of the distribution's own shape) and their reference
values (normal, U_ref at k = 2), and asks :func:`mtplan.evaluation.validation.validate` for
its verdict. One seed, a SeedSequence stream per case.

Cases (the verdict expected):

- ``shared``: one reference value shared by all N results, U_ref = U (= 2 u), right u
  (consistent; the comparisons are correlated, so the generalised chi-square decides);
- ``own``: one reference per result, U_ref = 0.1 u, right u (consistent);
- ``rectangular``: as ``own`` with rectangular errors and their own 95 % interval
  (+-0.95 sqrt(3) u) (consistent; with U = 2 u it would be "too large");
- ``halved``: as ``shared`` with errors twice the stated u ("uncertainty too small");
- ``shared_as_independent``: the ``shared`` results compared as if independent (one
  reference row per result with the shared value): what the test without the reference's
  covariance does (for comparison; not a verdict of this code on shared data);
- ``common90``: repeated tests of one machine, 90 % of each result's u² one error common
  to all of them (one sensor, one set-up), a reference per result with U_ref = 0.1 u,
  validated with ``common=0.9`` (consistent);
- ``common90_as_independent``: the same results validated as independent (``common=0``,
  the default): what the verdict is when the common share is not stated (for comparison).

For the right-u cases the printed rate of wrong verdicts is checked against the two-sided
99 % binomial band of 1 - LEVEL (at most 1 - LEVEL is promised: the independent case makes
two tests at half of it each, so a rate below it is expected).

Usage: ``python benchmarks/bench_validate.py [REPLICATES] [N ...]`` (default 2000
replicates at N = 24 and 100).
"""

from __future__ import annotations

import sys
import time

import numpy as np
from scipy import stats

from mtplan.evaluation.validation import CONSISTENT, LEVEL, TOO_SMALL, validate

REPLICATES = 2000
SIZES = (24, 100)
SEED = 2026
HALF = {"normal": stats.norm.isf(0.025), "rectangular": 0.95 * np.sqrt(3)}
CASES = {  # name: (errors, error scale, U_ref, shared reference, shared value compared apart,
    #              common share of the errors' variance, common share stated to validate)
    "shared": ("normal", 1.0, 2.0, True, False, 0.0, 0.0),
    "own": ("normal", 1.0, 0.1, False, False, 0.0, 0.0),
    "rectangular": ("rectangular", 1.0, 0.1, False, False, 0.0, 0.0),
    "halved": ("normal", 2.0, 2.0, True, False, 0.0, 0.0),
    "shared_as_independent": ("normal", 1.0, 2.0, True, True, 0.0, 0.0),
    "common90": ("normal", 1.0, 0.1, False, False, 0.9, 0.9),
    "common90_as_independent": ("normal", 1.0, 0.1, False, False, 0.9, 0.0),
}
EXPECTED = {"halved": TOO_SMALL}


def _doc(name, y, half):
    return name, {"procedure": "p", "measurands": [
        {"name": "a", "unit": "um", "value": y, "u": 1.0, "interval": [y - half, y + half],
         "coverage": 0.95}]}


def _ref(value, U, result=""):
    return {"procedure": "p", "measurand": "a", "value": value, "U": U, "unit": "um",
            "result": result}


def one(case: str, n: int, rng) -> str:
    kind, scale, U_ref, shared, apart, common, stated = CASES[case]
    e = scale * (rng.standard_normal(n) if kind == "normal"
                 else rng.uniform(-np.sqrt(3), np.sqrt(3), n))
    if common:  # one error shared by every result, the rest their own: u² in all
        e = np.sqrt(common) * scale * rng.standard_normal() + np.sqrt(1 - common) * e
    ref_error = U_ref / 2 * rng.standard_normal(1 if shared else n)
    results = [_doc(f"r{i}", float(e[i]), HALF[kind]) for i in range(n)]
    if shared and not apart:
        refs = [_ref(float(-ref_error[0]), U_ref)]
    else:
        refs = [_ref(float(-ref_error[0 if shared else i]), U_ref, f"r{i}") for i in range(n)]
    return validate(results, refs, common=stated).overall.verdict


def main(argv) -> int:
    replicates = int(argv[0]) if argv else REPLICATES
    sizes = [int(a) for a in argv[1:]] or list(SIZES)
    print(f"validate: {replicates} replicates per case, verdicts at {100 * LEVEL:g} % "
          "confidence (nominal wrong-verdict rate of a right u: "
          f"at most {1 - LEVEL:g})")
    print("case                    N   consistent  too small  too large  expected     rate of "
          "the expected (99% band of a wrong one)")
    bad = False
    for case in CASES:
        for n in sizes:
            ss = np.random.SeedSequence([SEED, list(CASES).index(case), n])
            rng = np.random.default_rng(ss)
            t0 = time.perf_counter()
            verdicts = [one(case, n, rng) for _ in range(replicates)]
            counts = {v: sum(x == v for x in verdicts) for v in
                      (CONSISTENT, TOO_SMALL, "uncertainty too large")}
            expected = EXPECTED.get(case, CONSISTENT)
            wrong = replicates - counts[expected]
            hi = stats.binom.ppf(0.995, replicates, 1 - LEVEL) / replicates
            note = ""
            if case == "shared_as_independent":
                note = "(the reference's covariance left out; for comparison)"
            elif case == "common90_as_independent":
                note = (f"wrong {wrong / replicates:.3f} (the common share not stated; for "
                        "comparison)")
            elif expected == CONSISTENT:
                inside = wrong / replicates <= hi
                bad |= not inside
                note = f"wrong {wrong / replicates:.3f} <= {hi:.3f} {'ok' if inside else 'OUT'}"
            else:
                note = f"{counts[expected] / replicates:.3f}"
            print(f"{case:22s} {n:4d}  {counts[CONSISTENT]:9d}  {counts[TOO_SMALL]:9d}  "
                  f"{counts['uncertainty too large']:9d}  {expected:22s} {note}  "
                  f"({time.perf_counter() - t0:.0f} s)", flush=True)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
