"""The moving trace lives on the global lattice while the window scrolls (method.md §6, §7)."""

from __future__ import annotations

import numpy as np

from evperc.geo.window import Window
from evperc.render.trace import MovingTrace


def test_trace_follows_the_world_when_the_window_scrolls() -> None:
    trace = MovingTrace(tile_cells=4)
    w1 = Window(0.5, 6, 6, 0, 0)
    mask = np.zeros((6, 6), bool)
    mask[5, 5] = True                           # global (5, 5)
    trace.add(mask, w1)
    w2 = Window(0.5, 6, 6, 3, 2)                # moved 3 rows north, 2 columns east
    got = trace.sample(w2)
    assert got.sum() == 1 and got[5 - 3, 5 - 2]
    w3 = Window(0.5, 6, 6, 6, 6)                # no longer covers (5, 5)
    assert not trace.sample(w3).any()


def test_trace_matches_a_dense_global_reference() -> None:
    rng = np.random.default_rng(4)
    trace = MovingTrace(tile_cells=5)
    offset = 40                                  # dense reference covers indices -40..79
    dense = np.zeros((120, 120), bool)
    for _ in range(25):
        row0, col0 = (int(v) for v in rng.integers(-40, 60, 2))
        w = Window(1.0, 13, 17, row0, col0)
        mask = rng.random(w.shape) < 0.05
        trace.add(mask, w)
        dense[row0 + offset:row0 + offset + 13, col0 + offset:col0 + offset + 17] |= mask
        probe = Window(1.0, 13, 17, *(int(v) for v in rng.integers(-40, 60, 2)))
        expected = dense[probe.row0 + offset:probe.row0 + offset + 13,
                         probe.col0 + offset:probe.col0 + offset + 17]
        np.testing.assert_array_equal(trace.sample(probe), expected)


def test_only_touched_tiles_are_stored_and_memory_is_bounded() -> None:
    trace = MovingTrace(tile_cells=4, max_tiles=6)
    empty = np.zeros((8, 8), bool)
    trace.add(empty, Window(1.0, 8, 8, 0, 0))
    assert trace.tiles == {}
    full = np.ones((8, 8), bool)
    for k in range(6):
        trace.add(full, Window(1.0, 8, 8, 0, 8 * k))
        assert len(trace.tiles) <= 6
    # kept: the last window's 4 tiles (columns 40..47) and the 2 nearest (columns 32..35)
    assert trace.sample(Window(1.0, 8, 8, 0, 40)).all()
    assert trace.sample(Window(1.0, 8, 4, 0, 36)).all()
    assert not trace.sample(Window(1.0, 8, 32, 0, 0)).any()
