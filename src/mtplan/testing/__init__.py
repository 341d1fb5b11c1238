"""Conformance checks for a procedure, wherever it lives (as scikit-learn ships
``check_estimator``).

A procedure in its own package is checked with the same functions mtplan's test suite runs
on its built-in procedures::

    from mtplan.models import get
    from mtplan.testing import check_procedure

    check_procedure(get("edge_line"))     # or the Procedure object itself

:func:`check_procedure` runs every check of :data:`CHECKS` and raises one
:class:`ProcedureCheckError` naming every check that failed and why. In a pytest suite,
parametrise over :data:`CHECKS` to see each check as a test of its own::

    @pytest.mark.parametrize("check", CHECKS, ids=lambda c: c.__name__)
    def test_conformance(check):
        check(PROCEDURE)

The checks (each a function of the Procedure, raising AssertionError): the default set-up
and truth build; measurands have distinct names, known units and finite true values; the
source method is cited and is one of the estimators, by the name the procedure gives it
(``patent`` unless it names its own); every error source declares the set-up field that sizes
it (``Source(field=...)``) and that field at 0 switches it off; the levers are set-up fields
that size no source; simulated readings are batch-first and every estimator gives a finite
value per trial and measurand; the exact estimators recover the truth from noise-free
readings; one seed gives one result whatever ``n_jobs``; readings survive the round trip
through their CSV table; the duration is positive; unknown fields, estimators and sources
and bad set-up values are refused, naming the field. They use no test framework: mtplan
does not need pytest to run them.

The template procedure that docs/adding_a_procedure.md starts from ships here too
(:mod:`mtplan.testing.template`); :func:`template_source` gives its text renamed, to be
written to a module of one's own::

    python -c "from mtplan.testing import template_source; print(template_source('edge_line'), end='')" > mtplan_edge_line.py
"""

from __future__ import annotations

import keyword
from pathlib import Path

from mtplan._validate import InvalidInput
from mtplan.models import Procedure, get
from mtplan.testing.checks import CHECKS

__all__ = ["CHECKS", "ProcedureCheckError", "check_procedure", "template_source"]

#: the template's file, shipped with mtplan
TEMPLATE = Path(__file__).with_name("template.py")


class ProcedureCheckError(AssertionError):
    """One or more conformance checks failed.

    Attributes
    ----------
    procedure : str
        The procedure's name.
    failures : dict of str to str
        The failed checks' names and what each found wrong.
    """

    def __init__(self, procedure: str, failures: dict[str, str]):
        self.procedure, self.failures = procedure, dict(failures)
        lines = [f"{len(failures)} of the conformance checks failed on {procedure}:"]
        lines += [f"  {check}: {why}" for check, why in failures.items()]
        super().__init__("\n".join(lines))


def check_procedure(procedure, *, checks=CHECKS) -> None:
    """Run the conformance checks on a procedure.

    Parameters
    ----------
    procedure : Procedure or str
        The procedure, or the name under which it is registered.
    checks : sequence of callables, optional
        The checks to run (default: all of :data:`CHECKS`).

    Raises
    ------
    ProcedureCheckError
        Naming every check that failed and its message; the first failure's exception is
        its ``__cause__`` (its traceback points at the failing line).
    """
    proc = procedure if isinstance(procedure, Procedure) else get(procedure)
    failures, first = {}, None
    for check in checks:
        try:
            check(proc)
        except Exception as exc:  # noqa: BLE001 - every failure is listed, not only the first
            failures[check.__name__] = f"{type(exc).__name__}: {exc}".strip()
            first = first or exc
    if failures:
        raise ProcedureCheckError(proc.name, failures) from first


def template_source(name: str = "toy_line") -> str:
    """The text of the template procedure (:mod:`mtplan.testing.template`) with its name
    ``toy_line`` replaced by `name`: the start of a procedure's own module (its
    ``Procedure(name=...)`` and the names in its error messages).

    Raises
    ------
    InvalidInput
        When `name` is not a lower-case Python name.
    """
    if not (isinstance(name, str) and name.isidentifier() and name == name.lower()
            and not keyword.iskeyword(name)):
        raise InvalidInput([f"The 'name' parameter of template_source must be a lower-case "
                            f"Python name (edge_line). Got {name!r} instead."])
    return TEMPLATE.read_text(encoding="utf-8").replace("toy_line", name)
