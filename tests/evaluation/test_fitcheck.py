"""The fit check (chi-square of the whitened residuals and the largest w) on every procedure.

Per procedure, on a small set-up: clean simulated readings pass at the default alpha,
0.05 (a seed range, not one seed: at most one of three replicates may be flagged,
probability 0.007 when the check is right); one reading moved by 30 times its own scatter is flagged
and is the worst reading named; readings perturbed by effects outside the model (the
readings' own scatter three times larger, a harmonic along the readings that no source
has) are flagged. The p-values' uniformity over many replicates is the benchmark
``benchmarks/bench_fitcheck.py``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import mtplan
from mtplan.cli import main
from mtplan.evaluation.fitcheck import FIT_ALPHA, fit_check, reading_vector, with_reading_vector
from mtplan.evaluation.measured import estimate_measured
from mtplan.evaluation.readings import reading_origin
from mtplan.models import get, registry

EXAMPLES = Path(mtplan.__file__).parent / "examples"
ALPHA = FIT_ALPHA
#: small set-ups: the check's statistics do not depend on the number of readings
SETUPS = {"geometry21": {"line_repeats": 1, "line_points": 7, "circle_points": 12},
          "line_laser": {"lines": 16, "points_per_line": 9},
          "tracker_frame": {"n_submachines": 1, "points_per_axis": 5, "points_per_arc": 4}}


def _setup(name):
    proc = get(name)
    return proc, proc.Setup(**SETUPS.get(name, {}))


@pytest.fixture(scope="module")
def clean():
    cache = {}

    def get_clean(name):
        if name not in cache:
            proc, setup = _setup(name)
            readings = proc.simulate(setup, proc.Truth(), 1, rng=7)
            cache[name] = (proc, setup, readings, fit_check(proc, setup, readings))
        return cache[name]

    return get_clean


NAMES = sorted(registry())


@pytest.mark.parametrize("name", NAMES)
def test_clean_readings_pass(clean, name):
    proc, setup, _, fc = clean(name)
    flagged = [fc.ok is False]
    for seed in (8, 9):
        readings = proc.simulate(setup, proc.Truth(), 1, rng=seed)
        flagged.append(fit_check(proc, setup, readings).ok is False)
    assert fc.ok is not None and fc.dof > 0, fc.reason
    assert sum(flagged) <= 1, (name, fc.summary())
    assert 0 <= fc.p_value <= 1 and fc.chi2 > 0
    assert fc.n_readings - fc.dof <= fc.n_parameters


@pytest.mark.parametrize("name", NAMES)
def test_one_reading_off_by_30_times_its_scatter_is_flagged_and_named(clean, name):
    proc, setup, readings, fc = clean(name)
    keys, y = reading_vector(readings)
    assert y.size == fc.n_readings
    # a reading that the fit leaves residual freedom (finite z), in the middle of the file
    candidates = np.flatnonzero(np.isfinite(fc.z))
    i = int(candidates[candidates.size // 2])
    y = y.copy()
    y[i] += 30 * fc.scatter[i]
    moved = with_reading_vector(readings, keys, y)
    out = fit_check(proc, setup, moved)
    assert out.ok is False, out.summary()
    origin = reading_origin(proc, setup, readings)
    rows = np.concatenate([np.asarray(origin[k][0]).reshape(-1) for k in keys])
    assert out.worst[0]["row"] == rows[i], (out.worst, rows[i])
    # geometry21's model lets every reading of a circle have its own 0.3 um of repeatable
    # path deviation (path_residual, which the line repeats share but a circle point does
    # not), so 30 times its 0.05 um encoder scatter is about 8 of its w-test's sigmas
    assert abs(out.worst[0]["z"]) > (6 if name == "geometry21" else 10)
    assert "do not fit" in out.warning() and f"row {rows[i]}" in out.warning()


def _three_times_noise(fc, y, rng):
    return y + np.sqrt(9 - 1) * fc.scatter * rng.standard_normal(y.size)


def _harmonic_size(setup, fc):
    """The harmonic's amplitude: 3 times a reading's own random scatter.

    That is ``fc.scatter`` (what touches the reading alone) except for geometry21, whose
    repeatability is correlated along each pass (AR(1)): its elements then touch several
    readings, so its 0.3 um no longer counts in ``fc.scatter`` (0.05 um, the encoder
    noise alone). A harmonic of 3 x 0.05 = 0.15 um (5.3 periods over the readings, smooth
    along every pass) is genuinely inside that model's stated noise: on the small set-up
    it raises the chi-square by about 10 on 279 degrees of freedom (p = 0.36-0.39 at two
    phases), a path deviation the repeatability states. Outside the model is the size the
    test had with independent readings: 3 x sqrt(0.3^2 + 0.05^2) = 0.91 um raises it by
    about 400 (p < 1e-33)."""
    if getattr(setup, "repeatability_correlation_mm", 0) > 0:
        return 1e-3 * np.hypot(setup.repeatability_um, setup.encoder_noise_um)
    return np.median(fc.scatter)


def _harmonic(fc, y, rng, setup=None):
    j = np.arange(y.size)
    size = 3 * _harmonic_size(setup, fc)
    return y + size * np.sin(2 * np.pi * 5.3 * j / y.size + rng.random())


@pytest.mark.parametrize("effect", [_three_times_noise, _harmonic], ids=["noise_x3", "harmonic"])
@pytest.mark.parametrize("name", NAMES)
def test_effects_outside_the_model_are_flagged(clean, name, effect):
    proc, setup, readings, fc = clean(name)
    keys, y = reading_vector(readings)
    rng = np.random.default_rng(11)
    moved = effect(fc, y, rng, setup) if effect is _harmonic else effect(fc, y, rng)
    out = fit_check(proc, setup, with_reading_vector(readings, keys, moved))
    assert out.ok is False, out.summary()


def test_no_residual_freedom_gives_no_verdict():
    """circle_centre, 3 contacts without the start points and two coordinates missing: 4
    readings for the 4 fitted parameters (centre, radius, one start coordinate) leave no
    residual freedom: ok is None, with the reason. The expansion coefficients' errors are
    off: with no temperature measured they act only times the unmeasured temperature
    deviation, a second-order product that the budget samples as a nuisance parameter,
    which changes the count this test is about."""
    proc = get("circle_centre")
    setup = proc.Setup(n_points=3, expansion_u_ppm_per_k=0, scale_expansion_u_ppm_per_k=0)
    readings = dict(proc.simulate(setup, proc.Truth(), 1, rng=3))
    for k in ("p_x_mm", "p_y_mm"):
        readings[k] = np.full_like(readings[k], np.nan)
    for k, j in (("x_mm", 0), ("y_mm", 1)):
        readings[k] = readings[k].copy()
        readings[k][0, j] = np.nan
    fc = fit_check(proc, setup, readings)
    assert fc.n_readings == 4 and fc.dof <= 0
    assert fc.ok is None and fc.p_value is None and "degree of freedom" in fc.reason
    assert fc.to_dict()["ok"] is None and "not made" in fc.summary()


def test_measured_result_carries_the_fit_and_alpha_is_checked():
    proc = get("rotary_axis")
    setup = proc.Setup()
    readings = proc.simulate(setup, proc.Truth(), 1, rng=5)
    res = estimate_measured(proc, setup, readings, trials=200, rng=0, fit_alpha=0.01)
    doc = res.to_dict()["fit"]
    assert set(doc) >= {"chi2", "dof", "p_value", "ok", "worst"} and doc["alpha"] == 0.01
    assert all(set(w) >= {"row", "z"} for w in doc["worst"])
    with pytest.raises(mtplan._validate.InvalidInput, match="fit_alpha"):
        estimate_measured(proc, setup, readings, trials=200, fit_alpha=1.5)


def _edited(tmp_path, row, shift_mm, comments=0):
    """The rotary_axis example with the reading on the file's `row` (as a spreadsheet counts
    it: the header is row 1) moved by `shift_mm`, after `comments` comment lines put on top
    (which move every row down)."""
    lines = (EXAMPLES / "rotary_axis_readings.csv").read_text().splitlines()
    lines = [f"# comment {i}" for i in range(comments)] + lines
    cells = lines[row - 1].split(",")
    assert cells[:4] == ["C", "3", "180.0", "9"] or comments  # position 3, point 9
    cells[-1] = f"{float(cells[-1]) + shift_mm:.9f}"
    lines[row - 1] = ",".join(cells)
    path = tmp_path / "moved.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_cli_warns_and_names_the_files_row_when_the_readings_do_not_fit(tmp_path, capsys):
    """The reading on the file's row 86 (position 3, point 9; the header is row 1) moved by
    0.2 mm: the table still prints, then the warning naming row 86; --json has fit.ok
    false and the w-test's verdict."""
    path = _edited(tmp_path, 86, 0.2)
    assert main(["estimate", "rotary_axis", str(path), "--trials", "200"]) == 0
    out = capsys.readouterr().out
    assert "EX0C" in out and "WARNING: the readings do not fit the model" in out
    assert "the w-test names row 86 z_mm" in out and "worst readings: row 86 z_mm" in out
    assert main(["estimate", "rotary_axis", str(path), "--trials", "200", "--json"]) == 0
    fit = json.loads(capsys.readouterr().out)["fit"]
    assert fit["ok"] is False and fit["w_ok"] is False and fit["worst"][0]["row"] == 86
    assert abs(fit["w_max"]) > fit["w_critical"]
    assert main(["estimate", "rotary_axis", str(path), "--fit-alpha", "2"]) == 2


def test_rows_count_comment_lines_as_a_spreadsheet_does(tmp_path):
    """Two comment lines on top put the header on row 3 and the moved reading on row 88,
    as the reader's own error messages count them."""
    from mtplan.evaluation.readings import read_measurement

    proc = get("rotary_axis")
    m = read_measurement(proc, _edited(tmp_path, 88, 0.2, comments=2))
    fc = fit_check(proc, m.setup, m.readings, origin=m.origin)
    assert fc.worst[0]["row"] == 88 and fc.worst[0]["column"] == "z_mm"


def test_a_passing_check_still_names_its_worst_reading(capsys):
    """The unedited example: no evidence of misfit, never "the readings fit the model", and
    the largest |w| with its row, which is the row of the largest |z| in --json."""
    path = EXAMPLES / "rotary_axis_readings.csv"
    assert main(["estimate", "rotary_axis", str(path), "--trials", "200", "--json"]) == 0
    fit = json.loads(capsys.readouterr().out)["fit"]
    assert fit["ok"] is True
    assert main(["estimate", "rotary_axis", str(path), "--trials", "200"]) == 0
    out = capsys.readouterr().out
    assert "no evidence of misfit" in out and "the readings fit the model" not in out
    assert f"largest |w| {abs(fit['w_max']):.2f} at row {fit['worst'][0]['row']} z_mm" in out


def test_the_significance_level_is_split_between_the_two_tests(clean):
    """ok is both tests at their shares of alpha; the w limit is Bonferroni's; p_overall is
    the smallest alpha that flags; w_share 0 is the chi-square alone."""
    from scipy import stats

    from mtplan.evaluation.fitcheck import W_SHARE, w_limit

    proc, setup, readings, fc = clean("rotary_axis")
    assert fc.alpha_chi2 == pytest.approx((1 - W_SHARE) * ALPHA)
    assert fc.alpha_w == pytest.approx(W_SHARE * ALPHA)
    n = int(np.sum(np.isfinite(fc.z)))
    assert fc.n_tested == n and fc.w_max == fc.worst[0]["z"] == fc.z[np.nanargmax(np.abs(fc.z))]
    assert fc.w_critical == pytest.approx(stats.norm.isf(fc.alpha_w / (2 * n)), rel=1e-12)
    assert w_limit(0.005, 150) == pytest.approx(4.1494, abs=1e-4)
    assert fc.p_w == pytest.approx(min(1, 2 * n * stats.norm.sf(abs(fc.w_max))))
    assert fc.ok == (fc.chi2_ok and fc.w_ok) == (fc.p_overall >= ALPHA)
    for alpha in (fc.p_overall * 0.99, min(fc.p_overall * 1.01, 0.999)):
        assert fit_check(proc, setup, readings, alpha=alpha).ok == (alpha <= fc.p_overall)
    chi_only = fit_check(proc, setup, readings, w_share=0.0)
    assert chi_only.ok == (fc.p_value >= ALPHA) and chi_only.w_ok is None
    assert "the w-test not made" in chi_only.summary()
    none_listed = fit_check(proc, setup, readings, n_worst=0)
    assert none_listed.worst == [] and none_listed.w_at in none_listed.summary()


def test_one_reading_at_twice_its_detectable_bias_is_flagged_by_the_w_test_alone(clean):
    """A reading moved by 2 MDB (the whole check's minimal detectable bias at 80 % power,
    about 10 times its scatter on rotary_axis, about 10 um): its w moves by 2 MDB
    sqrt(P_ii), between 2 w_critical and 2 (w_critical + 0.84) (the w-test alone needs the
    latter for 80 %; at the former it flags half the time; the model is linear in a reading's
    size at this size), the chi-square of 146 degrees of freedom may still pass, the w-test
    flags it and names its row."""
    proc, setup, readings, fc = clean("rotary_axis")
    keys, y = reading_vector(readings)
    i = 84  # position 3, point 9: the file's row 86
    y = y.copy()
    y[i] += 2 * fc.mdb[i]
    out = fit_check(proc, setup, with_reading_vector(readings, keys, y))
    assert 2 * fc.w_critical < out.z[i] - fc.z[i] < 2 * (fc.w_critical + 0.8416)
    assert out.w_ok is False and out.ok is False and out.worst[0]["row"] == 86
    assert "w-test names row 86" in out.warning()
    assert 4 < fc.mdb[i] / fc.scatter[i] < 7


def test_posterior_evaluation_carries_the_fit_and_a_free_noise_takes_one_dof():
    import warnings

    proc = get("circle_centre")
    setup = proc.Setup(n_points=6)
    readings = proc.simulate(setup, proc.Truth(), 1, rng=4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = estimate_measured(proc, setup, readings, uncertainty="posterior", rng=0,
                                allow_unconverged=True, max_steps=100, progress=False)
    # the same start as the evaluation's (its estimator's estimate): the budget is
    # linearised there when the least squares moves less than a standard error from it
    fixed = fit_check(proc, setup, readings, estimator=res.estimator)
    assert res.fit.dof == fixed.dof and res.fit.chi2 == pytest.approx(fixed.chi2, rel=1e-6)
    assert res.to_dict()["fit"]["ok"] is not None
    free = fit_check(proc, setup, readings, noise="free", estimator=res.estimator)
    assert free.dof == fixed.dof - 1 and free.ok is not None


def test_the_docs_examples_are_what_the_check_prints():
    """docs/fit_check.md prints a passing check and a warning (rotary_axis, seed 3, the
    reading on row 86 moved by 9 um, which the w-test flags and the chi-square passes at
    its share) and the chi-square's p-value: they are what the code prints now (the doc's
    line wraps aside), and so are the default alpha, its split and the w-test's limit it
    quotes."""
    from mtplan.evaluation.fitcheck import W_SHARE, w_limit

    doc = " ".join((Path(__file__).resolve().parents[2] / "docs" / "fit_check.md")
                   .read_text(encoding="utf-8").split())
    proc = get("rotary_axis")
    setup = proc.Setup()
    readings = proc.simulate(setup, proc.Truth(), 1, rng=3)
    passed = fit_check(proc, setup, readings)
    keys, y = reading_vector(readings)
    y = y.copy()
    y[84] += 0.009
    failed = fit_check(proc, setup, with_reading_vector(readings, keys, y))
    assert failed.chi2_ok and not failed.w_ok
    assert " ".join(passed.summary().split()) in doc
    assert " ".join(failed.warning().split()) in doc
    assert (f"The chi-square passes these readings (p = {failed.p_value:.2g} >= "
            f"{failed.alpha_chi2:g})") in doc
    a_chi2, a_w = (1 - W_SHARE) * FIT_ALPHA, W_SHARE * FIT_ALPHA
    assert (f"(default {FIT_ALPHA:g}, `--fit-alpha`)" in doc and f"`W_SHARE = {W_SHARE:g}`"
            in doc and f"({a_chi2:g} and {a_w:g} at the default" in doc)
    assert f"{w_limit(a_w, 150):.2f} for 150 readings at {a_w:g}" in doc


def test_mc_evaluation_shares_its_least_squares_with_the_fit_check(monkeypatch):
    """The `mc` evaluation's readings least squares (correction's, which conditions the
    Monte Carlo) and the fit check's are one generalised least squares, fitted once: the
    check is the one started from the first exact estimator, whichever estimator gave the
    estimate."""
    from mtplan.evaluation import correction, posterior

    proc = get("circle_centre")
    setup = proc.Setup(n_points=6)
    readings = proc.simulate(setup, proc.Truth(), 1, rng=4)
    calls = []
    real = posterior._fit_start
    monkeypatch.setattr(posterior, "_fit_start", lambda *a: calls.append(1) or real(*a))
    monkeypatch.setattr(posterior, "_STARTS", {})
    monkeypatch.setattr(correction, "_CACHE", {})
    res = estimate_measured(proc, setup, readings, trials=200, rng=0,
                            estimator=proc.exact_names[-1])
    assert proc.exact_names[-1] != proc.exact_names[0] and len(calls) == 1
    alone = fit_check(proc, setup, readings)
    assert len(calls) == 1
    assert res.fit.dof == alone.dof and res.fit.chi2 == alone.chi2 and res.fit.ok is not None
    np.testing.assert_array_equal(res.fit.z, alone.z)
