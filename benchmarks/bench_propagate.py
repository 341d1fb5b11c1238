"""Speed of the uncertainty engine (a benchmark that prints figures; not a test).

1. ``propagate`` on the JCGM 101 additive model Y = X1 + X2 + X3 + X4 (normal inputs)
   with 10**6 trials, against drawing the same number of normal variates (4 x 10**6)
   with numpy alone; best of several repeats.
2. Start-up time of ``mtplan --help`` (a fresh interpreter each time).

Run: ``.venv/bin/python benchmarks/bench_propagate.py``
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import time

import numpy as np

from mtplan.uncertainty import Normal, propagate


def best(fn, repeat=7):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main():
    trials = 10**6
    inputs = {f"x{i}": Normal(0.0, 1.0) for i in range(1, 5)}

    def model(x1, x2, x3, x4):
        return x1 + x2 + x3 + x4

    t_prop = best(lambda: propagate(model, inputs, trials=trials, rng=1, progress=False))
    rng = np.random.default_rng(1)
    t_bare = best(lambda: rng.standard_normal(4 * trials))
    print(f"propagate, additive model, {trials:.0e} trials: {t_prop * 1e3:.1f} ms")
    print(f"numpy alone, {4 * trials:.0e} normal variates:    {t_bare * 1e3:.1f} ms")
    print(f"ratio: {t_prop / t_bare:.2f} (goal <= 1.5)")
    t_shortest = best(lambda: propagate(model, inputs, trials=trials, rng=1, interval="shortest",
                                        progress=False), repeat=3)
    print(f"propagate with the shortest interval: {t_shortest * 1e3:.1f} ms (a full sort)")

    exe = shutil.which("mtplan") or None
    cmd = [exe, "--help"] if exe else [sys.executable, "-m", "mtplan.cli", "--help"]
    t_help = best(lambda: subprocess.run(cmd, capture_output=True, check=True), repeat=5)
    print(f"'mtplan --help' start-up: {t_help * 1e3:.0f} ms (goal < 1000 ms)")


if __name__ == "__main__":
    main()
