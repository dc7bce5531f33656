"""A check shared by the tests of the step-9 rules (tests/objects/test_moving_needs_object.py,
test_support.py): two runs of one drive, the second with a rule that may only send moving
cells no moving record holds to ``static``."""

from __future__ import annotations

import numpy as np

from evperc.fusion.twin import DECISION_CODES as D
from evperc.output.objects import OBJECT_STATES


def unheld_static(a, b) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``b`` against ``a`` (the same scan): masses and objects equal; the decision
    differs only on cells decided moving in ``a`` that no moving record of the frame holds,
    now ``static``. Returns (those cells of ``a``, the cells that changed), bool layers."""
    np.testing.assert_array_equal(a.masses, b.masses)
    np.testing.assert_array_equal(a.objects, b.objects)
    labels = a.object_labels()
    moving_ids = a.objects["track_id"][a.objects["state"] == OBJECT_STATES["moving"]]
    held = np.isin(labels, moving_ids) & (labels > 0)
    da, db = np.asarray(a.decision), np.asarray(b.decision)
    unheld = (da == D["moving"]) & ~held
    changed = da != db
    assert not (changed & ~unheld).any()
    assert (db[changed] == D["static"]).all()
    return unheld, changed
