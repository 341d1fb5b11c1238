"""A running ``mtplan explore`` for the tests: started as the user starts it, on a free
loopback port, with the link it prints (which holds the launch's token)."""

from __future__ import annotations

import json
import queue
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

import pytest

MTPLAN = [sys.executable, "-m", "mtplan.cli"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class Server:
    link: str  # what the command printed: http://127.0.0.1:PORT/?token=...
    base: str  # http://127.0.0.1:PORT/
    port: int
    token: str
    proc: subprocess.Popen
    output: list = field(default_factory=list)

    def api(self, path: str, body=None, timeout: float = 120):
        """GET (body None) or JSON POST with the token header: (status, parsed answer)."""
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(self.base + path.lstrip("/"), data=data, headers={
            "X-Mtplan-Token": self.token, "Content-Type": "application/json"})
        try:
            with urllib.request.urlopen(req, timeout=timeout) as r:
                return r.status, json.loads(r.read())
        except urllib.error.HTTPError as exc:
            text = exc.read().decode()
            try:
                return exc.code, json.loads(text)
            except ValueError:
                return exc.code, text

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:  # busy computing: stop it
            self.proc.kill()
            self.proc.wait()


def start_server(*args: str, timeout: float = 120, port: int | None = None) -> Server:
    """Start ``mtplan explore ARGS --no-browser`` (on `port`, else a free one) and wait
    until it answers."""
    port = port or free_port()
    proc = subprocess.Popen([*MTPLAN, "explore", *args, "--no-browser", "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: queue.Queue = queue.Queue()
    output: list = []

    def read():  # keeps the pipe drained for the server's whole life
        for line in proc.stdout:
            output.append(line)
            lines.put(line)

    threading.Thread(target=read, daemon=True).start()
    deadline = time.monotonic() + timeout
    link = None
    while link is None:
        try:
            line = lines.get(timeout=max(deadline - time.monotonic(), 0.1))
        except queue.Empty:
            line = None
        if line and "?token=" in line:
            link = line.split("serving on ", 1)[1].split()[0]
        elif proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise RuntimeError("mtplan explore did not start: " + "".join(output))
    server = Server(link=link, base=f"http://127.0.0.1:{port}/", port=port,
                    token=link.split("token=", 1)[1], proc=proc, output=output)
    while True:
        try:
            if server.api("api/procedures", timeout=10)[0] == 200:
                return server
        except OSError:
            pass
        if proc.poll() is not None or time.monotonic() > deadline:
            server.stop()
            raise RuntimeError("mtplan explore did not answer: " + "".join(output))
        time.sleep(0.3)


@pytest.fixture(scope="module")
def browser():
    """Headless Chromium through Playwright: Debian's, as the user has it (else the PATH's)."""
    from playwright.sync_api import sync_playwright

    from tests.reports.conftest import need

    debian = Path("/usr/bin/chromium")
    exe = str(debian) if debian.exists() else need("chromium", "chromium-browser")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=exe, args=["--no-sandbox"])
        yield b
        b.close()
