"""Measured readings files: read and check them, and complete the set-up they imply.

The readings format of each procedure is what ``procedure.readings.frame`` writes
(``mtplan simulate PROC --readings-out FILE.csv``): a tidy CSV, units in the column
names, one reading per row. Reading one goes in steps, each a function below:

1. the file (:func:`_read_rows`): exists, is a readable UTF-8 CSV, not empty, a
   header with named, distinct columns, rows as long as the header (blank lines and
   lines starting with ``#`` are skipped);
2. the columns (:func:`_match_columns`): the procedure's columns; a column a
   procedure may leave out (circle_centre's ``point``: a bare point file) may be
   absent, and a length column named without its unit (``x`` for ``x_mm``) is read in
   millimetres, with a note;
3. the cells (:func:`_parse_cells`): numbers where numbers belong, no NaN, no
   repeated row;
4. the set-up (:func:`_complete_setup`, only in :func:`read_measurement`): the fields
   the file determines (``procedure.readings.setup_from_frame``) fill in what the user did not
   state; a stated value that contradicts the file is refused;
5. the design (:func:`_match_design`): the set-up's number of readings and its
   positions, angles and indices, in any row order;
6. the instrument's range (:func:`_check_limits`);
7. the readings (:func:`_to_readings`): ``procedure.readings.from_frame``.

Every refusal is one :class:`InvalidInput` sentence naming the file and the row (as a
spreadsheet shows it: the header is row 1) or the column.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mtplan._validate import InvalidInput

__all__ = ["read_readings", "read_measurement", "Measurement", "reading_origin"]

_NAN_WORDS = ("", "nan", "na", "n/a", "null", "none")
#: no reading of a machine tool reaches this in any column's unit (mm, deg, rad, index): 1000 km
_LARGEST = 1e9


def _fail(path, text):
    raise InvalidInput([f"readings file {str(path)!r}: {text}"])


# --------------------------------------------------------------------------- 1. the file
def _read_rows(path) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """The header and the data rows (file row number, cells) of a CSV; blank rows dropped."""
    path = Path(path)
    if not path.exists():
        _fail(path, "no such file")
    if path.is_dir():
        _fail(path, "is a folder, not a CSV file")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        _fail(path, f"cannot be read ({exc.strerror})")
    if not raw.strip():
        _fail(path, "is empty")
    if b"\x00" in raw[:4096]:
        _fail(path, "is not a CSV file (binary content)")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        _fail(path, "is not a CSV file (not UTF-8 text)")
    reader = csv.reader(io.StringIO(text, newline=""))
    rows = []
    try:
        for cells in reader:
            if cells and cells[0].lstrip().startswith("#"):
                continue  # a comment line
            if any(c.strip() for c in cells):
                rows.append((reader.line_num, cells))
    except csv.Error as exc:
        _fail(path, f"is not a valid CSV file (row {reader.line_num}: {exc})")
    if not rows:
        _fail(path, "is empty")
    header = [c.strip() for c in rows[0][1]]
    seen = set()
    for c in header:
        if c == "":
            _fail(path, "has an unnamed column in its header")
        if c in seen:
            _fail(path, f"has the column {c!r} twice")
        seen.add(c)
    return header, rows[1:]


def _check_shape(path, header, rows, columns) -> None:
    if len(header) < 2 and header[0] not in columns:
        _fail(path, f"is not a comma-separated file with the columns {', '.join(columns)} "
              f"(header {','.join(header)[:60]!r})")
    if not rows:
        _fail(path, "has a header but no data rows")
    for line, r in rows:
        if len(r) != len(header):
            _fail(path, f"row {line} has {len(r)} cells, the header has {len(header)}")


# --------------------------------------------------------------------------- 2. the columns
@dataclass
class _Columns:
    """How the file's header maps onto the procedure's columns."""

    names: list  # the procedure's columns the file has, in the procedure's order
    source: dict  # procedure column -> the file's column
    reduced: list  # optional columns the file leaves out
    notes: list


def _match_columns(proc, path, header, expected) -> _Columns:
    """The procedure's columns in the file; unit-less length columns read in mm (noted)."""
    columns = list(expected.columns)
    source = {c: c for c in header if c in columns}
    notes = []
    for c in header:
        if c in columns:
            continue
        for name in (c.lower(), c.lower() + "_mm"):
            if name in columns and name not in source:
                source[name] = c
                if name != c.lower():
                    notes.append(f"column {c!r} names no unit: read as {name} (millimetres)")
                break
    reduced = [c for c in proc.readings.optional_columns if c not in source]
    names = [c for c in columns if c not in reduced]
    missing = [c for c in names if c not in source]
    extra = [c for c in header if c not in source.values()]
    if missing or extra:
        parts = []
        if missing:
            parts.append("lacks column(s) " + ", ".join(map(repr, missing)))
        if extra:
            parts.append("has unexpected column(s) " + ", ".join(map(repr, extra)))
        _fail(path, " and ".join(parts) + f"; {proc.name} readings have the columns "
              + ", ".join(names))
    return _Columns(names, source, reduced, notes)


# --------------------------------------------------------------------------- 3. the cells
def _parse_cells(path, header, rows, cols: _Columns, expected):
    """The table: numbers parsed where the procedure has numbers, every bad cell refused."""
    import pandas as pd

    lines = [line for line, _ in rows]
    data = {}
    for c in cols.names:
        j = header.index(cols.source[c])
        cells = [r[j].strip() for _, r in rows]
        if not pd.api.types.is_numeric_dtype(expected[c]):
            data[c] = cells
            continue
        values = np.empty(len(cells))
        for i, cell in enumerate(cells):
            if cell.lower() in _NAN_WORDS:
                _fail(path, f"row {lines[i]}, column {cols.source[c]!r} is empty or NaN"
                      + (f": {cell!r}" if cell else ""))
            try:
                v = float(cell)
            except ValueError:
                _fail(path, f"row {lines[i]}, column {cols.source[c]!r} is not a number: "
                      f"{cell[:40]!r}")
            if not math.isfinite(v):
                _fail(path, f"row {lines[i]}, column {cols.source[c]!r} is not finite: {cell!r}")
            if abs(v) > _LARGEST:
                _fail(path, f"row {lines[i]}, column {cols.source[c]!r} is {v:.6g}, beyond any "
                      f"machine (|value| <= {_LARGEST:g})")
            values[i] = v
        data[c] = values
    df = pd.DataFrame(data, columns=cols.names)
    dup = df.duplicated(keep="first").to_numpy()
    if dup.any():
        j = int(np.flatnonzero(dup)[0])
        first = int(np.flatnonzero((df == df.iloc[j]).all(axis=1).to_numpy())[0])
        _fail(path, f"row {lines[j]} repeats row {lines[first]}")
    # an array, not a list: pandas deep-copies attrs on every operation on the frame
    df.attrs["lines"] = np.asarray(lines, dtype=np.int64)
    return df


# --------------------------------------------------------------------------- 5. the design
def _nominal_truth(proc, setup):
    """The default truth, or where the set-up cannot take it (the default bore centre
    outside a small bore) the truth with every deviation zero."""
    truth = proc.Truth()
    try:
        proc.forward(setup, truth, proc.zero_errors(setup, 1))
    except (InvalidInput, ValueError):
        zero = {f.name: 0.0 for f in dataclasses.fields(truth)
                if isinstance(getattr(truth, f.name), float)}
        truth = dataclasses.replace(truth, **zero)
    return truth


def _expected_frames(proc, setup):
    """Frames of a noise-free nominal measurement, a noisy one and a perturbed truth one."""
    truth = _nominal_truth(proc, setup)
    frames = [proc.readings.frame(setup, proc.forward(setup, truth, proc.zero_errors(setup, 1))),
              proc.readings.frame(setup, proc.simulate(setup, truth, 1, rng=12345))]
    changes = {}
    for f in dataclasses.fields(truth):
        v = getattr(truth, f.name)
        if isinstance(v, float):
            changes[f.name] = v * 1.01 + 1e-4
    try:
        other = dataclasses.replace(truth, **changes)
        frames.append(proc.readings.frame(setup, proc.forward(setup, other,
                                                              proc.zero_errors(setup, 1))))
    except (InvalidInput, ValueError, TypeError, ArithmeticError):
        pass
    return frames


def _design_columns(frames):
    """Columns equal in every expected frame: they describe the set-up, not the readings."""
    first = frames[0]
    out = []
    for c in first.columns:
        a = first[c].to_numpy()
        if all(c in f.columns and np.array_equal(f[c].to_numpy(), a) for f in frames[1:]):
            out.append(c)
    return out


def _design_key(frame, design, expected):
    cols = []
    for c in design:
        col = frame[c].to_numpy()
        if col.dtype.kind in "fiu":
            scale = max(float(np.max(np.abs(expected[c].to_numpy()))), 1.0)
            col = np.round(col.astype(float) / (scale * 1e-9)).astype(np.int64)
        cols.append(col)
    return list(zip(*cols, strict=True))


def _match_design(proc, path, df, frames, reduced):
    """The set-up's number of readings and its design columns, rows put in its order."""
    expected = frames[0]
    lines = df.attrs.get("lines", list(range(2, len(df) + 2)))
    if reduced:  # a reduced file: from_frame checks the counts
        return df
    if len(df) != len(expected):
        _fail(path, f"has {len(df)} readings but this {proc.name} set-up takes {len(expected)} "
              "(check the set-up: --config/--set)")
    design = [c for c in _design_columns(frames) if c in df.columns]
    if not design:
        return df
    got, want = _design_key(df, design, expected), _design_key(expected, design, expected)
    if got == want:
        return df
    if sorted(got) == sorted(want):
        order = sorted(range(len(got)), key=lambda i: got[i])
        target = sorted(range(len(want)), key=lambda i: want[i])
        perm = np.empty(len(got), dtype=int)
        perm[target] = order
        out = df.iloc[perm].reset_index(drop=True)
        out.attrs["lines"] = np.asarray(lines, dtype=np.int64)[perm]
        return out
    wanted = set(want)
    bad = next(i for i, g in enumerate(got) if g not in wanted or got.count(g) > want.count(g))
    shown = ", ".join(f"{c} = {df[c].iloc[bad]}" for c in design)
    _fail(path, f"row {lines[bad]} ({shown}) is not a reading position of this {proc.name} "
          "set-up (check the set-up: --config/--set)")


# --------------------------------------------------------------------------- 6. the range
def _check_limits(proc, setup, path, df) -> None:
    """Readings outside the instrument's range (``procedure.readings.limits``) are refused."""
    lines = df.attrs.get("lines", list(range(2, len(df) + 2)))
    for c, (lo, hi, what) in proc.readings.limits(setup).items():
        v = df[c].to_numpy(dtype=float)
        lo = np.broadcast_to(np.asarray(lo, dtype=float), v.shape)
        hi = np.broadcast_to(np.asarray(hi, dtype=float), v.shape)
        out = np.flatnonzero((v < lo) | (v > hi))
        if out.size:
            i = int(out[0])
            _fail(path, f"the reading in column {c!r} of {proc.name} measurement row {i + 2} "
                  f"(in measuring order; file row {lines[i]}) is {v[i]:.6g}, outside {what} "
                  f"[{lo[i]:.6g}, {hi[i]:.6g}] there")


# --------------------------------------------------------------------------- 7. the readings
def _to_readings(proc, setup, path, df, expected, reduced) -> dict:
    """``procedure.readings.from_frame`` with its refusals named after the file."""
    df = _typed(df, expected)
    try:
        readings = proc.readings.from_frame(setup, df)
    except InvalidInput as exc:
        _fail(path, " ".join(exc.problems))
    except KeyError as exc:
        _fail(path, f"lacks column {exc.args[0]!r}")
    except (ValueError, TypeError, IndexError) as exc:
        _fail(path, str(exc))
    if not reduced:  # a reduced file leaves the readings it lacks as NaN, on purpose
        for k, v in readings.items():
            a = np.asarray(v)
            if a.dtype.kind in "fc" and not np.all(np.isfinite(a)):
                _fail(path, f"reading {k!r} holds NaN or infinite values")
    return readings


def _table(proc, setup, path):
    """Steps 1-3: the file's table (procedure columns, parsed cells) and its column map."""
    header, rows = _read_rows(path)
    expected = _nominal_frame(proc, setup)
    _check_shape(path, header, rows, list(expected.columns))
    cols = _match_columns(proc, path, header, expected)
    return _parse_cells(path, header, rows, cols, expected), cols


def _nominal_frame(proc, setup):
    return proc.readings.frame(setup, proc.forward(setup, proc.Truth(), proc.zero_errors(setup, 1)))


def _finish(proc, setup, path, df, cols, origin=None) -> dict:
    """Steps 5-7 for the set-up the readings were taken with; `origin` (a dict) receives
    the file's row (as a spreadsheet counts it: the header is row 1) and column of every
    reading (:func:`_origin`)."""
    frames = _expected_frames(proc, setup)
    frames = [f[[c for c in f.columns if c not in cols.reduced]] for f in frames]
    df = _match_design(proc, path, df, frames, cols.reduced)
    if not cols.reduced:
        _check_limits(proc, setup, path, df)
    readings = _to_readings(proc, setup, path, df, frames[0], cols.reduced)
    if origin is not None:
        lines = df.attrs.get("lines", list(range(2, len(df) + 2)))
        found = _origin(proc, setup, _typed(df, frames[0]), readings,
                        _design_columns(frames), np.asarray(lines, dtype=np.int64))
        origin.update(found or {})
    return readings


# --------------------------------------------------------------------------- where a reading is
def _typed(df, expected):
    """The frame with integer columns as integers where the procedure's are (from_frame),
    without the file's attributes (pandas deep-copies them on every copy and column)."""
    df = df.copy()
    df.attrs = {}
    for c in df.columns:
        if expected[c].dtype.kind in "iu" and df[c].dtype.kind == "f":
            if np.all(df[c] == np.round(df[c])):
                df[c] = df[c].astype(expected[c].dtype)
    return df


def _origin(proc, setup, df, readings, design, rows) -> dict | None:
    """File row (``rows[i]`` for frame row i) and column of every reading: key -> (rows,
    columns), arrays shaped like the reading without its batch axis (0 and "" where none).

    Found through ``procedure.readings.from_frame`` itself, in 1 + log2(rows) + 1 calls per reading
    column: the cells of the rows whose index has bit b set are nudged, and the readings
    that move spell out, bit by bit, the row they come from; a last call nudges a random
    half of the rows and checks that exactly their readings move. None where a reading
    depends on several cells or from_frame refuses a nudged frame."""
    keys = [k for k, v in readings.items() if np.asarray(v).dtype.kind in "fiu"]
    base = {k: np.asarray(readings[k], dtype=float).reshape(np.shape(readings[k])[1:])
            for k in keys}
    out = {k: (np.zeros(v.shape, dtype=int), np.full(v.shape, "", dtype=object))
           for k, v in base.items()}
    n = len(df)
    idx = np.arange(n)
    bits = max(1, (n - 1).bit_length())
    rng = np.random.default_rng(0)

    def moved(column, mask):
        f = df.copy()
        v = f[column].to_numpy(dtype=float)
        f[column] = np.where(mask, v + 1e-7 * (np.abs(v) + 1.0), v)
        r = proc.readings.from_frame(setup, f)
        return {k: np.asarray(r[k], dtype=float).reshape(base[k].shape) != base[k] for k in keys}

    columns = [c for c in df.columns if c not in design and df[c].dtype.kind in "fiu"]
    try:
        for c in columns:
            every = moved(c, np.ones(n, dtype=bool))
            code = {k: np.zeros(base[k].shape, dtype=np.int64) for k in keys}
            for b in range(bits):
                hit = moved(c, ((idx >> b) & 1).astype(bool))
                for k in keys:
                    code[k] |= hit[k].astype(np.int64) << b
            half = rng.random(n) < 0.5
            check = moved(c, half)
            for k in keys:
                if np.any(code[k][every[k]] >= n) or not np.array_equal(
                        check[k], every[k] & half[np.minimum(code[k], n - 1)]):
                    return None
                rows_k, cols_k = out[k]
                if np.any(rows_k[every[k]] > 0):  # one reading from two columns
                    return None
                rows_k[every[k]] = np.asarray(rows)[code[k][every[k]]]
                cols_k[every[k]] = c
    except (InvalidInput, ValueError, TypeError, KeyError, IndexError):
        return None
    return out


def reading_origin(procedure, setup, readings) -> dict | None:
    """Row and column of every reading in the table ``procedure.readings.frame`` writes
    (``mtplan simulate --readings-out``): key -> (rows, columns), arrays shaped like the
    reading without its batch axis; rows counted as a spreadsheet shows the written file
    (the header is row 1, the first data row 2; 0: none). None where the procedure's
    table does not say it (a reading computed from several cells)."""
    from mtplan.models import get

    proc = get(procedure)
    frame = proc.readings.frame(setup, readings)
    design = _design_columns(_expected_frames(proc, setup))
    return _origin(proc, setup, frame, readings, design, np.arange(2, len(frame) + 2))


def read_readings(procedure, setup, path) -> dict:
    """Read a readings CSV into a procedure's readings (a batch of one).

    Parameters
    ----------
    procedure : str or Procedure
    setup : Setup
        The set-up the readings were taken with (positions, counts). To complete a
        set-up from the file instead, use :func:`read_measurement`.
    path : str or Path
        CSV in the format of ``procedure.readings.frame``.

    Returns
    -------
    dict of str to array
        As ``procedure.readings.from_frame`` returns (leading axis 1).

    Raises
    ------
    InvalidInput
        One sentence naming the file and the offending row (1-based, as a
        spreadsheet shows it: the header is row 1) or column.
    """
    from mtplan.models import get

    proc = get(procedure)
    proc.check_setup(setup)
    df, cols = _table(proc, setup, path)
    return _finish(proc, setup, path, df, cols)


# --------------------------------------------------------------------------- 4. the set-up
@dataclass
class Measurement:
    """A measured readings file with the set-up it was taken with.

    Attributes
    ----------
    setup : the procedure's Setup
        The stated fields, completed by those the file determines.
    readings : dict of str to array
        A batch of one, as ``procedure.readings.from_frame`` returns.
    from_file : dict
        Fields whose value comes from the file (field -> value).
    defaults : tuple of str
        Fields at their defaults: neither stated nor determined by the file.
    notes : list of str
        What was taken from the file, scaled to it, or read with an assumption.
    origin : dict or None
        Where each reading is in the file: key -> (rows, columns), arrays shaped like the
        reading without its batch axis; a row is the file's row as a spreadsheet counts
        it (the header is row 1; comment and blank lines are counted, as in the reader's
        error messages; 0: none). None where the file does not say it
        (:func:`reading_origin`).
    """

    setup: object
    readings: dict
    from_file: dict = field(default_factory=dict)
    defaults: tuple = ()
    notes: list = field(default_factory=list)
    origin: dict | None = None


def _show(value) -> str:
    if value is None:
        return "empty"
    if isinstance(value, tuple | list):
        items = [_show(v) for v in value]
        return ",".join(items[:8]) + (f",... ({len(items)} values)" if len(items) > 8 else "")
    if isinstance(value, float):
        return f"{value:.7g}"
    return str(value)


def _complete_setup(proc, given, implied, path):
    """(setup, from_file, defaults, notes): stated values, completed by the file's.

    A stated value that contradicts the file beyond its tolerance is refused, all of them
    in one sentence. A default that the file contradicts is replaced by the file's value
    (for a bound: by the bound); a default the file agrees with is kept.
    """
    from mtplan.models.protocol import fields_info, make

    defaults = {i.name: i.default for i in fields_info(proc.Setup)}
    chosen, taken, confirmed, conflicts, notes = {}, [], [], [], []
    for name, imp in implied.items():
        if any(g in given for g in imp.unless_given if g != name):
            continue
        why = f" ({imp.why})" if imp.why else ""
        rel = {"max": "at most ", "min": "at least "}.get(imp.bound, "")
        if name in given:
            if imp.agrees(given[name]):
                continue
            text = (f"{name} = {_show(given[name])} is stated, the file implies {rel}"
                    f"{_show(imp.value)}{why}")
            if imp.soft:
                notes.append(text + "; the stated value is kept")
            else:
                conflicts.append(text + (f", within {imp.tolerance:.3g}" if imp.tolerance
                                         else ""))
        elif imp.agrees(defaults[name]):
            confirmed.append(name)
        else:
            chosen[name] = imp.value
            parts = [imp.why] if imp.why else []
            if imp.bound != "equal":
                parts.insert(0, f"default {_show(defaults[name])}")
            shown = f" ({'; '.join(parts)})" if parts else ""
            taken.append(f"{name} = {_show(imp.value)}{shown}")
    if conflicts:
        _fail(path, "contradicts the stated set-up: " + "; ".join(conflicts))
    try:
        setup = make(proc.Setup, {**chosen, **given}, owner=proc.name)
    except InvalidInput as exc:
        _fail(path, "the set-up it implies with the stated fields is not valid: "
              + " ".join(exc.problems))
    if taken:
        notes.insert(0, "set-up from the readings file: " + "; ".join(taken))
    if confirmed:
        notes.append("defaults the readings file agrees with: " + ", ".join(confirmed))
    kept = tuple(n for n in defaults if n not in given and n not in implied)
    if kept:
        notes.append("at their defaults (the file does not determine them): " + ", ".join(kept))
    return setup, dict(chosen), kept, notes


def read_measurement(procedure, path, values=None) -> Measurement:
    """Read a readings CSV and the set-up it was taken with.

    The fields the file determines (``procedure.readings.setup_from_frame``: counts, positions,
    angles, lattice, a bore's radius) need not be stated; stated ones (`values`) must
    agree with the file within the procedure's tolerance. The rest keep their defaults.

    Parameters
    ----------
    procedure : str or Procedure
    path : str or Path
        CSV in the format of ``procedure.readings.frame`` (or a reduced format the
        procedure accepts, such as circle_centre's bare ``x_mm, y_mm`` points).
    values : mapping of str to value, optional
        Set-up fields the user states (strings from the command line are parsed).

    Returns
    -------
    Measurement

    Raises
    ------
    InvalidInput
        One sentence naming the file and the offending row or column, or every stated
        field that contradicts the file (the field, the stated value, the value the file
        implies).
    """
    from mtplan.models import get
    from mtplan.models.protocol import parse_fields

    proc = get(procedure)
    given = parse_fields(proc.Setup, values, owner=proc.name)  # each value alone, first
    nominal = proc.Setup()
    df, cols = _table(proc, nominal, path)
    try:
        implied = proc.readings.setup_from_frame(df)
    except InvalidInput as exc:
        _fail(path, " ".join(exc.problems))
    setup, from_file, kept, notes = _complete_setup(proc, given, implied, path)
    origin = {}
    readings = _finish(proc, setup, path, df, cols, origin)
    return Measurement(setup=setup, readings=readings, from_file=from_file, defaults=kept,
                       notes=cols.notes + notes, origin=origin or None)
