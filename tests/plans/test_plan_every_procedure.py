"""`mtplan plan` end to end on every registered procedure (small set-ups, few trials)."""

from __future__ import annotations

import json

import pytest

from mtplan import cli
from mtplan.models import registry

# a cheap set-up and a field to vary per procedure (geometry21's full set-up has ~3500
# error inputs: its linearisation takes seconds, so the test uses fewer points)
CASES = {
    "circle_centre": ([], "n_points=3,5", "centre_x"),
    "geometry21": (["line_points=9", "line_repeats=1", "circle_points=24"],
                   "circle_radius_mm=30,60", "EXX"),
    "line_laser": (["lines=16", "points_per_line=33"], "raise_mm=1,2", "alpha_y"),
    "rotary_axis": ([], "positions=3,6", "EX0C"),
    "tracker_frame": (["n_submachines=1"], "a_arc_deg=60,120", "origin_z_1"),
}


def test_every_procedure_has_a_case():
    assert set(CASES) == set(registry())


@pytest.mark.parametrize("name", sorted(registry()))
def test_plan_end_to_end(capsys, name):
    sets, vary, measurand = CASES[name]
    argv = ["plan", name, "--vary", vary, "--trials", "300", "--json", "--confirm", "2"]
    for s in sets:
        argv += ["--set", s]
    # a target every candidate meets: the cheapest candidate wins and is confirmed
    assert cli.main([*argv, "--target", f"{measurand}<=1e9"]) == 0
    doc = json.loads(capsys.readouterr().out)
    best = doc["best"]
    assert best["confirmed"][measurand] <= 1e9 and doc["confirmation"][-1]["met"]
    ident = best["identifiability"]
    assert set(ident) == {"rank", "n_params", "condition", "O1", "O2", "O3", "O4", "O5"}
    assert 0 < ident["rank"] <= ident["n_params"]
    durations = [c["duration_s"] for c in doc["pareto"]]
    assert best["duration_s"] == min(durations)
    # an impossible target names the best reachable value, exit 2, one line
    assert cli.main([*argv, "--target", f"{measurand}<=1e-9"]) == 2
    err = capsys.readouterr().err
    assert "cannot be met" in err and "best reachable" in err and len(err.strip().splitlines()) == 1
