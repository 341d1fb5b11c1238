"""Each error source, switched on alone, moves the measurands it should and no others.

One table of (procedure, set-up, source, measurands expected to move), run through the
command line as a user would: ``mtplan procedures PROC --json`` must list the source,
``mtplan simulate PROC --sources NAME --json`` (every other source off, so the readings
are noise-free but for it) must give a spread to exactly the expected measurands.

A measurand that does not depend on the source keeps the truth to round-off or to
second order (its std is below 1e-4 um or urad here: air_refraction's 1 ppm scale on
origin_x at x ~ 0); one that does moves by 0.1 um or urad or more at the default
sizes. The limit below sits a decade or more from either side.
"""

from __future__ import annotations

import json

import pytest

from mtplan import cli

MOVES = 1e-3  # display units (um, urad): a spread above this is a measurand that moves
STILL = 1e-3  # ... and |bias| and spread below it, one that does not

TRACKER_ORIGINS = {f"origin_{a}_{k}" for a in "yz" for k in (1, 2)}
TRACKER_DIRECTIONS = {f"{q}_{k}" for q in ("rot_x", "rot_y", "rot_z", "sq_xy", "sq_yz", "sq_zx")
                      for k in (1, 2)}
ALL = None  # every measurand
RA_POSE = {"pose_dx", "pose_dy", "pose_dz"}
RA_POSITIONS = {"EX0C", "EY0C", "EY0A", "EZ0A", "ac_offset"} | RA_POSE
RA_DIRECTIONS = {"EA0C", "EB0C", "EB0A", "EC0A", "ac_squareness"} | RA_POSE

CASES = [
    # tracker_frame, issue 17: the tracker's angle error split into a per-test systematic
    # part and a per-point one, the reflector, the air, drift, straightness of the travels
    ("tracker_frame", {}, "angular_systematic", ALL),
    ("tracker_frame", {}, "transverse_per_length", ALL),
    ("tracker_frame", {}, "smr_centring", ALL),
    # a scale about the tracker: directions and the A-C offset (30 um) keep their values;
    # the registration leaves the scale as p - c (c the marks' centroid): origin_x (x ~ 0)
    # stays too
    ("tracker_frame", {}, "air_refraction", TRACKER_ORIGINS),
    ("tracker_frame", {}, "thermal_drift", ALL),
    # the travels' deviations tilt the fitted lines only; the arcs give the origin
    ("tracker_frame", {}, "straightness", TRACKER_DIRECTIONS),
    # rotary_axis, the combined C+A test: translations of the axis at each position move
    # the axes' positions, the offset of C from A and the pose, never a direction; tilts
    # the reverse; the angles are not used at all
    ("rotary_axis", {"axis": "CA"}, "radial_motion", RA_POSITIONS),
    ("rotary_axis", {"axis": "CA"}, "axial_motion", RA_POSITIONS),
    ("rotary_axis", {"axis": "CA"}, "tilt_motion", RA_DIRECTIONS),
    ("rotary_axis", {"axis": "CA"}, "angular_positioning", set()),
    # geometry21, issue 16 (joint, the seed's set-up): the lines run back and forth and the
    # circles both ways, so reversal cancels; a scale growing over the test's time moves the
    # positioning errors only; the head's drift the translational errors and squareness,
    # never the angular errors the circles give
    ("geometry21", {"estimator": "joint"}, "repeatability", ALL),
    ("geometry21", {"estimator": "joint"}, "reversal", set()),
    ("geometry21", {"estimator": "joint"}, "thermal_growth", {"EXX", "EYY", "EZZ"}),
    ("geometry21", {"estimator": "joint"}, "thermal_drift",
     {"EXX", "EYY", "EZZ", "EYX", "EZX", "EXY", "EZY", "EXZ", "EYZ", "EC0Y", "EB0Z", "EA0Z"}),
]


def _cli_json(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out)


@pytest.mark.parametrize("proc,setup,source,moved", CASES,
                         ids=[f"{c[0]}-{c[2]}" + "".join(f"-{k}={v}" for k, v in c[1].items())
                              for c in CASES])
def test_a_source_alone_moves_only_its_measurands(capsys, proc, setup, source, moved):
    sets = [a for k, v in setup.items() if k != "estimator" for a in ("--set", f"{k}={v}")]
    sets += ["--estimator", setup["estimator"]] if "estimator" in setup else []
    listing = _cli_json(capsys, "procedures", proc, "--json")
    assert source in listing[0]["sources"]
    doc = _cli_json(capsys, "simulate", proc, *sets, "--sources", source, "--trials", "40",
                    "--seed", "5", "--json")
    names = [m["name"] for m in doc["measurands"]]
    expected = set(names) if moved is ALL else set(moved)
    assert expected <= set(names)
    for m in doc["measurands"]:
        if m["name"] in expected:
            assert m["std"] > MOVES, m
        else:
            assert m["std"] < STILL and abs(m["bias"]) < STILL, m
