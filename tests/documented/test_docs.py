"""The commands docs/*.md document run as written (see :mod:`tests.documented.commands`),
those README.md holds too excepted (``test_readme.py`` runs them)."""

import json

import pytest

from tests.documented.commands import check, command_id, documented_first_in, run

ARGVS = documented_first_in("docs/*.md")
ALL21 = ("simulate", "geometry21", "--config", "examples/geometry21_all21.toml", "--json")


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory):
    """Each command's (status, stdout, stderr), run when a test first asks for it."""
    done = {}

    def outcome(argv):
        if argv not in done:
            done[argv] = run(argv, tmp_path_factory.mktemp("cmd"))
        return done[argv]

    return outcome


@pytest.mark.parametrize("argv", ARGVS, ids=command_id)
def test_documented_command_runs(argv, outcomes):
    check(argv, outcomes(argv))


def test_all21_simulation_lists_every_error(outcomes):
    assert ALL21 in ARGVS  # docs/geometry21.md shows it
    doc = json.loads(outcomes(ALL21)[1])
    assert len(doc["measurands"]) == 21
    assert all(m["determinable"] and m["u"] > 0 for m in doc["measurands"])
