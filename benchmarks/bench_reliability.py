"""Is a gross error of the stated MDB flagged in 80 % of files? (docs/fit_check.md, "What one
bad reading can do unseen").

For a procedure at its default set-up (circle_centre unless named), the reliability
service states the minimal detectable bias (MDB) of every reading and of every error the
procedure declares (circle_centre: a bad contact along its probing direction) at the design
readings. Each replicate simulates one file with every default error source (the set-up's
distributions, non-Gaussian ones included, at its truth), then checks:

- the clean file (false alarms: the check is built to flag at most alpha);
- the file with the stated MDB added, with a random sign, to the reading whose MDB is the
  largest (the worst reading, the one the documents name);
- the file with a bad contact of its stated MDB along its probing direction, on the
  contact whose MDB is the largest (where the procedure declares such errors).
- the same two errors, each at the MDB the check states for that file's own readings (what
  its report states), on the file's own worst reading and contact along the file's own
  probing direction: the simulated files do not all share the design's geometry
  (circle_centre's scattered start point puts about half of them on the path's other
  branch, where the contacts lie elsewhere and a contact's probing direction differs).

Every check is a new fit (``fit_check``), not the linear design. Printed: the share of
files flagged with its 95 % Clopper-Pearson interval. The MDB is the whole check's (the
chi-square or any reading's w) 0.8 point in the linear Gaussian design at the design
readings (:mod:`mtplan.evaluation.detectability`); the simulated files differ from that
design by their own geometry, the sources' stated distributions and the new fit.

Usage: ``python benchmarks/bench_reliability.py [FILES] [PROCEDURE]`` (default 200 files
of circle_centre; 200 files took 4.5 min on a shared 2-core machine).
"""

from __future__ import annotations

import sys
import time

import numpy as np
from scipy import stats

from mtplan.evaluation.fitcheck import fit_check, reading_vector, with_reading_vector
from mtplan.evaluation.reliability import design_readings, reliability
from mtplan.models import get

SEED = 20261207


def interval(k: int, n: int) -> tuple[float, float]:
    """95 % Clopper-Pearson interval of a binomial share k / n."""
    lo = stats.beta.ppf(0.025, k, n - k + 1) if k > 0 else 0.0
    hi = stats.beta.ppf(0.975, k + 1, n - k) if k < n else 1.0
    return float(lo), float(hi)


def main(files: int = 200, name: str = "circle_centre") -> None:
    t0 = time.perf_counter()
    proc = get(name)
    setup, truth = proc.Setup(), proc.Truth()
    rel = reliability(proc, setup, truth, readings=design_readings(proc, setup, truth))
    n = rel.mdb_values.size
    errors = {"one reading": int(np.argmax(rel.sizes[:n]))}
    if rel.sizes.size > n:
        errors["one contact"] = n + int(np.argmax(rel.sizes[n:]))
    for what, j in errors.items():
        g = _group(rel, j)
        print(f"{what}: {g['at']} ({g['readings']}), stated MDB {g['largest']:.3g} {g['unit']}")
    files_seq, signs_seq = np.random.SeedSequence(SEED).spawn(2)
    signs = np.random.default_rng(signs_seq).choice([-1.0, 1.0], size=(files, len(errors)))
    own = [f"{what}, file's MDB" for what in errors]
    flagged = {"clean": 0, **{what: 0 for what in errors}, **{what: 0 for what in own}}
    failed = 0
    for f, stream in enumerate(files_seq.spawn(files)):
        readings = proc.simulate(setup, truth, 1, rng=stream)
        keys, y = reading_vector(readings)
        declared = proc.capabilities.gross_errors(setup, readings)
        clean = fit_check(proc, setup, readings, origin={},
                          directions=None if declared is None else declared[2])
        if clean.ok is None:
            failed += 1 + 2 * len(errors)
            continue
        flagged["clean"] += int(not clean.ok)
        checks = {}
        for (what, j), sign in zip(errors.items(), signs[f], strict=True):
            checks[what] = with_reading_vector(
                readings, keys, y + sign * rel.sizes[j] * rel.effects[:, j])
        # the same errors at the MDB stated for this file's own readings (its report's)
        for what, sign in zip(own, signs[f], strict=True):
            checks[what] = with_reading_vector(readings, keys,
                                               y + sign * _own_error(clean, declared, y, what))
        for what, r in checks.items():
            fc = fit_check(proc, setup, r, origin={})
            if fc.ok is None:
                failed += 1
                continue
            flagged[what] += int(not fc.ok)
    print(f"{name}, {files} files, alpha {rel.alpha:g} ({failed} checks failed):")
    for what, k in flagged.items():
        lo, hi = interval(k, files)
        print(f"  {what:26s} flagged {k:4d} / {files} = {k / files:.3f} "
              f"[{lo:.3f}, {hi:.3f}]")
    print(f"{time.perf_counter() - t0:.0f} s")


def _own_error(check, declared, y, what: str) -> np.ndarray:
    """The error of the file's own worst reading or contact at the MDB its check states
    (over the reading vector, missing readings included)."""
    used = np.flatnonzero(np.isfinite(y))
    error = np.zeros(y.size)
    if what.startswith("one reading"):
        i = int(np.nanargmax(np.where(np.isfinite(check.mdb), check.mdb, np.nan)))
        error[used[i]] = check.mdb[i]
        return error
    sizes = np.where(np.isfinite(check.mdb_directions), check.mdb_directions, np.nan)
    j = int(np.nanargmax(sizes))
    return sizes[j] * np.asarray(declared[2], dtype=float)[:, j]


def _group(rel, j: int) -> dict:
    """The documents' entry of error j, the worst of its kind: the group whose largest MDB
    it is."""
    scale = {"um": 1e3, "urad": 1e6}
    return min(rel.mdb, key=lambda g: abs(g["largest"] - rel.sizes[j] * scale.get(g["unit"],
                                                                                  1.0)))


if __name__ == "__main__":
    args = sys.argv[1:]
    main(int(args[0]) if args else 200, args[1] if len(args) > 1 else "circle_centre")
