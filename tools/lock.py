"""The pinned installs of ``make demo`` and ``make test``: write them, and say whether they fit.

``make demo`` and ``make test`` install mtplan's dependencies from the files in
``requirements/<interpreter>/`` when this Python is the one they were resolved for: each
package by its wheel's address and sha256, with no resolution, by uv (``uv.txt``: uv
itself, which pip installs into the venv first), which fetches and unpacks them in
parallel: ``core.txt`` the dependencies with pip (as ``python -m venv`` would bring it)
and setuptools (mtplan's build backend: mtplan then installs without an isolated build
environment), ``test.txt`` the test extras beyond them. pip's resolution over the package
indexes was about 7 s of a 13 s install, and its unpacking, one package after the other,
5 s more; uv installs the same wheels in about 1.5 s. Where no such directory fits this
Python, pip resolves pyproject.toml's ranges as it always did. The versions are those a
resolution from PyPI gave on the day the files were written; the ranges in pyproject.toml
stay what mtplan needs.

    python tools/lock.py          # resolve from PyPI again and rewrite the files
    python tools/lock.py --fits   # print the directory that fits this Python (exit 0),
                                  # or exit 1 where none does

Standard library only: it runs with the Python that makes the venv, before anything is
installed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import sysconfig
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
INDEX = "https://pypi.org/simple"
#: what the venv gets beside the dependencies: pip (as ``python -m venv`` would give it)
#: and setuptools (mtplan's build backend, so that mtplan installs without an isolated
#: build environment, which would be resolved from the indexes again)
TOOLS = ["pip", "setuptools"]
#: the installer of the pinned files (pip installs it first, by its own pinned file)
INSTALLER = ["uv"]


def interpreter_tag() -> str:
    """``cp311-linux-x86_64``: implementation, version and platform of this Python."""
    impl = {"cpython": "cp"}.get(sys.implementation.name, sys.implementation.name)
    return f"{impl}{sys.version_info[0]}{sys.version_info[1]}-{sysconfig.get_platform()}"


def _glibc() -> tuple[int, int] | None:
    libc, version = platform.libc_ver()
    if libc != "glibc" or not version:
        return None
    major, minor = version.split(".")[:2]
    return int(major), int(minor)


def fits(root: Path = ROOT) -> Path | None:
    """The lock directory for this Python, or None: one written for its tag whose wheels'
    glibc (the largest manylinux version among them) this system has."""
    folder = root / "requirements" / interpreter_tag()
    header = folder / "core.txt"
    if not header.is_file():
        return None
    need = re.search(r"glibc (\d+)\.(\d+)", header.read_text(encoding="utf-8").split("\n")[1])
    if need:
        have = _glibc()
        if have is None or have < (int(need.group(1)), int(need.group(2))):
            return None
    return folder


def _requirements(root: Path) -> tuple[list[str], list[str]]:
    project = tomllib.loads((root / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    return list(project["dependencies"]), list(project["optional-dependencies"]["test"])


def _resolve(reqs: list[str], constraints: dict | None = None) -> dict:
    """{name: (version, url, sha256)} of a resolution from PyPI alone (wheels only),
    ignoring this machine's pip configuration (its extra indexes and local folders)."""
    env = dict(os.environ, PIP_CONFIG_FILE=os.devnull)
    for key in [k for k in env if k.startswith("PIP_") and k != "PIP_CONFIG_FILE"]:
        del env[key]
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "pip", "install", "--dry-run", "--ignore-installed",
               "--quiet", "--disable-pip-version-check", "--only-binary", ":all:",
               "--index-url", INDEX, "--report", str(Path(tmp) / "r.json"), *reqs]
        if constraints:
            pins = Path(tmp) / "c.txt"
            pins.write_text("".join(f"{n}=={v[0]}\n" for n, v in constraints.items()))
            cmd += ["-c", str(pins)]
        subprocess.run(cmd, check=True, env=env)
        report = json.loads((Path(tmp) / "r.json").read_text(encoding="utf-8"))
    out = {}
    for item in report["install"]:
        info = item["download_info"]
        name = re.sub(r"[-_.]+", "-", item["metadata"]["name"]).lower()
        out[name] = (item["metadata"]["version"], info["url"],
                     info["archive_info"]["hashes"]["sha256"])
    return out


def _glibc_needed(pins: dict) -> tuple[int, int] | None:
    need = None
    for _, url, _ in pins.values():
        name = url.rsplit("/", 1)[-1]
        found = [(int(a), int(b)) for a, b in re.findall(r"manylinux_(\d+)_(\d+)", name)]
        found += [(2, 17)] if "manylinux2014" in name else []
        if found:
            least = min(found)  # a wheel with several tags installs where the oldest does
            need = least if need is None else max(need, least)
    return need


def _write(path: Path, pins: dict, what: str, glibc, installer="uv pip") -> None:
    lines = [f"# {what}: written by tools/lock.py, do not edit",
             f"# for {interpreter_tag()}"
             + (f", glibc {glibc[0]}.{glibc[1]} or newer" if glibc else ""),
             f"# resolved from {INDEX}; install with {installer} install --no-deps -r "
             f"{path.name}"]
    lines += [f"{name} @ {url} --hash=sha256:{sha}"
              for name, (_, url, sha) in sorted(pins.items())]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write(root: Path = ROOT) -> Path:
    """Resolve the test set, then the demo's set under its pins, and uv, and write the
    files."""
    core, test = _requirements(root)
    everything = _resolve(core + test + TOOLS)
    demo = _resolve(core + TOOLS, constraints=everything)
    rest = {n: v for n, v in everything.items() if n not in demo}
    installer = _resolve(INSTALLER)
    glibc = max(g for g in (_glibc_needed(everything), _glibc_needed(installer)) if g)
    folder = root / "requirements" / interpreter_tag()
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob("*.txt"):
        old.unlink()
    _write(folder / "core.txt", demo, "mtplan's dependencies", glibc)
    _write(folder / "test.txt", rest, "the test extras beyond them", glibc)
    _write(folder / "uv.txt", installer, "the installer of the two files beside", glibc,
           installer="pip")
    return folder


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fits", action="store_true",
                        help="print the lock directory that fits this Python, or exit 1")
    args = parser.parse_args(argv)
    if args.fits:
        folder = fits()
        if folder is None:
            return 1
        print(folder.relative_to(ROOT))
        return 0
    print(write())
    return 0


if __name__ == "__main__":
    sys.exit(main())
