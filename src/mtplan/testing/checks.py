"""The conformance checks: plain functions of a Procedure, each raising AssertionError.

Every check runs at the procedure's default set-up and truth, with tolerances that hold for
any procedure (no per-procedure table): a procedure states what the checks need as data of
its record (its exact estimators, its levers) and chooses defaults at which they hold.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from contextlib import contextmanager

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.evaluation.simulation import simulate_uncertainty
from mtplan.models.protocol import UNITS, Procedure, fields_info, make

__all__ = ["CHECKS", "NOISE_FREE_ATOL", "bad_values", "numeric_fields"]

#: the largest difference [display unit: um, urad, ...] between an exact estimator's value
#: from noise-free readings and the truth: round-off and iteration tolerances stay far below
#: it, a model error (a sign, a factor, a lost term) far above
NOISE_FREE_ATOL = 1e-6
#: trials and block size of the seed and n_jobs check: three blocks, so that two workers
#: share them unevenly
INVARIANCE_TRIALS, INVARIANCE_BLOCK = 96, 32


def _expect(condition, message: str) -> None:
    """AssertionError(message) unless `condition` (an ``assert`` that ``python -O`` keeps)."""
    if not condition:
        raise AssertionError(message)


@contextmanager
def _accepted(what: str):
    """The block must not raise InvalidInput: `what` is a set-up the procedure accepts."""
    try:
        yield
    except InvalidInput as exc:
        raise AssertionError(f"{what} is refused: {exc}") from None


@contextmanager
def _refused(what: str, *needles: str):
    """The block must raise InvalidInput whose message holds every one of `needles`; the
    list it yields then holds that error."""
    caught: list[InvalidInput] = []
    try:
        yield caught
    except InvalidInput as exc:
        missing = [n for n in needles if n not in str(exc)]
        _expect(not missing, f"{what}: the error does not name {missing}: {exc}")
        caught.append(exc)
    else:
        raise AssertionError(f"{what}: no InvalidInput was raised")


def check_defaults_construct(proc: Procedure) -> None:
    """The default Setup and Truth build, also through the record's helpers; the procedure
    has a title and at least one estimator."""
    setup, truth = proc.Setup(), proc.Truth()
    _expect(proc.setup() == setup, "proc.setup() differs from Setup()")
    _expect(proc.truth() == truth, "proc.truth() differs from Truth()")
    _expect(proc.title, "the procedure has no title")
    _expect(proc.estimators, "the procedure has no estimator")


def check_measurands(proc: Procedure) -> None:
    """Measurands have distinct names and known display units; ``true_values`` gives a finite
    value for each of them and nothing else."""
    setup = proc.Setup()
    names = [m.name for m in proc.measurands(setup)]
    _expect(names, "the procedure has no measurand")
    _expect(len(names) == len(set(names)), f"measurand names repeat: {names}")
    units = {m.name: m.unit for m in proc.measurands(setup) if m.unit not in UNITS}
    _expect(not units, f"measurands with a unit not in {sorted(UNITS)}: {units}")
    tv = proc.true_values(setup, proc.Truth())
    _expect(set(tv) == set(names), f"true_values gives {sorted(tv)}, the measurands are {names}")
    bad = {k: v for k, v in tv.items() if not math.isfinite(float(v))}
    _expect(not bad, f"true values that are not finite: {bad}")


def check_source_method(proc: Procedure) -> None:
    """The source method is cited (``source_method.title``) and is one of the estimators, by
    the name ``source_method.estimator`` gives (``patent`` unless the procedure names its
    own)."""
    method = proc.source_method
    _expect(method.estimator in proc.estimators,
            f"the source method is the estimator {method.estimator!r} "
            f"(Capabilities(source_method=SourceMethod(estimator=...))), but the estimators are "
            f"{', '.join(map(repr, proc.estimators))}: name the source method's estimator "
            f"'patent', or name it in SourceMethod(estimator=...)")
    _expect(method.title, "the source method is not cited: give its title (and its document, "
                          "e.g. 'patent CN101982726', or who published it and when) in "
                          "Capabilities(source_method=SourceMethod(...))")


def _sizing_fields(proc: Procedure, sources) -> dict:
    """Source name -> the set-up field it declares (``Source(field=...)``), for the sources
    whose field is a numeric set-up field; the others are refused, naming each."""
    numeric = {f.name for f in numeric_fields(proc)}
    bad = {name: src.field for name, src in sources.items() if src.field not in numeric}
    _expect(not bad, "sources whose Source(field=...) names no numeric set-up field: "
            + ", ".join(f"{name} (field {field!r})" for name, field in bad.items()))
    return {name: src.field for name, src in sources.items()}


def check_sources_declare_their_fields(proc: Procedure) -> None:
    """Every error source declares the numeric set-up field that sizes it
    (``Source(field=...)``) and is described."""
    sources = proc.sources(proc.Setup())
    _expect(sources, "a procedure without error sources has nothing to simulate")
    _sizing_fields(proc, sources)
    undescribed = [name for name, src in sources.items() if not src.description]
    _expect(not undescribed, f"sources without a description: {undescribed}")


def check_switching_a_source_off_through_its_field(proc: Procedure) -> None:
    """Setting a source's field to 0 switches that source off."""
    setup = proc.Setup()
    fields = _sizing_fields(proc, proc.sources(setup))
    for name in proc.active_sources(setup):
        off = make(proc.Setup, {fields[name]: 0}, base=setup, owner=proc.name)
        _expect(name not in proc.active_sources(off),
                f"{fields[name]}=0 does not switch {name} off")


def check_levers(proc: Procedure) -> None:
    """The levers (the fields an engineer chooses) are set-up fields, and none sizes an error
    source (that is a property of the machine, the workpiece or the instrument)."""
    fields = {f.name for f in fields_info(proc.Setup)}
    _expect(proc.levers, "the procedure names no levers (the set-up fields a planner may vary)")
    unknown = set(proc.levers) - fields
    _expect(not unknown, f"levers that are no set-up field: {sorted(unknown)}")
    sized = {src.field for src in proc.sources(proc.Setup()).values()}
    _expect(not sized & set(proc.levers),
            f"levers that size an error source: {sorted(sized & set(proc.levers))}")


def check_lever_options_and_calibrations(proc: Procedure) -> None:
    """Only levers declare ``levels`` (the planner's options; ``param`` checks each against
    the field's range), and each calibration sets set-up fields to values the procedure
    accepts at its defaults and removes sources it has."""
    setup = proc.Setup()
    stray = [f.name for f in fields_info(proc.Setup) if f.levels and f.name not in proc.levers]
    _expect(not stray, f"fields that declare levels but are no lever: {stray}")
    for cal in proc.capabilities.calibrations:
        _expect(cal.values, f"the calibration {cal.name!r} sets no set-up field")
        with _accepted(f"the calibration {cal.name!r}"):
            make(proc.Setup, dict(cal.values), base=setup, owner=proc.name)
        unknown = sorted(set(cal.removes) - set(proc.sources(setup)))
        _expect(not unknown, f"the calibration {cal.name!r} removes no source {unknown}")


def check_simulate_shapes_and_all_estimators(proc: Procedure) -> None:
    """Simulated readings are batch-first, and every estimator gives a finite (n,) array per
    measurand."""
    setup = proc.Setup()
    readings = proc.simulate(setup, draws=5, rng=1)
    _expect(readings, "simulate gives no readings")
    shapes = {k: np.shape(v) for k, v in readings.items() if np.shape(v)[:1] != (5,)}
    _expect(not shapes, f"readings whose leading axis is not the 5 trials: {shapes}")
    for est in proc.estimators:
        out = proc.display_estimate(setup, readings, est)
        for m in proc.measurands(setup):
            value = np.asarray(out[m.name])
            _expect(value.shape == (5,), f"{est}: {m.name} has shape {value.shape}, not (5,)")
            _expect(np.all(np.isfinite(value)), f"{est}: {m.name} is not finite: {value}")


def check_noise_free_recovery(proc: Procedure) -> None:
    """Every exact estimator recovers the true values from noise-free readings to
    :data:`NOISE_FREE_ATOL`."""
    setup = proc.Setup()
    _expect(proc.exact_names, "mark the estimators that are exact without noise "
                              "(Estimator(..., exact=True))")
    readings = proc.forward(setup, proc.Truth(), proc.zero_errors(setup, 2))
    truth = proc.display_truth(setup)
    for est in proc.exact_names:
        out = proc.display_estimate(setup, readings, est)
        for name, value in truth.items():
            np.testing.assert_allclose(out[name], value, rtol=0, atol=NOISE_FREE_ATOL,
                                       err_msg=f"{est} {name}")


def check_seed_and_n_jobs_invariance(proc: Procedure) -> None:
    """The same seed gives the same result bit for bit, on one worker or two; another seed
    gives another."""
    kw = dict(trials=INVARIANCE_TRIALS, block_size=INVARIANCE_BLOCK, progress=False)
    a = simulate_uncertainty(proc, **kw, rng=11)
    b = simulate_uncertainty(proc, **kw, rng=11, n_jobs=2, backend="threading")
    c = simulate_uncertainty(proc, **kw, rng=11)
    for what in ("mean", "std", "low", "high"):
        np.testing.assert_array_equal(getattr(a.mc, what), getattr(b.mc, what),
                                      err_msg=f"{what}: n_jobs=1 and n_jobs=2 differ")
        np.testing.assert_array_equal(getattr(a.mc, what), getattr(c.mc, what),
                                      err_msg=f"{what}: two runs with one seed differ")
    d = simulate_uncertainty(proc, **kw, rng=12)
    _expect(not np.array_equal(a.mc.mean, d.mc.mean), "seeds 11 and 12 give the same mean")


def check_readings_round_trip(proc: Procedure) -> None:
    """One measurement's readings go through ``readings.frame`` and ``readings.from_frame``
    unchanged,
    and estimate the same."""
    setup = proc.Setup()
    readings = proc.simulate(setup, draws=3, rng=2)
    frame = proc.readings.frame(setup, readings)
    _expect(len(frame) > 0, "readings.frame gives an empty table")
    _expect(frame.notna().all().all(), "readings.frame leaves empty cells")
    back = proc.readings.from_frame(setup, frame)
    _expect(set(back) == set(readings),
            f"from_frame gives {sorted(back)}, simulate gave {sorted(readings)}")
    for key, value in back.items():
        value = np.asarray(value)
        _expect(value.shape[:1] == (1,), f"from_frame's {key!r} is no batch of one: {value.shape}")
        np.testing.assert_array_equal(value[0], np.asarray(readings[key])[0],
                                      err_msg=f"{key} changed on the round trip")
    est_a = proc.display_estimate(setup, back)
    est_b = proc.display_estimate(setup, {k: np.asarray(v)[:1] for k, v in readings.items()})
    for name in est_a:
        np.testing.assert_array_equal(est_a[name], est_b[name], err_msg=name)


def check_duration(proc: Procedure) -> None:
    """The test takes a finite, positive machine time."""
    d = proc.duration(proc.Setup())
    _expect(math.isfinite(d) and d > 0, f"duration {d!r} is not a positive number of seconds")


def check_unknown_field_and_estimator_are_refused(proc: Procedure) -> None:
    """An unknown set-up field, estimator or error source is refused, naming it."""
    with _refused("an unknown set-up field", "no_such_field"):
        proc.setup(no_such_field=1)
    with _refused("an unknown estimator", "estimator", "no_such_estimator"):
        proc.estimator("no_such_estimator")
    with _refused("an unknown error source", "sources", "no_such_source"):
        proc.active_sources(proc.Setup(), ["no_such_source"])


def numeric_fields(proc: Procedure) -> list[dict]:
    """The set-up fields (``fields_info`` records) that hold a number."""
    return [f for f in fields_info(proc.Setup) if f.kind in (int, float)]


def bad_values(info) -> list:
    """Values the set-up field described by `info` (from ``fields_info``) must refuse."""
    bad = [math.nan, "abc"] if info.optional else [math.nan, math.inf, -math.inf, "abc", None]
    if info.low is not None:
        bad.append(info.low - (1 if info.kind is int else 1e-3 * max(abs(info.low), 1)))
    if info.high is not None:
        bad.append(info.high + (1 if info.kind is int else 1e-3 * max(abs(info.high), 1)))
    if info.kind is int:
        bad.append(2.5)
    return bad


def check_all_problems_reported_at_once(proc: Procedure) -> None:
    """Several bad fields are refused together, each named."""
    fields = [f.name for f in numeric_fields(proc)[:3]]
    with _refused("fields that are no number", *fields) as caught:
        make(proc.Setup, {f: "not-a-number" for f in fields}, owner=proc.name)
    problems = caught[0].problems
    _expect(len(problems) >= len(fields),
            f"{len(problems)} problems listed for {len(fields)} bad fields: {problems}")


def check_bad_setup_values_name_the_field(proc: Procedure) -> None:
    """Every value out of a numeric field's range or kind (NaN, infinities, text, None, just
    past a bound, a fraction for a count) is refused, naming the field."""
    for info in numeric_fields(proc):
        for value in bad_values(info):
            with _refused(f"{info.name}={value!r}", info.name):
                proc.Setup(**{info.name: value})


#: every check, in the order they are worth reading; each takes the Procedure
CHECKS: tuple[Callable[[Procedure], None], ...] = (
    check_defaults_construct,
    check_measurands,
    check_source_method,
    check_sources_declare_their_fields,
    check_switching_a_source_off_through_its_field,
    check_levers,
    check_lever_options_and_calibrations,
    check_simulate_shapes_and_all_estimators,
    check_noise_free_recovery,
    check_seed_and_n_jobs_invariance,
    check_readings_round_trip,
    check_duration,
    check_unknown_field_and_estimator_are_refused,
    check_all_problems_reported_at_once,
    check_bad_setup_values_name_the_field,
)
