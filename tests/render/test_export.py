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
from tests.render.conftest import CODES, make_frame, write_run

ROWS, COLS, RES = 3, 4, 0.5
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
    assert grid.frame_id == "map"
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
    # pignistic colour as RGBA fields: .25·I + .25·U + .5·M = (191, 64, 32); the stored
    # betP is within 1/255, which may move a channel by one step
    rgb = [field_value(grid, name, 0, 1) for name in ("red", "green", "blue", "alpha")]
    assert np.allclose(rgb, [191.0, 64.0, 32.0, 255.0], atol=1.0)
    _, _, _, tf = tfs[2]
    assert (tf.parent_frame_id, tf.child_frame_id) == ("map", "ego")
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
