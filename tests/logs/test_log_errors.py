"""User mistakes and damaged files: one-line LogError / TopicError, or one warning."""

from __future__ import annotations

import logging
import zlib

import mcap.stream_reader
import numpy as np
import pytest
from isal import isal_zlib

from evperc.errors import LogError, TopicError
from evperc.logs.factory import open_log
from tests.logs.reference import S0
from tests.mcap_writers import transform, write_ros2_mcap

MS = 1_000_000


def _clouds(n=3, layout_points=50):
    rng = np.random.default_rng(0)
    return [(S0 + i * 100 * MS, rng.uniform(-5, 5, (layout_points, 3)), "velodyne")
            for i in range(n)]


def _odometry(n=10):
    return [(S0 - 50 * MS + i * 100 * MS, transform(x=i)) for i in range(n)]


def _one_line(err) -> str:
    text = str(err.value)
    assert "\n" not in text
    return text


def test_missing_file(tmp_path):
    with pytest.raises(LogError) as err:
        open_log(tmp_path / "nope.mcap")
    assert _one_line(err) == f"{tmp_path / 'nope.mcap'}: log file not found"


def test_not_an_mcap(tmp_path):
    path = tmp_path / "drive.mcap"
    path.write_bytes(b"PK\x03\x04" + bytes(100))  # a zip archive named .mcap
    with pytest.raises(LogError) as err:
        open_log(path)
    text = _one_line(err)
    assert text.startswith(f"{path}: not an MCAP file or bag: it starts with 50 4b 03 04 00")
    assert "ROS 1 bags (.bag)" in text


def test_directory(tmp_path):
    with pytest.raises(LogError, match="is a directory"):
        open_log(tmp_path)


def test_no_lidar_topic(tmp_path):
    path = write_ros2_mcap(tmp_path / "a.mcap", odometry=_odometry())
    with pytest.raises(TopicError) as err:
        open_log(path)
    text = _one_line(err)
    assert text.startswith(f"{path}: no lidar topic") and "nav_msgs/msg/Odometry" in text


def test_no_pose_topic(tmp_path):
    path = write_ros2_mcap(tmp_path / "a.mcap", clouds=_clouds(),
                           tf_static=[("base_link", "velodyne", np.eye(4))])
    with pytest.raises(TopicError) as err:
        open_log(path)
    text = _one_line(err)
    assert text.startswith(f"{path}: no pose topic")
    assert "sensor_msgs/msg/PointCloud2, tf2_msgs/msg/TFMessage" in text


def test_ambiguous_lidar_topics_list_ready_to_paste_options(tmp_path):
    path = write_ros2_mcap(tmp_path / "a.mcap", clouds=_clouds(), odometry=_odometry(),
                           extra_cloud_topics=["/velodyne_points"])
    with pytest.raises(TopicError) as err:
        open_log(path)
    text = _one_line(err)
    assert "2 lidar topics fit" in text
    assert "--lidar-topic /points" in text and "--lidar-topic /velodyne_points" in text
    assert len(list(open_log(path, lidar_topic="/velodyne_points").scans())) == 3


def test_ambiguous_pose_topics(tmp_path):
    path = write_ros2_mcap(tmp_path / "a.mcap", clouds=_clouds(), odometry=_odometry(),
                           pose_stamped=_odometry())
    with pytest.raises(TopicError, match=r"--pose-topic /odom \| --pose-topic /pose"):
        open_log(path)


def test_unknown_requested_topic(tmp_path):
    path = write_ros2_mcap(tmp_path / "a.mcap", clouds=_clouds(), odometry=_odometry())
    with pytest.raises(TopicError) as err:
        open_log(path, lidar_topic="/lidar")
    assert _one_line(err) == f"{path}: no topic /lidar; lidar topics in the log: /points"
    with pytest.raises(TopicError, match="topic /odom has schema nav_msgs/msg/Odometry, not a "
                                         "lidar schema"):
        open_log(path, lidar_topic="/odom")


def test_missing_xyz_fields(tmp_path):
    path = write_ros2_mcap(tmp_path / "a.mcap", clouds=_clouds(), odometry=_odometry(),
                           layout="no_xyz")
    with pytest.raises(LogError) as err:
        list(open_log(path).scans())
    assert _one_line(err) == (f"{path}: topic /points: point cloud has no x/y/z fields "
                              "(fields: azimuth, intensity, range); evperc needs x, y, z")


def test_truncated_mid_chunk_reads_what_is_valid(tmp_path, caplog):
    clouds = _clouds(n=20, layout_points=200)
    full = write_ros2_mcap(tmp_path / "full.mcap", clouds=clouds, odometry=_odometry(23),
                           tf_static=[("base_link", "velodyne", np.eye(4))], chunk_size=8 * 1024)
    data = full.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.55)])
    with caplog.at_level(logging.WARNING):
        log = open_log(cut)
        out = list(log.scans())
        list(log.scans())
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1, [r.getMessage() for r in warnings]
    assert str(cut) in warnings[0].getMessage() and "truncated" in warnings[0].getMessage()
    assert "byte" in warnings[0].getMessage()
    print(warnings[0].getMessage())
    assert not log.source.indexed and log.info()["complete"] is False
    assert 3 <= len(out) < 20
    assert [s.stamp_ns for s in out] == [c[0] for c in clouds[: len(out)]]
    for scan, (_, pts, _) in zip(out, clouds, strict=False):
        np.testing.assert_allclose(scan.points, pts.astype(np.float32))
        np.testing.assert_allclose(scan.T_world_sensor[:3, 3],
                                   [(scan.stamp_ns - S0 + 50 * MS) / 100 / MS, 0, 0], atol=1e-9)


def test_corrupt_chunk_in_indexed_file_stops_there(tmp_path, caplog):
    clouds = _clouds(n=20, layout_points=200)
    full = write_ros2_mcap(tmp_path / "full.mcap", clouds=clouds, odometry=_odometry(23),
                           tf_static=[("base_link", "velodyne", np.eye(4))], chunk_size=8 * 1024)
    data = bytearray(full.read_bytes())
    middle = len(data) // 2
    data[middle: middle + 64] = bytes(64)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with caplog.at_level(logging.WARNING):
        log = open_log(bad)
        out = list(log.scans())
    assert log.source.indexed
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "damaged" in warnings[0]
    assert 1 <= len(out) < 20
    assert [s.stamp_ns for s in out] == [c[0] for c in clouds[: len(out)]]


def test_chunk_crc_is_checked_with_isal(tmp_path, caplog):
    """mcap checks chunk CRC-32s with ISA-L's crc32 (evperc.logs.mcap_source), the same value
    as zlib's: an intact uncompressed log reads whole, and one flipped bit in a point of
    cloud 12 — still a valid float, which only the CRC can catch — ends the stream there."""
    assert mcap.stream_reader.zlib.crc32 is isal_zlib.crc32
    data = np.random.default_rng(1).integers(0, 256, 100_000, dtype=np.uint8).tobytes()
    assert mcap.stream_reader.zlib.crc32(data) == zlib.crc32(data)
    clouds = _clouds(n=20, layout_points=200)
    kwargs = {"clouds": clouds, "odometry": _odometry(23), "chunk_size": 8 * 1024,
              "tf_static": [("base_link", "velodyne", np.eye(4))], "compression": "none"}
    full = write_ros2_mcap(tmp_path / "full.mcap", **kwargs)
    assert len(list(open_log(full).scans())) == 20
    raw = bytearray(full.read_bytes())
    point = clouds[12][1][100].astype(np.float32).tobytes()
    at = raw.find(point)
    assert at > 0 and raw.find(point, at + 1) == -1
    raw[at] ^= 1  # the lowest bit of x's mantissa
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(raw))
    with caplog.at_level(logging.WARNING):
        out = list(open_log(bad).scans())
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "damaged" in warnings[0], warnings
    assert "CRC" in warnings[0] or "crc" in warnings[0].lower(), warnings[0]
    assert [s.stamp_ns for s in out] == [c[0] for c in clouds[:len(out)]]
    assert 1 <= len(out) <= 12
