"""Time from a lever change to the updated numbers, in the browser, per procedure.

Starts ``mtplan explore`` on a free loopback port, opens each procedure in headless
Chromium (Debian's, driven by Playwright), moves one lever to a new value each time (so
no answer comes from the cache) and reads the page's own clock: from the change event to
the moment the table shows the numbers of that change. The budget plot and the link follow
after that frame; their times, for the changes whose plot was drawn before the next change
came, are the second line. Prints p50, p95 and max per procedure [ms], the server's CPU
time per change [ms] (a figure the machine's load changes far less than the wall times: on
an idle machine a change takes about that plus the page's own work) and the machine's
load average beside each line.

    python benchmarks/bench_explore.py [--changes N]

With ``--end-stops`` it times instead, in this process, what the page asks of the server
for every slider at each end of its range, alone and with all the others at the same end:
the numbers (``evaluate``), the spot check and the sensitivity curve, wall and CPU time;
each should answer within 2 s on an idle machine, with numbers or a plain refusal.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import sys
import time

import numpy as np

from mtplan.testing.browser import chromium, served_designer

#: procedure -> (lever, first value, step, starting set-up)
LEVERS = {
    "rotary_axis": ("incline_deg", 10.0, 2.5, {}),
    "circle_centre": ("spread_deg", 120.0, 10.0, {}),
    "tracker_frame": ("a_arc_deg", 30.0, 3.0, {}),
    "geometry21": ("circle_radius_mm", 30.0, 2.0, {}),
    # at its default scan (15 600 readings), whose first-order prediction is its own
    # budget hook's, not a linearisation over every reading
    "line_laser": ("raise_mm", 1.0, 0.1, {}),
}


def _cpu_s(pid: int) -> float:
    """User and system CPU time of a process [s] (Linux: /proc/PID/stat)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def end_stops(only=None) -> None:
    """Every slider's end-stops, alone and together: the slowest answers per procedure."""
    from mtplan._parallel import one_blas_thread
    from mtplan._validate import InvalidInput
    from mtplan.explore import design as d

    blas = one_blas_thread()  # as the server runs
    print(f"load average before: {os.getloadavg()}, cores: {os.cpu_count()}")
    for name in LEVERS:
        if only and name not in only:
            continue
        sliders = d.sliders(name)
        designs = [{f["name"]: str(f[end])} for f in sliders for end in ("low", "high")]
        designs += [{f["name"]: str(f[end]) for f in sliders} for end in ("low", "high")]
        worst, refused = {}, 0
        for setup in designs:
            design = {"procedure": name, "setup": setup}
            for what, call in (("evaluate", d.evaluate), ("check", d.check),
                               ("sensitivity", d.sensitivity)):
                t, c = time.perf_counter(), time.process_time()
                try:
                    r = call(design)
                except InvalidInput:  # refused (the page shows the one line)
                    r = {"ok": False}
                wall, cpu = time.perf_counter() - t, time.process_time() - c
                worst[what] = max(worst.get(what, (0, 0)), (wall, cpu))
                if what == "evaluate" and not r.get("ok"):
                    refused += 1
                    break  # the page asks nothing more of a refused set-up
        print(f"{name:14s} {len(designs):3d} end-stop set-ups, {refused} refused; slowest: "
              + "; ".join(f"{k} {1000 * w:.0f} ms wall, {1000 * c:.0f} ms CPU"
                          for k, (w, c) in worst.items())
              + f"  load {os.getloadavg()[0]:.1f}")
    blas.restore_original_limits()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--changes", type=int, default=20, help="lever changes per procedure")
    ap.add_argument("--only", nargs="*", help="procedures to time (default all)")
    ap.add_argument("--end-stops", action="store_true",
                    help="time every slider's end-stops in this process instead")
    args = ap.parse_args(argv)
    if args.end_stops:
        end_stops(args.only)
        return 0
    with served_designer(quiet=True, tries=200) as (server, link), chromium() as browser:
        print(f"load average before: {os.getloadavg()}, cores: {os.cpu_count()}")
        for name, (field, start, step, setup) in LEVERS.items():
            if args.only and name not in args.only:
                continue
            page = browser.new_page()
            page.set_default_timeout(300_000)
            design = base64.urlsafe_b64encode(json.dumps(
                {"procedure": name, "setup": setup}).encode()).decode().rstrip("=")
            page.goto(f"{link}&d={design}")
            page.wait_for_function("window.mtplan && window.mtplan.rendered > 0")
            cpu = _cpu_s(server.pid)
            for i in range(args.changes):
                page.evaluate(f"""() => {{ const b = document.getElementById('f-{field}');
                    b.value = '{start + i * step:.6g}';
                    b.dispatchEvent(new Event('change')); }}""")
                page.wait_for_function("window.mtplan.rendered === window.mtplan.changes "
                                       "&& !window.mtplan.inflight")
            cpu = (_cpu_s(server.pid) - cpu) / args.changes
            page.wait_for_function("window.mtplan.drawn === window.mtplan.rendered")
            lat = np.array(page.evaluate("window.mtplan.latencies"))[1:]  # the change ones
            fig = np.array(page.evaluate("window.mtplan.figureLatencies"))[1:]
            print(f"{name:14s} {field:18s} n={lat.size:3d}  p50 {np.percentile(lat, 50):5.0f} ms"
                  f"  p95 {np.percentile(lat, 95):5.0f} ms  max {lat.max():5.0f} ms"
                  f"  server CPU {1000 * cpu:4.0f} ms/change"
                  f"  load {os.getloadavg()[0]:.1f}")
            if fig.size:  # the changes whose plot was drawn before the next change
                print(f"{'':14s} {'with the figures':18s} n={fig.size:3d}  p50 "
                      f"{np.percentile(fig, 50):5.0f} ms  p95 {np.percentile(fig, 95):5.0f} ms")
            page.close()
        print(f"load average after: {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
