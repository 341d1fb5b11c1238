"""A study's result kept on disk under a content address.

:func:`run_study_cached` stores what :func:`~mtplan.plans.study.runner.run_study` computed
under :func:`study_cache_key`, the SHA-256 of everything the numbers depend on, and reads it
back on a later run with the same key; :data:`CACHE_KEEP` results are kept.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from mtplan.plans.study.provenance import file_sha256, provenance
from mtplan.plans.study.runner import StudyResult, run_study
from mtplan.plans.study.schema import Study

__all__ = ["study_cache_key", "run_study_cached", "CACHE_KEEP"]

#: the packages whose versions a study's numbers depend on (besides mtplan's own code)
_NUMERIC_PACKAGES = ("numpy", "scipy", "pandas", "emcee", "joblib")


def study_cache_key(study: Study, readings: bool = True) -> str:
    """SHA-256 of everything a study's result depends on: the study file, its readings
    files, whether the readings are evaluated, every file of the installed mtplan package
    (its code, templates and examples), the Python version and the numeric packages'
    versions. Any change to one of them gives another key; ``n_jobs`` does not enter (the
    result does not depend on it)."""
    import importlib.metadata as md
    import platform

    digest = hashlib.sha256()
    digest.update(f"study {study.digest}\nreadings {bool(readings)}\n".encode())
    for ps in study.procedures:
        if ps.readings is not None and readings:
            digest.update(f"{ps.name} {file_sha256(ps.readings['file'])}\n".encode())
            if ps.as_left is not None:
                digest.update(f"{ps.name} as left {file_sha256(ps.as_left['file'])}\n".encode())
    package = Path(__file__).resolve().parents[2]
    for path in sorted(package.rglob("*")):
        if path.is_file() and "__pycache__" not in path.parts:
            name = path.relative_to(package).as_posix()
            digest.update(f"{name} {file_sha256(path)}\n".encode())
    digest.update(f"python {platform.python_version()} {platform.machine()}\n".encode())
    for pkg in _NUMERIC_PACKAGES:
        try:
            digest.update(f"{pkg} {md.version(pkg)}\n".encode())
        except md.PackageNotFoundError:
            digest.update(f"{pkg} -\n".encode())
    return digest.hexdigest()


def run_study_cached(study: Study, cache_dir, *, progress=None, n_jobs: int = 1,
                     command: str | None = None, readings: bool = True,
                     then=None) -> StudyResult:
    """:func:`run_study`, or its result stored in ``cache_dir`` by an earlier run with the
    same :func:`study_cache_key` (None: always computed). The provenance is this run's (its
    date and command) and names the cache file the numbers were read from. ``then`` as
    :func:`run_study` where the study is computed (a result read from the cache has none)."""
    import os
    import pickle

    if cache_dir is None:
        return run_study(study, progress=progress, n_jobs=n_jobs, command=command,
                         readings=readings, then=then)
    key = study_cache_key(study, readings)
    path = Path(cache_dir) / f"study-{key}.pickle"
    try:
        with open(path, "rb") as fh:
            outcomes = pickle.load(fh)
    except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError):
        outcomes = None  # none stored, or unreadable: computed again and stored anew
    if outcomes is not None:
        for outcome, ps in zip(outcomes, study.procedures, strict=True):
            outcome.spec = ps  # the same content (the key says so); this run's file paths
        made = provenance(study, command)
        made["cached"] = str(path)
        return StudyResult(study=study, outcomes=outcomes, provenance=made)
    result = run_study(study, progress=progress, n_jobs=n_jobs, command=command,
                       readings=readings, then=then)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        with open(tmp, "wb") as fh:
            pickle.dump(result.outcomes, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
        _prune(path.parent)
    except OSError:  # a cache that cannot be written only costs the next run its time
        pass
    return result


#: how many study results the cache keeps (the newest; each code change makes a new key)
CACHE_KEEP = 4


def _prune(folder: Path) -> None:
    """Remove all but the CACHE_KEEP newest study results of the cache folder."""
    stored = sorted(folder.glob("study-*.pickle"), key=lambda p: p.stat().st_mtime,
                    reverse=True)
    for old in stored[CACHE_KEEP:]:
        old.unlink(missing_ok=True)
