#!/usr/bin/env python3
"""Share of a run's moving-trace cells that lie within a distance of a building outline.

The moving trace (SPEC §6) is every cell decided ``moving`` at any frame of the run. A cell
counts as *near a building* when its centre lies within ``--within`` metres (default 1 m) of a
building polygon's outline or inside a building. Independent of the fusion code: it reads the
run's decisions with :func:`evperc.load` and the buildings of a GeoJSON file (longitude /
latitude, RFC 7946) with json, pyproj and shapely directly.

    .venv/bin/python scripts/trace_near_buildings.py evperc-out/sample sample_data/map.geojson
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np
import pyproj
import shapely
from shapely.geometry import shape

import evperc


def trace_cells(run: evperc.Run) -> np.ndarray:
    """``(K, 2)`` int64 global ``(row, col)`` indices of the cells decided moving at any frame."""
    moving = run.decision_codes["moving"]
    cells: set[tuple[int, int]] = set()
    for frame in run.frames:
        rows, cols = np.nonzero(frame.decision == moving)
        cells.update(zip((rows + frame.origin[0]).tolist(), (cols + frame.origin[1]).tolist(),
                         strict=True))
    return np.array(sorted(cells), dtype=np.int64).reshape(-1, 2)


def near_share(run_dir: str, map_path: str, within_m: float) -> tuple[int, int]:
    """``(cells near a building, trace cells)``."""
    run = evperc.load(run_dir)
    cells = trace_cells(run)
    if len(cells) == 0:
        return 0, 0
    with open(map_path) as f:
        features = json.load(f)["features"]
    lonlat = [shape(f["geometry"]) for f in features if "building" in (f.get("properties") or {})
              and f["geometry"]["type"] in ("Polygon", "MultiPolygon")]
    to_run = pyproj.Transformer.from_crs("EPSG:4326", run.crs, always_xy=True)
    geoms = shapely.transform(np.asarray(lonlat, dtype=object),
                              lambda xy: np.column_stack(to_run.transform(xy[:, 0], xy[:, 1])))
    res = run.resolution_m
    x = (cells[:, 1] + 0.5) * res
    y = (cells[:, 0] + 0.5) * res
    zone = shapely.union_all(shapely.buffer(np.asarray(geoms), within_m))
    shapely.prepare(zone)
    near = shapely.intersects_xy(zone, x, y)
    return int(near.sum()), len(cells)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir")
    parser.add_argument("map", help="GeoJSON in lon/lat; features with a 'building' property")
    parser.add_argument("--within", type=float, default=1.0, help="metres [1.0]")
    args = parser.parse_args(argv)
    near, total = near_share(args.run_dir, args.map, args.within)
    share = near / total if total else 0.0
    print(f"{near} of {total} moving-trace cells ({100 * share:.1f} %) within "
          f"{args.within:g} m of a building")
    return 0


if __name__ == "__main__":
    sys.exit(main())
