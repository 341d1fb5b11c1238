"""The conformance suite every procedure passes (scikit-learn's parametrize_with_checks).

Parametrised over every registered procedure and the test-only ``toy_line``: the checks
of ``tests/models/conformance.py`` (shapes, units, source naming, seed and ``n_jobs``
invariance, noise-free recovery, readings round trip, duration, and errors on bad
set-ups), each procedure against each check.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mtplan.models import registry
from mtplan.models.protocol import Procedure
from tests.models import toy_line
from tests.models.conformance import CHECKS, bad_values, check_bad_setup_value, numeric_fields

PROCEDURES = {"toy_line": toy_line.PROCEDURE, **registry()}
NAMES = list(PROCEDURES)


@pytest.fixture(params=NAMES)
def proc(request) -> Procedure:
    return PROCEDURES[request.param]


def test_registry_finds_the_procedures():
    assert "toy_line" not in registry()  # test procedure is not registered
    for name, p in registry().items():
        assert p.name == name


@pytest.mark.parametrize("check", CHECKS, ids=lambda c: c.__name__.removeprefix("check_"))
def test_conformance(proc, check):
    check(proc)


@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_bad_setup_values_name_the_field(name, data):
    proc = PROCEDURES[name]
    info = data.draw(st.sampled_from(numeric_fields(proc)))
    check_bad_setup_value(proc, info, data.draw(st.sampled_from(bad_values(info))))
