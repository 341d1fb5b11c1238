"""Readings files as users have them: the set-up they imply, bare point files, refusals.

The Gander-Golub-Strebel six points (BIT 34, 1994; ``tests/reference/ggs1994_circle.csv``,
see its header) are the user's case of issue 15: estimated with no set-up at all.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mtplan import cli
from mtplan._validate import InvalidInput
from mtplan.evaluation.readings import read_measurement
from mtplan.models import registry

GGS = Path(__file__).resolve().parent.parent / "reference" / "ggs1994_circle.csv"
EXAMPLES = Path(__file__).resolve().parents[2] / "src" / "mtplan" / "examples"
#: Chernov's printed geometric fit of the GGS points (7 significant digits)
GGS_CENTRE, GGS_RADIUS = (4.739782, 2.983533), 4.714226


def run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _one_line(code, err):
    lines = err.strip().splitlines()
    return code == 2 and len(lines) == 1 and lines[0].startswith("mtplan: error:") \
        and "Traceback" not in err


def test_ggs_points_with_no_setup_give_the_published_circle(capsys):
    """Done-when of issue 15: the published centre and radius to the printed digits, with a
    finite, plausible uncertainty from the set-up the file implies."""
    code, out, err = run(capsys, "estimate", "circle_centre", GGS, "--estimator", "geometric",
                         "--json", "--trials", 2000)
    assert code == 0, err
    doc = json.loads(out)
    m = {d["name"]: d for d in doc["measurands"]}
    # half a unit of the 7th printed digit
    assert abs(m["centre_x"]["estimate"] / 1e3 - GGS_CENTRE[0]) <= 5e-7
    assert abs(m["centre_y"]["estimate"] / 1e3 - GGS_CENTRE[1]) <= 5e-7
    radius = doc["setup"]["bore_radius_mm"] + m["radius"]["estimate"] / 1e3
    assert abs(radius - GGS_RADIUS) <= 5e-7
    assert doc["setup"]["n_points"] == 6 and doc["setup_from_file"]["n_points"] == 6
    # the points scatter by sqrt(SSR/(n-3)) = 0.64 mm about their circle: the uncertainty
    # follows it (the linearised u of the centre is 0.5-1.5 mm), not the probe's 0.5 um
    assert 0.3e3 < doc["setup"]["probe_noise_um"] < 1e3
    for d in doc["measurands"]:
        lo, hi = d["interval"]
        assert math.isfinite(d["u"]) and d["u"] > 0
        assert 200 < d["u"] < 5e3, d  # um: of the scatter's order, not the wild trials' std
        assert lo <= d["estimate"] <= hi
        # the Monte Carlo errors are heavy-tailed here: no bias can be pinned down, so the
        # value is the published estimate itself
        assert d["value"] == d["estimate"] and d["bias_correction"] == 0
        assert 200 < (hi - lo) / 2 < 2 * GGS_RADIUS * 1e3, d  # um: about the scatter
    assert any("bore_radius_mm = 4.714226" in n for n in doc["notes"])
    assert "probe_feed_mm_min" in doc["setup_defaults"]


@pytest.mark.parametrize("name", sorted(registry()))
def test_every_example_readings_file_estimates_with_no_set(capsys, name):
    # the trials give only the u, which is not what is checked here: 10 are enough (each of
    # line_laser's costs about 0.08 s of CPU)
    code, out, err = run(capsys, "estimate", name, EXAMPLES / f"{name}_readings.csv", "--json",
                         "--trials", 10)
    assert code == 0, err
    doc = json.loads(out)
    # every measurand the set-up determines has a finite estimate; those it does not (the six
    # blind errors of geometry21's one-head set-up) are listed with their reason
    assert all(math.isfinite(m["estimate"]) for m in doc["measurands"] if m["determinable"])
    assert all(m["reason"] for m in doc["measurands"] if not m["determinable"])


@pytest.mark.parametrize("n", [3, 4, 12])
def test_bare_point_files_of_any_count(tmp_path, n):
    rng = np.random.default_rng(n)
    phi = np.sort(rng.uniform(0, 2 * np.pi, n)) if n > 3 else np.array([0.3, 2.4, 4.4])
    x, y = 12.0 + 80.0 * np.cos(phi), -3.0 + 80.0 * np.sin(phi)
    path = tmp_path / "points.csv"
    pd.DataFrame({"x_mm": x, "y_mm": y}).to_csv(path, index=False)
    m = read_measurement("circle_centre", path)
    assert m.setup.n_points == n and abs(m.setup.bore_radius_mm - 80.0) < 1e-9
    # the default start scatter (25 mm) fits an 80 mm bore: kept; the default radius not
    assert m.setup.start_scatter_mm == 25.0 and "bore_radius_mm" in m.from_file


def test_bare_points_of_a_small_bore_scale_the_setup_to_it(tmp_path):
    path = tmp_path / "points.csv"
    phi = np.linspace(0, 2 * np.pi, 5, endpoint=False)
    pd.DataFrame({"x_mm": 3 * np.cos(phi), "y_mm": 3 * np.sin(phi)}).to_csv(path, index=False)
    m = read_measurement("circle_centre", path)
    assert m.setup.spread_deg == 360.0
    assert m.setup.start_scatter_mm * math.sqrt(2) <= 0.5 * 3.0  # scaled, not refused
    assert m.setup.clearance_mm < 3.0
    assert any("start_scatter_mm" in n and "default 25" in n for n in m.notes)


@pytest.mark.parametrize("labelled", [False, True])
def test_a_bore_smaller_than_the_default_truth_is_read(tmp_path, capsys, labelled):
    """The default truth's centre (0.35, -0.2) mm lies outside a 0.5 mm bore: the file is
    still checked and estimated (against a nominal truth, then around the estimate)."""
    phi = np.radians([0, 120, 240])
    x, y = 0.5 * np.cos(phi), 0.5 * np.sin(phi)
    frame = pd.DataFrame({"x_mm": x, "y_mm": y})
    if labelled:
        frame = pd.DataFrame({"point": ["p1", "p2", "d1", "d2", "d3"],
                              "x_mm": [0.0, 0.0, *x], "y_mm": [-0.5, 0.5, *y]})
    path = tmp_path / "tiny.csv"
    frame.to_csv(path, index=False)
    code, out, err = run(capsys, "estimate", "circle_centre", path, "--json", "--trials", 200)
    assert code == 0, err
    assert json.loads(out)["setup"]["bore_radius_mm"] == pytest.approx(0.5)


@pytest.mark.parametrize("content, needle", [
    ("x_mm,y_mm\n1,2\n3,4\n", "n_points"),  # two points: no circle
    ("x_mm,y_mm\n0,0\n1,1\n2,2\n", "straight line"),
    ("x_mm,y_mm\n1.5e154,0\n0,1\n-1,0\n", "row 2, column 'x_mm' is 1.5e.154, beyond any"),
])
def test_bare_points_that_make_no_circle_are_refused(tmp_path, content, needle):
    path = tmp_path / "p.csv"
    path.write_text(content)
    with pytest.raises(InvalidInput, match=needle):
        read_measurement("circle_centre", path)


def test_a_stated_field_that_contradicts_the_file_is_refused(capsys):
    code, _, err = run(capsys, "estimate", "circle_centre", GGS, "--set", "bore_radius_mm=250",
                       "--set", "n_points=5")
    assert _one_line(code, err)
    assert "bore_radius_mm = 250 is stated" in err and "4.714226" in err
    assert "n_points = 5 is stated" in err and "implies 6" in err
    # within the tolerance: the stated (drawing) radius is kept (the set-up is what is
    # checked, not the u: 20 trials)
    code, out, err = run(capsys, "estimate", "circle_centre", GGS, "--set", "bore_radius_mm=4.7",
                         "--json", "--trials", 20)
    assert code == 0, err
    assert json.loads(out)["setup"]["bore_radius_mm"] == 4.7


def test_a_stated_noise_below_the_scatter_is_kept_with_a_note(tmp_path):
    m = read_measurement("circle_centre", GGS, {"probe_noise_um": "0.5"})
    assert m.setup.probe_noise_um == 0.5
    assert any("probe_noise_um = 0.5 is stated" in n and "kept" in n for n in m.notes)
    m = read_measurement("circle_centre", GGS, {"roundness_um": "50"})  # a noise budget
    assert m.setup.probe_noise_um == 0.5 and m.setup.roundness_um == 50


_NON_DEFAULT = [
    ("rotary_axis", {"axis": "A", "positions": 5, "range_deg": 50, "a_order": "ascending",
                     "lattice_nx": 3, "lattice_offset_y_mm": 4}),
    ("rotary_axis", {"axis": "CA", "lattice_ny": 4, "lattice_size_mm": 30,
                     "lattice_offset_x_mm": 7, "lattice_offset_y_mm": -3}),
    ("rotary_axis", {"axis": "C", "angles_deg": (0, 30, 100, 200)}),
    ("line_laser", {"lines": 20, "points_per_line": 33, "line_width_mm": 12, "step_mm": 0.1}),
    ("tracker_frame", {"n_submachines": 3, "points_per_axis": 5, "points_per_arc": 9,
                       "c_arc_deg": 360, "a_arc_deg": 90, "travel_z_mm": 300}),
    ("geometry21", {"line_points": 11, "line_repeats": 2, "line_length_mm": 80,
                    "circle_points": 36, "circle_radius_mm": 40, "circle_arc_deg": 270,
                    "xy_plane_z_mm": -20, "yz_plane_x_mm": 90}),
    ("circle_centre", {"n_points": 7, "spread_deg": 120, "bore_radius_mm": 100}),
]


@pytest.mark.parametrize("name, fields", _NON_DEFAULT)
def test_the_file_gives_back_the_setup_it_was_taken_with(tmp_path, name, fields):
    proc = registry()[name]
    setup = proc.setup(**fields)
    path = tmp_path / "r.csv"
    proc.readings.frame(setup, proc.simulate(setup, proc.Truth(), 1, rng=3)).to_csv(
        path, index=False)
    m = read_measurement(proc, path)
    for k, v in fields.items():
        got = getattr(m.setup, k)
        if isinstance(v, tuple):
            np.testing.assert_allclose(got, v, rtol=0, atol=1e-9)
        elif name == "circle_centre" and k in ("bore_radius_mm", "spread_deg"):
            # from the probed points: the radius within the form error and noise, the arc
            # within its tolerance (the points are probed, not commanded)
            assert abs(got - v) <= (0.05 if k == "bore_radius_mm" else 0.1 * v + 2), (k, got)
        else:
            assert got == pytest.approx(v, abs=1e-9), (k, got)
    assert set(m.defaults).isdisjoint(fields)
    np.testing.assert_array_equal(m.readings[next(iter(m.readings))].shape[0], 1)


def test_unit_less_length_columns_are_read_in_mm_with_a_note(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("X,Y\n10,0\n0,10\n-10,0\n0,-10\n")
    m = read_measurement("circle_centre", path)
    assert m.setup.bore_radius_mm == pytest.approx(10.0)
    assert sum("names no unit" in n for n in m.notes) == 2


def test_contradicting_design_fields_are_named_all_at_once(tmp_path):
    proc = registry()["rotary_axis"]
    path = tmp_path / "r.csv"
    setup = proc.Setup()
    proc.readings.frame(setup, proc.simulate(setup, proc.Truth(), 1, rng=1)).to_csv(
        path, index=False)
    with pytest.raises(InvalidInput) as exc:
        read_measurement(proc, path, {"axis": "A", "range_deg": "180", "lattice_nx": "4"})
    msg = str(exc.value)
    assert all(f"{f} = " in msg for f in ("axis", "range_deg", "lattice_nx"))
    assert "\n" not in msg
