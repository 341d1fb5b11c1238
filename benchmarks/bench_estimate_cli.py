"""End-to-end wall time of ``mtplan estimate`` on the example readings, from the command line.

For each example readings file ``examples/<name>_readings.csv`` (its procedure is the
longest procedure name that begins the file's name: ``tracker_frame_warm_readings.csv`` is
tracker_frame's), runs

    mtplan estimate PROC examples/NAME_readings.csv --json [--uncertainty posterior]

as a subprocess (interpreter start, imports, reading, the estimate, its uncertainty and the
printing all count; ``--json`` only formats what is printed) and prints a table: the best
repeat's wall and CPU time (user + system of the command and its workers, every thread),
the median wall time, the one-minute load average when the best run started, the largest
relative change of u over the measurands against a reference, and whether the best wall
time is within the goal (default 15 s: what a user waits for with no flags; 10 s for the
posteriors).

    .venv/bin/python benchmarks/bench_estimate_cli.py [NAME ...] [--uncertainty posterior]
        [--repeat N] [--threads N] [--goal S] [--baseline SRC]
        [--reference DIR] [--save-reference DIR]

``NAME`` picks files by the part before ``_readings.csv`` (default: every example file).
``--save-reference DIR`` writes each run's JSON to ``DIR/NAME.json``; ``--reference DIR``
compares u with those (run it once on the code before a change, then on the change).
``--threads`` sets OMP/OpenBLAS/MKL threads of the subprocess (default: the
environment's, as a user runs it). The machine's load counts too: on a shared machine
take the best of a few repeats, read the CPU seconds (a better guide than the wall time to
the wall time on an idle machine) and the load beside them, and compare figures from the
same run only: ``--baseline SRC`` times another checkout's ``src`` folder (e.g. an earlier
commit's, ``git archive REV src | tar -x -C DIR``) alternately with this one, same load.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROCEDURES = ("rotary_axis", "circle_centre", "tracker_frame", "geometry21", "line_laser")
EXAMPLES = ROOT / "examples"


def example_files(names=()) -> list[tuple[str, Path]]:
    """(procedure, file) of every ``examples/*_readings.csv`` (or those named), the
    procedure the longest of :data:`PROCEDURES` that begins the file's name."""
    out = []
    for path in sorted(EXAMPLES.glob("*_readings.csv")):
        name = path.name.removesuffix("_readings.csv")
        procs = [p for p in PROCEDURES if name == p or name.startswith(p + "_")]
        if procs and (not names or name in names):
            out.append((max(procs, key=len), path))
    missing = set(names) - {p.name.removesuffix("_readings.csv") for _, p in out}
    if missing:
        raise SystemExit(f"no example readings file for {', '.join(sorted(missing))}")
    return out


def _command(proc: str, path: Path, uncertainty: str | None) -> list[str]:
    exe = Path(sys.executable).with_name("mtplan")
    head = [str(exe)] if exe.exists() else [sys.executable, "-c",
                                            "import sys; from mtplan.cli import main; "
                                            "sys.exit(main())"]
    return [*head, "estimate", proc, str(path), "--json",
            *(["--uncertainty", uncertainty] if uncertainty else [])]


def time_one(proc: str, path: Path, env: dict, uncertainty: str | None = None
             ) -> tuple[float, float, float, dict]:
    """(wall [s], CPU [s], one-minute load average at the start, the command's JSON) of one
    run; raises when the command fails. CPU is user + system of the command and its
    workers, every thread: on a loaded machine the better guide to the wall time on an
    idle one."""
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(_command(proc, path, uncertainty), cwd=ROOT, env=env,
                          capture_output=True, text=True)
    dt = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise RuntimeError(f"{proc} {path.name}: exit {done.returncode}\n{done.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return dt, cpu, load, json.loads(done.stdout)


def u_change(doc: dict, ref: dict | None) -> float | None:
    """The largest |u / u_ref - 1| over the measurands both give a u for (None: no
    reference)."""
    if ref is None:
        return None
    old = {m["name"]: m["u"] for m in ref["measurands"] if m.get("u")}
    ratios = [abs(m["u"] / old[m["name"]] - 1.0) for m in doc["measurands"]
              if m.get("u") and m["name"] in old]
    return max(ratios) if ratios else None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("names", nargs="*", metavar="NAME",
                    help="example files by the part before _readings.csv (default: all)")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--uncertainty", choices=["mc", "posterior"], default=None,
                    help="as the command's option (default: none given, as a user runs it)")
    ap.add_argument("--goal", type=float, default=None,
                    help="seconds (default 15; 10 with --uncertainty posterior)")
    ap.add_argument("--baseline", default=None, help="another checkout's src folder")
    ap.add_argument("--reference", default=None, metavar="DIR",
                    help="compare u with DIR/NAME.json (written by --save-reference)")
    ap.add_argument("--save-reference", default=None, metavar="DIR",
                    help="write each best run's JSON to DIR/NAME.json")
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
    for proc, path in example_files(args.names):
        name = path.name.removesuffix("_readings.csv")
        runs, base = [], []
        for _ in range(max(1, args.repeat)):
            if base_env is not None:
                base.append(time_one(proc, path, base_env, args.uncertainty))
            runs.append(time_one(proc, path, env, args.uncertainty))
        best = min(runs, key=lambda r: r[0])
        ref = None
        if args.reference:
            ref_path = Path(args.reference) / f"{name}.json"
            ref = json.loads(ref_path.read_text()) if ref_path.exists() else None
        if args.save_reference:
            Path(args.save_reference).mkdir(parents=True, exist_ok=True)
            (Path(args.save_reference) / f"{name}.json").write_text(json.dumps(best[3]))
        rows.append((name, best, statistics.median(r[0] for r in runs), best[0] <= args.goal,
                     min(base, key=lambda r: r[0]) if base else None, u_change(best[3], ref)))
        print(f"{name}: wall/cpu/load {', '.join(f'{w:.1f}/{c:.1f}/{ld:.1f}' for w, c, ld, _ in runs)}"
              + (f" (baseline {', '.join(f'{w:.1f}/{c:.1f}/{ld:.1f}' for w, c, ld, _ in base)})"
                 if base else ""), file=sys.stderr, flush=True)
    extra = f"{'baseline wall/cpu':>19}" if base_env is not None else ""
    print(f"{'readings':<21}{'wall [s]':>9}{'cpu [s]':>8}{'load':>6}{'median wall':>12}"
          f"{'max du/u':>10}{extra}  wall within {args.goal:g} s")
    for name, (wall, cpu, load, _), med, ok, b, du in rows:
        col = f"{b[0]:>13.1f}/{b[1]:<5.1f}" if b is not None else ""
        shown = f"{100 * du:>9.2f}%" if du is not None else f"{'-':>10}"
        print(f"{name:<21}{wall:>9.1f}{cpu:>8.1f}{load:>6.1f}{med:>12.1f}{shown}{col}  "
              f"{'yes' if ok else 'NO'}")
    return 0 if all(r[3] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
