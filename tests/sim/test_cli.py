"""`evperc simulate` through click's CliRunner."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from evperc.cli import cli
from evperc.sim.truth import load_truth

DATA = Path(__file__).resolve().parents[1] / "data" / "osm"


def test_simulate_writes_drive_map_and_truth(tmp_path: Path) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text("[grid]\nwindow_size_m = 30.0\n[sim]\nmoving_cars = 2\n")
    out = tmp_path / "d"
    res = CliRunner().invoke(cli, [
        "simulate", "--map", str(DATA / "helsinki_buildings.geojson"), "--roads",
        str(DATA / "helsinki_roads.geojson"), "--out", str(out), "--seconds", "0.5",
        "--seed", "3", "--config", str(cfg)])
    assert res.exit_code == 0, res.output
    assert (out / "drive.mcap").stat().st_size > 0 and (out / "map.geojson").is_file()
    truth = load_truth(out / "truth")
    assert len(truth) == 5 and truth.shape == (60, 60)
    again = CliRunner().invoke(cli, [
        "simulate", "--map", str(DATA / "helsinki_buildings.geojson"), "--roads",
        str(DATA / "helsinki_roads.geojson"), "--out", str(out)])
    assert again.exit_code == 2 and "--overwrite" in again.output


def test_simulate_missing_map_is_one_line_exit_2(tmp_path: Path) -> None:
    res = CliRunner().invoke(cli, ["simulate", "--map", str(tmp_path / "nope.geojson"),
                                   "--out", str(tmp_path / "o")])
    assert res.exit_code == 2
    assert res.output.count("\n") == 1 and "nope.geojson" in res.output
