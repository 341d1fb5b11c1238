"""The live numbers never cost the machine: every slider's end-stop, alone and with all
the others at theirs, gives numbers or a plain refusal from the estimated cost, never a
computation beyond the live budget; set-ups known to cost minutes are refused, not computed.
"""

from __future__ import annotations

import json
import time

import pytest

from mtplan.explore import design as d
from mtplan.models import get, registry


def _ends(f) -> list:
    return [str(f["low"]), str(f["high"])]


def _answers(design) -> str:
    """'numbers', or the refusal, of the page's three live requests; each bounded by the
    estimated cost (what keeps an end-stop from exhausting the machine)."""
    t = time.monotonic()
    r = d.evaluate(design)
    if r["ok"]:
        proc = get(design["procedure"])
        _, setup = d.setup_of(d.normalise(design))
        est = d.normalise(design)["estimator"]
        cost = d.prediction_cost(proc, setup, est)
        assert cost["bytes"] <= d.LIVE_MEMORY and cost["seconds"] <= d.LIVE_SECONDS
        d.check(design)
        d.sensitivity(design)
        answer = "numbers"
    else:
        answer = " ".join(r["problems"]) or json.dumps(r["field_errors"])
        assert "Traceback" not in answer and "\n" not in answer
    # not a timing test (the benchmark times it): a guard against a computation of minutes
    assert time.monotonic() - t < 60, (design, answer)
    return answer


@pytest.mark.parametrize("name", sorted(registry()))
def test_every_slider_end_stop_answers_with_numbers_or_a_plain_refusal(name):
    sliders = d.sliders(name)
    assert sliders
    for f in sliders:
        for end in _ends(f):
            _answers({"procedure": name, "setup": {f["name"]: end}})
    for i in (0, 1):  # every slider at the same end together
        _answers({"procedure": name, "setup": {f["name"]: _ends(f)[i] for f in sliders}})


def test_rotary_axis_fine_lattice_is_refused_from_its_memory_before_computing():
    r = d.evaluate({"procedure": "rotary_axis", "setup": {"lattice_nx": "101",
                                                          "lattice_ny": "101"}})
    # from its size, estimated from the lattice alone (before its sources are built)
    assert not r["ok"] and r["refused"] == "cost" and "lattice_nx may be at most" in \
        r["problems"][0]


def test_line_laser_registration_at_its_defaults_is_refused_not_computed():
    t = time.monotonic()
    r = d.evaluate({"procedure": "line_laser", "estimator": "registration"})
    assert not r["ok"] and r["refused"] == "cost"
    assert time.monotonic() - t < 60  # (minutes when it was computed)
