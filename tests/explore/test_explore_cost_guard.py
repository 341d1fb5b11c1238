"""The cost guard before any work: every field that sizes the work (the integer counts:
points, lines, repeats, lattice, positions, sub-machines) has a largest allowed value, and
at it and beyond it, alone and with all the others at theirs, the server answers within
2 s with numbers or a plain refusal, its memory back within 200 MB of its level before."""

from __future__ import annotations

import os
import time

import pytest

from mtplan.models import registry
from mtplan.models.protocol import fields_info
from tests.explore.test_explore_browser import server  # noqa: F401 (mtplan explore)

COUNTS = {name: [f for f in fields_info(p.Setup) if f.kind is int]
          for name, p in registry().items()}


def _proc(pid: int) -> tuple:
    """(resident memory [MB], CPU time [s]) of the server's process."""
    with open(f"/proc/{pid}/status", encoding="ascii") as fh:
        rss = int(next(x for x in fh if x.startswith("VmRSS:")).split()[1]) / 1024
    with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
        fields = fh.read().rsplit(")", 1)[1].split()
    return rss, (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _answer(server, design) -> str:
    """'numbers' or the one-line refusal. The server's CPU time for it is bounded by 2 s
    (the issue's bound on what the page waits for a count at its end-stop; CPU time, as the
    guard itself counts, so that the bound holds on a machine other jobs load too), its
    wall time by a minute (a computation of minutes is what the guard prevents)."""
    cpu, wall = _proc(server.proc.pid)[1], time.monotonic()
    status, r = server.api("api/evaluate", {"design": design})
    took = _proc(server.proc.pid)[1] - cpu
    assert took < 2.0 and time.monotonic() - wall < 60, (design, took)
    if status != 200:
        text = r["error"]
    elif r["ok"]:
        return "numbers"
    else:
        text = " ".join(r["problems"]) or " ".join(r["field_errors"].values())
    assert text and "\n" not in text and "Traceback" not in text and "Error)" not in text
    return text


def test_every_count_has_a_largest_allowed_value():
    unbounded = [f"{n}.{f.name}" for n, fs in COUNTS.items() for f in fs if f.high is None]
    assert unbounded == []


@pytest.mark.parametrize("name", sorted(COUNTS))
def test_each_count_at_its_largest_and_beyond_alone_and_together(server, name):
    _answer(server, {"procedure": name})  # warm: the procedure's one-off costs are not timed
    before = _proc(server.proc.pid)[0]
    for f in COUNTS[name]:
        high = int(f.high)
        _answer(server, {"procedure": name, "setup": {f.name: str(high)}})
        beyond = _answer(server, {"procedure": name, "setup": {f.name: str(high + 1)}})
        assert f.name in beyond and str(high) in beyond, beyond  # names the largest
    _answer(server, {"procedure": name, "setup": {f.name: str(int(f.high))
                                                 for f in COUNTS[name]}})
    assert _proc(server.proc.pid)[0] < before + 200
