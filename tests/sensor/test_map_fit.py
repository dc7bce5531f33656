"""evperc.sensor.map_fit: the map's offset from the scans' returns. Synthetic blocks of buildings
whose walls are sampled as a lidar would return them, the map moved by a known offset; and
end to end on the bundled drive with its map moved by scripts/shift_map.py."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pyproj
import pytest
import shapely

import evperc
from evperc.geo.maps import MapData
from evperc.sensor.map_fit import MIN_MOVE_M, fit_returns, moved, outline_points

REPO = Path(__file__).resolve().parents[2]
UTM35 = pyproj.CRS.from_epsg(32635)


def _street() -> np.ndarray:
    """Two rows of houses along a street running east (y = 0 … 12 m between them), one
    of them L-shaped, in UTM coordinates near Helsinki."""
    x0, y0 = 385_000.0, 6_672_000.0
    houses = [shapely.box(x0 + x, y0 + 12.0, x0 + x + 14.0, y0 + 24.0) for x in (0, 16, 32)]
    houses += [shapely.box(x0 + x, y0 - 10.0, x0 + x + 10.0, y0) for x in (2, 20, 38)]
    houses.append(shapely.Polygon([(x0 + 52, y0 + 12), (x0 + 62, y0 + 12), (x0 + 62, y0 + 30),
                                   (x0 + 56, y0 + 30), (x0 + 56, y0 + 18), (x0 + 52, y0 + 18)]))
    return np.array(houses, dtype=object)


def _returns(buildings: np.ndarray, seed: int, clutter: int = 600) -> np.ndarray:
    """Points on the walls facing the street (every 0.1 m, 2 cm of range noise) and clutter
    on the street (parked cars, poles): what the fit sees."""
    rng = np.random.default_rng(seed)
    walls = shapely.get_coordinates(shapely.segmentize(shapely.boundary(buildings), 0.1))
    walls = walls[rng.random(len(walls)) < 0.6]
    walls = walls + rng.normal(0, 0.02, walls.shape)
    lo = shapely.total_bounds(buildings)
    street = np.column_stack([rng.uniform(lo[0], lo[2], clutter),
                              rng.uniform(lo[1] + 10.5, lo[1] + 21.5, clutter)])
    return np.concatenate([walls, street])


@pytest.mark.parametrize("offset", [(0.8, -0.5), (-1.2, 0.3), (0.0, 1.5)])
def test_a_moved_map_is_moved_back(offset: tuple[float, float]) -> None:
    """The returns are those of the true walls; the map given is moved by ``offset``: the fit
    moves it back within 0.05 m (the fine search's step) on each axis."""
    true = _street()
    given = moved(MapData(true, np.zeros(0, object), UTM35, "test"), *offset)
    fit = fit_returns(_returns(true, 1), given.buildings, scans=1)
    assert fit is not None and fit.moved
    np.testing.assert_allclose(fit.offset_m, (-offset[0], -offset[1]), atol=0.05)
    assert fit.share_best > fit.share_at_map + 0.2


def test_a_map_off_by_more_than_the_pose_checks_search_is_found() -> None:
    """2.5 m off: beyond the pose check's ±2 m, within the fit's ±4 m (with ±2 m, two of five
    simulated ibeo4 maps 2.5 m off were moved the wrong way, to the search's edge)."""
    true = _street()
    given = moved(MapData(true, np.zeros(0, object), UTM35, "test"), 2.5, 0.0)
    fit = fit_returns(_returns(true, 4), given.buildings, scans=1)
    assert fit is not None and fit.moved
    np.testing.assert_allclose(fit.offset_m, (-2.5, 0.0), atol=0.05)


@pytest.mark.parametrize("found, moves", [((3.9, 0.0), False), ((0.0, -3.9), False),
                                          ((3.85, 0.0), True), ((-1.0, 3.8), True)])
def test_a_best_offset_at_the_search_edge_moves_nothing(
        monkeypatch: pytest.MonkeyPatch, found: tuple[float, float], moves: bool) -> None:
    """The rule alone (the search's result given): past SEARCH_M − COARSE_M / 2 = 3.875 m on
    an axis the best offset is the search's edge, no peak, and the map stays."""
    import evperc.sensor.map_fit as map_fit

    monkeypatch.setattr(map_fit, "best_offset", lambda a, b, half: (0.1, 0.6, found))
    fit = fit_returns(_returns(_street(), 5), _street(), scans=1)
    assert fit is not None and fit.moved is moves
    assert fit.best_m == (-found[0], -found[1])


def test_a_map_that_fits_is_not_moved() -> None:
    true = _street()
    fit = fit_returns(_returns(true, 2), true, scans=1)
    assert fit is not None and not fit.moved and fit.offset_m == (0.0, 0.0)
    assert np.hypot(*fit.best_m) < MIN_MOVE_M


def test_nothing_to_fit_without_buildings_or_returns() -> None:
    true = _street()
    far = _returns(true, 3) + np.array([5_000.0, 0.0])   # returns 5 km from every building
    assert fit_returns(far, true) is None
    assert fit_returns(_returns(true, 3)[:50], true) is None   # too few returns
    assert fit_returns(_returns(true, 3), np.zeros(0, object)) is None


def test_outline_points_are_on_the_outlines_and_in_the_box() -> None:
    true = _street()
    box = (385_000.0, 6_672_005.0, 385_030.0, 6_672_030.0)
    xy = outline_points(true, box)
    assert len(xy) > 1000
    assert (xy[:, 0] >= box[0]).all() and (xy[:, 1] <= box[3]).all()
    lines = shapely.boundary(true)
    d = shapely.distance(shapely.union_all(lines), shapely.points(xy))
    assert d.max() < 1e-6


def test_moved_translates_buildings_and_roads() -> None:
    road = shapely.box(0, 0, 10, 2)
    md = MapData(np.array([shapely.box(0, 3, 4, 6)], object), np.array([road], object), UTM35,
                 "test")
    out = moved(md, 1.5, -0.5)
    assert shapely.equals(out.buildings[0], shapely.box(1.5, 2.5, 5.5, 5.5))
    assert shapely.equals(out.roads[0], shapely.box(1.5, -0.5, 11.5, 1.5))
    assert out.crs == md.crs


@pytest.fixture(scope="module")
def sample_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The bundled drive (ibeo4, 20 s) run with the defaults (``map.fit_to_scans`` on) on its
    map and on its map moved 0.71 m east and 0.71 m north, and with the option off on its
    map."""
    from click.testing import CliRunner

    from evperc.cli import cli
    sys.path.insert(0, str(REPO / "scripts"))
    import shift_map

    root = tmp_path_factory.mktemp("map-fit")
    data = REPO / "sample_data"
    moved_map = root / "moved.geojson"
    moved_map.write_text(json.dumps(shift_map.shift(
        json.loads((data / "map.geojson").read_text()), 0.71, 0.71)))
    plain = root / "plain.toml"
    plain.write_text("[map]\nfit_to_scans = false\n")
    runs = {"fit": (data / "map.geojson", None), "moved_fit": (moved_map, None),
            "plain": (data / "map.geojson", plain)}
    out = {}
    for name, (map_path, config) in runs.items():
        args = ["-q", "run", str(data / "drive.mcap"), "--map", str(map_path), "--out",
                str(root / name)] + (["--config", str(config)] if config else [])
        result = CliRunner().invoke(cli, args)
        assert result.exit_code == 0, result.output
        out[name] = root / name
    return out


def test_the_drive_with_its_map_moved_gets_it_back(sample_runs: dict[str, Path]) -> None:
    fit = json.loads((sample_runs["moved_fit"] / "manifest.json").read_text())["map_fit"]
    assert fit["moved"]
    np.testing.assert_allclose(fit["offset_m"], (-0.71, -0.71), atol=0.1)
    assert fit["share_best"] > fit["share_at_map"] + 0.2


def test_the_drive_with_its_own_map_runs_as_with_the_option_off(
        sample_runs: dict[str, Path]) -> None:
    """Its map fits (the simulator's): not moved, and every frame's decision is the one of the
    run with the option off."""
    fit = json.loads((sample_runs["fit"] / "manifest.json").read_text())["map_fit"]
    assert not fit["moved"] and fit["offset_m"] == [0.0, 0.0]
    plain = json.loads((sample_runs["plain"] / "manifest.json").read_text())
    assert plain["map_fit"] is None
    a, b = evperc.load(sample_runs["fit"]), evperc.load(sample_runs["plain"])
    n = 0
    for fa, fb in zip(a.frames, b.frames, strict=True):
        np.testing.assert_array_equal(fa.decision, fb.decision)
        n += 1
    assert n == 200
