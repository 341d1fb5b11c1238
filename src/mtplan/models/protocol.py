"""The procedure protocol: what every measurement procedure module provides.

A procedure module (``mtplan/models/<name>.py``) defines a module-level
``PROCEDURE = Procedure(...)`` built from:

- ``Setup``: a frozen dataclass of :class:`SetupBase` whose fields are declared
  with :func:`param` (unit in the field name, e.g. ``incline_deg``,
  ``probe_noise_um``; range in the metadata). Validation runs on construction
  and lists every problem at once; cross-field rules go in ``_check``.
- ``Truth``: the true measurands and nuisance geometry, same mechanism.
- ``measurands(setup) -> tuple[Measurand, ...]``: names (ISO 230), display units.
- ``sources(setup) -> dict[str, Source]``: the error sources. Each declares the set-up
  field that sizes it (``Source(field="probe_noise_um")`` for ``probe_noise``); a size of 0
  switches it off (its distribution's std is 0). Each source is drawn per trial into
  ``(trials, *shape)`` in internal units (mm, rad); :func:`active_sources` and
  :func:`zero_errors` are functions of the sources.
- ``forward(setup, truth, errors) -> readings``: the deterministic forward model;
  ``errors`` maps every source name to an array of shape ``(n, *source.shape)``;
  ``readings`` is a :class:`Readings` of batch-first arrays (leading axis = trials).
- ``estimators``: name -> :class:`Estimator`, a record of the function
  ``estimate(setup, readings) -> dict[measurand, (n,) array]`` in internal units (mm, rad),
  its plain ``description`` (the reports quote it), whether it is ``exact`` without noise
  and, for a quantised estimator, its ``resolution``; the first is the default.
- ``true_values(setup, truth) -> dict[measurand, float]`` in internal units.
- ``duration(setup) -> float``: machine time of the test [s].
- ``readings``: a :class:`ReadingsFormat`, ``frame(setup, readings) -> DataFrame`` and
  ``from_frame(setup, df) -> readings`` (the tidy CSV format of measured data, batch of one,
  and back), and optionally ``setup_from_frame(df) -> dict[field, Implied]`` (the set-up
  fields a measured table determines, each with the tolerance within which a value the
  user states agrees with the file, :class:`Implied`), ``optional_columns``, ``limits``
  and ``noise_source``; a callable left out is a function that answers {}.
- ``description``: the test in plain words.
- ``capabilities``: a :class:`Capabilities` (:mod:`mtplan.models.capabilities`), what the
  procedure offers beyond its model, after scikit-learn's base classes and tags: data as
  tags (the Monte Carlo ``block_size``, the ``calibrations`` the planner may offer, the
  ``levers``: the set-up fields an engineer chooses, each one's options for the planner's
  default search from its declaration, ``param(levels=...)``; the ``source_method``: the
  estimator that is the published source method, ``patent`` unless named otherwise, and its
  citation, which the certificate prints; the ``correction`` a controller takes) and every
  optional behaviour as a method whose body is the generic one (truths from estimates, the
  start of a least squares, a source's structure, the one derivative hook
  ``first_order_sensitivities``, the identifiability report and tables, observability,
  report extras); a procedure subclasses it and overrides only what it needs. No field is
  a hook that may be None. ``Procedure.levers``, ``.source_method`` and ``.correction`` read
  them.

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
from mtplan.models.correction import CorrectionModel
from mtplan.models.fields import (
    DATASHEET_NOTE,
    UNIT_SUFFIXES,
    UNITS,
    Implied,
    SetupBase,
    fields_info,
    lever_options,
    file_content,
    file_fields,
    frame_columns,
    make,
    param,
    parse_fields,
    parse_pairs,
    resolve_file_fields,
    shown_with_unit,
    split_unit,
    with_conditions,
)
from mtplan.models.capabilities import Calibration, Capabilities, SourceMethod
from mtplan.uncertainty.distributions import SHAPES, Constant, Distribution, with_shape
from mtplan.uncertainty.streams import as_seed_sequence, block_sequence, named_generator

__all__ = [
    "DATASHEET_NOTE",
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
    "Calibration",
    "Capabilities",
    "SourceMethod",
    "Procedure",
    "Readings",
    "active_sources",
    "zero_errors",
    "distributions_field",
]


def distributions_field():
    """The set-up field ``distributions`` every procedure declares, last: the error sources
    the Monte Carlo draws from another distribution of the same standard uncertainty
    (:data:`~mtplan.uncertainty.distributions.SHAPES`), as ``source=shape`` pairs. The GUM's
    first order uses only the standard uncertainty and so does not change; the Monte Carlo
    does where the measurands' distribution or a nonlinear estimator shows the shape.
    :meth:`Procedure.draw_errors` applies it, :meth:`Procedure.source_shapes` checks it."""
    return param("", doc="Error sources the Monte Carlo draws from another distribution of "
                 "the same standard uncertainty, as source=shape pairs (e.g. "
                 "'probe_noise=rectangular'); shapes: " + ", ".join(SHAPES) + " (the GUM "
                 "uses only the standard uncertainty; empty: each source's own)",
                 pairs=SHAPES)


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
    field : str
        The set-up field that sizes the source (``probe_noise_um`` for ``probe_noise``): 0
        there switches the source off. The designer offers it as the source's control, and
        the conformance checks switch the source off through it.
    """

    distribution: Distribution
    shape: tuple = ()
    description: str = ""
    field: str = ""

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


def active_sources(sources: Mapping[str, Source], only=None, *, owner: str = "procedure"
                   ) -> dict:
    """The sources of `sources` that will be drawn: the active ones, restricted to those named
    by `only` (a name or names) when given.

    Raises
    ------
    InvalidInput
        When `only` is empty or names no source of `sources` (`owner`: the procedure's name
        in the message).
    """
    if only is not None:
        only = [only] if isinstance(only, str) else list(only)
        if not only:
            raise InvalidInput(
                [f"The 'sources' parameter of {owner} must name at least one of its "
                 f"error sources ({', '.join(sources)}), or be None for all of them. "
                 "Got an empty list instead."]
            )
        unknown = [s for s in only if s not in sources]
        if unknown:
            raise InvalidInput(
                [f"The 'sources' parameter of {owner} must name its error sources "
                 f"({', '.join(sources)}). Got {', '.join(map(repr, unknown))} instead."]
            )
        return {k: v for k, v in sources.items() if k in only and v.active}
    return {k: v for k, v in sources.items() if v.active}


def zero_errors(sources: Mapping[str, Source], n: int) -> dict:
    """Errors of every source of `sources` set to zero, shape (n, *shape) each."""
    return {
        name: np.zeros((n, *src.shape, *src.distribution.event_shape))
        for name, src in sources.items()
    }


def _plain_summary(function) -> str:
    """The first paragraph of `function`'s docstring as plain prose: one line, without reST
    markup and without the return value's units and shape ("" without a docstring)."""
    doc = " ".join((getattr(function, "__doc__", None) or "").strip().split("\n\n")[0].split())
    if not doc:
        return ""
    doc = re.sub(r":\w+:`~?([^`]+)`", r"\1", doc).replace("``", "")
    doc = re.sub(r";?\s*(measurands\s*)?\[mm, rad\],?\s*\(n,\)\.?", ".", doc)
    return doc.rstrip(" .;") + "."


def continuous(setup) -> dict:
    """The resolution of an estimator whose values are continuous: no steps."""
    return {}


def implies_nothing(df) -> dict:
    """The set-up fields a readings table determines where it determines none."""
    return {}


def no_limits(setup) -> dict:
    """The instrument's range per readings column where none is stated."""
    return {}


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
    resolution : callable
        ``resolution(setup) -> {measurand: step}``: the steps [internal unit] in which the
        estimator's values come (a quantised estimator): where its Monte Carlo interval has
        zero width, ``simulate`` states u = step / sqrt(12). Default: {} for every set-up,
        continuous values.
    """

    function: Callable
    description: str = ""
    exact: bool = False
    resolution: Callable = continuous

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
        """``resolution(setup)``: {} for an estimator whose values are continuous."""
        return dict(self.resolution(setup))


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
    setup_from_frame : callable
        ``setup_from_frame(df) -> {field: Implied}``: the set-up fields a measured table
        determines (``df`` as read from the file: numeric columns as floats, rows in the
        file's order, optional columns possibly absent). Default: {}, the table implies
        nothing.
    optional_columns : tuple of str
        Columns a measured file may leave out (``from_frame`` copes without them).
    limits : callable
        ``limits(setup) -> {column: (low, high, what)}``: the instrument's range per row of
        the table (arrays or scalars); measured values outside are refused, naming the row,
        the value and ``what`` range it left. Default: {}, no range.
    noise_source : str or None
        The error source whose spread is the readings' noise in the likelihood (posterior,
        fit checks). None: the procedure has no single noise source.
    """

    frame: Callable
    from_frame: Callable
    setup_from_frame: Callable = implies_nothing
    optional_columns: tuple = ()
    limits: Callable = no_limits
    noise_source: str | None = None


@dataclass(frozen=True)
class Procedure:
    """A registered measurement procedure: forward model, estimators and metadata.

    See the module docstring for the meaning of each field; :class:`Estimator`,
    :class:`ReadingsFormat`, :class:`Capabilities` and :class:`SourceMethod` hold the rest
    of the contract.
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
    #: what the procedure offers beyond its model, as data (block size, calibrations,
    #: levers, source method, correction) and methods whose defaults are the generic
    #: analyses (one derivative hook among them)
    capabilities: Capabilities = Capabilities()

    def __post_init__(self):
        if not self.estimators:  # a record is whole when made: no estimators to add later
            raise ValueError(f"The 'estimators' parameter of Procedure {self.name!r} must name "
                             f"at least one estimator. Got {dict(self.estimators)!r} instead.")
        object.__setattr__(self, "estimators", {
            k: v if isinstance(v, Estimator) else Estimator(v)
            for k, v in self.estimators.items()})

    @property
    def levers(self) -> tuple:
        """The set-up fields an engineer chooses (:attr:`Capabilities.levers`)."""
        return self.capabilities.levers

    @property
    def source_method(self) -> SourceMethod:
        """The published method and its citation (:attr:`Capabilities.source_method`)."""
        return self.capabilities.source_method

    @property
    def correction(self) -> CorrectionModel:
        """How a result becomes a controller's correction (:attr:`Capabilities.correction`)."""
        return self.capabilities.correction

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

    def lever_options(self, setup) -> dict:
        """lever -> the values the planner tries by default, the set-up's own first
        (:func:`~mtplan.models.fields.lever_options`)."""
        infos = {i.name: i for i in fields_info(self.Setup)}
        return {n: lever_options(infos[n], getattr(setup, n)) for n in self.levers}

    def truth(self, values: Mapping | None = None, **kw):
        """Build this procedure's Truth from defaults and overrides."""
        return make(self.Truth, {**(values or {}), **kw}, owner=f"{self.name} truth")

    def check_setup(self, setup) -> None:
        if not isinstance(setup, self.Setup):
            raise InvalidInput(
                [f"The 'setup' parameter of {self.name} must be a {self.name}.Setup. "
                 f"Got {type(setup).__name__} instead."]
            )
        self.source_shapes(setup)

    def source_shapes(self, setup) -> dict:
        """Source -> the distribution shape the set-up's ``distributions`` field draws it
        from (:func:`distributions_field`); InvalidInput naming the field for a name that
        is not one of the procedure's sources or a source drawn as a vector (its elements
        correlated), which keeps its own."""
        shapes = parse_pairs(getattr(setup, "distributions", "") or "")
        if not shapes:
            return {}
        sources = self.sources(setup)
        p = Problems(self.name)
        for name in shapes:
            if name not in sources:
                p.add("distributions", setup.distributions,
                      f"pairs naming its error sources ({', '.join(sources)}); "
                      f"{name!r} is none of them")
            elif sources[name].distribution.event_shape:
                p.add("distributions", setup.distributions,
                      f"pairs naming sources drawn element by element; {name!r} is drawn "
                      "with its elements correlated and keeps its own distribution")
        p.raise_if_any()
        return shapes

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
        return active_sources(self.sources(setup), only, owner=self.name)

    def zero_errors(self, setup, n: int) -> dict:
        """Errors of every source set to zero, shape (n, *shape) each."""
        return zero_errors(self.sources(setup), n)

    def drawn_distributions(self, setup, only=None) -> dict:
        """Active source -> (its :class:`Source`, the distribution the Monte Carlo draws its
        elements from: its own, in the shape the set-up's ``distributions`` gives it,
        :meth:`source_shapes`)."""
        shapes = self.source_shapes(setup)
        return {name: (src, with_shape(src.distribution, shapes[name]) if name in shapes
                       else src.distribution)
                for name, src in self.active_sources(setup, only).items()}

    def draw_errors(self, setup, n: int, seq: np.random.SeedSequence, only=None) -> dict:
        """Draw the active sources, each from its own named stream of `seq`
        (:meth:`drawn_distributions`)."""
        errors = self.zero_errors(setup, n)
        for name, (src, dist) in self.drawn_distributions(setup, only).items():
            errors[name] = dist.draw(named_generator(seq, name), (n, *src.shape))
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
