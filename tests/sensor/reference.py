"""method.md §3 sensor grid written out per point and per cell in plain Python (math, lists, dicts).

An oracle for :mod:`evperc.sensor`: it shares no code with it. It follows the documented
model of evperc.sensor (levelling, polar bins centred on multiples of Δ, the histogram
low-percentile ground estimate with its constants, the three world passes) one point / one
cell at a time. Slow by design: O(points + cells + polar cells) Python iterations.
"""

from __future__ import annotations

import math

import numpy as np

# the ground-estimate constants documented in evperc/sensor/ground.py
SECTOR_DEG, BAND_M, PERCENTILE, MIN_POINTS = 10.0, 2.0, 0.1, 5
Z_BIN_M, Z_SPAN_M, BASE_TOL_M, MAX_SLOPE = 0.05, 3.0, 0.5, 0.1
# the foot rule's small object (docs/method.md §3 "An object's foot"): at most this many
# occupied cells in the 5 × 5 block around the foot's cell
SMALL_OBJECT_CELLS = 4

UNKNOWN, FREE, OCCUPIED = 0, 1, 2
# the map context of a road cell (CONTEXT_ROAD, as docs/architecture.md lists the codes)
ROAD = 1


def reference_state(points, planar, t_crs_sensor, window, params,
                    context=None) -> list[list[int]]:
    """Per-cell state rows × cols (row 0 south) of UNKNOWN / FREE / OCCUPIED. ``context``:
    the window's map context (1 = road), read with ``ground_chain_gap_road_only``."""
    t = [[float(v) for v in row] for row in np.asarray(t_crs_sensor)]
    heading = math.atan2(t[1][0], t[0][0])
    sx, sy = t[0][3], t[1][3]
    n_az = max(1, round(360.0 / params.azimuth_resolution_deg))
    step = 2 * math.pi / n_az
    c = params.range_bin_m or window.resolution_m
    lo, hi = params.min_range_m, params.max_range_m

    kept = []  # (x, y, z, r, a, k) level offsets, horizontal range, bins
    for p in np.asarray(points, dtype=float).tolist():
        if not all(math.isfinite(v) for v in p):
            continue
        x, y, z = (sum(t[i][j] * p[j] for j in range(3)) for i in range(3))
        r = math.hypot(x, y)
        if not lo <= r < hi:
            continue
        a = round((math.atan2(y, x) - heading) / step) % n_az
        kept.append((x, y, z, r, a, math.floor(r / c)))

    r0 = window.resolution_m

    def on_road(x: float, y: float) -> bool:
        col = math.floor((sx + x) / r0) - window.col0
        row = math.floor((sy + y) / r0) - window.row0
        return (context is not None and 0 <= row < window.rows and 0 <= col < window.cols
                and int(context[row][col]) == ROAD)

    if planar:
        kinds, lifts = ["obstacle"] * len(kept), [0.0] * len(kept)
    elif params.ground_chain_gap_road_only:   # the cap only for the returns on the road
        road = [on_road(x, y) for (x, y, _, _, _, _) in kept]
        capped = classify(kept, n_az, params)
        uncapped = classify(kept, n_az, params, gap=0.0)
        kinds = [c if r else u for c, u, r in zip(capped[0], uncapped[0], road, strict=True)]
        lifts = [c if r else u for c, u, r in zip(capped[1], uncapped[1], road, strict=True)]
    else:
        kinds, lifts = classify(kept, n_az, params)

    nearest = {}
    furthest = {}
    for (_, _, _, _, a, k), kind in zip(kept, kinds, strict=True):
        if kind == "obstacle":
            nearest[a] = min(nearest.get(a, k), k)
        elif kind == "ground":
            furthest[a] = max(furthest.get(a, k), k)

    def polar(a: int, k: int) -> int:
        if a in nearest:
            return OCCUPIED if k == nearest[a] else FREE if k < nearest[a] else UNKNOWN
        return FREE if a in furthest and k <= furthest[a] else UNKNOWN

    state = [[UNKNOWN] * window.cols for _ in range(window.rows)]
    for row in range(window.rows):
        for col in range(window.cols):
            dx = (window.col0 + col + 0.5) * r0 - sx
            dy = (window.row0 + row + 0.5) * r0 - sy
            r = math.hypot(dx, dy)
            if lo <= r < hi:
                a = round((math.atan2(dy, dx) - heading) / step) % n_az
                state[row][col] = polar(a, math.floor(r / c))

    def mark(x: float, y: float, value: int) -> None:
        col = math.floor(x / r0) - window.col0
        row = math.floor(y / r0) - window.row0
        if 0 <= row < window.rows and 0 <= col < window.cols:
            state[row][col] = max(state[row][col], value)

    for a in range(n_az):
        for k in range(int(hi // c) + 2):
            rc = (k + 0.5) * c
            if lo <= rc < hi and polar(a, k) == FREE:
                ang = a * step + heading
                mark(sx + rc * math.cos(ang), sy + rc * math.sin(ang), FREE)
    for (x, y, _, _, a, k), kind in zip(kept, kinds, strict=True):
        if kind == "obstacle" and k == nearest[a]:
            mark(sx + x, sy + y, OCCUPIED)
    if params.foot_lift_m > 0:   # a foot frees nothing unless a small object stands beside it
        def occupied(row: int, col: int, reach: int) -> int:
            return sum(state[i][j] == OCCUPIED
                       for i in range(max(row - reach, 0), min(row + reach + 1, window.rows))
                       for j in range(max(col - reach, 0), min(col + reach + 1, window.cols)))

        for (x, y, _, _, _, _), kind, lift in zip(kept, kinds, lifts, strict=True):
            col = math.floor((sx + x) / r0) - window.col0
            row = math.floor((sy + y) / r0) - window.row0
            if (kind == "ground" and lift >= params.foot_lift_m and 0 <= row < window.rows
                    and 0 <= col < window.cols and state[row][col] == FREE
                    and not (occupied(row, col, 1) > 0
                             and occupied(row, col, 2) <= SMALL_OBJECT_CELLS)):
                state[row][col] = UNKNOWN
    return state


def classify(kept, n_az, params, gap=None) -> tuple[list[str], list[float]]:
    """'ground' / 'obstacle' / 'ignored' per point, by height above the local ground, and
    each point's height above the ground of the nearest accepted band nearer the sensor in
    its sector (0, the prior, if none). ``gap``: the chain's gap cap (default
    ``params.ground_chain_gap_m``; 0 = none)."""
    cap = params.ground_chain_gap_m if gap is None else gap
    n_sector = round(360.0 / SECTOR_DEG)
    n_band = int(params.max_range_m // BAND_M) + 1
    n_z = round(2 * Z_SPAN_M / Z_BIN_M)
    cells: dict[tuple[int, int], list[float]] = {}
    keys = []
    for (_, _, z, r, a, _) in kept:
        key = (a * n_sector // n_az, min(int(r / BAND_M), n_band - 1))
        keys.append(key)
        cells.setdefault(key, []).append(z + params.sensor_height_m)
    accepted = {}
    for key, heights in cells.items():
        heights.sort()
        nth = heights[max(math.ceil(PERCENTILE * len(heights)), 1) - 1]
        zb = min(max(math.floor((nth + Z_SPAN_M) / Z_BIN_M), 0), n_z - 1)
        estimate = (zb + 0.5) * Z_BIN_M - Z_SPAN_M
        tol = min(BASE_TOL_M + MAX_SLOPE * (key[1] + 1) * BAND_M, Z_SPAN_M)
        if len(heights) >= MIN_POINTS and 0 < zb < n_z - 1 and abs(estimate) <= tol:
            accepted[key] = estimate
    if params.ground_chain:   # outward along each sector: within the slope bound of the last kept
        for sector in range(n_sector):
            last, last_r = 0.0, 0.0
            for band in range(n_band):
                if (sector, band) in accepted:
                    r_out = (band + 1) * BAND_M
                    span = r_out - last_r   # sensor.ground_chain_gap_m caps it (0: no cap)
                    if cap > 0 and last_r > 0:
                        span = min(span, cap)
                    bound = BASE_TOL_M + MAX_SLOPE * span
                    if abs(accepted[(sector, band)] - last) <= bound:
                        last, last_r = accepted[(sector, band)], r_out
                    else:
                        del accepted[(sector, band)]

    def ground_at(sector: int, band: int) -> float:
        for b in range(band, -1, -1):
            if (sector, b) in accepted:
                return accepted[(sector, b)]
        return 0.0

    kinds, lifts = [], []
    for (_, _, z, _, _, _), key in zip(kept, keys, strict=True):
        d = z + params.sensor_height_m - ground_at(*key)
        kinds.append("ground" if d < params.ground_threshold_m
                     else "obstacle" if d <= params.max_obstacle_height_m else "ignored")
        lifts.append(z + params.sensor_height_m - ground_at(key[0], key[1] - 1))
    return kinds, lifts


def reference_grid(points, planar, t_crs_sensor, window, params, context=None):
    """``(free, occupied)`` float32 arrays from :func:`reference_state`."""
    state = np.array(reference_state(points, planar, t_crs_sensor, window, params, context),
                     np.uint8)
    free = np.where(state == FREE, params.mu_free, 0.0).astype(np.float32)
    occupied = np.where(state == OCCUPIED, params.mu_occupied, 0.0).astype(np.float32)
    return free, occupied


def assert_matches_reference(points, planar, t_crs_sensor, window, params, context=None):
    """evperc's sensor grid of ``points`` equal to :func:`reference_grid`'s, cell for cell;
    returns the reference's ``(free, occupied)`` for the caller's own checks."""
    from evperc.sensor import sensor_grid

    free, occ = sensor_grid(points, planar, t_crs_sensor, window, params, context=context)
    want_free, want_occ = reference_grid(points, planar, t_crs_sensor, window, params,
                                         context)
    np.testing.assert_array_equal(free, want_free)
    np.testing.assert_array_equal(occ, want_occ)
    return want_free, want_occ
