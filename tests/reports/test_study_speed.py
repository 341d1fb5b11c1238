"""The study on several cores and from the cache: the same numbers as one serial run, and a
cache that any change of the study, its readings or the code misses."""

from __future__ import annotations

import pickle

import numpy as np
import pandas as pd
import pytest

from mtplan.plans.study import load_study, run_study, run_study_cached, study_cache_key


def _same(a, b, where="result") -> None:
    """Recursive equality of two computed results (arrays and frames exactly)."""
    if isinstance(a, pd.DataFrame | pd.Series):
        assert a.equals(b), where
    elif isinstance(a, np.ndarray):
        assert a.shape == b.shape and np.array_equal(a, b, equal_nan=True), where
    elif isinstance(a, dict):
        assert set(a) == set(b), where
        for key in a:
            _same(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{i}]")
    elif hasattr(a, "__dict__") and not isinstance(a, type):
        _same(_state(a), _state(b), where)
    elif isinstance(a, float) and np.isnan(a):
        assert isinstance(b, float) and np.isnan(b), where
    else:
        assert a == b, where


def _state(obj) -> dict:
    """An object's state as it crosses processes (its own ``__getstate__`` where it has
    one: a first-order result takes its value, not the closure that computes it), without
    ``cost``, the time a propagation took, which no two runs share."""
    own = type(obj).__getstate__ is not object.__getstate__
    state = dict(obj.__getstate__() if own else vars(obj))
    state.pop("cost", None)
    return state


@pytest.fixture(scope="module")
def early_result(small_study_file):
    """The small study on two workers, each test's part of the plan drawn as soon as the
    test is complete (``then``: its body and its appendix, each a stage), as ``mtplan
    report`` and ``mtplan demo`` do with workers."""
    from mtplan.reports.certificate import PLAN_PARTS

    return run_study(load_study(small_study_file), progress=False, n_jobs=2, then=PLAN_PARTS)


def test_two_workers_give_the_serial_result(small_study_file, early_result):
    """Stages on two processes draw the same streams as one serial run: identical outcomes
    (also where each test's figures are drawn beside the stages). The serial run is made
    here: the shared ``small_result`` is decided in place by the plan when another test of
    this worker writes its report first."""
    serial = run_study(load_study(small_study_file), progress=False)
    assert early_result.then is not None and len(early_result.then) == len(serial.outcomes)
    assert all(len(parts) == 2 for parts in early_result.then)  # (body, appendix) per test
    _same(early_result.outcomes, serial.outcomes, "outcomes")


def test_plan_and_report_rendered_at_once_are_the_serial_ones(early_result, tmp_path):
    """The plan and the report built in two processes, with each test's figures drawn there
    (from a result read from the cache) or drawn already as the study ran: the same
    plan.json, HTML and CSV files as one after the other (the PDFs differ only in their
    creation time)."""
    from mtplan.reports import write_report

    def copy(then):
        result = pickle.loads(pickle.dumps(early_result))
        result.then = result.then if then else None
        return result

    serial, both, early = tmp_path / "serial", tmp_path / "both", tmp_path / "early"
    one = write_report(copy(False), serial)
    two = write_report(copy(False), both, n_jobs=2)
    three = write_report(copy(True), early, n_jobs=2)
    assert set(one) == set(two) == set(three)
    for name in ["plan.json", "plan.html", "report.html",
                 *(p.relative_to(serial) for p in (serial / "results").glob("*.csv"))]:
        assert (serial / name).read_bytes() == (both / name).read_bytes(), name
        assert (serial / name).read_bytes() == (early / name).read_bytes(), name
    for name in ("plan.pdf", "report.pdf"):
        assert (both / name).read_bytes().startswith(b"%PDF")
        assert (early / name).read_bytes().startswith(b"%PDF")


def test_the_cache_returns_the_stored_result_and_any_change_misses_it(small_study_file,
                                                                       tmp_path):
    study = load_study(small_study_file)
    first = run_study_cached(study, tmp_path, progress=False, command="first")
    assert "cached" not in first.provenance
    again = run_study_cached(load_study(small_study_file), tmp_path, progress=False,
                             command="again")
    assert again.provenance["cached"].startswith(str(tmp_path))
    assert again.provenance["command"] == "again"
    _same(again.outcomes, first.outcomes, "outcomes")
    key = study_cache_key(study)
    assert key != study_cache_key(study, readings=False)
    # another seed in the study file: another key
    changed = tmp_path / "changed.toml"
    changed.write_text(small_study_file.read_text().replace("seed = 3", "seed = 4"))
    assert study_cache_key(load_study(changed)) != key
    # the same study file, its readings file changed: another key
    spec = study.procedures[0].readings
    readings = tmp_path / "readings.csv"
    readings.write_bytes(spec["file"].read_bytes())
    moved = tmp_path / "moved.toml"
    moved.write_text(small_study_file.read_text().replace(spec["file"].as_posix(),
                                                          readings.as_posix()))
    before = study_cache_key(load_study(moved))
    readings.write_text(readings.read_text() + "\n")
    assert study_cache_key(load_study(moved)) != before


def test_a_changed_source_file_misses_the_cache(small_study_file, monkeypatch, tmp_path):
    """The key hashes every file of the package: an edited module gives another key."""
    from mtplan.plans.study import cache as module

    study = load_study(small_study_file)
    key = study_cache_key(study)
    real = module.file_sha256
    target = module.__file__

    def edited(path):
        return "edited" if str(path) == target else real(path)

    monkeypatch.setattr(module, "file_sha256", edited)
    assert study_cache_key(study) != key


def test_the_cache_keeps_only_the_newest_results(tmp_path):
    import os

    from mtplan.plans.study import cache as module

    for i in range(module.CACHE_KEEP + 2):
        path = tmp_path / f"study-{i:064x}.pickle"
        path.write_bytes(b"x")
        os.utime(path, (1000 + i, 1000 + i))
    module._prune(tmp_path)
    kept = sorted(p.name for p in tmp_path.glob("study-*.pickle"))
    assert kept == [f"study-{i:064x}.pickle" for i in range(2, module.CACHE_KEEP + 2)]
