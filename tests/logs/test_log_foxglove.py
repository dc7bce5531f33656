"""foxglove-sdk logs (protobuf): PointCloud + PoseInFrame + FrameTransforms + LocationFix."""

from __future__ import annotations

import numpy as np

from evperc.logs.factory import open_log
from tests.logs.reference import S0, geodesic_interpolation
from tests.mcap_writers import transform, write_foxglove_mcap

MS = 1_000_000


def _at(poses, stamp):
    stamps = [ns for ns, _ in poses]
    i = int(np.searchsorted(stamps, stamp))
    (t0, T0), (t1, T1) = poses[i - 1], poses[i]
    return geodesic_interpolation(T0, T1, (stamp - t0) / (t1 - t0))


def _log(tmp_path, cloud_pose=None):
    rng = np.random.default_rng(2)
    clouds = [(S0 + i * 100 * MS, rng.uniform(-10, 10, (250, 3)), "lidar") for i in range(3)]
    poses = [(S0 - 10 * MS + i * 70 * MS, transform(x=3.0 * i, y=-1.0 * i, yaw=-0.2 * i))
             for i in range(6)]
    base_lidar = transform(x=1.0, z=2.0, yaw=0.1)
    fixes = [(S0 + i * 100 * MS, 48.98 + 1e-5 * i, 8.39, 116.0) for i in range(3)]
    path = write_foxglove_mcap(
        tmp_path / "fox.mcap", clouds=clouds, poses=poses,
        frame_transforms=[(ns, "world", "base_link", T) for ns, T in poses],
        static_transforms=[("base_link", "lidar", base_lidar)], fixes=fixes,
        cloud_pose=cloud_pose)
    return path, clouds, poses, base_lidar, fixes


def test_foxglove_pose_in_frame(tmp_path):
    path, clouds, poses, base_lidar, fixes = _log(tmp_path)
    log = open_log(path)
    info = log.info()
    assert {t["topic"]: (t["schema"], t["encoding"]) for t in info["topics"]} == {
        "/lidar": ("foxglove.PointCloud", "protobuf"),
        "/pose": ("foxglove.PoseInFrame", "protobuf"),
        "/tf": ("foxglove.FrameTransforms", "protobuf"),
        "/tf_static": ("foxglove.FrameTransforms", "protobuf"),
        "/gps": ("foxglove.LocationFix", "protobuf")}
    assert info["detected"]["gnss_topic"] == "/gps"
    out = list(log.scans())
    assert len(out) == 3 and log.stats == {}
    for scan, (ns, pts, _) in zip(out, clouds, strict=True):
        np.testing.assert_allclose(scan.points, pts.astype(np.float32))
        # PoseInFrame names no body: the body is the root of the static tree (base_link)
        np.testing.assert_allclose(scan.T_world_sensor, _at(poses, ns) @ base_lidar, atol=1e-9)
    np.testing.assert_allclose(log.gnss_fixes(), np.array(fixes, dtype=np.float64))


def test_foxglove_frame_transforms_as_pose_source(tmp_path):
    path, clouds, poses, base_lidar, _ = _log(tmp_path)
    log = open_log(path, pose_topic="/tf")
    out = list(log.scans())
    assert len(out) == 3
    for scan in out:
        np.testing.assert_allclose(scan.T_world_sensor,
                                   _at(poses, scan.stamp_ns) @ base_lidar, atol=1e-9)


def test_point_cloud_origin_pose_is_folded_into_the_sensor_pose(tmp_path):
    origin = transform(x=0.5, y=-0.25, yaw=0.3)
    path, clouds, poses, base_lidar, _ = _log(tmp_path, cloud_pose=origin)
    for scan in open_log(path).scans():
        np.testing.assert_allclose(scan.T_world_sensor,
                                   _at(poses, scan.stamp_ns) @ base_lidar @ origin, atol=1e-9)
