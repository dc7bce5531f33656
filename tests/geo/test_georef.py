"""Geo-referencing a local pose frame (method.md §7): origin + heading, GNSS fit, identity.

Expected positions are computed with pyproj's Geod (on the ellipsoid) and Transformer
independently of the code under test."""

from __future__ import annotations

import math

import numpy as np
import pyproj
import pytest

from evperc.errors import GeoreferenceError
from evperc.geo.georef import Georeference, from_gnss, from_origin, identity

UTM35 = pyproj.CRS.from_epsg(32635)
GEOD = pyproj.Geod(ellps="WGS84")
TO_UTM = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32635", always_xy=True)
TO_LL = pyproj.Transformer.from_crs("EPSG:32635", "EPSG:4326", always_xy=True)
LAT, LON = 60.1699, 24.9414  # Helsinki, 2° west of zone 35's central meridian


def pose(x: float, y: float, yaw: float = 0.0) -> np.ndarray:
    t = np.eye(4)
    t[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    t[:2, 3] = [x, y]
    t[2, 3] = 1.7
    return t


def test_origin_lands_on_its_projected_position() -> None:
    g = from_origin(LAT, LON, 0.0, UTM35)
    x, y = TO_UTM.transform(LON, LAT)
    assert g.apply(np.eye(4))[:2, 3] == pytest.approx([x, y], abs=1e-6)
    assert g.apply(pose(0, 0))[2, 3] == pytest.approx(1.7)


@pytest.mark.parametrize("heading_deg", [0.0, 59.6, 90.0, -135.0])
def test_point_along_the_heading_lands_where_the_ellipsoid_says(heading_deg: float) -> None:
    g = from_origin(LAT, LON, heading_deg, UTM35)
    # 200 m along the true heading: bearing clockwise from north = 90° − heading
    lon2, lat2, _ = GEOD.fwd(LON, LAT, 90.0 - heading_deg, 200.0)
    expected = TO_UTM.transform(lon2, lat2)
    got = g.apply_xy(np.array([[200.0, 0.0]]))[0]
    # only the UTM scale (k ≈ 0.99975 here: 5 cm over 200 m) is left; ignoring the grid
    # convergence (≈ 1.8° here) would be 6 m off
    assert np.hypot(*(got - expected)) < 0.1
    assert g.apply(pose(200.0, 0.0))[:2, 3] == pytest.approx(got)


def test_grid_convergence_is_applied() -> None:
    # true north at Helsinki points ~ (lon − 27°)·sin(lat) = −1.79° off grid north
    g = from_origin(LAT, LON, 90.0, UTM35)
    expected = 90.0 + (LON - 27.0) * math.sin(math.radians(LAT))
    assert math.degrees(g.heading_rad) == pytest.approx(expected, abs=0.02)


def test_bad_origin() -> None:
    with pytest.raises(GeoreferenceError, match="input.origin_lat_deg"):
        from_origin(float("nan"), LON, 0.0, UTM35)


def test_gnss_fit_recovers_rotation_and_translation() -> None:
    rng = np.random.default_rng(7)
    theta, tx, ty = 0.7, 385_100.0, 6_672_300.0
    s = np.linspace(0, 1, 300)
    world = np.column_stack([250 * s, 60 * np.sin(3 * s)])  # a curving 250 m drive
    rot = np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])
    truth = world @ rot.T + [tx, ty]
    noisy = truth + rng.normal(0.0, 0.5, truth.shape)
    lon, lat = TO_LL.transform(noisy[:, 0], noisy[:, 1])
    fixes = np.column_stack([lon, lat])
    fixes[5] = np.nan  # a bad fix is dropped
    g = from_gnss(world, fixes, UTM35)
    assert g.heading_rad == pytest.approx(theta, abs=math.radians(0.3))
    assert g.T_crs_world[:2, 3] == pytest.approx([tx, ty], abs=0.3)
    assert 0.5 < g.rms_residual_m < 0.9  # ≈ 0.5·√2 for 2-D noise of σ = 0.5 m
    assert np.abs(g.apply_xy(world) - truth).max() < 1.0


def test_gnss_fit_with_too_little_motion() -> None:
    world = np.array([[0.0, 0.0], [1.0, 0.5], [2.0, 1.0]])
    lon, lat = TO_LL.transform(385_000 + world[:, 0], 6_672_000 + world[:, 1])
    with pytest.raises(GeoreferenceError, match=r"2\.2 m.*input.origin_heading_deg") as err:
        from_gnss(world, np.column_stack([lon, lat]), UTM35)
    assert "\n" not in str(err.value)
    with pytest.raises(GeoreferenceError, match="1 usable"):
        from_gnss(world[:1], np.column_stack([lon, lat])[:1], UTM35)


def test_identity() -> None:
    g = identity(UTM35)
    assert isinstance(g, Georeference) and g.crs == UTM35
    p = pose(385_000.0, 6_672_000.0, 0.3)
    assert np.array_equal(g.apply(p), p)
