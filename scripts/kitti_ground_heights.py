#!/usr/bin/env python3
"""How far above the ground the static points decided moving stand, on a SemanticKITTI slice
(docs/evaluation.md § "the local ground step").

For a run made with ``evperc run SEQ --no-map --point-labels`` and its sequence folder, from
scan ``--warmup`` on: three sets of points — the false moving points (labelled static,
labelled moving by the run, as ``evperc.eval.semantickitti.confusion`` counts them), the
obstacle returns of labelled-moving objects, and a sample of 300 obstacle returns per scan of
labelled-static ones — and for each its height above the coarse ground estimate
(:mod:`evperc.sensor.ground`, the defaults' sensor keys) and above the lowest return in the
3 × 3 block of 0.5 m cells around it (the local minimum step 5 looks at). Prints the quantiles
and the share below the ground threshold (0.3 m) and 0.4 m. Scans are levelled by the sequence's
poses, as the run levels them.

    python scripts/kitti_ground_heights.py RUN ../shared/data/semantickitti/09
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from evperc.config import load_config  # noqa: E402
from evperc.eval.semantickitti import point_masks, read_label_file  # noqa: E402
from evperc.logs.kitti import KittiLog  # noqa: E402
from evperc.sensor.beams import PolarLayout, level_points, polar_bins, sensor_heading  # noqa: E402
from evperc.sensor.ground import OBSTACLE, classify_points, histogram_shape  # noqa: E402
from evperc.sensor.params import SensorParams  # noqa: E402

CELL_M = 0.5
SAMPLE = 300


def split(points: np.ndarray, pose: np.ndarray, params: SensorParams):
    """Levelled x, y, height above the prior, the kind and the height above the coarse
    estimate of each point (as :func:`evperc.sensor.grid.sensor_grid` computes them)."""
    layout = PolarLayout.build(params.azimuth_resolution_deg, params.range_bin_m,
                               params.min_range_m, params.max_range_m)
    n = len(points)
    x, y, z, r, az = (np.empty(n, np.float32) for _ in range(5))
    level_points(np.ascontiguousarray(points).reshape(-1), pose[:3, :3].astype(np.float32),
                 x, y, z, r)
    np.arctan2(y, x, out=az)
    az_bin, range_bin = np.empty(n, np.int32), np.empty(n, np.int32)
    polar_bins(r, az, np.float32(sensor_heading(pose)), layout.inv_az_step32, layout.n_az,
               np.float32(params.min_range_m), np.float32(params.max_range_m),
               layout.inv_range_bin32, az_bin, range_bin)
    hist = np.empty(math.prod(histogram_shape(layout.max_range_m)), np.int32)
    kind, every, d = np.empty(n, np.uint8), np.empty(n, np.uint8), np.empty(n, np.float32)
    scan_fallback = params.ground_fallback == "scan"
    classify_points(z, r, az_bin, layout.n_az, layout.max_range_m, False,
                    np.float32(params.sensor_height_m), np.float32(params.ground_threshold_m),
                    np.float32(params.max_obstacle_height_m), hist, kind, scan_fallback)
    # threshold -10 m: every kept point an obstacle, so d is every point's coarse height
    classify_points(z, r, az_bin, layout.n_az, layout.max_range_m, False,
                    np.float32(params.sensor_height_m), np.float32(-10.0), np.float32(100.0),
                    hist, every, scan_fallback, d)
    return x, y, z + np.float32(params.sensor_height_m), kind, d, az_bin >= 0


def local_heights(x, y, h, kept, index) -> np.ndarray:
    """Height of points ``index`` above the lowest kept return in their 3 × 3 block."""
    ix = np.floor(x / CELL_M).astype(np.int64)
    iy = np.floor(y / CELL_M).astype(np.int64)
    lowest = {}
    for a, b, v in zip(ix[kept], iy[kept], h[kept], strict=True):
        key = (int(a), int(b))
        if v < lowest.get(key, np.inf):
            lowest[key] = float(v)
    out = np.empty(len(index), np.float32)
    for k, i in enumerate(index):
        out[k] = h[i] - min(lowest.get((int(ix[i]) + da, int(iy[i]) + db), np.inf)
                            for da in (-1, 0, 1) for db in (-1, 0, 1))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("sequence", type=Path)
    parser.add_argument("--warmup", type=int, default=2)
    args = parser.parse_args(argv)
    config = load_config()
    params = SensorParams.from_config(config["sensor"], config["grid"]["cell_size_m"])
    log = KittiLog(args.sequence)
    rng = np.random.default_rng(0)
    sets: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {"false moving": [],
                                                             "moving obstacles": [],
                                                             "static obstacles (sample)": []}
    for k, scan in enumerate(log.scans()):
        if k < args.warmup:
            continue
        name = f"{scan.number:06d}.label"
        predicted = read_label_file(args.run / "labels" / name) & 0xFFFF
        truth = read_label_file(args.sequence / "labels" / name) & 0xFFFF
        if scan.source_index is not None:
            predicted, truth = predicted[scan.source_index], truth[scan.source_index]
        x, y, h, kind, d, kept = split(scan.points, scan.T_world_sensor, params)
        said, labelled, moving = point_masks(predicted, truth)
        static_obstacles = np.flatnonzero(labelled & ~moving & (kind == OBSTACLE))
        chosen = {"false moving": np.flatnonzero(said & labelled & ~moving),
                  "moving obstacles": np.flatnonzero(moving & (kind == OBSTACLE)),
                  "static obstacles (sample)": rng.choice(
                      static_obstacles, min(SAMPLE, static_obstacles.size), replace=False)}
        for key, index in chosen.items():
            sets[key].append((d[index], local_heights(x, y, h, kept, index)))
    for key, parts in sets.items():
        if not parts or not sum(len(p[0]) for p in parts):
            print(f"{key}: none")
            continue
        coarse = np.concatenate([p[0] for p in parts])
        local = np.concatenate([p[1] for p in parts])
        print(f"{key}: {coarse.size} points")
        for label, v in (("above the coarse estimate", coarse),
                         ("above the block's lowest return", local)):
            q = np.percentile(v, [10, 25, 50, 75, 90])
            print(f"  {label:32s} q10/25/50/75/90 {' '.join(f'{e:.2f}' for e in q)}  "
                  f"< 0.3 m {np.mean(v < 0.3):.2f}  < 0.4 m {np.mean(v < 0.4):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
