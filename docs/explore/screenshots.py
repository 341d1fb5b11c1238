"""Screenshots of the designer, one per procedure, for the documentation.

    python docs/explore/screenshots.py [PROC ...]   # docs/explore/<procedure>[_390].png

Each page is opened through its link with a lever moved, a target and a tolerance entered,
so the plots show the current value, the target line and the acceptance figures; at
1440 px and at 390 px (a phone). The print and the state views: ``screenshots_state.py``.
"""

from __future__ import annotations

import base64
import json
import sys
import time
from pathlib import Path

from mtplan.testing.browser import chromium, served_designer

HERE = Path(__file__).resolve().parent
DESIGNS = {
    "rotary_axis": {"setup": {"positions": "8", "incline_deg": "25"}, "lever": "incline_deg",
                    "targets": {"EX0C": "40", "EY0C": "8"},
                    "tolerances": {"EX0C": {"lower": "-150", "upper": "150",
                                            "prior": "normal:0,60", "rule": "iso14253"}}},
    "circle_centre": {"setup": {"n_points": "6"}, "lever": "spread_deg",
                      "targets": {"centre_x": "4"},
                      "tolerances": {"centre_x": {"lower": "-400", "upper": "400",
                                                  "prior": "normal:0,200", "rule": "iso14253"}}},
    "geometry21": {"setup": {}, "lever": "circle_radius_mm", "targets": {"EBX": "12"},
                   "tolerances": {"EXX": {"lower": "-6", "upper": "6", "prior": "normal:0,3",
                                          "rule": "iso14253"}}},
    "line_laser": {"setup": {"lines": "20", "points_per_line": "17"}, "lever": "raise_mm",
                   "targets": {"alpha_y": "80"},
                   "tolerances": {"alpha_y": {"lower": "-2500", "upper": "2500",
                                              "prior": "normal:0,1200", "rule": "iso14253"}}},
    "tracker_frame": {"setup": {}, "lever": "a_arc_deg",
                      "targets": {"origin_x_1": "15", "origin_y_1": "25"},
                      "tolerances": {"origin_x_1": {"lower": "-100", "upper": "100",
                                                    "prior": "normal:0,50",
                                                    "rule": "iso14253"}}},
    # the states of a number and the kinds of tolerance: a check that fails, a check too
    # costly live (with its button), and one-sided tolerances on either side
    "tracker_frame_short_arcs": {
        "procedure": "tracker_frame", "setup": {"a_arc_deg": "3", "c_arc_deg": "5"},
        "lever": "a_arc_deg",
        "tolerances": {"origin_y_1": {"lower": "-20000", "upper": "20000",
                                      "prior": "normal:0,5000", "rule": "iso14253"}}},
    "line_laser_not_checked": {
        "procedure": "line_laser", "estimator": "patent", "lever": "raise_mm",
        "setup": {"points_per_line": "340"},  # a live check would hold over 256 MB
        "tolerances": {"alpha_y": {"lower": "-400", "upper": "400",
                                   "prior": "normal:0,100", "rule": "iso14253"}}},
    "rotary_axis_one_sided": {
        "procedure": "rotary_axis", "lever": "incline_deg",
        "tolerances": {"EX0C": {"upper": "100", "prior": "normal:0,30", "rule": "iso14253"},
                       "EY0C": {"lower": "-60", "prior": "normal:0,30", "rule": "iso14253"}}},
}


#: (file suffix, viewport width, media): the wide screen, the phone (the print, a PDF of
#: one A4 page: screenshots_state.py)
VIEWS = [("", 1440, "screen"), ("_390", 390, "screen")]


def main(argv=None) -> int:
    only = (argv if argv is not None else sys.argv[1:]) or list(DESIGNS)
    with served_designer() as (_, link), chromium() as browser:
        for name in only:
            design = DESIGNS[name]
            for suffix, width, media in VIEWS:
                page = browser.new_page(viewport={"width": width, "height": 1000})
                page.set_default_timeout(300_000)
                d = base64.urlsafe_b64encode(json.dumps(
                    {"procedure": name, **design}).encode()).decode().rstrip("=")
                page.goto(f"{link}&d={d}")
                page.wait_for_function("window.mtplan && window.mtplan.rendered > 0 && "
                                       "!window.mtplan.inflight")
                page.wait_for_function("document.querySelector('#sens-plot').dataset.field"
                                       " || /^no sensitivity/.test(document."
                                       "querySelector('#sens-msg').textContent)")
                page.wait_for_function("!window.mtplan.lastResult.ok || !window.mtplan"
                                       ".lastResult.measurands.some((m) => m.pending)")
                time.sleep(1.0)
                page.emulate_media(media=media)
                time.sleep(0.5)
                out = HERE / f"{name}{suffix}.png"
                page.screenshot(path=str(out), full_page=True)
                page.close()
                print("wrote", out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
