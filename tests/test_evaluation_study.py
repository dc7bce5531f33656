"""scripts/evaluation_study.py's choice of city (`--map`, `--roads`): the drives are simulated
on the map given, and a work directory never mixes the drives of two maps (its cache key is
the profile, seed and length only)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
OSM = REPO / "tests" / "data" / "osm"
sys.path.insert(0, str(REPO / "scripts"))
import evaluation_study as study  # noqa: E402

DRIVE = study.Drive("hdl64", 11, 10.0)


@pytest.fixture(autouse=True)
def _keep_the_default_map(monkeypatch: pytest.MonkeyPatch) -> None:
    """`use_map` sets module globals; put them back after each test."""
    monkeypatch.setattr(study, "MAP", study.MAP)
    monkeypatch.setattr(study, "ROADS", study.ROADS)


def _flag(command: list[str], flag: str) -> str | None:
    return command[command.index(flag) + 1] if flag in command else None


def test_default_city_is_the_helsinki_extract_with_its_roads(tmp_path: Path) -> None:
    study.use_map(tmp_path, None, None)
    command = study.simulate_command(tmp_path, DRIVE)
    assert _flag(command, "--map") == str(OSM / "helsinki_buildings.geojson")
    assert _flag(command, "--roads") == str(OSM / "helsinki_roads.geojson")


def test_another_city_is_simulated_from_its_own_file(tmp_path: Path) -> None:
    prague = OSM / "prague_bubenec.gpkg"
    study.use_map(tmp_path, prague, None)
    command = study.simulate_command(tmp_path, DRIVE)
    assert _flag(command, "--map") == str(prague.resolve())
    assert "--roads" not in command  # the GeoPackage's `streets` layer holds them


def test_a_work_directory_keeps_one_city(tmp_path: Path) -> None:
    study.use_map(tmp_path, OSM / "prague_bubenec.gpkg", None)
    study.use_map(tmp_path, OSM / "prague_bubenec.gpkg", None)  # the same again: fine
    with pytest.raises(SystemExit, match="prague_bubenec.gpkg; use another --work"):
        study.use_map(tmp_path, None, None)


def test_roads_without_a_map_and_missing_files_are_refused(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="--roads needs --map"):
        study.use_map(tmp_path, None, OSM / "helsinki_roads.geojson")
    with pytest.raises(SystemExit, match="no such map file"):
        study.use_map(tmp_path, tmp_path / "nowhere.gpkg", None)
    assert not (tmp_path / "map.txt").exists()
