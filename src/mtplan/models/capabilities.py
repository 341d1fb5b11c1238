"""What a procedure offers beyond its model, and the published method it implements.

:class:`Capabilities` is a base class after scikit-learn's estimator base classes and tags:
what is data is a field (a *tag*: the Monte Carlo block size), and every optional behaviour
is a method whose body is the generic implementation. A procedure that needs more subclasses
it and overrides only those methods, a plain function of its module assigned as a static
method::

    class _Capabilities(Capabilities):
        truth_from_estimate = staticmethod(truth_from_estimate)

    PROCEDURE = Procedure(..., capabilities=_Capabilities(block_size=2000))

No capability is a hook that may be None, and no caller branches on one: a caller calls the
method, and the generic default answers where the procedure has nothing of its own (an empty
report, no extras, the truth unchanged, the chain rule). Where the generic answer is that
nothing can be done (no truth is built from an estimate), a tag derived from the override
says so (:attr:`Capabilities.builds_truths`), and the default method raises
``NotImplementedError`` naming the method to override.

:class:`SourceMethod` names the estimator that is the published source method and cites it;
the certificate reads the citation from the procedure, so that a procedure from another
package cites its own source.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass

from mtplan.models.correction import NO_CORRECTION, CorrectionModel

__all__ = ["Capabilities", "Calibration", "SourceMethod", "METHODS"]


@dataclass(frozen=True)
class SourceMethod:
    """The published method a procedure implements: the estimator that computes it and the
    citation the documents print.

    Parameters
    ----------
    estimator : str
        The name of the estimator that is the source method: ``"patent"`` by the house's
        convention, or the method's own name (circle_centre's ``"three_point"``). It must
        be one of the procedure's estimators (checked by
        :func:`mtplan.testing.check_procedure`).
    title : str
        The title of the publication in English ("": no published source method).
    document : str
        What identifies the publication, as cited: ``"patent CN101982726"``,
        ``"ISO 230-1:2012"``; "" where the copies the procedure was built from state none
        (it is then cited by title, `who` and date).
    who : str
        Applicant or authors and date (``"Shanghai Jiao Tong University, filed
        2010-09-27"``); "" where not stated.
    """

    estimator: str = "patent"
    title: str = ""
    document: str = ""
    who: str = ""


@dataclass(frozen=True)
class Calibration:
    """A calibration a procedure offers: set-up values that replace an error source's bound
    by a calibrated characteristic (and its smaller calibration error), at a cost. The
    planner weighs it beside the levers, as one more option of the search.

    Parameters
    ----------
    name : str
        What it is called in the planner's answers ("sensor angle characteristic").
    values : mapping of set-up field to value
        The fields it sets; a file field names a representative calibration (a packaged
        example): only the calibration's own error enters the budget, so its values do not
        change u.
    cost_s : float
        What it costs, in the planner's unit of cost: seconds, as a set-up's duration.
    removes : tuple of str
        The error sources it takes out of the budget (replaced by the calibration's error).
    description : str
        How the cost and the representative calibration were chosen.
    """

    name: str
    values: Mapping
    cost_s: float
    removes: tuple = ()
    description: str = ""

    def __post_init__(self):
        if not (math.isfinite(self.cost_s) and self.cost_s >= 0):
            raise ValueError(f"The 'cost_s' parameter of Calibration {self.name!r} must be a "
                             f"finite number >= 0. Got {self.cost_s!r} instead.")
        object.__setattr__(self, "values", dict(self.values))


@dataclass(frozen=True)
class Capabilities:
    """What a procedure offers beyond its model: tags (data) and methods whose defaults are
    the generic behaviour (see the module docstring for how a procedure overrides one).

    Parameters
    ----------
    block_size : int
        Monte Carlo block size (trials); smaller for procedures with many readings.
    calibrations : tuple of Calibration
        The calibrations that replace an error source's bound by a calibrated
        characteristic at a cost: options the planner searches beside the levers. Generic:
        none.
    levers : tuple of str
        The set-up fields an engineer chooses when planning the test (counts, geometry and
        order of the test, dwell, feed): those the planner searches and advice may name;
        every other field is a property of the machine, the workpiece or the instrument,
        named as what dominates. Each one's options come from its declaration
        (``param(levels=...)``, :func:`~mtplan.models.fields.lever_options`). Generic: none.
    source_method : SourceMethod
        The estimator that is the published source method and its citation, which the
        certificate prints. Generic: ``patent``, uncited.
    correction : CorrectionModel
        How a measured result becomes the correction a controller takes (``mtplan
        compensate``). Generic: none stated.
    """

    block_size: int = 10_000
    calibrations: tuple = ()
    levers: tuple = ()
    source_method: SourceMethod = SourceMethod()
    correction: CorrectionModel = NO_CORRECTION

    # ------------------------------------------------------------------ derived tags
    @property
    def builds_truths(self) -> bool:
        """Whether the procedure builds a Truth from an estimate (overrides
        :meth:`truth_from_estimate`): Monte Carlo around a measured result, the posterior's
        start and the readings' sensitivities to the measurands need it."""
        return "truth_from_estimate" in self.overrides()

    @property
    def batches_truths(self) -> bool:
        """Whether the procedure builds many truths as one batch (overrides
        :meth:`truths_from_estimates`): the readings' sensitivities are then one forward
        run (``plans.planner.readings_jacobian``), else one run per step of each
        measurand."""
        return "truths_from_estimates" in self.overrides()

    def overrides(self) -> tuple[str, ...]:
        """The methods of :data:`METHODS` this procedure overrides, in that order."""
        return tuple(m for m in METHODS
                     if getattr(type(self), m) is not getattr(Capabilities, m))

    # ------------------------------------------------------------------ variants
    def generic(self, *methods: str) -> Capabilities:
        """A copy whose `methods` are the generic defaults again (the tags kept): how a
        procedure's result compares with what the generic path gives."""
        return self._variant({m: getattr(Capabilities, m) for m in _known(methods)})

    def overriding(self, **methods) -> Capabilities:
        """A copy whose `methods` (name -> plain function, with the method's parameters
        after ``self``) override those of this one (the tags kept)."""
        _known(methods)
        return self._variant({m: staticmethod(fn) for m, fn in methods.items()})

    def _variant(self, body: dict) -> Capabilities:
        cls = type(type(self).__name__, (type(self),), {"__doc__": type(self).__doc__,
                                                          **body})
        return cls(**{f.name: getattr(self, f.name) for f in dataclasses.fields(self)})

    # ------------------------------------------------------------------ truths
    def truth_from_estimate(self, setup, estimate):
        """``truth_from_estimate(setup, estimate) -> Truth``: the Truth whose measurands
        equal an estimate (internal units; nuisance fields at their defaults), for Monte
        Carlo around a measured result and as a posterior start.

        Generic: none (:attr:`builds_truths` is False); the study runs at the stated truth
        and the posterior is not available."""
        raise NotImplementedError(_missing(self, "truth_from_estimate"))

    def truths_from_estimates(self, setup, estimates):
        """``truths_from_estimates(setup, estimates) -> Truth``: :meth:`truth_from_estimate`
        for many estimates at once, `estimates` mapping each measurand to an array (m,);
        the Truth's float fields are arrays (m,), which ``forward`` takes as one truth per
        batch row.

        Generic: none (:attr:`batches_truths` is False); callers build one truth per
        estimate."""
        raise NotImplementedError(_missing(self, "truths_from_estimates"))

    def start_from_readings(self, setup, readings, truth):
        """`truth` (of :meth:`truth_from_estimate`) with the fields that no measurand
        depends on but that the readings give directly (circle_centre's start point, whose x
        is that of the readings p1 and p2) put where the readings put them: the start of the
        posterior's and the fit check's least squares, which a forward model with branches
        (a path planned from earlier readings) needs on the readings' branch.

        Generic: `truth` as it is."""
        return truth

    # ------------------------------------------------------------------ effects
    def source_structure(self, setup, truth, name):
        """``(colours, owners)`` or None: for a source of many elements that each move a few
        readings (an artifact's facets), a colouring of its elements: those of one colour
        never move a common reading, and ``owners`` (colours, readings) names the element
        of each colour each reading of ``forward`` (flattened) depends on, -1 for none. The
        source's effects then take two forward rows per colour instead of two per element
        (``fitting.source_effects``).

        Generic: None, no structure (NaN probes, then element by element)."""
        return None

    def first_order_sensitivities(self, setup, truth, *, estimator, sources):
        """The derivative hook (as astropy.modeling's ``fit_deriv``): the closed form of the
        measurands' sensitivity [display unit per internal unit] to every element of every
        active source (columns: the active sources in order, each one's elements flattened)
        at the sources' means, an array (measurands, elements). The first-order service
        (``mtplan.evaluation.first_order``) takes it for the planner, the designer and
        ``mtplan linearize`` alike. It takes the estimator's name rather than living on each
        estimator because the closed forms share one model linearisation between a
        procedure's estimators.

        Generic: None for every estimator, the chain rule through the forward model and the
        estimator (so is None for an estimator an override does not map)."""
        return None

    def gross_errors(self, setup, readings):
        """The gross errors of the test that move several readings together (one bad
        contact of a probe moves both coordinates it reads along its probing direction):
        ``(kind, labels, directions)``, what they are ("a contact along its probing
        direction"), a name per error ("contact d2") and an array (readings, errors) of
        each one's effect per unit [the readings' internal unit] over the numeric reading
        arrays of `readings` (a batch of one) flattened in order. The fit check's reliability
        (:mod:`mtplan.evaluation.reliability`) states their minimal detectable bias and
        what they move unseen beside those of each reading alone.

        Generic: None (every gross error is one reading's)."""
        return None

    # ------------------------------------------------------------------ analyses
    def identifiability_report(self, setup) -> dict:
        """The procedure's own rank analysis of its full model: ``rank``, ``parameters``,
        ``readings``, ``condition_number``, ``singular_values`` and ``null_space`` (a list
        of dicts parameter -> weight), and optionally ``jacobian``, ``scale``, ``names``,
        ``rank_tol`` and ``functions`` (the measurands as functions of its parameters, by
        name).

        Generic: {} (no analysis of its own): the sensitivities of the readings to the
        measurands (or truth fields) are analysed (``plans.identifiability``)."""
        return {}

    def identifiability(self, setup, estimator):
        """A DataFrame indexed by every measurand the procedure can report, with ``listed``
        (a measurand at this set-up), ``status`` ('identified', 'unidentifiable', 'no
        effect', ...) and ``confounded_with``.

        Generic: an empty table: every measurand is listed at every set-up, and none is
        reported that the set-up does not list."""
        import pandas as pd

        return pd.DataFrame({"listed": [], "status": [], "confounded_with": []})

    def observability(self, setup) -> dict:
        """``{estimator: {measurand: ...}}``: which measurands each estimator can observe at
        the set-up, with their limits; shown in the report (unless :meth:`report_extras`
        already gives ``observability``).

        Generic: {} (not shown)."""
        return {}

    def report_extras(self, setup, truth) -> dict:
        """Procedure-specific data for the report (a figure's path, uncertainty bands);
        plain data, the reports draw it.

        Generic: {} (no extras)."""
        return {}


#: the methods of :class:`Capabilities` a procedure may override
METHODS = ("truth_from_estimate", "truths_from_estimates", "start_from_readings",
           "source_structure", "first_order_sensitivities", "gross_errors",
           "identifiability_report",
           "identifiability", "observability", "report_extras")


def _known(methods) -> tuple:
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise TypeError(f"Capabilities has no method {', '.join(map(repr, unknown))}; its "
                        f"methods are {', '.join(METHODS)}.")
    return tuple(methods)


def _missing(capabilities: Capabilities, method: str) -> str:
    return (f"{type(capabilities).__name__} has no {method}: a procedure that needs one "
            f"overrides Capabilities.{method}")
