"""Decoded log messages -> plain records, by schema name.

One small adapter per message type turns a decoded message (a ROS 2, ROS 1 (genpy or rosbags)
or protobuf object, or the dict of a JSON message) into a record evperc uses: a scan (points in
the sensor frame), a pose, a list of frame transforms, or a GNSS fix. Field access works on
objects and dicts alike. ROS 1 messages have the same fields as their ROS 2 counterparts, apart
from the Header's ``seq`` (ignored) and the stamp's ``secs``/``nsecs``; their schema names lack
the ``/msg/`` (``sensor_msgs/PointCloud2``; rosbags spells them the ROS 2 way), and ROS 1's
``tf/tfMessage`` is read like ``tf2_msgs/TFMessage``.

Stamps: the message's own stamp (``header.stamp`` / ``timestamp``) in integer nanoseconds; a
zero stamp (drivers that do not fill it) falls back to the message's log time.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from evperc.logs.mcap_source import json_bytes
from evperc.logs.pointcloud import (
    foxglove_fields,
    layer_count,
    planar_points_indexed,
    ros_fields,
    xyz_indexed_from_packed,
)
from evperc.logs.transforms import pose_matrix

IDENTITY_QUATERNION = (0.0, 0.0, 0.0, 1.0)


@dataclass(frozen=True)
class ScanRecord:
    """Points of one scan in its sensor frame; ``T_frame_sensor`` places the sensor origin in
    ``frame_id`` (foxglove messages carry such an origin ``pose``; identity otherwise)."""

    stamp_ns: int
    frame_id: str
    points: np.ndarray
    planar: bool
    T_frame_sensor: np.ndarray | None = None
    #: points in the message before invalid ones were dropped (None: len(points))
    source_count: int | None = None
    #: index in the message's point order of each row of ``points`` (None: 0..N-1)
    source_index: np.ndarray | None = None


@dataclass(frozen=True)
class PoseRecord:
    """Pose of ``child_frame_id`` (``""`` when the message does not say) in ``frame_id``."""

    stamp_ns: int
    frame_id: str
    child_frame_id: str
    translation: tuple[float, float, float]
    rotation: tuple[float, float, float, float]


@dataclass(frozen=True)
class GnssFix:
    """A GNSS fix: WGS84 latitude, longitude in degrees and altitude in metres."""

    stamp_ns: int
    lat_deg: float
    lon_deg: float
    alt_m: float
    frame_id: str = ""


# --- field access -------------------------------------------------------------------------

def get(msg: Any, name: str, default: Any = None) -> Any:
    """Field ``name`` of a decoded message (object attribute or dict key)."""
    if msg is None:
        return default
    if isinstance(msg, Mapping):
        value = msg.get(name, default)
    else:
        value = getattr(msg, name, default)
    return default if value is None else value


def stamp_of(stamp: Any, log_time_ns: int) -> int:
    """Integer ns of a ROS 2 Time (sec, nanosec), ROS 1 time (secs, nsecs), protobuf Timestamp
    (seconds, nanos) or JSON time (sec, nsec); ``log_time_ns`` when absent or zero."""
    if stamp is None:
        return log_time_ns
    sec = get(stamp, "sec", get(stamp, "secs", get(stamp, "seconds", 0)))
    nsec = get(stamp, "nanosec", get(stamp, "nsecs", get(stamp, "nsec", get(stamp, "nanos", 0))))
    value = int(sec) * 1_000_000_000 + int(nsec)
    return value if value != 0 else log_time_ns


def vector3(msg: Any) -> tuple[float, float, float]:
    return (float(get(msg, "x", 0.0)), float(get(msg, "y", 0.0)), float(get(msg, "z", 0.0)))


def quaternion(msg: Any) -> tuple[float, float, float, float]:
    if msg is None:
        return IDENTITY_QUATERNION
    return (float(get(msg, "x", 0.0)), float(get(msg, "y", 0.0)), float(get(msg, "z", 0.0)),
            float(get(msg, "w", 0.0)))


def _bytes(value: Any) -> bytes | np.ndarray:
    if isinstance(value, bytes | bytearray | memoryview | np.ndarray):
        return value
    if isinstance(value, str):
        return json_bytes(value)
    return np.asarray(value, dtype=np.uint8)


def _pose_matrix(pose: Any) -> np.ndarray | None:
    """4×4 of a foxglove ``pose`` field, or None when it is absent or the identity."""
    if pose is None:
        return None
    T = pose_matrix(vector3(get(pose, "position")), quaternion(get(pose, "orientation")))
    return None if np.allclose(T, np.eye(4)) else T


# --- lidar --------------------------------------------------------------------------------

def ros_pointcloud2(msg: Any, log_time_ns: int) -> ScanRecord:
    header = get(msg, "header")
    points, index, count = xyz_indexed_from_packed(
        _bytes(get(msg, "data", b"")), ros_fields(get(msg, "fields", [])),
        point_step=int(get(msg, "point_step", 0)), width=int(get(msg, "width", 0)),
        height=int(get(msg, "height", 1)), row_step=int(get(msg, "row_step", 0)),
        big_endian=bool(get(msg, "is_bigendian", False)))
    return ScanRecord(stamp_of(get(header, "stamp"), log_time_ns), str(get(header, "frame_id", "")),
                      points, planar=False, source_count=count, source_index=index)


def ros_pointcloud2_layers(msg: Any) -> tuple[int, str] | None:
    """The scanner's layers as a PointCloud2 shows them (:func:`layer_count`)."""
    return layer_count(_bytes(get(msg, "data", b"")), ros_fields(get(msg, "fields", [])),
                       point_step=int(get(msg, "point_step", 0)),
                       width=int(get(msg, "width", 0)), height=int(get(msg, "height", 1)),
                       row_step=int(get(msg, "row_step", 0)),
                       big_endian=bool(get(msg, "is_bigendian", False)))


def ros_laserscan(msg: Any, log_time_ns: int) -> ScanRecord:
    header = get(msg, "header")
    ranges = np.asarray(get(msg, "ranges", []), dtype=np.float64)
    angles = float(get(msg, "angle_min", 0.0)) + float(
        get(msg, "angle_increment", 0.0)) * np.arange(ranges.size)
    points, index, count = planar_points_indexed(ranges, angles,
                                                 float(get(msg, "range_min", 0.0)),
                                                 float(get(msg, "range_max", np.inf)))
    return ScanRecord(stamp_of(get(header, "stamp"), log_time_ns), str(get(header, "frame_id", "")),
                      points, planar=True, source_count=count, source_index=index)


def _foxglove_packed(msg: Any) -> tuple[bytes | np.ndarray, int, int]:
    """``(data, point_stride, points)`` of a foxglove PointCloud (one row of points)."""
    data = _bytes(get(msg, "data", b""))
    stride = int(get(msg, "point_stride", 0))
    n = (len(data) if not isinstance(data, np.ndarray) else data.size) // stride if stride else 0
    return data, stride, n


def foxglove_pointcloud(msg: Any, log_time_ns: int) -> ScanRecord:
    data, stride, n = _foxglove_packed(msg)
    points, index, count = xyz_indexed_from_packed(
        data, foxglove_fields(get(msg, "fields", [])), point_step=stride, width=n)
    return ScanRecord(stamp_of(get(msg, "timestamp"), log_time_ns), str(get(msg, "frame_id", "")),
                      points, planar=False, T_frame_sensor=_pose_matrix(get(msg, "pose")),
                      source_count=count, source_index=index)


def foxglove_pointcloud_layers(msg: Any) -> tuple[int, str] | None:
    """The scanner's layers as a foxglove PointCloud shows them (a laser index field only:
    the message has no rows)."""
    data, stride, n = _foxglove_packed(msg)
    return layer_count(data, foxglove_fields(get(msg, "fields", [])), point_step=stride,
                       width=n)


def foxglove_laserscan(msg: Any, log_time_ns: int) -> ScanRecord:
    ranges = np.asarray(get(msg, "ranges", []), dtype=np.float64)
    start, end = float(get(msg, "start_angle", 0.0)), float(get(msg, "end_angle", 0.0))
    angles = np.linspace(start, end, ranges.size) if ranges.size > 1 else np.full(ranges.size,
                                                                                   start)
    points, index, count = planar_points_indexed(ranges, angles)
    return ScanRecord(stamp_of(get(msg, "timestamp"), log_time_ns), str(get(msg, "frame_id", "")),
                      points, planar=True, T_frame_sensor=_pose_matrix(get(msg, "pose")),
                      source_count=count, source_index=index)


# --- poses --------------------------------------------------------------------------------

def ros_odometry(msg: Any, log_time_ns: int) -> PoseRecord:
    header = get(msg, "header")
    pose = get(get(msg, "pose"), "pose")
    return PoseRecord(stamp_of(get(header, "stamp"), log_time_ns), str(get(header, "frame_id", "")),
                      str(get(msg, "child_frame_id", "")), vector3(get(pose, "position")),
                      quaternion(get(pose, "orientation")))


def ros_pose_stamped(msg: Any, log_time_ns: int) -> PoseRecord:
    header = get(msg, "header")
    pose = get(msg, "pose")
    if get(pose, "pose") is not None:  # PoseWithCovarianceStamped: pose.pose
        pose = get(pose, "pose")
    return PoseRecord(stamp_of(get(header, "stamp"), log_time_ns), str(get(header, "frame_id", "")),
                      "", vector3(get(pose, "position")), quaternion(get(pose, "orientation")))


def foxglove_pose(msg: Any, log_time_ns: int) -> PoseRecord:
    pose = get(msg, "pose")
    return PoseRecord(stamp_of(get(msg, "timestamp"), log_time_ns), str(get(msg, "frame_id", "")),
                      str(get(msg, "body_frame_id", "")), vector3(get(pose, "position")),
                      quaternion(get(pose, "orientation")))


def ros_tf(msg: Any, log_time_ns: int) -> list[PoseRecord]:
    out = []
    for ts in get(msg, "transforms", []):
        header, transform = get(ts, "header"), get(ts, "transform")
        out.append(PoseRecord(stamp_of(get(header, "stamp"), log_time_ns),
                              str(get(header, "frame_id", "")), str(get(ts, "child_frame_id", "")),
                              vector3(get(transform, "translation")),
                              quaternion(get(transform, "rotation"))))
    return out


def foxglove_frame_transform(msg: Any, log_time_ns: int) -> list[PoseRecord]:
    return [PoseRecord(stamp_of(get(msg, "timestamp"), log_time_ns),
                       str(get(msg, "parent_frame_id", "")), str(get(msg, "child_frame_id", "")),
                       vector3(get(msg, "translation")), quaternion(get(msg, "rotation")))]


def foxglove_frame_transforms(msg: Any, log_time_ns: int) -> list[PoseRecord]:
    return [r for t in get(msg, "transforms", []) for r in foxglove_frame_transform(t, log_time_ns)]


# --- GNSS ---------------------------------------------------------------------------------

def ros_navsatfix(msg: Any, log_time_ns: int) -> GnssFix | None:
    """None when the receiver reports no fix (status −1) or the position is not finite."""
    if int(get(get(msg, "status"), "status", 0)) < 0:
        return None
    header = get(msg, "header")
    return _fix(stamp_of(get(header, "stamp"), log_time_ns), msg,
                str(get(header, "frame_id", "")))


def foxglove_location_fix(msg: Any, log_time_ns: int) -> GnssFix | None:
    return _fix(stamp_of(get(msg, "timestamp"), log_time_ns), msg,
                str(get(msg, "frame_id", "")))


def _fix(stamp_ns: int, msg: Any, frame_id: str) -> GnssFix | None:
    lat, lon, alt = (float(get(msg, k, np.nan)) for k in ("latitude", "longitude", "altitude"))
    if not (np.isfinite(lat) and np.isfinite(lon)):
        return None
    return GnssFix(stamp_ns, lat, lon, alt if np.isfinite(alt) else 0.0, frame_id)


# --- schema tables ------------------------------------------------------------------------

LIDAR_ADAPTERS: dict[str, Callable[[Any, int], ScanRecord]] = {
    "sensor_msgs/msg/PointCloud2": ros_pointcloud2,
    "sensor_msgs/msg/LaserScan": ros_laserscan,
    "foxglove.PointCloud": foxglove_pointcloud,
    "foxglove.LaserScan": foxglove_laserscan,
}
#: the scanner's layers from one lidar message (:func:`evperc.logs.pointcloud.layer_count`);
#: a 2-D LaserScan has one
LAYER_ADAPTERS: dict[str, Callable[[Any], tuple[int, str] | None]] = {
    "sensor_msgs/msg/PointCloud2": ros_pointcloud2_layers,
    "sensor_msgs/msg/LaserScan": lambda msg: (1, "a 2-D scan"),
    "foxglove.PointCloud": foxglove_pointcloud_layers,
    "foxglove.LaserScan": lambda msg: (1, "a 2-D scan"),
}
POSE_ADAPTERS: dict[str, Callable[[Any, int], PoseRecord]] = {
    "nav_msgs/msg/Odometry": ros_odometry,
    "geometry_msgs/msg/PoseStamped": ros_pose_stamped,
    "geometry_msgs/msg/PoseWithCovarianceStamped": ros_pose_stamped,
    "foxglove.PoseInFrame": foxglove_pose,
    "foxglove.Odometry": foxglove_pose,
}
TF_ADAPTERS: dict[str, Callable[[Any, int], list[PoseRecord]]] = {
    "tf2_msgs/msg/TFMessage": ros_tf,
    "foxglove.FrameTransform": foxglove_frame_transform,
    "foxglove.FrameTransforms": foxglove_frame_transforms,
}
GNSS_ADAPTERS: dict[str, Callable[[Any, int], GnssFix | None]] = {
    "sensor_msgs/msg/NavSatFix": ros_navsatfix,
    "foxglove.LocationFix": foxglove_location_fix,
}


def _add_ros1_names(table: dict[str, Any]) -> None:
    """ROS 1 schema names (``pkg/Type``) next to each ROS 2 one (``pkg/msg/Type``)."""
    for name, adapter in list(table.items()):
        if "/msg/" in name:
            table.setdefault(name.replace("/msg/", "/"), adapter)


for _table in (LIDAR_ADAPTERS, LAYER_ADAPTERS, POSE_ADAPTERS, TF_ADAPTERS, GNSS_ADAPTERS):
    _add_ros1_names(_table)
#: ROS 1's tf (before tf2) on /tf: the same fields as tf2_msgs/TFMessage
TF_ADAPTERS["tf/tfMessage"] = TF_ADAPTERS["tf/msg/tfMessage"] = ros_tf


def schema_list(table: dict[str, Any]) -> str:
    """The schema names of an adapter table for a message: the ROS 2 and foxglove ones, the
    ROS 1 spellings summarised."""
    names = [n for n in table if "/msg/" in n or "/" not in n]
    return ", ".join(names) + " (and their ROS 1 names, without /msg/)"


def is_static_tf_topic(topic: str) -> bool:
    """Transforms on ``/tf_static`` (or any topic ending in ``tf_static``) hold for all time."""
    return topic.rstrip("/").endswith("tf_static")
