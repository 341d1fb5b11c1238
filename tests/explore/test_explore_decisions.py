"""Decisions only on checked numbers, and on tolerances of every kind, in Debian's Chromium.

Every live number is checked (against its spot check's Monte Carlo), failed (with the
reason in words and what to do) or not checked (too costly live, with the button that
checks it). TUR, risks, zones and the verdict are given only on a checked number; a
failed check is shown, never left "being checked". A one-sided tolerance gets the
figures, judgement, zones and risk curve of ``mtplan accept``.
"""

from __future__ import annotations

import json

import pytest

from tests.explore.test_explore_browser import _cli, _open, _settled, server  # noqa: F401


def test_short_arcs_fail_their_check_with_the_reason_and_give_no_verdict(browser, server):
    # the spot check's circle fits do not converge over 3 deg; mtplan simulate refuses it
    ctx, pg = _open(browser, server, {
        "procedure": "tracker_frame", "setup": {"a_arc_deg": "3", "c_arc_deg": "5"},
        "tolerances": {"origin_y_1": {"lower": "-20000", "upper": "20000",
                                      "prior": "normal:0,5000", "rule": "iso14253"}}})
    rows = pg.locator("#measurands tbody tr")
    assert rows.count() > 0
    assert set(pg.evaluate("[...document.querySelectorAll('#measurands tbody tr')]"
                           ".map((r) => r.dataset.trust)")) == {"no"}
    note = pg.locator("#banner").inner_text()  # the set-up's reason, said once
    assert "did not converge" in note and "Use a longer arc" in note, note
    assert "check failed" in pg.locator("#note-origin_y_1").inner_text()
    assert "first order not reliable" in pg.locator("#m-origin_y_1 td.U").inner_text()
    assert pg.locator("#status").inner_text() == "up to date"  # not "being checked" forever
    assert "no decision" in pg.locator("#acc-tur-origin_y_1").inner_text()
    assert pg.locator("#acc-pfr-origin_y_1").inner_text() == ""
    verdict = pg.locator("#verdict").inner_text()
    assert "no verdict on origin_y_1" in verdict and "decided" not in verdict, verdict
    assert "TUR" not in verdict and pg.locator("#zone-plot .main-svg").count() == 0
    ctx.close()


def test_a_cell_not_checked_gets_no_verdict_until_its_check_is_run(browser, server):
    # 340 points a line: a live check of 40 trials would hold over 256 MB, so the cells
    # are not checked; the button checks them in the background (200 trials)
    ctx, pg = _open(browser, server, {
        "procedure": "line_laser", "estimator": "patent",
        "setup": {"points_per_line": "340"},
        "tolerances": {"alpha_y": {"lower": "-400", "upper": "400", "prior": "normal:0,100",
                                   "rule": "iso14253"}}})
    row = pg.locator("#m-alpha_y")
    assert row.get_attribute("data-trust") == "unchecked"
    assert "not checked" in pg.locator("#note-alpha_y").inner_text()
    assert "no decision" in pg.locator("#acc-tur-alpha_y").inner_text()
    verdict = pg.locator("#verdict").inner_text()
    assert "no verdict on alpha_y" in verdict and "TUR" not in verdict, verdict
    pg.locator("#check-alpha_y").click()
    pg.wait_for_function("document.querySelector('#check-done')", timeout=180_000)
    _settled(pg)
    pg.wait_for_function("document.querySelector('#m-alpha_y').dataset.trust === 'ok'")
    assert float(pg.locator("#acc-tur-alpha_y").inner_text()) > 0
    verdict = pg.locator("#verdict").inner_text()
    assert "alpha_y" in verdict and "TUR" in verdict and "no verdict on alpha_y" not in verdict
    # alpha_x failed the check (its Monte Carlo is 0.25 times first order): marked, no target
    assert pg.locator("#m-alpha_x").get_attribute("data-trust") == "no"
    ctx.close()


def test_one_sided_tolerances_on_both_sides_are_judged_as_mtplan_accept_judges_them(
        browser, server):
    from mtplan.explore import design as d

    # limits at 5 U with a population of 1.5 U: decided at their risks whatever the model's
    # u (a missing TUR once compared as less than 2: "cannot be decided well (TUR -)")
    big_u = {m["name"]: m["U"] for m in d.evaluate({"procedure": "rotary_axis"})["measurands"]}
    tol = {"EX0C": {"upper": f"{5 * big_u['EX0C']:.0f}",
                    "prior": f"normal:0,{1.5 * big_u['EX0C']:.0f}", "rule": "iso14253"},
           "EY0C": {"lower": f"{-5 * big_u['EY0C']:.0f}",
                    "prior": f"normal:0,{1.5 * big_u['EY0C']:.0f}", "rule": "iso14253"}}
    ctx, pg = _open(browser, server, {"procedure": "rotary_axis", "tolerances": tol})
    verdict = pg.locator("#verdict").inner_text()
    for name, side in (("EX0C", "upper"), ("EY0C", "lower")):
        u = pg.evaluate(f"window.mtplan.lastResult.measurands.find((m) => m.name === "
                        f"'{name}').u")
        acc = json.loads(_cli("accept", f"--{side}", tol[name][side], "--u", repr(u),
                              "--prior", tol[name]["prior"], "--rule", "iso14253", "--json"))
        assert acc["tur"] is None and acc["judgement"]["quality"] != "cannot be decided well"
        assert pg.locator(f"#acc-tur-{name}").inner_text() == "none (one-sided)"
        for key in ("pfa", "pfr"):
            shown = pg.locator(f"#acc-{key}-{name}").inner_text()
            assert float(shown.rstrip(" %")) == float(f"{100 * acc[key]:.4g}"), (name, key)
        limit = acc["acceptance_limits"][1 if side == "upper" else 0]
        assert pg.locator(f"#acc-limits-{name}").inner_text() == \
            f"{'≤' if side == 'upper' else '≥'} {float(f'{limit:.4g}'):g}"
        judged = acc["judgement"]["text"].replace("items", "machines")
        assert f"{name} {judged}" in verdict, (verdict, judged)
        # the zones: the open side is accepted up to the view's edge, one reject zone
        pg.locator("#risk-of").select_option(name)
        pg.wait_for_function(f"document.querySelector('#zone-plot').layout.xaxis.title.text"
                             f".startsWith('{name}')")
        shapes = pg.evaluate("document.querySelector('#zone-plot').layout.shapes"
                             ".map((s) => [s.name, s.x0, s.x1])")
        view = pg.evaluate("document.querySelector('#zone-plot').layout.xaxis.range")
        bands = {n: (x0, x1) for n, x0, x1 in shapes}
        assert [n for n, *_ in shapes].count("reject") == 1
        if side == "upper":
            assert bands["acceptance"] == pytest.approx((view[0], limit))
            assert bands["reject"] == pytest.approx((limit, view[1]))
            assert bands["tolerance"] == pytest.approx((view[0], float(tol[name][side])))
        else:
            assert bands["acceptance"] == pytest.approx((limit, view[1]))
            assert bands["reject"] == pytest.approx((view[0], limit))
        # the risk curve, with the design's point on it at the rule's guard band
        names = pg.evaluate("document.querySelector('#risk-plot').data.map((t) => t.name)")
        assert names == ["PFA", "PFR", "this design"]
        point = pg.evaluate("document.querySelector('#risk-plot').data[2].y")
        assert point == pytest.approx([100 * acc["pfa"], 100 * acc["pfr"]], rel=1e-9)
    assert "TUR -" not in verdict and "cannot be decided well" not in verdict, verdict
    ctx.close()
