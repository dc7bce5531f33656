"""Block-sparse mass planes: how a frame's 32 uint8 mass planes are stored (output
format 3, docs/output-format.md).

The window's rows are cut into **tiles** of ``tile`` cells (the last tile of a row is
shorter when ``tile`` does not divide ``cols``); tiles are numbered row by row. Each tile
has a uint32 **mask**: bit A set ⇔ the plane of subset A is stored for that tile (the union
of the focal sets of the tile's cells). The **runs** are uint8 values: for each tile in
order, for each subset A in its mask in increasing order, the quantised m(A) of the tile's
cells, left to right. Planes not in a tile's mask are zero there.

A frame of workload (a) (160,000 cells, 58 % never observed) stores ~15 planes in an
observed tile and Ω only in an unobserved one: ~1 MB of runs instead of 5.1 MB of dense
planes, which the fused step writes and the writer deflates (docs/performance.md). The
fused step writes this layout directly (evperc/fusion/codegen.py, ``_store_tile``); this
module encodes (for frames given as dense arrays) and decodes it, in numpy.
"""

from __future__ import annotations

import numpy as np

#: bit counts of the bytes 0..255
_POPCOUNT8 = np.array([bin(v).count("1") for v in range(256)], np.int64)


def tiles_per_row(cols: int, tile: int) -> int:
    """Tiles in one window row of ``cols`` cells."""
    return -(-cols // tile)


def popcount(masks: np.ndarray) -> np.ndarray:
    """Number of set bits of each uint32 mask (int64)."""
    b = np.ascontiguousarray(masks, np.uint32).view(np.uint8).reshape(*masks.shape, 4)
    return _POPCOUNT8[b].sum(axis=-1)


def run_bytes(tile_masks: np.ndarray, cols: int, tile: int) -> int:
    """Length of the runs described by ``tile_masks`` ``(rows, tiles_per_row)``."""
    return int((popcount(tile_masks) * _widths(cols, tile)).sum())


def encode(masses: np.ndarray, tile_masks: np.ndarray, tile: int) -> np.ndarray:
    """The runs of dense uint8 planes ``masses`` ``(32, rows, cols)`` for the given masks;
    planes outside a tile's mask must be zero there (ValueError otherwise)."""
    _, rows, cols = masses.shape
    runs = np.empty(run_bytes(tile_masks, cols, tile), np.uint8)
    flat = masses.reshape(32, rows * cols)
    covered = np.zeros((32, rows * cols), bool)
    for a, cells, positions in _runs_of_planes(tile_masks, rows, cols, tile):
        runs[positions] = flat[a, cells]
        covered[a, cells] = True
    if flat[~covered].any():
        raise ValueError("masses outside the tile masks are not zero")
    return runs


def masks_of(masses: np.ndarray, tile: int) -> np.ndarray:
    """uint32 ``(rows, tiles_per_row)``: the planes of ``masses`` ``(32, rows, cols)`` that
    are non-zero somewhere in each tile."""
    _, rows, cols = masses.shape
    n_tiles = tiles_per_row(cols, tile)
    padded = np.zeros((32, rows, n_tiles * tile), bool)
    padded[..., :cols] = masses != 0
    used = padded.reshape(32, rows, n_tiles, tile).any(axis=-1)
    bits = np.uint32(1) << np.arange(32, dtype=np.uint32)
    return (used * bits[:, None, None]).sum(axis=0, dtype=np.uint64).astype(np.uint32)


def decode(runs: np.ndarray, tile_masks: np.ndarray, shape: tuple[int, int],
           tile: int) -> np.ndarray:
    """Dense uint8 planes ``(32, rows, cols)`` from ``runs`` and ``tile_masks``;
    ValueError if their lengths disagree."""
    rows, cols = shape
    if tile_masks.shape != (rows, tiles_per_row(cols, tile)):
        raise ValueError(f"tile masks of shape {tile_masks.shape} for a {shape} window in "
                         f"tiles of {tile}")
    if runs.shape != (run_bytes(tile_masks, cols, tile),):
        raise ValueError(f"{runs.size} bytes of mass runs, the tile masks describe "
                         f"{run_bytes(tile_masks, cols, tile)}")
    masses = np.zeros((32, rows * cols), np.uint8)
    for a, cells, positions in _runs_of_planes(tile_masks, rows, cols, tile):
        masses[a, cells] = runs[positions]
    return masses.reshape(32, rows, cols)


def _widths(cols: int, tile: int) -> np.ndarray:
    """Cells of each tile of a row."""
    starts = np.arange(0, cols, tile)
    return np.minimum(starts + tile, cols) - starts


def _runs_of_planes(tile_masks: np.ndarray, rows: int, cols: int, tile: int):
    """For each subset ``a`` stored somewhere: flat cell indices and the positions of their
    values in the runs."""
    n_tiles = tiles_per_row(cols, tile)
    masks = np.ascontiguousarray(tile_masks, np.uint32).reshape(-1)
    widths = np.tile(_widths(cols, tile), rows)
    first_cell = (np.arange(rows)[:, None] * cols + np.arange(n_tiles) * tile).reshape(-1)
    start = np.cumsum(popcount(masks) * widths) - popcount(masks) * widths
    for a in range(32):
        has = (masks >> np.uint32(a)) & np.uint32(1) != 0
        if not has.any():
            continue
        rank = popcount(masks[has] & np.uint32((1 << a) - 1))
        w = widths[has]
        lane = np.arange(int(w.sum())) - np.repeat(np.cumsum(w) - w, w)
        yield (a, np.repeat(first_cell[has], w) + lane,
               np.repeat(start[has] + rank * w, w) + lane)
