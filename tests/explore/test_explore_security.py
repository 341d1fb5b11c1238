"""The designer's server defends itself, checked against a running ``mtplan explore``:
Host, Origin, content type, token, body size, concurrent jobs and requests, a server path
in the prior, and bad numbers through the API (one line naming the field, no traceback,
no child process spawned)."""

from __future__ import annotations

import http.client
import json
import subprocess
from concurrent.futures import ThreadPoolExecutor

import pytest

from tests.explore.conftest import start_server

DESIGN = {"procedure": "circle_centre", "setup": {}, "trials": 400, "seed": 1}


@pytest.fixture(scope="module")
def server():
    s = start_server("circle_centre")
    yield s
    s.stop()


def _request(server, method, path, body=b"", headers=None, timeout=60):
    """(status, text) of one raw request; `headers` replace the defaults (token, JSON)."""
    h = {"Host": f"127.0.0.1:{server.port}", "X-Mtplan-Token": server.token,
         "Content-Type": "application/json"}
    h.update(headers or {})
    h = {k: v for k, v in h.items() if v is not None}
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=timeout)
    try:
        conn.request(method, path, body=body, headers=h)
        r = conn.getresponse()
        return r.status, r.read().decode(errors="replace"), dict(r.getheaders())
    finally:
        conn.close()


def _one_line(text: str) -> str:
    """The message of an answer (JSON 'error' or plain text), checked to be one line
    without a traceback."""
    try:
        text = json.loads(text)["error"]
    except (ValueError, KeyError, TypeError):
        pass
    assert "Traceback" not in text and 'File "' not in text, text
    assert len(text.strip().splitlines()) == 1, text
    return text


def _children(server) -> int:
    """Processes the server has spawned (its jobs)."""
    r = subprocess.run(["ps", "-o", "pid=", "--ppid", str(server.proc.pid)],
                       capture_output=True, text=True)
    return len(r.stdout.split())


@pytest.mark.parametrize("host", ["attacker.example", "attacker.example:{port}",
                                  "127.0.0.1:1", "localhost.attacker.example:{port}",
                                  "127.0.0.1"])
def test_a_foreign_host_is_refused(server, host):
    status, text, _ = _request(server, "GET", "/api/procedures",
                               headers={"Host": host.format(port=server.port)})
    assert status in (403, 421)
    assert "Host" in _one_line(text)
    for own in (f"127.0.0.1:{server.port}", f"localhost:{server.port}"):
        assert _request(server, "GET", "/api/procedures", headers={"Host": own})[0] == 200


@pytest.mark.parametrize("origin", ["http://attacker.example", "null",
                                    "http://127.0.0.1:1", "https://127.0.0.1:{port}"])
def test_a_foreign_origin_cannot_change_state(server, origin):
    body = json.dumps({"design": DESIGN}).encode()
    status, text, _ = _request(server, "POST", "/api/evaluate", body,
                               {"Origin": origin.format(port=server.port)})
    assert status == 403 and "Origin" in _one_line(text)
    status, _, _ = _request(server, "POST", "/api/jobs", json.dumps(
        {"kind": "confirm", "design": DESIGN}).encode(), {"Origin": "http://attacker.example"})
    assert status == 403
    ok, _, _ = _request(server, "POST", "/api/evaluate", body,
                        {"Origin": f"http://127.0.0.1:{server.port}"})
    assert ok == 200


@pytest.mark.parametrize("kind", ["text/plain", "application/x-www-form-urlencoded",
                                  "multipart/form-data; boundary=x", None])
def test_a_post_that_is_not_json_is_refused(server, kind):
    before = _children(server)
    body = json.dumps({"kind": "confirm", "design": {**DESIGN, "trials": 10**9}}).encode()
    status, text, _ = _request(server, "POST", "/api/jobs", body, {"Content-Type": kind})
    assert status == 415 and "application/json" in _one_line(text)
    assert _children(server) == before


def test_the_token_is_needed_and_the_printed_link_gives_it(server):
    for path in ("/", "/api/procedures", "/api/procedure/circle_centre"):
        status, text, _ = _request(server, "GET", path, headers={"X-Mtplan-Token": None})
        assert status == 403 and "token" in _one_line(text).lower(), path
        status, _, _ = _request(server, "GET", path, headers={"X-Mtplan-Token": "guess"})
        assert status == 403
    status, _, _ = _request(server, "POST", "/api/evaluate", json.dumps({"design": DESIGN}),
                            {"X-Mtplan-Token": None})
    assert status == 403
    # the printed link: a cookie and a redirect to the page without the token in its address
    path = server.link.split(str(server.port), 1)[1]
    status, _, headers = _request(server, "GET", path + "&d=abc", headers={"X-Mtplan-Token": None})
    assert status == 303 and headers["location"] == "/?d=abc"
    cookie = headers["set-cookie"].split(";")[0]
    assert server.token in cookie and "HttpOnly" in headers["set-cookie"]
    assert "SameSite=Strict" in headers["set-cookie"]
    status, text, _ = _request(server, "GET", "/", headers={"X-Mtplan-Token": None,
                                                             "Cookie": cookie})
    assert status == 200 and "<html" in text
    # the static files need none (the page's script and style)
    assert _request(server, "GET", "/static/app.js", headers={"X-Mtplan-Token": None})[0] == 200


def test_a_large_body_is_refused_as_it_streams(server):
    big = b'{"design": {"procedure": "' + b"x" * (10 * 2**20) + b'"}}'
    status, text, _ = _request(server, "POST", "/api/evaluate", big)
    assert status == 413 and "limit" in _one_line(text)

    def chunks():  # no Content-Length: counted as it arrives
        yield b'{"toml": "'
        for _ in range(10):
            yield b"a" * 2**20
        yield b'"}'

    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=60)
    try:
        conn.request("POST", "/api/load", body=chunks(), encode_chunked=True, headers={
            "Host": f"127.0.0.1:{server.port}", "X-Mtplan-Token": server.token,
            "Content-Type": "application/json", "Transfer-Encoding": "chunked"})
        r = conn.getresponse()
        status, text = r.status, r.read().decode()
    except (ConnectionResetError, BrokenPipeError):  # refused before all was sent
        status, text = 413, '{"error": "limit"}'
    finally:
        conn.close()
    assert status == 413 and "limit" in _one_line(text)
    assert server.api("api/procedures")[0] == 200


def test_a_server_path_in_the_prior_is_never_read(server, tmp_path):
    secret = tmp_path / "values.csv"
    secret.write_text("value\n1\n2\n3\n", encoding="utf-8")
    for path in ("/etc/passwd", str(secret)):
        design = {**DESIGN, "tolerances": {"centre_x": {"lower": "-20", "upper": "20",
                                                        "prior": path}}}
        status, r = server.api("api/evaluate", {"design": design})
        assert status == 200
        err = r["measurands"][0]["acceptance"]["error"]
        assert "uploaded" in err and "tokeniz" not in err and "EmpiricalPrior" not in err
    # the same values uploaded as content give the acceptance figures (once u is checked)
    design = {**DESIGN, "tolerances": {"centre_x": {
        "lower": "-20", "upper": "20", "prior_csv": secret.read_text(), "prior_name": "v.csv"}}}
    status, r = server.api("api/check", {"design": design})
    acc = r["measurands"][0]["acceptance"]
    assert status == 200 and "error" not in acc and acc["pfa"] is not None


def test_twenty_concurrent_job_starts_run_at_most_the_cap(server):
    body = {"kind": "confirm", "design": {**DESIGN, "trials": 50_000}}
    with ThreadPoolExecutor(20) as pool:
        answers = list(pool.map(lambda _: server.api("api/jobs", body), range(20)))
    started = [r["id"] for s, r in answers if s == 200]
    refused = [r for s, r in answers if s != 200]
    assert 1 <= len(started) <= 2 and len(refused) == 20 - len(started)
    assert all(s in (429, 503) for s, _ in answers if s != 200)  # the job cap, or the
    for r in refused:  # cap on requests in flight: each a plain line
        assert "running" in _one_line(r if isinstance(r, str) else json.dumps(r)) or \
            "busy" in r
    assert _children(server) <= 2 + 1  # the jobs (and at most a resource tracker)
    for job in started:
        assert server.api(f"api/jobs/{job}/cancel", {})[1]["state"] == "cancelled"


@pytest.mark.parametrize("change, field", [
    ({"trials": "abc"}, "trials"), ({"trials": -5}, "trials"), ({"trials": 1.5}, "trials"),
    ({"trials": 10**9}, "trials"), ({"trials": "1e12"}, "trials"), ({"trials": None}, "trials"),
    ({"seed": -1}, "seed"), ({"seed": "x"}, "seed"), ({"seed": [1]}, "seed"),
    ({"setup": {"n_points": "2"}}, "n_points"), ({"setup": {"spread_deg": "nan"}}, "spread_deg"),
    ({"estimator": "nope"}, "estimator"), ({"kind": "rm -rf"}, "kind"),
])
def test_bad_numbers_are_one_line_naming_the_field_before_any_process(server, change, field):
    before = _children(server)
    kind = change.pop("kind", "confirm")
    status, r = server.api("api/jobs", {"kind": kind, "design": {**DESIGN, **change}})
    assert status == 400, r
    assert field in _one_line(json.dumps(r)), r
    assert _children(server) == before


def test_a_trials_count_over_the_time_budget_is_refused_with_the_estimate(server):
    # tracker_frame's trials take milliseconds: 10^7 of them are hours on any machine
    big = {"procedure": "tracker_frame", "trials": 10**7, "seed": 1}
    status, est = server.api("api/jobs/estimate", {"kind": "confirm", "design": big})
    assert status == 200 and est["seconds"] > 0 and est["text"].startswith("about")
    assert not est["fits"]  # said before it starts, with what fits
    before = _children(server)
    status, r = server.api("api/jobs", {"kind": "confirm", "design": big})
    assert status == 400 and str(est["max_trials"]) in r["error"]
    assert _children(server) == before
    small = server.api("api/jobs/estimate", {"kind": "confirm", "design": DESIGN})[1]
    assert small["fits"] and small["seconds"] < est["seconds"]


def test_many_requests_in_flight_are_refused_plainly_and_the_numbers_still_come(server):
    body = {"design": DESIGN, "field": "spread_deg", "tab": "flood", "change": 1}
    with ThreadPoolExecutor(30) as pool:
        floods = [pool.submit(server.api, "api/sensitivity", body) for _ in range(30)]
        status, r = server.api("api/evaluate", {"design": DESIGN})
        answers = [f.result() for f in floods]
    assert status in (200, 503) and (status == 503 or r["ok"])
    codes = {s for s, _ in answers}
    assert codes <= {200, 429, 503} and codes & {429, 503}
    for s, r in answers:
        if s != 200:
            _one_line(r if isinstance(r, str) else json.dumps(r))
    assert server.api("api/evaluate", {"design": DESIGN})[0] == 200  # alive after the flood
