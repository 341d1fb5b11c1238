"""The commands in the headers of the files in examples/ run as written (see
:mod:`tests.documented.commands`), those a document holds too excepted."""

import pytest

from tests.documented.commands import (
    COMMANDS,
    DOCUMENT_COMMANDS,
    EXAMPLE_COMMANDS,
    EXAMPLES,
    check,
    command_id,
    documented_first_in,
    run,
)

ARGVS = documented_first_in("examples/*")


def test_the_commands_are_found():
    """The collection finds what the documents hold (a change of format must not hide them)."""
    assert len(DOCUMENT_COMMANDS) >= 20
    headers = {tuple(a) for f, a in EXAMPLE_COMMANDS if f.endswith("geometry21_all21.toml")}
    assert headers == {("plan", "geometry21", "--config", "examples/geometry21_all21.toml"),
                       ("simulate", "geometry21", "--config", "examples/geometry21_all21.toml",
                        "--json")}
    used = " ".join(" ".join(argv) for argv in COMMANDS)
    for path in EXAMPLES.iterdir():  # every example file is used by a command
        assert f"examples/{path.name}" in used, path.name


def test_every_command_is_run_by_one_module():
    """README.md, docs/ and examples/ hold every command between them: none is left out."""
    modules = [documented_first_in(p) for p in ("README.md", "docs/*.md", "examples/*")]
    assert sorted(a for argvs in modules for a in argvs) == COMMANDS


@pytest.mark.parametrize("argv", ARGVS, ids=command_id)
def test_documented_command_runs(argv, tmp_path):
    check(argv, run(argv, tmp_path))
