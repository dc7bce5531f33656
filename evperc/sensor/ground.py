"""Ground / obstacle split of 3-D clouds by height above a local ground estimate (SPEC §3).

Local ground estimate, per cell of a coarse polar partition (sectors of ``SECTOR_DEG``
azimuth × bands of ``BAND_M`` horizontal range):

1. ``h`` = z + sensor_height_m, the point's height above the *prior* ground (the flat plane
   ``sensor_height_m`` below the sensor in the levelled frame).
2. Per cell, the ``PERCENTILE`` low percentile of ``h``, from a histogram of ``Z_BIN_M`` bins
   over ``±Z_SPAN_M`` (values outside fall into the two edge bins); the estimate is the
   centre of the bin holding the ⌈p·n⌉-th lowest point. One ``bincount`` and one ``cumsum``:
   no sort, no per-cell loop.
3. The estimate is kept if the cell has at least ``MIN_POINTS`` points, the percentile is not
   in an edge bin, and it lies within ``BASE_TOLERANCE_M + MAX_SLOPE·r_out`` of the prior
   (``r_out`` the band's outer range) — the ground may slope by at most ``MAX_SLOPE``.
4. Otherwise the cell takes the estimate of the nearest accepted band nearer the sensor in
   the same sector, or the prior (height 0) if there is none.

A point is *ground* if its height above the estimate is below ``ground_threshold_m``
(points below the estimate, e.g. in a ditch or multipath echoes, count as ground), an
*obstacle* if it is between the threshold and ``max_obstacle_height_m``, and *ignored* above
(overhanging trees, bridges, signs).

Failure modes: a cell seen only on an object (a wall or truck side filling a whole cell with
no ground visible below it) gets its ground at the object's lowest visible part, so the
object's bottom ``ground_threshold_m`` is called ground — the object's upper part still
makes it an obstacle; the slope bound rejects cells lifted further than the tolerance.
Slopes steeper than ``MAX_SLOPE`` (or a pose with wrong roll/pitch) leave far ground outside
the tolerance: it falls back to the nearer band and can turn into obstacles. Within one band
a slope of s rises by s·BAND_M (0.2 m at 10 %), eating into the threshold. Kerbs
(0.1–0.15 m) stay below the default threshold and are ground. A canopy cell at long range
with no ground under it (occluded) can be accepted as ground; such cells lie behind the
occluder's obstacle bin, so they rarely change the grid.
"""

from __future__ import annotations

import numpy as np

SECTOR_DEG = 10.0
BAND_M = 2.0
PERCENTILE = 0.1
MIN_POINTS = 5
Z_BIN_M = 0.05
Z_SPAN_M = 3.0
BASE_TOLERANCE_M = 0.5
MAX_SLOPE = 0.1


def local_ground_height(height: np.ndarray, range_m: np.ndarray, az_bin: np.ndarray,
                        n_az: int, max_range_m: float) -> np.ndarray:
    """Estimated ground height (float32, above the prior plane) under each point.

    ``height``: z + sensor_height_m of each point; ``range_m``: horizontal range;
    ``az_bin``: polar azimuth bin (of ``n_az``). See the module docstring for the method."""
    n_sector = max(1, int(round(360.0 / SECTOR_DEG)))
    n_band = int(max_range_m // BAND_M) + 1
    n_z = int(round(2 * Z_SPAN_M / Z_BIN_M))
    sector = (az_bin.astype(np.int64) * n_sector) // n_az
    band = np.minimum((range_m * np.float32(1.0 / BAND_M)).astype(np.int64), n_band - 1)
    cell = sector * n_band + band
    z_bin = np.clip(((height + np.float32(Z_SPAN_M)) * np.float32(1.0 / Z_BIN_M))
                    .astype(np.int64), 0, n_z - 1)
    hist = np.bincount(cell * n_z + z_bin, minlength=n_sector * n_band * n_z)
    cum = np.cumsum(hist.reshape(n_sector * n_band, n_z), axis=1)
    count = cum[:, -1]
    target = np.maximum(np.ceil(PERCENTILE * count), 1)
    pct_bin = (cum < target[:, None]).sum(axis=1)
    estimate = (pct_bin + 0.5) * Z_BIN_M - Z_SPAN_M
    outer = (np.arange(n_band) + 1.0) * BAND_M
    tolerance = np.tile(np.minimum(BASE_TOLERANCE_M + MAX_SLOPE * outer, Z_SPAN_M), n_sector)
    accepted = ((count >= MIN_POINTS) & (pct_bin > 0) & (pct_bin < n_z - 1)
                & (np.abs(estimate) <= tolerance)).reshape(n_sector, n_band)
    source = np.where(accepted, np.arange(n_band), -1)
    source = np.maximum.accumulate(source, axis=1)
    filled = np.where(source >= 0,
                      np.take_along_axis(estimate.reshape(n_sector, n_band),
                                         np.maximum(source, 0), axis=1), 0.0)
    return filled.astype(np.float32).ravel()[cell]


def split_ground(height: np.ndarray, ground: np.ndarray, threshold_m: float,
                 max_height_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Masks ``(is_ground, is_obstacle)``: height above ground ``d = height − ground``;
    ground if d < threshold, obstacle if threshold ≤ d ≤ max_height, else ignored."""
    d = height - ground
    is_ground = d < np.float32(threshold_m)
    is_obstacle = ~is_ground & (d <= np.float32(max_height_m))
    return is_ground, is_obstacle
