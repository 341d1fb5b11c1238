"""The conformance checks every procedure passes, as plain functions of a Procedure.

``tests/models/test_conformance.py`` runs them on every registered procedure and the
test-only ``toy_line``; :func:`check_procedure` runs them all on any one procedure (a new
one, see ``docs/adding_a_procedure.md``):

    from tests.models.conformance import check_procedure
    check_procedure(get("my_procedure"))

Each check raises AssertionError (or the library's own error) naming what is wrong.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mtplan._validate import InvalidInput
from mtplan.evaluation.simulation import simulate_uncertainty
from mtplan.models.protocol import UNIT_SUFFIXES, UNITS, Procedure, fields_info, make

__all__ = ["CHECKS", "check_procedure", "check_bad_setup_value", "bad_values", "numeric_fields"]


def check_defaults_construct(proc: Procedure) -> None:
    setup, truth = proc.Setup(), proc.Truth()
    assert proc.setup() == setup
    assert proc.truth() == truth
    assert proc.title and proc.estimators


def check_measurands(proc: Procedure) -> None:
    setup = proc.Setup()
    ms = proc.measurands(setup)
    names = [m.name for m in ms]
    assert len(names) == len(set(names)) > 0
    assert all(m.unit in UNITS for m in ms)
    tv = proc.true_values(setup, proc.Truth())
    assert set(tv) == set(names)
    assert all(math.isfinite(float(v)) for v in tv.values())


def _source_field(name: str, fields) -> list[str]:
    return [f for f in fields if f.startswith(name + "_") and f[len(name) + 1:] in UNIT_SUFFIXES]


def check_sources_are_named_after_setup_fields(proc: Procedure) -> None:
    fields = {f["name"] for f in fields_info(proc.Setup)}
    sources = proc.sources(proc.Setup())
    assert sources, "a procedure without error sources has nothing to simulate"
    for name, src in sources.items():
        assert _source_field(name, fields), f"source {name!r} has no set-up field {name}_<unit>"
        assert src.description, f"source {name!r} has no description"


def check_switching_a_source_off_through_its_field(proc: Procedure) -> None:
    setup = proc.Setup()
    fields = {f["name"] for f in fields_info(proc.Setup)}
    for name in proc.active_sources(setup):
        field = _source_field(name, fields)[0]
        off = make(proc.Setup, {field: 0}, base=setup, owner=proc.name)
        assert name not in proc.active_sources(off), f"{field}=0 does not switch {name} off"


def check_simulate_shapes_and_all_estimators(proc: Procedure) -> None:
    setup = proc.Setup()
    readings = proc.simulate(setup, draws=5, rng=1)
    assert readings and all(np.asarray(v).shape[0] == 5 for v in readings.values())
    for est in proc.estimators:
        out = proc.display_estimate(setup, readings, est)
        for m in proc.measurands(setup):
            assert out[m.name].shape == (5,), (est, m.name)
            assert np.all(np.isfinite(out[m.name])), (est, m.name)


def check_noise_free_recovery(proc: Procedure) -> None:
    setup = proc.Setup()
    assert proc.exact_estimators, "name the estimators that are exact without noise"
    readings = proc.forward(setup, proc.Truth(), proc.zero_errors(setup, 2))
    truth = proc.display_truth(setup)
    for est in proc.exact_estimators:
        out = proc.display_estimate(setup, readings, est)
        for name, value in truth.items():
            np.testing.assert_allclose(out[name], value, rtol=0, atol=1e-6, err_msg=f"{est} {name}")


def check_seed_and_n_jobs_invariance(proc: Procedure) -> None:
    kw = dict(trials=96, block_size=32, rng=11)
    a = simulate_uncertainty(proc, **kw)
    b = simulate_uncertainty(proc, **kw, n_jobs=2, backend="threading")
    c = simulate_uncertainty(proc, **kw)
    np.testing.assert_array_equal(a.mc.mean, b.mc.mean)
    np.testing.assert_array_equal(a.mc.std, b.mc.std)
    np.testing.assert_array_equal(a.mc.low, b.mc.low)
    np.testing.assert_array_equal(a.mc.mean, c.mc.mean)
    d = simulate_uncertainty(proc, trials=96, block_size=32, rng=12)
    assert not np.array_equal(a.mc.mean, d.mc.mean)


def check_readings_round_trip(proc: Procedure) -> None:
    setup = proc.Setup()
    readings = proc.simulate(setup, draws=3, rng=2)
    frame = proc.readings_frame(setup, readings)
    assert len(frame) > 0 and frame.notna().all().all()
    back = proc.from_frame(setup, frame)
    assert set(back) == set(readings)
    for key, value in back.items():
        value = np.asarray(value)
        assert value.shape[0] == 1
        np.testing.assert_array_equal(value[0], np.asarray(readings[key])[0])
    est_a = proc.display_estimate(setup, back)
    est_b = proc.display_estimate(setup, {k: np.asarray(v)[:1] for k, v in readings.items()})
    for name in est_a:
        np.testing.assert_array_equal(est_a[name], est_b[name])


def check_duration(proc: Procedure) -> None:
    d = proc.duration(proc.Setup())
    assert math.isfinite(d) and d > 0


def check_unknown_field_and_estimator_are_refused(proc: Procedure) -> None:
    with pytest.raises(InvalidInput, match="no_such_field"):
        proc.setup(no_such_field=1)
    with pytest.raises(InvalidInput, match="estimator"):
        proc.estimator("no_such_estimator")
    with pytest.raises(InvalidInput, match="sources"):
        proc.active_sources(proc.Setup(), ["no_such_source"])


def check_all_problems_reported_at_once(proc: Procedure) -> None:
    fields = numeric_fields(proc)[:3]
    with pytest.raises(InvalidInput) as exc:
        make(proc.Setup, {f["name"]: "not-a-number" for f in fields}, owner=proc.name)
    for f in fields:
        assert f["name"] in str(exc.value)
    assert len(exc.value.problems) >= len(fields)


def bad_values(info) -> list:
    """Values the set-up field described by `info` (from ``fields_info``) must refuse."""
    bad = [math.nan, math.inf, -math.inf, "abc", None] if not info["optional"] else [math.nan, "abc"]
    if info["low"] is not None:
        bad.append(info["low"] - (1 if info["kind"] is int else 1e-3 * max(abs(info["low"]), 1)))
    if info["high"] is not None:
        bad.append(info["high"] + (1 if info["kind"] is int else 1e-3 * max(abs(info["high"]), 1)))
    if info["kind"] is int:
        bad.append(2.5)
    return bad


def numeric_fields(proc: Procedure) -> list[dict]:
    return [f for f in fields_info(proc.Setup) if f["kind"] in (int, float)]


def check_bad_setup_value(proc: Procedure, info, value) -> None:
    """A bad value of one set-up field is refused with a message naming the field."""
    with pytest.raises(InvalidInput) as exc:
        proc.Setup(**{info["name"]: value})
    assert info["name"] in str(exc.value)


def check_bad_setup_values_name_the_field(proc: Procedure) -> None:
    """Every bad value of every numeric field (the registered procedures draw a sample of
    them with hypothesis instead)."""
    for info in numeric_fields(proc):
        for value in bad_values(info):
            check_bad_setup_value(proc, info, value)


#: every check of one procedure, in the order they are worth reading
CHECKS = (
    check_defaults_construct,
    check_measurands,
    check_sources_are_named_after_setup_fields,
    check_switching_a_source_off_through_its_field,
    check_simulate_shapes_and_all_estimators,
    check_noise_free_recovery,
    check_seed_and_n_jobs_invariance,
    check_readings_round_trip,
    check_duration,
    check_unknown_field_and_estimator_are_refused,
    check_all_problems_reported_at_once,
)


def check_procedure(proc: Procedure) -> None:
    """Run every conformance check on `proc`, the exhaustive bad-value check included."""
    for check in (*CHECKS, check_bad_setup_values_name_the_field):
        check(proc)
