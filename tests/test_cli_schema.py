"""One schema for every command: the same names for value, u, interval, coverage and notes;
a measurand the set-up cannot determine listed with its reason; a closed pipe ends quietly."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import pandas as pd
import pytest

from mtplan.cli import EXIT_PIPE, main
from mtplan.evaluation.simulation import MEASURAND_KEYS

ROOT = Path(__file__).resolve().parents[1]
READINGS = str(ROOT / "examples" / "circle_centre_readings.csv")
G21 = str(ROOT / "examples" / "geometry21_readings.csv")

#: every command that prints JSON, at a small size: (argv, writes a measurand table)
COMMANDS = {
    "procedures": (["procedures", "circle_centre", "--json"], False),
    "simulate": (["simulate", "circle_centre", "--trials", "60"], True),
    "linearize": (["linearize", "circle_centre"], True),
    "sweep": (["sweep", "circle_centre", "--vary", "n_points=3,4", "--trials", "60"], False),
    "estimate": (["estimate", "circle_centre", READINGS, "--trials", "60"], True),
    "plan": (["plan", "circle_centre", "--vary", "n_points=3,4", "--target", "centre_x<=5",
              "--trials", "100", "--confirm", "1"], False),
    "accept": (["accept", "--u", "1", "--lower", "-5", "--upper", "5"], False),
    "compensate": (["compensate", str(ROOT / "examples" / "compensation" /
                                      "rotary_axis_result.json"),
                    "--out", str(Path(tempfile.gettempdir()) / "mtplan-schema-compensation")],
                   False),
    "validate": (["validate", *map(str, sorted((ROOT / "examples" / "validate_results").glob("*.json"))),
                  "--references", str(ROOT / "examples" / "validate_references.csv")], False),
}


def _keys(doc):
    """Every key of a JSON document, at any depth."""
    if isinstance(doc, dict):
        return set(doc) | {k for v in doc.values() for k in _keys(v)}
    if isinstance(doc, list):
        return {k for v in doc for k in _keys(v)}
    return set()


def _json(capsys, argv):
    code = main([*argv, "--json"] if "--json" not in argv else argv)
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out)


def test_every_command_is_covered():
    from mtplan.cli import COMMANDS as ALL

    # report writes a document and explore serves a page (tests/explore), not JSON
    assert set(COMMANDS) == set(ALL) - {"report", "explore"}


@pytest.mark.parametrize("command", list(COMMANDS))
def test_the_standard_uncertainty_is_u_in_every_command(capsys, tmp_path, command):
    argv, table = COMMANDS[command]
    doc = _json(capsys, argv)
    keys = _keys(doc)
    assert "std" not in keys, command
    if table:
        for m in doc["measurands"]:
            assert list(m)[: len(MEASURAND_KEYS)] == list(MEASURAND_KEYS), m
        assert isinstance(doc["notes"], list)
    if "--out" in " ".join(a for a in argv) or command in ("procedures", "accept", "validate"):
        return
    out = tmp_path / "t.csv"
    assert main([*argv, "--out", str(out)]) == 0
    capsys.readouterr()
    columns = set(pd.read_csv(out).columns)
    assert "std" not in columns and "mean" not in columns, columns
    if table and command != "linearize":  # linearize's CSV is its budget
        assert {"value", "u", "low", "high", "coverage", "determinable", "reason"} <= columns
    if command == "sweep":
        assert {"value", "u", "low", "high"} <= columns


def test_the_result_of_estimate_measured_is_what_estimate_prints(capsys):
    """The library's result carries the file's notes and set-up provenance: the command
    only prints it."""
    from mtplan.evaluation.measured import estimate_measured, read_measurement

    doc = _json(capsys, ["estimate", "circle_centre", READINGS, "--trials", "60"])
    measurement = read_measurement("circle_centre", READINGS, {})
    result = estimate_measured("circle_centre", None, measurement, trials=60, rng=0)
    assert json.loads(json.dumps(result.to_dict())) == doc
    assert doc["notes"][: len(measurement.notes)] == measurement.notes
    assert "setup_from_file" in doc and doc["setup_defaults"]


def _computed_once(monkeypatch, module, name):
    """`module.name` (the library call behind a command) computes once for the same arguments:
    a second run of the command in this test prints the first run's result (the command reads
    the function from its module when it runs). The JSON and the table of one command then
    show the same result, and geometry21's seconds-long evaluation is not repeated."""
    import importlib
    import pickle

    mod = importlib.import_module(module)
    function, seen = getattr(mod, name), {}

    def once(*args, **kwargs):
        key = pickle.dumps((args, kwargs))
        if key not in seen:
            seen[key] = function(*args, **kwargs)
        return seen[key]

    monkeypatch.setattr(mod, name, once)


@pytest.mark.parametrize("argv, module, function", [
    (["simulate", "geometry21", "--trials", "20"], "mtplan.evaluation.simulation",
     "simulate_uncertainty"),
    (["linearize", "geometry21"], "mtplan.evaluation.simulation", "linearize_result"),
    (["estimate", "geometry21", G21, "--trials", "20"], "mtplan.evaluation.measured",
     "estimate_measured")], ids=["simulate", "linearize", "estimate"])
def test_geometry21_lists_the_six_blind_errors_with_their_reason(capsys, monkeypatch, argv,
                                                                 module, function):
    _computed_once(monkeypatch, module, function)
    doc = _json(capsys, argv)
    blind = {m["name"]: m for m in doc["measurands"] if not m["determinable"]}
    assert set(blind) == {"EAX", "EBY", "ECY", "EAZ", "EBZ", "ECZ"}
    for m in blind.values():
        assert m["u"] is None and m["value"] is None and m["unit"] == "urad"
        assert "not determinable at this set-up" in m["reason"]
    assert len(doc["measurands"]) == 21
    code = main(argv)  # the table says it too
    out = capsys.readouterr().out
    assert code == 0 and out.count("not determinable at this set-up") == 6


def _mtplan():
    return [sys.executable, "-c", "import sys; from mtplan.cli import main; sys.exit(main())"]


def test_a_closed_pipe_ends_quietly():
    """The reader leaves before the JSON is written (| head -1 on a long document)."""
    proc = subprocess.Popen([*_mtplan(), "estimate", "circle_centre", READINGS, "--trials",
                             "60", "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # nobody reads: the first write meets a closed pipe
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == EXIT_PIPE
    assert err == "", err
    shell = subprocess.run(
        f"{' '.join(_mtplan()[:2])} {json.dumps(_mtplan()[2])} simulate geometry21 --trials 20 "
        "--json | head -1", shell=True, capture_output=True, text=True, timeout=120)
    assert shell.stdout == "{\n" and "Traceback" not in shell.stderr, shell.stderr


def test_readings_out_with_one_trial(capsys, tmp_path):
    out = tmp_path / "one.csv"
    assert main(["simulate", "circle_centre", "--trials", "1", "--seed", "4",
                 "--readings-out", str(out)]) == 0
    assert "wrote one simulated circle_centre measurement" in capsys.readouterr().err
    assert main(["estimate", "circle_centre", str(out), "--trials", "60"]) == 0
    assert main(["simulate", "circle_centre", "--trials", "1"]) == 2  # nothing to show
