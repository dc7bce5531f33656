"""Point clouds and 2-D scans from packed message buffers into (N, 3) float32 arrays.

No per-point Python loop and no copy of the buffer: each of x, y, z is a strided numpy view of
the packed bytes, built from the message's field table (name, byte offset, numeric type), its
point stride, row stride and byte order; one compiled pass converts them to float32 and drops
the points that are not finite.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numba
import numpy as np

#: sensor_msgs/msg/PointField datatype constants -> numpy type code
ROS_POINTFIELD_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
#: foxglove.PackedElementField.NumericType -> numpy type code (note: UINT8 = 1, INT8 = 2)
FOXGLOVE_NUMERIC_TYPES = {1: "u1", 2: "i1", 3: "u2", 4: "i2", 5: "u4", 6: "i4", 7: "f4", 8: "f8"}

XYZ = ("x", "y", "z")


class MissingFieldsError(ValueError):
    """The point layout has no x, y and z fields; ``present`` lists the field names it has."""

    def __init__(self, present: list[str]):
        super().__init__(f"no x/y/z fields (fields: {', '.join(present) or 'none'})")
        self.present = present


def xyz_from_packed(data: bytes | bytearray | memoryview | np.ndarray,
                    fields: Mapping[str, tuple[int, str]], point_step: int, width: int,
                    height: int = 1, row_step: int | None = None,
                    big_endian: bool = False) -> np.ndarray:
    """x, y, z of every point in a packed buffer, as (N, 3) float32 with non-finite rows dropped.

    ``fields`` maps a field name to (byte offset, numpy type code such as ``"f4"``); only
    ``x``, ``y``, ``z`` are read. Rows of an organised cloud (``height`` > 1) are ``row_step``
    bytes apart, which may exceed ``width · point_step`` (row padding); only complete rows
    are read. The buffer is not copied: each coordinate is a strided view of it, and one
    compiled pass converts to float32 and keeps the rows whose three values are finite.
    Raises :class:`MissingFieldsError` when x, y or z is absent, ValueError when a field does
    not fit in the point.
    """
    return xyz_indexed_from_packed(data, fields, point_step, width, height, row_step,
                                   big_endian)[0]


def xyz_indexed_from_packed(data: bytes | bytearray | memoryview | np.ndarray,
                            fields: Mapping[str, tuple[int, str]], point_step: int, width: int,
                            height: int = 1, row_step: int | None = None,
                            big_endian: bool = False
                            ) -> tuple[np.ndarray, np.ndarray | None, int]:
    """:func:`xyz_from_packed` with ``(points, index, count)``: ``count`` points in the
    buffer (complete rows), ``index`` the position in the buffer's point order of each kept
    row (None when none was dropped; computed only then, from the same float32 values)."""
    if not all(name in fields for name in XYZ):
        raise MissingFieldsError(sorted(fields))
    order = ">" if big_endian else "<"
    dtypes = [np.dtype(order + fields[name][1]) for name in XYZ]
    for name, dtype in zip(XYZ, dtypes, strict=True):
        if not 0 <= fields[name][0] <= point_step - dtype.itemsize:
            raise ValueError(f"field {name} ({dtype.str} at byte {fields[name][0]}) does not "
                             f"fit in a {point_step}-byte point")
    if height <= 0 or width <= 0 or point_step <= 0:
        return np.empty((0, 3), np.float32), None, 0
    raw = _byte_view(data)
    n_rows, row_step = _complete_rows(raw, point_step, width, height, row_step)
    if n_rows <= 0:
        return np.empty((0, 3), np.float32), None, 0
    x, y, z = (_column(raw, fields[name][0], dtype, (n_rows, width), (row_step, point_step))
               for name, dtype in zip(XYZ, dtypes, strict=True))
    out = np.empty((n_rows * width, 3), np.float32)
    kept = _finite_xyz(x, y, z, out)
    if kept == out.shape[0]:
        return out, None, kept
    finite = np.ones((n_rows, width), bool)
    with np.errstate(over="ignore"):  # a float64 beyond float32's range is inf: dropped
        for column in (x, y, z):
            finite &= np.isfinite(column.astype(np.float32))
    return out[:kept], np.flatnonzero(finite.ravel()), out.shape[0]


#: per-point laser index fields of spinning-lidar drivers (velodyne_pointcloud, ouster-ros,
#: HesaiLidar, rslidar: ``ring``; some converters: ``laser_id``)
RING_FIELDS = ("ring", "laser_id")


def layer_count(data: bytes | bytearray | memoryview | np.ndarray,
                fields: Mapping[str, tuple[int, str]], point_step: int, width: int,
                height: int = 1, row_step: int | None = None,
                big_endian: bool = False) -> tuple[int, str] | None:
    """The scanner's number of layers (beams stacked in elevation) as one cloud shows it, and
    how it was read: ``(max ring + 1, "ring field")`` when the points carry a laser index
    (:data:`RING_FIELDS`), else ``(height, "organised rows")`` for an organised cloud (a
    driver's rows are its rings), else None (an unorganised cloud without a laser index says
    nothing certain about its layers)."""
    name = next((n for n in RING_FIELDS if n in fields), None)
    if name is not None and point_step > 0 and width > 0 and height > 0:
        offset, code = fields[name]
        dtype = np.dtype((">" if big_endian else "<") + code)
        raw = _byte_view(data)
        n_rows, row_step = _complete_rows(raw, point_step, width, height, row_step)
        if 0 <= offset <= point_step - dtype.itemsize and n_rows > 0:
            top = _column(raw, offset, dtype, (n_rows, width), (row_step, point_step)).max()
            if np.isfinite(top) and 0 <= top < 1024:  # a laser index, not another quantity
                return int(top) + 1, f"{name} field"
    if height > 1:
        return int(height), "organised rows"
    return None


def _complete_rows(raw: np.ndarray, point_step: int, width: int, height: int,
                   row_step: int | None) -> tuple[int, int]:
    """``(rows, row_step)``: the complete rows of ``height`` a buffer of ``raw.size`` bytes
    holds (a row padded to ``row_step`` bytes, at least ``width · point_step``)."""
    packed_row = width * point_step
    row_step = max(row_step or packed_row, packed_row)
    return min(height, (raw.size + row_step - packed_row) // row_step), row_step


def _byte_view(data: bytes | bytearray | memoryview | np.ndarray) -> np.ndarray:
    """The buffer as a flat uint8 array, without a copy."""
    if isinstance(data, np.ndarray):
        return data.reshape(-1).view(np.uint8)
    return np.frombuffer(data, dtype=np.uint8)


def _column(raw: np.ndarray, offset: int, dtype: np.dtype, shape: tuple[int, int],
            strides: tuple[int, int]) -> np.ndarray:
    """One field of every point as a (rows, width) strided view of ``raw``; a copy in native
    float32 only for types the kernel is not compiled for (integers, foreign byte order)."""
    view = np.ndarray(shape, dtype=dtype, buffer=raw, offset=offset, strides=strides)
    if dtype.isnative and dtype.kind == "f" and dtype.itemsize in (4, 8):
        return view
    return view.astype(np.float32)


@numba.njit(cache=True, nogil=True)
def _finite_xyz(x: np.ndarray, y: np.ndarray, z: np.ndarray, out: np.ndarray) -> int:
    """Rows (x, y, z) as float32 into ``out`` in point order, skipping a point when any of its
    three float32 values is NaN or ±inf; returns the number of rows written."""
    kept = 0
    for r in range(x.shape[0]):
        for c in range(x.shape[1]):
            px, py, pz = np.float32(x[r, c]), np.float32(y[r, c]), np.float32(z[r, c])
            if math.isfinite(px) and math.isfinite(py) and math.isfinite(pz):
                out[kept, 0] = px
                out[kept, 1] = py
                out[kept, 2] = pz
                kept += 1
    return kept


def ros_fields(fields: list) -> dict[str, tuple[int, str]]:
    """PointField list (objects or dicts with name, offset, datatype, count) -> field table."""
    table = {}
    for field in fields:
        name, offset, datatype = (_attr(field, "name"), _attr(field, "offset"),
                                  _attr(field, "datatype"))
        if datatype in ROS_POINTFIELD_TYPES:
            table[str(name)] = (int(offset), ROS_POINTFIELD_TYPES[int(datatype)])
    return table


def foxglove_fields(fields: list) -> dict[str, tuple[int, str]]:
    """foxglove PackedElementField list (objects or dicts: name, offset, type) -> field table."""
    names = {"UINT8": 1, "INT8": 2, "UINT16": 3, "INT16": 4, "UINT32": 5, "INT32": 6,
             "FLOAT32": 7, "FLOAT64": 8}
    table = {}
    for field in fields:
        numeric = _attr(field, "type")
        if isinstance(numeric, str):
            numeric = names.get(numeric.upper(), 0)
        numeric = int(getattr(numeric, "value", numeric))
        if numeric in FOXGLOVE_NUMERIC_TYPES:
            table[str(_attr(field, "name"))] = (int(_attr(field, "offset")),
                                                FOXGLOVE_NUMERIC_TYPES[numeric])
    return table


def planar_points(ranges: np.ndarray, angles: np.ndarray, range_min: float = 0.0,
                  range_max: float = np.inf) -> np.ndarray:
    """Points (r cos a, r sin a, 0) of a 2-D scan, keeping finite r in [range_min, range_max].

    Returns (N, 3) float32. A range of zero or below is never a return.
    """
    return planar_points_indexed(ranges, angles, range_min, range_max)[0]


def planar_points_indexed(ranges: np.ndarray, angles: np.ndarray, range_min: float = 0.0,
                          range_max: float = np.inf
                          ) -> tuple[np.ndarray, np.ndarray | None, int]:
    """Points (r cos a, r sin a, 0) of a 2-D scan, keeping finite r in [range_min, range_max].

    Returns (N, 3) float32. A range of zero or below is never a return.
    """
    r = np.asarray(ranges, dtype=np.float64)
    a = np.asarray(angles, dtype=np.float64)[: r.size]
    r = r[: a.size]
    keep = np.isfinite(r) & (r > 0.0) & (r >= range_min) & (r <= range_max) & np.isfinite(a)
    index = None if keep.all() else np.flatnonzero(keep)
    r, a = r[keep], a[keep]
    points = np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r)], axis=-1)
    return points.astype(np.float32), index, keep.size


def _attr(obj: object, name: str) -> object:
    return obj[name] if isinstance(obj, Mapping) else getattr(obj, name)
