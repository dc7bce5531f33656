"""The scrolling window on the global lattice (method.md §7), edges tested as grid_map does."""

from __future__ import annotations

import numpy as np
import pytest

from evperc.geo.window import Window, overlap, scroll


def test_centred_window_is_on_the_lattice() -> None:
    w = Window.centred_on(100.3, -20.7, 10.0, 0.5)
    assert w.shape == (20, 20)
    xmin, ymin, xmax, ymax = w.bounds
    for edge in (xmin, ymin, xmax, ymax):
        assert edge / 0.5 == pytest.approx(round(edge / 0.5))
    row, col = w.index_of(np.array([100.3]), np.array([-20.7]))
    assert (row[0], col[0]) == (10, 10)


@pytest.mark.parametrize(("x", "expected_col"), [
    (0.0, 0), (0.4999999, 0), (0.5, 1), (-1e-9, -1), (-0.5, -1), (-0.50001, -2)])
def test_points_on_cell_edges(x: float, expected_col: int) -> None:
    w = Window(0.5, 4, 4, 0, 0)
    _, col = w.index_of(np.array([x]), np.array([0.0]))
    assert col[0] == expected_col


def test_cell_centres_and_row_orientation() -> None:
    w = Window(0.5, 3, 2, 10, -4)
    x, y = w.cell_centres()
    np.testing.assert_allclose(x, [-1.75, -1.25])
    np.testing.assert_allclose(y, [5.25, 5.75, 6.25])  # row 0 is the southern row
    row, col = w.index_of(x[[1]], y[[2]])
    assert (row[0], col[0]) == (2, 1)
    assert w.contains(np.array([2, 3, -1]), np.array([1, 1, 0])).tolist() == [True, False, False]


def test_scroll_keeps_world_cells_and_fills_entering_ones() -> None:
    old = Window(1.0, 4, 5, 0, 0)
    layer = np.arange(20, dtype=float).reshape(4, 5)
    new = Window(1.0, 4, 5, 1, 2)  # moved one cell north, two east
    out = scroll(layer, old, new, fill=-1.0)
    # global cell (iy, ix) keeps its value wherever both windows hold it
    for r in range(4):
        for c in range(5):
            iy, ix = new.row0 + r, new.col0 + c
            if 0 <= iy < 4 and 0 <= ix < 5:
                assert out[r, c] == layer[iy, ix]
            else:
                assert out[r, c] == -1.0


def test_scroll_vector_fill_and_disjoint_windows() -> None:
    old = Window(0.5, 2, 2, 0, 0)
    layer = np.zeros((2, 2, 3))
    fill = np.array([0.0, 0.0, 1.0])
    out = scroll(layer, old, Window(0.5, 2, 2, 100, 100), fill)
    assert np.all(out == fill)
    assert overlap(old, Window(0.5, 2, 2, 2, 0)) is None
    with pytest.raises(ValueError):
        overlap(old, Window(1.0, 2, 2, 0, 0))


@pytest.mark.parametrize(("drow", "dcol"), [(0, 0), (1, 2), (-3, 1), (0, -4), (7, 7), (99, 0)])
def test_scroll_matches_a_cell_by_cell_move(drow: int, dcol: int) -> None:
    """Every cell of the new window, looked up by its world cell: the old value where the
    old window held it, the fill elsewhere (only the entering strips are filled)."""
    rng = np.random.default_rng([drow + 100, dcol + 100])
    old = Window(1.0, 6, 5, 10, 20)
    new = Window(1.0, 6, 5, 10 + drow, 20 + dcol)
    layer = rng.uniform(size=(6, 5, 3))
    fill = np.array([0.0, 0.0, 1.0])
    got = scroll(layer, old, new, fill)
    for r in range(new.rows):
        for c in range(new.cols):
            r_old, c_old = new.row0 + r - old.row0, new.col0 + c - old.col0
            inside = 0 <= r_old < old.rows and 0 <= c_old < old.cols
            np.testing.assert_array_equal(got[r, c], layer[r_old, c_old] if inside else fill)
