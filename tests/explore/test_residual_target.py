"""The designer takes a target on the residual after compensation (``residual:M``) as a
study's plan does: through the same planner function."""

from __future__ import annotations

import pytest

from mtplan._validate import InvalidInput


def _design(targets, procedure="geometry21", vary=None):
    from mtplan.explore.state import normalise

    return normalise({"procedure": procedure, "targets": targets,
                      "vary": vary or {"line_repeats": "1,2"}, "trials": 200})


def test_a_residual_target_reaches_the_planner():
    from mtplan import models
    from mtplan.explore.jobs import planner_inputs

    design = _design({"residual:EXX": 1.4, "EC0Y": 40})
    vary, targets = planner_inputs(models.get("geometry21"), design)
    assert targets == {"residual:EXX": 1.4, "EC0Y": 40.0}
    assert vary == {"line_repeats": [1, 2]}


def test_a_residual_target_of_no_measurand_is_refused_naming_it():
    from mtplan import models
    from mtplan.explore.jobs import planner_inputs

    with pytest.raises(InvalidInput, match="'residual:nope' names no measurand"):
        planner_inputs(models.get("geometry21"), _design({"residual:nope": 1.0}))


def test_the_cheapest_set_up_for_a_residual_target():
    """rotary_axis states nothing unseen: its residual target is its measured one, so the
    planner gives the same set-up for both."""
    from mtplan.explore.jobs import cheapest

    vary = {"positions": "4,6"}
    measured = cheapest(_design({"EX0C": 200.0}, "rotary_axis", vary))
    residual = cheapest(_design({"residual:EX0C": 200.0}, "rotary_axis", vary))
    assert residual["targets"] == {"residual:EX0C": 200.0}
    best, other = residual["best"], measured["best"]
    assert best["setup"] == other["setup"] and best["duration_s"] == other["duration_s"]
    assert best["predicted"]["residual:EX0C"] == other["predicted"]["EX0C"]
