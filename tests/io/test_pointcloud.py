"""Packed point buffers and 2-D scans into (N, 3) points, for several real-world layouts."""

from __future__ import annotations

import numpy as np
import pytest

from evperc.io.pointcloud import (
    MissingFieldsError,
    foxglove_fields,
    planar_points,
    ros_fields,
    xyz_from_packed,
)
from tests.mcap_writers import packed_cloud

POINTS = np.array([[1.0, 2.0, 3.0, 0.1], [-4.5, 0.25, 1e-3, 0.9], [100.0, -200.0, 7.5, 0.0]])


def _ros_table(fields):
    return ros_fields([{"name": n, "offset": o, "datatype": d, "count": 1} for n, o, d in fields])


@pytest.mark.parametrize("layout", ["xyzi16", "padded32", "xyz_f64"])
@pytest.mark.parametrize("big_endian", [False, True])
def test_layouts_give_back_the_points(layout, big_endian):
    data, step, fields = packed_cloud(POINTS, layout, big_endian)
    got = xyz_from_packed(data, _ros_table(fields), step, width=len(POINTS),
                          big_endian=big_endian)
    assert got.dtype == np.float32 and got.shape == (3, 3)
    np.testing.assert_allclose(got, POINTS[:, :3].astype(np.float32))


def test_padded32_by_hand():
    """x y z at 0/4/8, intensity at 16, ring (uint16) at 20, time at 24 — bytes set by hand."""
    buf = bytearray(64)
    np.frombuffer(buf, "<f4", 3, 0)[:] = (1.5, -2.0, 0.25)
    np.frombuffer(buf, "<u2", 1, 20)[:] = 7
    np.frombuffer(buf, "<f4", 3, 32)[:] = (3.0, 4.0, 5.0)
    table = _ros_table([("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 16, 7),
                        ("ring", 20, 4), ("time", 24, 7)])
    got = xyz_from_packed(bytes(buf), table, 32, width=2)
    np.testing.assert_array_equal(got, [[1.5, -2.0, 0.25], [3.0, 4.0, 5.0]])


def test_non_finite_points_are_dropped():
    pts = POINTS.copy()
    pts[1, 0] = np.nan
    pts[2, 2] = np.inf
    data, step, fields = packed_cloud(pts, "xyzi16")
    got = xyz_from_packed(data, _ros_table(fields), step, width=3)
    np.testing.assert_allclose(got, POINTS[:1, :3])


def test_organised_cloud_with_row_padding():
    """2 rows × 2 points, 16-byte points, rows 40 bytes apart (8 bytes of row padding)."""
    pts = np.arange(16, dtype=np.float32).reshape(4, 4)
    rows = [pts[:2].tobytes() + b"\xff" * 8, pts[2:].tobytes() + b"\xff" * 8]
    table = _ros_table([("x", 0, 7), ("y", 4, 7), ("z", 8, 7)])
    got = xyz_from_packed(b"".join(rows), table, 16, width=2, height=2, row_step=40)
    np.testing.assert_array_equal(got, pts[:, :3])


def test_missing_xyz_fields():
    data, step, fields = packed_cloud(POINTS, "no_xyz")
    with pytest.raises(MissingFieldsError) as err:
        xyz_from_packed(data, _ros_table(fields), step, width=3)
    assert err.value.present == ["azimuth", "intensity", "range"]


def test_foxglove_numeric_types_differ_from_ros():
    # foxglove: UINT8 = 1, INT8 = 2; FLOAT64 = 8 — and enum names are accepted (JSON)
    table = foxglove_fields([{"name": "x", "offset": 0, "type": 8},
                             {"name": "y", "offset": 8, "type": "FLOAT64"},
                             {"name": "z", "offset": 16, "type": 8},
                             {"name": "flag", "offset": 24, "type": 1}])
    assert table == {"x": (0, "f8"), "y": (8, "f8"), "z": (16, "f8"), "flag": (24, "u1")}
    assert ros_fields([{"name": "flag", "offset": 0, "datatype": 1}]) == {"flag": (0, "i1")}


def test_planar_points_drop_invalid_ranges():
    ranges = np.array([1.0, np.nan, 2.0, np.inf, 0.05, 50.0, 3.0])
    angles = np.radians([0, 10, 90, 30, 40, 50, 180])
    got = planar_points(ranges, angles, range_min=0.1, range_max=30.0)
    np.testing.assert_allclose(got, [[1, 0, 0], [0, 2, 0], [-3, 0, 0]], atol=1e-6)
