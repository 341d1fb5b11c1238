"""Time from a lever change to the updated numbers, in the browser, per procedure.

Starts ``mtplan explore`` on a free loopback port, opens each procedure in headless
Chromium (Debian's, driven by Playwright), moves one lever to a new value each time (so
no answer comes from the cache) and reads the page's own clock: from the change event to
the moment the table shows the numbers of that change. Prints p50, p95 and max per
procedure [ms], and the machine's load average.

    python benchmarks/bench_explore.py [--changes N]
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.request

import numpy as np
from playwright.sync_api import sync_playwright

#: Debian's Chromium, as the user has it (else the one on the PATH)
CHROMIUM = ("/usr/bin/chromium" if os.path.exists("/usr/bin/chromium")
            else shutil.which("chromium"))

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


def _start(port):
    """``mtplan explore`` on `port`: (process, the link it printed with its token)."""
    proc = subprocess.Popen([sys.executable, "-m", "mtplan.cli", "explore", "--no-browser",
                             "--port", str(port)], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    link = proc.stdout.readline().split("serving on ", 1)[1].split()[0]
    token = link.split("token=", 1)[1]
    for _ in range(200):
        try:
            urllib.request.urlopen(urllib.request.Request(
                f"http://127.0.0.1:{port}/api/procedures",
                headers={"X-Mtplan-Token": token}), timeout=5)
            return proc, link
        except OSError:
            time.sleep(0.3)
    proc.kill()
    raise RuntimeError("the server did not start")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--changes", type=int, default=20, help="lever changes per procedure")
    ap.add_argument("--only", nargs="*", help="procedures to time (default all)")
    args = ap.parse_args(argv)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server, link = _start(port)
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM,
                                        args=["--no-sandbox"])
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
                for i in range(args.changes):
                    page.evaluate(f"""() => {{ const b = document.getElementById('f-{field}');
                        b.value = '{start + i * step:.6g}';
                        b.dispatchEvent(new Event('change')); }}""")
                    page.wait_for_function("window.mtplan.rendered === window.mtplan.changes "
                                           "&& !window.mtplan.inflight")
                lat = np.array(page.evaluate("window.mtplan.latencies"))[1:]  # the change ones
                print(f"{name:14s} {field:18s} n={lat.size:3d}  p50 {np.percentile(lat, 50):7.0f} ms"
                      f"  p95 {np.percentile(lat, 95):7.0f} ms  max {lat.max():7.0f} ms")
                page.close()
            print(f"load average after: {os.getloadavg()}")
            browser.close()
    finally:
        server.terminate()
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:  # busy computing: stop it
            server.kill()
            server.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main())
