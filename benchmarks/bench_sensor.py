"""Sensor-grid benchmark (SPEC §3): milliseconds per frame of :func:`evperc.sensor.sensor_grid`
and the speed-up over a naive per-point / per-cell Python implementation.

Cases: (a) a ~120k-point synthetic HDL-64-like street cloud on a 400 × 400 window (200 m at
0.5 m); (b) an ibeo-like 4-layer scan (≤ 800 points) on a 200 × 200 window; (c) the real
KITTI 00 scan 0 (124,668 points) on a 400 × 400 window, if /work/shared/data/kitti00 exists.
The naive reference is the oracle of the tests (tests/sensor/reference.py), run once on the
*full* input of each case (no subset, no scaling); its output is checked equal to the fast
one. Single process; numpy may use one or two cores for nothing here (no BLAS calls).

Run: ``.venv/bin/python benchmarks/bench_sensor.py``
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from evperc.config import default_config  # noqa: E402
from evperc.geo.window import Window  # noqa: E402
from evperc.sensor import SensorParams, sensor_grid  # noqa: E402
from tests.sensor.reference import reference_grid  # noqa: E402
from tests.sensor.scenes import hdl64_scene, ibeo_scene, pose  # noqa: E402

KITTI_SCAN = ROOT.parent / "shared/data/kitti00/velodyne/000000.bin"


def _cases() -> list[dict]:
    base = SensorParams.from_config(default_config()["sensor"], 0.5)
    t = pose(457_123.4, 5_428_765.3, 118.0, yaw_deg=37.0, pitch_deg=1.5, roll_deg=-0.7)
    level = hdl64_scene(0).astype(np.float64)
    cases = [{
        "case": "a: synthetic HDL-64, 3-D", "points": (level @ t[:3, :3]).astype(np.float32),
        "planar": False, "pose": t, "params": base,
        "window": Window.centred_on(t[0, 3], t[1, 3], 200.0, 0.5)}]
    t_ibeo = pose(457_123.4, 5_428_765.3, 0.5, yaw_deg=-12.0)
    cases.append({
        "case": "b: ibeo-like 4 layers, 3-D", "points": ibeo_scene(0), "planar": False,
        "pose": t_ibeo, "window": Window.centred_on(t_ibeo[0, 3], t_ibeo[1, 3], 100.0, 0.5),
        "params": SensorParams.from_config({**default_config()["sensor"],
                                            "sensor_height_m": 0.5}, 0.5)})
    if KITTI_SCAN.exists():
        t_k = pose(457_000.0, 5_428_000.0, 118.0, yaw_deg=59.6)
        cases.append({
            "case": "c: KITTI 00 scan 0, 3-D",
            "points": np.fromfile(KITTI_SCAN, np.float32).reshape(-1, 4)[:, :3].copy(),
            "planar": False, "pose": t_k, "params": base,
            "window": Window.centred_on(t_k[0, 3], t_k[1, 3], 200.0, 0.5)})
    return cases


def run(repeats: int = 30, naive: bool = True) -> list[dict]:
    """One row per case: points, window, fast ms/frame (median and best of ``repeats``),
    naive seconds (one run, full input), speed-up, and whether both outputs agree."""
    rows = []
    for case in _cases():
        args = (case["points"], case["planar"], case["pose"], case["window"], case["params"])
        free, occ = sensor_grid(*args)   # warm-up
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            sensor_grid(*args)
            times.append(time.perf_counter() - t0)
        row = {"case": case["case"], "points": len(case["points"]),
               "window": "x".join(map(str, case["window"].shape)),
               "ms_median": 1e3 * float(np.median(times)), "ms_best": 1e3 * min(times),
               "free_cells": int((free > 0).sum()), "occupied_cells": int((occ > 0).sum())}
        if naive:
            t0 = time.perf_counter()
            ref_free, ref_occ = reference_grid(*args)
            row["naive_s"] = time.perf_counter() - t0
            row["speedup"] = row["naive_s"] * 1e3 / row["ms_median"]
            row["agree"] = bool(np.array_equal(free, ref_free) and np.array_equal(occ, ref_occ))
        rows.append(row)
    return rows


def main() -> None:
    rows = run()
    head = (f"{'case':30} {'points':>7} {'window':>8} {'ms med':>7} {'ms best':>7} "
            f"{'naive s':>8} {'speedup':>8} {'agree':>5} {'free':>6} {'occ':>5}")
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r['case']:30} {r['points']:7d} {r['window']:>8} {r['ms_median']:7.2f} "
              f"{r['ms_best']:7.2f} {r.get('naive_s', float('nan')):8.2f} "
              f"{r.get('speedup', float('nan')):8.0f} {str(r.get('agree', '-')):>5} "
              f"{r['free_cells']:6d} {r['occupied_cells']:5d}")
    print("naive = tests/sensor/reference.py (plain Python per point / per cell), one run on "
          "the full input, not scaled")


if __name__ == "__main__":
    main()
