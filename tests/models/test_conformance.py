"""The conformance suite every procedure passes (scikit-learn's parametrize_with_checks).

Parametrised over every registered procedure and the test-only ``toy_line``:
shapes, units, source naming, seed and ``n_jobs`` invariance, noise-free recovery,
readings round trip, duration, and errors on bad set-ups.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mtplan._validate import InvalidInput
from mtplan.models import registry
from mtplan.models._protocol import UNIT_SUFFIXES, UNITS, Procedure, fields_info, make
from mtplan.evaluation.simulation import simulate_uncertainty
from tests.models import toy_line

PROCEDURES = {"toy_line": toy_line.PROCEDURE, **registry()}
NAMES = list(PROCEDURES)


@pytest.fixture(params=NAMES)
def proc(request) -> Procedure:
    return PROCEDURES[request.param]


def test_registry_finds_the_procedures():
    assert "toy_line" not in registry()  # test procedure is not registered
    for name, p in registry().items():
        assert p.name == name


def test_defaults_construct(proc):
    setup, truth = proc.Setup(), proc.Truth()
    assert proc.setup() == setup
    assert proc.truth() == truth
    assert proc.title and proc.estimators


def test_measurands(proc):
    setup = proc.Setup()
    ms = proc.measurands(setup)
    names = [m.name for m in ms]
    assert len(names) == len(set(names)) > 0
    assert all(m.unit in UNITS for m in ms)
    tv = proc.true_values(setup, proc.Truth())
    assert set(tv) == set(names)
    assert all(math.isfinite(float(v)) for v in tv.values())


def test_sources_are_named_after_setup_fields(proc):
    setup = proc.Setup()
    fields = {f["name"] for f in fields_info(proc.Setup)}
    sources = proc.sources(setup)
    assert sources, "a procedure without error sources has nothing to simulate"
    for name, src in sources.items():
        matches = [f for f in fields if f.startswith(name + "_") and f[len(name) + 1 :] in UNIT_SUFFIXES]
        assert matches, f"source {name!r} has no set-up field {name}_<unit>"
        assert src.description, f"source {name!r} has no description"


def test_switching_a_source_off_through_its_field(proc):
    setup = proc.Setup()
    fields = {f["name"] for f in fields_info(proc.Setup)}
    for name in proc.active_sources(setup):
        field = next(f for f in fields if f.startswith(name + "_") and f[len(name) + 1 :] in UNIT_SUFFIXES)
        off = make(proc.Setup, {field: 0}, base=setup, owner=proc.name)
        assert name not in proc.active_sources(off), f"{field}=0 does not switch {name} off"


def test_simulate_shapes_and_all_estimators(proc):
    setup = proc.Setup()
    readings = proc.simulate(setup, draws=5, rng=1)
    assert readings and all(np.asarray(v).shape[0] == 5 for v in readings.values())
    for est in proc.estimators:
        out = proc.display_estimate(setup, readings, est)
        for m in proc.measurands(setup):
            assert out[m.name].shape == (5,), (est, m.name)
            assert np.all(np.isfinite(out[m.name])), (est, m.name)


def test_noise_free_recovery(proc):
    setup = proc.Setup()
    assert proc.exact_estimators, "name the estimators that are exact without noise"
    readings = proc.forward(setup, proc.Truth(), proc.zero_errors(setup, 2))
    truth = proc.display_truth(setup)
    for est in proc.exact_estimators:
        out = proc.display_estimate(setup, readings, est)
        for name, value in truth.items():
            np.testing.assert_allclose(out[name], value, rtol=0, atol=1e-6, err_msg=f"{est} {name}")


def test_seed_and_n_jobs_invariance(proc):
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


def test_readings_round_trip(proc):
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


def test_duration(proc):
    d = proc.duration(proc.Setup())
    assert math.isfinite(d) and d > 0


def test_unknown_field_and_estimator_are_refused(proc):
    with pytest.raises(InvalidInput, match="no_such_field"):
        proc.setup(no_such_field=1)
    with pytest.raises(InvalidInput, match="estimator"):
        proc.estimator("no_such_estimator")
    with pytest.raises(InvalidInput, match="sources"):
        proc.active_sources(proc.Setup(), ["no_such_source"])


def _bad_values(info):
    bad = [math.nan, math.inf, -math.inf, "abc", None] if not info["optional"] else [math.nan, "abc"]
    if info["low"] is not None:
        bad.append(info["low"] - (1 if info["kind"] is int else 1e-3 * max(abs(info["low"]), 1)))
    if info["high"] is not None:
        bad.append(info["high"] + (1 if info["kind"] is int else 1e-3 * max(abs(info["high"]), 1)))
    if info["kind"] is int:
        bad.append(2.5)
    return bad


def _numeric_fields(proc):
    return [f for f in fields_info(proc.Setup) if f["kind"] in (int, float)]


@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_bad_setup_values_name_the_field(name, data):
    proc = PROCEDURES[name]
    fields = _numeric_fields(proc)
    info = data.draw(st.sampled_from(fields))
    value = data.draw(st.sampled_from(_bad_values(info)))
    with pytest.raises(InvalidInput) as exc:
        proc.Setup(**{info["name"]: value})
    assert info["name"] in str(exc.value)


@pytest.mark.parametrize("name", NAMES)
def test_all_problems_reported_at_once(name):
    proc = PROCEDURES[name]
    fields = _numeric_fields(proc)[:3]
    with pytest.raises(InvalidInput) as exc:
        make(proc.Setup, {f["name"]: "not-a-number" for f in fields}, owner=proc.name)
    for f in fields:
        assert f["name"] in str(exc.value)
    assert len(exc.value.problems) >= len(fields)
