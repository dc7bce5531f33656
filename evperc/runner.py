"""The `evperc run` driver: log + map in, output directory out. Reads like its table of
contents: open inputs, geo-reference, then for each scan sensor grid → fusion step →
decision → write. The maths lives in :mod:`evperc.pipeline` and the modules it calls."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from evperc.errors import GeoreferenceError
from evperc.geo import georef as georef_mod
from evperc.geo.crs import working_crs
from evperc.geo.prior import PriorRasteriser, prior_masses
from evperc.geo.window import Window, scroll
from evperc.io.log import PosedScan, open_log
from evperc.io.maps import MapData, check_overlap, load_map
from evperc.io.writer import RunWriter
from evperc.pipeline import (
    CLASSES, DECISION_CODES, OMEGA, FusionParams, decide, fusion_step, sensor_masses, vacuous)
from evperc.sensor import SensorParams, sensor_grid

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunRequest:
    """What the user asked `evperc run` to do."""

    log_path: Path
    out_dir: Path
    config: dict[str, Any]
    map_path: Path | None = None
    roads_path: Path | None = None
    overwrite: bool = False
    start_s: float | None = None
    end_s: float | None = None
    every: int = 1
    lidar_topic: str | None = None
    pose_topic: str | None = None


def extrinsic_matrix(ext: dict[str, float]) -> np.ndarray:
    """4×4 sensor pose in the vehicle frame from the config's ``input.extrinsic`` (ZYX Euler)."""
    r, p, y = (math.radians(ext[k]) for k in ("roll_deg", "pitch_deg", "yaw_deg"))
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), \
        math.sin(y)
    t = np.eye(4)
    t[:3, :3] = [[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                 [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                 [-sp, cp * sr, cp * cr]]
    t[:3, 3] = [ext["x_m"], ext["y_m"], ext["z_m"]]
    return t


def geo_reference(reader: Any, config: dict[str, Any], need_crs: bool
                  ) -> georef_mod.Georeference | None:
    """Place the log's world frame in the working CRS: poses_crs, else origin, else GNSS.

    Returns ``None`` (work in the log's own frame) when no map is used and nothing geo-
    references the log."""
    inp = config["input"]
    if inp["poses_crs"]:
        return georef_mod.identity(working_crs(config["map"]["crs"] or inp["poses_crs"], None))
    if not (math.isnan(inp["origin_lat_deg"]) or math.isnan(inp["origin_lon_deg"])):
        lonlat = (inp["origin_lon_deg"], inp["origin_lat_deg"])
        crs = working_crs(config["map"]["crs"], lonlat)
        return georef_mod.from_origin(inp["origin_lat_deg"], inp["origin_lon_deg"],
                                      inp["origin_heading_deg"], crs)
    fixes = reader.gnss_fixes()
    if len(fixes):
        crs = working_crs(config["map"]["crs"], (float(fixes[0, 2]), float(fixes[0, 1])))
        world_xy = reader.positions_at(fixes[:, 0].astype(np.int64))[:, :2]
        return georef_mod.from_gnss(world_xy, fixes[:, [2, 1]], crs)
    if need_crs:
        raise GeoreferenceError(
            f"{reader.path}: poses are in a local frame and the log has no GNSS topic; set "
            "input.origin_lat_deg / origin_lon_deg / origin_heading_deg (or input.poses_crs) "
            "in a --config file, or run with --no-map")
    return None


def pose_xy_yaw(t_crs_sensor: np.ndarray) -> np.ndarray:
    return np.array([t_crs_sensor[0, 3], t_crs_sensor[1, 3],
                     math.atan2(t_crs_sensor[1, 0], t_crs_sensor[0, 0])])


def run(request: RunRequest, on_frame: Callable[[Any], None] | None = None) -> dict[str, Any]:
    """Run the whole pipeline; returns the summary written into the manifest."""
    config = request.config
    ext = extrinsic_matrix(config["input"]["extrinsic"])
    reader = open_log(request.log_path, lidar_topic=request.lidar_topic or
                      config["input"]["lidar_topic"] or None,
                      pose_topic=request.pose_topic or config["input"]["pose_topic"] or None,
                      gnss_topic=config["input"]["gnss_topic"] or None,
                      world_frame=config["input"]["world_frame"] or None, extrinsic=ext,
                      max_pose_gap_s=config["input"]["max_pose_gap_s"])
    georef = geo_reference(reader, config, need_crs=request.map_path is not None)
    crs_name = georef.crs.to_string() if georef is not None else "local"

    resolution = config["grid"]["cell_size_m"]
    rasteriser = None
    map_data: MapData | None = None
    if request.map_path is not None:
        map_data = load_map(request.map_path, request.roads_path, config_map=config["map"])
        map_data = map_data.to_crs(georef.crs)
        rasteriser = PriorRasteriser(map_data, resolution, config["map"]["tile_size_cells"])
    betas = (config["map"]["beta_building"], config["map"]["beta_road"],
             config["map"]["beta_other"])
    params = FusionParams.from_config(config)
    sensor_params = SensorParams.from_config(config["sensor"], resolution)
    size = config["grid"]["window_size_m"]
    probe = Window.centred_on(0.0, 0.0, size, resolution)
    meta = {"decision_codes": DECISION_CODES, "classes": list(CLASSES), "crs": crs_name,
            "resolution_m": resolution, "rows": probe.rows, "cols": probe.cols,
            "log": str(request.log_path),
            "map": str(request.map_path) if request.map_path else None,
            "roads": str(request.roads_path) if request.roads_path else None}
    writer = RunWriter(request.out_dir, config, meta, overwrite=request.overwrite)

    start_ns = None if request.start_s is None else reader.start_ns + int(request.start_s * 1e9)
    end_ns = None if request.end_s is None else reader.start_ns + int(request.end_s * 1e9)
    omega_vec = np.zeros(32, dtype=np.float32)
    omega_vec[OMEGA] = 1
    window: Window | None = None
    pg = zeta = None
    prev_ns: int | None = None
    decision_counts = np.zeros(len(DECISION_CODES), dtype=np.int64)
    checked_overlap = False
    t0 = time.perf_counter()
    frames = 0
    scans = reader.scans(start_ns=start_ns, end_ns=end_ns)
    bar = tqdm(scans, unit="frame", desc=request.log_path.name, disable=None, leave=False)
    for i, scan in enumerate(bar):
        if i % request.every:
            continue
        scan: PosedScan
        t_crs = georef.apply(scan.T_world_sensor) if georef is not None else scan.T_world_sensor
        pose = pose_xy_yaw(t_crs)
        new_window = Window.centred_on(pose[0], pose[1], size, resolution)
        if map_data is not None and not checked_overlap:
            check_overlap(map_data, new_window.bounds)
            checked_overlap = True
        if window is None:
            pg, zeta = vacuous(new_window.shape), np.zeros(new_window.shape, np.float32)
        elif new_window != window:
            pg = scroll(pg, window, new_window, omega_vec)
            zeta = scroll(zeta, window, new_window, 0.0)
        window = new_window
        free, occupied = sensor_grid(scan.points, scan.planar, t_crs, window, sensor_params)
        prior = (prior_masses(rasteriser.labels(window), *betas) if rasteriser is not None
                 else vacuous(window.shape))
        dt_s = 0.0 if prev_ns is None else (scan.stamp_ns - prev_ns) * 1e-9
        prev_ns = scan.stamp_ns
        pg, zeta, conflict = fusion_step(pg, zeta, sensor_masses(free, occupied), prior,
                                         (free > 0) | (occupied > 0), dt_s, params)
        betp, decision = decide(pg, params)
        writer.add(scan.stamp_ns, pose, (window.row0, window.col0), pg, betp, decision, zeta,
                   conflict)
        if on_frame is not None:
            on_frame(writer.manifest["frame_count"])
        decision_counts += np.bincount(decision.ravel(), minlength=len(decision_counts))
        frames += 1
    bar.close()
    wall = time.perf_counter() - t0
    total = max(int(decision_counts.sum()), 1)
    names = sorted(DECISION_CODES, key=DECISION_CODES.get)
    summary = {"frames": frames, "wall_time_s": round(wall, 3),
               "frames_per_s": round(frames / wall, 2) if wall > 0 else None,
               "decision_share": {n: round(float(decision_counts[DECISION_CODES[n]]) / total, 6)
                                  for n in names},
               "skipped_scans": dict(reader.stats)}
    writer.close(summary)
    return summary
