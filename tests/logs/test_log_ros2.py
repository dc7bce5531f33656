"""ROS 2 logs written with mcap-ros2-support: LaserScan + PoseStamped + NavSatFix, TF chains,
interpolation, skipped scans and bounded memory."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from evperc.errors import PoseError
from evperc.logs.factory import open_log
from tests.logs.reference import S0, geodesic_interpolation
from tests.mcap_writers import transform, write_ros2_mcap

MS = 1_000_000


def _laserscan_log(tmp_path, **kwargs):
    ranges = np.array([2.0, np.nan, 4.0, np.inf, 0.05, 40.0, 5.0])
    scans = [(S0 + i * 100 * MS, ranges, -np.pi / 2, np.pi / 6, "laser") for i in range(4)]
    poses = [(S0 - 30 * MS + i * 80 * MS, transform(x=2.0 * i, y=0.5 * i, yaw=0.3 * i,
                                                     roll=0.05 * i)) for i in range(7)]
    fixes = [(S0 + i * 200 * MS, 60.17 + 1e-5 * i, 24.94, 12.0) for i in range(3)]
    defaults = dict(laserscans=scans, pose_stamped=poses, fixes=fixes)
    defaults.update(kwargs)
    return write_ros2_mcap(tmp_path / "scan.mcap", **defaults), scans, poses


def _expected_pose(poses, stamp):
    stamps = [ns for ns, _ in poses]
    i = int(np.searchsorted(stamps, stamp))
    (t0, T0), (t1, T1) = poses[i - 1], poses[i]
    return geodesic_interpolation(T0, T1, (stamp - t0) / (t1 - t0))


def test_laserscan_posestamped_navsatfix(tmp_path, caplog):
    path, scans, poses = _laserscan_log(tmp_path)
    log = open_log(path)
    with caplog.at_level(logging.WARNING):
        out = list(log.scans())
    assert [s.stamp_ns for s in out] == [s[0] for s in scans]
    for scan in out:
        assert scan.planar and scan.frame_id == "laser"
        # ranges 2, 4, 5 at -90°, -30°, +90° survive (NaN, inf, below min, above max dropped)
        a = np.array([-np.pi / 2, -np.pi / 2 + 2 * np.pi / 6, -np.pi / 2 + 6 * np.pi / 6])
        expected = np.column_stack([[2, 4, 5] * np.cos(a), [2, 4, 5] * np.sin(a), np.zeros(3)])
        np.testing.assert_allclose(scan.points, expected, atol=1e-5)
        # PoseStamped has no child frame and no TF: the pose is taken as the lidar's (warned)
        np.testing.assert_allclose(scan.T_world_sensor, _expected_pose(poses, scan.stamp_ns),
                                   atol=1e-9)
    assert "assuming the lidar sits at the pose" in caplog.text
    assert log.stats == {}
    fixes = log.gnss_fixes()
    np.testing.assert_allclose(fixes, [[S0 + i * 200 * MS, 60.17 + 1e-5 * i, 24.94, 12.0]
                                       for i in range(3)])


def test_extrinsic_argument_used_without_tf_static(tmp_path):
    path, scans, poses = _laserscan_log(tmp_path)
    E = transform(x=1.2, z=1.9, yaw=0.1)
    out = list(open_log(path, extrinsic=E).scans())
    for scan in out:
        np.testing.assert_allclose(scan.T_world_sensor, _expected_pose(poses, scan.stamp_ns) @ E,
                                   atol=1e-9)


def test_positions_at(tmp_path):
    path, scans, poses = _laserscan_log(tmp_path)
    stamps = np.array([S0 + 150 * MS, S0 - 10 * MS, S0 + 10_000 * MS, S0 + 20 * MS])
    got = open_log(path).positions_at(stamps)
    np.testing.assert_allclose(got[0], _expected_pose(poses, stamps[0])[:3, 3], atol=1e-9)
    np.testing.assert_allclose(got[1], _expected_pose(poses, stamps[1])[:3, 3], atol=1e-9)
    assert np.isnan(got[2]).all()
    np.testing.assert_allclose(got[3], _expected_pose(poses, stamps[3])[:3, 3], atol=1e-9)


def test_tf_chain_map_odom_base_velodyne(tmp_path):
    """map->odom and odom->base_link on /tf at different rates, base_link->velodyne static."""
    rng = np.random.default_rng(5)
    clouds = [(S0 + i * 100 * MS, rng.uniform(-5, 5, (200, 3)), "velodyne") for i in range(5)]
    map_odom = [(S0 - 100 * MS + i * 250 * MS, transform(x=0.1 * i, y=-3.0, yaw=0.02 * i))
                for i in range(4)]
    odom_base = [(S0 - 20 * MS + i * 60 * MS, transform(x=1.5 * i, yaw=0.1 * i))
                 for i in range(10)]
    base_velo = transform(x=0.3, z=1.8, roll=0.01)
    tf = ([(ns, "map", "odom", T) for ns, T in map_odom]
          + [(ns, "odom", "base_link", T) for ns, T in odom_base])
    path = write_ros2_mcap(tmp_path / "tf.mcap", clouds=clouds, tf=tf,
                           tf_static=[("base_link", "velodyne", base_velo)])
    log = open_log(path)
    assert log.pose_topics == ("tf", ["/tf"])
    out = list(log.scans())
    assert len(out) == 5 and log.stats == {}
    for scan in out:
        expected = (_expected_pose(map_odom, scan.stamp_ns)
                    @ _expected_pose(odom_base, scan.stamp_ns) @ base_velo)
        np.testing.assert_allclose(scan.T_world_sensor, expected, atol=1e-9)
        assert scan.points.shape == (200, 3)
    # the same chain from odom only, when the world frame is given
    out = list(open_log(path, world_frame="odom").scans())
    for scan in out:
        np.testing.assert_allclose(scan.T_world_sensor,
                                   _expected_pose(odom_base, scan.stamp_ns) @ base_velo,
                                   atol=1e-9)


def test_broken_tf_chain_counts_scans(tmp_path):
    clouds = [(S0 + i * 100 * MS, np.ones((10, 3)), "velodyne") for i in range(3)]
    tf = [(S0 - 50 * MS + i * 100 * MS, "odom", "base_link", transform(x=i)) for i in range(5)]
    path = write_ros2_mcap(tmp_path / "broken.mcap", clouds=clouds, tf=tf)  # no base->velodyne
    log = open_log(path)
    assert list(log.scans()) == []
    assert log.stats == {"no_transform_chain": 3}


def test_skips_outside_span_gaps_duplicates_and_backwards(tmp_path):
    clouds_at = [-300, 0, 100, 100, 200, 150, 700, 900, 1000, 2500]  # ms
    clouds = [(S0 + t * MS, np.full((5, 3), 1.0), "base_link", S0 + i * 60 * MS + t * MS)
              for i, t in enumerate(clouds_at)]  # logged in this order, 150 after 200
    # poses every 50 ms on [-100, 400] and [1500, 2000] ms: 700, 900 and 1000 lie between
    # poses 1.1 s apart (max 1 s); -300 is before the poses, 2500 after them.
    pose_ts = list(range(-100, 401, 50)) + list(range(1500, 2001, 50))
    odometry = [(S0 + t * MS, transform(x=t / 1000)) for t in pose_ts]
    path = write_ros2_mcap(tmp_path / "gaps.mcap", clouds=clouds, odometry=odometry,
                           odom_frames=("map", "base_link"))
    log = open_log(path)
    out = list(log.scans())
    assert [(s.stamp_ns - S0) // MS for s in out] == [0, 100, 200]
    np.testing.assert_allclose([s.T_world_sensor[0, 3] for s in out], [0.0, 0.1, 0.2])
    assert log.stats == {"before_pose_span": 1, "duplicate_stamp": 1, "backwards_stamp": 1,
                         "pose_gap": 3, "after_pose_span": 1}


def test_start_end_filter_by_stamp(tmp_path):
    clouds = [(S0 + t * MS, np.ones((3, 3)), "base_link") for t in range(0, 1000, 100)]
    odometry = [(S0 + t * MS, transform(x=t)) for t in range(-50, 1100, 50)]
    path = write_ros2_mcap(tmp_path / "range.mcap", clouds=clouds, odometry=odometry)
    out = list(open_log(path).scans(start_ns=S0 + 300 * MS, end_ns=S0 + 600 * MS))
    assert [(s.stamp_ns - S0) // MS for s in out] == [300, 400, 500]


def test_world_frame_without_static_link_is_a_pose_error(tmp_path):
    path, _, _ = _laserscan_log(tmp_path)
    with pytest.raises(PoseError, match="world frame 'earth'"):
        list(open_log(path, world_frame="earth").scans())


def test_memory_stays_bounded_on_a_long_log(tmp_path):
    """600 scans at 10 Hz, odometry at 50 Hz: the pose buffer and the scan queue stay small."""
    clouds = [(S0 + t * 100 * MS, np.ones((2, 3)), "base_link") for t in range(600)]
    odometry = [(S0 - 10 * MS + t * 20 * MS, transform(x=0.01 * t)) for t in range(3005)]
    path = write_ros2_mcap(tmp_path / "long.mcap", clouds=clouds, odometry=odometry,
                           chunk_size=64 * 1024)
    gen = open_log(path).scans()
    largest_track = largest_queue = n = 0
    for _ in gen:
        n += 1
        frame = gen.gi_frame.f_locals
        largest_track = max(largest_track, len(frame["poses"].track))
        largest_queue = max(largest_queue, len(frame["pending"]))
    assert n == 600
    assert largest_track <= 10 and largest_queue <= 2
