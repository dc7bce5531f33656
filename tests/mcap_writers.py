"""Small MCAP logs written with third-party writers, for tests.

Each writer takes plain numpy data (points in the sensor frame, 4×4 poses ``T_parent_child``,
stamps in integer ns) and produces a log the way a real recorder would:

- :func:`write_ros2_mcap` — mcap-ros2-support's writer (ROS 2 CDR), the most general one;
- :func:`write_rosbags_mcap` — a ROS 2 bag with rosbags' MCAP storage plugin;
- :func:`write_foxglove_mcap` — foxglove-sdk (protobuf-encoded foxglove schemas);
- :func:`write_json_mcap` — mcap's own writer with JSON-encoded foxglove schemas;
- :func:`write_kitti_odometry_mcap` — a KITTI odometry folder (velodyne bins, poses, calib,
  times) as ROS 2 MCAP: PointCloud2 in ``velodyne``, Odometry (or /tf) ``map -> base_link``,
  /tf_static ``base_link -> velodyne``;
- :func:`write_kitti_raw_folder` — a tiny synthetic KITTI *raw* drive for the kitti2mcap tool.

Rotations are converted to quaternions here with an eigenvector method (Bar-Itzhack 2000),
independently of evperc's own quaternion code.
"""

from __future__ import annotations

import base64
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

Cloud = tuple[int, np.ndarray, str]            # (stamp_ns, points (N, 3 or 4), frame_id)
StampedPose = tuple[int, np.ndarray]           # (stamp_ns, T_parent_child 4×4)
StampedTransform = tuple[int, str, str, np.ndarray]   # (stamp_ns, parent, child, T)
StaticTransform = tuple[str, str, np.ndarray]  # (parent, child, T)
Fix = tuple[int, float, float, float]          # (stamp_ns, lat_deg, lon_deg, alt_m)

#: PointCloud2 layouts: name -> (point_step, [(field, offset, PointField datatype)])
LAYOUTS = {
    "xyzi16": (16, [("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 12, 7)]),
    # Velodyne driver style: x y z pad intensity ring pad time, 32 bytes
    "padded32": (32, [("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 16, 7),
                      ("ring", 20, 4), ("time", 24, 7)]),
    "xyz_f64": (32, [("x", 0, 8), ("y", 8, 8), ("z", 16, 8), ("intensity", 24, 7)]),
    "no_xyz": (12, [("range", 0, 7), ("azimuth", 4, 7), ("intensity", 8, 7)]),
}
_NP = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


# --- maths independent of evperc ----------------------------------------------------------

def quaternion_xyzw(R: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w) of rotation ``R``: the eigenvector of Bar-Itzhack's
    symmetric 4×4 K matrix with the largest eigenvalue (robust to slightly non-orthonormal R)."""
    R = np.asarray(R, dtype=np.float64)[:3, :3]
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = R
    K = np.array([
        [m00 - m11 - m22, 0.0, 0.0, 0.0],
        [m01 + m10, m11 - m00 - m22, 0.0, 0.0],
        [m02 + m20, m12 + m21, m22 - m00 - m11, 0.0],
        [m21 - m12, m02 - m20, m10 - m01, m00 + m11 + m22]]) / 3.0
    w, v = np.linalg.eigh(K, UPLO="L")
    q = v[:, np.argmax(w)]
    q = q if q[3] >= 0 else -q
    return tuple(float(c) for c in q)


def rotation_z(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def transform(x: float = 0.0, y: float = 0.0, z: float = 0.0, yaw: float = 0.0,
              roll: float = 0.0) -> np.ndarray:
    """T = Trans(x, y, z) · Rz(yaw) · Rx(roll)."""
    c, s = np.cos(roll), np.sin(roll)
    Rx = np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])
    T = rotation_z(yaw) @ Rx
    T[:3, 3] = (x, y, z)
    return T


def packed_cloud(points: np.ndarray, layout: str = "xyzi16", big_endian: bool = False
                 ) -> tuple[bytes, int, list[tuple[str, int, int]]]:
    """(data, point_step, fields) of ``points`` (N, 3 or 4) in a PointCloud2 layout."""
    step, fields = LAYOUTS[layout]
    order = ">" if big_endian else "<"
    dtype = np.dtype({"names": [f[0] for f in fields],
                      "formats": [order + _NP[f[2]] for f in fields],
                      "offsets": [f[1] for f in fields], "itemsize": step})
    arr = np.zeros(len(points), dtype=dtype)
    pts = np.asarray(points, dtype=np.float64)
    names = [f[0] for f in fields]
    for i, name in enumerate(("x", "y", "z")):
        if name in names:
            arr[name] = pts[:, i]
    if "range" in names:
        arr["range"] = np.linalg.norm(pts[:, :3], axis=1)
    if "intensity" in names:
        arr["intensity"] = pts[:, 3] if pts.shape[1] > 3 else 0.5
    if "ring" in names:
        arr["ring"] = np.arange(len(points)) % 16
    if "time" in names:
        arr["time"] = np.linspace(0.0, 0.1, len(points))
    return arr.tobytes(), step, fields


# --- ROS 2 message dicts (mcap-ros2-support takes dicts) ----------------------------------

def _stamp(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def _header(ns: int, frame: str) -> dict:
    return {"stamp": _stamp(ns), "frame_id": frame}


def _pose(T: np.ndarray) -> dict:
    x, y, z, w = quaternion_xyzw(T)
    return {"position": {"x": float(T[0, 3]), "y": float(T[1, 3]), "z": float(T[2, 3])},
            "orientation": {"x": x, "y": y, "z": z, "w": w}}


def _transform(T: np.ndarray) -> dict:
    x, y, z, w = quaternion_xyzw(T)
    return {"translation": {"x": float(T[0, 3]), "y": float(T[1, 3]), "z": float(T[2, 3])},
            "rotation": {"x": x, "y": y, "z": z, "w": w}}


def _tf_message(items: Sequence[StampedTransform]) -> dict:
    return {"transforms": [{"header": _header(ns, parent), "child_frame_id": child,
                            "transform": _transform(T)} for ns, parent, child, T in items]}


def pointcloud2_dict(stamp_ns: int, points: np.ndarray, frame: str, layout: str = "xyzi16",
                     big_endian: bool = False) -> dict:
    data, step, fields = packed_cloud(points, layout, big_endian)
    return {"header": _header(stamp_ns, frame), "height": 1, "width": len(points),
            "fields": [{"name": n, "offset": o, "datatype": d, "count": 1} for n, o, d in fields],
            "is_bigendian": big_endian, "point_step": step, "row_step": step * len(points),
            "data": data, "is_dense": False}


def ros2_msgdef(typename: str) -> str:
    """ROS 2 message definition text (with dependencies) from rosbags' bundled Humble types."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE).generate_msgdef(typename, ros_version=2)[0]


def write_ros2_mcap(path: str | Path, *, clouds: Sequence[Cloud] = (),
                    cloud_topic: str = "/points", layout: str = "xyzi16",
                    big_endian: bool = False,
                    laserscans: Sequence[tuple[int, np.ndarray, float, float, str]] = (),
                    scan_topic: str = "/scan", scan_range: tuple[float, float] = (0.1, 30.0),
                    odometry: Sequence[StampedPose] = (), odom_topic: str = "/odom",
                    odom_frames: tuple[str, str] = ("map", "base_link"),
                    pose_stamped: Sequence[StampedPose] = (), pose_topic: str = "/pose",
                    pose_frame: str = "map", pose_covariance: bool = False,
                    tf: Sequence[StampedTransform] = (),
                    tf_static: Sequence[StaticTransform] = (), fixes: Sequence[Fix] = (),
                    fix_topic: str = "/fix", extra_cloud_topics: Sequence[str] = (),
                    chunk_size: int = 1024 * 1024, compression: str = "zstd",
                    poses_first: bool = False) -> Path:
    """A ROS 2 MCAP written with mcap-ros2-support. Messages are logged at their stamps
    (a cloud may carry a 4th item, its log time, to log it late); chunks ``compression``
    "zstd", "lz4" or "none". Messages go into the file in log-time order, or with
    ``poses_first`` all other messages (poses, TF, fixes) before the lidar's (as the bundled
    sample drive has them: the poses' chunks first, then the scans').

    ``laserscans`` items are (stamp_ns, ranges, angle_min, angle_increment, frame_id).
    ``extra_cloud_topics`` repeat every cloud on more topics (for ambiguity tests).
    ``pose_covariance`` writes ``pose_stamped`` as PoseWithCovarianceStamped.
    """
    from mcap_ros2.writer import Writer

    path = Path(path)
    messages: list[tuple[int, str, str, dict]] = []
    for ns, pts, frame, *log_time in clouds:
        msg = pointcloud2_dict(ns, pts, frame, layout, big_endian)
        for topic in (cloud_topic, *extra_cloud_topics):
            messages.append(((log_time or [ns])[0], topic, "sensor_msgs/msg/PointCloud2", msg))
    for ns, ranges, a0, da, frame in laserscans:
        messages.append((ns, scan_topic, "sensor_msgs/msg/LaserScan", {
            "header": _header(ns, frame), "angle_min": a0, "angle_max": a0 + da * (len(ranges) - 1),
            "angle_increment": da, "time_increment": 0.0, "scan_time": 0.1,
            "range_min": scan_range[0], "range_max": scan_range[1],
            "ranges": [float(r) for r in ranges], "intensities": []}))
    parent, child = odom_frames
    for ns, T in odometry:
        messages.append((ns, odom_topic, "nav_msgs/msg/Odometry", {
            "header": _header(ns, parent), "child_frame_id": child,
            "pose": {"pose": _pose(T), "covariance": [0.0] * 36},
            "twist": {"twist": {"linear": {"x": 0.0, "y": 0.0, "z": 0.0},
                                "angular": {"x": 0.0, "y": 0.0, "z": 0.0}},
                      "covariance": [0.0] * 36}}))
    for ns, T in pose_stamped:
        if pose_covariance:
            messages.append((ns, pose_topic, "geometry_msgs/msg/PoseWithCovarianceStamped",
                             {"header": _header(ns, pose_frame),
                              "pose": {"pose": _pose(T), "covariance": [0.01] * 36}}))
        else:
            messages.append((ns, pose_topic, "geometry_msgs/msg/PoseStamped",
                             {"header": _header(ns, pose_frame), "pose": _pose(T)}))
    for item in tf:
        messages.append((item[0], "/tf", "tf2_msgs/msg/TFMessage", _tf_message([item])))
    if tf_static:
        t0 = min([m[0] for m in messages] or [0])
        messages.append((t0, "/tf_static", "tf2_msgs/msg/TFMessage",
                         _tf_message([(t0, p, c, T) for p, c, T in tf_static])))
    for ns, lat, lon, alt in fixes:
        messages.append((ns, fix_topic, "sensor_msgs/msg/NavSatFix", {
            "header": _header(ns, "gps"), "status": {"status": 0, "service": 1},
            "latitude": lat, "longitude": lon, "altitude": alt,
            "position_covariance": [0.0] * 9, "position_covariance_type": 0}))
    lidar_types = ("sensor_msgs/msg/PointCloud2", "sensor_msgs/msg/LaserScan")
    messages.sort(key=lambda m: (poses_first and m[2] in lidar_types, m[0]))
    with path.open("wb") as f:
        from mcap.writer import CompressionType

        writer = Writer(f, chunk_size=chunk_size,
                        compression=CompressionType[compression.upper()])
        schemas = {}
        for ns, topic, typename, msg in messages:
            if typename not in schemas:
                schemas[typename] = writer.register_msgdef(typename, ros2_msgdef(typename))
            writer.write_message(topic=topic, schema=schemas[typename], message=msg,
                                 log_time=ns, publish_time=ns)
        writer.finish()
    return path


# --- rosbags ------------------------------------------------------------------------------

def write_rosbags_mcap(bag_dir: str | Path, *, clouds: Sequence[Cloud],
                       odometry: Sequence[StampedPose] = (),
                       odom_frames: tuple[str, str] = ("odom", "base_link"),
                       tf: Sequence[StampedTransform] = (),
                       tf_static: Sequence[StaticTransform] = (),
                       layout: str = "padded32") -> Path:
    """A ROS 2 bag (rosbags, MCAP storage plugin); returns the path of its .mcap file."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    t = ts.types
    Time, Header = t["builtin_interfaces/msg/Time"], t["std_msgs/msg/Header"]
    Vector3, Quaternion = t["geometry_msgs/msg/Vector3"], t["geometry_msgs/msg/Quaternion"]
    Point, Pose = t["geometry_msgs/msg/Point"], t["geometry_msgs/msg/Pose"]

    def header(ns: int, frame: str):
        return Header(stamp=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000),
                      frame_id=frame)

    def quat(T):
        x, y, z, w = quaternion_xyzw(T)
        return Quaternion(x=x, y=y, z=z, w=w)

    def tf_msg(items):
        return t["tf2_msgs/msg/TFMessage"](transforms=[t["geometry_msgs/msg/TransformStamped"](
            header=header(ns, parent), child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=Vector3(x=T[0, 3], y=T[1, 3], z=T[2, 3]), rotation=quat(T)))
            for ns, parent, child, T in items])

    messages = []
    for ns, pts, frame in clouds:
        data, step, fields = packed_cloud(pts, layout)
        messages.append((ns, "/velodyne_points", "sensor_msgs/msg/PointCloud2",
                         t["sensor_msgs/msg/PointCloud2"](
                             header=header(ns, frame), height=1, width=len(pts),
                             fields=[t["sensor_msgs/msg/PointField"](name=n, offset=o, datatype=d,
                                                                     count=1)
                                     for n, o, d in fields],
                             is_bigendian=False, point_step=step, row_step=step * len(pts),
                             data=np.frombuffer(data, np.uint8), is_dense=True)))
    zero = Vector3(x=0.0, y=0.0, z=0.0)
    for ns, T in odometry:
        pose = Pose(position=Point(x=T[0, 3], y=T[1, 3], z=T[2, 3]), orientation=quat(T))
        messages.append((ns, "/odom", "nav_msgs/msg/Odometry", t["nav_msgs/msg/Odometry"](
            header=header(ns, odom_frames[0]), child_frame_id=odom_frames[1],
            pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=t["geometry_msgs/msg/Twist"](linear=zero, angular=zero),
                covariance=np.zeros(36)))))
    for item in tf:
        messages.append((item[0], "/tf", "tf2_msgs/msg/TFMessage", tf_msg([item])))
    t0 = min(m[0] for m in messages)
    if tf_static:
        messages.append((t0, "/tf_static", "tf2_msgs/msg/TFMessage",
                         tf_msg([(t0, p, c, T) for p, c, T in tf_static])))
    messages.sort(key=lambda m: m[0])
    bag_dir = Path(bag_dir)
    with Writer(bag_dir, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {}
        for ns, topic, typename, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, typename, typestore=ts)
            writer.write(connections[topic], ns, ts.serialize_cdr(msg, typename))
    (mcap_path,) = sorted(bag_dir.glob("*.mcap"))
    return mcap_path


# --- foxglove-sdk (protobuf) --------------------------------------------------------------

def write_foxglove_mcap(path: str | Path, *, clouds: Sequence[Cloud] = (),
                        poses: Sequence[StampedPose] = (), pose_frame: str = "world",
                        frame_transforms: Sequence[StampedTransform] = (),
                        static_transforms: Sequence[StaticTransform] = (),
                        fixes: Sequence[Fix] = (),
                        cloud_pose: np.ndarray | None = None) -> Path:
    """foxglove-sdk MCAP: /lidar PointCloud, /pose PoseInFrame, /tf FrameTransforms,
    /tf_static FrameTransforms (logged once at the first stamp), /gps LocationFix."""
    import foxglove
    from foxglove import channels as ch
    from foxglove import messages as fm

    def ts(ns: int):
        return fm.Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)

    def fpose(T):
        x, y, z, w = quaternion_xyzw(T)
        return fm.Pose(position=fm.Vector3(x=T[0, 3], y=T[1, 3], z=T[2, 3]),
                       orientation=fm.Quaternion(x=x, y=y, z=z, w=w))

    def ftransform(ns, parent, child, T):
        x, y, z, w = quaternion_xyzw(T)
        return fm.FrameTransform(timestamp=ts(ns), parent_frame_id=parent, child_frame_id=child,
                                 translation=fm.Vector3(x=T[0, 3], y=T[1, 3], z=T[2, 3]),
                                 rotation=fm.Quaternion(x=x, y=y, z=z, w=w))

    path = Path(path)
    context = foxglove.Context()
    events = []
    lidar = ch.PointCloudChannel("/lidar", context=context)
    f32 = fm.PackedElementFieldNumericType.Float32
    for ns, pts, frame in clouds:
        data = np.ascontiguousarray(np.asarray(pts)[:, :3], dtype="<f4").tobytes()
        fields = [fm.PackedElementField(name=n, offset=4 * i, type=f32)
                  for i, n in enumerate("xyz")]
        msg = fm.PointCloud(timestamp=ts(ns), frame_id=frame, point_stride=12, fields=fields,
                            data=data, pose=fpose(np.eye(4) if cloud_pose is None else cloud_pose))
        events.append((ns, lidar, msg))
    if poses:
        pose_ch = ch.PoseInFrameChannel("/pose", context=context)
        events += [(ns, pose_ch, fm.PoseInFrame(timestamp=ts(ns), frame_id=pose_frame,
                                                pose=fpose(T))) for ns, T in poses]
    if frame_transforms:
        tf_ch = ch.FrameTransformsChannel("/tf", context=context)
        events += [(item[0], tf_ch, fm.FrameTransforms(transforms=[ftransform(*item)]))
                   for item in frame_transforms]
    t0 = min(e[0] for e in events)
    if static_transforms:
        static_ch = ch.FrameTransformsChannel("/tf_static", context=context)
        events.append((t0, static_ch, fm.FrameTransforms(
            transforms=[ftransform(t0, p, c, T) for p, c, T in static_transforms])))
    if fixes:
        gps = ch.LocationFixChannel("/gps", context=context)
        events += [(ns, gps, fm.LocationFix(timestamp=ts(ns), frame_id="gps", latitude=lat,
                                            longitude=lon, altitude=alt))
                   for ns, lat, lon, alt in fixes]
    events.sort(key=lambda e: e[0])
    with foxglove.open_mcap(path, allow_overwrite=True, context=context):
        for ns, channel, msg in events:
            channel.log(msg, log_time=ns)
    return path


# --- mcap's own writer, JSON encoding -----------------------------------------------------

#: minimal JSON schemas (the reader needs only the schema *name*)
_JSON_SCHEMAS = {
    "foxglove.PointCloud": {"type": "object", "properties": {
        "timestamp": {"type": "object"}, "frame_id": {"type": "string"},
        "pose": {"type": "object"}, "point_stride": {"type": "integer"},
        "fields": {"type": "array"}, "data": {"type": "string", "contentEncoding": "base64"}}},
    "foxglove.LaserScan": {"type": "object"},
    "foxglove.PoseInFrame": {"type": "object"},
    "foxglove.FrameTransform": {"type": "object"},
    "foxglove.LocationFix": {"type": "object"},
}


def write_json_mcap(path: str | Path, *, clouds: Sequence[Cloud] = (),
                    laserscans: Sequence[tuple[int, np.ndarray, float, float, str]] = (),
                    poses: Sequence[StampedPose] = (), pose_frame: str = "world",
                    frame_transforms: Sequence[StampedTransform] = (),
                    fixes: Sequence[Fix] = (), use_index: bool = True,
                    double_xyz: bool = False) -> Path:
    """mcap.writer.Writer, JSON messages with foxglove schemas: /lidar PointCloud (or /scan
    LaserScan items (stamp_ns, ranges, start_angle, end_angle, frame)), /pose PoseInFrame,
    /tf FrameTransform, /gps LocationFix. ``use_index=False`` writes no summary/index."""
    from mcap.writer import IndexType, Writer

    def ts(ns: int) -> dict:
        return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}

    def vec(T) -> dict:
        return {"x": float(T[0, 3]), "y": float(T[1, 3]), "z": float(T[2, 3])}

    def quat(T) -> dict:
        return dict(zip("xyzw", quaternion_xyzw(T), strict=True))

    events: list[tuple[int, str, str, dict]] = []
    for ns, pts, frame in clouds:
        kind = "<f8" if double_xyz else "<f4"
        size = 8 if double_xyz else 4
        data = np.ascontiguousarray(np.asarray(pts)[:, :3], dtype=kind).tobytes()
        events.append((ns, "/lidar", "foxglove.PointCloud", {
            "timestamp": ts(ns), "frame_id": frame,
            "pose": {"position": {"x": 0, "y": 0, "z": 0},
                     "orientation": {"x": 0, "y": 0, "z": 0, "w": 1}},
            "point_stride": 3 * size,
            "fields": [{"name": n, "offset": size * i, "type": 8 if double_xyz else 7}
                       for i, n in enumerate("xyz")],
            "data": base64.b64encode(data).decode()}))
    for ns, ranges, a0, a1, frame in laserscans:
        events.append((ns, "/scan", "foxglove.LaserScan", {
            "timestamp": ts(ns), "frame_id": frame, "start_angle": a0, "end_angle": a1,
            "ranges": [float(r) if np.isfinite(r) else None for r in ranges],
            "intensities": []}))
    for ns, T in poses:
        events.append((ns, "/pose", "foxglove.PoseInFrame", {
            "timestamp": ts(ns), "frame_id": pose_frame,
            "pose": {"position": vec(T), "orientation": quat(T)}}))
    for ns, parent, child, T in frame_transforms:
        events.append((ns, "/tf", "foxglove.FrameTransform", {
            "timestamp": ts(ns), "parent_frame_id": parent, "child_frame_id": child,
            "translation": vec(T), "rotation": quat(T)}))
    for ns, lat, lon, alt in fixes:
        events.append((ns, "/gps", "foxglove.LocationFix", {
            "timestamp": ts(ns), "frame_id": "gps", "latitude": lat, "longitude": lon,
            "altitude": alt}))
    events.sort(key=lambda e: e[0])
    path = Path(path)
    with path.open("wb") as f:
        if use_index:
            writer = Writer(f, chunk_size=4096)
        else:
            writer = Writer(f, index_types=IndexType.NONE, repeat_channels=False,
                            repeat_schemas=False, use_statistics=False,
                            use_summary_offsets=False)
        writer.start(profile="", library="tests")
        schema_ids, channel_ids = {}, {}
        for ns, topic, schema, msg in events:
            if schema not in schema_ids:
                schema_ids[schema] = writer.register_schema(
                    name=schema, encoding="jsonschema",
                    data=json.dumps(_JSON_SCHEMAS[schema]).encode())
            if topic not in channel_ids:
                channel_ids[topic] = writer.register_channel(
                    topic=topic, message_encoding="json", schema_id=schema_ids[schema])
            writer.add_message(channel_id=channel_ids[topic], log_time=ns, publish_time=ns,
                               data=json.dumps(msg).encode())
        writer.finish()
    return path


# --- KITTI --------------------------------------------------------------------------------

KITTI_BASE_NS = 1_317_646_000_000_000_000   # 2011-10-03, the day sequence 00 was recorded
KITTI_LIDAR_HEIGHT_M = 1.73


def read_kitti_odometry(kitti_dir: str | Path, n_scans: int) -> dict:
    """times (s), P_cam0 (n, 4, 4), Tr (4, 4, lidar -> cam0) and bin paths of the first scans."""
    kitti_dir = Path(kitti_dir)
    times = np.loadtxt(kitti_dir / "times.txt", ndmin=1)[:n_scans]
    poses = np.loadtxt(kitti_dir / "poses.txt", ndmin=2)[:n_scans].reshape(-1, 3, 4)
    P = np.tile(np.eye(4), (len(poses), 1, 1))
    P[:, :3, :] = poses
    Tr = np.eye(4)
    for line in (kitti_dir / "calib.txt").read_text().splitlines():
        if line.startswith("Tr:"):
            Tr[:3, :] = np.array(line.split()[1:], dtype=np.float64).reshape(3, 4)
    bins = sorted((kitti_dir / "velodyne").glob("*.bin"))[:n_scans]
    return {"times": times, "P_cam0": P, "Tr": Tr, "bins": bins}


def kitti_lidar_poses(kitti_dir: str | Path, n_scans: int, world: str = "lidar0") -> np.ndarray:
    """T_world_lidar per scan: P_cam0 · Tr (``world="cam0"``, KITTI's camera-axes world, y down)
    or (P_cam0,0 · Tr)⁻¹ · P_cam0 · Tr (``world="lidar0"``: the first lidar frame, z up,
    x forward — about 59.6° counter-clockwise from east for sequence 00)."""
    k = read_kitti_odometry(kitti_dir, n_scans)
    T = k["P_cam0"] @ k["Tr"]
    if world == "lidar0":
        T = np.linalg.inv(T[0]) @ T
    return T


def write_kitti_odometry_mcap(kitti_dir: str | Path, out_path: str | Path, n_scans: int, *,
                              world: str = "lidar0", pose_source: str = "odometry",
                              point_stride: int = 1, with_fixes: bool = False) -> Path:
    """KITTI odometry scans as a ROS 2 MCAP (mcap-ros2-support).

    Topics: ``/velodyne_points`` PointCloud2 (x, y, z, intensity float32) in ``velodyne``;
    ``/odom`` Odometry ``map -> base_link`` (``pose_source="odometry"``) or ``/tf``
    ``map -> base_link`` (``"tf"``); ``/tf_static`` ``base_link -> velodyne`` (lidar
    1.73 m above base_link, which sits on the road). Stamps: KITTI_BASE_NS + times.txt.
    ``world`` as in :func:`kitti_lidar_poses`; ``point_stride`` keeps every k-th point.
    ``with_fixes`` adds /fix NavSatFix from the documented start georeference (start only,
    constant; a placeholder, not the real GNSS track).
    """
    k = read_kitti_odometry(kitti_dir, n_scans)
    T_world_lidar = kitti_lidar_poses(kitti_dir, n_scans, world)
    T_base_lidar = transform(z=KITTI_LIDAR_HEIGHT_M)
    T_world_base = T_world_lidar @ np.linalg.inv(T_base_lidar)
    stamps = [KITTI_BASE_NS + int(round(t * 1e9)) for t in k["times"]]
    clouds = [(ns, np.fromfile(b, dtype="<f4").reshape(-1, 4)[::point_stride], "velodyne")
              for ns, b in zip(stamps, k["bins"], strict=True)]
    poses = list(zip(stamps, T_world_base, strict=True))
    kwargs = {}
    if pose_source == "odometry":
        kwargs["odometry"] = poses
    else:
        kwargs["tf"] = [(ns, "map", "base_link", T) for ns, T in poses]
    if with_fixes:
        kwargs["fixes"] = [(ns, 48.982545, 8.390366, 116.38) for ns in stamps[:1]]
    return write_ros2_mcap(out_path, clouds=clouds, cloud_topic="/velodyne_points",
                           odom_topic="/odom", odom_frames=("map", "base_link"),
                           tf_static=[("base_link", "velodyne", T_base_lidar)], **kwargs)


def write_kitti_raw_folder(root: str | Path, date: str = "2011_09_26", drive: str = "0001",
                           n_frames: int = 3, n_points: int = 200, speed_mps: float = 10.0,
                           yaw_rate: float = 0.1, lat0: float = 49.0, lon0: float = 8.4,
                           T_velo_imu: np.ndarray | None = None) -> dict:
    """A tiny synthetic KITTI *raw* drive (calib, velodyne, oxts, timestamps; no images).

    The car drives east at ``speed_mps`` while turning at ``yaw_rate`` rad/s; returns the
    written values: stamps_ns, lat/lon/alt/roll/pitch/yaw per frame, T_velo_imu and points.
    """
    rng = np.random.default_rng(0)
    root = Path(root)
    calib_dir = root / date
    drive_dir = calib_dir / f"{date}_drive_{drive}_sync"
    if T_velo_imu is None:
        T_velo_imu = transform(x=-0.8, y=0.3, z=-0.9, yaw=0.02)
    eye = " ".join(["1 0 0 0 1 0 0 0 1"])
    P = "7.2e+02 0 6.0e+02 0 0 7.2e+02 1.7e+02 0 0 0 1 0"
    (calib_dir).mkdir(parents=True)
    (calib_dir / "calib_imu_to_velo.txt").write_text(
        "calib_time: 25-May-2012 12:00:00\n"
        f"R: {' '.join(f'{v:.12e}' for v in T_velo_imu[:3, :3].ravel())}\n"
        f"T: {' '.join(f'{v:.12e}' for v in T_velo_imu[:3, 3])}\n")
    (calib_dir / "calib_velo_to_cam.txt").write_text(
        "calib_time: 25-May-2012 12:00:00\nR: 0 -1 0 0 0 -1 1 0 0\nT: 0 -0.08 -0.27\n")
    cam = ["calib_time: 25-May-2012 12:00:00", "corner_dist: 9.95e-02"]
    for i in range(4):
        cam += [f"S_0{i}: 1392 512", f"K_0{i}: 9.8e+02 0 6.9e+02 0 9.7e+02 2.4e+02 0 0 1",
                f"D_0{i}: 0 0 0 0 0", f"R_0{i}: {eye}", f"T_0{i}: 0 0 0",
                f"S_rect_0{i}: 1242 375", f"R_rect_0{i}: {eye}", f"P_rect_0{i}: {P}"]
    (calib_dir / "calib_cam_to_cam.txt").write_text("\n".join(cam) + "\n")
    stamps = [1_317_000_000_000_000_000 + i * 103_000_000 for i in range(n_frames)]
    iso = [_kitti_time(ns) for ns in stamps]
    er = 6378137.0
    values = {"stamps_ns": stamps, "T_velo_imu": T_velo_imu, "points": [], "oxts": []}
    for sensor in ("velodyne_points", "oxts"):
        (drive_dir / sensor / "data").mkdir(parents=True)
        (drive_dir / sensor / "timestamps.txt").write_text("\n".join(iso) + "\n")
    for i in range(n_frames):
        t = i * 0.103
        yaw = yaw_rate * t
        lat = lat0
        lon = lon0 + np.degrees(speed_mps * t / (er * np.cos(np.radians(lat0))))
        oxts = [lat, lon, 110.0 + 0.1 * i, 0.01 * i, -0.02 * i, yaw] + [0.0] * 19 + [4, 10, 4,
                                                                                    4, 0]
        values["oxts"].append(oxts[:6])
        (drive_dir / "oxts" / "data" / f"{i:010d}.txt").write_text(
            " ".join(repr(float(v)) for v in oxts[:25]) + " " + " ".join(str(v) for v in oxts[25:])
            + "\n")
        pts = np.column_stack([rng.uniform(-20, 20, (n_points, 3)),
                               rng.uniform(0, 1, n_points)]).astype("<f4")
        pts.tofile(drive_dir / "velodyne_points" / "data" / f"{i:010d}.bin")
        values["points"].append(pts)
    return values


def _kitti_time(ns: int) -> str:
    from datetime import UTC, datetime

    seconds, frac = divmod(ns, 1_000_000_000)
    return datetime.fromtimestamp(seconds, UTC).strftime("%Y-%m-%d %H:%M:%S") + f".{frac:09d}"
