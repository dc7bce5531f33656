"""`evperc export`: foxglove.Grid + FrameTransform in MCAP, read back with the mcap reader."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from evperc.cli import cli
from evperc.logs.factory import open_log
from tests.render.conftest import CODES, make_frame, write_run

ROWS, COLS, RES = 3, 4, 0.5
SAMPLE = Path(__file__).parents[2] / "sample_data"
FLOAT32, UINT8 = 7, 1      # foxglove.PackedElementField.NumericType values


def frames() -> list:
    out = []
    for k in range(3):
        f = make_frame(ROWS, COLS, row0=100 + k, col0=-7, resolution_m=RES,
                       stamp_ns=5_000_000_000 + k * 50_000_000, index=k,
                       pose=(1.5 + k, -2.0, math.pi / 2))
        f.betp[0, 1] = [0.0, 0.25, 0.25, 0.0, 0.5]     # southern row, second column
        f.decision[0, 1] = CODES["moving"]
        f.zeta[0, 1] = 0.75
        f.decision[2, 3] = CODES["infrastructure"]      # northern row, last column
        out.append(f)
    return out


def read(path: Path):
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        messages = [(channel.topic, schema.name, message.log_time, decoded)
                    for schema, channel, message, decoded in reader.iter_decoded_messages()]
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    return messages, metadata


def field_value(grid, name: str, row: int, col: int) -> float:
    """Decode one cell field from the message alone (fields, strides), row 0 first in data."""
    (field,) = [f for f in grid.fields if f.name == name]
    start = row * grid.row_stride + col * grid.cell_stride + field.offset
    dtype = {FLOAT32: "<f4", UINT8: "u1"}[field.type]
    return float(np.frombuffer(grid.data, dtype=dtype, count=1, offset=start)[0])


def test_export_round_trip(tmp_path: Path) -> None:
    out = write_run(tmp_path / "run", frames())
    mcap = tmp_path / "grids.mcap"
    result = CliRunner().invoke(cli, ["export", str(out), "--mcap", str(mcap)],
                                catch_exceptions=False)
    assert result.exit_code == 0, result.output
    messages, metadata = read(mcap)
    grids = [m for m in messages if m[1] == "foxglove.Grid"]
    tfs = [m for m in messages if m[1] == "foxglove.FrameTransform"]
    assert [g[2] for g in grids] == [5_000_000_000, 5_050_000_000, 5_100_000_000]
    assert len(tfs) == 3
    topic, _, log_time, grid = grids[1]
    assert grid.frame_id == "evperc"
    assert grid.column_count == COLS
    assert grid.cell_stride == 32 and grid.row_stride == 32 * COLS
    assert len(grid.data) == ROWS * grid.row_stride
    assert grid.timestamp.seconds == 5 and grid.timestamp.nanos == 50_000_000
    # the grid's corner is the window's south-west corner: (col0·r, row0·r) = (-3.5, 50.5)
    assert (grid.pose.position.x, grid.pose.position.y) == (-3.5, 50.5)
    assert grid.pose.orientation.w == 1.0
    assert grid.cell_size.x == RES and grid.cell_size.y == RES
    step = 1 / 510 + 1e-6  # the run stores values in [0, 1] within 1/255 (uint8)
    assert field_value(grid, "betp_M", 0, 1) == pytest.approx(0.5, abs=step)
    assert field_value(grid, "betp_I", 0, 1) == pytest.approx(0.25, abs=step)
    assert field_value(grid, "betp_F", 0, 1) == 0.0
    assert field_value(grid, "betp_F", 1, 1) == 1.0
    assert field_value(grid, "zeta", 0, 1) == pytest.approx(0.75, abs=step)
    assert field_value(grid, "decision", 0, 1) == CODES["moving"]
    assert field_value(grid, "decision", 2, 3) == CODES["infrastructure"]   # last row = north
    assert field_value(grid, "decision", 0, 3) == CODES["free"]
    # pignistic colour as RGBA fields: .25·I(0,0,255) + .25·U(255,0,255) + .5·M(255,0,0)
    # = (191, 0, 128); the stored
    # betP is within 1/255, which may move a channel by one step
    rgb = [field_value(grid, name, 0, 1) for name in ("red", "green", "blue", "alpha")]
    assert np.allclose(rgb, [191.0, 0.0, 128.0, 255.0], atol=1.0)
    _, _, _, tf = tfs[2]
    assert (tf.parent_frame_id, tf.child_frame_id) == ("evperc", "ego")
    assert (tf.translation.x, tf.translation.y) == (3.5, -2.0)
    assert math.isclose(tf.rotation.z, math.sin(math.pi / 4))
    assert math.isclose(tf.rotation.w, math.cos(math.pi / 4))
    info = metadata["evperc"]
    assert info["crs"] == "EPSG:32631" and float(info["resolution_m"]) == RES
    assert json.loads(info["decision_codes"]) == CODES


def test_export_frames_and_overwrite(tmp_path: Path) -> None:
    out = write_run(tmp_path / "run", frames())
    mcap = tmp_path / "grids.mcap"
    runner = CliRunner()
    args = ["export", str(out), "--mcap", str(mcap), "--frames", "1:", "--frame-id", "utm"]
    assert runner.invoke(cli, args).exit_code == 0
    messages, _ = read(mcap)
    grids = [m[3] for m in messages if m[1] == "foxglove.Grid"]
    assert len(grids) == 2 and grids[0].frame_id == "utm"
    result = runner.invoke(cli, args)
    assert result.exit_code == 2 and "--overwrite" in result.output
    assert runner.invoke(cli, [*args, "--overwrite"]).exit_code == 0
    assert not list(tmp_path.glob(".*.tmp"))


def planar(tf) -> np.ndarray:
    """4×4 of a decoded foxglove.FrameTransform that turns about the vertical only."""
    assert tf.rotation.x == tf.rotation.y == 0.0
    yaw = 2 * math.atan2(tf.rotation.z, tf.rotation.w)
    T = np.eye(4)
    T[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    T[:3, 3] = [tf.translation.x, tf.translation.y, tf.translation.z]
    return T


def test_export_links_the_grids_to_the_logs_world_frame(tmp_path: Path) -> None:
    """A run of the sample drive (poses in the log's local frame `map`, geo-referenced by
    GNSS) exported: /evperc/world carries `evperc` → `map` = the run's T_crs_world, so the
    log's own lidar poses, carried through it, land on the exported ego poses — the grids
    lie under the log's data in Foxglove."""
    out, mcap = tmp_path / "run", tmp_path / "grids.mcap"
    runner = CliRunner()
    result = runner.invoke(cli, ["run", str(SAMPLE / "drive.mcap"), "--map",
                                 str(SAMPLE / "map.geojson"), "--out", str(out), "--end", "1"],
                           catch_exceptions=False)
    assert result.exit_code == 0, result.output
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["world_frame"] == "map"
    result = runner.invoke(cli, ["export", str(out), "--mcap", str(mcap)], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    messages, metadata = read(mcap)
    links = {t: m for topic, _, t, m in messages if topic == "/evperc/world"}
    egos = {t: m for topic, _, t, m in messages if topic == "/evperc/ego"}
    assert len(links) == len(egos) == manifest["frame_count"] > 5
    assert metadata["evperc"]["world_frame"] == "map"
    link = next(iter(links.values()))
    assert (link.parent_frame_id, link.child_frame_id) == ("evperc", "map")
    np.testing.assert_allclose(planar(link), manifest["T_crs_world"], atol=1e-9)
    # the log's poses, read independently, through the link = the exported ego poses
    posed = {s.stamp_ns: s.T_world_sensor for s in open_log(SAMPLE / "drive.mcap").scans()}
    for stamp, ego in egos.items():
        T_crs_sensor = planar(links[stamp]) @ posed[stamp]
        assert ego.parent_frame_id == "evperc"
        assert ego.translation.x == pytest.approx(T_crs_sensor[0, 3], abs=1e-6)
        assert ego.translation.y == pytest.approx(T_crs_sensor[1, 3], abs=1e-6)
        yaw = math.atan2(T_crs_sensor[1, 0], T_crs_sensor[0, 0])
        assert math.remainder(2 * math.atan2(ego.rotation.z, ego.rotation.w) - yaw,
                              2 * math.pi) == pytest.approx(0.0, abs=1e-9)


def test_export_names_no_world_frame_equal_to_the_grid_frame(tmp_path: Path) -> None:
    """--frame-id equal to the log's world frame: the link would be a loop; it is left out
    (the grids are still written)."""
    out, mcap = tmp_path / "run", tmp_path / "grids.mcap"
    runner = CliRunner()
    assert runner.invoke(cli, ["run", str(SAMPLE / "drive.mcap"), "--no-map", "--out",
                               str(out), "--end", "0.5"]).exit_code == 0
    result = runner.invoke(cli, ["export", str(out), "--mcap", str(mcap), "--frame-id", "map"],
                           catch_exceptions=False)
    assert result.exit_code == 0, result.output
    messages, _ = read(mcap)
    assert not [m for m in messages if m[0] == "/evperc/world"]
    assert [m for m in messages if m[0] == "/evperc/grid"]
