"""Property-based fuzz of the command line: random field names and values, random TOML and
CSV content, for every command. Whatever comes in, ``mtplan`` exits 0, or 2 with one line
on stderr; never a traceback, and a failed command leaves no file behind.

Runs in-process through ``cli.main(argv)`` (an exception escaping ``main`` is a traceback a
user would see) with tiny trial counts and a fixed hypothesis seed, plus a few subprocess
checks of the installed entry point.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import pytest

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mtplan import cli
from mtplan.models import registry
from mtplan.models.protocol import fields_info  # noqa: E402

PROCS = sorted(registry())
FIELDS = sorted({i.name for p in registry().values() for i in fields_info(p.Setup)})
FAST_PROC = "circle_centre"  # the one whose successful runs take milliseconds
#: examples per command (derandomized by tests/conftest.py's profile); for a deeper hunt:
#: MTPLAN_FUZZ_EXAMPLES=300 HYPOTHESIS_PROFILE=explore
SETTINGS = settings(max_examples=int(os.environ.get("MTPLAN_FUZZ_EXAMPLES", 30)), deadline=None,
                    suppress_health_check=list(HealthCheck))

# --------------------------------------------------------------------------- strategies
text = st.text(alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"),
               max_size=12)
number = st.one_of(st.integers(-10**13, 10**13).map(str),
                   st.floats(allow_nan=True, allow_infinity=True).map(repr),
                   st.sampled_from(["", " ", "nan", "inf", "-0", "1e400", "3", "6", "0.5"]))
value = st.one_of(number, text, st.lists(number, max_size=4).map(",".join))
field = st.one_of(st.sampled_from(FIELDS), text)
#: values a user would plausibly give the fast procedure's fields (most runs then go deep)
CIRCLE_FIELDS = [i.name for i in fields_info(registry()[FAST_PROC].Setup)]
plausible = st.one_of(st.integers(0, 12).map(str), st.floats(0, 400).map(lambda v: f"{v:.3g}"))
pair = st.one_of(st.tuples(st.sampled_from(CIRCLE_FIELDS), plausible),
                 st.tuples(st.sampled_from(CIRCLE_FIELDS), plausible),
                 st.tuples(field, value)).map(lambda kv: f"{kv[0]}={kv[1]}")
pair_ok = st.tuples(st.sampled_from(["n_points", "probe_noise_um", "roundness_um",
                                     "spread_deg", "lobes"]),
                    st.integers(3, 9).map(str)).map(lambda kv: f"{kv[0]}={kv[1]}")
vary_ok = st.tuples(st.sampled_from(["n_points", "probe_noise_um", "spread_deg"]),
                    st.lists(st.integers(3, 9).map(str), min_size=1, max_size=3).map(",".join)
                    ).map(lambda kv: f"{kv[0]}={kv[1]}")
vary = st.one_of(st.tuples(st.sampled_from(["n_points", "probe_noise_um", "spread_deg"]),
                           st.lists(plausible, min_size=1, max_size=3).map(",".join)),
                 st.tuples(field, value)).map(lambda kv: f"{kv[0]}={kv[1]}")
count_ok = st.integers(2, 30).map(str)
proc = st.one_of(st.just(FAST_PROC), st.just(FAST_PROC), st.sampled_from(PROCS),
                 text.filter(lambda s: s.strip()))
small_count = st.one_of(st.integers(2, 30), st.integers(2, 30), st.integers(-3, 1),
                        st.sampled_from([10**12, 10**9 + 1])).map(str)
sources = st.one_of(st.none(), st.none(), text,
                    st.lists(st.sampled_from(["probe_noise", "roundness", "start_scatter",
                                              "nope"]), max_size=3).map(",".join))
toml_value = st.one_of(st.integers(-10**6, 10**6), st.floats(allow_nan=False), text,
                       st.lists(st.integers(-100, 400), max_size=4), st.booleans())
toml_table = st.dictionaries(field, toml_value, max_size=4)


def _toml(doc: dict) -> str:
    def show(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
        if isinstance(v, list):
            return "[" + ", ".join(show(x) for x in v) + "]"
        if isinstance(v, float) and v != v:
            return "nan"
        return repr(v) if not isinstance(v, float) else f"{v!r}".replace("inf", "inf")

    top = [f'"{k}" = {show(v)}' for k, v in doc.items() if not isinstance(v, dict)]
    tables = [f'["{k}"]\n' + "\n".join(f'"{a}" = {show(b)}' for a, b in v.items())
              for k, v in doc.items() if isinstance(v, dict)]
    return "\n".join(top + tables) + "\n"


config_doc = st.dictionaries(
    st.one_of(st.sampled_from(["setup", "truth", "vary", "trials", "seed", "sources",
                               "procedure", "estimator", "set-up", "digits"]), text),
    st.one_of(toml_value, toml_table), max_size=4)
config_file = st.one_of(config_doc.map(_toml), text, st.binary(max_size=40))

csv_cell = st.one_of(number, st.floats(-300, 300, allow_nan=False).map(repr), text)
csv_header = st.lists(st.one_of(st.sampled_from(["x_mm", "y_mm", "point", "x", "y", "z_mm",
                                                 "axis", "position", "angle_deg"]), text),
                      min_size=1, max_size=4)


@st.composite
def bore_points(draw):
    """Points on a bore, bare or labelled, sometimes with one cell spoiled."""
    import math

    n = draw(st.one_of(st.integers(3, 10), st.integers(3, 10), st.integers(0, 2)))
    r = draw(st.floats(0.5, 500))
    noise = draw(st.floats(0, 0.2)) * r
    phi = sorted(draw(st.lists(st.integers(0, 359), min_size=n, max_size=n, unique=True)))
    phi = [math.radians(a + draw(st.floats(0, 0.9))) for a in phi]
    cx, cy = draw(st.floats(-50, 50)), draw(st.floats(-50, 50))
    rows = [[f"{cx + (r + noise * math.sin(7 * k)) * math.cos(a):.9g}",
             f"{cy + (r + noise * math.sin(7 * k)) * math.sin(a):.9g}"]
            for k, a in enumerate(phi)]
    header = draw(st.sampled_from([["x_mm", "y_mm"], ["x", "y"], ["point", "x_mm", "y_mm"]]))
    if header[0] == "point":
        rows += rows[:2]  # p1 and p2 probe the wall too
        labels = [f"d{k + 1}" for k in range(n)] + ["p1", "p2"]
        rows = [[lab, *row] for lab, row in zip(labels, rows, strict=False)]
    if rows and draw(st.booleans()):
        i, j = draw(st.integers(0, len(rows) - 1)), draw(st.integers(0, len(header) - 1))
        rows[i][j] = draw(csv_cell)
    return "\n".join([",".join(header)] + [",".join(r) for r in rows]).encode(
        "utf-8", "surrogatepass")


@st.composite
def csv_file(draw):
    header = draw(csv_header)
    n = draw(st.integers(0, 8))
    rows = [[draw(csv_cell) for _ in range(draw(st.sampled_from([len(header), len(header),
                                                                  len(header) + 1])))]
            for _ in range(n)]
    if draw(st.booleans()):
        return draw(st.binary(max_size=60))
    lines = [",".join(header)] + [",".join(r) for r in rows]
    return "\n".join(lines).encode("utf-8", "surrogatepass")


# --------------------------------------------------------------------------- the property
def _check(argv, files=None):
    """Run `argv` in a fresh folder holding `files`; the outcome must be 0, or 2 with one
    line, and a failure must leave only the input files there."""
    import io
    from contextlib import redirect_stderr, redirect_stdout

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name, content in (files or {}).items():
            (tmp / name).write_bytes(content if isinstance(content, bytes) else content.encode())
        argv = [str(a).replace("{tmp}", str(tmp)) for a in argv]
        out, err = io.StringIO(), io.StringIO()
        with redirect_stdout(out), redirect_stderr(err), warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            warnings.filterwarnings("error", category=RuntimeWarning, module="mtplan")
            try:
                code = cli.main(argv)
            except SystemExit as exc:  # --help / --version only
                code = exc.code
        err = err.getvalue()
        # a warning is one more line on stderr: a refusal must come alone
        assert code != 2 or not w, (argv, [str(x.message) for x in w])
        assert "Traceback" not in err, (argv, err)
        assert code in (0, 2), (argv, code, err)
        if code == 2:
            lines = err.strip().splitlines()
            assert len(lines) == 1 and lines[0].startswith("mtplan: error:"), (argv, err)
            left = sorted(p.name for p in tmp.iterdir())
            assert left == sorted(files or {}), (argv, left)


class _Draw:
    """Each part of a command line drawn plausible, except the parts chosen to be wild (at
    most two per example: one fault at a time mostly, so that runs also go deep)."""

    def __init__(self, data, parts):
        self.data = data
        self.wild = data.draw(st.sets(st.sampled_from(parts), max_size=2), label="wild")

    def __call__(self, part, plausible, wild):
        return self.data.draw(wild if part in self.wild else plausible, label=part)


def _pairs(draw, part, n):
    return draw(part, st.lists(pair_ok, max_size=n), st.lists(pair, min_size=1, max_size=n))


@SETTINGS
@given(data=st.data(), command=st.sampled_from(["simulate", "linearize"]))
def test_simulate_and_linearize(data, command):
    draw = _Draw(data, ["proc", "set", "truth", "trials", "sources", "config"])
    # the GUM of the large procedures takes 3-30 s (their own tests cover it): linearize
    # fuzzes the fast one and unknown names
    wild_proc = proc if command == "simulate" else st.one_of(st.just(FAST_PROC), text)
    argv = [command, draw("proc", st.just(FAST_PROC), wild_proc), "--out", "{tmp}/out.csv"]
    argv += [a for s in _pairs(draw, "set", 3) for a in ("--set", s)]
    argv += [a for s in draw("truth", st.just([]), st.lists(pair, max_size=1))
             for a in ("--truth", s)]
    if command == "simulate":
        argv += ["--trials", draw("trials", count_ok, small_count), "--readings-out",
                 "{tmp}/r.csv"]
    src = draw("sources", st.none(), sources)
    if src is not None:
        argv += ["--sources", src]
    files = {}
    cfg = draw("config", st.none(), config_file)
    if cfg is not None:
        files["c.toml"] = cfg
        argv += ["--config", "{tmp}/c.toml"]
    _check(argv, files)


@SETTINGS
@given(data=st.data(), command=st.sampled_from(["sweep", "sweep", "plan"]))
def test_sweep_and_plan(data, command):
    draw = _Draw(data, ["set", "vary", "trials", "target"])
    trials = draw("trials", count_ok, small_count)
    if command == "plan" and "trials" not in draw.wild:
        trials = "100"  # the planner's least
    argv = [command, FAST_PROC, "--trials", trials, "--out", "{tmp}/s.csv"]
    argv += [a for s in _pairs(draw, "set", 2) for a in ("--set", s)]
    argv += [a for s in draw("vary", st.lists(vary_ok, min_size=1, max_size=2),
                             st.lists(vary, max_size=2)) for a in ("--vary", s)]
    if command == "plan":
        argv += ["--target", draw("target", st.just("centre_x<=5"), value)]
    _check(argv)


@SETTINGS
@given(data=st.data(), method=st.sampled_from(["mc", "mc", "posterior"]))
def test_estimate(data, method):
    draw = _Draw(data, ["proc", "file", "set", "trials"])
    argv = ["estimate", draw("proc", st.just(FAST_PROC), proc), "{tmp}/r.csv", "--trials",
            draw("trials", count_ok, small_count), "--uncertainty", method, "--max-steps", "60",
            "--allow-unconverged", "--out", "{tmp}/e.csv"]
    argv += [a for s in draw("set", st.just([]), st.lists(pair, max_size=2)) for a in ("--set", s)]
    _check(argv, {"r.csv": draw("file", bore_points(), csv_file())})


@SETTINGS
@given(data=st.data())
def test_accept(data):
    draw = _Draw(data, ["lower", "upper", "u", "measured", "prior", "rule"])
    sane = {"lower": st.floats(-20, 0).map(repr), "upper": st.floats(1, 20).map(repr),
            "u": st.floats(0.01, 5).map(repr), "measured": st.floats(-20, 20).map(repr)}
    argv = ["accept", "--rule", draw("rule", st.sampled_from(["simple", "guard:0.5",
                                                               "target-pfa:0.01", "iso14253"]),
                                     text)]
    for opt, ok in sane.items():
        v = draw(opt, ok, st.one_of(st.none(), number))
        if v is not None:
            argv += [f"--{opt}", v]
    prior = draw("prior", st.sampled_from(["normal:0,3", "{tmp}/prior.csv"]),
                 st.one_of(text, st.just("{tmp}/prior.csv")))
    values = "value\n" + "\n".join(f"{v:.4g}" for v in data.draw(
        st.lists(st.floats(-10, 10), min_size=2, max_size=20), label="values"))
    argv += ["--prior", prior]
    _check(argv, {"prior.csv": draw("prior", st.just(values.encode()), csv_file())})


@SETTINGS
@given(study=config_file, name=st.one_of(st.none(), proc))
def test_report_and_procedures(study, name):
    _check(["report", "{tmp}/study.toml", "--out", "{tmp}/study.toml"], {"study.toml": study})
    _check(["report", "{tmp}/study.toml", "--out", "{tmp}/rep"], {"study.toml": study})
    _check(["procedures"] + ([name] if name is not None else []) + ["--json"])


@pytest.mark.parametrize("argv", [
    ["simulate", "circle_centre", "--set", "n_points="],
    ["estimate", "circle_centre", "/no/such/file.csv"],
    ["simulate", "circle_centre", "--trials", "1000000000000"],
])
def test_the_installed_command_prints_one_line(argv):
    done = subprocess.run([sys.executable, "-m", "mtplan.cli", *argv], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 2 and done.stdout == ""
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("mtplan: error:"), done.stderr
