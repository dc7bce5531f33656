"""What a failed or interrupted `evperc run` leaves behind (issue 22 items 2 and 3): a run
that stops on an input error leaves nothing, so the corrected run needs no --overwrite; an
existing output is refused before the slow work; an interrupted run resumes from any
directory, and from a moved output directory."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import evperc
from evperc.cli import cli
from evperc.config import load_config
from evperc.runner import RunRequest, run

from .scenes import write_street_drive

DATA = Path(__file__).resolve().parents[1] / "data" / "osm"
BUILDINGS = DATA / "helsinki_buildings.geojson"
ROADS = DATA / "helsinki_roads.geojson"
SMALL = "[grid]\nwindow_size_m = 30.0\n[output]\nchunk_frames = 5\ncheckpoint_frames = 1\n"


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_street_drive(tmp_path_factory.mktemp("failed") / "street.mcap", n_scans=20,
                              beams=360)


def invoke(*args: str) -> object:
    return CliRunner().invoke(cli, list(args))


def error_line(output: str) -> str:
    lines = [line for line in output.splitlines() if line.startswith("evperc: error")]
    assert len(lines) == 1, output
    return lines[0]


@pytest.mark.parametrize("case", ["map-without-overlap", "start-after-the-end"])
def test_input_error_leaves_nothing_and_the_corrected_run_needs_no_overwrite(
        drive: Path, tmp_path: Path, case: str) -> None:
    out = tmp_path / "o"
    if case == "map-without-overlap":
        prague = tmp_path / "prague.toml"
        prague.write_text(SMALL + "[input]\norigin_lat_deg = 50.10\norigin_lon_deg = 14.39\n")
        bad = ["--map", str(BUILDINGS), "--roads", str(ROADS), "--config", str(prague)]
        needle = "overlap"
    else:  # the drive is 2 s long
        bad = ["--no-map", "--start", "30"]
        needle = "no scan in the requested span"
    result = invoke("run", str(drive), *bad, "--out", str(out))
    assert result.exit_code == 2, result.output
    assert needle in error_line(result.output)
    assert not out.exists()
    # nothing to resume, and nothing in the way of the corrected run
    result = invoke("run", "--resume", str(out))
    assert result.exit_code == 2, result.output
    assert "not an evperc output (no manifest.json)" in error_line(result.output)
    result = invoke("run", str(drive), "--no-map", "--out", str(out))
    assert result.exit_code == 0, result.output
    assert json.loads((out / "manifest.json").read_text())["complete"] is True


def test_existing_output_is_refused_before_the_inputs_are_read(drive: Path, tmp_path: Path,
                                                               monkeypatch) -> None:
    out = tmp_path / "o"
    assert invoke("run", str(drive), "--no-map", "--out", str(out)).exit_code == 0
    before = sorted(p.name for p in out.rglob("*"))

    def slow(*args, **kwargs):
        raise AssertionError("the log was opened before the output was refused")

    import evperc.runner as runner_mod

    monkeypatch.setattr(runner_mod, "Pipeline", slow)
    result = invoke("run", str(drive), "--no-map", "--out", str(out))
    assert result.exit_code == 2, result.output
    assert "output directory exists; pass --overwrite" in error_line(result.output)
    assert sorted(p.name for p in out.rglob("*")) == before


def _interrupted(drive: Path, out: Path, stop_at: int) -> None:
    """A run stopped by Ctrl-C after ``stop_at`` frames, started with relative paths from
    the drive's directory."""
    config = load_config(overrides={"grid.window_size_m": 30.0, "output.chunk_frames": 5,
                                    "output.checkpoint_frames": 1})
    seen = []

    def stop(frame: dict) -> None:
        seen.append(frame["stamp_ns"])
        if len(seen) == stop_at:
            raise KeyboardInterrupt

    cwd = os.getcwd()
    os.chdir(drive.parent)
    try:
        with pytest.raises(KeyboardInterrupt):
            run(RunRequest(log_path=Path(drive.name), out_dir=Path(os.path.relpath(out)),
                           config=config), on_frame=stop)
    finally:
        os.chdir(cwd)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["complete"] is False and manifest["frame_count"] == 10
    assert Path(manifest["request"]["log_path"]) == drive.resolve()
    assert Path(manifest["log"]).is_absolute()


@pytest.mark.parametrize("moved", [False, True], ids=["other-cwd", "moved-output"])
def test_resume_from_another_directory(drive: Path, tmp_path: Path, moved: bool,
                                       monkeypatch) -> None:
    full = tmp_path / "full"
    assert invoke("run", str(drive), "--no-map", "--config", str(_small(tmp_path)),
                  "--out", str(full)).exit_code == 0
    part = tmp_path / "part"
    _interrupted(drive, part, stop_at=12)
    if moved:
        shutil.move(part, tmp_path / "elsewhere")
        part = tmp_path / "elsewhere"
    elsewhere = tmp_path / "cwd"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    result = invoke("run", "--resume", str(part))
    assert result.exit_code == 0, result.output
    a, b = list(evperc.load(full).frames), list(evperc.load(part).frames)
    assert [f.stamp_ns for f in a] == [f.stamp_ns for f in b] and len(a) == 20
    for fa, fb in zip(a, b, strict=True):
        np.testing.assert_array_equal(fa.masses, fb.masses)


def _small(tmp_path: Path) -> Path:
    path = tmp_path / "small.toml"
    path.write_text(SMALL)
    return path
