"""The specific risk of a value measured on a machine, in the designer: the probability
that the measurand is outside its tolerance given the measured value and the design's u
(JCGM 106), and the rule's decision for it, as ``mtplan accept --measured`` gives them;
and, on the same page, the picture of the measuring positions."""

from __future__ import annotations

import base64
import json
import subprocess

import pytest

from tests.explore.conftest import MTPLAN, start_server

TIMEOUT_MS = 60_000
TOL = {"lower": "-150", "upper": "150", "prior": "normal:0,60", "rule": "iso14253"}


@pytest.fixture(scope="module")
def server():
    s = start_server("rotary_axis")
    yield s
    s.stop()


def test_a_measured_value_gets_the_specific_risk_mtplan_accept_gives(browser, server):
    design = {"procedure": "rotary_axis", "setup": {"positions": "8"},
              "tolerances": {"EX0C": TOL}}
    d = base64.urlsafe_b64encode(json.dumps(design).encode()).decode().rstrip("=")
    ctx = browser.new_context(viewport={"width": 1400, "height": 1000})
    try:
        pg = ctx.new_page()
        pg.set_default_timeout(TIMEOUT_MS)
        pg.goto(f"{server.link}&d={d}")
        settled = ("window.mtplan && window.mtplan.changes > 0 && !window.mtplan.inflight && "
                   "window.mtplan.rendered === window.mtplan.changes && "
                   "window.mtplan.lastResult.measurands.every((m) => m.trust === 'ok')")
        pg.wait_for_function(settled)
        assert pg.locator("#specific").is_visible()
        for y, decision in (("130", "rejects"), ("5", "accepts")):
            pg.fill("#specific-value", y)
            pg.dispatch_event("#specific-value", "change")
            pg.wait_for_function(settled)
            m = pg.evaluate("window.mtplan.lastResult.measurands.find((x) => x.name === 'EX0C')")
            out = subprocess.run([*MTPLAN, "accept", "--lower", TOL["lower"], "--upper",
                                  TOL["upper"], "--u", repr(m["u"]), "--prior", TOL["prior"],
                                  "--rule", TOL["rule"], "--measured", y, "--json"],
                                 capture_output=True, text=True, timeout=300)
            assert out.returncode == 0, out.stderr
            want = json.loads(out.stdout)
            shown = pg.locator("#specific-out").inner_text()
            # the CLI's number, written as the page writes a probability
            assert pg.evaluate("(p) => pct(p)", want["specific_risk"]) in shown, shown
            lo, hi = want["acceptance_limits"]
            assert decision == ("accepts" if lo <= float(y) <= hi else "rejects")
            assert f"the rule iso14253 {decision} it" in shown
        # the value is part of the design: in its link and in the print
        assert pg.evaluate("window.mtplan.design.tolerances.EX0C.measured") == "5"
        assert "Specific risk: P(EX0C outside" in pg.locator("#report").inner_text()
        # the picture of the measuring positions: every reading of the 8 positions' lattice
        pg.wait_for_function("document.getElementById('positions-plot').dataset.points")
        assert pg.locator("#positions-plot").get_attribute("data-points") == str(8 * 25)
        status, answer = server.api("api/positions", {"design": "rotary_axis"})
        assert status == 400 and "'design'" in answer["error"]
        pg.fill("#specific-value", "abc")
        pg.dispatch_event("#specific-value", "change")
        pg.wait_for_function(settled)
        pg.wait_for_function("/'measured'/.test(document.getElementById('specific-out')"
                             ".textContent)")
        assert "'measured'" in pg.locator("#specific-out").inner_text()
    finally:
        ctx.close()
