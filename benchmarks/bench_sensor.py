"""Sensor-grid benchmark (method.md §3): milliseconds per frame of :func:`evperc.sensor.sensor_grid`
and the speed-up over a naive per-point / per-cell Python implementation.

Cases:

- (a) the scans of workload (a) of ``bench_run.py`` (hdl64, ~117,000 points, 200 m window at
  0.5 m = 400 × 400 cells): every 10th scan of ``bench-out/sim-hdl64-10s/drive.mcap`` in the
  working CRS, with the state and window the runner would use; only if ``bench_run.py`` has
  simulated that log (``bench-out/`` is not in git);
- (a') a ~120k-point synthetic HDL-64-like street cloud on a 400 × 400 window (always there);
- (b) an ibeo-like 4-layer scan (≤ 800 points) on a 200 × 200 window;
- (c) the real KITTI 00 scan 0 (124,668 points) on a 400 × 400 window, if
  /work/shared/data/kitti00 exists.

``ms med`` / ``ms best``: median / best of ``repeats`` calls per scan, averaged over the scans
of the case; ``fps`` = 1000 / ``ms med``. The naive reference is the oracle of the tests
(tests/sensor/reference.py), run once on the *full* input of the first scan of each case (no
subset, no scaling); ``agree``: its output equals the fast one. One thread.

Before / after a change: run this same script from the root of each source tree (e.g. an
older commit unpacked with ``git archive``), ``--no-naive`` to skip the slow reference.

Run: ``.venv/bin/python benchmarks/bench_sensor.py [--repeats N] [--no-naive]``
"""

from __future__ import annotations

import argparse
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
HDL64_LOG = ROOT / "bench-out/sim-hdl64-10s"
LOG_SCANS = 10  # every 10th scan of the 100


def _log_case() -> dict | None:
    """Workload (a): scans of the simulated hdl64 log as the runner hands them over."""
    if not (HDL64_LOG / "drive.mcap").exists():
        return None
    from evperc.runner import Pipeline, RunRequest, pose_xy_yaw

    config = default_config()
    config["grid"]["window_size_m"] = 200.0
    pipeline = Pipeline(RunRequest(log_path=HDL64_LOG / "drive.mcap",
                                   out_dir=HDL64_LOG.parent / "unused", config=config,
                                   map_path=HDL64_LOG / "map.geojson"))
    frames = []
    for index, scan in pipeline.scans(-1):
        if index % 10 == 1:
            t = pipeline.georef.apply(scan.T_world_sensor)
            xy_yaw = pose_xy_yaw(t)
            window = Window.centred_on(xy_yaw[0], xy_yaw[1], pipeline.window_size,
                                       pipeline.resolution)
            frames.append((scan.points, scan.planar, t, window, pipeline.sensor_params))
        if len(frames) == LOG_SCANS:
            break
    return {"case": "a: hdl64 log, workload (a)", "frames": frames}


def _cases() -> list[dict]:
    base = SensorParams.from_config(default_config()["sensor"], 0.5)
    cases = [case for case in [_log_case()] if case is not None]
    t = pose(457_123.4, 5_428_765.3, 118.0, yaw_deg=37.0, pitch_deg=1.5, roll_deg=-0.7)
    level = hdl64_scene(0).astype(np.float64)
    cases.append({"case": "a': synthetic HDL-64, 3-D", "frames": [
        ((level @ t[:3, :3]).astype(np.float32), False, t,
         Window.centred_on(t[0, 3], t[1, 3], 200.0, 0.5), base)]})
    t_ibeo = pose(457_123.4, 5_428_765.3, 0.5, yaw_deg=-12.0)
    ibeo_params = SensorParams.from_config({**default_config()["sensor"], "sensor_height_m": 0.5},
                                           0.5)
    cases.append({"case": "b: ibeo-like 4 layers, 3-D", "frames": [
        (ibeo_scene(0), False, t_ibeo, Window.centred_on(t_ibeo[0, 3], t_ibeo[1, 3], 100.0, 0.5),
         ibeo_params)]})
    if KITTI_SCAN.exists():
        t_k = pose(457_000.0, 5_428_000.0, 118.0, yaw_deg=59.6)
        points = np.fromfile(KITTI_SCAN, np.float32).reshape(-1, 4)[:, :3].copy()
        cases.append({"case": "c: KITTI 00 scan 0, 3-D", "frames": [
            (points, False, t_k, Window.centred_on(t_k[0, 3], t_k[1, 3], 200.0, 0.5), base)]})
    return cases


def _time_frame(args: tuple, repeats: int) -> tuple[float, float]:
    """Median and best seconds of ``repeats`` calls (after one warm-up call)."""
    sensor_grid(*args)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sensor_grid(*args)
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), min(times)


def run(repeats: int = 30, naive: bool = True) -> list[dict]:
    """One row per case: points, window, ms/frame (median and best of ``repeats`` per scan,
    averaged over the case's scans), frames/s, naive seconds (one run on the first scan),
    speed-up, and whether both outputs agree."""
    rows = []
    for case in _cases():
        frames = case["frames"]
        timed = np.array([_time_frame(args, repeats) for args in frames])
        first = frames[0]
        free, occ = sensor_grid(*first)
        ms_median, ms_best = 1e3 * timed.mean(axis=0)
        row = {"case": case["case"], "scans": len(frames), "points": len(first[0]),
               "window": "x".join(map(str, first[3].shape)), "ms_median": ms_median,
               "ms_best": ms_best, "frames_per_s": 1e3 / ms_median,
               "free_cells": int((free > 0).sum()), "occupied_cells": int((occ > 0).sum())}
        if naive:
            t0 = time.perf_counter()
            ref_free, ref_occ = reference_grid(*first)
            row["naive_s"] = time.perf_counter() - t0
            row["speedup"] = row["naive_s"] * 1e3 / ms_median
            row["agree"] = bool(np.array_equal(free, ref_free) and np.array_equal(occ, ref_occ))
        rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--no-naive", action="store_true", help="skip the naive reference")
    args = parser.parse_args()
    rows = run(args.repeats, naive=not args.no_naive)
    head = (f"{'case':30} {'scans':>5} {'points':>7} {'window':>8} {'ms med':>7} {'ms best':>7} "
            f"{'fps':>6} {'naive s':>8} {'speedup':>8} {'agree':>5} {'free':>6} {'occ':>5}")
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r['case']:30} {r['scans']:5d} {r['points']:7d} {r['window']:>8} "
              f"{r['ms_median']:7.3f} {r['ms_best']:7.3f} {r['frames_per_s']:6.0f} "
              f"{r.get('naive_s', float('nan')):8.2f} {r.get('speedup', float('nan')):8.0f} "
              f"{str(r.get('agree', '-')):>5} {r['free_cells']:6d} {r['occupied_cells']:5d}")
    print("ms med / ms best: per scan, averaged over the scans; fps = 1000 / ms med. naive = "
          "tests/sensor/reference.py (plain Python per point / per cell), one run on the first "
          "scan's full input, not scaled")


if __name__ == "__main__":
    main()
