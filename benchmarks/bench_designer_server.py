"""Server-side cost of a lever change in the designer: `mtplan.explore.design.evaluate`.

For each procedure, moves one lever to new values (so that no answer comes from the
cache) and times the whole evaluation of each, and its two parts: the first-order
prediction with its budget (the first-order service, ``mtplan linearize``'s numbers)
and the identifiability of the new geometry. CPU time of this process (what a request
costs whatever else the machine runs) and wall time, median and maximum [ms]; then the
largest relative difference between the designer's u and ``mtplan linearize``'s.

    python benchmarks/bench_designer_server.py [--changes N] [--only PROC ...]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from mtplan.evaluation.simulation import linearize_procedure
from mtplan.explore import design as d

#: procedure -> (lever, first value, step): the browser benchmark's levers
LEVERS = {
    "rotary_axis": ("incline_deg", 10.0, 1.3),
    "circle_centre": ("spread_deg", 120.0, 3.1),
    "tracker_frame": ("a_arc_deg", 30.0, 1.7),
}


def _timed(fn, *args):
    c, w = time.process_time(), time.perf_counter()
    out = fn(*args)
    return out, 1e3 * (time.process_time() - c), 1e3 * (time.perf_counter() - w)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--changes", type=int, default=7, help="lever changes per procedure")
    ap.add_argument("--only", nargs="*", help="procedures to time (default all listed)")
    args = ap.parse_args(argv)
    print(f"load average: {os.getloadavg()}, cores: {os.cpu_count()}")
    for name, (field, start, step) in LEVERS.items():
        if args.only and name not in args.only:
            continue
        d.evaluate({"procedure": name, "setup": {field: str(start)}})  # imports, first use
        times = {"predict": [], "identify": [], "evaluate": []}
        worst = 0.0
        for i in range(1, args.changes + 1):
            value = f"{start + i * step:.6g}"
            proc, setup = d.setup_of(d.normalise({"procedure": name, "setup": {field: value}}))
            pred, *t = _timed(d.compute_prediction, proc, setup, proc.default_estimator)
            times["predict"].append(t)
            times["identify"].append(_timed(d.identify, proc, setup)[1:])
            other = {"procedure": name, "setup": {field: f"{start + (i + 0.5) * step:.6g}"}}
            times["evaluate"].append(_timed(d.evaluate, other)[1:])
            g = linearize_procedure(proc, setup)
            worst = max(worst, max(abs(pred["u"][n] - u) / u for n, u in zip(g.names, g.std,
                                                                              strict=True)
                                   if u > 0))
        parts = "  ".join(
            f"{k} cpu {np.median([c for c, _ in v]):5.0f} (max {max(c for c, _ in v):5.0f}) "
            f"wall {np.median([w for _, w in v]):5.0f}" for k, v in times.items())
        print(f"{name:14s} {field:12s} {parts} ms; u vs linearize: {worst:.1e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
