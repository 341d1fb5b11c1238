"""The pinned installs (``requirements/<python>/``, written by ``tools/lock.py``) agree with
pyproject.toml: every dependency and test extra pinned once, at a version its range admits,
each by a wheel address and its sha256; and ``tools/lock.py --fits`` names the directory
only for the Python it was written for."""

from __future__ import annotations

import importlib.util
import re
import tomllib
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parent.parent
_LINE = re.compile(r"^(?P<name>[A-Za-z0-9._-]+) @ (?P<url>https://\S+\.whl) "
                   r"--hash=sha256:(?P<sha>[0-9a-f]{64})$")


def _lock_tool():
    spec = importlib.util.spec_from_file_location("lock_tool", ROOT / "tools" / "lock.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _pins(path: Path) -> dict:
    pins = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        if not line or line.startswith("#"):
            continue
        m = _LINE.match(line)
        assert m, f"{path.name}: {line[:80]}"
        wheel = m["url"].rsplit("/", 1)[-1]
        version = Version(wheel.split("-")[1])
        name = canonicalize_name(m["name"])
        assert name not in pins, f"{name} pinned twice in {path.name}"
        assert canonicalize_name(wheel.split("-")[0]) == name, wheel
        pins[name] = version
    return pins


FOLDERS = sorted(p for p in (ROOT / "requirements").glob("*") if p.is_dir())


def test_there_is_a_pinned_install():
    assert FOLDERS, "no requirements/<python>/ folder: make falls back to resolving"


@pytest.mark.parametrize("folder", FOLDERS, ids=lambda p: p.name)
def test_the_pins_admit_what_pyproject_asks(folder):
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    core, test, uv = (_pins(folder / f"{n}.txt") for n in ("core", "test", "uv"))
    assert not set(core) & set(test), "a package in both core.txt and test.txt"
    assert set(uv) == {"uv"}
    assert {"pip", "setuptools"} <= set(core)  # the venv's pip; mtplan's build backend
    for text, where in [(r, core) for r in project["dependencies"]] + \
            [(r, {**core, **test}) for r in project["optional-dependencies"]["test"]]:
        req = Requirement(text)
        name = canonicalize_name(req.name)
        assert name in where, f"{req.name} is not pinned"
        assert req.specifier.contains(where[name], prereleases=True), (text, where[name])


def test_fits_names_the_folder_only_for_its_python(monkeypatch, tmp_path):
    tool = _lock_tool()
    here = tool.interpreter_tag()
    folder = tmp_path / "requirements" / here
    folder.mkdir(parents=True)
    (folder / "core.txt").write_text("# x\n# for tag, glibc 2.28 or newer\n")
    monkeypatch.setattr(tool, "_glibc", lambda: (2, 36))
    assert tool.fits(tmp_path) == folder
    monkeypatch.setattr(tool, "_glibc", lambda: (2, 17))
    assert tool.fits(tmp_path) is None  # the wheels need a newer C library
    monkeypatch.setattr(tool, "_glibc", lambda: None)
    assert tool.fits(tmp_path) is None  # not glibc (musl, macOS)
    monkeypatch.setattr(tool, "interpreter_tag", lambda: "cp312-linux-x86_64")
    monkeypatch.setattr(tool, "_glibc", lambda: (2, 36))
    assert tool.fits(tmp_path) is None  # another Python
