"""The procedure protocol: what every measurement procedure module provides.

A procedure module (``mtplan/models/<name>.py``) defines a module-level
``PROCEDURE = Procedure(...)`` built from:

- ``Setup``: a frozen dataclass of :class:`SetupBase` whose fields are declared
  with :func:`param` (unit in the field name, e.g. ``incline_deg``,
  ``probe_noise_um``; range in the metadata). Validation runs on construction
  and lists every problem at once; cross-field rules go in ``_check``.
- ``Truth``: the true measurands and nuisance geometry, same mechanism.
- ``measurands(setup) -> tuple[Measurand, ...]``: names (ISO 230), display units.
- ``sources(setup) -> dict[str, Source]``: the error sources. A source named
  ``probe_noise`` is sized by the set-up field ``probe_noise_um``; a size of 0
  switches it off (its distribution's std is 0). Each source is drawn per trial
  into ``(trials, *shape)`` in internal units (mm, rad).
- ``forward(setup, truth, errors) -> readings``: the deterministic forward model;
  ``errors`` maps every source name to an array of shape ``(n, *source.shape)``;
  ``readings`` is a :class:`Readings` of batch-first arrays (leading axis = trials).
- ``estimators``: name -> :class:`Estimator`, a record of the function
  ``estimate(setup, readings) -> dict[measurand, (n,) array]`` in internal units (mm, rad),
  its plain ``description`` (the reports quote it), whether it is ``exact`` without noise
  and, for a quantised estimator, its ``resolution``. The patent's method is named
  ``patent`` (or the patent's own name) and is always present; the first is the default.
- ``true_values(setup, truth) -> dict[measurand, float]`` in internal units.
- ``duration(setup) -> float``: machine time of the test [s].
- ``readings``: a :class:`ReadingsFormat`, ``frame(setup, readings) -> DataFrame`` and
  ``from_frame(setup, df) -> readings`` (the tidy CSV format of measured data, batch of one,
  and back), and optionally ``setup_from_frame(df) -> dict[field, Implied]`` (the set-up
  fields a measured table determines, each with the tolerance within which a value the
  user states agrees with the file, :class:`Implied`), ``optional_columns``, ``limits``
  and ``noise_source``.
- ``description`` and ``levers`` (the set-up fields an engineer chooses).
- ``capabilities``: a :class:`Capabilities` record, what the procedure offers beyond its
  model as data with generic defaults (as scikit-learn's estimator tags): the Monte Carlo
  ``block_size``, ``truth_from_estimate`` and its batched form, ``start_from_readings``,
  ``source_structure``, the
  analysis hooks ``identifiability_report``, ``report_extras``, ``identifiability`` and
  ``observability``, and one derivative hook, ``first_order_sensitivities`` (the closed
  form of the first-order sensitivities, from which the first-order service derives u and
  the budget for every caller). Each default (None) selects the generic analysis.

The field machinery (:func:`param`, :class:`SetupBase`, :func:`make`, :func:`fields_info`,
:class:`Implied`, ...) lives in :mod:`mtplan.models.fields`; its names are re-exported here,
so that a procedure module imports its whole contract from one place.

The :class:`Procedure` record is the whole contract: the planner, the study and the
reports use only its fields, never a function looked up by name in a procedure's module.

``simulate`` = draw the active sources + ``forward``; it and the Monte Carlo engine
live here, once, so no procedure writes its own random-number handling.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from mtplan._validate import InvalidInput, Problems
from mtplan.models.correction import NO_CORRECTION, CorrectionModel
from mtplan.models.fields import (
    UNIT_SUFFIXES,
    UNITS,
    Implied,
    SetupBase,
    fields_info,
    file_content,
    file_fields,
    frame_columns,
    make,
    param,
    parse_fields,
    resolve_file_fields,
    shown_with_unit,
    split_unit,
    with_conditions,
)
from mtplan.uncertainty.distributions import Constant, Distribution
from mtplan.uncertainty.streams import as_seed_sequence, block_sequence, named_generator

__all__ = [
    "UNITS",
    "UNIT_SUFFIXES",
    "Measurand",
    "Source",
    "SetupBase",
    "param",
    "with_conditions",
    "fields_info",
    "split_unit",
    "shown_with_unit",
    "make",
    "frame_columns",
    "parse_fields",
    "file_fields",
    "file_content",
    "resolve_file_fields",
    "Implied",
    "Estimator",
    "ReadingsFormat",
    "Capabilities",
    "Procedure",
    "Readings",
]


@dataclass(frozen=True)
class Measurand:
    """A quantity a procedure determines.

    Parameters
    ----------
    name : str
        ISO 230 name where one exists (``EX0C``, ``EBX``, ``EC0Y``) or a plain one.
    unit : str
        Display unit, a key of :data:`UNITS` (``um``, ``urad``, ...).
    description : str
        Plain English.
    """

    name: str
    unit: str
    description: str = ""

    def __post_init__(self):
        if self.unit not in UNITS:
            raise ValueError(
                f"The 'unit' parameter of Measurand {self.name!r} must be one of "
                f"{', '.join(UNITS)}. Got {self.unit!r} instead."
            )

    @property
    def scale(self) -> float:
        """Factor from the internal unit (mm or rad) to the display unit."""
        return UNITS[self.unit]


@dataclass(frozen=True)
class Source:
    """An error source: one distribution drawn per trial into ``shape``.

    Parameters
    ----------
    distribution : Distribution
        Distribution of each element, in internal units (mm, rad, or 1 for scale errors).
    shape : tuple of int
        Elements per trial (e.g. ``(positions, points)`` for reading noise, ``()`` for
        one scale error per test).
    description : str
        What the source is, and where its default size comes from.
    """

    distribution: Distribution
    shape: tuple = ()
    description: str = ""

    @property
    def active(self) -> bool:
        """A source whose distribution has zero spread is switched off."""
        return bool(np.any(np.asarray(self.distribution.std) > 0))

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64)) * int(
            np.prod(self.distribution.event_shape, dtype=np.int64)
        )


# --------------------------------------------------------------------------- procedure
class Readings(dict):
    """A procedure's readings: reading name -> array, batch-first (leading axis: the trials,
    one row per simulated or measured test).

    What ``forward`` and ``ReadingsFormat.from_frame`` return (a measured table is a batch
    of one). It reads as the dict it is (``readings["z_mm"]``, ``.items()``, ``{**readings}``)
    at a dict's speed, knows its :attr:`rows` and the :attr:`units` its names carry
    (``"distance_mm"`` is in mm), and is not changed in place: :meth:`replace` gives a copy
    with some arrays changed.
    """

    __slots__ = ()

    @property
    def rows(self) -> int:
        """The number of rows (trials) of the batch: the leading axis of its arrays."""
        return int(np.shape(next(iter(self.values())))[0]) if self else 0

    @property
    def units(self) -> dict[str, str]:
        """reading name -> its unit, the suffix of the name (:func:`split_unit`)."""
        return {name: split_unit(name)[1] for name in self}

    def replace(self, **changes) -> Readings:
        """A copy with the arrays `changes` (name -> array) put in."""
        return Readings({**self, **changes})

    def _frozen(self, *args, **kwargs):
        raise TypeError("Readings are not changed in place; use readings.replace(name=array) "
                        "for a copy with an array changed")

    __setitem__ = __delitem__ = update = pop = popitem = setdefault = clear = _frozen
    __ior__ = _frozen

    def __reduce__(self):
        return (Readings, (dict(self),))

    def __repr__(self) -> str:
        return f"Readings({dict.__repr__(self)})"


def _plain_summary(function) -> str:
    """The first paragraph of `function`'s docstring as plain prose: one line, without reST
    markup and without the return value's units and shape ("" without a docstring)."""
    doc = " ".join((getattr(function, "__doc__", None) or "").strip().split("\n\n")[0].split())
    if not doc:
        return ""
    doc = re.sub(r":\w+:`~?([^`]+)`", r"\1", doc).replace("``", "")
    doc = re.sub(r";?\s*(measurands\s*)?\[mm, rad\],?\s*\(n,\)\.?", ".", doc)
    return doc.rstrip(" .;") + "."


@dataclass(frozen=True)
class Estimator:
    """An estimator of a procedure: its function and what the documents say of it.

    Calling the record calls the function: ``estimator(setup, readings) ->
    {measurand: (n,) array}`` in internal units (mm, rad).

    Parameters
    ----------
    function : callable
        ``function(setup, readings) -> dict[measurand, (n,) array]``.
    description : str
        Plain English for the documents (the reports quote it); default: the first
        paragraph of the function's docstring, without markup.
    exact : bool
        Recovers the truth exactly from noise-free readings at the default set-up (checked
        by :func:`mtplan.testing.check_procedure`).
    resolution : callable or None
        ``resolution(setup) -> {measurand: step}``: the steps [internal unit] in which the
        estimator's values come (a quantised estimator): where its Monte Carlo interval has
        zero width, ``simulate`` states u = step / sqrt(12). None: continuous values.
    """

    function: Callable
    description: str = ""
    exact: bool = False
    resolution: Callable | None = None

    def __post_init__(self):
        if not callable(self.function):
            raise TypeError(f"The 'function' parameter of Estimator must be callable. Got "
                            f"{type(self.function).__name__} instead.")
        if not self.description:
            object.__setattr__(self, "description", _plain_summary(self.function))
        # the function's docstring stays readable through the record (``help``, reports)
        object.__setattr__(self, "__doc__", getattr(self.function, "__doc__", None))

    def __call__(self, setup, readings) -> dict:
        return self.function(setup, readings)

    def steps(self, setup) -> dict:
        """``resolution(setup)``, or {} for an estimator whose values are continuous."""
        return {} if self.resolution is None else dict(self.resolution(setup))


@dataclass(frozen=True)
class ReadingsFormat:
    """How a procedure's readings are written to and read from a tidy table (CSV).

    Parameters
    ----------
    frame : callable
        ``frame(setup, readings) -> DataFrame``: the tidy table of a batch of one.
    from_frame : callable
        ``from_frame(setup, df) -> readings``: the table back to readings (batch of one),
        in any row order; refuses a bad table with :class:`InvalidInput`.
    setup_from_frame : callable or None
        ``setup_from_frame(df) -> {field: Implied}``: the set-up fields a measured table
        determines (``df`` as read from the file: numeric columns as floats, rows in the
        file's order, optional columns possibly absent). None: the table implies nothing.
    optional_columns : tuple of str
        Columns a measured file may leave out (``from_frame`` copes without them).
    limits : callable or None
        ``limits(setup) -> {column: (low, high, what)}``: the instrument's range per row of
        the table (arrays or scalars); measured values outside are refused, naming the row,
        the value and ``what`` range it left. None: no range.
    noise_source : str or None
        The error source whose spread is the readings' noise in the likelihood (posterior,
        fit checks). None: the procedure has no single noise source.
    """

    frame: Callable
    from_frame: Callable
    setup_from_frame: Callable | None = None
    optional_columns: tuple = ()
    limits: Callable | None = None
    noise_source: str | None = None


@dataclass(frozen=True)
class Capabilities:
    """What a procedure offers beyond its model, as data with generic defaults (as
    scikit-learn's estimator tags). Every field is optional; its default selects the
    generic analysis named with it.

    Parameters
    ----------
    block_size : int
        Monte Carlo block size (trials); smaller for procedures with many readings.
    truth_from_estimate : callable or None
        ``truth_from_estimate(setup, estimate) -> Truth``: the Truth whose measurands equal
        an estimate (internal units; nuisance fields at their defaults), for Monte Carlo
        around a measured result and as a posterior start. None: the study runs at the
        stated truth and the posterior is not available.
    truths_from_estimates : callable or None
        ``truths_from_estimates(setup, estimates) -> Truth``: ``truth_from_estimate`` for many
        estimates at once, `estimates` mapping each measurand to an array (m,); the Truth's
        float fields are arrays (m,), which ``forward`` takes as one truth per batch row. The
        readings' sensitivities to the measurands are then one forward run
        (``plans.planner.readings_jacobian``). None: one run per step of each measurand.
    start_from_readings : callable or None
        ``start_from_readings(setup, readings, truth) -> Truth``: `truth` (of
        ``truth_from_estimate``) with the fields that no measurand depends on but that the
        readings give directly (circle_centre's start point, whose x is that of the readings
        p1 and p2) put where the readings put them: the start of the posterior's and the fit
        check's least squares, which a forward model with branches (a path planned from
        earlier readings) needs on the readings' branch. None: `truth` as it is.
    source_structure : callable or None
        ``source_structure(setup, truth, name) -> (colours, owners)`` or None: for a source
        of many elements that each move a few readings (an artifact's facets), a colouring of
        its elements: those of one colour never move a common reading, and ``owners``
        (colours, readings) names the element of each colour each reading of ``forward``
        (flattened) depends on, -1 for none. The source's effects then take two forward rows
        per colour instead of two per element (``fitting.source_effects``). None: NaN
        probes, then element by element.
    identifiability_report : callable or None
        ``identifiability_report(setup) -> dict``: the procedure's own rank analysis of its
        full model, with ``rank``, ``parameters``, ``readings``, ``condition_number``,
        ``singular_values`` and ``null_space`` (a list of dicts parameter -> weight), and
        optionally ``jacobian``, ``scale``, ``names``, ``rank_tol`` and ``functions`` (the
        measurands as functions of its parameters, by name). None: the sensitivities of the
        readings to the measurands (or truth fields) are analysed (``plans.identifiability``).
    report_extras : callable or None
        ``report_extras(setup, truth) -> dict``: procedure-specific data for the report (a
        figure's path, uncertainty bands); plain data, the reports draw it. None: no extras.
    identifiability : callable or None
        ``identifiability(setup, estimator) -> DataFrame`` indexed by every measurand the
        procedure can report, with ``listed`` (a measurand at this set-up), ``status``
        ('identified', 'unidentifiable', 'no effect', ...) and ``confounded_with``. None:
        every measurand is listed at every set-up.
    observability : callable or None
        ``observability(setup) -> {estimator: {measurand: ...}}``: which measurands each
        estimator can observe at the set-up, with their limits; shown in the report (unless
        ``report_extras`` already gives ``observability``). None: not shown.
    first_order_sensitivities : callable or None
        ``first_order_sensitivities(setup, truth, *, estimator, sources) -> jacobian``: the
        derivative hook (as astropy.modeling's ``fit_deriv``), the closed form of the
        measurands' sensitivity [display unit per internal unit] to every element of every
        active source (columns: the active sources in order, each one's elements flattened)
        at the sources' means. The first-order service (``mtplan.evaluation.first_order``)
        takes it for the planner, the designer and ``mtplan linearize`` alike. None (or the
        hook returning None for an estimator it does not map): the chain rule through the
        forward model and the estimator. It takes the estimator's name rather than living on
        each :class:`Estimator` because the closed forms share one model linearisation
        between a procedure's estimators.
    """

    block_size: int = 10_000
    truth_from_estimate: Callable | None = None
    truths_from_estimates: Callable | None = None
    start_from_readings: Callable | None = None
    source_structure: Callable | None = None
    identifiability_report: Callable | None = None
    report_extras: Callable | None = None
    identifiability: Callable | None = None
    observability: Callable | None = None
    first_order_sensitivities: Callable | None = None


@dataclass(frozen=True)
class Procedure:
    """A registered measurement procedure: forward model, estimators and metadata.

    See the module docstring for the meaning of each field; :class:`Estimator`,
    :class:`ReadingsFormat` and :class:`Capabilities` hold the rest of the contract.
    """

    name: str
    title: str
    Setup: type
    Truth: type
    measurands: Callable
    sources: Callable
    forward: Callable
    #: name -> :class:`Estimator` (a bare function is taken as ``Estimator(function)``);
    #: the first is the default
    estimators: Mapping[str, Estimator]
    true_values: Callable
    duration: Callable
    readings: ReadingsFormat
    description: str = ""
    #: the set-up fields an engineer chooses when planning the test (counts, geometry and
    #: order of the test, dwell, feed): the levers advice may name; every other field is
    #: a property of the machine, the workpiece or the instrument, named as what dominates
    levers: tuple = ()
    #: what the procedure offers beyond its model; the defaults select the generic analyses
    capabilities: Capabilities = Capabilities()
    #: how a measured result becomes the correction a controller takes (``mtplan
    #: compensate``); the default states none
    correction: CorrectionModel = NO_CORRECTION

    def __post_init__(self):
        object.__setattr__(self, "estimators", {
            k: v if isinstance(v, Estimator) else Estimator(v)
            for k, v in self.estimators.items()})

    @property
    def exact_names(self) -> tuple:
        """Names of the estimators that are exact without noise, in order."""
        return tuple(k for k, e in self.estimators.items() if e.exact)

    # ----------------------------------------------------------------- helpers
    @property
    def default_estimator(self) -> str:
        return next(iter(self.estimators))

    def setup(self, values: Mapping | None = None, **kw):
        """Build this procedure's Setup from defaults and overrides (strings allowed)."""
        return make(self.Setup, {**(values or {}), **kw}, owner=self.name)

    def truth(self, values: Mapping | None = None, **kw):
        """Build this procedure's Truth from defaults and overrides."""
        return make(self.Truth, {**(values or {}), **kw}, owner=f"{self.name} truth")

    def check_setup(self, setup) -> None:
        if not isinstance(setup, self.Setup):
            raise InvalidInput(
                [f"The 'setup' parameter of {self.name} must be a {self.name}.Setup. "
                 f"Got {type(setup).__name__} instead."]
            )

    def estimator(self, name: str | None) -> tuple[str, Estimator]:
        """(name, record) of an estimator, the default one when `name` is None; the record
        is called as the function."""
        name = name or self.default_estimator
        if name not in self.estimators:
            raise InvalidInput(
                [f"The 'estimator' parameter of {self.name} must be one of "
                 f"{', '.join(map(repr, self.estimators))}. Got {name!r} instead."]
            )
        return name, self.estimators[name]

    def active_sources(self, setup, only=None) -> dict:
        """The sources that will be drawn: active ones, restricted to `only` when given."""
        all_sources = self.sources(setup)
        if only is not None:
            only = [only] if isinstance(only, str) else list(only)
            if not only:
                raise InvalidInput(
                    [f"The 'sources' parameter of {self.name} must name at least one of its "
                     f"error sources ({', '.join(all_sources)}), or be None for all of them. "
                     "Got an empty list instead."]
                )
            unknown = [s for s in only if s not in all_sources]
            if unknown:
                raise InvalidInput(
                    [f"The 'sources' parameter of {self.name} must name its error sources "
                     f"({', '.join(all_sources)}). Got {', '.join(map(repr, unknown))} instead."]
                )
            return {k: v for k, v in all_sources.items() if k in only and v.active}
        return {k: v for k, v in all_sources.items() if v.active}

    def zero_errors(self, setup, n: int) -> dict:
        """Errors of every source set to zero, shape (n, *shape) each."""
        return {
            name: np.zeros((n, *src.shape, *src.distribution.event_shape))
            for name, src in self.sources(setup).items()
        }

    def draw_errors(self, setup, n: int, seq: np.random.SeedSequence, only=None) -> dict:
        """Draw the active sources (each from its own named stream of `seq`)."""
        errors = self.zero_errors(setup, n)
        for name, src in self.active_sources(setup, only).items():
            errors[name] = src.distribution.draw(named_generator(seq, name), (n, *src.shape))
        return errors

    def simulate(self, setup, truth=None, draws: int = 1, rng=None, *, sources=None) -> Readings:
        """Simulated raw readings: ``draws`` trials, batch-first.

        Parameters
        ----------
        setup : Setup
        truth : Truth, optional (default values when None)
        draws : int
            Number of trials (leading axis of every reading array).
        rng : None, int, SeedSequence or Generator
        sources : iterable of str, optional
            Simulate with only these error sources (default: every active one).
        """
        self.check_setup(setup)
        truth = self.Truth() if truth is None else truth
        p = Problems(f"{self.name}.simulate")
        p.number("draws", draws, integer=True, low=1)
        p.raise_if_any()
        seq = block_sequence(as_seed_sequence(rng), 0)
        errors = self.draw_errors(setup, int(draws), seq, sources)
        return self.forward(setup, truth, errors)

    def estimate(self, setup, readings: Readings, estimator: str | None = None) -> dict:
        """Measurands from readings, in internal units (mm, rad), batch-first."""
        self.check_setup(setup)
        _, fn = self.estimator(estimator)
        return fn(setup, readings)

    def display_estimate(self, setup, readings: Readings, estimator: str | None = None) -> dict:
        """Measurands in display units (um, urad), batch-first."""
        est = self.estimate(setup, readings, estimator)
        return {m.name: np.asarray(est[m.name], dtype=float) * m.scale
                for m in self.measurands(setup)}

    def display_truth(self, setup, truth=None) -> dict:
        """True measurand values in display units."""
        truth = self.Truth() if truth is None else truth
        tv = self.true_values(setup, truth)
        return {m.name: float(tv[m.name]) * m.scale for m in self.measurands(setup)}


Constant = Constant  # re-exported for procedure modules: ``Constant(0.0)`` is a source that is off
