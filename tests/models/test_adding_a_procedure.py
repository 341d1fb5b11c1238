"""docs/adding_a_procedure.md followed: a procedure in a package of its own, built and installed.

The package is the guide's walk-through: its ``pyproject.toml`` as the guide prints it, and
the toy procedure renamed. It is built and installed into a temporary folder (pip's
``--target``), beside a second package whose entry point is broken; the commands then run in
fresh interpreters with that folder on ``PYTHONPATH``, so that the procedure is found only
through its installed entry point, as a user's would be.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import mtplan
from tests.packaging import pip_install
from tests.test_layers import LAYERS, _imports, _layer

GUIDE = Path(__file__).resolve().parents[2] / "docs" / "adding_a_procedure.md"
TOY = Path(__file__).resolve().parent / "toy_line.py"
NAME = "edge_line"
BROKEN = "broken_line"
#: a package whose module fails on import: the other procedures must still work
BROKEN_PYPROJECT = f"""\
[build-system]
requires = ["setuptools>=68"]
build-backend = "setuptools.build_meta"

[project]
name = "mtplan-broken-line"
version = "0.1.0"

[project.entry-points."mtplan.procedures"]
{BROKEN} = "mtplan_broken_line:PROCEDURE"

[tool.setuptools]
py-modules = ["mtplan_broken_line"]
"""


def _guide_blocks(language: str) -> list[str]:
    text = GUIDE.read_text(encoding="utf-8")
    return re.findall(rf"```{language}\n(.*?)```", text, re.S)


def _package(folder: Path, pyproject: str, module: str, source: str) -> Path:
    folder.mkdir()
    (folder / "pyproject.toml").write_text(pyproject, encoding="utf-8")
    (folder / f"{module}.py").write_text(source, encoding="utf-8")
    return folder


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(run, folder): the guide's package and the broken one installed; run(*argv) runs
    ``mtplan argv`` (or ``python argv`` for ``-c``) in a fresh interpreter in `folder`."""
    tmp = tmp_path_factory.mktemp("plugin")
    pyproject = next(b for b in _guide_blocks("toml") if "[build-system]" in b)
    source = TOY.read_text(encoding="utf-8").replace("toy_line", NAME)
    good = _package(tmp / "mtplan-edge-line", pyproject, f"mtplan_{NAME}", source)
    bad = _package(tmp / "mtplan-broken-line", BROKEN_PYPROJECT, "mtplan_broken_line",
                   "import mtplan_no_such_module  # noqa: F401\n")
    site = tmp / "site"
    pip_install(site, good, bad)
    work = tmp / "work"
    work.mkdir()
    # the installed packages first, then the mtplan under test (not another one)
    path = [str(site), str(Path(mtplan.__file__).resolve().parents[1]),
            os.environ.get("PYTHONPATH", "")]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in path if p)}

    def run(*argv):
        lead = [] if argv[0] == "-c" else ["-m", "mtplan.cli"]
        return subprocess.run([sys.executable, *lead, *map(str, argv)], capture_output=True,
                              text=True, cwd=work, env=env, timeout=300)

    return run, work


def test_the_installed_procedure_is_listed_and_the_broken_one_named(installed):
    run, _ = installed
    done = run("procedures")
    assert done.returncode == 0, done.stderr
    assert f"{NAME}: Straight edge" in done.stdout
    assert "rotary_axis:" in done.stdout  # the built-in ones are still there
    warnings = done.stderr.strip().splitlines()
    assert len(warnings) == 1, done.stderr
    assert warnings[0].startswith("mtplan: warning: the entry point broken_line")
    assert "mtplan-broken-line 0.1.0" in warnings[0] and "ModuleNotFoundError" in warnings[0]
    # asked for by name, the broken one is a user's error: one line, status 2
    done = run("simulate", BROKEN)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    assert "installed but unusable" in done.stderr and "mtplan_no_such_module" in done.stderr


def test_the_installed_procedure_passes_check_procedure(installed):
    run, _ = installed
    done = run("-c", "import sys\n"
                     "from mtplan.models import get\n"
                     "from mtplan.testing import check_procedure\n"
                     f"check_procedure({NAME!r})\n"
                     f"print(get({NAME!r}).forward.__module__, 'pytest' in sys.modules)\n")
    assert done.returncode == 0, done.stderr
    # found through the installed package, and checked without a test framework
    assert done.stdout.split() == [f"mtplan_{NAME}", "False"]


def test_the_guides_commands_run_on_the_installed_procedure(installed):
    """simulate (keeping a readings file), plan and estimate, as the guide writes them."""
    run, work = installed
    lines = [line for block in _guide_blocks("bash") for line in block.splitlines()
             if re.match(r"mtplan (simulate|plan|estimate) NAME ", line)]
    assert [line.split()[1] for line in lines] == ["simulate", "plan", "estimate"]
    docs = {}
    for line in lines:
        argv = line.replace("NAME", NAME).split()[1:]
        done = run(*argv, "--json")
        assert done.returncode == 0, (line, done.stderr)
        docs[argv[0]] = json.loads(done.stdout)
    assert docs["simulate"]["procedure"] == NAME
    assert (work / f"{NAME}_readings.csv").is_file()
    # u(offset) = 1 um / sqrt(n_points): the fewest points, 5, already meet 1 um
    assert docs["plan"]["best"]["setup"]["n_points"] == 5
    offset = {m["name"]: m for m in docs["estimate"]["measurands"]}["offset"]
    assert abs(offset["estimate"] - 12.0) <= 5 * offset["u"]  # the truth: 0.012 mm


def test_the_toy_keeps_the_layer_rule():
    """The template imports only the models' layer and those below it."""
    targets = _imports(TOY, "mtplan_toy", set())
    assert targets and all(LAYERS.index(_layer(t)) <= LAYERS.index("models") for t in targets)
