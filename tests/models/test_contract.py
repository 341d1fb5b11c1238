"""The Procedure contract stays small, and every capability only one procedure sets says, in a
test here, why the generic default cannot serve that procedure."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import mtplan.models
from mtplan.models import Procedure, registry
from mtplan.models.protocol import fields_info


def test_procedure_has_at_most_16_fields():
    """The record stays small: what is optional lives in its records with defaults (the
    capabilities' methods, the readings format), not as more fields here. 16: the model's
    ten, description and levers, capabilities, and two records the documents and the
    controller read (the source method's citation, the correction model)."""
    assert len(dataclasses.fields(Procedure)) <= 16


def _setters() -> dict[str, set]:
    """Optional field of the records, or method of the capabilities -> the procedures that
    set it away from its default (override it)."""
    from mtplan.models.protocol import continuous

    out: dict[str, set] = {}
    for name, proc in registry().items():
        for prefix, record in (("readings", proc.readings), ("capabilities", proc.capabilities)):
            for f in dataclasses.fields(record):
                if f.default is not dataclasses.MISSING and getattr(record, f.name) != f.default:
                    out.setdefault(f"{prefix}.{f.name}", set()).add(name)
        for method in proc.capabilities.overrides():
            out.setdefault(f"capabilities.{method}", set()).add(name)
        for est in proc.estimators.values():
            if est.exact:
                out.setdefault("estimator.exact", set()).add(name)
            if est.resolution is not continuous:
                out.setdefault("estimator.resolution", set()).add(name)
    return out


#: each optional field only one procedure sets -> the test below that says why the generic
#: default cannot serve it
WHY_NOT_GENERIC = {
    "capabilities.truths_from_estimates": "test_batched_truths_take_one_forward_run",
    "capabilities.source_structure": "test_facet_colouring_takes_a_forward_row_pair_per_colour",
    "capabilities.start_from_readings": "test_circle_centre_starts_its_least_squares_on_the_readings_branch",
    "capabilities.identifiability_report": "test_geometry21_errors_are_no_float_truth_fields",
    "capabilities.identifiability": "test_geometry21_names_the_errors_a_setup_leaves_out",
    "capabilities.observability": "test_line_laser_patent_cannot_see_what_the_readings_show",
    "estimator.resolution": "test_line_laser_patent_values_come_in_steps",
    "capabilities.gross_errors": "test_circle_centre_a_bad_contact_moves_both_its_coordinates",
    "capabilities.calibrations": "test_rotary_axis_calibration_meets_what_no_lever_does",
}


def test_circle_centre_a_bad_contact_moves_both_its_coordinates():
    """Only circle_centre reads one contact as two readings (x and y of the probed point),
    so only it has a gross error that moves several readings at once: each contact's
    direction is a unit vector along the bore's radius there, over its own x and y alone."""
    import numpy as np

    from mtplan.models import get

    proc = get("circle_centre")
    setup = proc.Setup()
    readings = proc.forward(setup, proc.Truth(), proc.zero_errors(setup, 1))
    kind, labels, D = proc.capabilities.gross_errors(setup, readings)
    assert kind == "a contact along its probing direction"
    assert len(labels) == D.shape[1] == np.asarray(readings["x_mm"]).shape[-1]
    np.testing.assert_allclose(np.linalg.norm(D, axis=0), 1.0, rtol=1e-12)
    assert np.all(np.count_nonzero(D, axis=0) <= 2)
    for name in ("rotary_axis", "geometry21", "line_laser", "tracker_frame"):
        other = get(name)
        assert other.capabilities.gross_errors(other.Setup(), None) is None, name


def test_every_capability_one_procedure_sets_is_explained():
    single = {field for field, procs in _setters().items() if len(procs) == 1}
    assert single == set(WHY_NOT_GENERIC)
    assert all(callable(globals().get(test)) for test in WHY_NOT_GENERIC.values())


def test_estimator_records_describe_themselves_in_plain_words():
    """Each estimator's description is what the reports print (they read ``description``,
    never the docstring): a sentence without markup, the source method called so (not "the
    patent"), and a bare function still gets its docstring's first paragraph."""
    import re

    from mtplan.models.protocol import Estimator

    for proc in registry().values():
        for name, est in proc.estimators.items():
            text = est.description
            assert text.endswith(".") and "``" not in text and ":func:" not in text, name
            assert not re.search(r"\bpatent", text, re.I), (proc.name, name, text)
            assert est.__doc__ == est.function.__doc__

    def bare(setup, readings):
        """A fit of :func:`x` to ``readings``; measurands [mm, rad], (n,).

        More."""
    assert Estimator(bare).description == "A fit of x to readings."


def test_a_bare_function_is_an_estimator_with_the_defaults():
    proc = registry()["circle_centre"]
    fn = proc.estimators["kasa"].function
    bare = dataclasses.replace(proc, estimators={"kasa": fn})
    assert bare.estimators["kasa"].function is fn and not bare.estimators["kasa"].exact
    assert bare.exact_names == ()


# ------------------------------------------------------------ why the generic default cannot serve
def test_batched_truths_take_one_forward_run(monkeypatch):
    """tracker_frame: the generic default (one truth_from_estimate and two forward runs per
    measurand) gives the same sensitivities, in 2 x 12 forward runs instead of one; the
    designer asks for them at every candidate set-up, so the hook is speed, not physics."""
    from mtplan.plans.planner import readings_jacobian

    proc = registry()["tracker_frame"]
    calls = []

    def counted(setup, truth, errors):
        calls.append(1)
        return proc.forward(setup, truth, errors)

    batched = dataclasses.replace(proc, forward=counted)
    generic = dataclasses.replace(batched, capabilities=proc.capabilities.generic(
        "truths_from_estimates"))
    get_ = mtplan.models.get
    monkeypatch.setattr(mtplan.models, "get",
                        lambda p: p if isinstance(p, Procedure) else get_(p))
    setup = proc.Setup()
    j, _ = readings_jacobian(batched, setup)
    assert len(calls) == 1
    calls.clear()
    j0, _ = readings_jacobian(generic, setup)
    assert len(calls) == 2 * len(proc.measurands(setup)) > 1
    np.testing.assert_allclose(j, j0, rtol=0, atol=1e-9 * np.abs(j0).max())


def test_circle_centre_starts_its_least_squares_on_the_readings_branch():
    """circle_centre: the estimate's Truth puts the start point at the bore's centre, where
    the planner's free direction is undefined: the readings predicted there lie on another
    branch of the planned path, tens to hundreds of millimetres from the readings, so a
    local least squares may not find its way back (with the scales' datum 300 mm off it ran
    to a centre 170 mm away). The readings' start (the x of p1 and p2) predicts them to
    micrometres, and the fit check on such readings is sane (chi-square per degree of
    freedom of order 1)."""
    from mtplan.evaluation.fitcheck import fit_check

    proc = registry()["circle_centre"]
    setup = proc.Setup(n_points=6, scale_datum_x_mm=-300.0, scale_datum_y_mm=-300.0)
    readings = proc.simulate(setup, proc.Truth(), 1, rng=4)
    est = {k: float(v[0]) for k, v in proc.estimate(setup, readings).items()}
    generic = proc.capabilities.truth_from_estimate(setup, est)
    started = proc.capabilities.start_from_readings(setup, readings, generic)
    errors = {k: np.zeros((1, *s.shape, *s.distribution.event_shape))
              for k, s in proc.sources(setup).items()}

    def miss(truth):
        pred = proc.forward(setup, truth, errors)
        return max(float(np.max(np.abs(pred[k] - readings[k]))) for k in pred)

    assert miss(generic) > 10.0 and miss(started) < 0.05
    fc = fit_check(proc, setup, readings)
    assert fc.ok is not None and fc.chi2 / fc.dof < 4, fc.summary()


def test_facet_colouring_takes_a_forward_row_pair_per_colour():
    """line_laser: the generic default probes the facets' 180 position errors element by
    element (two forward rows each, 360); the colouring needs two per colour."""
    proc = registry()["line_laser"]
    setup, truth = proc.Setup(), proc.Truth()
    source = proc.sources(setup)["facet_position"]
    colours, owners = proc.capabilities.source_structure(setup, truth, "facet_position")
    assert np.asarray(colours).shape == (source.size,)
    assert len(owners) * 10 <= source.size  # 6 colours for 180 facets at the default


def test_geometry21_errors_are_no_float_truth_fields():
    """geometry21: the generic rank analysis steps the float Truth fields, but the 21 errors
    are polynomial coefficients in tuple fields: the generic default would see 5 of the
    model's parameters."""
    proc = registry()["geometry21"]
    setup = proc.Setup()
    floats = [f.name for f in fields_info(proc.Truth) if f.kind is float]
    rep = proc.capabilities.identifiability_report(setup)
    assert rep["parameters"] > 10 * len(floats)


def test_geometry21_names_the_errors_a_setup_leaves_out():
    """geometry21: which of the 21 errors a set-up determines changes with the set-up; the
    generic default knows only the measurands listed, so it cannot say that arms along the
    YZ plate's normal alone leave EAX, EBY, EAZ and ECZ out, nor why."""
    proc = registry()["geometry21"]
    setup = proc.Setup(poly_order=2, line_points=5, line_repeats=1, circle_points=12,
                       yz_extra_heads_mm=(100, 60, 0, 100, 120, 0))
    table = proc.capabilities.identifiability(setup, "joint")
    listed = {m.name for m in proc.measurands(setup)}
    left_out = set(table.index[~table["listed"].astype(bool)])
    assert left_out == {"EAX", "EBY", "EAZ", "ECZ"} and not left_out & listed


@pytest.fixture(scope="module")
def line_laser_noise_free():
    proc = registry()["line_laser"]
    setup = proc.Setup()
    truth = proc.Truth(alpha_x_mrad=-2.0)
    readings = proc.forward(setup, truth, proc.zero_errors(setup, 1))
    return proc, setup, truth, readings


def test_line_laser_patent_cannot_see_what_the_readings_show(line_laser_noise_free):
    """line_laser: the readings determine alpha_x (the registration recovers it from
    noise-free readings), so no analysis of the model finds a gap; the patent's estimator
    still cannot see it. Only the procedure knows its estimators' limits."""
    proc, setup, truth, readings = line_laser_noise_free
    true = proc.display_truth(setup, truth)["alpha_x"]
    reg = proc.display_estimate(setup, readings, "registration")["alpha_x"][0]
    pat = proc.display_estimate(setup, readings, "patent")["alpha_x"][0]
    assert reg == pytest.approx(true, abs=1e-3)
    assert abs(pat - true) > 100  # urad
    obs = proc.capabilities.observability(setup)
    assert obs["registration"]["alpha_x"].observable and not obs["patent"]["alpha_x"].observable


def test_line_laser_patent_values_come_in_steps():
    """line_laser: the patent's alpha_z is a whole row shift; noisy trials all give the same
    step, a Monte Carlo interval of zero width, which without the step would be stated as
    u = 0 (the generic default: continuous values)."""
    proc = registry()["line_laser"]
    setup = proc.Setup()
    step = proc.estimators["patent"].steps(setup)["alpha_z"]
    values = proc.estimate(setup, proc.simulate(setup, draws=6, rng=1), "patent")["alpha_z"]
    np.testing.assert_allclose(values / step, np.round(values / step), rtol=0, atol=1e-9)
    assert np.ptp(values) == 0 and step > 0
    assert proc.estimators["registration"].steps(setup) == {}


def test_rotary_axis_calibration_meets_what_no_lever_does():
    """rotary_axis: with the generic default (no calibration) the planner's search over every
    lever cannot bring the A axis's EZ0A to 1.5 times its calibrated u (the angle influence's
    even part, which the reversal does not cancel); with the sensor's calibrated angle
    characteristic it can."""
    from mtplan.evaluation.first_order import first_order
    from mtplan.plans import levers

    proc = registry()["rotary_axis"]
    base = proc.setup(axis="A")
    cal = proc.capabilities.calibrations[0]
    target = 1.5 * first_order(proc, proc.setup(axis="A", **cal.values)).u()["EZ0A"]

    def evaluate(setup):
        u = first_order(proc, setup).u()["EZ0A"]
        return levers.Score(values=[u / target], worst=u / target, feasible=u <= target)

    generic = dataclasses.replace(proc, capabilities=dataclasses.replace(
        proc.capabilities, calibrations=()))
    assert not any(s.feasible for s in levers.search(generic, base, evaluate).scores)
    assert any(s.feasible for s in levers.search(proc, base, evaluate).scores)
