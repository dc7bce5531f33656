"""End-to-end simulator invariants on the Helsinki OSM extract (tests/data/osm)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pyproj
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from evperc.config import load_config
from evperc.geo.window import Window, overlap
from evperc.sim.drive import ODOM_HZ, SCAN_HZ, SimRequest, simulate
from evperc.sim.truth import load_truth

DATA = Path(__file__).resolve().parents[1] / "data" / "osm"
BUILDINGS = DATA / "helsinki_buildings.geojson"
ROADS = DATA / "helsinki_roads.geojson"
MOVING = 2


def run_sim(out: Path, profile: str = "ibeo4", seconds: float = 2.0, seed: int = 7,
            **overrides: object) -> Path:
    cfg = load_config(overrides={"grid.window_size_m": 40.0, **overrides})
    simulate(SimRequest(BUILDINGS, out, cfg, roads_path=ROADS, profile=profile,
                        seconds=seconds, seed=seed))
    return out


def decoded(path: Path, topic: str) -> list:
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [(msg.log_time, ros) for _, _, msg, ros in
                reader.iter_decoded_messages(topics=[topic])]


def truth_arrays(out: Path) -> list[np.ndarray]:
    arrays = []
    for t in load_truth(out / "truth").frames:
        arrays += [t.classes, t.observed, t.visible, t.agent, t.sensor_pose]
    return arrays


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return run_sim(tmp_path_factory.mktemp("sim") / "drive")


def test_each_points_ring_is_its_layer_by_elevation(drive: Path) -> None:
    """The ring field a driver writes: 0 for the lowest layer. Checked from the points'
    own geometry: each ring's elevations (atan2(z, horizontal range)) lie within 0.01° of
    one value, and those values rise with the ring — ibeo4's four layers 0.8° apart."""
    raw = np.dtype({"names": ["x", "y", "z", "ring"], "formats": ["<f4", "<f4", "<f4", "<u2"],
                    "offsets": [0, 4, 8, 12], "itemsize": 16})
    for _, msg in decoded(drive / "drive.mcap", "/lidar/points")[:3]:
        p = np.frombuffer(bytes(msg.data), raw)
        elevation = np.degrees(np.arctan2(p["z"], np.hypot(p["x"], p["y"])))
        rings = np.unique(p["ring"])
        assert set(rings.tolist()) <= {0, 1, 2, 3} and len(rings) >= 3
        centre = [np.median(elevation[p["ring"] == r]) for r in rings]
        for r, c in zip(rings, centre, strict=True):
            assert np.abs(elevation[p["ring"] == r] - c).max() < 0.01
        np.testing.assert_allclose(np.diff(centre), 0.8 * np.diff(rings), atol=0.01)


def test_mcap_decodes_with_mcap_ros2(drive: Path) -> None:
    with (drive / "drive.mcap").open("rb") as f:
        summary = make_reader(f).get_summary()
    topics = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert topics == {"/lidar/points": "sensor_msgs/msg/PointCloud2",
                      "/odom": "nav_msgs/msg/Odometry", "/tf": "tf2_msgs/msg/TFMessage",
                      "/tf_static": "tf2_msgs/msg/TFMessage",
                      "/gnss": "sensor_msgs/msg/NavSatFix"}
    clouds = decoded(drive / "drive.mcap", "/lidar/points")
    assert len(clouds) == 20
    for log_time, msg in clouds:
        assert msg.header.frame_id == "lidar" and msg.point_step == 16
        assert [(f.name, f.offset, f.datatype) for f in msg.fields] == [
            ("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("ring", 12, 4), ("intensity", 14, 2)]
        assert len(bytes(msg.data)) == 16 * msg.width * msg.height
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == log_time
        assert 500 <= msg.width <= 800   # ibeo4: 800 beams, most return in a street
    stamps = np.array([t for t, _ in clouds])
    np.testing.assert_array_equal(np.diff(stamps), 100_000_000)
    (_, tf_static), = decoded(drive / "drive.mcap", "/tf_static")
    tr = tf_static.transforms[0]
    assert (tr.header.frame_id, tr.child_frame_id) == ("base_link", "lidar")
    assert (tr.transform.translation.x, tr.transform.translation.z) == (3.7, 0.5)
    odom = decoded(drive / "drive.mcap", "/odom")
    assert odom[0][1].header.frame_id == "map" and odom[0][1].child_frame_id == "base_link"
    first = odom[0][1].pose.pose
    assert (first.position.x, first.position.y, first.orientation.z) == (0.0, 0.0, 0.0)
    fixes = decoded(drive / "drive.mcap", "/gnss")
    assert len(fixes) >= 20
    lat = np.array([m.latitude for _, m in fixes])
    lon = np.array([m.longitude for _, m in fixes])
    assert ((60.16 < lat) & (lat < 60.18) & (24.93 < lon) & (lon < 24.96)).all()


def test_messages_are_in_log_time_order_in_the_file(drive: Path) -> None:
    """As a recorder writes them: in file order (not the reader's log-time merge) every
    message's log time is at or after the one before, so the poses of the drive are spread
    over the scans' chunks instead of all sitting in the first ones."""
    with (drive / "drive.mcap").open("rb") as f:
        reader = make_reader(f)
        in_file = [(channel.topic, message.log_time) for _, channel, message in
                   reader.iter_messages(log_time_order=False)]
    times = np.array([t for _, t in in_file])
    assert (np.diff(times) >= 0).all()
    topics = [topic for topic, _ in in_file]
    first_scan, last_scan = topics.index("/lidar/points"), len(topics) - 1 - topics[::-1].index(
        "/lidar/points")
    between = topics[first_scan:last_scan]
    assert between.count("/odom") == round(ODOM_HZ / SCAN_HZ) * 19  # between the 20 scans
    assert topics.count("/lidar/points") == 20 and topics.count("/tf_static") == 1


def test_truth_windows_follow_the_lidar_pose_from_odometry_and_origin(drive: Path) -> None:
    truth = load_truth(drive / "truth")
    meta = truth.manifest
    origin = meta["odom_origin"]
    odom = {t: m.pose.pose for t, m in decoded(drive / "drive.mcap", "/odom")}
    for t in truth.frames:
        p = odom[t.stamp_ns]
        yaw_local = 2 * math.atan2(p.orientation.z, p.orientation.w)
        c, s = math.cos(origin["yaw_rad"]), math.sin(origin["yaw_rad"])
        bx = origin["x_m"] + c * p.position.x - s * p.position.y
        by = origin["y_m"] + s * p.position.x + c * p.position.y
        yaw = origin["yaw_rad"] + yaw_local
        lx, ly = bx + 3.7 * math.cos(yaw), by + 3.7 * math.sin(yaw)
        np.testing.assert_allclose(t.sensor_pose[:2], [lx, ly], atol=1e-6)
        w = Window.centred_on(lx, ly, 40.0, 0.5)
        assert t.origin == (w.row0, w.col0) and t.classes.shape == (80, 80)
    # GNSS is base_link's position: project the first fix and compare with the origin
    _, fix = decoded(drive / "drive.mcap", "/gnss")[0]
    fwd = pyproj.Transformer.from_crs("EPSG:4326", meta["crs"], always_xy=True)
    np.testing.assert_allclose(fwd.transform(fix.longitude, fix.latitude),
                               [origin["x_m"], origin["y_m"]], atol=1e-3)


def test_observed_accumulates_and_contains_visible(drive: Path) -> None:
    frames = list(load_truth(drive / "truth").frames)
    assert all((f.observed >= f.visible).all() for f in frames)
    assert frames[-1].visible.any()
    for a, b in zip(frames, frames[1:], strict=False):
        (ra, ca), (rb, cb) = overlap(a.window, b.window)
        assert (b.observed[rb, cb] >= a.observed[ra, ca]).all()


def test_map_holds_buildings_and_highways_only(drive: Path) -> None:
    doc = json.loads((drive / "map.geojson").read_text())
    props = [f["properties"] for f in doc["features"]]
    assert sum("building" in p for p in props) == 446
    assert all(("building" in p) != ("highway" in p) for p in props)
    assert doc["crs"]["properties"]["name"].endswith("CRS84")


def test_same_seed_same_bytes_other_seed_differs(drive: Path, tmp_path: Path) -> None:
    again = run_sim(tmp_path / "again")
    for a, b in zip(truth_arrays(drive), truth_arrays(again), strict=True):
        assert a.tobytes() == b.tobytes()
    pa = [bytes(m.data) for _, m in decoded(drive / "drive.mcap", "/lidar/points")]
    pb = [bytes(m.data) for _, m in decoded(again / "drive.mcap", "/lidar/points")]
    assert pa == pb
    other = run_sim(tmp_path / "other", seed=8)
    pc = [bytes(m.data) for _, m in decoded(other / "drive.mcap", "/lidar/points")]
    assert pa != pc


def test_stationary_ego_without_movers_has_no_moving_truth(tmp_path: Path) -> None:
    out = run_sim(tmp_path / "still", seconds=1.0, **{
        "sim.ego_max_speed_m_per_s": 0.0, "sim.moving_cars": 0, "sim.pedestrians": 0,
        "sim.parked_car_spacing_m": 1e6})
    frames = list(load_truth(out / "truth").frames)
    assert all(not (f.classes == MOVING).any() for f in frames)
    assert len({f.origin for f in frames}) == 1
    assert (frames[-1].classes != 1).any()   # the scene is not empty: buildings at least


@pytest.mark.parametrize(("profile", "topic", "low", "high", "mount_m"), [
    ("hdl64", "/lidar/points", 100_000, 128_000, 1.9),
    # vlp16: 16 layers × 1,800 azimuths; the 7 lowest meet the road within 100 m (the −1°
    # layer at 103 m), so at least 7 × 1,800 less 1 % dropouts return
    ("vlp16", "/lidar/points", 12_400, 28_800, 1.8),
    # hdl32: 32 layers × 1,800 azimuths; the 23 lowest meet the road within 100 m (the
    # −1.41° layer at 77 m, the next, −0.08°, beyond), so at least 23 × 1,800 less 1 % return
    ("hdl32", "/lidar/points", 40_900, 57_600, 1.9),
    ("scan2d", "/scan", 1, 541, None),
])
def test_point_counts_per_profile(tmp_path: Path, profile: str, topic: str, low: int,
                                  high: int, mount_m: float | None) -> None:
    out = run_sim(tmp_path / profile, profile=profile, seconds=0.2)
    msgs = decoded(out / "drive.mcap", topic)
    assert len(msgs) == 2
    for _, m in msgs:
        if profile == "scan2d":
            r = np.array(m.ranges)
            assert len(r) == 541 and m.header.frame_id == "lidar"
            n = int(np.isfinite(r).sum())
            assert (r[np.isfinite(r)] <= m.range_max).all()
        else:
            n = m.width
            z = np.frombuffer(bytes(m.data), "<f4").reshape(-1, 4)[:, 2]
            assert (np.abs(z + mount_m) < 0.1).mean() > 0.3   # ground returns, mount_m below
        assert low <= n <= high
