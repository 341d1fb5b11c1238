"""Sweeps: Monte Carlo uncertainty over a grid of set-ups, as a tidy table.

One row per set-up, estimator and measurand, with the set-up's fields, its
duration and the uncertainty columns. Set-ups run in parallel through joblib
(``backend="dask"`` runs on a Dask cluster through joblib's dask backend).

Every set-up draws from a seed derived from the sweep seed and a hash of the
set-up's own field values (less a field that only chooses what is reported, at its
default: :func:`mtplan.models.fields.identity`), so a row does not depend on the grid it
sits in, on ``n_jobs`` or on the backend, and all estimators of one set-up share their
random numbers (a paired comparison).

Given an output file, the sweep appends each finished set-up in one write and
flush, beside a small ``<out>.sweep.json`` that records what the sweep is. Started
again with the same arguments it reads what is there, drops a set-up whose rows
were cut off by a kill, and computes only what is missing: no row is lost or
duplicated. A removed output starts a new sweep (its left-over side file is replaced,
noted in ``table.attrs["notes"]``). A Parquet output is written (atomically) when the sweep completes,
from a CSV journal ``<out>.partial.csv`` kept while it runs. Workers finish set-ups in any
order; the finished file holds them in grid order, so the same sweep gives the same bytes
whatever ``n_jobs`` and the backend.
"""

from __future__ import annotations

import csv
import hashlib
import io
import itertools
import json
import os
import sys
import zlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from mtplan._io import atomic_write, output_problem
from mtplan._parallel import effective_jobs, ordered_map, parallel_session
from mtplan._validate import InvalidInput, Problems
from mtplan.evaluation.simulation import check_memory, simulate_uncertainty
from mtplan.models import get
from mtplan.models.fields import identity
from mtplan.models.protocol import fields_info, make
from mtplan.uncertainty.montecarlo import ModelError
from mtplan.uncertainty.options import RunOptions

__all__ = ["sweep", "setup_seed", "RESULT_COLUMNS"]

RESULT_COLUMNS = ["estimator", "measurand", "unit", "true", "value", "bias", "u", "low", "high",
                  "trials", "converged", "duration_s", "error"]


def canonical(setup) -> str:
    """A set-up's identity (:func:`mtplan.models.fields.identity`: its field values, less
    those that only choose what is reported, at their default) as text (sorted JSON): the
    same text, the same set-up."""
    return json.dumps(identity(setup), sort_keys=True, default=str)


def setup_id(setup) -> str:
    """A short stable identifier of a set-up's field values."""
    return hashlib.sha1(canonical(setup).encode()).hexdigest()[:12]


def setup_seed(seed: int, setup) -> np.random.SeedSequence:
    """The seed of one set-up in a sweep: the sweep seed and a hash of its fields."""
    key = zlib.crc32(canonical(setup).encode())
    return np.random.SeedSequence(entropy=int(seed), spawn_key=(key,))


def _run_setup(proc, setup, truth, estimators, sources, options, seed, point):
    rows = []
    for est in estimators:
        rows += point_rows(proc, setup, truth, est, sources, options, seed, point)
    return rows


def point_rows(proc, setup, truth, estimator, sources, options, seed, point=0) -> list:
    """The rows of one set-up and one estimator of a sweep (one per measurand), with
    ``point`` its index in the grid: what :func:`sweep` computes for it, on its own (the
    set-up's seed, :func:`setup_seed`, does not depend on the grid or the other
    estimators), so that a study can compute each once and share it between its sweeps.
    An estimator that cannot evaluate the set-up gives rows with NaN and the reason in
    ``error``."""
    fields = {k: (",".join(f"{x:g}" for x in v) if isinstance(v, list) else v)
              for k, v in setup.as_dict().items()}
    true = proc.display_truth(setup, truth)
    duration = float(proc.duration(setup))
    rows = []
    try:
        r = simulate_uncertainty(proc, setup, truth, estimator=estimator, sources=sources,
                                 rng=setup_seed(seed, setup), n_jobs=1, progress=False,
                                 **options)
    except (ModelError, InvalidInput) as exc:
        # an estimator that cannot evaluate this set-up is a finding of the sweep,
        # recorded in its rows, not a reason to lose the other set-ups
        r, error = None, str(exc)
    else:
        error = ""
    for i, m in enumerate(proc.measurands(setup)):
        nan = float("nan")
        rows.append({
            "point": point,
            "setup_id": setup_id(setup),
            **fields,
            "estimator": estimator,
            "measurand": m.name,
            "unit": m.unit,
            "true": true[m.name],
            "value": float(r.mc.mean[i]) if r else nan,
            "bias": float(r.bias[i]) if r else nan,
            "u": float(r.mc.std[i]) if r else nan,
            "low": float(r.mc.low[i]) if r else nan,
            "high": float(r.mc.high[i]) if r else nan,
            "trials": int(r.mc.trials) if r else 0,
            "converged": bool(r.mc.converged) if r else False,
            "duration_s": duration,
            "error": error,
        })
    return rows


def sweep_table(frames) -> "pd.DataFrame":
    """A sweep's table from the frames of its set-ups (any order): put together in grid
    order (``point``), as :func:`sweep` returns it."""
    import pandas as pd

    table = pd.concat(frames, ignore_index=True) if len(frames) else pd.DataFrame()
    if len(table):
        table = table.sort_values("point", kind="stable").reset_index(drop=True)
    return table


def setup_grid(proc, base, vary):
    p = Problems(f"sweep {proc.name}")
    infos = {i.name: i for i in fields_info(proc.Setup)}
    for key, values in vary.items():
        if key not in infos:
            p.add_text(f"{proc.name} has no set-up field {key!r} to vary; its fields are: "
                       + ", ".join(infos))
        elif isinstance(values, str) or not isinstance(values, Sequence) or len(values) == 0:
            p.add(f"vary[{key!r}]", values, "a non-empty list of values")
    p.raise_if_any()
    keys = list(vary)
    setups, problems = [], []
    for combo in itertools.product(*(vary[k] for k in keys)):
        values = dict(zip(keys, combo, strict=True))
        try:
            setups.append(make(proc.Setup, values, base=base, owner=proc.name))
        except InvalidInput as exc:
            shown = ", ".join(f"{k}={v}" for k, v in values.items())
            problems.append(f"Set-up {shown}: " + " ".join(exc.problems))
    if problems:
        raise InvalidInput(problems)
    return setups


def sweep(
    procedure,
    base_setup=None,
    vary: Mapping[str, Sequence] | None = None,
    *,
    truth=None,
    estimators=None,
    sources=None,
    out=None,
    **options,
):
    """Monte Carlo uncertainty over a grid of set-ups.

    Parameters
    ----------
    procedure : str or Procedure
    base_setup : Setup, optional
        The set-up the grid varies (default: the procedure's defaults).
    vary : mapping of field name to list of values
        The grid is the Cartesian product, in the order given.
    truth : Truth, optional
    estimators : str or list of str, optional
        Estimators to evaluate on every set-up ("all" for every one; default: the
        procedure's default estimator).
    sources : list of str, optional
        Simulate with only these error sources.
    out : str or Path, optional
        CSV or Parquet file written as the sweep goes; a rerun resumes it.
    **options
        The run options (:class:`~mtplan.uncertainty.options.RunOptions`): ``options=``
        a record, and any of its fields as keywords, which replace the record's:

        - ``trials``, ``digits``, ``coverage``, ``interval``, ``block_size``,
          ``max_trials``: each set-up's Monte Carlo (default 10**4 trials);
        - ``rng``: the sweep seed, an int (default 0); each set-up's seed derives from it
          and the set-up's fields;
        - ``n_jobs``, ``backend``, ``scheduler``: parallel execution over set-ups
          (joblib; "dask" for a Dask cluster);
        - ``progress``: progress bar on stderr (after one second; default: when stderr
          is a terminal).

    Returns
    -------
    pandas.DataFrame
        One row per set-up, estimator and measurand: ``point`` (grid index),
        ``setup_id``, every set-up field, then :data:`RESULT_COLUMNS`. A set-up that an
        estimator cannot evaluate (non-finite estimates) has NaN values and the reason in
        ``error`` (empty otherwise).
    """
    import pandas as pd

    g = sweep_grid(procedure, base_setup, vary, truth=truth, estimators=estimators,
                   sources=sources, out=out, **options)
    proc, base_setup, truth, estimators = g.proc, g.base_setup, g.truth, g.estimators
    fmt, setups, options, seed = g.fmt, g.setups, g.options, g.seed
    n_jobs, backend, scheduler = g.run.n_jobs, g.run.backend, g.run.scheduler
    progress = g.run.progress
    signature = _signature(proc, base_setup, truth, vary, estimators, sources, options, seed)
    done, journal, notes = pd.DataFrame(), None, []
    with parallel_session(n_jobs, backend, scheduler) as session:  # a bad scheduler: no file
        if out is not None:
            out = Path(out)
            journal = out if fmt == "csv" else out.with_name(out.name + ".partial.csv")
            done = _resume(out, journal, fmt, signature, notes)
        finished = set(done["setup_id"]) if len(done) else set()
        todo = [(i, s) for i, s in enumerate(setups) if setup_id(s) not in finished]
        if effective_jobs(n_jobs) != 1 or backend == "dask":
            # longest first (the test's duration as the proxy of its cost), so that no worker
            # is left with a long set-up while the others idle; rows are sorted back by point
            todo.sort(key=lambda task: -float(proc.duration(task[1])))
        bar = _bar(progress, len(setups), len(setups) - len(todo), proc.name)
        tasks = ((proc, s, truth, tuple(estimators), sources, options, seed, i) for i, s in todo)
        n_rows = len(estimators) * len(proc.measurands(base_setup))
        new_frames = _run(tasks, journal, n_rows, bar, session["n_jobs"], backend)
    if journal is not None and new_frames and journal.exists():
        _order_journal(journal)  # set-up order, so any jobs and backend give the same bytes
    if journal is not None:
        # one source of truth for fresh and resumed runs alike: the journal on disk
        table = sweep_table([_read_journal(journal, rewrite=False) if journal.exists() else done])
    else:
        table = sweep_table(new_frames)
    if out is not None and fmt == "parquet":
        with atomic_write(out, "wb") as fh:
            table.to_parquet(fh, index=False)
        Path(journal).unlink(missing_ok=True)
    table.attrs["notes"] = notes
    return table


def sweep_grid(procedure, base_setup=None, vary=None, *, truth=None, estimators=None,
               sources=None, out=None, **options):
    """A sweep's arguments checked (every problem at once) and its grid: a namespace of
    ``proc``, ``base_setup``, ``truth``, ``estimators`` (names), ``fmt`` (of ``out``),
    ``setups`` (grid order), ``run`` (the :class:`~mtplan.uncertainty.options.RunOptions`),
    ``seed`` (the sweep seed) and ``options`` (of each set-up's Monte Carlo, a dict).
    Arguments as :func:`sweep`; a grid whose largest set-up would not fit in memory is
    refused."""
    run = RunOptions.of(options.pop("options", None), **options)
    proc = get(procedure)
    base_setup = proc.Setup() if base_setup is None else base_setup
    proc.check_setup(base_setup)
    truth = proc.Truth() if truth is None else truth
    estimators, fmt = _check_arguments(proc, base_setup, estimators, sources, run, out)
    run = run.fixed(10**4)
    setups = setup_grid(proc, base_setup, dict(vary or {}))
    options = {"trials": run.trials, "digits": run.digits, "coverage": run.coverage,
               "interval": run.interval}
    # only when given, so that a sweep without them keeps the record it always had
    options.update({k: getattr(run, k) for k in ("block_size", "max_trials")
                    if getattr(run, k) is not None})
    _check_memory(proc, setups, truth, estimators, sources, options, run.n_jobs)
    return SimpleNamespace(proc=proc, base_setup=base_setup, truth=truth,
                           estimators=estimators, fmt=fmt, setups=setups, options=options,
                           run=run, seed=_seed(run.rng))


def _seed(rng) -> int:
    """The sweep seed (checked by :func:`_check_arguments`): an int, 0 by default."""
    return 0 if rng is None else int(rng)


def _check_arguments(proc, base_setup, estimators, sources, run, out) -> tuple[list, str | None]:
    """Every problem of the sweep's arguments at once; (estimator names, output format)."""
    p = Problems(f"sweep {proc.name}")
    run.check(p)
    p.number("seed", 0 if run.rng is None else run.rng, integer=True, low=0)
    if estimators is None:
        estimators = [proc.default_estimator]
    elif estimators == "all":
        estimators = list(proc.estimators)
    elif isinstance(estimators, str):
        estimators = [estimators]
    for e in estimators:
        if e not in proc.estimators:
            p.add("estimators", e, "among " + ", ".join(map(repr, proc.estimators)))
    fmt = None
    if out is not None:
        fmt = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet"}.get(Path(out).suffix.lower())
        problem = output_problem(out)
        if fmt is None:
            p.add("out", str(out), "a file name ending in .csv or .parquet")
        elif problem:
            p.add("out", str(out), f"a file that can be written ({problem})")
    p.raise_if_any()
    if sources is not None:
        proc.active_sources(base_setup, sources)  # validates the names
    return list(estimators), fmt


def _signature(proc, base_setup, truth, vary, estimators, sources, options, seed) -> dict:
    """What a sweep is, as plain JSON: a rerun with the same signature resumes it."""
    signature = {
        "procedure": proc.name,
        "base_setup": base_setup.as_dict(),
        "truth": truth.as_dict(),
        "vary": {k: [v if not isinstance(v, tuple) else list(v) for v in vals]
                 for k, vals in (vary or {}).items()},
        "estimators": list(estimators),
        "sources": None if sources is None else sorted(sources),
        "options": options,
        "seed": int(seed),
    }
    return json.loads(json.dumps(signature, default=str))


def _run(tasks, journal, n_rows, bar, n_jobs, backend) -> list:
    """Evaluate the set-ups (inside a parallel session); each finished one is appended to
    the journal at once."""
    import pandas as pd

    frames = []
    for rows in ordered_map(_run_setup, tasks, n_jobs=n_jobs, backend=backend):
        frame = pd.DataFrame(rows)
        if journal is not None:
            _append(journal, frame, n_rows)
        frames.append(frame)
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    return frames


def _check_memory(proc, setups, truth, estimators, sources, options, n_jobs) -> None:
    """Refuse, before any set-up runs, a grid whose largest set-up would exceed memory."""
    largest = max(setups, key=lambda s: sum(src.size for src in proc.sources(s).values()))
    block = options.get("block_size") or proc.capabilities.block_size
    if options["digits"] is None and not options.get("block_size"):
        block = min(block, max(options["trials"] or 0, 2))
    check_memory(proc, largest, truth, estimators[0],
                 tuple(proc.active_sources(largest, sources)), block_size=block, n_jobs=n_jobs,
                 trials=options["trials"])


def _bar(progress, total, initial, label):
    if progress is False:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, desc=f"sweep {label}", unit="set-up", delay=1.0,
                file=sys.stderr, leave=False,
                disable=progress is None and not sys.stderr.isatty())


def _sidecar(out: Path) -> Path:
    return out.with_name(out.name + ".sweep.json")


def _resume(out: Path, journal: Path, fmt: str, signature: dict, notes: list):
    """The rows of an earlier run of this sweep; a new sweep writes its side file.

    A side file whose output is gone (removed to start again) is replaced, with a note; an
    output without a side file, or with one of another sweep, is refused.
    """
    import pandas as pd

    side = _sidecar(out)
    outputs = out.exists() or journal.exists()
    if side.exists() and outputs:
        try:
            recorded = json.loads(side.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            recorded = None
        if recorded != signature:
            what = "is unreadable" if recorded is None else "differs from these arguments"
            raise InvalidInput(
                [f"The output file {str(out)!r} belongs to a different sweep (its {side.name} "
                 f"{what}); remove it or choose another 'out' file."]
            )
    elif outputs:
        raise InvalidInput(
            [f"The output file {str(out)!r} exists but was not written by this sweep (no "
             f"{side.name} beside it); remove it or choose another 'out' file."]
        )
    else:
        if side.exists():
            notes.append(f"{side.name} was left from a sweep whose output {out.name} is gone: "
                         "replaced, this is a new sweep")
        with atomic_write(side, "w", encoding="utf-8") as fh:
            json.dump(signature, fh, indent=1)
        return pd.DataFrame()
    if fmt == "parquet" and out.exists() and not journal.exists():
        return pd.read_parquet(out)
    if not journal.exists():
        return pd.DataFrame()
    return _read_journal(journal)


def _read_journal(journal: Path, rewrite: bool = True):
    import pandas as pd


    full = journal.read_text(encoding="utf-8")
    text = full[: full.rfind("\n") + 1]  # drop a line cut off by a kill
    cut_line = len(text) < len(full)
    if not text.strip():
        if rewrite:
            journal.unlink()
        return pd.DataFrame()
    df = pd.read_csv(io.StringIO(text))
    n_read = len(df)
    if "rows_in_setup" in df.columns:
        counts = df.groupby("setup_id")["setup_id"].transform("size")
        df = df[counts == df["rows_in_setup"]]
        df = df.drop_duplicates(subset=["setup_id", "estimator", "measurand"], keep="first")
    if rewrite and (cut_line or len(df) < n_read):
        # keep only whole set-ups, atomically, so appends continue after them
        with atomic_write(journal, "w", encoding="utf-8", newline="") as fh:
            df.to_csv(fh, index=False)
    return df.drop(columns=["rows_in_setup"], errors="ignore")


def _csv_records(text: str) -> list[str]:
    """The records of CSV text, each with its line end(s): a record ends at a line end
    outside quotes (a quoted value may hold line ends; a quote inside one is doubled)."""
    records, current, quotes = [], [], 0
    for line in text.splitlines(keepends=True):
        current.append(line)
        quotes += line.count('"')
        if quotes % 2 == 0:
            records.append("".join(current))
            current, quotes = [], 0
    if current:
        records.append("".join(current))
    return records


def _order_journal(journal: Path) -> None:
    """Rewrite the journal (atomically) with its set-ups in grid order, each record's bytes
    as written, when the workers finished them in another order."""
    header, *records = _csv_records(journal.read_text(encoding="utf-8"))
    column = next(csv.reader([header])).index("point")
    points = [int(next(csv.reader(io.StringIO(r)))[column]) for r in records]
    order = sorted(range(len(records)), key=points.__getitem__)
    if order == sorted(order):
        return
    with atomic_write(journal, "w", encoding="utf-8", newline="") as fh:
        fh.write(header + "".join(records[i] for i in order))


def _append(journal: Path, frame, n_rows: int) -> None:
    frame = frame.assign(rows_in_setup=n_rows)
    header = not journal.exists() or journal.stat().st_size == 0
    text = frame.to_csv(index=False, header=header)
    with open(journal, "a", encoding="utf-8", newline="") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())

