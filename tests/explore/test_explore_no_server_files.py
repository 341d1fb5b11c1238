"""No file of the server is read on behalf of a request, by any endpoint that takes a
design or a study: a path in a prior, in a set-up's file field, or among a study's
readings is refused (or left unread) with the same answer whether or not the file exists,
and nothing of the file reaches the answer."""

from __future__ import annotations

import json

import pytest

from tests.explore.conftest import start_server

SECRET = "s3cret-line-of-a-server-file"
TOML = """title = "t"
[[procedure]]
name = "rotary_axis"
setup = {{ positions = 8{setup} }}
{readings}
  [[procedure.acceptance]]
  measurand = "EX0C"
  upper = 100.0
  prior = "{prior}"
"""


@pytest.fixture(scope="module")
def server():
    s = start_server("rotary_axis")
    yield s
    s.stop()


@pytest.fixture(scope="module")
def paths(tmp_path_factory):
    folder = tmp_path_factory.mktemp("server")
    there = folder / "values.csv"
    there.write_text(f"value\n1\n2\n{SECRET}\n", encoding="utf-8")
    return str(there), str(folder / "nonexistent.csv")


def _design(path: str, where: str) -> dict:
    if where == "prior":
        return {"procedure": "rotary_axis", "trials": 100, "tolerances": {
            "EX0C": {"upper": "100", "prior": path, "rule": "iso14253"}}}
    return {"procedure": "rotary_axis", "trials": 100,
            "setup": {"sensor_characteristic": path}}


def _study(path: str, where: str) -> str:
    return TOML.format(
        prior=path if where == "prior" else "normal:0,30",
        setup=f', sensor_characteristic = "{path}"' if where == "setup" else "",
        readings=(f'  [procedure.readings]\n  file = "{path}"\n  [procedure.as_left]\n'
                  f'  file = "{path}"\n' if where == "readings" else ""))


CASES = [(endpoint, where) for endpoint in ("evaluate", "check", "sensitivity", "export",
                                            "jobs/estimate", "jobs")
         for where in ("prior", "setup") if (endpoint, where) != ("jobs", "prior")]
CASES += [("load", where) for where in ("prior", "setup", "readings")]


@pytest.mark.parametrize("endpoint, where", CASES)
def test_a_server_path_is_refused_unread_the_same_whether_it_exists(server, paths,
                                                                    endpoint, where):
    answers = []
    for path in paths:
        if endpoint == "load":
            body = {"toml": _study(path, where)}
        elif endpoint == "export":
            body = _design(path, where)
        elif endpoint.startswith("jobs"):
            body = {"kind": "confirm", "design": _design(path, where)}
        else:
            body = {"design": _design(path, where), "field": "incline_deg"}
        status, answer = server.api(f"api/{endpoint}", body)
        text = json.dumps(answer).replace(path, "PATH")
        assert SECRET not in text and "No such file" not in text and "exist" not in text
        answers.append((status, text))
    assert answers[0] == answers[1], answers
    status, text = answers[0]
    if where == "readings":  # a study's measurements are not opened: its set-up is loaded
        assert status == 200 and '"procedure": "rotary_axis"' in text
    elif endpoint == "load":
        assert status == 400 and ("upload the prior's CSV instead" in text if where == "prior"
                                  else "does not read files" in text), text
    elif where == "setup":
        assert "does not read files" in text and "sensor_characteristic" in text, text
    elif endpoint in ("evaluate", "check"):
        assert "reads no file on the server" in text, text
