"""The GIS prior grid GG (method.md §4): context labels per cell and their mass functions.

Each cell is classified by its centre point ``((ix + 0.5)·r, (iy + 0.5)·r)``: inside a
building → ``CONTEXT_BUILDING``, else inside a road surface → ``CONTEXT_ROAD``, else
``CONTEXT_OTHER`` (priority building > road > other where polygons overlap). A rasteriser
may widen its buildings first by ``building_margin_m`` (:func:`widen_polygons`,
docs/method.md §4a "Widened buildings"): the runner's second rasteriser, whose building cells
are the layer that holds the motion gate shut where a return at a building face falls
although the map or the pose is off by up to that margin (the prior keeps the outlines).
Or its roads by ``road_margin_m``: the runner's rasteriser of the roads' reach, whose road
cells take the ground chain's capped gap (``sensor.ground_chain_gap_road_reach_m``,
docs/method.md §3 "The chain's gap on the road").

Polygons are closed: a centre exactly on a polygon's edge or vertex counts as inside it
(``intersects``, i.e. ``polygon.covers(point)``; ``contains`` would say outside). So two
polygons sharing an edge leave no gap, and the result does not depend on vertex order.

Labels are computed by square tiles of ``tile_size_cells`` cells of the GLOBAL lattice (tile
``(ty, tx)`` holds global indices ``[ty·T, (ty+1)·T) × [tx·T, (tx+1)·T)``) and kept in an LRU
cache of at most ``max_tiles`` tiles, so memory stays bounded whatever the drive length and a
tile is rasterised once while it stays cached.
"""

from __future__ import annotations

import logging
from collections import OrderedDict

import numpy as np
import shapely

from evperc.geo.maps import MapData
from evperc.geo.window import Window

log = logging.getLogger(__name__)

CONTEXT_OTHER = 0
CONTEXT_ROAD = 1
CONTEXT_BUILDING = 2

# focal sets on Ω = {F, I, U, S, M}: bit0 F, bit1 I, bit2 U, bit3 S, bit4 M
_F, _I, _U, _S, _M = 1, 2, 4, 8, 16
OMEGA = 31
FOCAL_BUILDING = _I                    # {I}
FOCAL_ROAD = _F | _S | _M              # {F, S, M}
FOCAL_OTHER = _F | _U | _S | _M        # {F, U, S, M}

DEFAULT_MAX_TILES = 64  # 64 tiles of 256² uint8 cells = 4 MiB
#: the least margin for which a rasteriser of widened buildings takes its ``inner`` tiles'
#: building cells untested (a buffer this wide holds its polygon with room to spare for
#: GEOS's rounding, ~1e-9 m at UTM coordinates)
MIN_INNER_MARGIN_M = 1e-3
_BUFFER_QUAD_SEGS = 4   # segments per quarter circle of a widened building's rounded corners


class PriorRasteriser:
    """Context labels of any window on the lattice of ``resolution_m`` from ``map_data``
    (polygons in the working CRS), cached by global tiles.

    ``stats``: ``tiles_rasterised`` (tiles computed), ``tile_hits`` (tiles served from the
    cache), ``tiles_cached`` (tiles held now).

    ``inner``: for buildings widened by ``building_margin_m`` ≥ :data:`MIN_INNER_MARGIN_M`, the
    rasteriser of the same buildings unwidened, on the same lattice and tiles (the prior's):
    a centre in a building is in its widened polygon too, so the cells ``inner``'s tile labels
    building are taken as they are and only the others are tested — the same labels, with
    the tests of the buildings' interiors (most of a city block's tile) done once, not twice."""

    def __init__(self, map_data: MapData, resolution_m: float, tile_size_cells: int,
                 max_tiles: int = DEFAULT_MAX_TILES, building_margin_m: float = 0.0,
                 inner: PriorRasteriser | None = None, road_margin_m: float = 0.0) -> None:
        if resolution_m <= 0 or tile_size_cells < 1 or max_tiles < 1:
            raise ValueError("resolution_m, tile_size_cells and max_tiles must be positive")
        if not (building_margin_m >= 0 and road_margin_m >= 0):
            raise ValueError(f"building_margin_m and road_margin_m must be >= 0, got "
                             f"{building_margin_m}, {road_margin_m}")
        if inner is not None and (inner.resolution_m != resolution_m
                                  or inner.tile_size != tile_size_cells
                                  or inner.building_margin_m != 0.0):
            raise ValueError("inner must rasterise unwidened buildings on the same lattice "
                             "and tiles")
        self._inner = inner if building_margin_m >= MIN_INNER_MARGIN_M else None
        self.resolution_m = float(resolution_m)
        self.tile_size = int(tile_size_cells)
        self.max_tiles = int(max_tiles)
        self.building_margin_m = float(building_margin_m)
        self.road_margin_m = float(road_margin_m)
        self._geoms = {CONTEXT_ROAD: widen_polygons(
                           np.asarray(map_data.roads, dtype=object), road_margin_m),
                       CONTEXT_BUILDING: widen_polygons(
                           np.asarray(map_data.buildings, dtype=object), building_margin_m)}
        for geoms in self._geoms.values():
            shapely.prepare(geoms)
        self._bounds = {k: shapely.bounds(g).reshape(-1, 4) for k, g in self._geoms.items()}
        self._trees = {k: shapely.STRtree(g) for k, g in self._geoms.items()}
        self._tiles: OrderedDict[tuple[int, int], np.ndarray] = OrderedDict()
        self._rasterised = 0
        self._hits = 0

    @property
    def stats(self) -> dict[str, int]:
        return {"tiles_rasterised": self._rasterised, "tile_hits": self._hits,
                "tiles_cached": len(self._tiles)}

    def labels(self, window: Window) -> np.ndarray:
        """``uint8 (rows, cols)`` context of each cell of ``window`` (row 0 = south)."""
        if window.resolution_m != self.resolution_m:
            raise ValueError(f"window resolution {window.resolution_m} m differs from the "
                             f"rasteriser's {self.resolution_m} m")
        t = self.tile_size
        out = np.empty(window.shape, dtype=np.uint8)
        ty0, ty1 = window.row0 // t, (window.row0 + window.rows - 1) // t
        tx0, tx1 = window.col0 // t, (window.col0 + window.cols - 1) // t
        for ty in range(ty0, ty1 + 1):
            r_lo = max(window.row0, ty * t)
            r_hi = min(window.row0 + window.rows, (ty + 1) * t)
            for tx in range(tx0, tx1 + 1):
                c_lo = max(window.col0, tx * t)
                c_hi = min(window.col0 + window.cols, (tx + 1) * t)
                tile = self._tile(ty, tx)
                out[r_lo - window.row0:r_hi - window.row0, c_lo - window.col0:c_hi - window.col0] \
                    = tile[r_lo - ty * t:r_hi - ty * t, c_lo - tx * t:c_hi - tx * t]
        return out

    def _tile(self, ty: int, tx: int) -> np.ndarray:
        key = (ty, tx)
        tile = self._tiles.get(key)
        if tile is not None:
            self._tiles.move_to_end(key)
            self._hits += 1
            return tile
        t = self.tile_size
        inside = (self._inner._tile(ty, tx) == CONTEXT_BUILDING if self._inner is not None
                  else None)
        tile = self.rasterise(Window(self.resolution_m, t, t, ty * t, tx * t), inside)
        tile.setflags(write=False)
        self._tiles[key] = tile
        self._rasterised += 1
        if len(self._tiles) > self.max_tiles:
            self._tiles.popitem(last=False)
        return tile

    def rasterise(self, window: Window, inside: np.ndarray | None = None) -> np.ndarray:
        """Labels of ``window`` computed directly (no cache). For each class, the polygons
        whose bounding boxes meet the window come from an STRtree; each (prepared) polygon
        then tests the block of cell centres inside its own bounding box at once with
        ``shapely.intersects_xy`` (closed polygons). Buildings are written last so they win.
        ``inside``: a bool mask of the window's cells known to lie in a building (they are
        labelled building, and a building tests only the other cells of its box).

        The loop runs over candidate polygons, never over cells; it is about ten times
        faster than querying the tree with one Point object per cell."""
        out = np.full(window.shape, CONTEXT_OTHER, dtype=np.uint8)
        xs, ys = window.cell_centres()
        extent = shapely.box(xs[0], ys[0], xs[-1], ys[-1])
        for context in (CONTEXT_ROAD, CONTEXT_BUILDING):
            geoms, bounds = self._geoms[context], self._bounds[context]
            known = inside if context == CONTEXT_BUILDING else None
            hit = np.zeros(window.shape, dtype=bool) if known is None else known.copy()
            candidates = np.sort(self._trees[context].query(extent))
            b = bounds[candidates]
            c0, c1 = np.searchsorted(xs, b[:, 0], "left"), np.searchsorted(xs, b[:, 2], "right")
            r0, r1 = np.searchsorted(ys, b[:, 1], "left"), np.searchsorted(ys, b[:, 3], "right")
            for i in np.flatnonzero((c0 < c1) & (r0 < r1)):
                block = hit[r0[i]:r1[i], c0[i]:c1[i]]
                if known is None:
                    block |= shapely.intersects_xy(geoms[candidates[i]], xs[None, c0[i]:c1[i]],
                                                   ys[r0[i]:r1[i], None])
                    continue
                rr, cc = np.nonzero(~block)
                block[rr, cc] = shapely.intersects_xy(geoms[candidates[i]], xs[c0[i] + cc],
                                                      ys[r0[i] + rr])
            out[hit] = context
        return out


def widen_polygons(polygons: np.ndarray, margin_m: float) -> np.ndarray:
    """The polygons grown by ``margin_m`` (buildings: the map's and the pose's error; roads:
    their reach): every point within ``margin_m`` of a polygon is in its widened polygon (a
    round buffer, each quarter circle approximated by ``_BUFFER_QUAD_SEGS`` segments, so up to
    ``margin·(1 − cos(π/4n))`` ≈ 2 % short of the margin at the corners). ``margin_m = 0``:
    the polygons themselves."""
    if margin_m <= 0 or polygons.size == 0:
        return polygons
    return shapely.buffer(polygons, margin_m, quad_segs=_BUFFER_QUAD_SEGS)


def prior_masses(labels: np.ndarray, beta_building: float, beta_road: float,
                 beta_other: float, dtype: np.dtype = np.float32) -> np.ndarray:
    """GG masses ``(rows, cols, 32)`` from context labels (method.md §4):
    building m({I}) = β_B, road m({F,S,M}) = β_R, other m({F,U,S,M}) = β_T, the rest on Ω."""
    betas = np.array([beta_other, beta_road, beta_building], dtype=np.float64)
    if not np.all((betas >= 0.0) & (betas <= 1.0)):
        raise ValueError(f"prior masses must be in [0, 1], got {betas.tolist()}")
    labels = np.asarray(labels)
    if labels.size and labels.max() > CONTEXT_BUILDING:
        raise ValueError(f"unknown context label {int(labels.max())}")
    focal = np.array([FOCAL_OTHER, FOCAL_ROAD, FOCAL_BUILDING], dtype=np.intp)[labels]
    beta = betas.astype(dtype)[labels]
    out = np.zeros(labels.shape + (32,), dtype=dtype)
    np.put_along_axis(out, focal[..., None], beta[..., None], axis=-1)
    out[..., OMEGA] = 1 - beta
    return out
