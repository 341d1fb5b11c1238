"""Fit check on rotary_axis: the artifact's clamping tilt, and alpha's false alarms and power.

Not part of the test suite (about a second per replicate and case). The artifact's real
plane is clamped by eye; docs/fit_check.md calls 5-20 mrad per tilt common. Its prior in the
fit (``artifact_tilt_urad``, the standard deviation of each of the two tilts) is one
pseudo-reading each in the chi-square, so a prior narrower than the clampings that occur
flags good readings. For each case (the prior's size, the real tilts: drawn from the prior,
or both fixed at the doc's upper end, 20 mrad), REPLICATES clean files of the default C
test are simulated (every other default source drawn; one seed, a SeedSequence stream per
replicate, the same streams in every case) and checked; then one reading of the same file
is moved by 5 times its own scatter (as ``bench_fitcheck.py``) and checked again. Every
alpha in ALPHAS is evaluated from the same fits (the w-test's share 0.8, the default):
false alarms on the clean files with their two-sided 99 % binomial band, and the power
against the moved reading with its 95 % Clopper-Pearson interval.

Usage: ``python benchmarks/bench_fitcheck_clamping.py [REPLICATES]`` (default 200).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fitcheck import SIGMAS, _flags, _stats  # noqa: E402

from mtplan.evaluation.fitcheck import (W_SHARE, fit_check, reading_vector,  # noqa: E402
                                        with_reading_vector)
from mtplan.models import get  # noqa: E402

REPLICATES = 200
SEED = 2026
ALPHAS = (0.01, 0.02, 0.05)
#: (the prior's standard deviation per tilt [urad], the real tilts [rad] or None: drawn)
CASES = ((5000.0, 0.020), (10000.0, None), (10000.0, 0.020))


def replicate(prior: float, tilt, ss: np.random.SeedSequence) -> dict | None:
    proc = get("rotary_axis")
    setup = proc.Setup(artifact_tilt_urad=prior)
    draw, move = ss.spawn(2)
    errors = proc.draw_errors(setup, 1, draw)
    if tilt is not None:
        errors["artifact_tilt"] = np.full_like(errors["artifact_tilt"], tilt)
    readings = proc.forward(setup, proc.Truth(), errors)
    fc = fit_check(proc, setup, readings, origin={})
    if fc.ok is None:
        return None
    out = {"clean": _stats(fc)}
    rng = np.random.default_rng(move)
    keys, y = reading_vector(readings)
    i = int(rng.choice(np.flatnonzero(np.isfinite(fc.z))))
    y = y.copy()
    y[i] += rng.choice([-1.0, 1.0]) * SIGMAS * fc.scatter[i]
    moved = fit_check(proc, setup, with_reading_vector(readings, keys, y), origin={})
    if moved.ok is not None:
        out["moved"] = _stats(moved)
    return out


def main(argv) -> int:
    n = int(argv[0]) if argv else REPLICATES
    streams = np.random.SeedSequence(SEED).spawn(n)
    print(f"rotary_axis C default, {n} files per case; alpha split {1 - W_SHARE:g} chi-square "
          f"/ {W_SHARE:g} largest |w|; power: one reading moved by {SIGMAS:g} times its scatter")
    print("prior [mrad]  real tilts [mrad]  alpha  false alarms (99% band)      power (95% CI)"
          "           s/file")
    for prior, tilt in CASES:
        t0 = time.perf_counter()
        reps = [r for r in (replicate(prior, tilt, ss) for ss in streams) if r is not None]
        wall = (time.perf_counter() - t0) / n
        clean = [r["clean"] for r in reps]
        moved = [r["moved"] for r in reps if "moved" in r]
        real = "drawn" if tilt is None else f"{1e3 * tilt:g}, {1e3 * tilt:g}"
        for a in ALPHAS:
            k = sum(_flags(c, a, W_SHARE) for c in clean)
            hit = sum(_flags(m, a, W_SHARE) for m in moved)
            lo, hi = (stats.binom.ppf(q, len(clean), a) / len(clean) for q in (0.005, 0.995))
            ci = stats.binomtest(hit, len(moved)).proportion_ci(0.95)
            print(f"{prior / 1e3:12g}  {real:17s}  {a:5g}  {k:3d} of {len(clean)} "
                  f"({k / len(clean):.3f}) [{lo:.3f}, {hi:.3f}]  {hit / len(moved):.3f} "
                  f"[{ci.low:.3f}, {ci.high:.3f}]  {wall:.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
