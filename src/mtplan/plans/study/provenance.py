"""Where a study's numbers come from: the provenance a report prints.

A study's result names the command and the date of its run, the git commit of the mtplan
source that computed it, the study file and every readings file with their SHA-256, the
seed, and the versions of Python and the packages the numbers depend on.
"""

from __future__ import annotations

import datetime
import hashlib
from pathlib import Path

from mtplan.plans.study.schema import Study

__all__ = ["provenance", "git_commit", "file_sha256"]


def git_commit() -> str | None:
    """The git commit of the mtplan source when it runs from a checkout, else None."""
    import subprocess

    package = Path(__file__).resolve().parents[2]
    try:
        top = subprocess.run(["git", "-C", str(package), "rev-parse", "--show-toplevel"],
                             capture_output=True, text=True, timeout=10, check=True)
        if Path(top.stdout.strip()).resolve() / "src" / "mtplan" != package:
            return None
        head = subprocess.run(["git", "-C", str(package), "rev-parse", "HEAD"],
                              capture_output=True, text=True, timeout=10, check=True)
        dirty = subprocess.run(["git", "-C", str(package), "status", "--porcelain",
                                "--untracked-files=no", "--", str(package)],
                               capture_output=True, text=True, timeout=10, check=True)
    except (OSError, subprocess.SubprocessError):
        return None
    return head.stdout.strip() + (" with uncommitted changes" if dirty.stdout.strip() else "")


def file_sha256(path) -> str:
    """The SHA-256 of a file's bytes (64 hex)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def provenance(study: Study, command: str | None) -> dict:
    """What a study's numbers came from: the date, the command, the git commit of mtplan,
    the study file and the readings files with their SHA-256, the seed, Python and the
    packages' versions."""
    import importlib.metadata as md
    import platform

    versions = {}
    for pkg in ("mtplan", "numpy", "scipy", "pandas", "matplotlib", "joblib", "emcee", "jinja2",
                "reportlab"):
        try:
            versions[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            versions[pkg] = "not installed"
    readings = [(ps.label, str(ps.readings["file"]), file_sha256(ps.readings["file"]))
                for ps in study.procedures if ps.readings is not None]
    readings += [(f"{ps.label} (as left)", str(ps.as_left["file"]),
                  file_sha256(ps.as_left["file"])) for ps in study.procedures if ps.as_left]
    return {
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "command": command or "(called from Python)",
        "git_commit": git_commit(),
        "study_file": str(study.path) if study.path else "(in memory)",
        "study_sha256": study.digest,
        "readings": readings,
        "seed": study.seed,
        "python": platform.python_version(),
        "versions": versions,
    }
