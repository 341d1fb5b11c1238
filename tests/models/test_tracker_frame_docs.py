"""The numbers docs/tracker_frame.md prints in its checked table are the code's (same trials,
same seed): see tests/models/test_circle_centre_docs.py for the table's form."""

from __future__ import annotations

import pytest

from tests.models.test_circle_centre_docs import check_row, checked_rows

HEADER, ROWS = checked_rows("tracker_frame.md", "test_tracker_frame_docs.py")


@pytest.mark.parametrize("row", ROWS, ids=[" ".join(r[:3]) for r in ROWS])
def test_the_pages_table_is_the_codes(row):
    check_row("tracker_frame", HEADER, row, trials=1000, seed=3)
