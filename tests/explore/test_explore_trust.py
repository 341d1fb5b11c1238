"""The live numbers are never wrong unmarked.

- Every procedure at its defaults, with every estimator: a live cell shown as trusted
  agrees with an independent Monte Carlo within a factor 1.5 (plus three of that Monte
  Carlo's standard errors); every other cell is marked (or the set-up refused from its
  cost, which shows no number at all).
- The designer opens on the command line's default estimator.

That they never cost the machine (every slider's end-stop) is
``test_explore_end_stops.py``'s (a file of its own: the two halves take a minute or two
each, and the suite's workers take a file each).
"""

from __future__ import annotations

import json
import math

import pytest

from mtplan.evaluation.simulation import simulate_uncertainty
from mtplan.explore import design as d
from mtplan.models import registry

CASES = [(p.name, e) for p in registry().values() for e in p.estimators]
TRIALS = 300  # the independent Monte Carlo; its u is within 1/sqrt(2(n-1)) = 4 % (1 se)


@pytest.mark.parametrize("name, estimator", CASES)
def test_no_live_cell_is_far_from_its_monte_carlo_unmarked(name, estimator):
    design = {"procedure": name, "estimator": estimator}
    r = d.evaluate(design)
    if not r["ok"]:  # refused as a whole: no number is shown
        assert r["problems"] and len(r["problems"]) == 1, r
        return
    trusted = d.check(design)["trust"]
    mc = simulate_uncertainty(name, estimator=estimator, trials=TRIALS, rng=7).to_dict()
    mc_u = {m["name"]: m["u"] for m in mc["measurands"]}
    allowed = 1.5 * (1 + 3 / math.sqrt(2 * (TRIALS - 1)))
    for row in r["measurands"]:
        t = trusted[row["name"]]
        assert t["trust"] in ("ok", "no", "unchecked") and t["why"]
        if t["trust"] != "ok":
            continue
        u, ref = row["u"], mc_u[row["name"]]
        if u == 0:
            assert ref == 0, (row["name"], u, ref)
            continue
        assert 1 / allowed <= ref / u <= allowed, (row["name"], u, ref, t)


def test_line_laser_patent_blind_and_far_cells_are_marked_and_never_meet_a_target():
    design = {"procedure": "line_laser", "targets": {"alpha_z": 10, "alpha_x": 1e9}}
    d.check(design)
    r = d.evaluate(design)
    rows = {m["name"]: m for m in r["measurands"]}
    assert rows["alpha_z"]["trust"] == "no" and rows["alpha_x"]["trust"] == "no"
    assert "step" in rows["alpha_z"]["why"] or "u = 0" in rows["alpha_z"]["why"]


@pytest.mark.parametrize("name", sorted(registry()))
def test_opens_on_the_command_lines_default_estimator(name, capsys):
    from mtplan.cli import main

    assert main(["simulate", name, "--trials", "20", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert d.normalise({"procedure": name})["estimator"] == doc["estimator"]
