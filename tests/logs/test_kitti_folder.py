"""KITTI / SemanticKITTI sequence folders read directly (evperc.logs.kitti): the small copy in
tests/data/semantickitti05 (scans 0, 3, 6, 9 of sequence 05, cropped), the shared slices when
present, and the one-line errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial import cKDTree

import evperc
from evperc.cli import cli
from evperc.config import load_config
from evperc.errors import LogError, PoseError
from evperc.logs.factory import open_log
from evperc.logs.kitti import KittiLog, is_kitti_sequence
from evperc.runner import request_from_manifest
from tests.mcap_writers import KITTI_BASE_NS, kitti_lidar_poses, write_kitti_odometry_mcap

SMALL = Path(__file__).resolve().parents[1] / "data" / "semantickitti05"
SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "semantickitti"
needs_shared = pytest.mark.skipif(not (SHARED / "05" / "poses.txt").exists(),
                                  reason=f"shared SemanticKITTI slices not found at {SHARED} "
                                         "(../shared relative to the repo root)")


def _bin(path: Path) -> np.ndarray:
    return np.fromfile(path, "<f4").reshape(-1, 4)


def test_small_copy_reads_scan_by_scan_with_its_file_numbers() -> None:
    assert is_kitti_sequence(SMALL)
    log = open_log(SMALL)
    assert isinstance(log, KittiLog)
    scans = list(log.scans())
    assert [s.number for s in scans] == [0, 3, 6, 9]
    # stamps: times.txt line of the file number, seconds -> integer ns
    times = [float(line) for line in (SMALL / "times.txt").read_text().split()]
    assert [s.stamp_ns for s in scans] == [round(times[n] * 1e9) for n in (0, 3, 6, 9)]
    assert log.start_ns == scans[0].stamp_ns and log.end_ns == scans[-1].stamp_ns + 1
    for s in scans:
        np.testing.assert_array_equal(s.points, _bin(SMALL / "velodyne" / f"{s.number:06d}.bin")
                                      [:, :3])
        assert s.frame_id == "velodyne" and not s.planar and s.source_index is None
    # the pose chain written out independently (tests.mcap_writers, all 10 poses lines)
    expected = kitti_lidar_poses(SMALL, 10, world="lidar0")
    for s in scans:
        np.testing.assert_allclose(s.T_world_sensor, expected[s.number], atol=1e-9)
    np.testing.assert_allclose(scans[0].T_world_sensor, np.eye(4), atol=1e-12)
    assert log.posed_in == "kitti_lidar0" and log.stats == {}
    # only the requested span is read
    assert [s.number for s in log.scans(scans[1].stamp_ns, scans[3].stamp_ns)] == [3, 6]
    # positions between scans: linear (the car drives straight here)
    mid = (scans[0].stamp_ns + scans[1].stamp_ns) // 2
    pos = log.positions_at(np.array([mid, scans[0].stamp_ns - 1]))
    np.testing.assert_allclose(pos[0], (expected[0][:3, 3] + expected[3][:3, 3]) / 2, atol=0.01)
    assert np.isnan(pos[1]).all()
    assert log.gnss_fixes().shape == (0, 4)


def _static_structure(scan, labels: np.ndarray) -> np.ndarray:
    """World points of a scan that are static and not road: SemanticKITTI class > 1, not
    moving (< 252), more than 0.5 m above the road (lidar z > -1.23, the lidar 1.73 m up)."""
    cls = labels & 0xFFFF
    keep = (cls > 1) & (cls < 252) & (scan.points[:, 2] > -1.23)
    p = scan.points[keep].astype(np.float64)
    return p @ scan.T_world_sensor[:3, :3].T + scan.T_world_sensor[:3, 3]


def test_pose_chain_aligns_static_structure_of_first_and_last_scan() -> None:
    """Nearest-neighbour distance (scipy cKDTree) from each static point of scan 9 to those of
    scan 0 in the world frame. Median below 0.3 m (the issue's bound: the cropped copy keeps
    every 12th point, so a perfectly posed surface is sampled ~0.1 m apart); without the poses
    (both scans in their own lidar frame, the car 7 m on) it is over 1 m."""
    log = open_log(SMALL)
    scans = {s.number: s for s in log.scans()}
    lab = {n: np.fromfile(SMALL / "labels" / f"{n:06d}.label", "<u4") for n in (0, 9)}
    a, b = _static_structure(scans[0], lab[0]), _static_structure(scans[9], lab[9])
    assert len(a) > 2000 and len(b) > 2000
    d, _ = cKDTree(a).query(b)
    assert np.median(d) < 0.3, np.median(d)
    raw = [scans[n].points[((lab[n] & 0xFFFF) > 1) & (scans[n].points[:, 2] > -1.23)]
           for n in (0, 9)]
    d0, _ = cKDTree(raw[0]).query(raw[1])
    assert np.median(d0) > 1.0


@needs_shared
@pytest.mark.parametrize("seq", ["00", "05", "10"])
def test_mcap_written_from_the_same_folder_gives_the_same_scans_and_poses(tmp_path, seq):
    """tests.mcap_writers writes the folder as ROS 2 MCAP (its own pose chain, quaternions,
    a base_link 1.73 m below the lidar): evperc reads the same scans and poses from both."""
    n = 3
    folder = SHARED / seq
    mcap = open_log(write_kitti_odometry_mcap(folder, tmp_path / "k.mcap", n, point_stride=1))
    a, b = list(open_log(folder).scans())[:n], list(mcap.scans())
    assert len(b) == n
    for sa, sb in zip(a, b, strict=True):
        assert sb.stamp_ns - KITTI_BASE_NS == sa.stamp_ns
        np.testing.assert_array_equal(sa.points, sb.points)
        # quaternions of KITTI's 3x4 rotations (orthonormal to ~1e-7) differ by ~1e-6
        np.testing.assert_allclose(sa.T_world_sensor, sb.T_world_sensor, atol=2e-6)


def _copy(tmp_path: Path) -> Path:
    dest = tmp_path / "seq"
    shutil.copytree(SMALL, dest)
    return dest


def _info_error(path: Path) -> str:
    result = CliRunner().invoke(cli, ["info", str(path)])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("evperc: error: "), result.output
    return lines[0]


def test_error_no_tr_line(tmp_path: Path) -> None:
    seq = _copy(tmp_path)
    calib = seq / "calib.txt"
    calib.write_text("\n".join(line for line in calib.read_text().splitlines()
                               if not line.startswith("Tr:")))
    with pytest.raises(PoseError, match="no Tr: line"):
        open_log(seq)
    assert "calib.txt: no Tr: line" in _info_error(seq)


def test_error_fewer_poses_than_scans(tmp_path: Path) -> None:
    seq = _copy(tmp_path)
    lines = (seq / "poses.txt").read_text().splitlines()
    (seq / "poses.txt").write_text("\n".join(lines[:8]) + "\n")  # scan 9 needs line 10
    with pytest.raises(PoseError, match="8 poses for scans up to 000009.bin"):
        open_log(seq)
    assert "fewer poses than scans" in _info_error(seq)


def test_error_truncated_bin(tmp_path: Path) -> None:
    seq = _copy(tmp_path)
    path = seq / "velodyne" / "000006.bin"
    path.write_bytes(path.read_bytes()[:-6])
    with pytest.raises(LogError, match="000006.bin: truncated scan"):
        open_log(seq)
    assert "truncated scan" in _info_error(seq)


def test_error_empty_folder(tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(LogError, match="no scans"):
        open_log(empty)
    assert "is a directory with no scans (velodyne/NNNNNN.bin)" in _info_error(empty)
    (empty / "velodyne").mkdir()  # the layout, but no scan in it
    assert "no scans" in _info_error(empty)


def test_info_names_the_folder_and_its_scans() -> None:
    result = CliRunner().invoke(cli, ["info", str(SMALL)])
    assert result.exit_code == 0, result.output
    assert "KITTI sequence folder" in result.output
    assert "velodyne/" in result.output and "labels/" in result.output
    info = open_log(SMALL).info()
    assert info["topics"][0]["messages"] == 4 and info["labels"] == 4
    sizes = [(SMALL / "velodyne" / f"{n:06d}.bin").stat().st_size // 16 for n in (0, 3, 6, 9)]
    assert info["mean_points_per_scan"] == pytest.approx(np.mean(sizes))


def test_non_finite_points_are_dropped_with_their_index(tmp_path: Path) -> None:
    seq = _copy(tmp_path)
    path = seq / "velodyne" / "000003.bin"
    pts = _bin(path).copy()
    pts[[0, 5], 1] = np.nan
    pts.tofile(path)
    scan = [s for s in open_log(seq).scans() if s.number == 3][0]
    assert scan.source_count == len(pts) and len(scan.points) == len(pts) - 2
    np.testing.assert_array_equal(scan.source_index,
                                  np.delete(np.arange(len(pts)), [0, 5]))
    np.testing.assert_array_equal(scan.points, pts[scan.source_index, :3])


LINE = "running with --preset hdl64, tuned for such scanners"


def _same(a: dict, b: dict) -> bool:
    """Two configs equal, their NaN keys ("not set") included."""
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def test_a_kitti_run_takes_the_hdl64_preset(tmp_path: Path) -> None:
    # a KITTI folder is an HDL-64E: without --preset the run takes configs/hdl64.toml's keys
    # (the re-hit revokes the cells hit a moment ago, not the 3 x 3 block), says so in one
    # line and records it; `--preset none` runs the defaults alone
    result = CliRunner().invoke(cli, ["run", str(SMALL), "--no-map", "--out",
                                      str(tmp_path / "a")])
    assert result.exit_code == 0, result.output
    assert result.output.count(LINE) == 1, result.output
    manifest = evperc.load(tmp_path / "a").manifest
    assert _same(manifest["config"], load_config(None, preset="hdl64"))
    assert manifest["config"]["fusion"]["gate_rehit_revokes"] == "recent_returns"
    assert (manifest["request"]["preset"], manifest["request"]["sensor_preset"]) == (
        "hdl64", False)
    plain = CliRunner().invoke(cli, ["run", str(SMALL), "--no-map", "--preset", "none",
                                     "--out", str(tmp_path / "n")])
    assert plain.exit_code == 0, plain.output
    assert "--preset" not in plain.output
    manifest = evperc.load(tmp_path / "n").manifest
    assert _same(manifest["config"], load_config(None))
    assert manifest["config"]["fusion"]["gate_rehit_revokes"] == "block"
    assert manifest["request"]["preset"] is None


def test_the_hdl64_preset_on_a_kitti_folder(tmp_path: Path) -> None:
    result = CliRunner().invoke(cli, ["run", str(SMALL), "--no-map", "--preset", "hdl64",
                                      "--out", str(tmp_path / "b")])
    assert result.exit_code == 0, result.output
    assert LINE not in result.output  # asked for: nothing to say
    config = evperc.load(tmp_path / "b").manifest["config"]
    assert config["fusion"]["gate_rehit_revokes"] == "recent_returns"
    assert (config["objects"]["centroid"], config["objects"]["centroid_sigma_m"]) == (
        "returns", 0.1)


def test_a_user_config_goes_over_the_sensor_preset(tmp_path: Path) -> None:
    # the preset sits between the defaults and the user's file: the file's keys win, the
    # preset's others stay
    user = tmp_path / "u.toml"
    user.write_text("[grid]\nwindow_size_m = 30.0\n[objects]\ncentroid_max_cells = 5\n")
    result = CliRunner().invoke(cli, ["run", str(SMALL), "--no-map", "--config", str(user),
                                      "--out", str(tmp_path / "u")])
    assert result.exit_code == 0, result.output
    assert f"{LINE}, under {user}'s keys" in result.output
    manifest = evperc.load(tmp_path / "u").manifest
    assert manifest["request"]["config_path"] == str(user.absolute())
    config = manifest["config"]
    assert _same(config, load_config(user, preset="hdl64"))
    assert config["objects"]["centroid_max_cells"] == 5  # the file's (the preset's is 8)
    assert config["objects"]["centroid"] == "returns"    # the preset's
    assert config["grid"]["window_size_m"] == 30.0
    # --resume takes the manifest's config as it is: the preset is not chosen again
    path = tmp_path / "u" / "manifest.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), "complete": False}))
    again = request_from_manifest(tmp_path / "u")
    assert (again.sensor_preset, again.preset, again.config_path) == (False, "hdl64",
                                                                      user.absolute())
    assert _same(again.config, config)


def test_a_batch_of_kitti_folders_takes_the_preset_and_skips_them_again(tmp_path: Path
                                                                        ) -> None:
    # each log of a batch takes the preset of its own lidar; run again, the outputs made
    # with it are complete runs of the same config (skipped, not "another config")
    out = tmp_path / "runs"
    args = ["batch", str(SMALL), "--no-map", "--out", str(out), "--workers", "1"]
    first = CliRunner().invoke(cli, args)
    assert first.exit_code == 0, first.output
    (done,) = [p for p in out.iterdir() if p.is_dir()]
    manifest = evperc.load(done).manifest
    want = load_config(None, preset="hdl64")
    want["fusion"]["threads"] = 1  # a batch's logs run side by side, one thread each
    assert _same(manifest["config"], want) and manifest["request"]["preset"] == "hdl64"
    # the table names it (a worker's log line does not reach the user)
    (line,) = [r for r in first.output.splitlines() if r.startswith(SMALL.name)]
    assert line.split()[3] == "ok" and line.split()[-1] == "hdl64"  # status, ..., preset
    again = CliRunner().invoke(cli, args)
    assert again.exit_code == 0, again.output
    assert "skipped" in again.output and "another config" not in again.output
    plain = CliRunner().invoke(cli, [*args, "--preset", "none"])
    assert plain.exit_code == 1 and "another config" in plain.output
