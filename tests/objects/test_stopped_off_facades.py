"""Step 5 of the unmapped pass, a façade is not `stopped` (``objects.stopped_off_facades``,
evperc.objects.unmapped): hand-made decision grids, the expected result worked out in the
comments."""

from __future__ import annotations

import numpy as np

from evperc.config import load_config
from evperc.fusion.twin import DECISION_CODES as D
from evperc.objects.unmapped import STAT_UNSTOPPED, UnmappedParams
from tests.objects.unmapped_grids import free_window, run_cue, street_labels

ON = UnmappedParams(max_width_m=0.55, min_age_s=0.1, stopped_needs_road=True,
                    stopped_off_facades=True)
OFF = UnmappedParams(max_width_m=0.55, min_age_s=0.1, stopped_needs_road=True)
#: rows 0-5 road, rows 6-13 pavement (other); a building on the road's edge at rows 0-3,
#: cols 14-19 (its face along col 13 and row 4 is road context)
STREET = street_labels((slice(0, 4), slice(14, 20)))


def _run(decisions, params=ON, moving_cells=None):
    return run_cue(decisions, STREET, params, moving_cells)


def test_facade_strip_on_the_road_is_not_stopped() -> None:
    dec = free_window()
    dec[0:4, 13] = D["stopped"]      # the façade's returns in the road cells along its face:
    dec[4, 13] = D["static"]         # one component of 5 cells, a line (width 1 cell = 0.5 m
    # <= 0.55 m), on the road (so step 4 leaves it), 8-next to the building, never moving:
    # step 5 makes its 4 stopped cells static
    (final,), cue = _run([dec])
    want = dec.copy()
    want[0:4, 13] = D["static"]
    np.testing.assert_array_equal(final, want)
    (row,) = cue.stats
    assert row[STAT_UNSTOPPED] == 4
    (final,), cue = _run([dec], OFF)  # the rule off: the fusion's decision stands
    np.testing.assert_array_equal(final, dec)
    assert cue.stats[0, STAT_UNSTOPPED] == 0


def test_car_parked_against_the_wall_stays_stopped() -> None:
    dec = free_window()
    dec[0:4, 13] = D["stopped"]      # the façade strip ...
    dec[0:4, 9:13] = D["stopped"]    # ... joined by a car 2 m x 2 m beside it: one component
    # of 20 cells, 4 cells long, 5 wide (width 20 / 4 = 5 cells = 2.5 m): not a strip
    (final,), _ = _run([dec])
    np.testing.assert_array_equal(final, dec)


def test_strip_away_from_buildings_stays_stopped() -> None:
    dec = free_window()
    dec[5, 2:8] = D["stopped"]       # a line of stopped cells on the road, 3 m from any
    # building (a car's near face seen edge-on): nothing near a building, left as it is
    (final,), _ = _run([dec])
    np.testing.assert_array_equal(final, dec)


def test_strip_seen_moving_stays_stopped() -> None:
    moving, still = free_window(), free_window()
    moving[0:4, 13] = D["moving"]    # something moved along the face (frame 0) ...
    still[0:4, 13] = D["stopped"]    # ... and stopped there (frame 1): seen moving, kept
    out, _ = _run([moving, still])
    np.testing.assert_array_equal(out[1], still)


def test_the_defaults_turn_it_on_and_the_paper_preset_off() -> None:
    assert UnmappedParams.from_config(load_config()).stopped_off_facades
    paper = load_config(preset="kurdej2013")
    assert not paper["objects"]["stopped_off_facades"]
