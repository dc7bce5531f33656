"""Does the map fit the scans? The map's offset from the log's first scans, and the map moved by
it (``map.fit_to_scans``; docs/method.md §4b; docs/evaluation.md § Since 2026-12-08).

A map a metre off costs what the building margin was meant to spare: on the simulated ibeo4
drives with the map moved by 1 m, moving precision within one cell 0.979 → 0.916 (the façades
move again) and every profile's ``stopped`` (a kerb-side car beside a moved road is U / S
undecided). OpenStreetMap's outlines and a GNSS geo-reference are each off by about that
much. The walls of the map and the walls in the scans are the same lines, so:

1. The obstacle returns (the sensor grid's own ground split, as
   :func:`evperc.sensor.pose_fit.obstacle_xy` takes them, within :data:`REACH_M` of the
   sensor) of every :data:`EVERY`-th scan of the requested span from its first, placed in
   the working CRS by the run's poses and geo-reference (horizontal x, y): at least
   :data:`SCANS` scans, more until :data:`WANT_RETURNS` returns are in (a 4-layer scanner
   gives tens a scan, a 64-layer one tens of thousands), at most :data:`MAX_SCANS` read.
2. The outlines of the map's buildings near them, as points every :data:`OUTLINE_STEP_M`.
3. The returns' best horizontal offset onto the outlines
   (:func:`evperc.sensor.pose_fit.best_offset`: the share of returns within ~0.1–0.3 m of an
   outline point, searched within ±:data:`SEARCH_M` on each axis, by 0.25 m then 0.05 m).
4. The map is moved by minus that offset — its buildings and its roads together, one
   translation: a map traced off a shifted image, or a geo-reference off by its GNSS's error
   — when the offset is at least :data:`MIN_MOVE_M` (half the default cell), raises the
   share by at least :data:`MIN_GAIN`, and lies inside the search (at most 3.875 m on each
   axis: a best offset at the search's edge may be no peak at all); otherwise it is kept as
   it is (a map that fits moves by no noise).

What it does not do: turns and scales (a rotated map), errors that differ across the map
(one building off, its neighbour right), maps off by more than 3.875 m, logs whose first scans
see no mapped building (nothing to fit: kept, and said in the log). Cost: the scans read and
one ground split each, the search on ≤ 20,000 returns: once, before the run."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import shapely

from evperc.geo.maps import MapData
from evperc.sensor.params import SensorParams
from evperc.sensor.pose_fit import COARSE_M, best_offset, obstacle_xy

log = logging.getLogger(__name__)

#: every EVERY-th scan of the span is used, at least SCANS of them (5 s at 10 Hz), more
#: until WANT_RETURNS returns are in, of the first MAX_SCANS scans at most (20 s at 10 Hz)
SCANS = 10
EVERY = 5
WANT_RETURNS = 5_000
MAX_SCANS = 200
#: m: the returns used lie at most this far from their sensor (horizontally)
REACH_M = 50.0
#: m between the outline points
OUTLINE_STEP_M = 0.05
#: fewer obstacle returns, or fewer outline points, than this: nothing to fit
MIN_POINTS = 200
#: the map moves only by an offset at least this long (m) ...
MIN_MOVE_M = 0.25
#: ... that raises the share of returns on an outline by at least this much
MIN_GAIN = 0.05
#: m: the offsets searched, within ±SEARCH_M on each axis (the pose check's search, wider);
#: a best offset past SEARCH_M − COARSE_M / 2 is the search's edge, not a peak: no move
SEARCH_M = 4.0


@dataclass(frozen=True)
class MapFit:
    """The fit of the map to the scans (module docstring): ``returns`` compared, their
    ``share_at_map`` and ``share_best`` on the outlines, ``offset_m`` (east, north: how far
    the map was moved, (0, 0) when not), ``best_m`` (the best offset of the map found)."""

    scans: int
    returns: int
    share_at_map: float
    share_best: float
    best_m: tuple[float, float]
    offset_m: tuple[float, float]

    @property
    def moved(self) -> bool:
        return self.offset_m != (0.0, 0.0)

    def summary(self) -> dict[str, Any]:
        return {"scans": self.scans, "returns": self.returns,
                "share_at_map": round(self.share_at_map, 4),
                "share_best": round(self.share_best, 4),
                "best_m": [round(v, 3) + 0.0 for v in self.best_m],  # + 0.0: no -0.0
                "offset_m": [round(v, 3) + 0.0 for v in self.offset_m], "moved": self.moved}


def outline_points(buildings: np.ndarray, bounds: tuple[float, float, float, float]
                   ) -> np.ndarray:
    """(N, 2) float64: points every :data:`OUTLINE_STEP_M` along the outlines (exterior and
    holes) of the ``buildings`` that meet ``bounds`` (xmin, ymin, xmax, ymax), inside it."""
    box = shapely.box(*bounds)
    near = buildings[shapely.intersects(buildings, box)] if len(buildings) else buildings
    if len(near) == 0:
        return np.zeros((0, 2))
    lines = shapely.segmentize(shapely.boundary(near), OUTLINE_STEP_M)
    xy = shapely.get_coordinates(lines)
    inside = ((xy[:, 0] >= bounds[0]) & (xy[:, 0] <= bounds[2]) & (xy[:, 1] >= bounds[1])
              & (xy[:, 1] <= bounds[3]))
    return xy[inside]


def fit_returns(returns_xy: np.ndarray, buildings: np.ndarray, scans: int = 0) -> MapFit | None:
    """Steps 2–4 of the module docstring on ``returns_xy`` ((N, 2), the working CRS); None
    when there are too few returns or outline points near them to judge."""
    if len(returns_xy) < MIN_POINTS:
        return None
    lo, hi = returns_xy.min(axis=0), returns_xy.max(axis=0)
    reach = SEARCH_M + 1.0
    outline = outline_points(buildings, (lo[0] - reach, lo[1] - reach, hi[0] + reach,
                                         hi[1] + reach))
    if len(outline) < MIN_POINTS:
        return None
    at_map, best, (dx, dy) = best_offset(outline, returns_xy, SEARCH_M)
    # the returns fit best moved by (dx, dy): the map fits them moved by minus that
    best_m = (0.0 - dx, 0.0 - dy)  # not -0.0
    # a best offset past the middle of the coarse search's last step is where the search
    # ends, not where the share peaks: the map may be off by more (with a ±2 m search, maps
    # 2.5 m off: two of five simulated drives' maps moved the wrong way)
    inside = max(abs(dx), abs(dy)) <= SEARCH_M - COARSE_M / 2
    move = bool(inside and np.hypot(dx, dy) >= MIN_MOVE_M and best - at_map >= MIN_GAIN)
    return MapFit(scans, len(returns_xy), at_map, best, best_m,
                  best_m if move else (0.0, 0.0))


def fit_map(map_data: MapData, scans: Iterable[Any], place: Callable[[np.ndarray], np.ndarray],
            params: SensorParams) -> tuple[MapData, MapFit | None]:
    """``map_data`` moved to fit ``scans`` (the span's :class:`~evperc.logs.scan.PosedScan`
    dataclasses in order; step 1 of the module docstring says which are used) and the fit;
    ``place``: a scan's ``T_world_sensor`` → its pose in the map's CRS. The map as it is when
    the fit is None or does not move it."""
    returns, used, count = [], 0, 0
    for k, scan in enumerate(scans):
        if k >= MAX_SCANS or (used >= SCANS and count >= WANT_RETURNS):
            break
        if k % EVERY:
            continue
        placed = replace(scan, T_world_sensor=place(scan.T_world_sensor))  # the working CRS
        xy = obstacle_xy(placed, params, REACH_M)
        returns.append(xy)
        used += 1
        count += len(xy)
    xy = np.concatenate(returns) if returns else np.zeros((0, 2))
    fit = fit_returns(xy, map_data.buildings, used)
    if fit is None or not fit.moved:
        return map_data, fit
    return moved(map_data, *fit.offset_m), fit


def moved(map_data: MapData, east_m: float, north_m: float) -> MapData:
    """``map_data`` with every polygon translated by (``east_m``, ``north_m``) in its CRS."""
    shift = np.array([east_m, north_m])

    def move(geoms: np.ndarray) -> np.ndarray:
        return shapely.transform(geoms, lambda xy: xy + shift) if len(geoms) else geoms

    return replace(map_data, buildings=move(map_data.buildings), roads=move(map_data.roads))
