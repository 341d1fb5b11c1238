"""Parallel speed-up of a sweep: one job, loky with 2 jobs, and a real Dask cluster (not a
test; prints figures).

The sweep: rotary_axis, 6 incline angles x 3 position counts, 100 000 trials per set-up.
It runs with 1 job, with 2 loky jobs, and on a Dask scheduler with two one-thread workers
that this script starts on 127.0.0.1 (``dask scheduler``, ``dask worker --nthreads 1``) and
stops at the end. Each run writes its CSV; the files must be byte-identical (results never
depend on the jobs or the backend, and the rows come out in set-up order). Rounds interleave
the three ways so that a change in the machine's load touches them alike; the best of the
rounds is the figure, every round is printed, and so are the load average and the CPU time
of the process tree (on a loaded machine the wall times say little; the CPU times show what
the parallel ways cost beyond the work itself).

    .venv/bin/python benchmarks/bench_sweep_parallel.py [--trials 100000] [--repeat 3]

Where Dask's time went, on this sweep: not in task size or serialisation (a task pickles
to 2.6 kB, its result to 2.4 kB), nor in re-imports (once per worker). The workers spent
1.6 times the CPU of one job on the same set-ups: a Dask nanny starts its workers with
``MALLOC_TRIM_THRESHOLD_=65536``, which makes every large numpy temporary a fresh ``mmap``
paid in page faults. The workers here are started with that variable unset through Dask's
own configuration (``distributed.nanny.pre-spawn-environ``, given to ``dask worker`` in
its environment, as docs/performance.md shows), as the local cluster of ``--backend dask``
is (``mtplan._parallel.NANNY_ENVIRON``).
"""

from __future__ import annotations

import argparse
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

from mtplan.plans.sweep import sweep

VARY = {"incline_deg": [5, 10, 15, 20, 25, 30], "positions": [3, 6, 12]}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def dask_cluster(workers: int = 2):
    """A scheduler and `workers` one-thread workers on 127.0.0.1, as separate processes."""
    import distributed

    dask = shutil.which("dask", path=str(Path(sys.executable).parent)) or shutil.which("dask")
    if dask is None:
        raise SystemExit("the dask command is missing: pip install 'mtplan[dask]'")
    address = f"tcp://127.0.0.1:{_free_port()}"
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    # the nannies start their workers without Dask's MALLOC_TRIM_THRESHOLD_ (see above)
    worker_env = {**os.environ, "DASK_DISTRIBUTED__NANNY__PRE_SPAWN_ENVIRON":
                  "{'MALLOC_TRIM_THRESHOLD_': None}"}
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port",
                               address.rsplit(":", 1)[1], "--no-dashboard"], **quiet)]
    try:
        for _ in range(workers):
            procs.append(subprocess.Popen([dask, "worker", address, "--nthreads", "1",
                                           "--host", "127.0.0.1", "--no-dashboard"],
                                          env=worker_env, **quiet))
        deadline = time.monotonic() + 120
        while True:
            try:
                with distributed.Client(address, timeout=5) as client:
                    client.wait_for_workers(workers, timeout=max(deadline - time.monotonic(), 1))
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.5)
        yield address
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


def _cpu_seconds() -> float:
    """CPU time of this process and all it started (the loky pool, the Dask cluster)."""
    import psutil

    me = psutil.Process()
    total = 0.0
    for p in [me, *me.children(recursive=True)]:
        try:
            t = p.cpu_times()
        except psutil.Error:
            continue
        total += t.user + t.system
    return total


def timed(out: Path, trials: int, **parallel) -> tuple[float, float]:
    """(wall time, CPU time of the whole process tree) of one sweep."""
    out.unlink(missing_ok=True)
    out.with_name(out.name + ".sweep.json").unlink(missing_ok=True)
    c0, t0 = _cpu_seconds(), time.perf_counter()
    sweep("rotary_axis", vary=VARY, trials=trials, rng=1, progress=False, out=out, **parallel)
    return time.perf_counter() - t0, _cpu_seconds() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=3, help="rounds; the best of them is shown")
    args = ap.parse_args()
    print(f"rotary_axis sweep: {len(VARY['incline_deg'])} x {len(VARY['positions'])} set-ups, "
          f"{args.trials} trials each; {os.cpu_count()} cores, load average at start "
          + " ".join(f"{v:.2f}" for v in os.getloadavg()))
    with tempfile.TemporaryDirectory() as tmp, dask_cluster(2) as address:
        tmp = Path(tmp)
        ways = {"1 job": {"n_jobs": 1},
                "loky, 2 jobs": {"n_jobs": 2, "backend": "loky"},
                "dask, 2 workers": {"backend": "dask", "scheduler": address}}
        # a small warm-up: loky's pool and the Dask workers start and import once, as a
        # standing pool or cluster would have done already
        for name, parallel in ways.items():
            timed(tmp / "warm.csv", 1000, **parallel)
        times = {name: [] for name in ways}
        files = {}
        for r in range(args.repeat):
            for name, parallel in ways.items():
                out = tmp / f"{name.split(',')[0]}.{r}.csv"
                times[name].append(timed(out, args.trials, **parallel))
                files.setdefault(name, out.read_bytes())
            print(f"  round {r + 1}: " + ", ".join(f"{n} {t[-1][0]:.2f} s ({t[-1][1]:.1f} CPU-s)"
                                                   for n, t in times.items())
                  + "; load " + " ".join(f"{v:.2f}" for v in os.getloadavg()), flush=True)
    best = {name: min(w for w, _ in t) for name, t in times.items()}
    for name, t in best.items():
        cpu = min(c for _, c in times[name])
        print(f"  {name:16s} best {t:6.2f} s   speed-up over 1 job {best['1 job'] / t:.2f}x"
              f"   CPU {cpu:.1f} s (whole process tree, cluster's idle work included)")
    same = len(set(files.values())) == 1
    print(f"  CSV files of the three ways: {'byte-identical' if same else 'DIFFER'}")
    if not same:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
