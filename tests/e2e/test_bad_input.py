"""Bad input costs one clear line and exit code 2, never a traceback, never an output that
looks complete (issue: robustness). Each case runs the real `evperc run` command."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from evperc.cli import cli
from tests.mcap_writers import transform, write_ros2_mcap

from .scenes import BASE_NS, write_street_drive

DATA = Path(__file__).resolve().parents[1] / "data" / "osm"
BUILDINGS = DATA / "helsinki_buildings.geojson"
ROADS = DATA / "helsinki_roads.geojson"
#: the street drive placed in central Helsinki, heading east
HELSINKI = ("[grid]\nwindow_size_m = 40.0\n[input]\norigin_lat_deg = 60.1699\n"
            "origin_lon_deg = 24.9384\n")


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_street_drive(tmp_path_factory.mktemp("bad") / "street.mcap", n_scans=8)


def run_cli(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(cli, ["run", *args])
    return result.exit_code, result.output


def assert_one_line_error(code: int, output: str, *needles: str, exit_code: int = 2) -> None:
    assert code == exit_code, output
    assert "Traceback" not in output
    error_lines = [line for line in output.splitlines() if line.startswith("evperc: error")]
    assert len(error_lines) == 1, output
    for needle in needles:
        assert needle in error_lines[0], (needle, output)


def assert_not_complete(out: Path) -> None:
    manifest = out / "manifest.json"
    if manifest.exists():
        assert json.loads(manifest.read_text())["complete"] is False


def config_file(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "c.toml"
    path.write_text(text)
    return path


# --- logs -----------------------------------------------------------------------------------

def test_log_missing(tmp_path: Path) -> None:
    code, out = run_cli(str(tmp_path / "nope.mcap"), "--no-map", "--out", str(tmp_path / "o"))
    assert_one_line_error(code, out, "nope.mcap", "not found")
    assert not (tmp_path / "o").exists()


def test_log_not_mcap(tmp_path: Path) -> None:
    bad = tmp_path / "notes.mcap"
    bad.write_text("hello, I am a text file\n")
    code, out = run_cli(str(bad), "--no-map", "--out", str(tmp_path / "o"))
    assert_one_line_error(code, out, "notes.mcap", "not an MCAP")


def test_log_without_lidar(tmp_path: Path) -> None:
    log = write_ros2_mcap(tmp_path / "poses_only.mcap",
                          odometry=[(BASE_NS + k, transform(x=k)) for k in range(3)])
    code, out = run_cli(str(log), "--no-map", "--out", str(tmp_path / "o"))
    assert_one_line_error(code, out, "poses_only.mcap", "lidar")


def test_log_without_poses(tmp_path: Path) -> None:
    pts = np.array([[5.0, 0.0, 0.0]], dtype=np.float32)
    log = write_ros2_mcap(tmp_path / "scans_only.mcap",
                          clouds=[(BASE_NS + k, pts, "lidar") for k in range(3)])
    code, out = run_cli(str(log), "--no-map", "--out", str(tmp_path / "o"))
    assert_one_line_error(code, out, "scans_only.mcap", "pose")


def test_ambiguous_lidar_topics_list_ready_options(tmp_path: Path) -> None:
    pts = np.array([[5.0, 0.0, 0.0]], dtype=np.float32)
    log = write_ros2_mcap(tmp_path / "two.mcap",
                          clouds=[(BASE_NS + k, pts, "lidar") for k in range(3)],
                          cloud_topic="/front", extra_cloud_topics=["/rear"],
                          odometry=[(BASE_NS + k, transform(x=k)) for k in range(3)])
    code, out = run_cli(str(log), "--no-map", "--out", str(tmp_path / "o"))
    assert_one_line_error(code, out, "--lidar-topic /front", "--lidar-topic /rear")


def test_truncated_log_gives_a_partial_complete_run_with_a_warning(tmp_path: Path) -> None:
    """A log cut mid-chunk (a recorder that died) is read as far as it is valid."""
    drive = write_street_drive(tmp_path / "full.mcap", n_scans=8, chunk_size=8 * 1024)
    data = drive.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])  # inside the third of four chunks
    out = tmp_path / "o"
    result = CliRunner().invoke(cli, ["run", str(cut), "--no-map", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "Traceback" not in result.output
    assert "truncated" in result.output
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["complete"] is True
    assert 0 < manifest["frame_count"] < 8


# --- maps -----------------------------------------------------------------------------------

@pytest.mark.parametrize(("name", "content", "needle"), [
    ("none.geojson", None, "not found"),
    ("broken.geojson", "{ this is not json", "broken.geojson"),
    ("empty.geojson", '{"type": "FeatureCollection", "features": []}', "no features"),
])
def test_bad_map_file(drive: Path, tmp_path: Path, name: str, content: str | None,
                      needle: str) -> None:
    map_path = tmp_path / name
    if content is not None:
        map_path.write_text(content)
    code, out = run_cli(str(drive), "--map", str(map_path), "--config",
                        str(config_file(tmp_path, HELSINKI)), "--out", str(tmp_path / "o"))
    assert_one_line_error(code, out, name, needle)
    assert_not_complete(tmp_path / "o")


def test_map_without_overlap(drive: Path, tmp_path: Path) -> None:
    prague = "[input]\norigin_lat_deg = 50.10\norigin_lon_deg = 14.39\n"
    code, out = run_cli(str(drive), "--map", str(BUILDINGS), "--roads", str(ROADS),
                        "--config", str(config_file(tmp_path, prague)),
                        "--out", str(tmp_path / "o"))
    assert_one_line_error(code, out, "helsinki_buildings.geojson", "overlap")
    assert_not_complete(tmp_path / "o")


def test_map_with_local_poses_and_no_georeference(drive: Path, tmp_path: Path) -> None:
    code, out = run_cli(str(drive), "--map", str(BUILDINGS), "--out", str(tmp_path / "o"))
    assert_one_line_error(code, out, "street.mcap", "origin_lat_deg", "--no-map")


def test_good_map_run_succeeds(drive: Path, tmp_path: Path) -> None:
    """The control: the same log and map with a georeference runs."""
    out = tmp_path / "o"
    result = CliRunner().invoke(cli, ["run", str(drive), "--map", str(BUILDINGS), "--roads",
                                      str(ROADS), "--config",
                                      str(config_file(tmp_path, HELSINKI)), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert json.loads((out / "manifest.json").read_text())["crs"] == "EPSG:32635"


# --- config and output ------------------------------------------------------------------------

@pytest.mark.parametrize(("text", "needle"), [
    ("[fusion]\nzeta_incremnt = 0.1\n", "unknown key fusion.zeta_incremnt"),
    ('[sensor]\nmu_free = "high"\n', "sensor.mu_free must be float"),
    ("[sensor]\nmu_free = 1.5\n", "sensor.mu_free = 1.5 is outside"),
])
def test_bad_config(drive: Path, tmp_path: Path, text: str, needle: str) -> None:
    code, out = run_cli(str(drive), "--no-map", "--config", str(config_file(tmp_path, text)),
                        "--out", str(tmp_path / "o"))
    assert_one_line_error(code, out, "c.toml", needle)
    assert not (tmp_path / "o").exists()


def test_output_not_writable(drive: Path, tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, out = run_cli(str(drive), "--no-map", "--out", str(blocker / "sub"))
    assert_one_line_error(code, out, "cannot create output directory")


def test_disk_full_while_writing(drive: Path, tmp_path: Path, monkeypatch) -> None:
    import errno

    import evperc.output.npz as npz_mod

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(npz_mod, "_write_npy", full)
    out = tmp_path / "o"
    code, text = run_cli(str(drive), "--no-map", "--out", str(out))
    # valid input, a failed run: exit code 1 (2 is for bad usage and bad input)
    assert_one_line_error(code, text, "No space left on device", exit_code=1)
    # no frame was written: nothing is left (no chunk, no temporary file, no manifest)
    assert not out.exists()


def test_unsupported_message_encoding(tmp_path: Path) -> None:
    """A PointCloud2 topic in an encoding evperc cannot decode (here CBOR)."""
    from mcap.writer import Writer

    path = tmp_path / "cbor.mcap"
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start()
        cloud = writer.register_schema("sensor_msgs/msg/PointCloud2", "ros2msg", b"")
        odom = writer.register_schema("nav_msgs/msg/Odometry", "ros2msg", b"")
        c1 = writer.register_channel("/points", "cbor", cloud)
        c2 = writer.register_channel("/odom", "cbor", odom)
        for k in range(3):
            for channel in (c1, c2):
                writer.add_message(channel, log_time=BASE_NS + k, data=b"\xa0",
                                   publish_time=BASE_NS + k)
        writer.finish()
    code, out = run_cli(str(path), "--no-map", "--out", str(tmp_path / "o"))
    assert_one_line_error(code, out, "cbor.mcap", "/points")
    assert_not_complete(tmp_path / "o")


def test_undecodable_pose_messages_are_counted_and_no_frame_is_an_error(drive: Path,
                                                                         tmp_path: Path) -> None:
    """The Odometry schema names a type it does not define (found by the fuzz test): each
    pose message fails to decode; they are skipped and counted, and a run that could fuse no
    scan is a one-line error, not an empty output that says complete."""
    data = drive.read_bytes()
    name = b"MSG: geometry_msgs/PoseWithCovariance\n"
    assert data.count(name) == 1
    log = tmp_path / "broken.mcap"
    log.write_bytes(data.replace(name, b"MSG: geometry_msgs/PoseWithCovariancX\n"))
    out = tmp_path / "o"
    code, text = run_cli(str(log), "--no-map", "--out", str(out))
    assert_one_line_error(code, text, str(log), "no scan could be fused", "pose_undecodable")
    assert_not_complete(out)


def test_span_without_scans_is_an_error(drive: Path, tmp_path: Path) -> None:
    out = tmp_path / "o"
    code, text = run_cli(str(drive), "--no-map", "--start", "500", "--out", str(out))
    assert_one_line_error(code, text, str(drive), "no scan in the requested span")
    assert_not_complete(out)


def test_empty_and_non_finite_scans_run(tmp_path: Path) -> None:
    """Empty clouds and NaN/inf points are data, not errors: the run completes."""
    nan_cloud = np.array([[np.nan, 1, 0], [np.inf, 0, 0], [5, 0, 0]], dtype=np.float32)
    clouds = [(BASE_NS, np.zeros((0, 3), np.float32), "lidar"),
              (BASE_NS + 100_000_000, nan_cloud, "lidar"),
              (BASE_NS + 200_000_000, np.zeros((0, 3), np.float32), "lidar")]
    log = write_ros2_mcap(tmp_path / "sparse.mcap", clouds=clouds,
                          odometry=[(BASE_NS - 10**8 + k * 10**8, transform(x=k))
                                    for k in range(5)])
    out = tmp_path / "o"
    result = CliRunner().invoke(cli, ["run", str(log), "--no-map", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert json.loads((out / "manifest.json").read_text())["frame_count"] == 3
