"""The registry: procedures come from the entry points of ``mtplan.procedures``, mtplan's own
included; a plug-in that gives none is named, and the others work.

Installed packages are stood in for by their metadata alone (a ``.dist-info`` folder with
``entry_points.txt``, which is what an install writes) on ``sys.path``;
``tests/models/test_adding_a_procedure.py`` builds and installs a real one.
"""

from __future__ import annotations

import importlib
import pkgutil
import tomllib
from pathlib import Path

import pytest

import mtplan.models as models
from mtplan import cli
from mtplan._validate import InvalidInput
from mtplan.models import ENTRY_POINT_GROUP, Procedure, broken, get, registry
from mtplan.testing import template as toy_line

PYPROJECT = Path(__file__).resolve().parents[2] / "pyproject.toml"


def _procedure_modules() -> set[str]:
    """The modules of mtplan.models that define a procedure (what the fallback finds)."""
    found = set()
    for info in pkgutil.iter_modules(models.__path__):
        module = importlib.import_module(f"mtplan.models.{info.name}")
        if isinstance(getattr(module, "PROCEDURE", None), Procedure):
            found.add(info.name)
    return found


BUILT_IN = _procedure_modules()


def _installed(site: Path, package: str, points: dict[str, str]) -> None:
    """The metadata an install of `package` declaring `points` leaves in `site`."""
    info = site / f"{package.replace('-', '_')}-0.1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {package}\nVersion: 0.1.0\n",
                                   encoding="utf-8")
    lines = [f"[{ENTRY_POINT_GROUP}]", *(f"{k} = {v}" for k, v in points.items())]
    (info / "entry_points.txt").write_text("\n".join(lines) + "\n", encoding="utf-8")


@pytest.fixture
def site(tmp_path, monkeypatch):
    """A folder of installed metadata, first on sys.path, and a registry loaded afresh (the
    one loaded before comes back afterwards)."""
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(models, "_REGISTRY", None)
    monkeypatch.setattr(models, "_BROKEN", [])
    return tmp_path


def test_pyproject_registers_every_procedure_module_of_mtplan():
    """The table in pyproject.toml and the modules of mtplan.models that define a procedure
    agree: none is forgotten (the registry's fallback for an old install finds modules)."""
    assert {"rotary_axis", "geometry21", "circle_centre"} <= BUILT_IN  # the scan sees them
    table = tomllib.loads(PYPROJECT.read_text(encoding="utf-8"))["project"]["entry-points"]
    assert table[ENTRY_POINT_GROUP] == {m: f"mtplan.models.{m}:PROCEDURE" for m in BUILT_IN}
    missing = BUILT_IN - set(registry())
    assert not missing, f"{missing} not registered: install mtplan again (pip install -e .)"


def test_the_built_in_procedures_come_from_mtplans_entry_points(site):
    """An mtplan whose metadata registers two procedures has exactly those two: the modules
    are not scanned where mtplan declares entry points."""
    _installed(site, "mtplan", {"rotary_axis": "mtplan.models.rotary_axis:PROCEDURE",
                                "circle_centre": "mtplan.models.circle_centre:PROCEDURE"})
    assert list(registry()) == ["circle_centre", "rotary_axis"]
    assert broken() == []


def test_without_mtplans_entry_points_the_built_in_modules_are_found(site):
    """An mtplan installed before it declared entry points still has its procedures."""
    _installed(site, "mtplan", {})
    assert set(registry()) == BUILT_IN


BAD = {
    "no_import": ("mtplan_no_such_module:PROCEDURE", "ModuleNotFoundError"),
    "not_one": ("math:pi", "names a float, not an mtplan.models.Procedure"),
    "other_name": ("mtplan.testing.template:PROCEDURE", "names the procedure 'toy_line'"),
    "rotary_axis": ("mtplan.testing.template:PROCEDURE", "'rotary_axis' is already registered"),
}


def test_a_broken_plugin_is_named_and_the_others_work(site, capsys):
    _installed(site, "mtplan-plugins", {"toy_line": "mtplan.testing.template:PROCEDURE",
                                        **{k: v for k, (v, _) in BAD.items()}})
    procs = registry()
    assert procs["toy_line"] is toy_line.PROCEDURE
    assert BUILT_IN <= set(procs) and procs["rotary_axis"].title != toy_line.PROCEDURE.title
    reasons = broken()
    assert len(reasons) == len(BAD)
    for name, (value, why) in BAD.items():
        (reason,) = [r for r in reasons if f"the entry point {name} = {value!r}" in r]
        assert "package mtplan-plugins 0.1.0" in reason and why in reason, reason
    with pytest.raises(InvalidInput, match="'no_import' is installed but unusable.*Module"):
        get("no_import")
    # the command line: the list works and names each on stderr; the name is a one-line error
    assert cli.main(["procedures"]) == 0
    out, err = capsys.readouterr()
    assert "toy_line: Straight edge" in out and "rotary_axis:" in out
    assert [line.startswith("mtplan: warning: the entry point ")
            for line in err.splitlines()] == [True] * len(BAD)
    assert cli.main(["simulate", "not_one"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "names a float" in err
    assert cli.main(["simulate", "toy_line", "--trials", "100"]) == 0


def test_a_built_in_procedure_by_name_loads_alone():
    """``get`` of a built-in procedure before the registry is loaded imports that procedure
    alone (a command on one procedure does not import the others), and it is the object the
    registry then holds."""
    import subprocess
    import sys

    code = ("import sys; from mtplan.models import get, registry; p = get('circle_centre'); "
            "others = sorted({m.split('.')[2] for m in sys.modules "
            "if m.split('.')[:2] == ['mtplan', 'models'] "
            "and m.count('.') >= 2 and m.split('.')[2] in " + repr(sorted(BUILT_IN)) + "}); "
            "print(others); assert registry()['circle_centre'] is p")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=PYPROJECT.parent)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["['circle_centre']"]  # its own submodules, no other procedure
