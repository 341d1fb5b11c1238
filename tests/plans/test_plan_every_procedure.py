"""`mtplan plan` end to end on every registered procedure (default set-ups, few trials)."""

from __future__ import annotations

import json

import pytest

from mtplan import cli
from mtplan._validate import InvalidInput
from mtplan.models import registry
from mtplan.models.protocol import fields_info


def _case(proc) -> tuple[str, str]:
    """(--vary, measurand) for `proc`, read from its record: its first numeric lever, from
    its default to the next value its set-up takes, and its first measurand that the default
    estimator gives continuously, at the default set-up (no table to keep: a procedure's
    defaults are its cheap, representative set-up). A quantised measurand (one with a
    ``resolution`` step) has a linearised u of 0: the planner predicts that it meets any
    target, and only the Monte Carlo confirmation refuses, with another message."""
    setup = proc.Setup()
    steps = proc.estimators[proc.default_estimator].steps(setup)
    measurand = next(m.name for m in proc.measurands(setup) if m.name not in steps)
    fields = {info.name: info for info in fields_info(proc.Setup)}
    for info in (fields[lever] for lever in proc.levers):
        default = getattr(setup, info.name)
        if info.kind not in (int, float) or default is None:
            continue
        step = 1 if info.kind is int else abs(default) / 4 or 1.0
        for other in (default + step, default - step):
            try:
                proc.setup(**{info.name: other})
            except InvalidInput:
                continue
            return f"{info.name}={default},{other}", measurand
    raise AssertionError(f"{proc.name} has no numeric lever a plan could vary")


@pytest.mark.parametrize("name", sorted(registry()))
def test_plan_end_to_end(capsys, name):
    vary, measurand = _case(registry()[name])
    argv = ["plan", name, "--vary", vary, "--trials", "300", "--json", "--confirm", "2"]
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
