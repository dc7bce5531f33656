"""The sensor grid of one scan: {F, O} masses on the window (method.md §3, Moras 2011)."""

from __future__ import annotations

import logging
import math
import threading

import numpy as np

from evperc.geo.prior import CONTEXT_ROAD
from evperc.geo.window import Window
from evperc.sensor.beams import (
    PolarLayout,
    as_points,
    as_pose,
    level_points,
    polar_bins,
    sensor_heading,
)
from evperc.sensor.conservative import conservative_free
from evperc.sensor.evidence import beam_extents
from evperc.sensor.ground import (
    EVERY_POINT,
    NO_FEET,
    NO_HEIGHTS,
    NO_LOCAL,
    OBSTACLE,
    classify_points,
    histogram_shape,
    local_grid_side,
)
from evperc.sensor.params import SensorParams
from evperc.sensor.projection import (
    points_in_context,
    rasterise,
    scatter_all_hits,
    scatter_free_polar_cells,
    scatter_hits,
    scatter_return_sums,
    scatter_top_heights,
    scatter_top_heights_and_sums,
    unfree_feet,
)

log = logging.getLogger(__name__)


class _Scratch(threading.local):
    """Per-thread work arrays reused from frame to frame (grown when a frame needs more)."""

    def __init__(self) -> None:
        self.arrays: dict[str, np.ndarray] = {}

    def take(self, name: str, size: int, dtype: type) -> np.ndarray:
        """A 1-D array of ``size`` elements of ``dtype``, contents undefined."""
        array = self.arrays.get(name)
        if array is None or array.size < size:
            # headroom: point counts vary a little from scan to scan
            array = self.arrays[name] = np.empty(size + size // 4, dtype)
        return array[:size]


_scratch = _Scratch()


def sensor_grid(points: np.ndarray, planar: bool, T_crs_sensor: np.ndarray, window: Window,
                params: SensorParams, kinds_out: np.ndarray | None = None,
                hits_out: np.ndarray | None = None, heights_out: np.ndarray | None = None,
                sums_out: np.ndarray | None = None, context: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """``(free, occupied)``: float32 ``window.shape`` arrays of m({F}) and m({O}) for one scan;
    m(Ω_SG) = 1 − free − occupied and a cell has at most one of the two nonzero.

    ``points`` (N, 3) in the sensor frame (NaN/inf rows dropped), ``T_crs_sensor`` the sensor
    pose in the working CRS. Points are levelled (:mod:`.beams`); kept if their horizontal
    range is in ``[min_range_m, max_range_m)``; split into ground / obstacle by height above
    the local ground (:mod:`.ground`; for ``planar`` scans every point is an obstacle); each
    azimuth bin gives free / occupied / unknown polar cells (:mod:`.evidence`), mapped onto
    the window with occupied > free > unknown (:mod:`.projection`). Then
    free = μ_F where free, occupied = μ_O where occupied, 0 elsewhere; last, free cells within
    ``free_margin_m`` of an occupied cell or ``free_erosion_m`` of an unknown one lose their
    free mass (:mod:`.conservative`; both 0 in the paper's model).

    Compiled (numba) passes over the points and the cells on per-thread work arrays that are
    reused from call to call; the returned grids are new arrays (views of one block).
    ``kinds_out`` (uint8 (N,), optional) receives each point's kind from the ground split
    (:data:`~evperc.sensor.ground.IGNORED` — out of range, non-finite or above
    ``max_obstacle_height_m`` —, ``GROUND``, ``OBSTACLE``), for the per-point labels.
    ``hits_out`` (bool ``window.shape``, optional) is overwritten with the cells holding at
    least one OBSTACLE point of the scan — all its returns in range and in the height band,
    not only the first per azimuth bin that the sensor model marks occupied (the object
    stage's ``objects.cluster_on = "all_returns"``; the masses do not depend on it).
    ``heights_out`` (float32 ``window.shape``, optional) is overwritten with the height above
    the local ground of each cell's highest OBSTACLE point of the scan (0 where none, at
    least the smallest positive float32 where one; +inf for a ``planar`` scan's cells with a
    return: no ground), for ``objects.moving_min_height_m``; the masses do not depend on it
    either. ``sums_out`` (float32 ``(*window.shape, 3)``, optional) receives each cell's sums
    of its OBSTACLE points' offsets from the cell centre (x, y, m) and their count, for
    ``objects.centroid = "returns"``; the masses do not depend on it. Alone it is added to,
    not cleared (pass zeros; :func:`~evperc.sensor.projection.scatter_return_sums`); with
    ``heights_out`` the two come from one pass and the sums are written, valid exactly where
    ``heights_out`` > 0 — any block will do, nothing needs clearing
    (:func:`~evperc.sensor.projection.scatter_top_heights_and_sums`). ``context`` (uint8
    ``window.shape``, optional): the window's map context (:mod:`evperc.geo.prior`); with
    ``sensor.ground_chain_gap_road_only`` only the returns in its road cells take the chain's
    capped ground (none without it: the cap then applies nowhere; docs/method.md §3 "The
    chain's gap on the road").
    """
    layout = PolarLayout.build(params.azimuth_resolution_deg,
                               params.range_bin_m or window.resolution_m,
                               params.min_range_m, params.max_range_m)
    pts = as_points(points)
    t = as_pose(T_crs_sensor)
    heading = sensor_heading(t)
    sensor_xy = (float(t[0, 3]), float(t[1, 3]))
    n = pts.shape[0]
    x, y, z, azimuth, range_m = (_scratch.take(name, n, np.float32)
                                 for name in ("x", "y", "z", "azimuth", "range"))
    az_bin, range_bin = (_scratch.take(name, n, np.int32) for name in ("az_bin", "range_bin"))
    kind = _scratch.take("kind", n, np.uint8)

    level_points(pts.reshape(-1), t[:3, :3].astype(np.float32), x, y, z, range_m)
    np.arctan2(y, x, out=azimuth)
    polar_bins(range_m, azimuth, np.float32(heading), layout.inv_az_step32, layout.n_az,
               np.float32(params.min_range_m), np.float32(params.max_range_m),
               layout.inv_range_bin32, az_bin, range_bin)
    hist = _scratch.take("ground_histogram", math.prod(histogram_shape(layout.max_range_m)),
                         np.int32)
    height = (_scratch.take("height", n, np.float32) if heights_out is not None
              else NO_HEIGHTS)
    local = params.ground_local_raise_m > 0 and not planar
    foot = params.foot_lift_m > 0 and not planar
    feet = _scratch.take("feet", n, np.int32) if foot else NO_FEET
    local_min = (_scratch.take("local_min", local_grid_side(layout.max_range_m) ** 2, np.float32)
                 if local else NO_LOCAL)
    chain_gap, capped = params.ground_chain_gap_m, EVERY_POINT
    if (chain_gap > 0 and params.ground_chain and params.ground_chain_gap_road_only
            and not planar):
        if context is None:  # no map: no return is on a mapped road
            chain_gap = 0.0
        else:
            capped = _scratch.take("capped", n, np.uint8)
            points_in_context(capped, context, CONTEXT_ROAD, window, sensor_xy, x, y)
    n_feet = classify_points(
        z, range_m, az_bin, layout.n_az, layout.max_range_m, bool(planar),
        np.float32(params.sensor_height_m), np.float32(params.ground_threshold_m),
        np.float32(params.max_obstacle_height_m), hist, kind, params.ground_fallback == "scan",
        height, np.float32(params.ground_local_raise_m if local else 0.0), x, y, local_min,
        params.ground_chain, params.foot_lift_m if foot else 0.0, feet, chain_gap, capped)
    if kinds_out is not None:
        kinds_out[:] = kind

    obstacle_bin = np.empty(layout.n_az, np.int32)
    free_end = np.empty(layout.n_az, np.int32)
    beam_extents(az_bin, range_bin, kind, layout.n_range, obstacle_bin, free_end)

    state = _scratch.take("state", window.rows * window.cols, np.uint8).reshape(window.shape)
    state.fill(0)
    scatter_free_polar_cells(state, window, sensor_xy, heading, layout, free_end)
    scatter_hits(state, window, sensor_xy, x, y, az_bin, range_bin, kind, obstacle_bin)
    if hits_out is not None:
        if hits_out.shape != window.shape or hits_out.dtype != np.bool_:
            raise ValueError(f"hits_out must be bool {window.shape}, got {hits_out.dtype} "
                             f"{hits_out.shape}")
        hits_out.fill(False)
        scatter_all_hits(hits_out, window, sensor_xy, x, y, kind)
    if heights_out is not None:
        if heights_out.shape != window.shape or heights_out.dtype != np.float32:
            raise ValueError(f"heights_out must be float32 {window.shape}, got "
                             f"{heights_out.dtype} {heights_out.shape}")
        heights_out.fill(0.0)
    if sums_out is not None:
        if sums_out.shape != (*window.shape, 3) or sums_out.dtype != np.float32:
            raise ValueError(f"sums_out must be float32 {(*window.shape, 3)}, got "
                             f"{sums_out.dtype} {sums_out.shape}")
    if heights_out is not None and sums_out is not None:
        scatter_top_heights_and_sums(heights_out, sums_out, window, sensor_xy, x, y, kind,
                                     height)
    elif heights_out is not None:
        scatter_top_heights(heights_out, window, sensor_xy, x, y, kind, height)
    elif sums_out is not None:
        scatter_return_sums(sums_out, window, sensor_xy, x, y, kind)
    if log.isEnabledFor(logging.DEBUG):
        log.debug("sensor grid: %d points kept, %d obstacle", int((az_bin >= 0).sum()),
                  int((kind == OBSTACLE).sum()))
    free, occupied = rasterise(state, window, sensor_xy, heading, layout, obstacle_bin,
                               free_end, params.mu_free, params.mu_occupied,
                               _scratch.take("cell_azimuth", window.rows * window.cols,
                                             np.float32))
    # rasterise leaves in ``state`` the final state of every cell
    if n_feet:
        unfree_feet(state, free, window, sensor_xy, x, y, feet[:n_feet])
    conservative_free(state, free, window.resolution_m, params.free_margin_m,
                      params.free_erosion_m)
    return free, occupied
