"""Each record's cells from a frame's concatenated object cells (evperc.output.objects)."""

from __future__ import annotations

import numpy as np
import pytest

from evperc.output.objects import OBJECT_DTYPE, empty_objects, record_cells


def test_cells_split_by_record_in_order() -> None:
    objects = np.zeros(3, OBJECT_DTYPE)
    objects["cell_count"] = (2, 0, 3)
    got = record_cells(objects, np.array([7, 9, 1, 2, 3], np.uint32))
    assert [c.tolist() for c in got] == [[7, 9], [], [1, 2, 3]]
    assert all(c.dtype == np.int64 for c in got)


def test_no_records() -> None:
    assert record_cells(empty_objects(), np.zeros(0, np.uint32)) == []


def test_counts_that_do_not_match_the_cells_are_refused() -> None:
    objects = np.zeros(1, OBJECT_DTYPE)
    objects["cell_count"] = 2
    with pytest.raises(ValueError, match="3 object cells, the records list 2"):
        record_cells(objects, np.arange(3))
