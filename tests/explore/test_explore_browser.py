"""The designer in a real browser: one ``mtplan explore`` server and one headless Chromium
for the whole module, driven by Playwright against Debian's Chromium.

What the page shows is checked against the commands it stands for: ``mtplan linearize``
(U), ``mtplan accept`` (TUR and risks), ``mtplan report`` (the exported study) and
``mtplan simulate`` (Monte Carlo confirmation).
"""

from __future__ import annotations

import json
import subprocess
import tomllib
from pathlib import Path

import pytest

from tests.explore.conftest import MTPLAN, start_server

TIMEOUT_MS = 60_000  # first evaluations import scipy and numpy on a busy machine


def _cli(*args) -> str:
    r = subprocess.run([*MTPLAN, *args], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    return r.stdout


@pytest.fixture(scope="module")
def server():
    s = start_server("rotary_axis")
    yield s
    s.stop()


@pytest.fixture
def page(browser, server):
    ctx = browser.new_context(viewport={"width": 1400, "height": 1000}, accept_downloads=True)
    pg = ctx.new_page()
    pg.set_default_timeout(TIMEOUT_MS)
    pg.goto(server.link)
    _settled(pg)
    yield pg
    ctx.close()


def _settled(pg) -> None:
    """Wait until the numbers on the page, then its figures and link, answer the last change."""
    pg.wait_for_function("window.mtplan && window.mtplan.changes > 0 && "
                         "window.mtplan.rendered === window.mtplan.changes && "
                         "window.mtplan.drawn === window.mtplan.rendered && "
                         "!window.mtplan.inflight && !(window.mtplan.lastResult && "
                         "window.mtplan.lastResult.ok && "
                         "window.mtplan.lastResult.measurands.some((m) => m.pending))")


def _set(pg, field: str, value) -> None:
    box = pg.locator(f"#f-{field}")
    box.fill(str(value))
    box.dispatch_event("change")
    _settled(pg)


def _cell(pg, row: str, cls: str) -> float:
    return float(pg.locator(f"#{row} td.{cls}").inner_text())


def test_levers_give_linearize_u_and_accept_gives_risks(page):
    _set(page, "positions", 8)
    _set(page, "incline_deg", 30)
    doc = json.loads(_cli("linearize", "rotary_axis", "--set", "positions=8",
                          "--set", "incline_deg=30", "--json"))
    u = next(m["u"] for m in doc["measurands"] if m["name"] == "EX0C")
    assert _cell(page, "m-EX0C", "u") == float(f"{u:.3g}")
    assert _cell(page, "m-EX0C", "U") == float(f"{2 * u:.3g}")
    # the budget plot, drawn after the numbers' frame, is that of the numbers shown
    drawn = page.evaluate("""() => { const r = window.mtplan.lastResult;
        const plot = document.getElementById('budget-plot').data;
        const m = r.measurands.findIndex((x) => x.name === 'EX0C');
        return plot.map((t) => [t.name, t.x[m], 100 * (r.measurands[m].budget[t.name] || 0) ** 2
                                / r.measurands[m].u ** 2]); }""")
    assert drawn and all(x == pytest.approx(want, rel=1e-9) for _, x, want in drawn)

    # a tolerance the set-up can decide (U of EX0C is about 70 um with the 10 mm sensor read
    # one way: the odd part of its angle influence)
    for key, value in (("lower", "-150"), ("upper", "150"), ("prior", "normal:0,60")):
        box = page.locator(f"#tol-{key}-EX0C")
        box.fill(value)
        box.dispatch_event("change")
    _settled(page)
    acc = json.loads(_cli("accept", "--lower", "-150", "--upper", "150", "--u", repr(u),
                          "--prior", "normal:0,60", "--rule", "iso14253", "--json"))
    assert float(page.locator("#acc-tur-EX0C").inner_text()) == float(f"{acc['tur']:.4g}")
    for key in ("pfa", "pfr"):
        shown = page.locator(f"#acc-{key}-EX0C").inner_text()
        assert float(shown.rstrip(" %")) == float(f"{100 * acc[key]:.4g}"), key
    lo, hi = acc["acceptance_limits"]
    assert page.locator("#acc-limits-EX0C").inner_text() == \
        f"[{float(f'{lo:.4g}'):g}, {float(f'{hi:.4g}'):g}]"

    # the link holds the design: a new tab opened on it shows the same state
    url = page.url
    other = page.context.new_page()
    other.set_default_timeout(TIMEOUT_MS)
    other.goto(url)
    _settled(other)
    assert other.locator("#f-positions").input_value() == "8"
    assert other.locator("#f-incline_deg").input_value() == "30"
    assert other.locator("#tol-prior-EX0C").input_value() == "normal:0,60"
    assert other.locator("#m-EX0C td.U").inner_text() == page.locator("#m-EX0C td.U").inner_text()
    assert other.locator("#acc-pfa-EX0C").inner_text() == page.locator("#acc-pfa-EX0C").inner_text()
    # ... and does not share it: a change in one tab leaves the other as it was
    _set(other, "positions", 4)
    assert page.locator("#f-positions").input_value() == "8"
    assert page.locator("#m-EX0C td.U").inner_text() != other.locator("#m-EX0C td.U").inner_text()


def test_export_is_a_study_that_report_accepts(page, tmp_path):
    _set(page, "positions", 7)
    _set(page, "incline_deg", 25)
    page.locator("#on-flatness").uncheck()
    _settled(page)
    page.locator("#tol-upper-EX0C").fill("8")
    page.locator("#tol-upper-EX0C").dispatch_event("change")
    _settled(page)
    with page.expect_download() as dl:
        page.locator("#export").click()
    study = tmp_path / "study.toml"
    dl.value.save_as(study)
    data = tomllib.loads(study.read_text(encoding="utf-8"))
    setup = data["procedure"][0]["setup"]
    assert (setup["positions"], setup["incline_deg"], setup["flatness_um"]) == (7, 25.0, 0.0)
    assert data["procedure"][0]["acceptance"][0]["upper"] == 8.0

    from mtplan.plans.study import load_study

    ps = load_study(study).procedures[0]
    assert (ps.setup.positions, ps.setup.incline_deg, ps.setup.flatness_um) == (7, 25.0, 0.0)
    study.write_text(study.read_text(encoding="utf-8").replace("trials = 10000", "trials = 200"),
                     encoding="utf-8")
    out = tmp_path / "report"
    _cli("report", str(study), "--out", str(out))
    html = (out / "plan.html").read_text(encoding="utf-8")
    assert (out / "report.pdf").exists() and "EX0C" in html and "flatness" in html

    # the file loads back into the page with the same set-up
    fresh = page.context.new_page()
    fresh.set_default_timeout(TIMEOUT_MS)
    fresh.goto(page.url.split("?")[0])  # the cookie holds the token
    _settled(fresh)
    fresh.locator("#load").set_input_files(str(study))
    fresh.wait_for_function("document.querySelector('#f-positions').value === '7'")
    _settled(fresh)
    assert fresh.locator("#f-incline_deg").input_value() == "25"
    assert not fresh.locator("#on-flatness").is_checked()
    assert fresh.locator("#m-EX0C td.U").inner_text() == page.locator("#m-EX0C td.U").inner_text()


def test_bad_value_is_shown_beside_its_control_and_the_server_goes_on(page, server):
    _set(page, "positions", 2)
    message = page.locator("#err-positions").inner_text()
    assert "positions" in message and "2" in message and ">= 3" in message
    assert "not evaluated" in page.locator("#status").inner_text()
    _set(page, "incline_deg", "abc")
    assert "incline_deg" in page.locator("#err-incline_deg").inner_text()
    assert server.api("api/procedures")[0] == 200
    _set(page, "positions", 6)
    _set(page, "incline_deg", 20)
    assert page.locator("#err-positions").inner_text() == ""
    assert _cell(page, "m-EX0C", "U") > 0


def test_confirm_by_monte_carlo_matches_simulate_and_cancels(page):
    page.locator("#trials").fill("400")
    page.locator("#trials").dispatch_event("change")
    page.locator("#seed").fill("5")
    page.locator("#seed").dispatch_event("change")
    page.locator("#confirm").click()
    page.wait_for_selector("#mc-table", timeout=120_000)
    doc = json.loads(_cli("simulate", "rotary_axis", "--trials", "400", "--seed", "5", "--json"))
    for m in doc["measurands"]:
        assert float(page.locator(f"#mc-{m['name']} td.mc-u").inner_text()) == \
            float(f"{m['u']:.3g}"), m["name"]
    # the histogram of the Monte Carlo values, with the measurand's unit on its axis
    page.wait_for_selector("#mc-hist .main-svg")
    assert page.evaluate("document.querySelector('#mc-hist').data[0].y.reduce((a, b) => a + b)"
                         ) == 400
    assert "[\u00b5m]" in page.evaluate("document.querySelector('#mc-hist').layout.xaxis"
                                        ".title.text")
    # a long run (within a job's time budget): progress shown, then cancelled
    page.locator("#trials").fill("1e5")
    page.locator("#trials").dispatch_event("change")
    page.locator("#confirm").click()
    page.wait_for_selector("#job:not([hidden])")
    # the progress shows where the user is looking, not below the screen
    assert page.evaluate("(() => { const r = document.querySelector('#job')"
                         ".getBoundingClientRect(); return r.top >= 0 && "
                         "r.bottom <= window.innerHeight; })()")
    page.locator("#job-cancel").click()
    page.wait_for_selector("#job-cancelled")
    _set(page, "positions", 9)
    assert _cell(page, "m-EX0C", "U") > 0


LEVERS = {"rotary_axis": ("lattice_nx", 4), "geometry21": ("circle_radius_mm", 45),
          "circle_centre": ("n_points", 5), "line_laser": ("raise_mm", 1.5),
          "tracker_frame": ("points_per_arc", 9)}
#: set-ups the page opens through its link (none: every procedure at its defaults, line_laser
#: at its default scan of 15 600 readings, whose first-order budget is its own hook's)
START: dict = {}


@pytest.mark.parametrize("name", sorted(LEVERS))
def test_every_procedure_loads_and_follows_a_lever(browser, server, name):
    import base64

    design = {"procedure": name, "setup": START.get(name, {})}
    link = base64.urlsafe_b64encode(json.dumps(design).encode()).decode().rstrip("=")
    ctx = browser.new_context(viewport={"width": 1400, "height": 1000})
    page = ctx.new_page()
    page.set_default_timeout(120_000)
    page.goto(f"{server.link}&d={link}")
    _settled(page)
    assert page.locator("#procedure").input_value() == name
    first = page.locator("table#measurands tbody tr").first.locator("td.U").inner_text()
    field, value = LEVERS[name]
    _set(page, field, value)
    assert page.locator(f"#err-{field}").inner_text() == ""
    assert "up to date" in page.locator("#status").inner_text()
    rows = page.locator("table#measurands tbody tr")
    assert rows.count() >= 3
    assert first != "-" and rows.first.locator("td.U").inner_text() != "-"
    assert f"{field}=" in "".join(page.url) or "d=" in page.url
    ctx.close()


# ------------------------------------------------------------------ the defects of a new user
def _open(browser, server, design: dict, width: int = 1400):
    import base64

    link = base64.urlsafe_b64encode(json.dumps(design).encode()).decode().rstrip("=")
    ctx = browser.new_context(viewport={"width": width, "height": 1000})
    pg = ctx.new_page()
    pg.set_default_timeout(120_000)
    pg.goto(f"{server.link}&d={link}")
    _settled(pg)
    return ctx, pg


def test_trials_read_scientific_notation(page):
    page.locator("#trials").fill("1e6")
    page.locator("#trials").dispatch_event("change")
    assert page.evaluate("window.mtplan.design.trials") == 1_000_000
    page.wait_for_function("/1000000|trials/.test(document.querySelector('#job-estimate')"
                           ".textContent)")


def test_acceptance_table_follows_the_measurands(page):
    page.locator("#f-axis").select_option("A")
    page.locator("#f-axis").dispatch_event("change")
    _settled(page)
    shown = page.evaluate("[...document.querySelectorAll('#measurands tbody tr')]"
                          ".map((r) => r.id.slice(2))")
    table = page.evaluate("[...document.querySelectorAll('#acceptance tbody tr')]"
                          ".map((r) => r.id.slice(4))")
    assert shown and table == shown and "EY0A" in shown


def test_the_sensitivity_frame_says_how_to_fill_it_until_a_lever_is_moved(browser, server):
    ctx, pg = _open(browser, server, {"procedure": "circle_centre"})
    msg = pg.locator("#sens-msg")
    pg.wait_for_function("/^Move a lever/.test(document.querySelector('#sens-msg').textContent)")
    _set(pg, "spread_deg", 100)
    pg.wait_for_function("document.querySelector('#sens-plot').dataset.field === 'spread_deg'")
    assert msg.text_content() == ""
    ctx.close()


def test_plots_recover_after_a_refusal(page):
    page.wait_for_function("document.querySelector('#sens-plot').dataset.field")
    _set(page, "incline_deg", "abc")  # refused: the plots are marked old, not replaced
    assert page.locator("#sens-plot.js-plotly-plot").count() == 1
    _set(page, "range_deg", "100")
    _set(page, "range_deg", "")  # an optional lever cleared: no curve for it, said beside
    page.wait_for_function("document.querySelector('#sens-msg').textContent.length > 0 || "
                           "document.querySelector('#sens-plot').dataset.field === 'range_deg'")
    _set(page, "incline_deg", "30")
    page.wait_for_function("document.querySelector('#sens-plot').dataset.field === "
                           "'incline_deg' && !document.querySelector('#sens-plot')"
                           ".classList.contains('stale')")
    assert page.locator("#sens-plot .main-svg").count() >= 1


def test_old_results_are_marked_after_a_change(page):
    page.locator("#trials").fill("200")
    page.locator("#trials").dispatch_event("change")
    page.locator("#confirm").click()
    page.wait_for_selector("#mc-table", timeout=180_000)
    assert page.locator("#job-stale").count() == 0
    _set(page, "positions", 9)
    assert "earlier set-up" in page.locator("#job-stale").inner_text()
    assert "stale" in page.locator("#job-result").get_attribute("class")


def test_a_cell_first_order_gets_wrong_is_marked_and_never_green(browser, server):
    ctx, pg = _open(browser, server, {"procedure": "line_laser",
                                      "targets": {"alpha_z": "10", "alpha_y": "1e9"}})
    row = pg.locator("#m-alpha_z")
    assert "untrusted" in row.get_attribute("class") and "meet" not in row.get_attribute("class")
    assert "not reliable" in row.locator("td.U").inner_text()
    assert pg.evaluate("document.querySelector('#procedure').value") == "line_laser"
    ctx.close()


def test_every_input_has_an_accessible_name(page):
    missing = page.evaluate("""() => [...document.querySelectorAll('input, select')]
        .filter((e) => !(e.getAttribute('aria-label') || (e.id && document.querySelector(
            `label[for="${e.id}"]`)) || e.closest('label')))
        .map((e) => e.id || e.outerHTML.slice(0, 60))""")
    assert missing == []


def test_phone_width_stacks_and_print_hides_the_buttons(browser, server):
    ctx, pg = _open(browser, server, {"procedure": "rotary_axis"}, width=390)
    assert pg.evaluate("document.documentElement.scrollWidth") <= 390
    assert pg.evaluate("document.querySelector('#results').getBoundingClientRect().width") > 300
    pg.emulate_media(media="print")
    assert pg.evaluate("[...document.querySelectorAll('header button')]"
                       ".every((b) => getComputedStyle(b).display === 'none')")
    assert pg.locator("#report-measurands").is_visible()  # the one-page report, no controls
    assert not pg.locator("#measurands").is_visible()
    ctx.close()


# ------------------------------------------------------------------ help and verdict
GLOSSARY = Path(__file__).resolve().parents[2] / "docs" / "glossary.md"
HELP_PAGES = [{"procedure": "rotary_axis"},
              {"procedure": "geometry21"}, {"procedure": "circle_centre"},
              {"procedure": "line_laser"}, {"procedure": "tracker_frame"}]


@pytest.mark.parametrize("design", HELP_PAGES, ids=[p["procedure"] for p in HELP_PAGES])
def test_every_code_on_the_page_has_help_in_the_glossarys_or_the_procedures_words(
        browser, server, design):
    from mtplan.models import get
    from mtplan.models.protocol import fields_info

    rows = [[c.strip() for c in line.strip().strip("|").split("|")] for line in
            GLOSSARY.read_text(encoding="utf-8").replace("`", "").splitlines()
            if line.startswith("|")]
    words = {f"{r[0]}: {r[1]}" for r in rows if len(r) == 2}  # each row as the page says it
    proc = get(design["procedure"])
    ctx, pg = _open(browser, server, design)
    pg.wait_for_function("document.querySelectorAll('#help-list dt').length > 0")
    # every measurand code (both tables): the glossary's row, linked to its help entry
    codes = pg.evaluate("[...document.querySelectorAll('#measurands .code, #acceptance .code')]"
                        ".map((a) => [a.textContent, a.title, a.getAttribute('href')])")
    names = [m.name for m in proc.measurands(proc.Setup(**design.get("setup", {})))]
    assert sorted({c[0] for c in codes}) == sorted(names)
    descriptions = {m.name: m.description
                    for m in proc.measurands(proc.Setup(**design.get("setup", {})))}
    for code, title, href in codes:
        assert title.removesuffix(f". {descriptions[code]}") in words, (code, title)
        assert href and pg.locator(href).count() == 1, code
    # every lever: its field's own documentation
    docs = {f.name: f.doc for f in fields_info(proc.Setup)}
    for name in proc.levers:
        assert pg.locator(f"#row-{name}").get_attribute("title").startswith(docs[name]), name
        assert pg.locator(f"#help-f-{name} + dd").text_content() == docs[name]
    # every estimator: its record's description
    # every control's unit as an engineer writes it (um as µm, k_per_m as K/m)
    units = pg.evaluate("[...document.querySelectorAll('.field .unit')].map((u) => u.textContent)")
    assert not [u for u in units if "_" in u or u in ("um", "urad", "deg", "c", "k")], units
    for name, est in proc.estimators.items():
        assert pg.locator(f"#estimator option[value='{name}']").get_attribute("title") == \
            est.description
    # every term in the headings (TUR, PFA, PFR, guard band, O1, ...): the glossary's words
    terms = pg.evaluate("[...document.querySelectorAll('[data-term]')].map((e) => e.title)")
    assert len(terms) >= 15
    for title in terms:
        assert title in words, title
    # a code's link opens the help at its entry
    pg.locator("#measurands a.code").first.click()
    assert pg.evaluate("document.querySelector('#help').open")
    hit = pg.locator("#help-list dt.hit")
    hit.wait_for(state="visible", timeout=5000)
    # a live result that lands later redraws the list: the entry opened stays marked
    pg.evaluate("renderHelp(null)")
    assert hit.count() == 1 and hit.is_visible()
    ctx.close()


def test_the_verdict_says_plainly_what_a_poor_design_decides(page):
    from scipy.stats import norm

    from mtplan.plans.acceptance import parse_prior, plan_acceptance

    line = page.locator("#verdict").inner_text()
    U = _cell(page, "m-EX0C", "U")
    assert "at a TUR of 4 it decides tolerances of \u00b14 U or wider" in line
    shown = float(line.split("EX0C \u00b1", 1)[1].split(" \u00b5m")[0])
    assert shown == pytest.approx(4 * U, rel=0.01)  # (U as shown is rounded to 3 digits)
    # a tolerance of TUR 1.46, as the issue found: about half the good machines rejected
    half = round(1.46 * U, 1)
    sd = float(f"{half / 3:.3g}")  # a population of which about half would be rejected
    prior = f"normal:0,{sd:g}"
    for key, value in (("lower", -half), ("upper", half), ("prior", prior)):
        box = page.locator(f"#tol-{key}-EX0C")
        box.fill(str(value))
        box.dispatch_event("change")
    _settled(page)
    u = U / 2
    r = plan_acceptance(-half, half, u, prior=parse_prior(prior), rule="iso14253")
    good = r.pfr / (norm.cdf(half, scale=sd) - norm.cdf(-half, scale=sd))
    assert 0.4 <= good < 0.6, good  # the numbers chosen for "about half"
    line = page.locator("#verdict").inner_text()
    assert "EX0C cannot be decided well" in line, line
    assert f"TUR {float(f'{r.tur:.3g}'):g}" in line, line
    assert "about half of the good machines would be rejected" in line, line
    assert line.count("\n") == 0


def test_the_views_engineers_expect(page):
    """Risk curve, zones, GUM budget table, CSV and PNG downloads, scenarios and undo."""
    _set(page, "positions", 8)
    U = _cell(page, "m-EX0C", "U")
    for key, value in (("lower", -2 * U), ("upper", 2 * U), ("prior", f"normal:0,{U:.3g}")):
        box = page.locator(f"#tol-{key}-EX0C")
        box.fill(str(value))
        box.dispatch_event("change")
    _settled(page)
    # every column of the tolerance table in view at a desktop width, PFR included
    assert page.evaluate("document.querySelector('#acceptance').getBoundingClientRect().right"
                         " <= document.querySelector('#results').getBoundingClientRect().right")
    # the risk curve: PFA and PFR against the guard band, the design's point on it
    names = page.evaluate("document.querySelector('#risk-plot').data.map((t) => t.name)")
    assert names == ["PFA", "PFR", "this design"]
    assert page.evaluate("document.querySelector('#risk-plot').layout.xaxis.title.text") == \
        "guard band w [\u00b5m]"
    gb = float(page.locator("#acc-gb-EX0C").inner_text())
    assert page.evaluate("document.querySelector('#risk-plot').data[2].x[0]") == \
        pytest.approx(gb, rel=1e-3)
    # the zones: tolerance, acceptance and reject bands on the measurand's axis
    shapes = page.evaluate("document.querySelector('#zone-plot').layout.shapes.map((s) => s.name)")
    assert {"tolerance", "acceptance", "reject"} <= set(shapes)
    # the GUM budget table: contribution = c x input u, the shares add to 100 %
    rows = page.evaluate("""[...document.querySelectorAll('#budget-table tbody tr')].map(
        (r) => [...r.children].map((c) => c.textContent))""")
    assert rows and {r[0] for r in rows} <= set(page.evaluate(
        "window.mtplan.lastResult.measurands[0].budget_table.map((b) => b.source)"))
    shares = [float(r[4].split()[0]) for r in rows if r[4] not in ("-", "< 0.01 %")]
    assert sum(shares) == pytest.approx(100, abs=0.5)
    for r in rows:
        if r[1] != "-" and r[2] != "-":
            c, x, contribution = (float(r[k].split()[0]) for k in (2, 1, 3))
            assert c * x == pytest.approx(contribution, rel=0.02), r
    # every table as CSV, every plot as PNG
    with page.expect_download() as dl:
        page.locator("button.csv[data-table='measurands']").click()
    text = Path(dl.value.path()).read_text(encoding="utf-8")
    assert dl.value.suggested_filename == "rotary_axis_measurands.csv"
    assert text.splitlines()[0].startswith("Measurand,Unit,u,U (k=2)") and "\nEX0C," in text
    with page.expect_download() as dl:
        page.locator("#budget-plot .modebar-btn").first.click()
    assert dl.value.suggested_filename == "rotary_axis_budget.png"
    assert Path(dl.value.path()).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # two scenarios side by side, then undo back to the first one's set-up
    page.locator("#keep").click()
    _set(page, "positions", 12)
    page.locator("#keep").click()
    head = page.locator("#scenarios tr").first.locator("th")
    assert head.count() == 3
    # (EX0C's U is its sensor's angle influence, the same at 8 and 12 positions; EA0C's is not)
    cells = page.locator("#scenarios tr", has_text="EA0C").locator("td")
    assert cells.nth(1).inner_text() != cells.nth(2).inner_text()
    page.locator("#undo").click()
    _settled(page)
    assert page.locator("#f-positions").input_value() == "8"
    assert _cell(page, "m-EX0C", "U") == U
    # an error in the tolerance table is shown whole, never clipped
    box = page.locator("#tol-lower-EX0C")
    box.fill("abc")
    box.dispatch_event("change")
    _settled(page)
    cell = page.locator("#acc-tur-EX0C")
    assert "number" in cell.inner_text()
    assert page.evaluate("(() => { const c = document.querySelector('#acc-tur-EX0C'); "
                         "return c.scrollWidth <= c.clientWidth + 1; })()")
