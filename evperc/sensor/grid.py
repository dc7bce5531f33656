"""The sensor grid of one scan: {F, O} masses on the window (SPEC §3, Moras 2011)."""

from __future__ import annotations

import logging

import numpy as np

from evperc.geo.window import Window
from evperc.sensor.beams import (
    PolarLayout,
    as_pose,
    level_points,
    polar_coordinates,
    sensor_heading,
)
from evperc.sensor.evidence import (
    FREE,
    OCCUPIED,
    free_extent,
    furthest_ground_bin,
    nearest_obstacle_bin,
)
from evperc.sensor.ground import local_ground_height, split_ground
from evperc.sensor.params import SensorParams
from evperc.sensor.projection import sample_cell_centres, scatter_free_polar_cells, scatter_points

log = logging.getLogger(__name__)


def sensor_grid(points: np.ndarray, planar: bool, T_crs_sensor: np.ndarray, window: Window,
                params: SensorParams) -> tuple[np.ndarray, np.ndarray]:
    """``(free, occupied)``: float32 ``window.shape`` arrays of m({F}) and m({O}) for one scan;
    m(Ω_SG) = 1 − free − occupied and a cell has at most one of the two nonzero.

    ``points`` (N, 3) in the sensor frame (NaN/inf rows dropped), ``T_crs_sensor`` the sensor
    pose in the working CRS. Points are levelled (:mod:`.beams`); kept if their horizontal
    range is in ``[min_range_m, max_range_m)``; split into ground / obstacle by height above
    the local ground (:mod:`.ground`; for ``planar`` scans every point is an obstacle); each
    azimuth bin gives free / occupied / unknown polar cells (:mod:`.evidence`), mapped onto
    the window with occupied > free > unknown (:mod:`.projection`). Then
    free = μ_F where free, occupied = μ_O where occupied, 0 elsewhere.
    """
    layout = PolarLayout.build(params.azimuth_resolution_deg,
                               params.range_bin_m or window.resolution_m,
                               params.min_range_m, params.max_range_m)
    t = as_pose(T_crs_sensor)
    heading = sensor_heading(t)
    sensor_xy = (float(t[0, 3]), float(t[1, 3]))
    x, y, z = level_points(points, t)
    range_m, azimuth = polar_coordinates(x, y, heading)
    kept = (range_m >= np.float32(params.min_range_m)) & (range_m < np.float32(params.max_range_m))
    x, y, z, range_m = x[kept], y[kept], z[kept], range_m[kept]
    az_bin = layout.azimuth_bin(azimuth[kept])
    range_bin = layout.range_bin(range_m)

    if planar:
        is_obstacle = np.ones(range_m.shape, dtype=bool)
        is_ground = ~is_obstacle
    else:
        height = z + np.float32(params.sensor_height_m)
        ground = local_ground_height(height, range_m, az_bin, layout.n_az, params.max_range_m)
        is_ground, is_obstacle = split_ground(height, ground, params.ground_threshold_m,
                                              params.max_obstacle_height_m)

    obstacle_bin = nearest_obstacle_bin(az_bin[is_obstacle], range_bin[is_obstacle],
                                        layout.n_az, layout.n_range)
    ground_bin = furthest_ground_bin(az_bin[is_ground], range_bin[is_ground], layout.n_az)
    free_end = free_extent(obstacle_bin, ground_bin, layout.n_range)

    state = np.zeros(window.shape, dtype=np.uint8)
    sample_cell_centres(state, window, sensor_xy, heading, layout, obstacle_bin, free_end)
    scatter_free_polar_cells(state, window, sensor_xy, heading, layout, free_end)
    hits = is_obstacle & (range_bin == obstacle_bin[az_bin])
    scatter_points(state, window, sensor_xy[0] + x[hits].astype(np.float64),
                   sensor_xy[1] + y[hits].astype(np.float64))
    if log.isEnabledFor(logging.DEBUG):
        log.debug("sensor grid: %d points kept, %d obstacle, %d ground, %d hits",
                  range_m.size, int(is_obstacle.sum()), int(is_ground.sum()), int(hits.sum()))

    free = np.where(state == FREE, np.float32(params.mu_free), np.float32(0.0))
    occupied = np.where(state == OCCUPIED, np.float32(params.mu_occupied), np.float32(0.0))
    return free, occupied
