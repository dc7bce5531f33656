"""KITTI: a raw drive converted by the third-party kitti2mcap tool, and the kitti00 odometry
sequence written by tests.mcap_writers.write_kitti_odometry_mcap."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from evperc.logs.factory import open_log
from tests.mcap_writers import (
    KITTI_BASE_NS,
    kitti_lidar_poses,
    read_kitti_odometry,
    write_kitti_odometry_mcap,
    write_kitti_raw_folder,
)

KITTI00 = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "kitti00"


def _oxts_pose(oxts: list[float], lat0: float) -> np.ndarray:
    """IMU pose from an OXTS packet, KITTI devkit convention: Mercator position scaled by
    cos(lat0), R = Rz(yaw)·Ry(pitch)·Rx(roll)."""
    lat, lon, alt, roll, pitch, yaw = oxts
    er, scale = 6378137.0, np.cos(np.radians(lat0))
    t = np.array([scale * np.radians(lon) * er,
                  scale * er * np.log(np.tan(np.radians(90.0 + lat) / 2.0)), alt])
    c, s = np.cos, np.sin
    Rx = np.array([[1, 0, 0], [0, c(roll), -s(roll)], [0, s(roll), c(roll)]])
    Ry = np.array([[c(pitch), 0, s(pitch)], [0, 1, 0], [-s(pitch), 0, c(pitch)]])
    Rz = np.array([[c(yaw), -s(yaw), 0], [s(yaw), c(yaw), 0], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = Rz @ Ry @ Rx
    T[:3, 3] = t
    return T


def test_kitti2mcap_raw_drive(tmp_path):
    kitti2mcap = pytest.importorskip("kitti2mcap.cli", reason="kitti2mcap is not installed")
    values = write_kitti_raw_folder(tmp_path / "raw", n_frames=3, n_points=200)
    out = tmp_path / "drive.mcap"
    rc = kitti2mcap.main(["--date", "2011_09_26", "--drive", "0001", "--kitti-dir",
                          str(tmp_path / "raw"), "--output", str(out), "--cameras", ""])
    assert rc == 0
    log = open_log(out)
    assert log.lidar_topic == "/kitti/velodyne_points"
    assert log.pose_topics == ("tf", ["/tf"])  # map -> base_link (the IMU) on /tf
    scans = list(log.scans())
    assert [s.stamp_ns for s in scans] == values["stamps_ns"]
    lat0 = values["oxts"][0][0]
    origin = _oxts_pose(values["oxts"][0], lat0)[:3, 3]  # poses start at the first packet
    for scan, oxts, pts in zip(scans, values["oxts"], values["points"], strict=True):
        assert scan.frame_id == "velodyne"
        np.testing.assert_array_equal(scan.points, pts[:, :3])
        # tf_static base_link -> velodyne is inv(T_velo_imu): lidar pose = T_w_imu · T_imu_velo
        T_w_imu = _oxts_pose(oxts, lat0)
        T_w_imu[:3, 3] -= origin
        expected = T_w_imu @ np.linalg.inv(values["T_velo_imu"])
        np.testing.assert_allclose(scan.T_world_sensor, expected, atol=1e-6)


needs_kitti00 = pytest.mark.skipif(not (KITTI00 / "poses.txt").exists(),
                                   reason=f"KITTI sequence 00 excerpt not found at {KITTI00}")


@needs_kitti00
@pytest.mark.parametrize("world,pose_source", [("cam0", "odometry"), ("lidar0", "tf")])
def test_kitti00_odometry_mcap(tmp_path, world, pose_source):
    n = 3
    path = write_kitti_odometry_mcap(KITTI00, tmp_path / "k.mcap", n, world=world,
                                     pose_source=pose_source, point_stride=40)
    log = open_log(path)
    scans = list(log.scans())
    k = read_kitti_odometry(KITTI00, n)
    assert [s.stamp_ns for s in scans] == [KITTI_BASE_NS + int(round(t * 1e9))
                                           for t in k["times"]]
    # the KITTI convention, computed here from the files: P_world_lidar = P_cam0 · Tr
    expected = k["P_cam0"] @ k["Tr"]
    if world == "lidar0":
        expected = np.linalg.inv(expected[0]) @ expected
        np.testing.assert_allclose(scans[0].T_world_sensor, np.eye(4), atol=1e-6)
    for scan, T, bin_path in zip(scans, expected, k["bins"], strict=True):
        # KITTI's 3×4 rotations are orthonormal to ~1e-7; quaternions make them exact
        np.testing.assert_allclose(scan.T_world_sensor, T, atol=2e-6)
        pts = np.fromfile(bin_path, dtype="<f4").reshape(-1, 4)[::40, :3]
        np.testing.assert_array_equal(scan.points, pts[np.isfinite(pts).all(axis=1)])
    assert log.stats == {}
    np.testing.assert_allclose(kitti_lidar_poses(KITTI00, n, world), expected)
