"""Compare two folders of result CSVs (two runs of ``mtplan demo`` or ``mtplan report``).

For every CSV of the first folder, prints the largest relative difference of its numeric
cells against the file of the same name in the second folder, how many text cells differ,
or that the files' shapes or columns differ (a changed set-up record, a new source row).
A refactoring that must not change results shows 0 or a rounding-level figure (<= 1e-9)
for every file it did not mean to change.

    .venv/bin/python benchmarks/compare_results.py NEW/results OLD/results [--tol 1e-9]

Exits 1 when a file present in both differs by more than ``--tol`` or in shape.
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
    if list(x.columns) != list(y.columns) or x.shape != y.shape:
        extra = sorted(set(x.columns) ^ set(y.columns))
        return f"shape {x.shape} against {y.shape}; columns in one only: {extra}", None
    worst, text = 0.0, 0
    for col in x.columns:
        if pd.api.types.is_numeric_dtype(x[col]) and pd.api.types.is_numeric_dtype(y[col]):
            a, b = x[col].to_numpy(float), y[col].to_numpy(float)
            both = np.isfinite(a) & np.isfinite(b)
            text += int(np.sum(np.isfinite(a) != np.isfinite(b)))
            diff = np.abs(a[both] - b[both])
            moved = diff > 0
            if moved.any():
                worst = max(worst, float(np.max(diff[moved] / np.abs(b[both][moved]))))
        else:
            text += int((x[col].astype(str) != y[col].astype(str)).sum())
    return f"max relative difference {worst:.3g}, text cells differing {text}", worst + text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("new", type=Path)
    parser.add_argument("old", type=Path)
    parser.add_argument("--tol", type=float, default=1e-9)
    args = parser.parse_args(argv)
    failed = False
    for path in sorted(args.new.glob("*.csv")):
        other = args.old / path.name
        if not other.exists():
            print(f"{path.name}: only in {args.new}")
            continue
        line, worst = compare(path, other)
        failed |= worst is None or worst > args.tol
        print(f"{path.name}: {line}")
    for path in sorted(set(p.name for p in args.old.glob("*.csv"))
                       - set(p.name for p in args.new.glob("*.csv"))):
        print(f"{path}: only in {args.old}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
