"""`evperc info` through click's CliRunner."""

from __future__ import annotations

import json

import numpy as np
from click.testing import CliRunner

import evperc
from evperc.cli import cli
from evperc.config import load_config, preset_for_layers
from tests.logs.reference import S0
from tests.mcap_writers import transform, write_ros2_mcap

MS = 1_000_000


def _log(tmp_path, **kwargs):
    clouds = [(S0 + i * 100 * MS, np.ones((40, 3)) * (i + 1), "velodyne") for i in range(3)]
    odometry = [(S0 + i * 50 * MS, transform(x=i)) for i in range(6)]
    fixes = [(S0, 60.0, 25.0, 10.0)]
    return write_ros2_mcap(tmp_path / "drive.mcap", clouds=clouds, odometry=odometry,
                           fixes=fixes, tf_static=[("base_link", "velodyne", np.eye(4))],
                           **kwargs)


def test_info_prints_topics_and_counts(tmp_path):
    path = _log(tmp_path)
    result = CliRunner().invoke(cli, ["info", str(path)])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0] == f"{path}  (mcap, indexed)"
    assert "time span: 0.250 s" in lines
    rows = {line.split()[0]: line.split()[1:3] for line in lines[1:] if line.startswith("/")}
    assert rows == {"/fix": ["1", "sensor_msgs/msg/NavSatFix"],
                    "/odom": ["6", "nav_msgs/msg/Odometry"],
                    "/points": ["3", "sensor_msgs/msg/PointCloud2"],
                    "/tf_static": ["1", "tf2_msgs/msg/TFMessage"]}
    assert "lidar topic: /points" in lines and "pose source: /odom" in lines
    assert "gnss topic: /fix" in lines
    assert "lidar frame: velodyne; mean points per scan 40.0 (first 3 scans)" in lines
    # 3 scans 1 m apart: no pair 3 m apart to compare (evperc/sensor/pose_fit.py)
    assert lines[-1].startswith("poses against the scans: not checked")


def test_info_json(tmp_path):
    path = _log(tmp_path)
    result = CliRunner().invoke(cli, ["info", "--json", str(path)])
    assert result.exit_code == 0
    info = json.loads(result.output)
    assert info["indexed"] is True and info["duration_s"] == 0.25
    assert info["detected"]["lidar_topic"] == "/points"
    assert info["pose_fit"] is None
    assert info["pose_fits_later"] == []  # 0.25 s: too short to check again further on


def test_info_reports_ambiguous_topics_instead_of_failing(tmp_path):
    path = _log(tmp_path, extra_cloud_topics=["/points2"])
    result = CliRunner().invoke(cli, ["info", str(path)])
    assert result.exit_code == 0
    assert "--lidar-topic /points | --lidar-topic /points2" in result.output


def test_info_missing_file(tmp_path):
    result = CliRunner().invoke(cli, ["info", str(tmp_path / "none.mcap")])
    assert result.exit_code == 2
    assert result.output == f"evperc: error: {tmp_path / 'none.mcap'}: log file not found\n"


def test_info_gives_the_lidars_layers_from_its_ring_field(tmp_path):
    # padded32: a Velodyne driver's layout; the test writer numbers the rings 0..15
    path = _log(tmp_path, layout="padded32")
    result = CliRunner().invoke(cli, ["info", str(path)])
    assert result.exit_code == 0, result.output
    assert ("lidar layers: 16 (ring field); `evperc run` takes --preset vlp16's keys, tuned "
            "for such scanners" in result.output.splitlines())
    info = json.loads(CliRunner().invoke(cli, ["info", "--json", str(path)]).output)
    assert info["lidar_layers"] == {"count": 16, "from": "ring field"}


def test_info_says_nothing_of_layers_a_cloud_does_not_show(tmp_path):
    path = _log(tmp_path)  # x y z intensity, unorganised: no laser index
    info = json.loads(CliRunner().invoke(cli, ["info", "--json", str(path)]).output)
    assert info["lidar_layers"] is None
    assert "lidar layers" not in CliRunner().invoke(cli, ["info", str(path)]).output


def _no_gnss_log(path, layout):
    """3 scans 1 m apart, odometry, no GNSS fix (a run with --no-map needs no geo-reference)."""
    return write_ros2_mcap(path, layout=layout,
                           clouds=[(S0 + i * 100 * MS, np.ones((40, 3)) * (i + 1), "v")
                                   for i in range(3)],
                           odometry=[(S0 + i * 50 * MS, transform(x=i)) for i in range(6)],
                           tf_static=[("base_link", "v", np.eye(4))])


def test_run_takes_the_preset_tuned_for_a_16_layer_lidar(tmp_path):
    # a ring field of 16 layers: configs/vlp16.toml's keys under the defaults' place, said
    # once; an explicit --preset (or none) and a cloud without a laser index: nothing said
    sixteen = _no_gnss_log(tmp_path / "sixteen.mcap", "padded32")
    line = (f"{sixteen}: a 16-layer lidar (ring field): running with --preset vlp16, tuned "
            "for such scanners (--preset none: the defaults alone)")
    unknown = _no_gnss_log(tmp_path / "unknown.mcap", "xyzi16")  # no laser index
    runs = {name: CliRunner().invoke(cli, ["run", str(log), "--no-map", "--out",
                                           str(tmp_path / name), *extra])
            for name, log, extra in (("plain", sixteen, []),
                                     ("preset", sixteen, ["--preset", "vlp16"]),
                                     ("none", sixteen, ["--preset", "none"]),
                                     ("unknown", unknown, []))}
    for result in runs.values():
        assert result.exit_code == 0, result.output
    assert runs["plain"].output.count(line) == 1
    for name in ("preset", "none", "unknown"):
        assert "--preset" not in runs[name].output, name
    configs = {name: evperc.load(tmp_path / name).manifest["config"] for name in runs}
    vlp16 = load_config(None, preset="vlp16")
    assert vlp16["objects"]["growth_reach_cells"] != load_config(None)["objects"][
        "growth_reach_cells"]  # the preset changes a key: the check below can fail
    for name, want in (("plain", vlp16), ("preset", vlp16), ("none", load_config(None)),
                       ("unknown", load_config(None))):
        assert json.dumps(configs[name], sort_keys=True) == json.dumps(want, sort_keys=True)


def test_the_hint_reads_the_runs_own_log_so_a_damaged_log_is_reported_once(tmp_path):
    # the layers come from the run's reader: opening the log (and its warning) happens once
    full = _no_gnss_log(tmp_path / "full.mcap", "padded32").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full[:len(full) * 2 // 3])
    result = CliRunner().invoke(cli, ["run", str(cut), "--no-map", "--out",
                                      str(tmp_path / "c")])
    assert result.output.count("log is truncated or damaged") == 1, result.output


def test_which_preset_is_tuned_for_how_many_layers():
    # the ranges of evperc/config.py's LAYER_PRESETS: measured presets only
    assert [preset_for_layers(n) for n in (1, 4, 11, 12, 16, 24, 32, 48, 64, 128, 129)] == [
        None, None, None, "vlp16", "vlp16", "vlp16", None, "hdl64", "hdl64", "hdl64", None]
