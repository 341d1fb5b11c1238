"""The typed records at the core: readings, truth batches and field information.

A batch of truths is made by ``Truth.batch`` and readings are a :class:`Readings`; no frozen
record is changed after its construction (``object.__setattr__`` only in a dataclass's
``__post_init__``, where the record is still being made).
"""

from __future__ import annotations

import ast
import dataclasses
import pickle
from pathlib import Path

import numpy as np
import pytest

from mtplan.models import registry
from mtplan.models.fields import FieldInfo, TruthBatch, fields_info, split_unit
from mtplan.models.protocol import Readings

SRC = Path(__file__).resolve().parents[2] / "src"
PROCEDURES = registry()


def setattr_outside_post_init(source: str, where: str) -> list[str]:
    """The calls of ``object.__setattr__`` in `source` that are not in a ``__post_init__``."""
    tree = ast.parse(source)
    parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}
    found = []
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                and node.func.attr == "__setattr__" and isinstance(node.func.value, ast.Name)
                and node.func.value.id == "object"):
            continue
        scope = parents.get(node)
        while scope is not None and not isinstance(scope, ast.FunctionDef
                                                   | ast.AsyncFunctionDef):
            scope = parents.get(scope)
        if scope is None or scope.name != "__post_init__":
            found.append(f"{where}:{node.lineno} ({scope.name if scope else 'module'})")
    return found


def test_no_frozen_record_is_changed_after_it_is_made():
    found = [hit for path in sorted(SRC.rglob("*.py"))
             for hit in setattr_outside_post_init(path.read_text(encoding="utf-8"),
                                                  str(path.relative_to(SRC)))]
    assert not found, found


@pytest.mark.parametrize("source, expected", [
    ("def f(t):\n    object.__setattr__(t, 'x', 1)\n", 1),
    ("object.__setattr__(t, 'x', 1)\n", 1),
    ("class A:\n    def __post_init__(self):\n        object.__setattr__(self, 'x', 1)\n", 0),
    ("class A:\n    def __post_init__(self):\n        def g(t):\n"
     "            object.__setattr__(t, 'x', 1)\n", 1),
])
def test_the_scan_finds_a_record_changed_outside_its_post_init(source, expected):
    assert len(setattr_outside_post_init(source, "m")) == expected


@pytest.mark.parametrize("name", sorted(PROCEDURES))
def test_readings_are_a_type_that_knows_its_rows_and_units(name):
    proc = PROCEDURES[name]
    setup = proc.Setup()
    readings = proc.simulate(setup, draws=3, rng=0)
    assert isinstance(readings, Readings) and Readings is not dict
    assert readings.rows == 3
    assert all(np.shape(v)[0] == 3 for v in readings.values())
    assert set(readings.units) == set(readings) and all(readings.units.values())
    one = proc.readings.from_frame(setup, proc.readings.frame(setup, proc.simulate(setup, rng=1)))
    assert isinstance(one, Readings) and one.rows == 1


def test_readings_are_not_changed_in_place():
    readings = Readings({"z_mm": np.zeros((2, 3)), "a_rad": np.ones((2,))})
    with pytest.raises(TypeError, match="replace"):
        readings["z_mm"] = np.ones((2, 3))
    with pytest.raises(TypeError):
        readings.update(a_rad=np.zeros(2))
    other = readings.replace(a_rad=np.zeros(2))
    assert isinstance(other, Readings) and np.all(readings["a_rad"] == 1)
    assert readings.units == {"z_mm": "mm", "a_rad": "rad"}
    again = pickle.loads(pickle.dumps(readings))
    assert isinstance(again, Readings) and np.array_equal(again["z_mm"], readings["z_mm"])


def test_a_truth_batch_is_made_not_changed():
    proc = PROCEDURES["tracker_frame"]
    setup = proc.Setup()
    truth = proc.Truth()
    values = proc.true_values(setup, truth)
    m = 4
    batch = proc.capabilities.truths_from_estimates(
        setup, {k: np.full(m, v) + 1e-7 * np.arange(m) for k, v in values.items()})
    assert isinstance(batch, TruthBatch) and isinstance(batch, proc.Truth)
    assert batch.rows == m and type(batch).truth_class is proc.Truth
    with pytest.raises(dataclasses.FrozenInstanceError):
        batch.tracker_dx_um = 1.0
    # one forward run gives the readings of every truth of the batch
    readings = proc.forward(setup, batch, proc.zero_errors(setup, m))
    first = proc.forward(setup, proc.capabilities.truth_from_estimate(
        setup, {k: np.full(1, v) for k, v in values.items()}), proc.zero_errors(setup, 1))
    assert readings.rows == m
    for k in first:
        np.testing.assert_allclose(readings[k][:1], first[k], rtol=0, atol=1e-9)
    again = pickle.loads(pickle.dumps(batch))
    assert type(again) is type(batch) and again.rows == m


def test_a_truth_batch_refuses_arrays_of_different_lengths():
    truth_class = PROCEDURES["rotary_axis"].Truth
    floats = [f.name for f in fields_info(truth_class) if f.kind is float][:2]
    with pytest.raises(ValueError, match="one length"):
        truth_class.batch(**{floats[0]: np.zeros(2), floats[1]: np.zeros(3)})
    with pytest.raises(ValueError, match=floats[0]):
        truth_class.batch(**{floats[0]: np.zeros((2, 2))})
    one = truth_class.batch(truth_class(), **{floats[0]: np.zeros(5)})
    assert one.rows == 5 and getattr(one, floats[1]) == getattr(truth_class(), floats[1])


@pytest.mark.parametrize("name", sorted(PROCEDURES))
def test_field_information_is_a_record(name):
    proc = PROCEDURES[name]
    infos = fields_info(proc.Setup)
    assert infos and all(isinstance(i, FieldInfo) for i in infos)
    assert [i.name for i in infos] == [f.name for f in dataclasses.fields(proc.Setup)
                                       if not f.name.startswith("_")]
    assert all(i.unit == split_unit(i.name)[1] for i in infos)
    with pytest.raises(dataclasses.FrozenInstanceError):
        infos[0].name = "other"
