"""Sweeps: tidy table, invariance to n_jobs and backend, and resuming after a kill."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mtplan._validate import InvalidInput
from mtplan.plans.sweep import RESULT_COLUMNS, sweep
from mtplan.testing import template as toy_line

P = toy_line.PROCEDURE
VARY = {"n_points": [3, 5, 9], "probe_noise_um": [0.5, 2.0]}
ROOT = Path(__file__).resolve().parents[2]


def test_tidy_table_one_row_per_setup_and_measurand():
    df = sweep(P, vary=VARY, trials=2000, rng=3)
    assert len(df) == 3 * 2 * 2
    assert set(RESULT_COLUMNS) <= set(df.columns)
    assert {"n_points", "probe_noise_um", "length_mm", "setup_id", "point"} <= set(df.columns)
    assert list(df["point"]) == sorted(df["point"])
    # uncertainty scales with the noise and falls with the number of points
    offset = df[df.measurand == "offset"].set_index(["n_points", "probe_noise_um"])["u"]
    assert offset[(9, 2.0)] > offset[(9, 0.5)] * 3
    assert offset[(3, 0.5)] > offset[(9, 0.5)]
    # the theory for a mean of n points: u = sigma / sqrt(n), within Monte Carlo error
    n, sigma = 9, 2.0
    rel = 4 / np.sqrt(2 * (2000 - 1))
    assert abs(offset[(n, sigma)] / (sigma / np.sqrt(n)) - 1) < rel


def test_rows_do_not_depend_on_the_grid_or_on_n_jobs():
    full = sweep(P, vary=VARY, trials=1000, rng=5)
    part = sweep(P, vary={"n_points": [5], "probe_noise_um": [2.0]}, trials=1000, rng=5)
    row = full[(full.n_points == 5) & (full.probe_noise_um == 2.0)].reset_index(drop=True)
    np.testing.assert_array_equal(row["u"], part["u"])
    par = sweep(P, vary=VARY, trials=1000, rng=5, n_jobs=2, backend="loky")
    pd.testing.assert_frame_equal(full, par)


def test_dask_backend_gives_the_same_table():
    import distributed  # noqa: F401 - the test extras hold it: missing is a failure, not a skip
    a = sweep(P, vary={"n_points": [3, 5]}, trials=500, rng=2)
    b = sweep(P, vary={"n_points": [3, 5]}, trials=500, rng=2, n_jobs=2, backend="dask")
    pd.testing.assert_frame_equal(a, b)


def test_sweep_files_are_byte_identical_with_one_and_two_jobs(tmp_path, capsys):
    """The command's file holds the set-ups in grid order whatever the jobs: the workers take
    the longest set-up first (here 12 positions before 3), which the file must not show."""
    from mtplan import cli

    files = {}
    for jobs in ("1", "2"):
        files[jobs] = tmp_path / f"jobs{jobs}.csv"
        code = cli.main(["sweep", "rotary_axis", "--vary", "positions=3,12,6", "--vary",
                         "incline_deg=10,30", "--trials", "200", "--seed", "3", "--jobs", jobs,
                         "--out", str(files[jobs])])
        capsys.readouterr()
        assert code == 0
    one, two = (files[j].read_bytes() for j in ("1", "2"))
    assert one == two
    assert list(pd.read_csv(files["1"])["point"].drop_duplicates()) == list(range(6))


def test_a_journal_finished_out_of_order_is_put_in_grid_order(tmp_path):
    """Each record's bytes are kept, a quoted value with a line end and quotes included."""
    from mtplan.plans.sweep import _order_journal

    journal = tmp_path / "j.csv"
    rows = ['2,b,""\n', '0,a,"two\nlines, ""quoted"""\n', '1,c,\n']
    journal.write_text("point,x,error\n" + "".join(rows), encoding="utf-8")
    _order_journal(journal)
    assert journal.read_text(encoding="utf-8") == "point,x,error\n" + rows[1] + rows[2] + rows[0]
    before = journal.stat().st_mtime_ns
    _order_journal(journal)  # already in order: left alone
    assert journal.stat().st_mtime_ns == before


def test_estimators_share_random_numbers_and_all_expands():
    df = sweep(P, vary={"n_points": [4]}, trials=500, rng=1, estimators="all")
    assert set(df["estimator"]) == set(P.estimators)


def test_bad_grid_lists_every_problem():
    with pytest.raises(InvalidInput) as exc:
        sweep(P, vary={"n_points": [1, 5], "nope": [1]}, trials=100)
    assert "nope" in str(exc.value)
    with pytest.raises(InvalidInput) as exc:
        sweep(P, vary={"n_points": [1, 0, 5]}, trials=100)
    assert "n_points=1" in str(exc.value) and "n_points=0" in str(exc.value)
    with pytest.raises(InvalidInput, match="out"):
        sweep(P, vary={"n_points": [3]}, trials=100, out="table.txt")


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_rerun_with_a_complete_file_recomputes_nothing(tmp_path, suffix):
    out = tmp_path / f"s{suffix}"
    a = sweep(P, vary=VARY, trials=500, rng=4, out=out)
    mtime = out.stat().st_mtime_ns
    b = sweep(P, vary=VARY, trials=500, rng=4, out=out)
    pd.testing.assert_frame_equal(a, b)
    if suffix == ".csv":
        assert out.stat().st_mtime_ns == mtime
    with pytest.raises(InvalidInput, match="different sweep"):
        sweep(P, vary=VARY, trials=500, rng=5, out=out)


def test_a_line_cut_off_mid_write_is_dropped_and_recomputed(tmp_path):
    out = tmp_path / "s.csv"
    ref = sweep(P, vary=VARY, trials=500, rng=6, out=tmp_path / "ref.csv")
    sweep(P, vary={"n_points": [3, 5, 9], "probe_noise_um": [0.5, 2.0]}, trials=500, rng=6, out=out)
    lines = out.read_text().splitlines(keepends=True)
    # keep the header, the first set-up whole, half of the second and a cut line
    out.write_text("".join(lines[:4]) + lines[4][:10])
    again = sweep(P, vary=VARY, trials=500, rng=6, out=out)
    pd.testing.assert_frame_equal(again, ref)
    text = out.read_text()
    assert text == (tmp_path / "ref.csv").read_text() or len(pd.read_csv(out)) == len(ref)


SCRIPT = textwrap.dedent(
    """
    import sys
    sys.path.insert(0, {root!r})
    from mtplan.testing import template as toy_line
    from mtplan.plans.sweep import sweep
    sweep(toy_line.PROCEDURE, vary={vary!r}, trials={trials}, rng=9, out=sys.argv[1])
    """
)


def test_killed_sweep_resumes_to_the_same_table(tmp_path):
    vary = {"n_points": [3, 4, 5, 6, 7, 8], "probe_noise_um": [1.0]}
    trials = 400_000
    out = tmp_path / "killed.csv"
    script = tmp_path / "run.py"
    script.write_text(SCRIPT.format(root=str(ROOT), vary=vary, trials=trials))
    proc = subprocess.Popen([sys.executable, str(script), str(out)], cwd=tmp_path)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if out.exists() and out.read_text().count("\n") >= 1 + 2 * 2:  # two set-ups written
                break
            if proc.poll() is not None:
                break
            time.sleep(0.02)
        assert proc.poll() is None, "the sweep finished before it could be killed"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    finally:
        if proc.poll() is None:
            proc.kill()
    partial = pd.read_csv(out)
    assert 0 < partial["setup_id"].nunique() < 6
    resumed = sweep(P, vary=vary, trials=trials, rng=9, out=out)
    clean = sweep(P, vary=vary, trials=trials, rng=9, out=tmp_path / "clean.csv")
    pd.testing.assert_frame_equal(resumed, clean)
    assert resumed.groupby("setup_id").size().eq(2).all()


def test_a_setup_an_estimator_cannot_evaluate_is_recorded_not_fatal(tmp_path):
    import dataclasses

    def fragile(setup, readings):  # gives up (NaN) on the shortest edge, like a fit that
        est = toy_line.estimate_ls(setup, readings)  # does not converge
        if setup.n_points == 3:
            est = {k: v * np.nan for k, v in est.items()}
        return est

    proc = dataclasses.replace(P, estimators={"least_squares": toy_line.estimate_ls,
                                              "fragile": fragile})
    df = sweep(proc, vary={"n_points": [3, 5]}, trials=200, rng=1, estimators="all",
               out=tmp_path / "s.csv")
    bad = df[(df.estimator == "fragile") & (df.n_points == 3)]
    assert len(bad) == 2 and bad["u"].isna().all()
    assert bad["error"].str.contains("non-finite").all()
    good = df[~((df.estimator == "fragile") & (df.n_points == 3))]
    assert good["u"].notna().all() and good["error"].isna().all()



def test_a_field_that_only_chooses_what_is_reported_leaves_the_seed_as_it_was():
    """A `reports_only` set-up field (geometry21's positions along the travel, which add
    measurands from the same fit) at its default is no part of the set-up's identity: the
    set-up keeps the id and the sweep seed it had before the field existed, so the demo's
    geometry21 sweeps draw what they drew; set, it makes another set-up."""
    import dataclasses
    import hashlib
    import json
    import zlib

    from mtplan.models import get, registry
    from mtplan.models.fields import identity
    from mtplan.plans.sweep import setup_id, setup_seed

    proc = get("geometry21")
    setup = proc.Setup(circle_radius_mm=30.0)
    # the text of the set-up as it was before the fields existed (the demo's first sweep
    # point had id d2a6c345eb5f then; a later error source, medium_wave_um, moved it on purpose)
    before = {k: v for k, v in setup.as_dict().items() if not k.startswith("along_")}
    text = json.dumps(before, sort_keys=True, default=str)
    assert setup_id(setup) == hashlib.sha1(text.encode()).hexdigest()[:12]
    assert setup_seed(2024, setup).spawn_key == (zlib.crc32(text.encode()),)
    assert setup_id(dataclasses.replace(setup, along_x_mm=(0.0,))) != setup_id(setup)
    declared = set()
    for name, p in registry().items():  # every procedure's, at its default: left out
        s = p.Setup()
        out = {f.name for f in dataclasses.fields(s) if f.metadata.get("reports_only")}
        assert not out & set(identity(s)), name
        declared |= out
    assert {"along_x_mm", "along_y_mm", "along_z_mm"} <= declared
