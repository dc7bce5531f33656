"""The hand-made windows of the unmapped pass's tests (test_unmapped, test_stopped_needs_road,
test_stopped_off_facades): a 14 × 20 window of 0.5 m cells at 10 Hz, a street of road and
pavement, and the pass run over a list of decision grids."""

from __future__ import annotations

import numpy as np

from evperc.fusion.twin import DECISION_CODES as D
from evperc.geo.prior import CONTEXT_BUILDING, CONTEXT_OTHER, CONTEXT_ROAD
from evperc.objects.unmapped import UnmappedCue, UnmappedParams, UnmappedState

RES = 0.5
SHAPE = (14, 20)
DT = 0.1  # 10 Hz


def street_labels(building: tuple[slice, slice] = (slice(11, 14), slice(16, 20))) -> np.ndarray:
    """Map context: rows 0-5 road, rows 6-13 pavement (other), and a building at
    ``building`` (rows, cols; by default rows 11-13, cols 16-19, on the pavement)."""
    labels = np.full(SHAPE, CONTEXT_OTHER, np.uint8)
    labels[0:6] = CONTEXT_ROAD
    labels[building] = CONTEXT_BUILDING
    return labels


def free_window() -> np.ndarray:
    """A window decided free everywhere."""
    return np.full(SHAPE, D["free"], np.uint8)


def run_cue(decisions: list[np.ndarray], labels: np.ndarray | None, params: UnmappedParams,
            moving_cells: list[np.ndarray] | None = None
            ) -> tuple[list[np.ndarray], UnmappedCue]:
    """Each decision after the pass, the window fixed (a copy; the input is kept), and the
    cue (its ``stats`` are the last frame's); ``moving_cells``: per frame, or None."""
    cue = UnmappedCue(params, SHAPE, RES)
    state = UnmappedState.fresh(SHAPE)
    out = []
    for k, dec in enumerate(decisions):
        dec = dec.copy()
        cue.step(state, dec, labels, DT,
                 moving_cells=None if moving_cells is None else moving_cells[k])
        out.append(dec)
    return out, cue
