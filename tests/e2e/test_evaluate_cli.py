"""`evperc evaluate` refuses what cannot be compared (issue 22 items 4, 6, 9): a truth of
another drive, a --compare run over other frames, and an existing --json file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from evperc.cli import cli

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_data"
OSM = REPO / "tests" / "data" / "osm"


def invoke(*args: str) -> object:
    return CliRunner().invoke(cli, ["-q", *args])


def error_line(output: str) -> str:
    lines = [line for line in output.splitlines() if line.startswith("evperc: error")]
    assert len(lines) == 1, output
    return lines[0]


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The sample drive's first 2 s and 3 s (no map), and another simulated drive with its
    own truth and run."""
    root = tmp_path_factory.mktemp("evaluate")
    out = {}
    for name, end in (("two", "2"), ("three", "3")):
        result = invoke("run", str(SAMPLE / "drive.mcap"), "--no-map", "--end", end,
                        "--out", str(root / name))
        assert result.exit_code == 0, result.output
        out[name] = root / name
    other = root / "other"
    result = invoke("simulate", "--map", str(OSM / "helsinki_buildings.geojson"), "--roads",
                    str(OSM / "helsinki_roads.geojson"), "--seconds", "1", "--seed", "3",
                    "--out", str(other))
    assert result.exit_code == 0, result.output
    result = invoke("run", str(other / "drive.mcap"), "--no-map", "--out", str(root / "o"))
    assert result.exit_code == 0, result.output
    out["other_truth"], out["other_run"] = other / "truth", root / "o"
    return out


def test_the_runs_own_truth_is_scored(runs: dict[str, Path]) -> None:
    result = invoke("evaluate", str(runs["two"]), "--truth", str(SAMPLE / "truth"))
    assert result.exit_code == 0, result.output
    assert "frames matched: two 20" in result.output


@pytest.mark.parametrize(("run", "truth"), [("two", "other_truth"), ("other_run", "sample")])
def test_a_truth_of_another_drive_is_refused(runs: dict[str, Path], run: str,
                                             truth: str) -> None:
    truth_dir = SAMPLE / "truth" if truth == "sample" else runs[truth]
    result = invoke("evaluate", str(runs[run]), "--truth", str(truth_dir))
    assert result.exit_code == 2, result.output
    line = error_line(result.output)
    assert str(truth_dir) in line and "not the run's drive" in line, line
    # what differs is named: the sensor positions (the simulator starts every drive at the
    # same stamp)
    assert "m from the run's" in line, line


def test_compare_over_other_frames_is_refused(runs: dict[str, Path]) -> None:
    result = invoke("evaluate", str(runs["three"]), "--truth", str(SAMPLE / "truth"),
                    "--compare", str(runs["two"]))
    assert result.exit_code == 2, result.output
    line = error_line(result.output)
    assert "scored over different frames" in line and "30 frames" in line \
        and "20 frames" in line, line


def test_json_is_not_overwritten_without_overwrite(runs: dict[str, Path],
                                                   tmp_path: Path) -> None:
    path = tmp_path / "scores.json"
    path.write_text("keep me")
    args = ["evaluate", str(runs["two"]), "--truth", str(SAMPLE / "truth"), "--json", str(path)]
    result = invoke(*args)
    assert result.exit_code == 2, result.output
    assert "pass --overwrite" in error_line(result.output)
    assert path.read_text() == "keep me"
    result = invoke(*args, "--overwrite")
    assert result.exit_code == 0, result.output
    assert json.loads(path.read_text())["frames_matched"] == 20
