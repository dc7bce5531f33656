"""Packed point buffers and 2-D scans into (N, 3) points, for several real-world layouts."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from evperc.logs.pointcloud import (
    MissingFieldsError,
    foxglove_fields,
    layer_count,
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


# --- the compiled pass against a per-point struct.unpack reference ----------------------

_STRUCT = {"i1": "b", "u1": "B", "i2": "h", "u2": "H", "i4": "i", "u4": "I", "f4": "f", "f8": "d"}


def _reference_xyz(buf: bytes, fields: dict, point_step: int, width: int, height: int,
                   row_step: int, big_endian: bool) -> np.ndarray:
    """Plain Python: unpack x, y, z of each point of each complete row with ``struct``, round
    to float32, keep the points whose three float32 values are finite."""
    order = ">" if big_endian else "<"
    row_step = max(row_step, width * point_step)
    out = []
    for r in range(height):
        if r * row_step + width * point_step > len(buf):
            break
        for c in range(width):
            base = r * row_step + c * point_step
            xyz = [struct.unpack_from(order + _STRUCT[fields[n][1]], buf, base + fields[n][0])[0]
                   for n in ("x", "y", "z")]
            with np.errstate(over="ignore"):
                as32 = [np.float32(v) for v in xyz]
            if all(np.isfinite(v) for v in as32):
                out.append(as32)
    return np.array(out, dtype=np.float32).reshape(-1, 3)


def _random_cloud(rng, type_codes, big_endian, width, height, pad_bytes, truncate):
    """A buffer with x, y, z of the given types at random non-overlapping offsets, random
    other bytes, about 10 % NaN / inf values for float types, optional row padding and a
    cut end."""
    sizes = [np.dtype(t).itemsize for t in type_codes]
    slots, offset = [], int(rng.integers(0, 3))
    for size in sizes:
        offset += (-offset) % size  # aligned within the point, like real drivers
        slots.append(offset)
        offset += size + int(rng.integers(0, 5))
    point_step = offset + int(rng.integers(0, 4))
    row_step = width * point_step + pad_bytes
    buf = bytearray(rng.integers(0, 256, row_step * height, dtype=np.uint8).tobytes())
    order = ">" if big_endian else "<"
    for t, off in zip(type_codes, slots, strict=True):
        dtype = np.dtype(order + t)
        for r in range(height):
            for c in range(width):
                if dtype.kind == "f":
                    value = rng.choice([rng.normal(0, 50), np.nan, np.inf, -np.inf],
                                       p=[0.9, 0.04, 0.03, 0.03])
                else:
                    info = np.iinfo(dtype)
                    value = rng.integers(info.min, int(info.max) + 1)
                pos = r * row_step + c * point_step + off
                buf[pos:pos + dtype.itemsize] = np.array(value).astype(dtype).tobytes()
    fields = {n: (off, t) for n, off, t in zip("xyz", slots, type_codes, strict=True)}
    return bytes(buf[:len(buf) - truncate]), fields, point_step, row_step


@pytest.mark.parametrize("seed", range(12))
def test_random_layouts_match_the_struct_reference(seed):
    rng = np.random.default_rng(seed)
    kinds = ["f4", "f8", "i1", "u1", "i2", "u2", "i4", "u4"]
    same = rng.random() < 0.5
    type_codes = [str(rng.choice(kinds[:2] if same else kinds))] * 3 if same else [
        str(t) for t in rng.choice(kinds, 3)]
    big_endian = bool(rng.random() < 0.4)
    width, height = int(rng.integers(1, 40)), int(rng.integers(1, 5))
    pad = int(rng.choice([0, 0, 3, 8]))
    data, fields, step, row_step = _random_cloud(rng, type_codes, big_endian, width, height,
                                                 pad, truncate=int(rng.choice([0, 0, 5])))
    expected = _reference_xyz(data, fields, step, width, height, row_step, big_endian)
    got = xyz_from_packed(data, fields, step, width, height, row_step, big_endian)
    assert got.dtype == np.float32 and got.shape == expected.shape
    np.testing.assert_array_equal(got, expected)


def test_float64_beyond_float32_range_is_dropped_like_inf():
    pts = np.array([[1e300, 0, 0], [1.0, 2.0, 3.0], [0, -1e39, 0]])
    data = pts.astype("<f8").tobytes()
    table = {"x": (0, "f8"), "y": (8, "f8"), "z": (16, "f8")}
    np.testing.assert_array_equal(xyz_from_packed(data, table, 24, width=3), [[1, 2, 3]])


def test_unaligned_views_and_array_buffers():
    """The points start at an odd address (a memoryview into a larger buffer) or come as a
    uint8 array (JSON / protobuf bytes); both are read in place."""
    pts = np.array([[1.5, -2.0, 0.25, 9.0], [3.0, 4.0, 5.0, 9.0]], np.float32)
    shifted = memoryview(b"\x00" + pts.tobytes())[1:]
    table = {"x": (0, "f4"), "y": (4, "f4"), "z": (8, "f4")}
    np.testing.assert_array_equal(xyz_from_packed(shifted, table, 16, width=2), pts[:, :3])
    as_array = np.frombuffer(pts.tobytes(), np.uint8).copy()
    np.testing.assert_array_equal(xyz_from_packed(as_array, table, 16, width=2), pts[:, :3])


def test_result_does_not_alias_the_message_buffer():
    pts = np.array([[1.0, 2.0, 3.0]], np.float32)
    buf = bytearray(pts.tobytes())
    got = xyz_from_packed(buf, {"x": (0, "f4"), "y": (4, "f4"), "z": (8, "f4")}, 12, width=1)
    buf[:] = bytes(12)
    np.testing.assert_array_equal(got, pts)


def test_field_outside_the_point_is_an_error():
    with pytest.raises(ValueError, match="does not fit"):
        xyz_from_packed(bytes(64), {"x": (0, "f4"), "y": (4, "f4"), "z": (14, "f4")}, 16,
                        width=4)


# --- the scanner's layers (evperc/logs/pointcloud.py: layer_count) -----------------------

def test_layers_from_a_ring_field_set_by_hand():
    """Three 32-byte Velodyne-style points (ring uint16 at byte 20) with rings 0, 15, 3:
    16 layers; the same bytes big-endian read as such."""
    table = _ros_table([("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("ring", 20, 4)])
    for order in ("<", ">"):
        buf = bytearray(96)
        for i, ring in enumerate((0, 15, 3)):
            struct.pack_into(order + "H", buf, 32 * i + 20, ring)
        assert layer_count(bytes(buf), table, 32, width=3, big_endian=order == ">") == (
            16, "ring field")


def test_layers_from_the_test_writers_velodyne_layout():
    # tests/mcap_writers.py's padded32 layout numbers its points' rings 0..15 in turn
    data, step, fields = packed_cloud(np.zeros((40, 3)), "padded32")
    assert layer_count(data, _ros_table(fields), step, width=40) == (16, "ring field")


def test_layers_of_an_organised_cloud_without_ring_are_its_rows():
    table = _ros_table([("x", 0, 7), ("y", 4, 7), ("z", 8, 7)])
    data = np.zeros((32, 64, 4), np.float32).tobytes()
    assert layer_count(data, table, 16, width=64, height=32) == (32, "organised rows")


def test_no_layers_from_an_unorganised_cloud_without_ring():
    data, step, fields = packed_cloud(POINTS, "xyzi16")
    assert layer_count(data, _ros_table(fields), step, width=len(POINTS)) is None


def test_a_laser_id_field_and_a_ring_that_is_no_laser_index():
    table = _ros_table([("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("laser_id", 12, 2)])
    buf = bytearray(32)
    buf[12], buf[28] = 3, 1  # uint8 laser ids 3 and 1: 4 layers
    assert layer_count(bytes(buf), table, 16, width=2) == (4, "laser_id field")
    # a float "ring" of 1e6 is no laser index: nothing certain (unorganised cloud)
    table = _ros_table([("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("ring", 12, 7)])
    buf = bytearray(16)
    struct.pack_into("<f", buf, 12, 1e6)
    assert layer_count(bytes(buf), table, 16, width=1) is None


def test_layers_of_foxglove_and_ros_messages_as_decoded():
    """The message adapters (evperc/logs/mcap_messages.py) on decoded messages as dicts: a
    foxglove PointCloud with a uint16 ring (foxglove's UINT16 = 3) at byte 12, rings 0..31;
    a PointCloud2 organised in 8 rows; a LaserScan."""
    from evperc.logs.mcap_messages import LAYER_ADAPTERS

    buf = bytearray(16 * 4)
    for i, ring in enumerate((5, 31, 0, 7)):
        struct.pack_into("<H", buf, 16 * i + 12, ring)
    fox = {"data": bytes(buf), "point_stride": 16,
           "fields": [{"name": n, "offset": o, "type": t}
                      for n, o, t in (("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("ring", 12, 3))]}
    assert LAYER_ADAPTERS["foxglove.PointCloud"](fox) == (32, "ring field")
    ros = {"data": bytes(16 * 8 * 3), "point_step": 16, "width": 3, "height": 8,
           "row_step": 48, "is_bigendian": False,
           "fields": [{"name": n, "offset": o, "datatype": 7, "count": 1}
                      for n, o in (("x", 0), ("y", 4), ("z", 8))]}
    assert LAYER_ADAPTERS["sensor_msgs/PointCloud2"](ros) == (8, "organised rows")
    assert LAYER_ADAPTERS["sensor_msgs/msg/LaserScan"]({}) == (1, "a 2-D scan")
