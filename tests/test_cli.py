"""The command line: contract of --json, one-line errors with exit status 2, start-up."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from mtplan import cli
from mtplan.models import registry

PROCS = list(registry())


def run(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_help_and_version(capsys):
    code, out, _ = run(capsys)
    assert code == 0 and "simulate" in out
    with pytest.raises(SystemExit) as exc:
        cli.main(["--version"])
    assert exc.value.code == 0


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["simulate", "no_such_procedure"], "no_such_procedure"),
        (["frobnicate"], "frobnicate"),
        (["simulate"], "procedure"),
        (["simulate", "X", "--trials", "many"], "many"),
        (["sweep", "X", "--vary", "novalue"], None),
    ],
)
def test_usage_errors_are_one_line_with_status_2(capsys, argv, needle):
    code, out, err = run(capsys, *argv)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("mtplan: error:")
    if needle:
        assert needle in lines[0]
    assert "Traceback" not in err


@pytest.mark.parametrize("proc", PROCS)
def test_simulate_json_contract(capsys, proc):
    code, out, err = run(capsys, "simulate", proc, "--json", "--trials", "200", "--seed", "3")
    assert code == 0, err
    doc = json.loads(out)
    assert set(doc) == {"procedure", "estimator", "setup", "seed", "trials", "sources",
                        "interval_kind", "duration_s", "measurands", "notes",
                        "covariance"}
    assert doc["procedure"] == proc and doc["seed"] == 3 and doc["trials"] == 200
    for m in doc["measurands"]:
        assert set(m) == {"name", "unit", "value", "u", "interval", "coverage", "U",
                          "U_coverage", "U_coverage_se", "U_coverage_from", "determinable",
                          "reason", "true", "bias"}
        assert len(m["interval"]) == 2 and m["coverage"] == 0.95
        if m["determinable"]:  # U = 2u with the fraction of the values within +-U and its
            # standard error, at most a plain count's of the 200 trials (coverage_within)
            assert m["U"] == 2 * m["u"] and m["U_coverage_from"] == "monte carlo"
            assert 0 <= m["U_coverage"] <= 1
            assert 0 < m["U_coverage_se"] <= 0.5 / 200**0.5
    cov = doc["covariance"]
    assert cov["names"] == [m["name"] for m in doc["measurands"] if m["determinable"]]
    assert cov["units"] == [m["unit"] for m in doc["measurands"] if m["determinable"]]


def test_simulate_json_covariance_is_the_trials_covariance(capsys):
    """`simulate --json` carries the covariance of the Monte Carlo estimates in the display
    units: the sample covariance of the trials' values (computed here from the kept values,
    independently of the engine's block-wise merge), its diagonal the u^2 of the table."""
    import numpy as np

    from mtplan.evaluation import simulate_uncertainty

    code, out, err = run(capsys, "simulate", "rotary_axis", "--json", "--trials", "1500",
                         "--seed", "4")
    assert code == 0, err
    doc = json.loads(out)
    c = np.array(doc["covariance"]["matrix"])
    assert doc["covariance"]["units"] == ["um", "um", "urad", "urad"]
    assert np.diag(c) == pytest.approx([m["u"] ** 2 for m in doc["measurands"]], rel=1e-12)
    r = simulate_uncertainty("rotary_axis", trials=1500, rng=4, progress=False)
    values = np.vstack([r.mc.samples(n) for n in doc["covariance"]["names"]])
    assert c == pytest.approx(np.cov(values, ddof=1), rel=1e-9, abs=1e-12)
    assert np.all(np.linalg.eigvalsh(c) > 0)


@pytest.mark.parametrize("proc", PROCS)
def test_bad_set_values_are_listed_together(capsys, proc):
    code, _, err = run(capsys, "simulate", proc, "--set", "no_such_field=1",
                       "--set", "also_missing=2", "--trials", "100")
    assert code == 2
    assert "no_such_field" in err and "also_missing" in err
    assert len(err.strip().splitlines()) == 1


def test_missing_config_file(capsys):
    code, _, err = run(capsys, "simulate", PROCS[0], "--config", "/no/such/file.toml")
    assert code == 2 and "/no/such/file.toml" in err


def test_config_file_and_set_override(capsys, tmp_path):
    proc = registry()[PROCS[0]]
    noise_field = next(f for f in proc.Setup().as_dict() if f.endswith("noise_um"))
    cfg = tmp_path / "setup.toml"
    cfg.write_text(f'procedure = "{PROCS[0]}"\nseed = 4\n[setup]\n{noise_field} = 0.25\n')
    code, out, err = run(capsys, "simulate", PROCS[0], "--config", str(cfg), "--json",
                         "--trials", "100")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["setup"][noise_field] == 0.25 and doc["seed"] == 4
    code, out, _ = run(capsys, "simulate", PROCS[0], "--config", str(cfg), "--json",
                       "--trials", "100", "--set", f"{noise_field}=0.5")
    assert json.loads(out)["setup"][noise_field] == 0.5
    bad = tmp_path / "bad.toml"
    bad.write_text("this is = = not toml")
    code, _, err = run(capsys, "simulate", PROCS[0], "--config", str(bad))
    assert code == 2 and "TOML" in err


def test_linearize_and_sweep_commands(capsys, tmp_path):
    proc = PROCS[0]
    code, out, err = run(capsys, "linearize", proc, "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert all("budget" in m for m in doc["measurands"])
    field = next(f for f in registry()[proc].Setup().as_dict() if f.endswith("noise_um"))
    out_file = tmp_path / "sweep.csv"
    code, out, err = run(capsys, "sweep", proc, "--vary", f"{field}=0.5,1", "--trials", "100",
                         "--out", str(out_file))
    assert code == 0, err
    assert out_file.exists()
    code, _, err = run(capsys, "sweep", proc, "--trials", "100")
    assert code == 2 and "--vary" in err


def test_procedures_listing(capsys):
    code, out, _ = run(capsys, "procedures", "--json")
    assert code == 0
    assert [d["name"] for d in json.loads(out)] == PROCS


def test_console_script_starts_without_heavy_imports():
    code = ("import sys, mtplan.cli as c; c.build_parser(); "
            "heavy = [m for m in ('numpy', 'pandas', 'scipy', 'matplotlib') if m in sys.modules]; "
            "print(','.join(heavy))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
