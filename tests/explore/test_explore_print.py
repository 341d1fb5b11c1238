"""The designer's print is a one-page design report: printed to PDF by Chromium (as the
browser's Print does), its text holds every setting of the set-up (yes/no ones as yes or
no), each error source as on with its size or off, the results, the budget, the verdict
and the design's link, and no control; and it is one A4 page."""

from __future__ import annotations

import base64
import json
import re
import subprocess

import pytest

from tests.explore.conftest import start_server

TIMEOUT_MS = 60_000
DESIGNS = {
    # yes/no fields both ways, a source switched off, a tolerance
    "rotary_axis": {"procedure": "rotary_axis", "off": ["probe_noise", "flatness"],
                    "setup": {"positions": "8", "sensor_reversal": "true",
                              "z_follows_surface": "false", "sensor_range_mm": "25"},
                    "tolerances": {"EX0C": {"lower": "-150", "upper": "150",
                                            "prior": "normal:0,60", "rule": "iso14253"}}},
    # the most measurands (20) and many settings
    "tracker_frame": {"procedure": "tracker_frame", "off": ["thermal_drift"],
                      "tolerances": {"origin_x_1": {"lower": "-100", "upper": "100",
                                                    "prior": "normal:0,50",
                                                    "rule": "iso14253"}}},
}
CONTROLS = ("Confirm by Monte Carlo", "Find the cheapest", "Export study", "Load study",
            "Keep as scenario", "Undo", "Defaults", "Planner ranges", "CSV")


@pytest.fixture(scope="module")
def server():
    s = start_server("rotary_axis")
    yield s
    s.stop()


def _js(v) -> str:
    """A set-up value as the page writes it (JavaScript's String of a JSON value)."""
    if v is None or v == "":  # an empty text field (distributions) is its default
        return "default"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, list):
        return ", ".join(_js(x) for x in v)
    if isinstance(v, float):
        if v.is_integer() and abs(v) < 1e21:
            return str(int(v))
        text = repr(v)
        return re.sub(r"e([+-])0*(\d)", r"e\1\2", text)
    return str(v)


def _label(f) -> str:
    name = f["name"]
    if f["unit"] and name.endswith("_" + f["unit"]):
        name = name[: -len(f["unit"]) - 1]
    return name.replace("_", " ")


@pytest.mark.parametrize("name", sorted(DESIGNS))
def test_the_print_is_one_a4_page_with_every_setting_and_source_state(browser, server,
                                                                       name, tmp_path):
    design = DESIGNS[name]
    ctx = browser.new_context(viewport={"width": 1440, "height": 1000})
    try:
        pg = ctx.new_page()
        pg.set_default_timeout(TIMEOUT_MS)
        d = base64.urlsafe_b64encode(json.dumps(design).encode()).decode().rstrip("=")
        pg.goto(f"{server.link}&d={d}")
        pg.wait_for_function("window.mtplan && window.mtplan.changes > 0 && "
                             "window.mtplan.rendered === window.mtplan.changes && "
                             "window.mtplan.lastResult && window.mtplan.lastResult.ok && "
                             "!window.mtplan.inflight && !window.mtplan.lastResult"
                             ".measurands.some((m) => m.pending)")  # the check made
        link = pg.evaluate("designLink()")
        verdict = pg.locator("#verdict").inner_text()
        pdf = tmp_path / f"{name}.pdf"
        pg.pdf(path=str(pdf), format="A4")
    finally:
        ctx.close()
    info = subprocess.run(["pdfinfo", str(pdf)], capture_output=True, text=True).stdout
    assert re.search(r"^Pages:\s+1$", info, re.M), info
    w, h = map(float, re.search(r"Page size:\s+([\d.]+) x ([\d.]+)", info).groups())
    assert abs(w - 595.3) < 2 and abs(h - 841.9) < 2  # A4 (210 x 297 mm) in points
    text = subprocess.run(["pdftotext", str(pdf), "-"], capture_output=True, text=True).stdout
    lines = {" ".join(line.split()) for line in text.splitlines()}

    _, procedure = server.api(f"api/procedure/{name}")
    _, result = server.api("api/evaluate", {"design": design})
    assert result["ok"]
    missing = []
    for f in procedure["fields"]:
        value = result["setup"].get(f["name"])
        if f["source"]:
            want = f"{f['source']} off" if f["source"] in design["off"] else \
                f"{f['source']} on, {_js(value)}"
            found = any(line == want or line.startswith(want + " ") for line in lines)
        else:
            pattern = re.compile(re.escape(_label(f)) + r"( \[[^\]]+\])? " +
                                 re.escape(_js(value)) + "$")
            found = any(pattern.match(line) for line in lines)
            want = f"{_label(f)} {_js(value)}"
        if not found:
            missing.append(want)
    assert not missing, (missing, text)
    for source in design["off"]:  # off, never a size
        assert not any(line.startswith(f"{source} on") for line in lines)
    flat = "".join(text.split())
    assert "".join(verdict.split()) in flat and verdict.startswith("Verdict:")
    assert link in flat and "token" not in link
    layout = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], capture_output=True,
                            text=True).stdout.splitlines()
    for m in result["measurands"]:  # the results (U as the page rounds it) and the budget
        U = _js(float(f"{m['U']:.3g}")) if m["trust"] != "no" else "not reliable"
        assert any(re.match(rf"\s*{re.escape(m['name'])}\s.*\s{re.escape(U)}\s", line)
                   for line in layout), (m["name"], U)
    assert "Budget of" in text and "TUR" in text
    assert not [c for c in CONTROLS if c in text]
