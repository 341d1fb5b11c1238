"""What the server refuses of a request, at once and by name.

No file of the server is read on behalf of a request, by any endpoint that takes a
design or a study: a path in a prior, in a set-up's file field, or among a study's
readings is refused (or left unread) with the same answer whether or not the file exists,
and nothing of the file reaches the answer. Every malformed payload (a wrong type for any
key of a design, of a study request, of the planner's targets) is one line naming the
key, before any work or process."""

from __future__ import annotations

import json

import pytest

from tests.explore.test_explore_browser import server  # noqa: F401 (mtplan explore)

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
        # (a refusal quotes at most the path's first 60 characters)
        text = json.dumps(answer).replace(path, "PATH").replace(path[:60], "PATH")
        assert SECRET not in text and "No such file" not in text and "not exist" not in text
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


# ------------------------------------------------------------------ malformed payloads
KEYS = ("procedure", "setup", "off", "estimator", "tolerances", "targets", "vary", "lever",
        "seed", "trials")
WRONG = {"text": "abc", "number": 5, "list": [1, "x"], "object": {"a": 1}, "bool": True}
#: the JSON types each key takes (null is the default for every one)
TAKES = {"procedure": "text", "setup": "object", "off": "list", "estimator": "text",
         "tolerances": "object", "targets": "object", "vary": "object", "lever": "text",
         "seed": ("text", "number"), "trials": ("text", "number")}
PAYLOADS = [(key, kind) for key in KEYS for kind in WRONG if kind not in TAKES[key]]
PAYLOADS += [("off", "list"), ("tolerances", "rule"), ("tolerances", "row"),
             ("setup", "value"), ("targets", "value")]
NESTED = {("off", "list"): [1, "x"],
          ("tolerances", "rule"): {"EX0C": {"upper": "10", "rule": 5}},
          ("tolerances", "row"): {"EX0C": [1]}, ("setup", "value"): {"positions": [8]},
          ("targets", "value"): {"EX0C": {"u": 1}}}


@pytest.mark.parametrize("key, kind", PAYLOADS)
@pytest.mark.parametrize("endpoint", ["evaluate", "check", "sensitivity", "export",
                                      "jobs/estimate", "jobs"])
def test_a_wrong_type_for_a_key_is_one_line_naming_the_key(server, endpoint, key, kind):
    design = {"procedure": "rotary_axis", key: NESTED.get((key, kind), WRONG.get(kind))}
    body = design if endpoint == "export" else {"kind": "confirm", "design": design} \
        if endpoint.startswith("jobs") else {"design": design}
    status, answer = server.api(f"api/{endpoint}", body)
    assert status == 400, (status, answer)
    text = answer["error"]
    assert f"'{key}" in text and "\n" not in text and "Error)" not in text, text


@pytest.mark.parametrize("body, key", [
    ({"design": "abc"}, "design"), ({"design": [1]}, "design"),
    ({"design": {}, "field": 5}, "field"), ({"design": {}, "field": "nope"}, "nope")])
def test_a_wrong_body_names_what_is_wrong(server, body, key):
    status, answer = server.api("api/sensitivity", body)
    assert status == 400 and key in answer["error"], answer


@pytest.mark.parametrize("body, key", [({"toml": {"a": 1}}, "toml"),
                                       ({"toml": "", "procedure": 5}, "procedure"),
                                       ({"toml": "procedure = 5"}, "procedure")])
def test_a_wrong_study_names_what_is_wrong(server, body, key):
    status, answer = server.api("api/load", body)
    assert status == 400 and key in answer["error"], answer


@pytest.mark.parametrize("targets, word", [({"EX0C": "abc"}, "target of EX0C"),
                                           ({"EX0C": -1}, "target of EX0C"),
                                           ({"nope": 1}, "'nope'"), ({}, "target")])
def test_the_planners_targets_are_checked_before_a_job_starts(server, targets, word):
    design = {"procedure": "rotary_axis", "targets": targets, "vary": {"positions": "6,8"},
              "trials": 200}
    status, answer = server.api("api/jobs", {"kind": "cheapest", "design": design})
    assert status == 400 and word in answer["error"], answer
