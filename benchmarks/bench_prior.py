"""GIS prior timings over central Helsinki (tests/data/osm, 446 buildings, ~950 road surfaces).

A 200 m × 200 m window at 0.5 m (400 × 400 cells) with 256-cell tiles: the first call
(every tile rasterised), the same window again (all tiles from the cache), the window moved
by one cell (cache), the direct uncached rasterisation of the window, and the map loading;
the buildings widened by the default 0.5 m margin (the motion gate's layer, a second
rasteriser in a run), first time, with every cell of their boxes tested and with the
prior's building cells taken from its cached tiles (``inner``, as a run does).
``run()`` returns one dict per row; ``python benchmarks/bench_prior.py`` prints the table.
A cold time is measured on a fresh rasteriser each repeat; the best of the repeats is kept.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyproj
from timing import best_of  # noqa: E402  (benchmarks/ is on sys.path)

from evperc.config import default_config
from evperc.geo.maps import load_map
from evperc.geo.prior import PriorRasteriser, prior_masses
from evperc.geo.window import Window

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "osm"
CENTRE_LONLAT = (24.944, 60.170)
SIZE_M = 200.0
RESOLUTION_M = 0.5
TILE = 256
REPEATS = 3




def run() -> list[dict]:
    cfg = default_config()["map"]
    paths = (DATA / "helsinki_buildings.geojson", DATA / "helsinki_roads.geojson")
    load_s = best_of(lambda: load_map(*paths, config_map=cfg))
    md = load_map(*paths, config_map=cfg)
    x, y = pyproj.Transformer.from_crs("EPSG:4326", md.crs, always_xy=True).transform(
        *CENTRE_LONLAT)
    window = Window.centred_on(x, y, SIZE_M, RESOLUTION_M)
    moved = Window(RESOLUTION_M, window.rows, window.cols, window.row0 + 1, window.col0)
    cells = window.rows * window.cols

    colds = []
    for _ in range(REPEATS):
        r = PriorRasteriser(md, RESOLUTION_M, TILE)
        t0 = time.perf_counter()
        r.labels(window)
        colds.append(time.perf_counter() - t0)
    tiles = r.stats["tiles_rasterised"]
    labels = r.labels(window)
    buildings = replace(md, roads=md.roads[:0])
    margin = cfg["building_margin_m"]

    def widened(inner: PriorRasteriser | None) -> float:
        wide = PriorRasteriser(buildings, RESOLUTION_M, TILE, building_margin_m=margin,
                               inner=inner)
        t0 = time.perf_counter()
        wide.labels(window)
        return time.perf_counter() - t0

    wide_tested = min(widened(None) for _ in range(REPEATS))
    wide_inner = min(widened(r) for _ in range(REPEATS))
    cases = [
        ("load_map (2 GeoJSON files)", load_s, "-"),
        ("labels, first time", min(colds), f"{tiles} tiles rasterised"),
        ("labels, cache hit", best_of(lambda: r.labels(window)), "0 tiles rasterised"),
        ("labels, moved 1 cell", best_of(lambda: r.labels(moved)), "0 tiles rasterised"),
        ("rasterise, uncached window", best_of(lambda: r.rasterise(window)), "-"),
        (f"widened {margin} m, first time, every cell tested", wide_tested, "buildings only"),
        (f"widened {margin} m, first time, inner = the prior's", wide_inner,
         "its building cells untested"),
        ("prior_masses (float32)", best_of(lambda: prior_masses(labels, 0.9, 0.9, 0.8)), "-"),
    ]
    share = np.bincount(labels.ravel(), minlength=3) / cells
    rows = []
    for name, seconds, note in cases:
        per_cell = not name.startswith("load_map")
        rows.append({"case": name, "cells": cells if per_cell else "",
                     "ms": round(seconds * 1e3, 3),
                     "Mcells_per_s": round(cells / seconds / 1e6, 2) if per_cell else "",
                     "note": note})
    rows.append({"case": "label shares other/road/building", "cells": cells, "ms": "",
                 "Mcells_per_s": "", "note": "/".join(f"{v:.2f}" for v in share)})
    return rows


if __name__ == "__main__":
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from run import print_table

    print_table("prior", run())
