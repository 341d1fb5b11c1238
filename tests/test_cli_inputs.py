"""Every input checked before work starts: one line, exit status 2, nothing written.

One test per case of issue 15 (the property-based fuzz is ``test_cli_fuzz.py``).
"""

from __future__ import annotations

import json
import os
import socket
import time

import pytest

from mtplan import cli
from mtplan._validate import InvalidInput

FAST = ("--trials", "100")


def run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def refused(capsys, *argv, needle=()):
    """Run, and check: exit 2, one line on stderr, nothing on stdout, every needle in it."""
    code, out, err = run(capsys, *argv)
    lines = err.strip().splitlines()
    assert code == 2, (code, err)
    assert len(lines) == 1 and lines[0].startswith("mtplan: error:") and out == "", err
    for n in (needle,) if isinstance(needle, str) else needle:
        assert n in lines[0], (n, lines[0])
    return lines[0]


# --------------------------------------------------------------------------- config files
@pytest.mark.parametrize("text, needle", [
    ("trials = 100\n[set-up]\nn_points = 4\n", ("'set-up'", "[setup]", "[truth]")),
    ("setup = 3\n", ("setup", "table")),
    ("[setup]\nn_points = \"\"\n", "n_points no value"),
    ("trials = \"many\"\n", ("trials", "integer")),
    ("sources = [1, 2]\n", "sources"),
    ("this is = = not toml", "not valid TOML"),
])
def test_bad_config_files_are_refused_naming_the_file(tmp_path, capsys, text, needle):
    cfg = tmp_path / "c.toml"
    cfg.write_text(text)
    refused(capsys, "simulate", "circle_centre", "--config", cfg, *FAST,
            needle=(str(cfg), *((needle,) if isinstance(needle, str) else needle)))


@pytest.mark.parametrize("content", [b"\xff\xfe\x00\x01binary", "n = 'é'".encode("latin-1")])
def test_binary_or_non_utf8_config_is_refused(tmp_path, capsys, content):
    cfg = tmp_path / "c.toml"
    cfg.write_bytes(content)
    refused(capsys, "simulate", "circle_centre", "--config", cfg, needle=(str(cfg), "UTF-8"))


def test_a_folder_as_config_is_refused(tmp_path, capsys):
    refused(capsys, "simulate", "circle_centre", "--config", tmp_path, needle="folder")


# --------------------------------------------------------------------------- options
@pytest.mark.parametrize("argv, needle", [
    (("--set", "n_points="), "n_points no value"),
    (("--set", "=4"), "FIELD=VALUE"),
    (("--sources", ""), "no error source"),
    (("--sources", " , "), "no error source"),
    (("--trials", "0"), "trials"),
    (("--trials", "-5"), "trials"),
    (("--jobs", "0"), "--jobs"),
    (("--digits", "0"), "digits"),
    (("--trials", "1000000000000"), ("trials", "1e+09")),
    (("--scheduler", "tcp://127.0.0.1:1"), "backend='dask'"),
])
def test_empty_zero_and_unbounded_options_are_refused(capsys, argv, needle):
    refused(capsys, "simulate", "circle_centre", *argv, needle=needle)


# --------------------------------------------------------------------------- counts
#: the integer options that count nothing, so that zero or a negative value can be right
NOT_COUNTS = {"--seed": "a random seed: any integer", "--port": "a port, checked by explore"}


def _int_options():
    """(command, option, its argparse type) for every integer-valued option of every command,
    read from the parsers."""
    import argparse

    from mtplan.cli import build_parser
    from mtplan.cli._common import count, workers

    commands = next(a for a in build_parser()._actions
                    if isinstance(a, argparse._SubParsersAction)).choices
    found = [(name, action.option_strings[-1], action.type)
             for name, parser in commands.items() for action in parser._actions
             if action.type in (int, count, workers)]
    assert {o for _, o, _ in found} >= {"--jobs", "--trials"}, found  # the parsers were read
    return found


def test_every_integer_option_is_a_count_or_says_why_not():
    """A new integer option takes the count type (refused at zero while the command line is
    read) unless it is listed above with the reason it is not a count."""
    plain = {o for _, o, kind in _int_options() if kind is int}
    assert plain <= set(NOT_COUNTS), plain - set(NOT_COUNTS)


COUNTS = [(c, o, v) for c, o, kind in _int_options() if kind is not int
          for v in (("0", "-1") if kind.__name__ == "count" else ("0",))]


@pytest.mark.parametrize("command, option, value", COUNTS,
                         ids=[f"{c} {o} {v}" for c, o, v in COUNTS])
def test_every_count_of_zero_or_less_is_refused_before_work_starts(capsys, command, option,
                                                                   value):
    """Every command, every count option: exit 2, one line naming the option, nothing run
    (the demo's --jobs 0 too, which would otherwise start the study)."""
    start = time.monotonic()
    refused(capsys, command, option, value, needle=(f"argument {option}", repr(value)))
    assert time.monotonic() - start < 5


@pytest.mark.parametrize("argv", [("report", "examples/demo.toml", "--out", "D"), ("demo",)])
def test_jobs_zero_is_refused_with_a_study_that_would_run(tmp_path, capsys, argv):
    """The case the issue found: a valid study and output, --jobs 0: no pool's traceback."""
    argv = [str(tmp_path / a) if a == "D" else a for a in argv]
    refused(capsys, *argv, "--jobs", "0", needle="--jobs")
    assert list(tmp_path.iterdir()) == []


def test_minus_one_job_still_means_every_core():
    from mtplan.cli import build_parser

    args = build_parser().parse_args(["report", "examples/demo.toml", "--out", "D", "--jobs",
                                      "-1"])
    assert args.jobs == -1


@pytest.mark.parametrize("argv, needle", [
    (("--trials", "0"), "trials"),
    (("--confirm", "0"), "confirm"),
    (("--k", "-1"), "'k'"),
])
def test_plan_counts_are_refused_not_replaced(capsys, argv, needle):
    refused(capsys, "plan", "circle_centre", "--vary", "n_points=3,4", "--target",
            "centre_x<=5", *argv, needle=needle)


def test_an_empty_source_list_is_refused_by_the_library():
    from mtplan.evaluation import simulate_uncertainty

    with pytest.raises(InvalidInput, match="at least one"):
        simulate_uncertainty("circle_centre", sources=[], trials=100)


def test_an_unreachable_scheduler_is_refused_within_seconds(capsys):
    import distributed  # noqa: F401 - the test extras hold it: missing is a failure, not a skip
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    start = time.monotonic()
    refused(capsys, "simulate", "circle_centre", *FAST, "--backend", "dask", "--scheduler",
            f"tcp://127.0.0.1:{port}", needle="cannot be reached")
    assert time.monotonic() - start < 10
    refused(capsys, "simulate", "circle_centre", *FAST, "--backend", "dask", "--scheduler",
            "no-port", needle="scheduler")


def test_a_run_predicted_to_exceed_memory_is_refused_with_the_estimate(capsys, monkeypatch):
    from mtplan.evaluation import simulation

    monkeypatch.setattr(simulation, "_available_memory", lambda: 20_000_000)
    line = refused(capsys, "simulate", "line_laser", *FAST, needle=("GB of memory",
                                                                     "available"))
    assert "MB per trial" in line
    monkeypatch.setattr(simulation, "_available_memory", lambda: 10**12)
    code, _, err = run(capsys, "simulate", "circle_centre", *FAST)
    assert code == 0, err


def test_a_prior_file_with_nan_or_text_is_refused_naming_the_row(tmp_path, capsys):
    for bad, row in (("nan", 3), ("abc", 3), ("inf", 3)):
        prior = tmp_path / f"prior_{bad}.csv"
        prior.write_text(f"value\n9.5\n{bad}\n9.7\n")
        refused(capsys, "accept", "--lower", 9, "--upper", 10, "--u", 0.1, "--prior", prior,
                needle=(str(prior), f"row {row}", repr(bad)))
    good = tmp_path / "prior.csv"
    good.write_text("value\n9.5\n\n9.7\n9.6\n")  # an empty cell is dropped
    code, _, err = run(capsys, "accept", "--lower", 9, "--upper", 10, "--u", 0.1, "--prior", good)
    assert code == 0, err


# --------------------------------------------------------------------------- outputs
def test_outputs_are_checked_before_any_work(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    readings = tmp_path / "readings.csv"
    # --out under a file: refused before computing; --readings-out not written
    refused(capsys, "simulate", "circle_centre", *FAST, "--out", blocker / "o.csv",
            "--readings-out", readings, needle="--out")
    assert not readings.exists()
    refused(capsys, "simulate", "circle_centre", *FAST, "--out", tmp_path, needle="folder")
    refused(capsys, "simulate", "circle_centre", *FAST, "--out", tmp_path / "a.csv",
            "--readings-out", tmp_path / "a.csv", needle="same file")
    refused(capsys, "linearize", "circle_centre", "--out", blocker / "o.csv", needle="--out")
    refused(capsys, "sweep", "circle_centre", "--vary", "n_points=3,4", *FAST, "--out",
            blocker / "s.csv", needle="'out'")
    refused(capsys, "estimate", "circle_centre", tmp_path / "nope.csv", "--out",
            blocker / "e.csv", needle="--out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_report_out_naming_an_existing_file_is_refused_at_once(tmp_path, capsys):
    target = tmp_path / "report.html"
    target.write_text("x")
    start = time.monotonic()
    refused(capsys, "report", "examples/demo.toml", "--out", target, needle="existing file")
    assert time.monotonic() - start < 5  # before the study is computed
    assert target.read_text() == "x"


def test_ctrl_c_leaves_nothing_half_written(tmp_path, capsys, monkeypatch):
    def interrupt(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "fsync", interrupt)  # while the output is being written
    out = tmp_path / "table.csv"
    code, _, err = run(capsys, "simulate", "circle_centre", *FAST, "--out", out)
    assert code == 130 and "interrupted" in err
    assert list(tmp_path.iterdir()) == []


def test_progress_is_shown_on_a_terminal(monkeypatch):
    from mtplan.uncertainty import montecarlo

    monkeypatch.setattr("sys.stderr.isatty", lambda: True, raising=False)
    bar = montecarlo._progress(None, 10**6, "x")
    assert bar is not None and not bar.disable
    bar.close()


# --------------------------------------------------------------------------- sweeps
def test_a_removed_sweep_output_starts_a_new_sweep(tmp_path, capsys):
    out = tmp_path / "s.csv"
    argv = ("sweep", "circle_centre", "--vary", "n_points=3,4", *FAST, "--out", out)
    code, _, err = run(capsys, *argv)
    assert code == 0, err
    side = tmp_path / "s.csv.sweep.json"
    assert side.exists()
    out.unlink()
    code, _, err = run(capsys, *argv[:-2], "--set", "probe_noise_um=2", "--out", out)
    assert code == 0, err
    assert "replaced" in err and out.exists()
    assert json.loads(side.read_text())["base_setup"]["probe_noise_um"] == 2.0
    side.write_text("{not json")  # a side file spoiled beside a live output: refused
    refused(capsys, *argv, needle="different sweep")
