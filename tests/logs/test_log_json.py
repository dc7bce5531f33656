"""mcap's own writer with JSON-encoded foxglove messages, indexed and unindexed."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from evperc.logs.factory import open_log
from tests.logs.reference import S0, geodesic_interpolation
from tests.mcap_writers import transform, write_json_mcap

MS = 1_000_000


def _at(poses, stamp):
    stamps = [ns for ns, _ in poses]
    i = int(np.searchsorted(stamps, stamp))
    (t0, T0), (t1, T1) = poses[i - 1], poses[i]
    return geodesic_interpolation(T0, T1, (stamp - t0) / (t1 - t0))


POSES = [(S0 - 20 * MS + i * 90 * MS, transform(x=-2.0 * i, y=4.0, yaw=0.15 * i))
         for i in range(7)]


@pytest.mark.parametrize("use_index", [True, False])
@pytest.mark.parametrize("double_xyz", [False, True])
def test_json_point_cloud(tmp_path, caplog, use_index, double_xyz):
    rng = np.random.default_rng(4)
    clouds = [(S0 + i * 100 * MS, rng.uniform(-3, 3, (120, 3)), "lidar") for i in range(5)]
    path = write_json_mcap(tmp_path / "j.mcap", clouds=clouds, poses=POSES,
                           fixes=[(S0, 1.5, 2.5, 3.5)], use_index=use_index,
                           double_xyz=double_xyz)
    with caplog.at_level(logging.INFO):
        log = open_log(path, extrinsic=transform(z=1.0))
        out = list(log.scans())
    assert log.source.indexed is use_index
    assert ("no index; reading it sequentially" in caplog.text) is (not use_index)
    assert "truncated" not in caplog.text
    assert len(out) == 5 and log.stats == {}
    for scan, (ns, pts, _) in zip(out, clouds, strict=True):
        np.testing.assert_allclose(scan.points, pts.astype(np.float32), rtol=1e-6)
        np.testing.assert_allclose(scan.T_world_sensor, _at(POSES, ns) @ transform(z=1.0),
                                   atol=1e-9)
    np.testing.assert_allclose(log.gnss_fixes(), [[S0, 1.5, 2.5, 3.5]])
    counts = {t["topic"]: t["messages"] for t in log.info()["topics"]}
    assert counts == {"/lidar": 5, "/pose": 7, "/gps": 1}


def test_json_laserscan_and_frame_transform(tmp_path):
    ranges = np.array([1.0, np.inf, 3.0, -1.0, 2.0])
    scans = [(S0 + i * 100 * MS, ranges, -1.0, 1.0, "laser") for i in range(3)]
    tf = [(ns, "odom", "laser", T) for ns, T in POSES]
    path = write_json_mcap(tmp_path / "s.mcap", laserscans=scans, frame_transforms=tf)
    log = open_log(path)
    assert log.pose_topics == ("tf", ["/tf"])
    out = list(log.scans())
    assert len(out) == 3
    angles = np.linspace(-1.0, 1.0, 5)[[0, 2, 4]]
    r = np.array([1.0, 3.0, 2.0])
    for scan in out:
        assert scan.planar
        np.testing.assert_allclose(scan.points[:, :2],
                                   np.column_stack([r * np.cos(angles), r * np.sin(angles)]),
                                   atol=1e-6)
        np.testing.assert_allclose(scan.T_world_sensor, _at(POSES, scan.stamp_ns), atol=1e-9)
