"""The commands README.md documents run as written (see :mod:`tests.documented.commands`)."""

import pytest

from tests.documented.commands import check, command_id, documented_first_in, run

ARGVS = documented_first_in("README.md")


@pytest.mark.parametrize("argv", ARGVS, ids=command_id)
def test_documented_command_runs(argv, tmp_path):
    check(argv, run(argv, tmp_path))
