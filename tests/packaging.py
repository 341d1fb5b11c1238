"""Packages built and installed as a user installs them: pip into a folder of its own."""

from __future__ import annotations

import importlib.metadata
import importlib.util
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest


def builds_here(setuptools: tuple[int, int] = (68, 0)) -> bool:
    """Whether this environment's setuptools meets a package's build requirement (at least
    `setuptools`, a version) and writes wheels (itself from 70.1 on, with the wheel package
    before)."""
    try:
        version = importlib.metadata.version("setuptools")
    except importlib.metadata.PackageNotFoundError:
        return False
    have = tuple(int(part) for part in re.findall(r"\d+", version)[:2])
    return have >= setuptools and (have >= (70, 1) or bool(importlib.util.find_spec("wheel")))


def pip_install(site: Path, *packages: Path, setuptools: tuple[int, int] = (68, 0)) -> None:
    """Build and install `packages` into `site`: pip, without their dependencies (mtplan is
    the one under test) and, where this environment's setuptools builds them (at least
    `setuptools`, their build requirement), offline, without a build environment of its own
    (else pip fetches setuptools for one)."""
    if importlib.util.find_spec("pip") is None:
        pytest.skip("this environment has no pip to install a package with")
    offline = ["--no-build-isolation", "--no-index"] if builds_here(setuptools) else []
    cmd = [sys.executable, "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
           "--no-deps", *offline, "--target", str(site), *map(str, packages)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr


#: the checkout whose mtplan is under test
ROOT = Path(__file__).resolve().parents[1]


def install_mtplan(site: Path, work: Path) -> None:
    """Build mtplan from this checkout's sources as a source distribution holds them (the
    package, its metadata and the docs it ships), and install it into `site`, in `work`."""
    tree = work / "mtplan-src"
    (tree / "docs").mkdir(parents=True)
    for name in ("pyproject.toml", "README.md", "docs/glossary.md"):
        shutil.copy2(ROOT / name, tree / name)
    shutil.copytree(ROOT / "src", tree / "src", symlinks=True,
                    ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    pip_install(site, tree, setuptools=(77, 0))  # pyproject.toml's build requirement
