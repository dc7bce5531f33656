"""`evperc info` and `evperc run --no-map` on a log of every supported encoding, each written
by an independent third-party writer (the readers' own tests check the values)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import evperc
from evperc.cli import cli
from tests.mcap_writers import (
    transform,
    write_foxglove_mcap,
    write_json_mcap,
    write_kitti_raw_folder,
    write_ros2_mcap,
    write_rosbags_mcap,
)

S0 = 1_700_000_000_000_000_000
MS = 1_000_000
N = 4


def _clouds() -> list:
    rng = np.random.default_rng(3)
    ring = np.column_stack([10 * np.cos(np.linspace(0, 6.2, 200)),
                            10 * np.sin(np.linspace(0, 6.2, 200)), rng.uniform(-1, 1, 200)])
    return [(S0 + i * 100 * MS, ring.astype(np.float32), "lidar") for i in range(N)]


def _poses() -> list:
    return [(S0 - 50 * MS + i * 100 * MS, transform(x=0.5 * i)) for i in range(N + 2)]


def ros2(tmp: Path) -> Path:
    return write_ros2_mcap(tmp / "ros2.mcap", clouds=_clouds(), odometry=_poses(),
                           tf_static=[("base_link", "lidar", transform(z=1.5))])


def rosbags(tmp: Path) -> Path:
    return write_rosbags_mcap(tmp / "bag", clouds=_clouds(), odometry=_poses(),
                              tf_static=[("base_link", "lidar", transform(z=1.5))])


def foxglove(tmp: Path) -> Path:
    return write_foxglove_mcap(tmp / "fox.mcap", clouds=_clouds(), poses=_poses())


def json_encoded(tmp: Path) -> Path:
    return write_json_mcap(tmp / "json.mcap", clouds=_clouds(), poses=_poses())


def json_unindexed(tmp: Path) -> Path:
    return write_json_mcap(tmp / "noindex.mcap", clouds=_clouds(), poses=_poses(),
                           use_index=False)


def laserscan(tmp: Path) -> Path:
    ranges = np.full(180, 8.0)
    scans = [(S0 + i * 100 * MS, ranges, -np.pi / 2, np.pi / 179, "lidar") for i in range(N)]
    return write_ros2_mcap(tmp / "scan.mcap", laserscans=scans, pose_stamped=_poses())


def kitti2mcap_raw(tmp: Path) -> Path:
    kitti2mcap = pytest.importorskip("kitti2mcap.cli", reason="kitti2mcap is not installed")
    write_kitti_raw_folder(tmp / "raw", n_frames=N, n_points=300)
    out = tmp / "kitti.mcap"
    assert kitti2mcap.main(["--date", "2011_09_26", "--drive", "0001", "--kitti-dir",
                            str(tmp / "raw"), "--output", str(out), "--cameras", ""]) == 0
    return out


FORMATS: dict[str, Callable[[Path], Path]] = {
    "ros2-cdr": ros2, "rosbags": rosbags, "foxglove-protobuf": foxglove,
    "foxglove-json": json_encoded, "json-unindexed": json_unindexed,
    "laserscan": laserscan, "kitti2mcap": kitti2mcap_raw}


@pytest.mark.parametrize("name", sorted(FORMATS))
def test_info_and_run_on_every_format(name: str, tmp_path: Path) -> None:
    log = FORMATS[name](tmp_path)
    info = CliRunner().invoke(cli, ["info", str(log)])
    assert info.exit_code == 0, info.output
    assert "lidar topic:" in info.output and "pose source:" in info.output
    out = tmp_path / "out"
    config = tmp_path / "c.toml"
    config.write_text("[grid]\nwindow_size_m = 30.0\n")
    result = CliRunner().invoke(cli, ["run", str(log), "--no-map", "--config", str(config),
                                      "--out", str(out)])
    assert result.exit_code == 0, result.output
    run = evperc.load(out)
    assert len(run) >= N - 1
    last = list(run.frames)[-1]
    assert (last.decision != run.decision_codes["unknown"]).sum() > 20  # it saw something
