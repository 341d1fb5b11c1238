"""The field machinery of set-ups and truths: declared fields, their units, parsing and checks.

A procedure's ``Setup`` and ``Truth`` are frozen dataclasses of :class:`SetupBase` whose
fields are declared with :func:`param`: the unit is the field name's suffix (``incline_deg``,
``probe_noise_um``; :func:`split_unit`), the range and meaning are its metadata. From these
declarations alone, and for every procedure alike:

- :class:`SetupBase` validates an instance on construction and lists every problem at once
  (cross-field rules go in a subclass's ``_check``);
- :func:`parse_fields` and :func:`make` read values given as text (the command line, a study
  file) into the fields' kinds;
- :func:`fields_info` describes the fields (kind, default, unit, range, meaning) for the
  command line, the reports and the designer;
- file fields (``param(reader=...)``) read their file once per version (:func:`file_content`,
  :func:`file_fields`, :func:`resolve_file_fields`), and condition fields take a test's
  recorded conditions (:func:`with_conditions`);
- :class:`Implied` is a field's value as a measured readings table determines it, and
  :func:`frame_columns` checks such a table's columns.

The records of the procedure contract (``Measurand``, ``Source``, ``Estimator``,
``Procedure``, ...) are in :mod:`mtplan.models.protocol`, which re-exports these names.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from mtplan._validate import InvalidInput, Problems, is_real

__all__ = [
    "UNITS",
    "UNIT_SUFFIXES",
    "split_unit",
    "shown_with_unit",
    "param",
    "OWNERS",
    "with_conditions",
    "fields_info",
    "file_fields",
    "file_content",
    "resolve_file_fields",
    "SetupBase",
    "TruthBatch",
    "FieldInfo",
    "parse_fields",
    "make",
    "Implied",
    "frame_columns",
]

#: Display units and their factor from the internal unit (mm for lengths, rad for angles).
UNITS = {
    "mm": 1.0,
    "um": 1e3,
    "nm": 1e6,
    "rad": 1.0,
    "mrad": 1e3,
    "urad": 1e6,
    "deg": 180 / math.pi,
    "arcsec": 648000 / math.pi,
    "1": 1.0,
    "ppm": 1e6,
    "s": 1.0,
}
UNIT_SUFFIXES = ("mm", "um", "nm", "rad", "mrad", "urad", "deg", "arcsec", "ppm", "s", "ms", "c",
                 "um_per_m", "urad_per_m", "mm_min", "per_s", "um_per_s", "urad_per_s",
                 "um_per_deg", "urad_per_deg", "um_per_h", "ppm_per_h", "k_per_m", "k",
                 "ppm_per_k")

_SUFFIXES_LONGEST_FIRST = tuple(sorted(UNIT_SUFFIXES, key=len, reverse=True))


def split_unit(name: str) -> tuple[str, str]:
    """(base, unit suffix) of a field name: ``"EY0A_um"`` -> ``("EY0A", "um")``; the suffix
    is "" when the name has none of :data:`UNIT_SUFFIXES`."""
    for suffix in _SUFFIXES_LONGEST_FIRST:
        if name.endswith("_" + suffix):
            return name[: -len(suffix) - 1], suffix
    return name, ""


def shown_with_unit(name: str, value) -> str:
    """A field's value as a note prints it: ``("EY0A_um", 10.0)`` -> ``"EY0A = 10 um"``."""
    base, suffix = split_unit(name)
    return f"{base} = {value:.6g}" + (f" {suffix}" if suffix else "")



#: who carries an error source (:func:`param`'s ``owner``)
OWNERS = ("machine", "instrument", "artefact", "workpiece", "method", "environment")


def param(
    default,
    *,
    doc: str,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    choices: tuple | None = None,
    min_len: int | None = None,
    max_len: int | None = None,
    reader: Callable | None = None,
    condition: str | None = None,
    owner: str | None = None,
):
    """Declare a set-up (or truth) field with its documentation and allowed range.

    The unit is the field name's suffix (``_mm``, ``_um``, ``_deg``, ...). For a
    tuple field (``tuple[float, ...]``) the range applies to every element and
    `min_len` and `max_len` to its length: every list field states its `max_len`, as every
    count states its `high`, so that no value given sizes the work beyond what was
    declared (a longer list is refused before its elements are read).

    A field with a `reader` is a *file field* (a ``str | None`` path, None: no file): the
    set-up reads the file on construction with ``reader(path) -> content``, which refuses a
    bad file with :class:`InvalidInput` listing every problem (naming the file, row and
    column); the content is then :func:`file_content`. A relative path is taken from the
    working directory, or from the set-up file that states it (:func:`resolve_file_fields`).
    Tools that must not open a user's path (the browser designer) leave file fields out
    (:func:`file_fields`).

    A field with a `condition` is a measured test condition (a ``float | None``, None: not
    measured) that a study records once for the whole test in its ``[conditions]`` table
    under that key: where the set-up leaves the field None, the readings are evaluated with
    the recorded value (:func:`with_conditions`).

    A field that sizes an error source names the source's `owner` (:data:`OWNERS`): who
    carries that error and so who can reduce it (the machine's own error, the instrument's
    or its calibration's, the artefact's, the workpiece's, the method's set-up, the
    environment's). Advice phrases an action by it: a calibration for an instrument, never
    a set-up.
    """
    if owner is not None and owner not in OWNERS:
        raise ValueError(f"The 'owner' parameter of param must be one of {', '.join(OWNERS)}. "
                         f"Got {owner!r} instead.")
    meta = {
        "doc": doc,
        "low": low,
        "high": high,
        "low_open": low_open,
        "high_open": high_open,
        "choices": choices,
        "min_len": min_len,
        "max_len": max_len,
        "reader": reader,
        "condition": condition,
        "owner": owner,
    }
    if isinstance(default, list):
        default = tuple(default)
    return dataclasses.field(default=default, metadata=meta)


def with_conditions(setup, conditions: dict):
    """`setup` with each field that declares a ``condition`` and is None (not measured) set
    to the value the test's `conditions` record under that key; `setup` itself where none
    applies. The set-up's own value wins: a test may state its own measurement."""
    changes = {f.name: conditions[f.metadata["condition"]]
               for f in dataclasses.fields(setup)
               if f.metadata.get("condition") in conditions and getattr(setup, f.name) is None}
    return dataclasses.replace(setup, **changes) if changes else setup


def _base_type(tp):
    """(kind, optional) for an annotation: kind in float, int, bool, str, tuple."""
    optional = False
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        optional = len(args) < len(typing.get_args(tp))
        tp = args[0] if len(args) == 1 else tp
        origin = typing.get_origin(tp)
    if origin is tuple or tp is tuple:
        args = typing.get_args(tp)
        return ("tuple", args[0] if args else float), optional
    return (tp, None), optional


@dataclass(frozen=True)
class FieldInfo:
    """What a Setup or Truth field declares (:func:`param`), read once per class.

    Attributes
    ----------
    name : str
        The field's name; its unit is the name's suffix.
    kind : type or str
        ``float``, ``int``, ``bool``, ``str`` or ``"tuple"`` (a list of numbers).
    element : type or None
        The kind of a tuple field's elements (``float``); None for other fields.
    optional : bool
        The field may be None (empty).
    default : object
        The field's default value.
    unit : str
        The unit suffix of the name (:func:`split_unit`; "" for none).
    doc : str
        What the field is, in plain words.
    low, high : float or None
        The allowed range (None: unbounded), each end open where `low_open` / `high_open`.
    low_open, high_open : bool
    choices : tuple or None
        The allowed values of a field that takes one of a few.
    min_len, max_len : int or None
        The fewest and the most elements of a tuple field.
    file : bool
        A file field (``param(reader=...)``): a path whose file the set-up reads.
    condition : str or None
        The key of the test condition a study records for this field
        (:func:`with_conditions`).
    owner : str or None
        Who carries the error source the field sizes (one of :data:`OWNERS`), None for a
        field that sizes none.
    """

    name: str
    kind: object
    element: object
    optional: bool
    default: object
    unit: str
    doc: str | None = None
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple | None = None
    min_len: int | None = None
    max_len: int | None = None
    file: bool = False
    condition: str | None = None
    owner: str | None = None

    @property
    def count(self) -> bool:
        """An int field or a list field: its value, or its length, may size the work (a
        count of points, repeats or positions; a list of positions). Each declares the
        largest it may be (:attr:`largest`)."""
        return self.kind is int or self.kind == "tuple"

    @property
    def largest(self) -> int | None:
        """The largest size a count field allows: `high` for an int, `max_len` for a list
        (None: unbounded, or not a count)."""
        if self.kind is int:
            return None if self.high is None else int(self.high)
        return self.max_len if self.kind == "tuple" else None

    def size(self, value) -> int | None:
        """The size a value of this count field states: the int itself, or the list's
        length; None for an empty (default) value or a value of another kind."""
        if isinstance(value, tuple | list) and self.kind == "tuple":
            return len(value)
        if self.kind is int and is_real(value) and float(value).is_integer():
            return int(value)
        return None


def fields_info(cls) -> tuple[FieldInfo, ...]:
    """What each field of a Setup or Truth class declares (name, kind, default, unit, doc,
    range), in the order of the class: one :class:`FieldInfo` per field."""
    return _fields_info(cls)


@functools.lru_cache(maxsize=None)
def _fields_info(cls) -> tuple[FieldInfo, ...]:
    """:func:`fields_info`, once per class (``typing.get_type_hints`` is slow, and every
    set-up built validates through it)."""
    if issubclass(cls, TruthBatch):
        return _fields_info(cls.truth_class)
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        if f.name.startswith("_"):
            continue
        (kind, elem), optional = _base_type(hints[f.name])
        out.append(FieldInfo(
            name=f.name, kind=kind, element=elem, optional=optional, default=f.default,
            unit=split_unit(f.name)[1],
            **{k: f.metadata.get(k) for k in ("doc", "low", "high", "choices", "min_len",
                                                 "max_len")},
            low_open=bool(f.metadata.get("low_open")),
            high_open=bool(f.metadata.get("high_open")),
            file=f.metadata.get("reader") is not None,
            condition=f.metadata.get("condition"), owner=f.metadata.get("owner")))
    return tuple(out)


def file_fields(cls) -> tuple[str, ...]:
    """The names of the file fields of a Setup class (declared with ``param(reader=...)``)."""
    return tuple(info.name for info in _fields_info(cls) if info.file)


def resolve_file_fields(cls, values: Mapping, base) -> dict:
    """`values` with each file field's relative path taken from the folder `base` (that of
    the set-up file stating them); other values, absolute paths and empty ones unchanged."""
    from pathlib import Path

    out = dict(values)
    for name in file_fields(cls):
        value = out.get(name)
        if isinstance(value, str) and value.strip() and value.strip().lower() not in (
                "none", "default") and not Path(value).is_absolute():
            out[name] = str(Path(base) / value)
    return out


@functools.lru_cache(maxsize=32)
def _read_file(reader, path: str, stamp: tuple):
    """``reader(path)``, once per file version (`stamp`: its absolute path, modification
    time and size)."""
    return reader(path)


def file_content(setup, name: str):
    """The content of the file field `name` of `setup` as its reader returns it (None when
    the field is empty); read once per version of the file."""
    import os

    path = getattr(setup, name)
    if path is None:
        return None
    reader = next(f.metadata["reader"] for f in dataclasses.fields(setup) if f.name == name)
    st = os.stat(path)
    return _read_file(reader, path, (os.path.abspath(path), st.st_mtime_ns, st.st_size))


def _check_file(p: "Problems", setup, info) -> None:
    """Read a file field's file, recording why it cannot be read or what its reader refuses."""
    path = getattr(setup, info.name)
    if path is None or not isinstance(path, str):
        return
    try:
        file_content(setup, info.name)
    except InvalidInput as exc:
        p.items.extend(exc.problems)
    except OSError as exc:
        p.add(info.name, path, f"a readable file ({exc.strerror or exc})")


def _describe(info) -> str:
    kind = info.kind
    name = {float: "a finite number", int: "an int", bool: "true or false", str: "a string"}.get(
        kind, "a comma-separated list of numbers" if kind == "tuple" else str(kind)
    )
    if info.choices:
        return "one of " + ", ".join(repr(c) for c in info.choices)
    if info.file:
        return "the path of a file" + (" (or empty for none)" if info.optional else "")
    bounds = []
    if info.low is not None:
        bounds.append(f"{'>' if info.low_open else '>='} {info.low:g}")
    if info.high is not None:
        bounds.append(f"{'<' if info.high_open else '<='} {info.high:g}")
    text = name + (" " + " and ".join(bounds) if bounds else "")
    if info.optional:
        text += " (or empty for the default)"
    return text


def _check_value(p: Problems, info, value) -> None:
    if value is None:
        if not info.optional:
            p.add(info.name, value, _describe(info))
        return
    kind = info.kind
    if info.choices:
        p.choice(info.name, value, info.choices)
        return
    rng = dict(low=info.low, high=info.high, low_open=info.low_open,
               high_open=info.high_open)
    if kind is bool:
        p.require(isinstance(value, bool | np.bool_), info.name, value, "true or false")
    elif kind is str:
        p.require(isinstance(value, str), info.name, value, "a string")
    elif kind is int:
        if not p.number(info.name, value, integer=True, **rng):
            return
    elif kind is float:
        p.number(info.name, value, **rng)
    elif kind == "tuple":
        if isinstance(value, tuple) and info.max_len is not None and len(value) > info.max_len:
            # before its elements are read: a list's length sizes the work
            p.add(info.name, value, _describe_list(info))
            return
        if not isinstance(value, tuple) or not all(is_real(v) for v in value):
            p.add(info.name, value, "a list of numbers")
            return
        arr = np.asarray(value, dtype=float)
        lo, hi = info.low, info.high
        ok = np.all(np.isfinite(arr))
        if lo is not None:
            ok &= np.all(arr > lo) if info.low_open else np.all(arr >= lo)
        if hi is not None:
            ok &= np.all(arr < hi) if info.high_open else np.all(arr <= hi)
        if info.min_len is not None:
            ok &= len(value) >= info.min_len
        if not ok:
            p.add(info.name, value, _describe_list(info))


def _describe_list(info) -> str:
    """What a tuple field allows: finite numbers, each in its range, and how many."""
    allowed = "a list of finite numbers"
    b = _describe(dataclasses.replace(info, kind=float, optional=False)).replace(
        "a finite number", "")
    if b.strip():
        allowed += ", each" + b
    lo, hi = info.min_len, info.max_len
    if lo and hi is not None:
        allowed += (f", exactly {lo} of them" if lo == hi
                    else f", {lo} to {hi} of them")
    elif lo:
        allowed += f", at least {lo} of them"
    elif hi is not None:
        allowed += f", at most {hi} of them"
    return allowed



class SetupBase:
    """Mixin for frozen Setup and Truth dataclasses: validation on construction.

    Subclasses set ``_owner`` (the procedure name used in messages) and may override
    ``_check(self, problems)`` for rules that involve several fields.
    """

    _owner = "setup"

    def __post_init__(self):
        p = Problems(self._owner)
        infos = fields_info(type(self))
        for info in infos:
            value = getattr(self, info.name)
            if isinstance(value, list):
                value = tuple(value)
                object.__setattr__(self, info.name, value)
            if info.kind is float and is_real(value) and not isinstance(value, float):
                object.__setattr__(self, info.name, float(value))
            if info.kind is int and is_real(value) and float(value).is_integer():
                object.__setattr__(self, info.name, int(value))
            _check_value(p, info, getattr(self, info.name))
        for info in infos:
            if info.file and not p:
                _check_file(p, self, info)
        if not p:
            self._check(p)
        p.raise_if_any()

    def _check(self, problems: Problems) -> None:
        """Cross-field rules; record problems with ``problems.add`` / ``add_text``."""

    def notes(self) -> list[str]:
        """What a reader of any result of this set-up must know about it (a temperature
        assumed, not measured); a procedure's Setup adds its own. Results print them
        first among their notes."""
        return []

    def replace(self, **changes):
        """A copy with `changes` applied (validated)."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def batch(cls, base=None, /, **values):
        """A batch of truths of this class (as astropy's model sets): `base` (default: the
        class's defaults) with `values` set, each float field a number or an array (m,) and
        each tuple field a tuple of such, one truth per batch row of ``forward``.

        The values are not checked against the fields' ranges (they are a fit's iterates,
        a Jacobian's steps or estimates, checked where they are made); only that the
        arrays agree in length. Returns an instance of :class:`TruthBatch` (a subclass of
        this class, so ``forward`` reads it as it reads one truth).
        """
        one = cls.truth_class if issubclass(cls, TruthBatch) else cls
        kw = {} if base is None else {f.name: getattr(base, f.name)
                                      for f in dataclasses.fields(base) if f.init}
        kw.update(values)
        return _batch_class(one)(**kw)

    def as_dict(self) -> dict:
        """Field values as plain Python (tuples as lists), for JSON and tables."""
        out = {}
        for f in dataclasses.fields(self):
            if f.name.startswith("_"):
                continue
            v = getattr(self, f.name)
            out[f.name] = list(v) if isinstance(v, tuple) else v
        return out


class TruthBatch:
    """A batch of truths: the base of ``Truth.batch``'s types (:meth:`SetupBase.batch`).

    Each procedure's Truth class has one batch type, a subclass of it (so the forward
    model, ``dataclasses.fields`` and ``dataclasses.replace`` treat a batch as a truth)
    whose fields hold numbers or arrays (m,), one truth per batch row. It is frozen like
    the Truth and is made only by ``Truth.batch``, never by changing a truth. Its
    construction checks the arrays' lengths, not the fields' ranges.
    """

    #: the Truth class whose batches this type holds
    truth_class: type = None

    def __post_init__(self):
        lengths = set()
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            for v in (value if isinstance(value, tuple) else (value,)):
                ndim = np.ndim(v)
                if ndim > 1:
                    raise ValueError(
                        f"The field {f.name!r} of a {self.truth_class.__name__} batch must "
                        f"hold numbers or arrays (m,). Got an array of shape {np.shape(v)} "
                        "instead.")
                if ndim == 1:
                    lengths.add(len(v))
        if len(lengths) > 1:
            raise ValueError(f"The fields of a {self.truth_class.__name__} batch must hold "
                             f"arrays of one length. Got lengths {sorted(lengths)} instead.")
        object.__setattr__(self, "_rows", lengths.pop() if lengths else None)

    @property
    def rows(self) -> int | None:
        """The number of truths m (None: every field is one number, one truth)."""
        return self._rows

    def __reduce__(self):
        return (_batch_of, (self.truth_class, {f.name: getattr(self, f.name)
                                               for f in dataclasses.fields(self) if f.init}))


@functools.lru_cache(maxsize=None)
def _batch_class(cls) -> type:
    """The batch type of the Truth class `cls` (one per class)."""
    return type(f"{cls.__name__}Batch", (TruthBatch, cls),
                {"truth_class": cls, "__doc__": f"A batch of {cls.__qualname__} (m truths)."})


def _batch_of(cls, values: dict):
    """``cls.batch(**values)`` (how a pickled batch is made again)."""
    return cls.batch(**values)


def _coerce(info, value):
    """Parse a command-line string (or TOML value) into the field's kind."""
    kind = info.kind
    if isinstance(value, str):
        text = value.strip()
        if info.optional and text.lower() in ("", "none", "default"):
            return None
        if kind is bool:
            low = text.lower()
            if low in ("1", "true", "yes", "on"):
                return True
            if low in ("0", "false", "no", "off"):
                return False
            raise ValueError
        if kind is int:
            f = float(text)
            if not f.is_integer():
                raise ValueError
            return int(f)
        if kind is float:
            return float(text)
        if kind == "tuple":
            parts = [s for s in text.replace(";", ",").split(",") if s.strip()]
            return tuple(float(s) for s in parts)
        return text
    if kind == "tuple" and isinstance(value, list | tuple):
        return tuple(value)
    if kind == "tuple" and is_real(value):
        return (value,)
    return value


def parse_fields(cls, values: Mapping | None, *, owner: str | None = None) -> dict:
    """Field values of a Setup (or Truth) class parsed into their kinds, not yet combined.

    Strings from the command line are parsed (``"6"`` -> 6, ``"0,90,180"`` -> a tuple)
    and each value is checked against its own field's range; rules between fields are
    left to the class, so that values that only make sense together with others (a
    set-up completed from a readings file) can be read first.

    Raises
    ------
    InvalidInput
        Listing unknown fields, unparsable and out-of-range values together.
    """
    owner = owner or getattr(cls, "_owner", cls.__name__)
    p = Problems(owner)
    infos = {i.name: i for i in fields_info(cls)}
    given = {}
    for key, value in (values or {}).items():
        if key not in infos:
            p.add_text(
                f"{owner} has no field {key!r}; its fields are: " + ", ".join(infos)
            )
            continue
        try:
            given[key] = _coerce(infos[key], value)
        except (ValueError, TypeError):
            p.add(key, value, _describe(infos[key]))
            continue
        _check_value(p, infos[key], given[key])
    p.raise_if_any()
    return given


def make(cls, values: Mapping | None = None, *, base=None, owner: str | None = None):
    """Build a Setup (or Truth) from `values`, coercing strings, reporting all problems.

    Parameters
    ----------
    cls : type
        The Setup or Truth dataclass.
    values : mapping of str to value
        Field overrides (strings from the command line are parsed).
    base : instance of cls, optional
        Values not given are taken from it (default: the class defaults).

    Raises
    ------
    InvalidInput
        Listing unknown fields, unparsable values and out-of-range values together.
    """
    owner = owner or getattr(cls, "_owner", cls.__name__)
    p = Problems(owner)
    try:
        given = parse_fields(cls, values, owner=owner)
    except InvalidInput as exc:
        raise InvalidInput(exc.problems) from None
    kwargs = dict(base.as_dict() if base is not None else {})
    kwargs = {k: (tuple(v) if isinstance(v, list) else v) for k, v in kwargs.items()}
    kwargs.update(given)
    try:
        obj = cls(**kwargs)
    except InvalidInput as exc:
        p.items.extend(exc.problems)
        obj = None
    p.raise_if_any()
    return obj


@dataclass(frozen=True)
class Implied:
    """A set-up field's value as a measured readings table determines it.

    Parameters
    ----------
    value : object
        The value in the field's kind and unit (a tuple for list fields; None: the file
        leaves the field empty, e.g. no range when the angles are not a regular grid).
    tolerance : float
        A value the user states agrees with the file when within this of `value` (in
        the field's unit; per element for list fields). 0: exactly.
    bound : {"equal", "max", "min"}
        ``"equal"``: the file determines the field (a default is replaced by `value`);
        ``"max"`` / ``"min"``: the file allows at most / at least `value` (a default
        beyond it is replaced by `value`, one within it is kept).
    why : str
        How the file determines it, for the note (``"the 6 points' geometric circle"``).
    soft : bool
        The file suggests rather than determines the value (the scatter of the readings
        bounds a noise from below): a stated value beyond it is kept, with a note.
    unless_given : tuple of str
        Other fields that, when the user states any of them, leave this field alone (a
        noise budget the user has set up).
    """

    value: object
    tolerance: float = 0.0
    bound: str = "equal"
    why: str = ""
    soft: bool = False
    unless_given: tuple = ()

    def agrees(self, given) -> bool:
        """Whether a stated value agrees with the file within the tolerance."""
        v, tol = self.value, self.tolerance
        if v is None or given is None:
            return v is None and given is None
        if isinstance(v, str) or isinstance(v, bool) or isinstance(given, str | bool):
            return v == given
        a = np.atleast_1d(np.asarray(given, dtype=float))
        b = np.atleast_1d(np.asarray(v, dtype=float))
        if a.shape != b.shape:
            return False
        if self.bound == "max":
            return bool(np.all(a <= b + tol))
        if self.bound == "min":
            return bool(np.all(a >= b - tol))
        return bool(np.all(np.abs(a - b) <= tol))


# --------------------------------------------------------------------------- readings
def frame_columns(df, columns, owner: str, *, numeric=None, problems: Problems | None = None
                  ) -> dict:
    """Check a readings table and return its columns as arrays (the start of ``from_frame``).

    Refuses, with one :class:`InvalidInput` listing every problem, a table that is not a
    DataFrame, lacks any of `columns`, or has a missing or non-numeric value in one of the
    `numeric` columns (default: all of them), naming the column and the first bad row.
    With `problems` given, bad values are added to it (for the caller to raise together
    with its own findings) instead of being raised here.

    Returns
    -------
    dict of column -> array (float for numeric columns, the raw values otherwise)
    """
    import pandas as pd

    columns = list(columns)
    numeric = columns if numeric is None else list(numeric)
    p = Problems(owner) if problems is None else problems
    if not isinstance(df, pd.DataFrame):
        p.add("data", type(df).__name__, "a pandas DataFrame")
        p.raise_if_any()
    missing = [c for c in columns if c not in df.columns]
    if missing:
        p.add_text(f"The {owner} lack the column(s) {', '.join(missing)}; the columns are "
                   f"{', '.join(columns)}")
        p.raise_if_any()
    out = {}
    for col in columns:
        if col not in numeric:
            out[col] = df[col].to_numpy()
            continue
        values = pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            p.add_text(f"The column {col!r} of the {owner} must hold finite numbers; row "
                       f"{int(bad[0])} holds {df[col].iloc[bad[0]]!r}"
                       + (f" ({bad.size} rows in all)" if bad.size > 1 else ""))
        out[col] = values
    if problems is None:
        p.raise_if_any()
    return out
