"""Compare two folders of result CSVs (two runs of ``mtplan demo`` or ``mtplan report``).

For every CSV of the first folder (its subfolders included, matched by relative path),
prints the largest relative difference of its numeric cells against the file of the same
name in the second folder, where it is (column and row), how many text cells differ (and
the first of them), the columns in one file only (a new set-up field: the shared columns
are still compared), or that the row counts differ (a new source row). A
refactoring that must not change results shows 0 or a rounding-level figure (<= 1e-9) for
every file it did not mean to change.

    .venv/bin/python benchmarks/compare_results.py NEW/results OLD/results [--rtol 1e-9]

Exits 1 when a file present in both differs by more than ``--rtol`` or in shape.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd


def compare(new: Path, old: Path) -> tuple[str, float | None]:
    """One file's verdict line and its largest relative numeric difference (None: not comparable)."""
    x, y = pd.read_csv(new), pd.read_csv(old)
    extra = [c for c in x.columns if c not in y.columns] + [c for c in y.columns
                                                            if c not in x.columns]
    if len(x) != len(y):
        return f"shape {x.shape} against {y.shape}; columns in one only: {extra}", None
    worst, where, text = 0.0, "", 0
    for col in [c for c in x.columns if c in y.columns]:
        if pd.api.types.is_numeric_dtype(x[col]) and pd.api.types.is_numeric_dtype(y[col]):
            a, b = x[col].to_numpy(float), y[col].to_numpy(float)
            both = np.isfinite(a) & np.isfinite(b)
            text += int(np.sum(np.isfinite(a) != np.isfinite(b)))
            with np.errstate(divide="ignore", invalid="ignore"):
                rel = np.where(both & (a != b), np.abs(a - b) / np.abs(b), 0.0)
            if rel.size and np.nanmax(rel) > worst:
                row = int(np.nanargmax(rel))
                worst = float(rel[row])
                where = f" (column {col!r}, row {row}: {b[row]:.10g} -> {a[row]:.10g})"
        else:
            a, b = (c.astype(object).where(c.notna(), "").astype(str) for c in (x[col], y[col]))
            moved = a != b  # two empty cells are the same text
            if moved.any() and not text:
                row = int(np.flatnonzero(moved)[0])
                where += f"; text first in {col!r}, row {row}: {b[row]!r} -> {a[row]!r}"
            text += int(moved.sum())
    line = f"max relative difference {worst:.3g}{where}, text cells differing {text}"
    if extra:  # the shared columns compared; a column in one only is a difference
        return f"{line}; columns in one only: {extra}", None
    return line, worst + text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("new", type=Path)
    parser.add_argument("old", type=Path)
    parser.add_argument("--rtol", "--tol", type=float, default=1e-9, dest="rtol")
    args = parser.parse_args(argv)
    failed = False
    names_new = {p.relative_to(args.new) for p in args.new.rglob("*.csv")}
    names_old = {p.relative_to(args.old) for p in args.old.rglob("*.csv")}
    for name in sorted(names_new):
        if name not in names_old:
            print(f"{name}: only in {args.new}")
            continue
        line, worst = compare(args.new / name, args.old / name)
        bad = worst is None or worst > args.rtol
        failed |= bad
        print(f"{'DIFFERS' if bad else 'same   '} {name}: {line}")
    for name in sorted(names_old - names_new):
        print(f"{name}: only in {args.old}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
