"""The conformance suite every procedure passes (scikit-learn's parametrize_with_checks).

The checks are mtplan's own, shipped in :mod:`mtplan.testing` for procedures anywhere: here
each one runs on every registered procedure (whatever registered it: mtplan's entry points
or an installed plug-in's) and on the test-only ``toy_line``. No list of procedures or of
their tunings is kept here: a procedure states what the checks need in its record.
"""

from __future__ import annotations

import pytest

from mtplan.models import broken, registry
from mtplan.models.protocol import Procedure
from mtplan.testing import CHECKS, ProcedureCheckError, check_procedure
from mtplan.testing import template as toy_line

PROCEDURES = {"toy_line": toy_line.PROCEDURE, **registry()}


@pytest.fixture(params=list(PROCEDURES))
def proc(request) -> Procedure:
    return PROCEDURES[request.param]


def test_the_registry_finds_the_procedures():
    assert "toy_line" not in registry()  # the test procedure is not registered
    assert {"circle_centre", "geometry21", "line_laser", "rotary_axis",
            "tracker_frame"} <= set(registry())
    for name, p in registry().items():
        assert p.name == name
    assert broken() == []


@pytest.mark.parametrize("check", CHECKS, ids=lambda c: c.__name__.removeprefix("check_"))
def test_conformance(proc, check):
    check(proc)


def test_check_procedure_names_every_failed_check():
    """A procedure that breaks two rules is told both, with what is wrong in each."""
    import dataclasses

    proc = toy_line.PROCEDURE
    bad = dataclasses.replace(proc, capabilities=dataclasses.replace(
        proc.capabilities, levers=("no_such_field",)), duration=lambda setup: -1.0)
    with pytest.raises(ProcedureCheckError) as exc:
        check_procedure(bad)
    assert set(exc.value.failures) == {"check_levers", "check_duration"}
    assert "no_such_field" in exc.value.failures["check_levers"]
    assert "-1.0" in exc.value.failures["check_duration"]
    assert isinstance(exc.value, AssertionError) and exc.value.procedure == "toy_line"
    check_procedure(toy_line.PROCEDURE)  # the unchanged toy passes every check
