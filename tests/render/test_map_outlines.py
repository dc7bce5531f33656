"""`evperc render --map`: real OSM buildings (tests/data/osm) drawn where they are."""

from __future__ import annotations

import json
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pyproj
import pytest
from click.testing import CliRunner

from evperc.cli import cli
from tests.render.conftest import make_frame, write_run

DATA = Path(__file__).resolve().parents[1] / "data" / "osm"
BUILDINGS = DATA / "helsinki_buildings.geojson"


@pytest.mark.skipif(not BUILDINGS.is_file(), reason="tests/data/osm/helsinki_buildings.geojson "
                    "absent")
def test_building_vertex_is_outlined(tmp_path: Path) -> None:
    feature = json.loads(BUILDINGS.read_text())["features"][10]
    geometry = feature["geometry"]
    ring = geometry["coordinates"][0][0] if geometry["type"] == "MultiPolygon" \
        else geometry["coordinates"][0]
    lon, lat = ring[0][:2]
    # central Helsinki is in UTM zone 35 north
    x, y = pyproj.Transformer.from_crs("OGC:CRS84", "EPSG:32635",
                                       always_xy=True).transform(lon, lat)
    res, n = 0.5, 60
    row0, col0 = int(np.floor(y / res)) - n // 2, int(np.floor(x / res)) - n // 2
    frame = make_frame(n, n, row0=row0, col0=col0, resolution_m=res, pose=(0.0, 0.0, 0.0))
    out = write_run(tmp_path / "run", [frame], crs="EPSG:32635")
    dest = tmp_path / "png"
    result = CliRunner().invoke(cli, ["render", str(out), "--dest", str(dest), "--layers",
                                      "decision", "--map", str(BUILDINGS)],
                                catch_exceptions=False)
    assert result.exit_code == 0, result.output
    image = iio.imread(dest / "frame_00000.png")
    px = 400 // n                                   # auto scale: 6 px per cell
    left, top = 8, 8 + 16                           # margin, title
    u = left + (x / res - col0) * px
    v = top + (n - (y / res - row0)) * px
    patch = image[int(v) - 1:int(v) + 2, int(u) - 1:int(u) + 2]
    assert np.all(patch == (255, 255, 255), axis=-1).any()
    # the rest of the panel is free (green) except outlines: most pixels stay green
    panel = image[top:top + n * px, left:left + n * px]
    assert np.all(panel == (0, 255, 0), axis=-1).mean() > 0.8


def test_map_needs_a_geographic_run(tmp_path: Path) -> None:
    out = write_run(tmp_path / "run", [make_frame(4, 4)], crs="local")
    result = CliRunner().invoke(cli, ["render", str(out), "--dest", str(tmp_path / "p"),
                                      "--map", str(BUILDINGS)])
    assert result.exit_code == 2 and "no geographic CRS" in result.output
