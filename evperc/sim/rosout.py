"""Writing the simulated drive as a ROS 2 MCAP (CDR, the standard .msg definitions).

Schema text is the message definition followed by every type it uses, each after a line of
80 ``=`` and ``MSG: pkg/Type``, as ``ros2 bag record`` writes it.
"""

from __future__ import annotations

import heapq
import itertools
import math
from pathlib import Path
from typing import Any

import numpy as np
from mcap_ros2.writer import Writer

_SEP = "=" * 80 + "\n"
#: a simulated lidar point as written: little-endian float32 x, y, z, a uint16 ring and a uint8
#: intensity (0-255, as Livox and Ouster drivers' reflectivity), 16 bytes with a pad byte. The
#: order matters to the chunks' zstd: this one compresses and decompresses as the float32
#: intensity of before did; a pad byte before the ring made the run's decode 5 % slower, 20-byte
#: points with a float32 intensity 18 % (docs/evaluation.md § Since 2026-12-07)
POINT_DTYPE = np.dtype({"names": ["x", "y", "z", "ring", "intensity"],
                        "formats": ["<f4", "<f4", "<f4", "<u2", "u1"],
                        "offsets": [0, 4, 8, 12, 14], "itemsize": 16})
#: sensor_msgs/PointField datatypes of :data:`POINT_DTYPE`'s fields
_POINT_DATATYPES = {"x": 7, "y": 7, "z": 7, "ring": 4, "intensity": 2}

_DEFS = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/Pose": "Point position\nQuaternion orientation\n",
    "geometry_msgs/PoseWithCovariance": "Pose pose\nfloat64[36] covariance\n",
    "geometry_msgs/Twist": "Vector3 linear\nVector3 angular\n",
    "geometry_msgs/TwistWithCovariance": "Twist twist\nfloat64[36] covariance\n",
    "geometry_msgs/Transform": "Vector3 translation\nQuaternion rotation\n",
    "geometry_msgs/TransformStamped": "std_msgs/Header header\nstring child_frame_id\n"
                                      "Transform transform\n",
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
    "nav_msgs/Odometry": "std_msgs/Header header\nstring child_frame_id\n"
                         "geometry_msgs/PoseWithCovariance pose\n"
                         "geometry_msgs/TwistWithCovariance twist\n",
    "sensor_msgs/PointField": "uint8 INT8 = 1\nuint8 UINT8 = 2\nuint8 INT16 = 3\n"
                              "uint8 UINT16 = 4\nuint8 INT32 = 5\nuint8 UINT32 = 6\n"
                              "uint8 FLOAT32 = 7\nuint8 FLOAT64 = 8\nstring name\n"
                              "uint32 offset\nuint8 datatype\nuint32 count\n",
    "sensor_msgs/PointCloud2": "std_msgs/Header header\nuint32 height\nuint32 width\n"
                               "PointField[] fields\nbool is_bigendian\nuint32 point_step\n"
                               "uint32 row_step\nuint8[] data\nbool is_dense\n",
    "sensor_msgs/LaserScan": "std_msgs/Header header\nfloat32 angle_min\nfloat32 angle_max\n"
                             "float32 angle_increment\nfloat32 time_increment\n"
                             "float32 scan_time\nfloat32 range_min\nfloat32 range_max\n"
                             "float32[] ranges\nfloat32[] intensities\n",
    "sensor_msgs/NavSatStatus": "int8 STATUS_NO_FIX = -1\nint8 STATUS_FIX = 0\n"
                                "uint16 SERVICE_GPS = 1\nint8 status\nuint16 service\n",
    "sensor_msgs/NavSatFix": "std_msgs/Header header\nNavSatStatus status\nfloat64 latitude\n"
                             "float64 longitude\nfloat64 altitude\n"
                             "float64[9] position_covariance\n"
                             "uint8 COVARIANCE_TYPE_UNKNOWN = 0\n"
                             "uint8 COVARIANCE_TYPE_APPROXIMATED = 1\n"
                             "uint8 COVARIANCE_TYPE_DIAGONAL_KNOWN = 2\n"
                             "uint8 COVARIANCE_TYPE_KNOWN = 3\n"
                             "uint8 position_covariance_type\n",
}

_DEPS = {
    "std_msgs/Header": ["builtin_interfaces/Time"],
    "geometry_msgs/Pose": ["geometry_msgs/Point", "geometry_msgs/Quaternion"],
    "geometry_msgs/PoseWithCovariance": ["geometry_msgs/Pose"],
    "geometry_msgs/Twist": ["geometry_msgs/Vector3"],
    "geometry_msgs/TwistWithCovariance": ["geometry_msgs/Twist"],
    "geometry_msgs/Transform": ["geometry_msgs/Vector3", "geometry_msgs/Quaternion"],
    "geometry_msgs/TransformStamped": ["std_msgs/Header", "geometry_msgs/Transform"],
    "tf2_msgs/TFMessage": ["geometry_msgs/TransformStamped"],
    "nav_msgs/Odometry": ["std_msgs/Header", "geometry_msgs/PoseWithCovariance",
                          "geometry_msgs/TwistWithCovariance"],
    "sensor_msgs/PointCloud2": ["std_msgs/Header", "sensor_msgs/PointField"],
    "sensor_msgs/LaserScan": ["std_msgs/Header"],
    "sensor_msgs/NavSatFix": ["std_msgs/Header", "sensor_msgs/NavSatStatus"],
}


def schema_text(name: str) -> str:
    """Concatenated definition of ``pkg/Type`` and all types it depends on."""
    order: list[str] = []

    def visit(t: str) -> None:
        for dep in _DEPS.get(t, []):
            if dep not in order:
                order.append(dep)
                visit(dep)

    visit(name)
    text = _DEFS[name]
    for dep in order:
        text += _SEP + f"MSG: {dep}\n" + _DEFS[dep]
    return text


def _full(name: str) -> str:
    pkg, typ = name.split("/")
    return f"{pkg}/msg/{typ}"


def stamp(ns: int) -> dict[str, int]:
    return {"sec": int(ns // 1_000_000_000), "nanosec": int(ns % 1_000_000_000)}


def yaw_quaternion(yaw: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}


class DriveWriter:
    """The MCAP of a simulated drive: lidar, odometry, tf, tf_static, GNSS.

    Messages go into the file in log-time order, as a recorder writes them: the pose,
    transform and GNSS messages (all given before the scans) are queued and written
    before the first scan stamped after them, so each chunk holds a scan and the poses
    around it (written first, every pose of the drive would sit in the file's first
    chunks, which a reader then decodes at once before the first scan)."""

    def __init__(self, path: Path) -> None:
        self._file = Path(path).open("wb")
        self._w = Writer(self._file)
        self._schemas: dict[str, Any] = {}
        # (log time, order given, topic, type, message): a heap, earliest first
        self._queued: list[tuple[int, int, str, str, dict[str, Any]]] = []
        self._given = itertools.count()

    def _schema(self, name: str) -> Any:
        if name not in self._schemas:
            self._schemas[name] = self._w.register_msgdef(_full(name), schema_text(name))
        return self._schemas[name]

    def _write(self, topic: str, name: str, msg: dict[str, Any], ns: int) -> None:
        """Queue a message (written by :meth:`_write_queued`)."""
        heapq.heappush(self._queued, (ns, next(self._given), topic, name, msg))

    def _write_queued(self, until_ns: int | None) -> None:
        """Write the queued messages stamped at or before ``until_ns`` (all if None), in
        log-time order (ties in the order they were given)."""
        queued = self._queued
        while queued and (until_ns is None or queued[0][0] <= until_ns):
            ns, _, topic, name, msg = heapq.heappop(queued)
            self._w.write_message(topic, self._schema(name), msg, log_time=ns, publish_time=ns)

    def _write_scan(self, topic: str, name: str, msg: dict[str, Any], ns: int) -> None:
        self._write_queued(ns)
        self._w.write_message(topic, self._schema(name), msg, log_time=ns, publish_time=ns)

    def points(self, ns: int, xyz: np.ndarray, intensity: np.ndarray, ring: np.ndarray,
               topic: str = "/lidar/points", frame_id: str = "lidar") -> None:
        """PointCloud2 of :data:`POINT_DTYPE` points: float32 x, y, z, uint16 ring (each
        point's layer, as a Velodyne or Ouster driver writes it) and uint8 intensity
        (``intensity`` in [0, 1] scaled to 0-255)."""
        data = np.zeros(len(xyz), POINT_DTYPE)
        for i, n in enumerate("xyz"):
            data[n] = xyz[:, i]
        data["intensity"] = np.clip(np.rint(intensity * 255.0), 0, 255)
        data["ring"] = ring
        fields = [{"name": n, "offset": POINT_DTYPE.fields[n][1], "datatype": d, "count": 1}
                  for n, d in _POINT_DATATYPES.items()]
        step = POINT_DTYPE.itemsize
        self._write_scan(topic, "sensor_msgs/PointCloud2", {
            "header": {"stamp": stamp(ns), "frame_id": frame_id}, "height": 1,
            "width": len(data), "fields": fields, "is_bigendian": False, "point_step": step,
            "row_step": step * len(data), "data": data.tobytes(), "is_dense": True}, ns)

    def scan(self, ns: int, angle_min: float, angle_increment: float, ranges: np.ndarray,
             range_min: float, range_max: float, topic: str = "/scan",
             frame_id: str = "lidar") -> None:
        """LaserScan; missing returns are +inf (REP 117)."""
        r = np.where(np.isfinite(ranges), ranges, np.inf).astype(np.float32)
        self._write_scan(topic, "sensor_msgs/LaserScan", {
            "header": {"stamp": stamp(ns), "frame_id": frame_id},
            "angle_min": angle_min, "angle_max": angle_min + angle_increment * (len(r) - 1),
            "angle_increment": angle_increment, "time_increment": 0.0, "scan_time": 0.1,
            "range_min": range_min, "range_max": range_max, "ranges": r.tolist(),
            "intensities": []}, ns)

    def odometry(self, ns: int, x: float, y: float, yaw: float, speed: float) -> None:
        """Odometry of ``base_link`` in ``map`` and the same as a /tf transform."""
        cov = [0.0] * 36
        for i in range(6):
            cov[7 * i] = 1e-3
        q = yaw_quaternion(yaw)
        self._write("/odom", "nav_msgs/Odometry", {
            "header": {"stamp": stamp(ns), "frame_id": "map"}, "child_frame_id": "base_link",
            "pose": {"pose": {"position": {"x": x, "y": y, "z": 0.0}, "orientation": q},
                     "covariance": cov},
            "twist": {"twist": {"linear": {"x": speed, "y": 0.0, "z": 0.0},
                                "angular": {"x": 0.0, "y": 0.0, "z": 0.0}},
                      "covariance": cov}}, ns)
        self._write("/tf", "tf2_msgs/TFMessage", {"transforms": [
            _transform(ns, "map", "base_link", (x, y, 0.0), yaw)]}, ns)

    def static_tf(self, ns: int, xyz: tuple[float, float, float]) -> None:
        """``base_link → lidar`` extrinsic on /tf_static."""
        self._write("/tf_static", "tf2_msgs/TFMessage", {"transforms": [
            _transform(ns, "base_link", "lidar", xyz, 0.0)]}, ns)

    def gnss(self, ns: int, lat: float, lon: float, alt: float, sigma_m: float) -> None:
        var = max(sigma_m, 0.01) ** 2
        self._write("/gnss", "sensor_msgs/NavSatFix", {
            "header": {"stamp": stamp(ns), "frame_id": "base_link"},
            "status": {"status": 0, "service": 1}, "latitude": lat, "longitude": lon,
            "altitude": alt, "position_covariance": [var, 0, 0, 0, var, 0, 0, 0, 4 * var],
            "position_covariance_type": 2}, ns)

    def close(self) -> None:
        self._write_queued(None)
        self._w.finish()
        self._file.close()


def _transform(ns: int, parent: str, child: str, xyz: tuple[float, float, float],
               yaw: float) -> dict[str, Any]:
    return {"header": {"stamp": stamp(ns), "frame_id": parent}, "child_frame_id": child,
            "transform": {"translation": dict(zip("xyz", map(float, xyz), strict=True)),
                          "rotation": yaw_quaternion(yaw)}}
