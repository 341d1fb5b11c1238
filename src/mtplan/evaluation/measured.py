"""Measured data: read a readings CSV, estimate the measurands with their uncertainty.

The readings format of each procedure is what ``procedure.readings_frame`` writes
(``mtplan simulate PROC --readings-out FILE.csv``): a tidy CSV, units in the
column names, one reading per row. :func:`read_readings` does the generic
file-level checks (exists, CSV, not empty, the expected columns, no duplicate
columns or rows, numbers where numbers belong, no NaN, the set-up's number of
rows and the set-up's positions) and leaves the procedure-specific ones to
``procedure.from_frame``. Every refusal is one :class:`InvalidInput` sentence
naming the file and the row or column.

:func:`estimate_measured` gives the measurands with their uncertainty, by Monte
Carlo around the estimate (``"mc"``) or by the posterior of the forward model
(``"posterior"``, :func:`mtplan.evaluation.posterior.sample_posterior`).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mtplan._validate import InvalidInput, Problems

__all__ = ["read_readings", "estimate_measured", "MeasuredResult", "UNCERTAINTY_METHODS"]

UNCERTAINTY_METHODS = ("mc", "posterior")


def _fail(path, text):
    raise InvalidInput([f"readings file {str(path)!r}: {text}"])


def _expected_frames(proc, setup):
    """Frames of a noise-free default measurement, a noisy one and a perturbed truth one."""
    import dataclasses

    truth = proc.Truth()
    frames = [proc.readings_frame(setup, proc.forward(setup, truth, proc.zero_errors(setup, 1))),
              proc.readings_frame(setup, proc.simulate(setup, truth, 1, rng=12345))]
    changes = {}
    for f in dataclasses.fields(truth):
        v = getattr(truth, f.name)
        if isinstance(v, float):
            changes[f.name] = v * 1.01 + 1e-4
    try:
        other = dataclasses.replace(truth, **changes)
        frames.append(proc.readings_frame(setup, proc.forward(setup, other,
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


def read_readings(procedure, setup, path) -> dict:
    """Read a readings CSV into a procedure's readings (a batch of one).

    Parameters
    ----------
    procedure : str or Procedure
    setup : Setup
        The set-up the readings were taken with (positions, counts).
    path : str or Path
        CSV in the format of ``procedure.readings_frame``.

    Returns
    -------
    dict of str to array
        As ``procedure.from_frame`` returns (leading axis 1).

    Raises
    ------
    InvalidInput
        One sentence naming the file and the offending row (1-based, as a
        spreadsheet shows it: the header is row 1) or column.
    """
    import pandas as pd

    from mtplan.models import get

    proc = get(procedure)
    proc.check_setup(setup)
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
    rows = list(csv.reader(text.splitlines()))
    rows = [r for r in rows if any(c.strip() for c in r)]
    header = [c.strip() for c in rows[0]]
    frames = _expected_frames(proc, setup)
    expected = frames[0]
    exp_cols = list(expected.columns)
    if len(header) < 2 and header[0] not in exp_cols:
        _fail(path, f"is not a comma-separated file with the columns {', '.join(exp_cols)} "
              f"(header {text.splitlines()[0][:60]!r})")
    seen = set()
    for c in header:
        if c == "":
            _fail(path, "has an unnamed column in its header")
        if c in seen:
            _fail(path, f"has the column {c!r} twice")
        seen.add(c)
    if len(rows) < 2:
        _fail(path, "has a header but no data rows")
    for i, r in enumerate(rows[1:], start=2):
        if len(r) != len(header):
            _fail(path, f"row {i} has {len(r)} cells, the header has {len(header)}")

    # a procedure may accept a reduced format (circle_centre: bare x_mm, y_mm points);
    # its from_frame then checks the counts
    reduced = [c for c in proc.optional_columns if c not in header]
    if reduced:
        exp_cols = [c for c in exp_cols if c not in reduced]
        expected = expected[exp_cols]
        frames = [f[[c for c in f.columns if c not in reduced]] for f in frames]
    missing = [c for c in exp_cols if c not in header]
    extra = [c for c in header if c not in exp_cols]
    if missing or extra:
        parts = []
        if missing:
            parts.append("lacks column(s) " + ", ".join(map(repr, missing)))
        if extra:
            parts.append("has unexpected column(s) " + ", ".join(map(repr, extra)))
        _fail(path, " and ".join(parts) + f"; {proc.name} readings have the columns "
              + ", ".join(exp_cols))

    data = {c: [r[j].strip() for r in rows[1:]] for j, c in enumerate(header)}
    df = pd.DataFrame({c: data[c] for c in exp_cols})
    for c in exp_cols:
        numeric = pd.api.types.is_numeric_dtype(expected[c])
        if not numeric:
            continue
        values = np.empty(len(df))
        for i, cell in enumerate(df[c]):
            row = i + 2
            if cell == "" or cell.lower() in ("nan", "na", "n/a", "null", "none"):
                _fail(path, f"row {row}, column {c!r} is empty or NaN")
            try:
                v = float(cell)
            except ValueError:
                _fail(path, f"row {row}, column {c!r} is not a number: {cell[:40]!r}")
            if not math.isfinite(v):
                _fail(path, f"row {row}, column {c!r} is not finite: {cell!r}")
            values[i] = v
        df[c] = values
    dup = df.duplicated(keep="first")
    if dup.any():
        j = int(np.flatnonzero(dup.to_numpy())[0])
        first = int(np.flatnonzero((df == df.iloc[j]).all(axis=1).to_numpy())[0])
        _fail(path, f"row {j + 2} repeats row {first + 2}")
    if len(df) != len(expected) and not reduced:
        _fail(path, f"has {len(df)} readings but this {proc.name} set-up takes {len(expected)} "
              "(check the set-up: --config/--set)")

    # design columns (positions, angles, indices) must be the set-up's, in any row order
    design = [] if reduced else [c for c in _design_columns(frames) if c in df.columns]
    if design:
        def key(frame):
            cols = []
            for c in design:
                col = frame[c].to_numpy()
                if col.dtype.kind in "fiu":
                    col = col.astype(float)
                    scale = max(float(np.max(np.abs(expected[c].to_numpy()))), 1.0)
                    col = np.round(col / (scale * 1e-9)).astype(np.int64)
                cols.append(col)
            return list(zip(*cols, strict=True))

        got, want = key(df), key(expected)
        if got != want:
            if sorted(got) == sorted(want):
                order = sorted(range(len(got)), key=lambda i: got[i])
                target = sorted(range(len(want)), key=lambda i: want[i])
                perm = np.empty(len(got), dtype=int)
                perm[target] = order
                df = df.iloc[perm].reset_index(drop=True)
            else:
                wanted = set(want)
                bad = next(i for i, g in enumerate(got) if g not in wanted or got.count(g) >
                           want.count(g))
                shown = ", ".join(f"{c} = {df[c].iloc[bad]}" for c in design)
                _fail(path, f"row {bad + 2} ({shown}) is not a reading position of this "
                      f"{proc.name} set-up (check the set-up: --config/--set)")
    if proc.reading_limits is not None and not reduced:
        for c, (lo, hi, what) in proc.reading_limits(setup).items():
            v = df[c].to_numpy(dtype=float)
            lo = np.broadcast_to(np.asarray(lo, dtype=float), v.shape)
            hi = np.broadcast_to(np.asarray(hi, dtype=float), v.shape)
            out = np.flatnonzero((v < lo) | (v > hi))
            if out.size:
                i = int(out[0])
                _fail(path, f"the reading in column {c!r} of {proc.name} measurement row {i + 2} "
                      f"(in measuring order) is {v[i]:.6g}, outside {what} "
                      f"[{lo[i]:.6g}, {hi[i]:.6g}] there")
    for c in exp_cols:
        if expected[c].dtype.kind in "iu" and df[c].dtype.kind == "f":
            if np.all(df[c] == np.round(df[c])):
                df[c] = df[c].astype(expected[c].dtype)
    try:
        readings = proc.from_frame(setup, df)
    except InvalidInput as exc:
        _fail(path, " ".join(exc.problems))
    except KeyError as exc:
        _fail(path, f"lacks column {exc.args[0]!r}")
    except (ValueError, TypeError, IndexError) as exc:
        _fail(path, str(exc))
    for k, v in readings.items():
        a = np.asarray(v)
        if reduced:  # a reduced file leaves the readings it lacks as NaN, on purpose
            continue
        if a.dtype.kind in "fc" and not np.all(np.isfinite(a)):
            _fail(path, f"reading {k!r} holds NaN or infinite values")
    return readings


# --------------------------------------------------------------------------- estimate
@dataclass
class MeasuredResult:
    """Measurands estimated from measured readings, with their uncertainty (display units).

    Attributes
    ----------
    procedure, estimator, uncertainty : str
        ``uncertainty`` is ``"mc"`` or ``"posterior"``.
    setup : the procedure's Setup
    measurands : tuple of Measurand
    estimate : array (n_measurands,)
        The estimator's value from the readings.
    value : array (n_measurands,)
        The reported value: the estimate (``mc``) or the posterior mean (``posterior``).
    std : array (n_measurands,)
        Standard uncertainty.
    low, high : array (n_measurands,)
        Coverage interval (``mc``: the estimate minus the Monte Carlo quantiles of the
        estimation error; ``posterior``: equal-tailed credible interval).
    coverage : float
    seed : int or list
    details : ProcedureResult or PosteriorResult
    notes : list of str
    """

    procedure: str
    estimator: str
    uncertainty: str
    setup: object
    measurands: tuple
    estimate: np.ndarray
    value: np.ndarray
    std: np.ndarray
    low: np.ndarray
    high: np.ndarray
    coverage: float
    seed: object
    details: object
    notes: list = field(default_factory=list)

    def summary(self):
        """DataFrame indexed by measurand: unit, estimate, value, std, low, high."""
        import pandas as pd

        return pd.DataFrame(
            {"unit": [m.unit for m in self.measurands], "estimate": self.estimate,
             "value": self.value, "std": self.std, "low": self.low, "high": self.high},
            index=pd.Index([m.name for m in self.measurands], name="measurand"))

    def to_dict(self) -> dict:
        """The ``--json`` document of ``mtplan estimate``."""
        doc = {
            "procedure": self.procedure,
            "estimator": self.estimator,
            "uncertainty": self.uncertainty,
            "setup": self.setup.as_dict(),
            "seed": self.seed,
            "measurands": [
                {"name": m.name, "unit": m.unit, "estimate": float(self.estimate[i]),
                 "value": float(self.value[i]), "std": float(self.std[i]),
                 "interval": [float(self.low[i]), float(self.high[i])],
                 "coverage": float(self.coverage)}
                for i, m in enumerate(self.measurands)
            ],
            "notes": list(self.notes),
        }
        if self.uncertainty == "posterior":
            doc["posterior"] = self.details.to_dict()
        else:
            doc["trials"] = int(self.details.mc.trials)
        return doc


def estimate_measured(
    procedure,
    setup,
    readings,
    *,
    estimator: str | None = None,
    uncertainty: str = "mc",
    trials: int = 10_000,
    coverage: float = 0.95,
    rng=None,
    noise=None,
    allow_unconverged: bool = False,
    posterior_options: dict | None = None,
) -> MeasuredResult:
    """The measurands of one measurement, with their uncertainty.

    Parameters
    ----------
    procedure : str or Procedure
    setup : Setup
    readings : dict of str to array
        A batch of one (:func:`read_readings`).
    estimator : str, optional
        Default: the procedure's default estimator.
    uncertainty : {"mc", "posterior"}
        ``"mc"``: Monte Carlo of the set-up's error sources around the estimate (the
        truth is ``procedure.truth_from_estimate(setup, estimate)`` when the procedure
        has that hook, else its default truth, noted in the result). ``"posterior"``:
        emcee posterior of the forward model (:func:`sample_posterior`).
    trials : int
        Monte Carlo trials (``"mc"``).
    coverage : float
    rng : None, int, SeedSequence or Generator
    noise, allow_unconverged, posterior_options
        Passed to :func:`sample_posterior` (``"posterior"``).

    Returns
    -------
    MeasuredResult
    """
    from mtplan.models import get
    from mtplan.uncertainty._random import as_seed_sequence

    proc = get(procedure)
    proc.check_setup(setup)
    p = Problems(f"estimate {proc.name}")
    p.choice("uncertainty", uncertainty, UNCERTAINTY_METHODS)
    p.number("trials", trials, integer=True, low=2)
    p.number("coverage", coverage, low=0, high=1, low_open=True, high_open=True)
    p.raise_if_any()
    est_name, _ = proc.estimator(estimator)
    measurands = tuple(proc.measurands(setup))
    est_internal = proc.estimate(setup, readings, est_name)
    est_internal = {m.name: float(np.asarray(est_internal[m.name]).reshape(-1)[0])
                    for m in measurands}
    estimate = np.array([est_internal[m.name] * m.scale for m in measurands])
    if not np.all(np.isfinite(estimate)):
        bad = [m.name for m, v in zip(measurands, estimate, strict=True) if not math.isfinite(v)]
        raise InvalidInput([f"The {est_name} estimator of {proc.name} gives no finite value of "
                            f"{', '.join(bad)} from these readings."])
    root = as_seed_sequence(rng)
    seed = root.entropy if isinstance(root.entropy, int) else list(root.entropy)
    notes = []
    if uncertainty == "mc":
        from mtplan.evaluation.simulation import simulate_uncertainty

        if proc.truth_from_estimate is not None:
            truth = proc.truth_from_estimate(setup, est_internal)
        else:
            truth = proc.Truth()
            notes.append(f"{proc.name} has no truth_from_estimate: the Monte Carlo ran at the "
                         "default truth, not at the estimate")
        r = simulate_uncertainty(proc, setup, truth, estimator=est_name, trials=trials,
                                 coverage=coverage, rng=root, progress=False)
        for i, m in enumerate(measurands):
            if not r.mc.std[i] > 0:
                notes.append(f"{m.name}: the {est_name} estimator gives the same value in every "
                             "trial around the estimate, so its uncertainty here is its "
                             "resolution, which this Monte Carlo cannot see; use another "
                             "estimator or --uncertainty posterior")
        err_low = r.mc.low - r.true  # quantiles of the estimation error
        err_high = r.mc.high - r.true
        return MeasuredResult(
            procedure=proc.name, estimator=est_name, uncertainty="mc", setup=setup,
            measurands=measurands, estimate=estimate, value=estimate.copy(),
            std=np.asarray(r.mc.std, dtype=float), low=estimate - err_high,
            high=estimate - err_low, coverage=float(coverage), seed=seed, details=r,
            notes=notes)
    from mtplan.evaluation.posterior import sample_posterior

    post = sample_posterior(proc, setup, readings, noise=noise, estimator=est_name,
                            coverage=coverage, rng=root, allow_unconverged=allow_unconverged,
                            **(posterior_options or {}))
    names = [m.name for m in measurands]
    notes.extend(post.notes)
    systematic = [k for k, src in proc.active_sources(setup).items() if k != proc.noise_source]
    if systematic:
        notes.append("the posterior's likelihood covers the readings' scatter only; the set-up's "
                     f"other error sources ({', '.join(systematic)}) are in --uncertainty mc")
    return MeasuredResult(
        procedure=proc.name, estimator=est_name, uncertainty="posterior", setup=setup,
        measurands=measurands, estimate=estimate,
        value=np.array([post.mean[n] for n in names]),
        std=np.array([post.std[n] for n in names]),
        low=np.array([post.low[n] for n in names]),
        high=np.array([post.high[n] for n in names]),
        coverage=float(coverage), seed=seed, details=post, notes=notes)
