"""The steps of docs/adding_a_procedure.md, followed on a copy of the toy procedure.

The copy is registered as the guide says (a module of ``mtplan.models`` that defines
``PROCEDURE``: here the package's search path is extended by a temporary folder instead of
writing into the source tree) and must pass the whole conformance suite and the layer rule.
"""

from __future__ import annotations

import sys
from pathlib import Path

import mtplan.models as models
from mtplan.models import get, registry
from tests.models.conformance import check_procedure
from tests.test_layers import LAYERS, _imports, _layer, procedure_module_lookups

GUIDE = Path(__file__).resolve().parents[2] / "docs" / "adding_a_procedure.md"
TOY = Path(__file__).resolve().parent / "toy_line.py"
NAME = "edge_line"


def follow_the_guide(folder: Path) -> Path:
    """Steps 1-3 of the guide: copy the toy, rename it, name its levers."""
    text = TOY.read_text(encoding="utf-8").replace("toy_line", NAME)  # step 2
    text = text.replace("    noise_source=\"probe_noise\",\n",  # step 3
                        "    noise_source=\"probe_noise\",\n    levers=(\"n_points\", \"length_mm\"),\n")
    assert "levers=" in text
    path = folder / f"{NAME}.py"  # step 1: src/mtplan/models/<name>.py
    path.write_text(text, encoding="utf-8")
    return path


def test_the_guide_names_the_steps_this_test_follows():
    guide = GUIDE.read_text(encoding="utf-8")
    for needed in ("tests/models/toy_line.py", "src/mtplan/models/<name>.py", "levers",
                   "tests/models/test_conformance.py", "tests/models/conformance.py",
                   "check_procedure"):
        assert needed in guide, needed


def test_a_procedure_copied_from_the_toy_passes_the_conformance_suite(tmp_path, monkeypatch):
    path = follow_the_guide(tmp_path)
    monkeypatch.setattr(models, "__path__", [*models.__path__, str(tmp_path)])
    monkeypatch.setattr(models, "_REGISTRY", None)
    try:
        assert NAME in registry(), "the registry does not find the new module"
        proc = get(NAME)
        assert proc.forward.__module__ == f"mtplan.models.{NAME}"
        check_procedure(proc)
    finally:
        sys.modules.pop(f"mtplan.models.{NAME}", None)
    # the copy keeps the layer rule: it imports only its own layer and those below
    module = f"mtplan.models.{NAME}"
    targets = _imports(path, module, set())
    assert all(LAYERS.index(_layer(t)) <= LAYERS.index("models") for t in targets), targets
    assert not procedure_module_lookups(path.read_text(encoding="utf-8"), module)
