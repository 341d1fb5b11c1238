"""The designer served and opened in Chromium, for the scripts that drive it (the
documentation's screenshots in docs/explore, the designer's benchmark in benchmarks).

    from mtplan.testing.browser import chromium, served_designer

    with served_designer() as (server, link), chromium() as browser:
        page = browser.new_page()
        page.goto(link)

Playwright is imported only by :func:`chromium` (it is not a dependency of mtplan).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.request

__all__ = ["CHROMIUM", "chromium", "free_port", "served_designer"]

#: Debian's Chromium, as the user has it (else the one on the PATH)
CHROMIUM = ("/usr/bin/chromium" if os.path.exists("/usr/bin/chromium")
            else shutil.which("chromium"))


def free_port() -> int:
    """A TCP port free on this machine now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def served_designer(port: int | None = None, *, quiet: bool = False, tries: int = 400):
    """``mtplan explore`` on `port` (default a free one) while the block runs: yields the
    server's process and the link it printed (with its token), once the server answers;
    stops it after the block (terminated, killed when still busy computing after 10 s).

    `quiet`: the server's stderr is discarded. Raises RuntimeError where the server does
    not answer within `tries` tries 0.3 s apart.
    """
    port = free_port() if port is None else port
    server = subprocess.Popen([sys.executable, "-m", "mtplan.cli", "explore", "--no-browser",
                               "--port", str(port)], stdout=subprocess.PIPE,
                              stderr=subprocess.DEVNULL if quiet else None, text=True)
    try:
        line = server.stdout.readline()  # "mtplan explore: serving on http://...?token=..."
        link = line.split("serving on ", 1)[1].split()[0]
        token = link.split("token=", 1)[1]
        for _ in range(tries):
            try:
                urllib.request.urlopen(urllib.request.Request(
                    f"http://127.0.0.1:{port}/api/procedures",
                    headers={"X-Mtplan-Token": token}), timeout=5)
                break
            except OSError:
                time.sleep(0.3)
        else:
            raise RuntimeError("the server did not start")
        yield server, link
    finally:
        server.terminate()
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:  # busy computing: stop it
            server.kill()
            server.wait()


@contextlib.contextmanager
def chromium():
    """A headless Chromium (:data:`CHROMIUM`, without its sandbox) through Playwright, closed
    after the block."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        try:
            yield browser
        finally:
            browser.close()
