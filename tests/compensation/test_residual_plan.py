"""Planning for the compensation the user wants: a target on the residual after it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mtplan import models
from mtplan._validate import InvalidInput
from mtplan.plans.planner import plan, target_u


def test_the_residual_adds_what_the_test_cannot_see():
    proc = models.get("geometry21")
    setup = proc.setup(path_residual_um=0.4, medium_wave_um=0.0)
    assert target_u(proc, setup, "residual:EXX", {"EXX": 0.3}) == pytest.approx(0.5)
    medium = proc.setup(path_residual_um=0.0, medium_wave_um=0.4)  # the medium wave too
    assert target_u(proc, medium, "residual:EYX", {"EYX": 0.3}) == pytest.approx(0.5)
    assert target_u(proc, setup, "residual:EXX@-20", {"EXX@-20": 0.3}) == pytest.approx(0.5)
    assert target_u(proc, setup, "residual:EBX", {"EBX": 3.0}) == 3.0  # angles: none stated
    assert target_u(proc, setup, "EXX", {"EXX": 0.3}) == 0.3
    assert math.isnan(target_u(proc, setup, "residual:EAX", {"EXX": 0.3}))


def test_geometry21_needs_more_repeats_for_the_same_target_on_the_residual():
    """EXX's u falls from 0.60 to 0.58 um from one to two line repeats; with the path
    residual's 0.3 um that the test cannot see, the residual after compensation meets
    0.66 um only with two (sqrt(0.66^2 - 0.3^2) = 0.588 um). Without the medium wave, whose
    0.3 um more would leave the two set-ups 0.005 um apart around the target."""
    proc = models.get("geometry21")
    base = proc.setup(medium_wave_um=0.0)
    kwargs = dict(vary={"line_repeats": [1, 2]}, trials=100, confirm=2)
    on_value = plan(proc, base, targets={"EXX": 0.66}, **kwargs)
    on_residual = plan(proc, base, targets={"residual:EXX": 0.66}, **kwargs)
    assert on_value.best["setup"]["line_repeats"] == 1
    assert on_residual.best["setup"]["line_repeats"] == 2
    best = on_residual.best
    assert best["predicted"]["residual:EXX"] == pytest.approx(
        math.hypot(best["predicted"]["EXX"], 0.3), rel=1e-12)
    assert best["confirmed"]["residual:EXX"] <= 0.66


def test_a_residual_target_needs_a_measurand_and_a_correction():
    with pytest.raises(InvalidInput, match="names no measurand"):
        plan("circle_centre", None, targets={"residual:centre_z": 2.0}, trials=100)


def test_the_plans_set_up_meets_the_residual_target_in_a_closed_loop():
    """circle_centre: the plan's set-up for a residual target of the work offset, then a
    closed loop by Monte Carlo: 4000 machines, each probed, estimated and corrected; the
    true residual's spread (true centre minus the written correction) meets the target
    within its Monte Carlo error."""
    proc = models.get("circle_centre")
    target = 2.0
    result = plan(proc, None, vary={"n_points": [3, 4, 6, 8]},
                  targets={"residual:centre_x": target}, k=2, trials=200, confirm=2)
    setup = proc.setup(result.best["setup"])
    truth = proc.Truth()
    readings = proc.simulate(setup, truth, draws=4000, rng=11)
    estimate = proc.display_estimate(setup, readings)
    true = proc.display_truth(setup, truth)
    residual = true["centre_x"] - estimate["centre_x"]  # the neutral table: no rounding
    spread = 2 * np.std(residual)
    assert spread <= target * (1 + 3 / math.sqrt(2 * 4000))


def test_a_study_plan_takes_a_residual_target():
    from mtplan.plans.study import load_study

    study = {"title": "t", "procedure": [{"name": "circle_centre", "plan": {
        "targets": {"residual:centre_x": 2.0}, "vary": {"n_points": [3, 4]}}}]}
    assert load_study(study).procedures[0].plan["targets"] == {"residual:centre_x": 2.0}
    study["procedure"][0]["plan"]["targets"] = {"residual:centre_z": 2.0}
    with pytest.raises(InvalidInput, match="'residual:centre_z', which is no measurand"):
        load_study(study)
