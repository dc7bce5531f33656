"""Trace of moving objects (method.md §6), kept on the global lattice while the window scrolls.

The trace is the set of world cells decided ``moving`` at any frame so far. It lives in
square tiles of ``tile_cells`` cells keyed by ``(iy // tile_cells, ix // tile_cells)`` of the
global lattice index (docs/conventions.md), so it follows the world, not the window. Only
tiles holding at least one traced cell are stored; past ``max_tiles`` the tiles farthest
from the current window are dropped (bounded memory).
"""

from __future__ import annotations

import logging

import numpy as np

from evperc.geo.window import Window

log = logging.getLogger(__name__)


class MovingTrace:
    """Accumulates a boolean layer in world (global lattice) coordinates."""

    def __init__(self, tile_cells: int = 128, max_tiles: int = 2048) -> None:
        if tile_cells < 1 or max_tiles < 1:
            raise ValueError("tile_cells and max_tiles must be positive")
        self.tile_cells = tile_cells
        self.max_tiles = max_tiles
        self.tiles: dict[tuple[int, int], np.ndarray] = {}
        self._warned = False

    def _tiles_over(self, window: Window):
        """Yield ``(key, tile_slices, window_slices)`` for every tile the window touches."""
        t = self.tile_cells
        for ty in range(window.row0 // t, (window.row0 + window.rows - 1) // t + 1):
            r_lo = max(window.row0, ty * t)
            r_hi = min(window.row0 + window.rows, (ty + 1) * t)
            for tx in range(window.col0 // t, (window.col0 + window.cols - 1) // t + 1):
                c_lo = max(window.col0, tx * t)
                c_hi = min(window.col0 + window.cols, (tx + 1) * t)
                yield ((ty, tx),
                       (slice(r_lo - ty * t, r_hi - ty * t), slice(c_lo - tx * t, c_hi - tx * t)),
                       (slice(r_lo - window.row0, r_hi - window.row0),
                        slice(c_lo - window.col0, c_hi - window.col0)))

    def add(self, mask: np.ndarray, window: Window) -> None:
        """OR ``mask`` ((rows, cols) bool, window cells) into the trace."""
        if mask.shape != window.shape:
            raise ValueError(f"mask shape {mask.shape} != window shape {window.shape}")
        for key, tile_sl, win_sl in self._tiles_over(window):
            part = mask[win_sl]
            tile = self.tiles.get(key)
            if tile is None:
                if not part.any():
                    continue
                tile = np.zeros((self.tile_cells, self.tile_cells), dtype=bool)
                self.tiles[key] = tile
            tile[tile_sl] |= part
        if len(self.tiles) > self.max_tiles:
            self._evict(window)

    def sample(self, window: Window) -> np.ndarray:
        """The trace over ``window``: (rows, cols) bool."""
        out = np.zeros(window.shape, dtype=bool)
        for key, tile_sl, win_sl in self._tiles_over(window):
            tile = self.tiles.get(key)
            if tile is not None:
                out[win_sl] = tile[tile_sl]
        return out

    def _evict(self, window: Window) -> None:
        """Drop the tiles farthest (Chebyshev, in tiles) from the window; never its own."""
        t = self.tile_cells
        keys = np.array(list(self.tiles), dtype=np.int64)
        lo = np.array([window.row0 // t, window.col0 // t])
        hi = np.array([(window.row0 + window.rows - 1) // t, (window.col0 + window.cols - 1) // t])
        distance = np.maximum(np.maximum(keys - hi, lo - keys), 0).max(axis=1)
        order = np.argsort(-distance, kind="stable")
        order = order[distance[order] > 0][: len(self.tiles) - self.max_tiles]
        for ty, tx in keys[order]:
            del self.tiles[(int(ty), int(tx))]
        if not self._warned:
            log.warning("moving trace exceeds %d tiles; forgetting the parts farthest away",
                        self.max_tiles)
            self._warned = True
