"""The contract has defaults, not holes: no field of a procedure's records is a hook that may be
None, and no caller in mtplan tests a capability for None; the capabilities are methods of a
base whose bodies are the generic behaviour, and the conformance checks state the guide's
conventions (the source method, the field that sizes each source) as messages."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import pytest

from mtplan.models import registry
from mtplan.models.capabilities import METHODS, Capabilities, SourceMethod
from mtplan.models.protocol import Estimator, Measurand, Procedure, ReadingsFormat, Source
from mtplan.testing import checks, template_source
from mtplan.testing import template as toy_line

SRC = Path(__file__).resolve().parents[2] / "src" / "mtplan"
RECORDS = (Procedure, Estimator, ReadingsFormat, Capabilities, SourceMethod, Source, Measurand)
#: the optional callables of the contract, by the record attribute they are read from:
#: the capabilities' methods, and the records' callable fields that have a default
OPTIONAL = {"capabilities": frozenset(METHODS),
            "readings": frozenset(f.name for f in dataclasses.fields(ReadingsFormat)
                                  if "Callable" in str(f.type)
                                  and f.default is not dataclasses.MISSING),
            "estimator": frozenset(f.name for f in dataclasses.fields(Estimator)
                                   if "Callable" in str(f.type)
                                   and f.default is not dataclasses.MISSING)}
CAPABILITIES = frozenset().union(*OPTIONAL.values())


def _capability(node: ast.AST) -> str | None:
    """The optional callable `node` reads without calling it: ``x.capabilities.<method>``,
    ``x.readings.<field>``, ``<estimator>.<field>`` (``resolution``) or ``getattr(x,
    "<any of them>", ...)``; None for anything else."""
    if isinstance(node, ast.Attribute):
        owner = node.value.attr if isinstance(node.value, ast.Attribute) else None
        if node.attr in OPTIONAL.get(owner, ()) or node.attr in OPTIONAL["estimator"]:
            return node.attr
    if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
            and node.func.id == "getattr" and len(node.args) >= 2
            and isinstance(node.args[1], ast.Constant) and node.args[1].value in CAPABILITIES):
        return node.args[1].value
    return None


def _none_tests(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, capability) of every ``is None`` / ``is not None`` test of a capability, read
    directly or through a name bound to it in the same function (``hook = proc.capabilities
    .report_extras``), and of every truth test of such a name (``if hook``)."""
    found = []
    functions = [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)]
    for scope in [tree, *functions]:  # names bound to a capability: within a function only
        bound = {}
        for node in ast.walk(scope) if scope is not tree else ():
            if isinstance(node, ast.Assign) and (cap := _capability(node.value)):
                bound.update({t.id: cap for t in node.targets if isinstance(t, ast.Name)})

        def read(node):
            if isinstance(node, ast.Name) and node.id in bound:
                return bound[node.id]
            return _capability(node)

        for node in ast.walk(scope):
            if isinstance(node, ast.Compare) and any(isinstance(o, ast.Is | ast.IsNot)
                                                     for o in node.ops):
                operands = [node.left, *node.comparators]
                if any(isinstance(o, ast.Constant) and o.value is None for o in operands):
                    found += [(node.lineno, cap) for o in operands if (cap := read(o))]
            elif isinstance(node, ast.If | ast.IfExp | ast.While):
                if isinstance(node.test, ast.Name) and (cap := read(node.test)):
                    found.append((node.lineno, cap))
            elif isinstance(node, ast.BoolOp):
                found += [(node.lineno, cap) for v in node.values
                          if isinstance(v, ast.Name) and (cap := read(v))]
    return sorted(set(found))


def test_no_caller_tests_a_capability_for_none():
    """An AST scan of mtplan: a capability is called, never tested for None (the generic
    default answers where a procedure has nothing of its own)."""
    found = {}
    for path in sorted(SRC.rglob("*.py")):
        hits = _none_tests(ast.parse(path.read_text(encoding="utf-8")))
        if hits:
            found[str(path.relative_to(SRC))] = hits
    assert not found, f"capabilities tested for None: {found}"


def test_the_scan_finds_the_tests_it_forbids():
    """The scan is no test that cannot fail: each form of a None test it forbids is found."""
    caught = """
def a(proc):
    if proc.capabilities.identifiability_report is not None:
        pass
def b(proc):
    hook = proc.capabilities.report_extras
    return hook(1, 2) if hook else {}
def c(proc):
    hook = getattr(proc, "source_structure", None)
    return None if hook is None else hook()
def d(proc):
    return proc.readings.limits is None or 1
"""
    assert [cap for _, cap in _none_tests(ast.parse(caught))] == [
        "identifiability_report", "report_extras", "source_structure", "limits"]
    fine = """
def e(proc, setup):
    rep = proc.capabilities.identifiability_report(setup)
    jac = proc.capabilities.first_order_sensitivities(setup)
    return rep if jac is None else None
"""
    assert _none_tests(ast.parse(fine)) == []


@pytest.mark.parametrize("record", RECORDS, ids=lambda r: r.__name__)
def test_the_contract_has_no_optional_callable_field(record):
    """No field of the records is a callable that may be None, nor defaults to None."""
    for f in dataclasses.fields(record):
        kind = str(f.type)
        assert not ("Callable" in kind and "None" in kind), (record.__name__, f.name, kind)
        if "Callable" in kind:
            assert callable(f.default) or f.default is dataclasses.MISSING, (
                record.__name__, f.name)


def test_every_capability_is_a_method_with_a_generic_body():
    """The capabilities are methods of the base, not data that may be None; a procedure
    overrides only what it needs, and a copy can go back to the generic default."""
    base = Capabilities()
    assert base.overrides() == () and not base.builds_truths and not base.batches_truths
    assert all(callable(getattr(base, m)) for m in METHODS)
    assert base.report_extras(None, None) == {} and base.identifiability_report(None) == {}
    assert base.start_from_readings(None, None, "truth") == "truth"
    assert len(base.identifiability(None, "patent")) == 0
    with pytest.raises(NotImplementedError, match="truth_from_estimate"):
        base.truth_from_estimate(None, {})
    for proc in registry().values():
        caps = proc.capabilities
        assert set(caps.overrides()) <= set(METHODS)
        plain = caps.generic(*caps.overrides())
        assert plain.overrides() == () and plain.block_size == caps.block_size
    rotary = registry()["rotary_axis"].capabilities
    assert rotary.builds_truths and rotary.overriding(
        report_extras=lambda setup, truth: {"x": 1}).report_extras(None, None) == {"x": 1}
    with pytest.raises(TypeError, match="no method 'no_such'"):
        rotary.generic("no_such")


def test_a_record_without_estimators_is_refused():
    """A Procedure is whole when made: none is built without estimators to complete later."""
    with pytest.raises(ValueError, match="'estimators' parameter of Procedure 'toy_line'"):
        dataclasses.replace(toy_line.PROCEDURE, estimators={})


def test_the_source_method_is_checked_and_cited_by_the_procedure():
    """The source method is one of the estimators and is cited; a procedure that names an
    estimator it lacks, or cites nothing, is told so."""
    for proc in registry().values():
        assert proc.source_method.estimator in proc.estimators and proc.source_method.title
    def citing(method):
        proc = toy_line.PROCEDURE
        return dataclasses.replace(proc, capabilities=dataclasses.replace(
            proc.capabilities, source_method=method))

    lost = citing(SourceMethod("patent", "A title"))
    with pytest.raises(AssertionError, match="'patent'.*'least_squares'"):
        checks.check_source_method(lost)
    uncited = citing(SourceMethod("least_squares"))
    with pytest.raises(AssertionError, match="not cited"):
        checks.check_source_method(uncited)


def test_a_source_without_its_field_is_named_not_an_index_error():
    """A source that declares no set-up field (or one that is none) fails the checks with a
    message naming it, not an IndexError."""
    def sources(setup):
        out = toy_line.sources(setup)
        return {**out, "probe_noise": dataclasses.replace(out["probe_noise"], field=""),
                "scale_error": dataclasses.replace(out["scale_error"], field="no_such_um")}

    bad = dataclasses.replace(toy_line.PROCEDURE, sources=sources)
    for check in (checks.check_sources_declare_their_fields,
                  checks.check_switching_a_source_off_through_its_field):
        with pytest.raises(AssertionError) as exc:
            check(bad)
        assert "probe_noise (field '')" in str(exc.value), check.__name__
        assert "scale_error (field 'no_such_um')" in str(exc.value), check.__name__


def test_the_template_is_shipped_and_renamed(tmp_path, monkeypatch):
    """The template of docs/adding_a_procedure.md is part of mtplan; its text renamed is a
    procedure of the new name."""
    import importlib

    text = template_source("edge_line")
    assert "toy_line" not in text and 'name="edge_line"' in text
    (tmp_path / "mtplan_edge_line.py").write_text(text, encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("mtplan_edge_line")
    monkeypatch.delitem(__import__("sys").modules, "mtplan_edge_line")
    assert module.PROCEDURE.name == "edge_line" and module.Setup._owner == "edge_line"
    with pytest.raises(Exception, match="lower-case Python name"):
        template_source("Edge line")
