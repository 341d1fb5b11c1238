"""End-to-end wall time of ``mtplan estimate`` on the example readings, from the command line.

For each procedure, runs

    mtplan estimate PROC examples/PROC_readings.csv [--uncertainty posterior]

as a subprocess (interpreter start, imports, reading, the estimate, its uncertainty and the
printing all count) and prints a table: the best repeat's wall and CPU time (user +
system, every thread), the median wall time, and whether the best wall time is within
the goal (default 15 s: what a user waits for with no flags; 10 s for the posteriors).

    .venv/bin/python benchmarks/bench_estimate_cli.py [PROC ...] [--uncertainty posterior]
        [--repeat N] [--threads N] [--goal S] [--baseline SRC]

``--threads`` sets OMP/OpenBLAS/MKL threads of the subprocess (default: the
environment's, as a user runs it). The machine's load counts too: on a shared machine
take the best of a few repeats, and compare figures from the same run only:
``--baseline SRC`` times another checkout's ``src`` folder (e.g. an earlier commit's,
``git archive REV src | tar -x -C DIR``) alternately with this one, same load.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROCEDURES = ("rotary_axis", "circle_centre", "tracker_frame", "geometry21", "line_laser")


def _command(proc: str, uncertainty: str | None) -> list[str]:
    exe = Path(sys.executable).with_name("mtplan")
    head = [str(exe)] if exe.exists() else [sys.executable, "-c",
                                            "import sys; from mtplan.cli import main; "
                                            "sys.exit(main())"]
    return [*head, "estimate", proc, str(ROOT / "examples" / f"{proc}_readings.csv"),
            *(["--uncertainty", uncertainty] if uncertainty else [])]


def time_one(proc: str, env: dict, uncertainty: str | None = None) -> tuple[float, float]:
    """Seconds of wall clock and of CPU (user + system, every thread) for one run; raises
    when the command fails. On a loaded machine the CPU time is the better guide to the
    wall time on an idle one."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(_command(proc, uncertainty), cwd=ROOT, env=env, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise RuntimeError(f"{proc}: exit {done.returncode}\n{done.stderr[-2000:]}")
    return dt, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("procedures", nargs="*", default=list(PROCEDURES))
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--uncertainty", choices=["mc", "posterior"], default=None,
                    help="as the command's option (default: none given, as a user runs it)")
    ap.add_argument("--goal", type=float, default=None,
                    help="seconds (default 15; 10 with --uncertainty posterior)")
    ap.add_argument("--baseline", default=None, help="another checkout's src folder")
    args = ap.parse_args(argv)
    if args.goal is None:
        args.goal = 10.0 if args.uncertainty == "posterior" else 15.0
    env = dict(os.environ)
    if args.threads is not None:
        for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            env[k] = str(args.threads)
    base_env = None
    if args.baseline:
        base_env = {**env, "PYTHONPATH": os.pathsep.join(
            [str(Path(args.baseline).resolve()), *filter(None, [env.get("PYTHONPATH")])])}
    rows = []
    for proc in args.procedures:
        runs, base = [], []
        for _ in range(max(1, args.repeat)):
            if base_env is not None:
                base.append(time_one(proc, base_env, args.uncertainty))
            runs.append(time_one(proc, env, args.uncertainty))
        best = min(runs)
        rows.append((proc, best, statistics.median(w for w, _ in runs), best[0] <= args.goal,
                     min(base) if base else None))
        print(f"{proc}: wall/cpu {', '.join(f'{w:.1f}/{c:.1f}' for w, c in runs)} s"
              + (f" (baseline {', '.join(f'{w:.1f}/{c:.1f}' for w, c in base)} s)"
                 if base else ""), file=sys.stderr, flush=True)
    extra = f"{'baseline wall/cpu':>19}" if base_env is not None else ""
    print(f"{'procedure':<15}{'wall [s]':>10}{'cpu [s]':>9}{'median wall':>13}{extra}"
          f"  wall within {args.goal:g} s")
    for proc, (wall, cpu), med, ok, b in rows:
        col = f"{b[0]:>13.1f}/{b[1]:<5.1f}" if b is not None else ""
        print(f"{proc:<15}{wall:>10.1f}{cpu:>9.1f}{med:>13.1f}{col}  {'yes' if ok else 'NO'}")
    return 0 if all(r[3] for r in rows) else 1

if __name__ == "__main__":
    sys.exit(main())
