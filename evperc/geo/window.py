"""The ego-centred window on the global lattice (method.md §7), after grid_map's moving grid.

Diagram (working CRS, x east, y north, resolution ``r``)::

      y ^           row rows-1  +---+---+---+
        |                       |   |   |   |
        |           row 1       +---+---+---+
        |                       |   |   |   |
        |           row 0       +---+---+---+      cell (row, col) covers
        |                     col0  col1  ...      x in [(col0+col)·r, (col0+col+1)·r)
        +-------> x                                y in [(row0+row)·r, (row0+row+1)·r)

Global lattice index ``(iy, ix)`` = ``(row0 + row, col0 + col)``: cell edges lie at whole
multiples of ``r`` in the working CRS, so two windows at different positions index the same
world cells. Row 0 is the *southern* row (row index grows northwards); images are flipped
for display. A cell index always means the cell centre ``((ix + 0.5)·r, (iy + 0.5)·r)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Window:
    """A ``rows × cols`` block of the lattice of cell size ``resolution_m`` starting at
    global index ``(row0, col0)`` (its south-west cell)."""

    resolution_m: float
    rows: int
    cols: int
    row0: int
    col0: int

    @staticmethod
    def centred_on(x_m: float, y_m: float, size_m: float, resolution_m: float) -> Window:
        """The window of side ``size_m`` (rounded to whole cells) whose centre cell holds
        ``(x_m, y_m)``; its edges stay on the lattice."""
        n = max(2, int(round(size_m / resolution_m)))
        ix = math.floor(x_m / resolution_m)
        iy = math.floor(y_m / resolution_m)
        return Window(resolution_m, n, n, iy - n // 2, ix - n // 2)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.rows, self.cols)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the window's outer cell edges, metres."""
        r = self.resolution_m
        return (self.col0 * r, self.row0 * r, (self.col0 + self.cols) * r,
                (self.row0 + self.rows) * r)

    def cell_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """``(x, y)``: 1-D arrays of the centre x of each column and centre y of each row."""
        r = self.resolution_m
        x = (np.arange(self.cols, dtype=np.float64) + self.col0 + 0.5) * r
        y = (np.arange(self.rows, dtype=np.float64) + self.row0 + 0.5) * r
        return x, y

    def index_of(self, x_m: np.ndarray, y_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Window ``(row, col)`` of the cells holding the points (may fall outside the window).

        A point exactly on a cell edge belongs to the cell to its north / east."""
        r = self.resolution_m
        col = np.floor(np.asarray(x_m) / r).astype(np.int64) - self.col0
        row = np.floor(np.asarray(y_m) / r).astype(np.int64) - self.row0
        return row, col

    def contains(self, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        return (row >= 0) & (row < self.rows) & (col >= 0) & (col < self.cols)


def overlap(old: Window, new: Window) -> tuple[tuple[slice, slice], tuple[slice, slice]] | None:
    """Slices ``(old_rows, old_cols), (new_rows, new_cols)`` of the cells both windows cover,
    or ``None`` if they share no cell. Both windows must be on the same lattice."""
    if old.resolution_m != new.resolution_m:
        raise ValueError("windows on different lattices")
    r_lo = max(old.row0, new.row0)
    r_hi = min(old.row0 + old.rows, new.row0 + new.rows)
    c_lo = max(old.col0, new.col0)
    c_hi = min(old.col0 + old.cols, new.col0 + new.cols)
    if r_lo >= r_hi or c_lo >= c_hi:
        return None
    return ((slice(r_lo - old.row0, r_hi - old.row0), slice(c_lo - old.col0, c_hi - old.col0)),
            (slice(r_lo - new.row0, r_hi - new.row0), slice(c_lo - new.col0, c_hi - new.col0)))


def scroll(layer: np.ndarray, old: Window, new: Window, fill: np.ndarray | float
           ) -> np.ndarray:
    """Move ``layer`` (shape ``old.shape + extra``) to ``new`` by whole cells: cells both
    windows cover keep their values, cells that enter get ``fill`` (broadcast over the
    trailing axes; e.g. the vacuous mass vector). Returns a new array; no resampling."""
    out = np.empty(new.shape + layer.shape[2:], dtype=layer.dtype)
    ov = overlap(old, new)
    if ov is None:
        out[...] = fill
        return out
    (ro, co), (rn, cn) = ov
    out[rn, cn] = layer[ro, co]
    # only the strips that enter are filled
    out[:rn.start] = fill
    out[rn.stop:] = fill
    out[rn, :cn.start] = fill
    out[rn, cn.stop:] = fill
    return out
