"""``evperc simulate``: a synthetic drive on a real map, written as MCAP + map + ground truth.

Output directory::

    DIR/drive.mcap       lidar (/lidar/points or /scan), /odom, /tf, /tf_static, /gnss
    DIR/map.geojson      the map only (buildings, highway lines; CRS84) — no unmapped objects
    DIR/truth/           per-frame truth on evperc's lattice (docs/truth-format.md)

Odometry is in a local frame ``map``: origin at base_link's start position, x axis along
its start heading (like a real odometry log); GNSS fixes geo-reference it. Deterministic for
a given seed: the scene, the traffic, the sensor noise and the pose noise each draw from
their own generator spawned from one ``numpy.random.SeedSequence(seed)``.
"""

from __future__ import annotations

import json
import logging
import math
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pyproj
import shapely

from evperc.errors import OutputError
from evperc.geo.window import Window, overlap
from evperc.progress import bar
from evperc.sim import lidar as lidar_mod
from evperc.sim.rosout import DriveWriter
from evperc.sim.scene import FREE, Scene, Solids, build_scene, read_map_layers
from evperc.sim.traffic import Agents, Trajectory, plan_ego, populate
from evperc.sim.truth import (
    TruthFrame,
    TruthWriter,
    paint_buildings,
    paint_solids,
    visible_cells,
)

log = logging.getLogger(__name__)

SCAN_HZ = 10.0
ODOM_HZ = 50.0
START_NS = 1_700_000_000 * 1_000_000_000


@dataclass(frozen=True)
class SimRequest:
    map_path: Path
    out_dir: Path
    config: dict[str, Any]
    roads_path: Path | None = None
    profile: str = "ibeo4"
    seconds: float = 10.0
    seed: int = 0
    overwrite: bool = False


def _nan_to_none(v: float) -> float | None:
    return None if isinstance(v, float) and math.isnan(v) else v


class DrivePlan(NamedTuple):
    """A drive before any scan is cast (:func:`plan`)."""

    scene: Scene
    profile: lidar_mod.LidarProfile
    t_scan: np.ndarray
    ego: Trajectory
    agents: Agents
    sensor_rng: np.random.Generator
    pose_rng: np.random.Generator


def plan(req: SimRequest, layers: Any) -> DrivePlan:
    """The drive of ``req`` before any scan is cast, from its seed (``layers``: the map's,
    :func:`read_map_layers`)."""
    cfg, sim = req.config, req.config["sim"]
    rngs = [np.random.default_rng(s) for s in np.random.SeedSequence(req.seed).spawn(4)]
    scene_rng, traffic_rng, sensor_rng, pose_rng = rngs
    crs = pyproj.CRS.from_user_input(cfg["map"]["crs"]) if cfg["map"]["crs"] else None
    scene = build_scene(layers, cfg["map"]["road_width_m"], cfg["map"]["default_road_width_m"],
                        crs, scene_rng, sim["furniture_spacing_m"])
    profile = lidar_mod.make_profile(req.profile, _nan_to_none(sim["range_noise_m"]),
                                     _nan_to_none(sim["dropout"]))
    t_scan = np.arange(max(1, int(round(req.seconds * SCAN_HZ)))) / SCAN_HZ
    start_xy = _start_xy(scene, sim)
    ego = plan_ego(scene, req.seconds, sim["ego_max_speed_m_per_s"], traffic_rng, start_xy)
    agents = populate(scene, ego, t_scan, traffic_rng, sim["moving_cars"], sim["pedestrians"],
                      sim["parked_car_spacing_m"], cfg["grid"]["window_size_m"] / 2 + 30.0)
    return DrivePlan(scene, profile, t_scan, ego, agents, sensor_rng, pose_rng)


def simulate(req: SimRequest) -> dict[str, Any]:
    """Simulate the drive of ``req`` and write ``req.out_dir``; returns a summary."""
    wall0 = time.perf_counter()
    cfg, sim = req.config, req.config["sim"]
    layers = read_map_layers(req.map_path, req.roads_path)
    out = _prepare(req.out_dir, req.overwrite)
    scene, profile, t_scan, ego, agents, sensor_rng, pose_rng = plan(req, layers)
    n_scans = len(t_scan)
    size_m, res = cfg["grid"]["window_size_m"], cfg["grid"]["cell_size_m"]
    lidar_xy = _lidar_positions(ego, t_scan, profile.mount_xyz_m)
    region = _region(lidar_xy, size_m, res)
    static = np.full(region.shape, FREE, dtype=np.uint8)
    paint_buildings(static, region, scene.buildings)
    paint_solids(static, None, region, scene.furniture)
    seen = np.zeros(region.shape, dtype=bool)

    drive = DriveWriter(out / "drive.mcap")
    origin = ego.pose(np.array([0.0]))
    to_geo = pyproj.Transformer.from_crs(scene.crs, "EPSG:4326", always_xy=True)
    _write_poses(drive, ego, req.seconds, origin, to_geo, sim, pose_rng)
    drive.static_tf(START_NS, profile.mount_xyz_m)
    meta = _meta(req, scene, profile, agents, origin, to_geo)
    truth = TruthWriter(out / "truth", Window.centred_on(0, 0, size_m, res).rows, res,
                        scene.crs.to_string(), meta, int(cfg["output"]["chunk_frames"]))
    counts = []
    ex, ey, eyaw, _ = ego.pose(t_scan)
    for k in bar(range(n_scans), total=n_scans, desc="simulate", unit="scan"):
        # one scan per iteration; everything inside is vectorised
        ns = START_NS + int(round(t_scan[k] * 1e9))
        lx, ly = lidar_xy[k]
        movers = agents.at(k)
        hits = lidar_mod.cast(profile, lx, ly, eyaw[k], scene.walls, scene.wall_height,
                              _concat(scene.furniture, movers), sensor_rng)
        if profile.planar:
            drive.scan(ns, float(profile.azimuths[0]),
                       float(profile.azimuths[1] - profile.azimuths[0]), hits.range_m[0],
                       profile.min_range_m, profile.max_range_m)
            counts.append(int(np.isfinite(hits.range_m).sum()))
        else:
            pts, intensity, ring = hits.points()
            drive.points(ns, pts, intensity, ring)
            counts.append(len(pts))
        truth.add(_truth_frame(k, ns, lx, ly, eyaw[k], hits, movers, static, seen, region,
                               size_m, res))
    drive.close()
    truth.close()
    _write_map(out / "map.geojson", layers)
    wall = time.perf_counter() - wall0
    summary = {"frames": n_scans, "points_per_scan": float(np.mean(counts)),
               "agents": len(agents), "unmapped_objects": len(scene.furniture),
               "crs": scene.crs.to_string(), "wall_time_s": wall, "out_dir": str(out)}
    log.info("simulated %d scans (%s, %.0f points/scan) in %.1f s -> %s", n_scans,
             profile.name, summary["points_per_scan"], wall, out)
    return summary


def _prepare(out: Path, overwrite: bool) -> Path:
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise OutputError(f"{out}: output directory exists; pass --overwrite to replace "
                              "it or --out to choose another")
        if not (out / "drive.mcap").exists():
            raise OutputError(f"{out}: exists and is not a simulated drive; refusing to "
                              "overwrite it, choose another --out")
        shutil.rmtree(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"{out}: cannot create output directory ({err.strerror})") from err
    return out


def _start_xy(scene: Scene, sim: dict[str, Any]) -> tuple[float, float] | None:
    lat, lon = sim["start_lat_deg"], sim["start_lon_deg"]
    if math.isnan(lat) or math.isnan(lon):
        return None
    fwd = pyproj.Transformer.from_crs("EPSG:4326", scene.crs, always_xy=True)
    return fwd.transform(lon, lat)


def _lidar_positions(ego: Trajectory, t: np.ndarray, mount: tuple[float, float, float]
                     ) -> np.ndarray:
    x, y, yaw, _ = ego.pose(t)
    return np.column_stack([x + mount[0] * np.cos(yaw) - mount[1] * np.sin(yaw),
                            y + mount[0] * np.sin(yaw) + mount[1] * np.cos(yaw)])


def _region(xy: np.ndarray, size_m: float, res: float) -> Window:
    """A lattice window holding every scan's window."""
    half = size_m / 2 + 2 * res
    lo = np.floor((xy.min(axis=0) - half) / res).astype(int)
    hi = np.ceil((xy.max(axis=0) + half) / res).astype(int)
    return Window(res, int(hi[1] - lo[1]), int(hi[0] - lo[0]), int(lo[1]), int(lo[0]))


def _concat(a: Solids, b: Solids) -> Solids:
    return Solids(*(np.concatenate([getattr(a, f), getattr(b, f)])
                    for f in Solids.__dataclass_fields__))


def _truth_frame(k: int, ns: int, lx: float, ly: float, yaw: float, hits: lidar_mod.Hits,
                 movers: Solids, static: np.ndarray, seen: np.ndarray, region: Window,
                 size_m: float, res: float) -> TruthFrame:
    window = Window.centred_on(lx, ly, size_m, res)
    (rg_r, rg_c), (w_r, w_c) = overlap(region, window)
    classes = np.full(window.shape, FREE, dtype=np.uint8)
    classes[w_r, w_c] = static[rg_r, rg_c]
    ids = np.zeros(window.shape, dtype=np.int32)
    paint_solids(classes, ids, window, movers)
    visible = visible_cells(window, hits, lx, ly, yaw)
    seen[rg_r, rg_c] |= visible[w_r, w_c]
    observed = np.zeros(window.shape, dtype=bool)
    observed[w_r, w_c] = seen[rg_r, rg_c]
    return TruthFrame(k, ns, (window.row0, window.col0), window,
                      np.array([lx, ly, yaw]), classes, observed, visible, ids)


def _write_poses(drive: DriveWriter, ego: Trajectory, seconds: float, origin: tuple,
                 to_geo: pyproj.Transformer, sim: dict[str, Any], rng: np.random.Generator
                 ) -> None:
    """Odometry + /tf at ODOM_HZ and GNSS at SCAN_HZ, covering the scans and 0.2 s more."""
    x0, y0, yaw0 = (float(v[0]) for v in origin[:3])
    t = np.arange(int(round((seconds + 0.2) * ODOM_HZ)) + 1) / ODOM_HZ
    x, y, yaw, speed = ego.pose(t)
    c, s = math.cos(yaw0), math.sin(yaw0)
    lx = c * (x - x0) + s * (y - y0)
    ly = -s * (x - x0) + c * (y - y0)
    lyaw = yaw - yaw0
    if sim["pose_noise_m"] > 0 or sim["pose_noise_deg"] > 0:
        lx = lx + rng.normal(0.0, sim["pose_noise_m"], len(t))
        ly = ly + rng.normal(0.0, sim["pose_noise_m"], len(t))
        lyaw = lyaw + np.deg2rad(rng.normal(0.0, sim["pose_noise_deg"], len(t)))
    lon, lat = to_geo.transform(x, y)
    gx = rng.normal(0.0, sim["gnss_noise_m"], len(t)) if sim["gnss_noise_m"] > 0 else 0 * t
    gy = rng.normal(0.0, sim["gnss_noise_m"], len(t)) if sim["gnss_noise_m"] > 0 else 0 * t
    glon, glat = to_geo.transform(x + gx, y + gy)
    every = int(round(ODOM_HZ / SCAN_HZ))
    for i in range(len(t)):  # one message per pose
        ns = START_NS + int(round(t[i] * 1e9))
        drive.odometry(ns, float(lx[i]), float(ly[i]), float(lyaw[i]), float(speed[i]))
        if i % every == 0:
            drive.gnss(ns, float(glat[i]), float(glon[i]), 20.0, sim["gnss_noise_m"])
    del lon, lat


def _meta(req: SimRequest, scene: Scene, profile: lidar_mod.LidarProfile, agents: Agents,
          origin: tuple, to_geo: pyproj.Transformer) -> dict[str, Any]:
    x0, y0, yaw0 = (float(v[0]) for v in origin[:3])
    lon0, lat0 = to_geo.transform(x0, y0)
    lon1, lat1 = to_geo.transform(x0 + 10.0 * math.cos(yaw0), y0 + 10.0 * math.sin(yaw0))
    azimuth = pyproj.Geod(ellps="WGS84").inv(lon0, lat0, lon1, lat1)[0]
    true_heading = (90.0 - azimuth + 180.0) % 360.0 - 180.0
    return {
        "seed": req.seed, "profile": profile.name, "seconds": req.seconds,
        "map": str(req.map_path), "roads": str(req.roads_path) if req.roads_path else None,
        "lidar_mount_m": list(profile.mount_xyz_m),
        "odom_origin": {"x_m": x0, "y_m": y0, "yaw_rad": yaw0, "lat_deg": lat0,
                        "lon_deg": lon0, "heading_deg": true_heading,
                        "grid_heading_deg": math.degrees(yaw0)},
        "agents": [{"id": i + 1, "role": str(agents.role[i]), "length_m": agents.length[i],
                    "width_m": agents.width[i], "height_m": agents.height[i]}
                   for i in range(len(agents))]}


def _write_map(path: Path, layers) -> None:  # noqa: ANN001 - MapLayers
    """OSM-style GeoJSON in CRS84: buildings (building=yes) and highway lines."""
    tf = pyproj.Transformer.from_crs(layers.crs, "OGC:CRS84", always_xy=True)

    def geo(geoms: np.ndarray) -> np.ndarray:
        return shapely.transform(geoms, lambda xy: np.column_stack(tf.transform(*xy.T)))

    features = [{"type": "Feature", "properties": {"building": "yes"},
                 "geometry": json.loads(g)} for g in shapely.to_geojson(geo(layers.buildings))]
    features += [{"type": "Feature", "properties": {"highway": str(h)},
                  "geometry": json.loads(g)}
                 for g, h in zip(shapely.to_geojson(geo(layers.roads)), layers.highway,
                                 strict=True)]
    doc = {"type": "FeatureCollection",
           "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:OGC:1.3:CRS84"}},
           "features": features}
    path.write_text(json.dumps(doc))
