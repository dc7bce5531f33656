"""A ROS 2 bag written by rosbags (MCAP storage plugin): PointCloud2 (32-byte Velodyne layout),
Odometry, /tf and /tf_static."""

from __future__ import annotations

import numpy as np

from evperc.logs.factory import open_log
from tests.logs.reference import S0, geodesic_interpolation
from tests.mcap_writers import transform, write_rosbags_mcap

MS = 1_000_000


def _at(poses, stamp):
    stamps = [ns for ns, _ in poses]
    i = int(np.searchsorted(stamps, stamp))
    if stamps[i] == stamp:
        return poses[i][1]
    (t0, T0), (t1, T1) = poses[i - 1], poses[i]
    return geodesic_interpolation(T0, T1, (stamp - t0) / (t1 - t0))


def test_rosbags_bag(tmp_path):
    rng = np.random.default_rng(11)
    clouds = [(S0 + i * 100 * MS, np.column_stack([rng.uniform(-30, 30, (300, 3)),
                                                    rng.uniform(0, 1, 300)]), "velodyne")
              for i in range(4)]
    odom_base = [(S0 - 40 * MS + i * 100 * MS, transform(x=1.0 * i, y=0.2 * i, yaw=0.05 * i))
                 for i in range(6)]
    map_odom = [(S0 - 50 * MS + i * 200 * MS, transform(x=100.0, y=50.0 + i, yaw=1.0))
                for i in range(4)]
    base_velo = transform(x=0.8, z=1.7, yaw=0.02)
    path = write_rosbags_mcap(
        tmp_path / "bag", clouds=clouds, odometry=odom_base, odom_frames=("odom", "base_link"),
        tf=[(ns, "map", "odom", T) for ns, T in map_odom]
        + [(ns, "odom", "base_link", T) for ns, T in odom_base],
        tf_static=[("base_link", "velodyne", base_velo)])
    log = open_log(path)
    assert log.lidar_topic == "/velodyne_points"
    assert log.pose_topics == ("topic", ["/odom"])  # a pose topic is preferred over TF
    out = list(log.scans())
    assert len(out) == 4 and log.stats == {}
    for scan, (ns, pts, _) in zip(out, clouds, strict=True):
        assert scan.stamp_ns == ns and not scan.planar
        np.testing.assert_allclose(scan.points, pts[:, :3].astype(np.float32))
        np.testing.assert_allclose(scan.T_world_sensor, _at(odom_base, ns) @ base_velo,
                                   atol=1e-9)

    log_tf = open_log(path, pose_topic="/tf")
    out = list(log_tf.scans())
    assert len(out) == 4
    for scan in out:
        expected = _at(map_odom, scan.stamp_ns) @ _at(odom_base, scan.stamp_ns) @ base_velo
        np.testing.assert_allclose(scan.T_world_sensor, expected, atol=1e-9)
    info = log.info()
    counts = {t["topic"]: t["messages"] for t in info["topics"]}
    assert counts == {"/velodyne_points": 4, "/odom": 6, "/tf": 10, "/tf_static": 1}
    assert info["mean_points_per_scan"] == 300.0
