"""Ground / obstacle split of 3-D clouds by height above a local ground estimate (method.md §3).

Local ground estimate, per cell of a coarse polar partition (sectors of ``SECTOR_DEG``
azimuth × bands of ``BAND_M`` horizontal range):

1. ``h`` = z + sensor_height_m, the point's height above the *prior* ground (the flat plane
   ``sensor_height_m`` below the sensor in the levelled frame).
2. Per cell, the ``PERCENTILE`` low percentile of ``h``, from a histogram of ``Z_BIN_M`` bins
   over ``±Z_SPAN_M`` (values outside fall into the two edge bins); the estimate is the
   centre of the bin holding the ⌈p·n⌉-th lowest point: one histogram, no sort.
3. The estimate is kept if the cell has at least ``MIN_POINTS`` points, the percentile is not
   in an edge bin, and it lies within ``BASE_TOLERANCE_M + MAX_SLOPE·r_out`` of the prior
   (``r_out`` the band's outer range) — the ground may slope by at most ``MAX_SLOPE``.
   With the chain (``sensor.ground_chain``, the default; off in the paper's preset) it must
   also lie within ``BASE_TOLERANCE_M + MAX_SLOPE·(r_out − r_last)`` of the estimate of the
   last band kept nearer the sensor in its sector (``r_last`` that band's outer range; the
   prior at 0 for the first), walking outwards: the slope bound holds from band to band, not
   only from the sensor. A band with no ground return — beyond the last ring a sparse
   scanner lays on the road (a 16-layer scanner 1.8 m up: 34 m, then 103 m) — holds only
   what stands in it, and the low percentile of a fence or a car's side 1.1 m up passes the
   prior's bound out there (0.5 + 0.1·40 m); it became the band's ground and the object's
   returns ground, free space that turned occupied as the layer slid down the object from
   scan to scan (false motion). With the chain that band keeps the nearer band's ground.
   The chain's bound still grows with the gap, so far past the last ring (a 16-layer
   scanner's −1° layer meets a car's side 1.05 m up at 43 m, 9 m past the ring's band:
   bound 1.4 m) an object passes again; ``sensor.ground_chain_gap_m`` = G caps the gap at
   G metres once a band is kept in the sector (an option: real terrain rising out there
   flickers about the tighter bound; docs/method.md §3 "The chain's gap").
4. Otherwise the cell takes the estimate of the nearest accepted band nearer the sensor in
   the same sector, or, if there is none, the *fallback*: the prior (height 0,
   ``sensor.ground_fallback = "prior"``, the paper's preset) or the median of the scan's
   accepted estimates (``"scan"``; the prior if none is accepted). A sensor mounted lower
   or higher than ``sensor_height_m`` (an IBEO at a bumper, 0.5 m, against the prior's
   1.73 m) sees the ground ``sensor_height_m − mount`` above the prior plane; in a sector
   whose few ground returns fall short of ``MIN_POINTS`` (behind a car, at the field of
   view's edge) the prior then makes them obstacles, a ring of false returns where the
   lowest layer meets the road. The scan's other sectors know better.

5. Optional local step (``sensor.ground_local_raise_m`` = Δ > 0; 0 in the paper's model):
   the estimate of step 2 is one height per 10° × 2 m cell, so terrain rising beside the
   road, a sidewalk behind its kerb or a slope within the cell stand a few tenths of a metre
   above it — just above the threshold, and such cells flicker between ground and obstacle
   from scan to scan (the false motion of the real slices, evaluation.md). A point whose
   height d above the estimate g lies in ``[threshold, threshold + Δ)`` takes as its ground
   ``max(lowest, g)``, ``lowest`` the lowest return with d < Δ (near the coarse ground) within
   ``LOCAL_CELLS`` cells of ``LOCAL_CELL_M`` around its own (a 1.5 m square, cells aligned on
   the sensor); with no such return there its estimate stands. So a point turns ground only
   within Δ above the threshold, and only where returns near the coarse ground are in sight
   (a lowest return higher than g + Δ, from a neighbouring coarse cell's estimate, changes
   nothing more: the point is ground either way): a slope's
   returns lie 0.1–0.3 m above their lower neighbours and become ground, an object keeps the
   ground visible beside it, and an object with nothing near the ground in sight (its base
   hidden) keeps its coarse split. A 4-layer scanner's lowest layer meets an object's face
   anywhere from its mount height down to the road, so its face returns can pass for ground
   (the simulated IBEO loses moving recall). Off by default: docs/method.md §3.

A point is *ground* if its height above the estimate is below ``ground_threshold_m``
(points below the estimate, e.g. in a ditch or multipath echoes, count as ground), an
*obstacle* if it is between the threshold and ``max_obstacle_height_m``, and *ignored* above
(overhanging trees, bridges, signs). A ground point's *lift* — its height above the ground of
the nearer band, what the road before it predicts — picks the *feet* on request: a layer that
meets an object only at its foot, under the threshold, gives a ground return well above the
nearer ground (``sensor.foot_lift_m``, :func:`evperc.sensor.projection.unfree_feet`).

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

import math

import numba
import numpy as np

SECTOR_DEG = 10.0
BAND_M = 2.0
PERCENTILE = 0.1
MIN_POINTS = 5
Z_BIN_M = 0.05
Z_SPAN_M = 3.0
BASE_TOLERANCE_M = 0.5
MAX_SLOPE = 0.1
#: step 5: cell edge of the lowest-return grid and the half-width (in cells) of its block
LOCAL_CELL_M = 0.5
LOCAL_CELLS = 1

#: point kinds written by :func:`classify_points` (and read by :mod:`.evidence`)
IGNORED = np.uint8(0)
GROUND = np.uint8(1)
OBSTACLE = np.uint8(2)


@numba.njit(cache=True, nogil=True)
def histogram_shape(max_range_m: float) -> tuple[int, int, int]:
    """``(n_sector, n_band, n_z)``: sectors, range bands and height bins of the estimate."""
    return (max(1, int(round(360.0 / SECTOR_DEG))), int(max_range_m // BAND_M) + 1,
            int(round(2 * Z_SPAN_M / Z_BIN_M)))


#: the ``height`` argument of :func:`classify_points` when no heights are asked for
NO_HEIGHTS = np.zeros(0, np.float32)
#: the ``feet`` argument of :func:`classify_points` without ``foot_lift``
NO_FEET = np.zeros(0, np.int32)
#: the ``x`` / ``y`` / ``local_min`` arguments of :func:`classify_points` without step 5
NO_LOCAL = np.zeros(0, np.float32)
#: the ``capped`` argument of :func:`classify_points`: the chain's gap cap for every point
EVERY_POINT = np.zeros(0, np.uint8)


@numba.njit(cache=True, nogil=True)
def local_grid_side(max_range_m: float) -> int:
    """Cells per side of step 5's square grid of ``LOCAL_CELL_M`` cells centred on the sensor
    (``±max_range_m`` plus a border of ``LOCAL_CELLS`` so that every block stays inside)."""
    return 2 * (int(math.ceil(max_range_m / LOCAL_CELL_M)) + LOCAL_CELLS) + 1


@numba.njit(cache=True, nogil=True)
def classify_points(z: np.ndarray, range_m: np.ndarray, az_bin: np.ndarray, n_az: int,
                    max_range_m: float, planar: bool, sensor_height: np.float32,
                    threshold: np.float32, max_height: np.float32, hist: np.ndarray,
                    kind: np.ndarray, scan_fallback: bool = False,
                    height: np.ndarray = NO_HEIGHTS, local_raise: float = 0.0,
                    x: np.ndarray = NO_LOCAL, y: np.ndarray = NO_LOCAL,
                    local_min: np.ndarray = NO_LOCAL, chain: bool = False,
                    foot_lift: float = 0.0, feet: np.ndarray = NO_FEET,
                    chain_gap: float = 0.0, capped: np.ndarray = EVERY_POINT) -> int:
    """Write into ``kind`` the GROUND / OBSTACLE / IGNORED kind of each point.

    ``z``: levelled height above the sensor; ``range_m``: horizontal range; ``az_bin``:
    polar azimuth bin (of ``n_az``; negative: dropped point, IGNORED). Height above the
    prior ``h = z + sensor_height`` and above the local ground ``d = h − ground`` are
    float32; ground if ``d < threshold``, obstacle if ``threshold ≤ d ≤ max_height``. See
    the module docstring for the ground estimate. ``planar``: every kept point is an
    obstacle. ``hist``: int32 work array of ``n_sector · n_band · n_z`` elements
    (:func:`histogram_shape`). ``scan_fallback``: step 4's fallback is the median of the
    scan's accepted estimates instead of the prior. ``height`` (float32, optional: when it
    has one element a point) receives each OBSTACLE point's ``d`` (+inf for a planar scan,
    which has no ground; NaN for the other points). ``local_raise`` > 0: step 5 with Δ =
    ``local_raise``, on the points' levelled offsets ``x``, ``y`` from the sensor and the
    float32 work array ``local_min`` of ``local_grid_side(max_range_m)²`` elements.
    ``chain``: step 3's chain along each sector; ``chain_gap`` > 0
    (``sensor.ground_chain_gap_m``): the chain's slope bound grows over at most that many
    metres past the last kept band of the sector (docs/method.md §3 "The chain's gap");
    ``capped`` (uint8, one per point, optional): only the points marked 1 take the capped
    chain's ground, the others that of the chain without the cap (both estimated from the
    same histogram; ``sensor.ground_chain_gap_road_only``: the points on a mapped road).
    ``foot_lift`` > 0 (``sensor.foot_lift_m``):
    the indices of the GROUND points whose *lift* — height above the ground of the nearer
    band, the estimate their band would take without its own (:func:`_chained`'s
    ``ground_near``) — is at least ``foot_lift`` are written to ``feet`` (int32, a point
    each), and their count returned (0 otherwise)."""
    heights = height.shape[0] == z.shape[0]
    foot = np.float32(foot_lift) if foot_lift > 0 else np.float32(np.inf)
    n_feet = 0
    if planar:
        for i in range(z.shape[0]):
            kind[i] = OBSTACLE if az_bin[i] >= 0 else IGNORED
            if heights:
                height[i] = np.inf if az_bin[i] >= 0 else np.nan
        return 0
    n_sector, n_band, n_z = histogram_shape(max_range_m)
    # sector·n_band of each azimuth bin: no division per point
    sector_start = (np.arange(n_az) * n_sector) // n_az * n_band
    hist[:] = 0
    inv_band = np.float32(1.0 / BAND_M)
    cells = np.empty(z.shape[0], np.int32)  # each point's coarse cell (−1: dropped)
    # successive points mostly fall in the same bin: counted in a register and added when
    # the bin changes (one increment per point made each wait for the previous one's store)
    last, run = np.int64(-1), np.int64(0)
    for i in range(z.shape[0]):
        cell = np.int64(-1)
        if az_bin[i] >= 0:
            cell = sector_start[az_bin[i]] + min(np.int64(range_m[i] * inv_band), n_band - 1)
            at = cell * n_z + _z_bin(z[i] + sensor_height, n_z)
            if at == last:
                run += 1
            else:
                if run:
                    hist[last] += run
                last, run = at, np.int64(1)
        cells[i] = cell
    if run:
        hist[last] += run
    accepted, ok = _accepted(hist, n_sector, n_band, n_z)
    ground, ground_near = _chained(accepted, ok, n_sector, n_band, scan_fallback, chain,
                                   chain_gap)
    split = chain and chain_gap > 0.0 and capped.shape[0] == z.shape[0]
    # the points not marked in ``capped``: the chain's ground without the cap
    free_ground, free_near = (_chained(accepted, ok, n_sector, n_band, scan_fallback, chain,
                                       0.0) if split else (ground, ground_near))
    refine = local_raise > 0
    if refine:
        side = local_grid_side(max_range_m)
        local_min[:side * side] = np.inf
        candidates = np.empty(z.shape[0], np.int32)
    n_candidates = 0
    for i in range(z.shape[0]):
        kind[i] = IGNORED
        cell = cells[i]
        if heights:
            height[i] = np.nan
        if cell >= 0:
            own = not split or capped[i] != 0
            g, g_near = (ground[cell], ground_near[cell]) if own else (free_ground[cell],
                                                                        free_near[cell])
            d = (z[i] + sensor_height) - g
            if refine and d < local_raise:  # near the coarse ground: may be a block's lowest
                at = _local_cell(x[i], y[i], max_range_m, side)
                local_min[at] = min(local_min[at], z[i] + sensor_height)
            if d < threshold:
                kind[i] = GROUND
                if (z[i] + sensor_height) - g_near >= foot:
                    feet[n_feet] = i
                    n_feet += 1
            elif d <= max_height:
                kind[i] = OBSTACLE
                if heights:
                    height[i] = d
                if refine and d < threshold + local_raise:
                    candidates[n_candidates] = i
                    n_candidates += 1
    for k in range(n_candidates):
        i = candidates[k]
        at = _local_cell(x[i], y[i], max_range_m, side)
        h = z[i] + sensor_height
        own = not split or capped[i] != 0
        base = ground[cells[i]] if own else free_ground[cells[i]]
        base_near = ground_near[cells[i]] if own else free_near[cells[i]]
        lowest = np.float32(np.inf)
        for dr in range(-LOCAL_CELLS, LOCAL_CELLS + 1):
            for dc in range(-LOCAL_CELLS, LOCAL_CELLS + 1):
                lowest = min(lowest, local_min[at + dr * side + dc])
        if lowest == np.inf:
            continue  # no return near the coarse ground in the block: the estimate stands
        d = h - max(lowest, base)
        if d < threshold:
            kind[i] = GROUND
            if heights:
                height[i] = np.nan
            if h - base_near >= foot:
                feet[n_feet] = i
                n_feet += 1
        elif heights:
            height[i] = d
    return n_feet


@numba.njit(cache=True, nogil=True, inline="always")
def _local_cell(x: np.float32, y: np.float32, max_range_m: float, side: int) -> int:
    """Flat index of the step-5 grid cell holding the offset ``(x, y)`` (|x|, |y| <
    ``max_range_m``: a kept point)."""
    inv = np.float32(1.0 / LOCAL_CELL_M)
    half = np.float32(max_range_m) * inv + np.float32(LOCAL_CELLS)
    return int(y * inv + half) * side + int(x * inv + half)


@numba.njit(cache=True, nogil=True, inline="always")
def _z_bin(height: np.float32, n_z: int) -> int:
    """Histogram bin ``⌊(h + Z_SPAN_M)/Z_BIN_M⌋`` (float32), clipped to ``[0, n_z − 1]``
    (NaN: 0); selects, no branches."""
    v = (height + np.float32(Z_SPAN_M)) * np.float32(1.0 / Z_BIN_M)
    top = np.float32(n_z - 1)
    return int(v if v < top else top) if v > 0 else 0


@numba.njit(cache=True, nogil=True)
def _accepted(hist: np.ndarray, n_sector: int, n_band: int, n_z: int
              ) -> tuple[np.ndarray, np.ndarray]:
    """Steps 2–3 without the chain: each coarse cell's estimate (float64) and whether the
    prior's slope bound accepts it."""
    accepted = np.empty(n_sector * n_band, dtype=np.float64)
    ok = np.zeros(n_sector * n_band, dtype=np.bool_)
    for cell in range(n_sector * n_band):
        band = cell % n_band
        n = hist[cell * n_z:(cell + 1) * n_z].sum()
        if n >= MIN_POINTS:
            target = max(math.ceil(PERCENTILE * n), 1)
            cum = 0
            pct_bin = 0
            while True:
                cum += hist[cell * n_z + pct_bin]
                if cum >= target:
                    break
                pct_bin += 1
            estimate = (pct_bin + 0.5) * Z_BIN_M - Z_SPAN_M
            tolerance = min(BASE_TOLERANCE_M + MAX_SLOPE * ((band + 1.0) * BAND_M), Z_SPAN_M)
            if 0 < pct_bin < n_z - 1 and abs(estimate) <= tolerance:
                accepted[cell] = estimate
                ok[cell] = True
    return accepted, ok


@numba.njit(cache=True, nogil=True)
def _chained(accepted: np.ndarray, ok_prior: np.ndarray, n_sector: int, n_band: int,
             scan_fallback: bool, chain: bool, chain_gap: float
             ) -> tuple[np.ndarray, np.ndarray]:
    """``(ground, ground_near)`` (float32) per coarse cell, from :func:`_accepted`'s
    estimates (``ok_prior`` is not changed). ``ground``: its own estimate if accepted (with
    ``chain``, also within the slope bound of the last accepted band nearer the sensor;
    ``chain_gap`` > 0 caps the distance the slope bound grows over, once a band of the
    sector is kept), else that of the nearest accepted band nearer the sensor in its sector,
    else the fallback — 0 (the prior) or, with ``scan_fallback``, the median of the accepted
    estimates (steps 2–4). ``ground_near``: the same without the cell's own estimate (the
    nearest accepted band strictly nearer, else the fallback)."""
    ok = ok_prior.copy()
    if chain:
        for sector in range(n_sector):
            last, last_r = 0.0, 0.0
            for band in range(n_band):
                cell = sector * n_band + band
                if ok[cell]:
                    r_out = (band + 1.0) * BAND_M
                    gap = r_out - last_r
                    if chain_gap > 0.0 and last_r > 0.0:
                        gap = min(gap, chain_gap)
                    bound = BASE_TOLERANCE_M + MAX_SLOPE * gap
                    if abs(accepted[cell] - last) <= bound:
                        last, last_r = accepted[cell], r_out
                    else:
                        ok[cell] = False
    fallback = 0.0
    if scan_fallback and ok.any():
        fallback = np.median(accepted[ok])
    ground = np.zeros(n_sector * n_band, dtype=np.float32)
    ground_near = np.zeros(n_sector * n_band, dtype=np.float32)
    for sector in range(n_sector):
        last = fallback
        for band in range(n_band):
            cell = sector * n_band + band
            ground_near[cell] = np.float32(last)
            if ok[cell]:
                last = accepted[cell]
            ground[cell] = np.float32(last)
    return ground, ground_near
