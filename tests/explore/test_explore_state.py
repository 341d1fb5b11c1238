"""State that lives in the designer: a saved design link survives a restart of the
server (the login page asks for the new token and keeps the link), named scenarios survive
a reload and export as studies, and the Monte Carlo's time estimate follows every change.

The login page is also checked as a door: it tells nothing, goes nowhere but the
designer's own page, and takes its token only as JSON from the page's own origin.
"""

from __future__ import annotations

import base64
import http.client
import json
import tomllib
from urllib.parse import parse_qs, urlsplit

import pytest

from mtplan.explore.login import safe_next
from mtplan.plans.study import load_study
from tests.explore.conftest import free_port, start_server

TIMEOUT_MS = 60_000
DESIGN = {"procedure": "rotary_axis", "setup": {"positions": "8", "incline_deg": "30"},
          "off": ["probe_noise"],
          "tolerances": {"EX0C": {"lower": "-150", "upper": "150", "prior": "normal:0,60",
                                  "rule": "iso14253"}}}


def _settled(pg) -> None:
    pg.wait_for_function("window.mtplan && window.mtplan.changes > 0 && "
                         "window.mtplan.rendered === window.mtplan.changes && "
                         "window.mtplan.drawn === window.mtplan.rendered && "
                         "!window.mtplan.inflight")


def _link(server, design) -> str:
    d = base64.urlsafe_b64encode(json.dumps(design).encode()).decode().rstrip("=")
    return f"{server.link}&d={d}"


def _request(server, method, path, body=b"", headers=None):
    h = {"Host": f"127.0.0.1:{server.port}", "Content-Type": "application/json"}
    h.update(headers or {})
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=60)
    try:
        conn.request(method, path, body=body, headers={k: v for k, v in h.items() if v})
        r = conn.getresponse()
        return r.status, r.read().decode(errors="replace"), dict(r.getheaders())
    finally:
        conn.close()


def test_next_is_only_ever_the_designers_own_page():
    assert safe_next("/?d=abc&token=old") == "/?d=abc"
    for bad in ("//evil.example/?d=1", "https://evil.example/", "/\\evil.example",
                "javascript:alert(1)", "/api/jobs", "", None, "http://127.0.0.1:1/?d=1"):
        assert safe_next(bad) == "/", bad


def test_a_saved_link_survives_a_restart_and_scenarios_survive_too(browser, tmp_path):
    """Start, open a design, keep it as a named scenario, stop; start again (same port, new
    token) and open the saved link: the login page asks for the token and keeps the link,
    then the design and the scenario are back, and the scenario exports as a study."""
    port = free_port()
    first = start_server("rotary_axis", port=port)
    ctx = browser.new_context(viewport={"width": 1400, "height": 1000}, accept_downloads=True)
    try:
        pg = ctx.new_page()
        pg.set_default_timeout(TIMEOUT_MS)
        pg.goto(_link(first, DESIGN))
        _settled(pg)
        pg.click("#keep")
        name = pg.locator("#scenarios .scenario-name").first
        name.fill("eight positions")
        name.dispatch_event("change")
        saved = pg.url
        assert "token" not in saved and "d=" in saved
    finally:
        first.stop()

    second = start_server("rotary_axis", port=port)
    try:
        assert second.token != first.token
        # the page left open asks the new server: it is sent to the login page, its design kept
        pg.evaluate("jobEstimate()")
        pg.wait_for_url("**/login?next=*")
        assert parse_qs(urlsplit(pg.url).query)["next"][0] == saved.split(str(port), 1)[1]
        pg.goto(saved)  # the saved link; the browser still holds the first launch's cookie
        pg.wait_for_url("**/login?next=*")
        assert parse_qs(urlsplit(pg.url).query)["next"][0] == saved.split(str(port), 1)[1]
        html = pg.content()
        assert second.token not in html and "EX0C" not in html and "rotary" not in html
        pg.fill("#token", "not-the-token")
        pg.click("#login")
        pg.wait_for_function("document.getElementById('login-error').textContent")
        assert "token" in pg.locator("#login-error").inner_text()
        pg.fill("#token", second.link)  # the printed link pasted whole
        pg.click("#login")
        pg.wait_for_url(saved)
        _settled(pg)
        assert pg.locator("#f-positions").input_value() == "8"
        assert pg.locator("#f-incline_deg").input_value() == "30"
        assert not pg.locator("#on-probe_noise").is_checked()
        assert pg.locator("#tol-prior-EX0C").input_value() == "normal:0,60"
        assert pg.locator("#acc-tur-EX0C").inner_text() != "-"
        # the named scenario was kept by the browser, and is a study `mtplan report` reads
        assert pg.locator("#scenarios .scenario-name").input_value() == "eight positions"
        pg.reload()
        _settled(pg)
        assert pg.locator("#scenarios .scenario-name").count() == 1
        with pg.expect_download() as dl:
            pg.click("#scenarios .scenario-study")
        assert dl.value.suggested_filename == "eight_positions_study.toml"
        path = tmp_path / "scenario.toml"
        dl.value.save_as(path)
        study = load_study(tomllib.loads(path.read_text()))
        ps = study.procedures[0]
        assert ps.name == "rotary_axis" and ps.setup.positions == 8
        assert ps.setup.incline_deg == 30 and ps.setup.probe_noise_um == 0
        assert [a["measurand"] for a in ps.acceptance] == ["EX0C"]
    finally:
        ctx.close()
        second.stop()


@pytest.fixture(scope="module")
def server():
    s = start_server("circle_centre")
    yield s
    s.stop()


def test_the_login_page_tells_nothing_and_takes_the_token_only_from_its_own_page(server):
    # a browser without the token is sent to the login page, the link kept as `next`
    status, _, headers = _request(server, "GET", "/?d=abc", headers={"Accept": "text/html"})
    assert status == 303 and headers["location"] == "/login?next=%2F%3Fd%3Dabc"
    # a script still gets the plain refusal
    status, text, _ = _request(server, "GET", "/?d=abc")
    assert status == 403 and "Token" in text
    status, page, headers = _request(server, "GET", "/login?next=%2F%3Fd%3Dabc")
    assert status == 200 and "<form" in page and server.token not in page
    assert "circle" not in page and "abc" not in page  # nothing of the server or the link
    assert headers["x-frame-options"] == "DENY" and headers["cache-control"] == "no-store"
    body = json.dumps({"token": server.token, "next": "//evil.example/"}).encode()
    # another site's page, a form or text POST, a wrong token: refused, no cookie
    for extra, want in (({"Origin": "http://evil.example"}, 403),
                        ({"Content-Type": "text/plain"}, 415),
                        ({"Content-Type": "application/x-www-form-urlencoded"}, 415)):
        status, _, headers = _request(server, "POST", "/login", body, extra)
        assert status == want and "set-cookie" not in headers
    status, text, headers = _request(server, "POST", "/login", json.dumps(
        {"token": "guess"}).encode(), {"Origin": f"http://127.0.0.1:{server.port}"})
    assert status == 403 and "set-cookie" not in headers
    assert len(json.loads(text)["error"].splitlines()) == 1
    for wrong in (b"[]", b'{"token": 5}', b"not json"):
        assert _request(server, "POST", "/login", wrong)[0] in (400, 403)
    # the right one: the cookie, and `next` is never another site
    status, text, headers = _request(server, "POST", "/login", body,
                                     {"Origin": f"http://127.0.0.1:{server.port}"})
    assert status == 200 and json.loads(text) == {"next": "/"}
    assert "HttpOnly" in headers["set-cookie"] and "SameSite=Strict" in headers["set-cookie"]
    cookie = headers["set-cookie"].split(";")[0]
    assert _request(server, "GET", "/api/procedures", headers={"Cookie": cookie})[0] == 200


def test_the_monte_carlos_time_follows_every_change(browser, server):
    """After a lever moves (not only after a trials or seed edit) the page asks the server
    for the Monte Carlo's time of the design shown, and shows that answer: geometry21's
    points per line size a trial."""
    ctx = browser.new_context(viewport={"width": 1400, "height": 1000})
    try:
        pg = ctx.new_page()
        pg.set_default_timeout(TIMEOUT_MS)
        answers = []  # (the design asked about, the server's answer)
        pg.on("response", lambda r: answers.append((r.request.post_data_json["design"], r))
              if r.url.endswith("/api/jobs/estimate") else None)
        pg.goto(_link(server, {"procedure": "geometry21", "trials": 10000}))
        _settled(pg)
        for points in ("21", "101"):
            box = pg.locator("#f-line_points")
            box.fill(points)
            box.dispatch_event("change")
            _settled(pg)
            pg.wait_for_function("() => { const e = document.getElementById('job-estimate');"
                                 "return e.dataset.design === JSON.stringify(window.mtplan.design); }")
            design = pg.evaluate("window.mtplan.design")
            assert design["setup"]["line_points"] == points
            cost = [r for d, r in answers if d == design][-1].json()
            shown = pg.locator("#job-estimate").inner_text()
            assert shown == (f"10000 trials: {cost['text']}" if cost["fits"] else cost["refusal"])
            assert cost["design"]["setup"]["line_points"] == points
    finally:
        ctx.close()
