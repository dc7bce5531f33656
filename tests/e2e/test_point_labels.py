"""`evperc run --point-labels`: per-point SemanticKITTI-MOS labels (evperc.objects.point_labels) by
hand on a tiny grid, through the CLI on the KITTI copy in tests/data, from an MCAP whose
cloud has non-finite points, and across an interrupted and resumed run."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from evperc.cli import cli
from evperc.config import load_config
from evperc.fusion.twin import DECISION_CODES as D
from evperc.geo.window import Window
from evperc.objects.point_labels import point_labels
from evperc.runner import RunRequest, run
from evperc.sensor.ground import GROUND, IGNORED, OBSTACLE
from tests.mcap_writers import kitti_lidar_poses, transform, write_ros2_mcap

from .scenes import write_street_drive

SMALL = Path(__file__).resolve().parents[1] / "data" / "semantickitti05"
NUMBERS = (0, 3, 6, 9)


def test_labels_by_hand_on_a_three_by_three_window() -> None:
    """Sensor at (10.2, 20.3) facing north (yaw 90°: sensor (x, y) -> world (-y, x)); window
    of 1 m cells, rows 20-22, cols 10-12. Point -> world -> cell -> label, by hand."""
    T = transform(x=10.2, y=20.3, yaw=math.pi / 2)
    window = Window(1.0, 3, 3, 20, 10)
    decision = np.full((3, 3), D["free"], np.uint8)
    decision[0, 0] = D["moving"]
    decision[0, 1] = D["unknown"]
    decision[1, 0] = D["stopped"]
    points = np.array([
        [0.1, 0.0, -1.7],   # ground, world (10.2, 20.4)               -> 9
        [0.2, 0.1, 0.5],    # obstacle, world (10.1, 20.5), cell (0, 0) moving  -> 251
        [0.3, -1.3, 0.5],   # obstacle, world (11.5, 20.6), cell (0, 1) unknown -> 0
        [2.5, -2.0, 0.5],   # obstacle, world (12.2, 22.8), cell (2, 2) free    -> 9
        [9.0, 0.0, 0.5],    # obstacle, world (10.2, 29.3), outside the window  -> 0
        [0.2, 0.1, 5.0],    # ignored (above the obstacle height)                -> 0
        [1.2, 0.1, 0.5],    # obstacle, world (10.1, 21.5), cell (1, 0) stopped -> 9
    ], np.float32)
    kinds = np.array([GROUND, OBSTACLE, OBSTACLE, OBSTACLE, OBSTACLE, IGNORED, OBSTACLE],
                     np.uint8)
    labels = point_labels(points, kinds, T, window, decision)
    assert labels.dtype == np.uint32
    assert labels.tolist() == [9, 251, 0, 9, 0, 0, 9]
    # two points of a 9-point cloud were dropped by the reader: they get 0, the rest move
    index = np.array([0, 2, 3, 4, 5, 6, 8])
    full = point_labels(points, kinds, T, window, decision, source_count=9, source_index=index)
    assert full.tolist() == [9, 0, 251, 0, 9, 0, 0, 0, 9]


def _run_cli(*args: str) -> None:
    result = CliRunner().invoke(cli, ["run", *args])
    assert result.exit_code == 0, result.output


def test_cli_writes_one_label_a_point_for_every_kitti_scan(tmp_path: Path) -> None:
    out = tmp_path / "out"
    _run_cli(str(SMALL), "--no-map", "--point-labels", "--out", str(out))
    names = sorted(p.name for p in (out / "labels").iterdir())
    assert names == [f"{n:06d}.label" for n in NUMBERS]  # the scans' own file numbers
    poses = kitti_lidar_poses(SMALL, 10)
    for n in NUMBERS:
        pts = np.fromfile(SMALL / "velodyne" / f"{n:06d}.bin", "<f4").reshape(-1, 4)[:, :3]
        labels = np.fromfile(out / "labels" / f"{n:06d}.label", "<u4")
        truth = np.fromfile(SMALL / "labels" / f"{n:06d}.label", "<u4") & 0xFFFF
        assert len(labels) == len(pts)
        assert set(np.unique(labels)) <= {0, 9, 251}
        # the road (SemanticKITTI 40) within 15 m is ground, hence static (a few road points
        # near kerbs and cars can fall in an obstacle cell; 95 % is the bound we hold)
        world_z = (pts @ poses[n][:3, :3].T + poses[n][:3, 3])[:, 2]
        road = (truth == 40) & (np.hypot(pts[:, 0], pts[:, 1]) < 15) & (world_z < -1.4)
        assert road.sum() > 500 and (labels[road] == 9).mean() > 0.95
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["point_labels"]["naming"] == "the scan's file number"
    assert manifest["request"]["point_labels"] is True
    result = CliRunner().invoke(cli, ["evaluate", str(out), "--semantickitti", str(SMALL)])
    assert result.exit_code == 0, result.output
    assert "all 2" in result.output  # scans 6 and 9 after a warm-up of 2


def test_no_labels_without_the_flag(tmp_path: Path) -> None:
    out = tmp_path / "out"
    _run_cli(str(SMALL), "--no-map", "--out", str(out))
    assert not (out / "labels").exists()
    assert json.loads((out / "manifest.json").read_text())["point_labels"] is None


def test_mcap_cloud_with_non_finite_points_gives_the_kitti_labels(tmp_path: Path) -> None:
    """The KITTI copy as ROS 2 MCAP (poses at the scan stamps, lidar = base_link), with NaN
    and inf rows inserted into each cloud: the label files have one label per row of the
    cloud, 0 at the inserted rows, and the KITTI run's labels elsewhere (up to a few points
    at cell edges: the MCAP poses are quaternions, ~1e-6 off KITTI's matrices)."""
    poses = kitti_lidar_poses(SMALL, 10)
    times = np.loadtxt(SMALL / "times.txt")
    clouds, odom, bad_rows = [], [], []
    for n in NUMBERS:
        pts = np.fromfile(SMALL / "velodyne" / f"{n:06d}.bin", "<f4").reshape(-1, 4)
        bad = np.array([0, 100, 101, len(pts) // 2])
        cloud = np.insert(pts, bad - np.arange(len(bad)), np.nan, axis=0)
        cloud[bad[1], 0] = np.inf
        bad_rows.append(bad)
        ns = int(round(times[n] * 1e9)) + 1_000_000_000
        clouds.append((ns, cloud, "velodyne"))
        odom.append((ns, poses[n]))
    log = write_ros2_mcap(tmp_path / "k.mcap", clouds=clouds, odometry=odom,
                          odom_frames=("map", "base_link"),
                          tf_static=[("base_link", "velodyne", np.eye(4))])
    a, b = tmp_path / "kitti", tmp_path / "mcap"
    _run_cli(str(SMALL), "--no-map", "--point-labels", "--out", str(a))
    _run_cli(str(log), "--no-map", "--point-labels", "--out", str(b))
    assert sorted(p.name for p in (b / "labels").iterdir()) == [f"{i:06d}.label"
                                                                  for i in range(4)]
    for i, (n, bad) in enumerate(zip(NUMBERS, bad_rows, strict=True)):
        la = np.fromfile(a / "labels" / f"{n:06d}.label", "<u4")
        lb = np.fromfile(b / "labels" / f"{i:06d}.label", "<u4")
        assert len(lb) == len(la) + len(bad)
        assert (lb[bad] == 0).all()
        kept = np.delete(lb, bad)
        assert (kept != la).mean() < 0.005, (kept != la).sum()


def test_interrupted_run_resumes_with_the_same_labels(tmp_path: Path) -> None:
    drive = write_street_drive(tmp_path / "street.mcap", n_scans=30)
    config = load_config(overrides={"grid.window_size_m": 40.0, "output.chunk_frames": 10,
                                    "output.checkpoint_frames": 1})
    full, part = tmp_path / "full", tmp_path / "part"
    run(RunRequest(log_path=drive, out_dir=full, config=config, point_labels=True))
    seen = []

    def stop(frame: dict) -> None:
        seen.append(frame)
        if len(seen) == 25:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run(RunRequest(log_path=drive, out_dir=part, config=config, point_labels=True),
            on_frame=stop)
    assert json.loads((part / "manifest.json").read_text())["frame_count"] == 20
    result = CliRunner().invoke(cli, ["run", "--resume", str(part)])
    assert result.exit_code == 0, result.output
    names = sorted(p.name for p in (full / "labels").iterdir())
    assert names == [f"{i:06d}.label" for i in range(30)]
    assert sorted(p.name for p in (part / "labels").iterdir()) == names
    moving = 0
    for name in names:
        la, lb = ((d / "labels" / name).read_bytes() for d in (full, part))
        assert la == lb
        labels = np.frombuffer(la, "<u4")
        assert len(labels) == 720  # one a beam of the 2-D scan, in beam order
        moving += int((labels == 251).sum())
    assert moving > 0  # the crossing car
