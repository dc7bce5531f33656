#!/usr/bin/env python3
"""A SemanticKITTI slice's own road as the map's road, for the ground split only: checks the
chain's gap on the road (``sensor.ground_chain_gap_road_only``, docs/method.md §3 "The chain's
gap on the road") on real scans, which come with no map.

The road cells are the 0.5 m lattice cells (in the run's world frame: the first scan's lidar
frame, as ``evperc run`` poses a KITTI folder) holding a point of SemanticKITTI's road,
parking or lane-marking classes (40, 44, 60) in any scan of ``--labels`` (the full slice: a
map does not depend on the sensor), grown by ``--grow`` cells (a map's road is a buffered
centre line, off by a metre or so). The run is ``evperc run SEQ --no-map --point-labels
--preset PRESET [--config FILE]``, with each sensor grid handed those cells as its window's
map context (:func:`evperc.sensor.sensor_grid`'s ``context``) — the prior, the gate and the
rest of the run see no map.

    python scripts/kitti_road_context.py /tmp/sk16/01 --labels ../shared/data/semantickitti/01 \\
        --out /tmp/runs/01-road --grow 2
    evperc evaluate /tmp/runs/01-road --semantickitti /tmp/sk16/01
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from evperc import runner  # noqa: E402
from evperc.cli import cli  # noqa: E402
from evperc.geo.prior import CONTEXT_ROAD  # noqa: E402
from evperc.geo.window import Window  # noqa: E402
from evperc.logs.kitti import KittiLog  # noqa: E402

#: SemanticKITTI's road, parking and lane-marking classes
ROAD_CLASSES = (40, 44, 60)
#: the road's lattice (the defaults' and every preset's grid.cell_size_m)
RESOLUTION_M = 0.5


def road_cells(seq_dir: Path, resolution_m: float = RESOLUTION_M, grow: int = 0) -> np.ndarray:
    """``(K, 2)`` int64 unique lattice cells ``(iy, ix)`` (y = ⌊y/res⌋, x = ⌊x/res⌋ in the
    first scan's lidar frame) holding a point of :data:`ROAD_CLASSES` in any scan of
    ``seq_dir`` (velodyne/, labels/, poses.txt, calib.txt), each grown by ``grow`` cells
    (Chebyshev)."""
    log = KittiLog(seq_dir)
    found = []
    for i, scan in enumerate(log.bins):
        xyz = np.fromfile(scan, "<f4").reshape(-1, 4)[:, :3].astype(np.float64)
        labels = np.fromfile(seq_dir / "labels" / f"{scan.stem}.label", "<u4") & 0xFFFF
        road = xyz[np.isin(labels, ROAD_CLASSES)]
        world = road @ log.poses[i][:3, :3].T + log.poses[i][:3, 3]
        found.append(np.floor(world[:, [1, 0]] / resolution_m).astype(np.int64))
    cells = np.unique(np.vstack(found), axis=0) if found else np.zeros((0, 2), np.int64)
    if grow > 0:
        steps = np.arange(-grow, grow + 1)
        offsets = np.stack(np.meshgrid(steps, steps, indexing="ij"), -1).reshape(-1, 2)
        cells = np.unique((cells[:, None, :] + offsets[None]).reshape(-1, 2), axis=0)
    return cells


def context_of(cells: np.ndarray, window: Window) -> np.ndarray:
    """The uint8 map context of ``window``: road where ``cells`` holds the cell, else 0."""
    context = np.zeros(window.shape, np.uint8)
    r, c = cells[:, 0] - window.row0, cells[:, 1] - window.col0
    inside = (r >= 0) & (r < window.rows) & (c >= 0) & (c < window.cols)
    context[r[inside], c[inside]] = CONTEXT_ROAD
    return context


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("seq", type=Path, help="the KITTI folder to run (e.g. a sparse copy)")
    parser.add_argument("--labels", type=Path, help="the slice whose road labels make the "
                        "road (default: SEQ)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--grow", type=int, default=0, help="cells to grow the road by [0]")
    parser.add_argument("--preset", default="vlp16")
    parser.add_argument("--config", type=Path)
    args = parser.parse_args(argv)
    cells = road_cells(args.labels or args.seq, grow=args.grow)
    sensor_grid = runner.sensor_grid

    def with_road(points, planar, t_crs, window, params, **kwargs):  # noqa: ANN001, ANN202
        if window.resolution_m != RESOLUTION_M:
            raise SystemExit(f"the run's cells are {window.resolution_m} m, the road's "
                             f"{RESOLUTION_M} m: run with grid.cell_size_m = {RESOLUTION_M}")
        kwargs["context"] = context_of(cells, window)
        return sensor_grid(points, planar, t_crs, window, params, **kwargs)

    runner.sensor_grid = with_road
    extra = ["--config", str(args.config)] if args.config else []
    cli.main(["-q", "run", str(args.seq), "--no-map", "--point-labels", "--preset",
              args.preset, *extra, "--out", str(args.out), "--overwrite"],
             standalone_mode=False)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
