"""docs/adding_a_procedure.md followed: a procedure in a package of its own, built and installed.

mtplan is built from this checkout and installed into a temporary folder (pip's ``--target``);
from it alone, the guide's command writes the package's module (the template that mtplan
ships, renamed). The package is the guide's walk-through: its ``pyproject.toml`` as the guide
prints it and that module. It is built and installed into the same folder, beside a second
package whose entry point is broken; the commands then run in fresh interpreters with only
that folder on ``PYTHONPATH``, so that mtplan and the procedure are the installed ones, found
as a user's would be.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from tests.packaging import ROOT, install_mtplan, pip_install
from tests.test_layers import LAYERS, _imports, _layer

GUIDE = ROOT / "docs" / "adding_a_procedure.md"
TEMPLATE = ROOT / "src" / "mtplan" / "testing" / "template.py"
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


def _package(folder: Path, pyproject: str, module: str, source: str | None = None) -> Path:
    folder.mkdir()
    (folder / "pyproject.toml").write_text(pyproject, encoding="utf-8")
    if source is not None:
        (folder / f"{module}.py").write_text(source, encoding="utf-8")
    return folder


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(run, folder): the guide's package and the broken one installed; run(*argv) runs
    ``mtplan argv`` (or ``python argv`` for ``-c``) in a fresh interpreter in `folder`."""
    tmp = tmp_path_factory.mktemp("plugin")
    site = tmp / "site"
    install_mtplan(site, tmp)
    env = {**os.environ, "PYTHONPATH": str(site)}  # the installed mtplan alone
    pyproject = next(b for b in _guide_blocks("toml") if "[build-system]" in b)
    good = _package(tmp / "mtplan-edge-line", pyproject, f"mtplan_{NAME}")
    # the guide's command writes the module, from the installed mtplan's template
    command = next(line for b in _guide_blocks("bash") for line in b.splitlines()
                   if "template_source" in line)
    assert command.startswith("python -c ") and f"> mtplan_{NAME}.py" in command
    done = subprocess.run(shlex.quote(sys.executable) + command.removeprefix("python"),
                          shell=True, cwd=good, env=env, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    bad = _package(tmp / "mtplan-broken-line", BROKEN_PYPROJECT, "mtplan_broken_line",
                   "import mtplan_no_such_module  # noqa: F401\n")
    pip_install(site, good, bad)
    work = tmp / "work"
    work.mkdir()

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
                     "import mtplan\n"
                     "from mtplan.models import get\n"
                     "from mtplan.testing import check_procedure\n"
                     f"check_procedure({NAME!r})\n"
                     f"print(get({NAME!r}).forward.__module__, 'pytest' in sys.modules)\n"
                     "print(mtplan.__file__)\n")
    assert done.returncode == 0, done.stderr
    # found through the installed package, checked without a test framework, and mtplan is
    # the installed one, not this checkout
    where, used = done.stdout.splitlines()[0], Path(done.stdout.splitlines()[1])
    assert where.split() == [f"mtplan_{NAME}", "False"]
    assert not used.is_relative_to(ROOT), used


def test_the_installed_procedures_certificate_cites_its_own_source_method(installed):
    """The certificate's method row names the procedure's own source method (the template's
    ISO 230-1), read from its record, not "no published source method"."""
    run, _ = installed
    done = run("-c", "from types import SimpleNamespace as N\n"
                     "from mtplan.models import get\n"
                     "from mtplan.reports.certificate import _methods\n"
                     f"spec = N(label='edge', standards=(), name={NAME!r}, "
                     f"procedure=get({NAME!r}))\n"
                     "result = N(outcomes=[N(spec=spec, verdicts=[])], "
                     "study=N(laboratory={}))\n"
                     "print(_methods(result, estimators=False)[0][1])\n")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("ISO 230-1:2012, \u201cTest code for machine tools - Part 1: "
                                  "Geometric accuracy of machines operating under no-load or "
                                  "quasi-static conditions\u201d;"), done.stdout


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


def test_the_template_keeps_the_layer_rule():
    """The template imports only the models' layer and those below it."""
    targets = _imports(TEMPLATE, "mtplan_toy", set())
    assert targets and all(LAYERS.index(_layer(t)) <= LAYERS.index("models") for t in targets)
