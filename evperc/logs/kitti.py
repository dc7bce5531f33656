"""Reading a KITTI odometry / SemanticKITTI sequence folder as a logged drive.

A folder is a KITTI sequence (:func:`is_kitti_sequence`) when it holds ``velodyne/`` and
``poses.txt``; it is read with ``calib.txt`` and ``times.txt`` next to them:

- ``velodyne/NNNNNN.bin``: float32 little-endian ``x, y, z, reflectance`` per point, in the
  lidar frame (x forward, y left, z up); the file number ``NNNNNN`` is the scan's line in
  ``poses.txt`` and ``times.txt``;
- ``poses.txt``: per scan, the 3×4 matrix ``[R|t]`` of the left camera cam0 in the sequence's
  world frame (camera axes: x right, y down, z forward);
- ``calib.txt``: the line ``Tr:`` (3×4, lidar → cam0); the other lines are ignored;
- ``times.txt``: scan times in seconds from the sequence start; stamps are
  ``round(t · 1e9)`` ns;
- ``labels/NNNNNN.label`` (SemanticKITTI, optional): not read here, see
  :mod:`evperc.eval.semantickitti`.

**Pose chain.** With ``P_i`` the cam0 pose of scan i and ``Tr`` the lidar → cam0 transform,
the lidar pose in KITTI's camera world is ``P_i · Tr`` (4×4). evperc's world frame is the first
scan's lidar frame: ``T_world_lidar,i = (P_0 · Tr)⁻¹ · P_i · Tr``, so the first pose is the
identity, x points forward, y left and z up (the HDL-64E is mounted level on the car to
within about a degree, which the ground model's percentile estimate absorbs). This is the
same world as ``tests.mcap_writers.write_kitti_odometry_mcap(world="lidar0")``.

**No GNSS.** The folder has no georeference: ``gnss_fixes()`` is empty, so a run with a map
needs ``input.origin_lat_deg / origin_lon_deg / origin_heading_deg`` in a ``--config`` file —
the position of the first lidar pose and the azimuth of its x axis, counter-clockwise from
east (README, "KITTI sequences"). ``--no-map`` runs in the sequence's own frame.

**Memory.** ``poses.txt`` and ``times.txt`` are read once (12 + 1 numbers a scan: 0.5 MB for
the 4,541 scans of sequence 00); the scans are read one ``.bin`` at a time as
:meth:`KittiLog.scans` is iterated.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from evperc.errors import LogError, PoseError
from evperc.logs.scan import PosedScan

log = logging.getLogger(__name__)

#: bytes per point of a KITTI ``.bin``: float32 x, y, z, reflectance
POINT_BYTES = 16
#: the lidar's frame name (``PosedScan.frame_id``, ``lidar_frame``)
LIDAR_FRAME = "velodyne"
#: the name of evperc's world frame of a KITTI sequence (the first scan's lidar frame)
WORLD_FRAME = "kitti_lidar0"
#: layers of the KITTI odometry scanner (a Velodyne HDL-64E)
KITTI_LAYERS = 64
_BIN_NAME = re.compile(r"^(\d+)\.bin$")


def is_kitti_sequence(path: str | Path) -> bool:
    """True for a directory that holds ``velodyne/`` and ``poses.txt`` (a KITTI odometry or
    SemanticKITTI sequence folder)."""
    p = Path(path)
    return p.is_dir() and (p / "velodyne").is_dir() and (p / "poses.txt").is_file()


def claims(path: Path) -> bool:
    """The factory's test (:mod:`evperc.logs.factory`): a directory laid out as a KITTI
    sequence, or one that is meant to be (``velodyne/`` or ``poses.txt`` there), or an empty
    one — :class:`KittiLog` then names what the folder lacks. A ROS 2 bag directory
    (``metadata.yaml``) is not one."""
    if not path.is_dir() or (path / "metadata.yaml").exists():
        return False
    return ((path / "velodyne").is_dir() or (path / "poses.txt").is_file()
            or not any(path.iterdir()))


def read_tr(calib_path: Path) -> np.ndarray:
    """The 4×4 lidar → cam0 transform of the ``Tr:`` line of ``calib.txt``; :class:`PoseError`
    if the file or the line is missing or malformed."""
    try:
        lines = calib_path.read_text().splitlines()
    except OSError as err:
        raise PoseError(f"{calib_path}: cannot read the calibration ({err.strerror}); a KITTI "
                        "sequence needs calib.txt with its Tr: line (lidar -> cam0)") from err
    for line in lines:
        if line.startswith("Tr:"):
            try:
                values = np.array(line.split()[1:], dtype=np.float64)
            except ValueError:
                values = np.empty(0)
            if values.size != 12 or not np.isfinite(values).all():
                raise PoseError(f"{calib_path}: the Tr: line needs 12 numbers (3x4, lidar -> "
                                f"cam0), it has {values.size}")
            T = np.eye(4)
            T[:3, :] = values.reshape(3, 4)
            return T
    raise PoseError(f"{calib_path}: no Tr: line (the 3x4 lidar -> cam0 transform); add it from "
                    "the KITTI odometry calibration of the sequence's recording day")


def _read_table(path: Path, columns: int, what: str) -> np.ndarray:
    try:
        rows = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except OSError as err:
        raise LogError(f"{path}: cannot read {what} ({err.strerror or err}); a KITTI sequence "
                       "folder needs velodyne/, poses.txt, calib.txt and times.txt") from err
    except ValueError as err:
        raise LogError(f"{path}: not a table of numbers ({err})") from err
    if rows.size == 0:
        return np.empty((0, columns))
    if rows.shape[1] != columns:
        raise LogError(f"{path}: {rows.shape[1]} numbers a line, {what} needs {columns}")
    return rows


class KittiLog:
    """Posed scans of a KITTI sequence folder, with the interface of
    :class:`evperc.logs.message_log.LogReader` that ``evperc run`` and ``evperc info`` use."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        root = self.path
        bins = []
        velodyne = root / "velodyne"
        if velodyne.is_dir():
            for entry in velodyne.iterdir():
                m = _BIN_NAME.match(entry.name)
                if m:
                    bins.append((int(m.group(1)), entry))
        if not bins:
            raise LogError(f"{root}: is a directory with no scans (velodyne/NNNNNN.bin); give "
                           "a KITTI sequence folder (velodyne/, poses.txt, calib.txt, times.txt) "
                           "or an MCAP file")
        bins.sort()
        self.numbers = np.array([n for n, _ in bins], dtype=np.int64)
        self.bins = [p for _, p in bins]
        for p in self.bins:
            size = p.stat().st_size
            if size % POINT_BYTES:
                raise LogError(f"{p}: truncated scan ({size} bytes, not a multiple of "
                               f"{POINT_BYTES}: float32 x, y, z, reflectance per point); "
                               "copy the file again")
        poses = _read_table(root / "poses.txt", 12, "poses (3x4 cam0 matrices)")
        last = int(self.numbers[-1])
        if len(poses) <= last:
            raise PoseError(f"{root / 'poses.txt'}: {len(poses)} poses for scans up to "
                            f"{last:06d}.bin ({last + 1} needed); fewer poses than scans")
        times = _read_table(root / "times.txt", 1, "scan times (s)")[:, 0]
        if len(times) <= last:
            raise LogError(f"{root / 'times.txt'}: {len(times)} times for scans up to "
                           f"{last:06d}.bin ({last + 1} needed)")
        self.Tr = read_tr(root / "calib.txt")
        P = np.tile(np.eye(4), (len(self.bins), 1, 1))
        P[:, :3, :] = poses[self.numbers].reshape(-1, 3, 4)
        T_cam_world_lidar = P @ self.Tr
        #: (n, 4, 4) lidar pose of each scan in the first scan's lidar frame
        self.poses = np.linalg.inv(T_cam_world_lidar[0]) @ T_cam_world_lidar
        self.stamps_ns = np.round(times[self.numbers] * 1e9).astype(np.int64)
        if np.any(np.diff(self.stamps_ns) <= 0):
            i = int(np.flatnonzero(np.diff(self.stamps_ns) <= 0)[0])
            raise LogError(f"{root / 'times.txt'}: time does not increase from scan "
                           f"{self.numbers[i]:06d} to {self.numbers[i + 1]:06d}")
        self.labels_dir = root / "labels" if (root / "labels").is_dir() else None
        self.stats: dict[str, int] = {}
        self.posed_in: str | None = None
        self.lidar_frame = LIDAR_FRAME

    # --- extent and streaming ------------------------------------------------------------

    @property
    def start_ns(self) -> int:
        """Stamp of the first scan (ns from the sequence start)."""
        return int(self.stamps_ns[0])

    @property
    def end_ns(self) -> int:
        """Just after the last scan's stamp (ranges are half-open)."""
        return int(self.stamps_ns[-1]) + 1

    @property
    def scan_count(self) -> int:
        """Scans of the sequence (its ``.bin`` files)."""
        return len(self.numbers)

    def read_points(self, i: int) -> tuple[np.ndarray, np.ndarray | None, int]:
        """``(points, source_index, count)`` of the i-th scan: its finite x, y, z (float32,
        (N, 3)), their indices in the file (None when every point is finite) and the file's
        point count."""
        try:
            raw = np.fromfile(self.bins[i], dtype="<f4")
        except OSError as err:
            raise LogError(f"{self.bins[i]}: cannot read scan ({err.strerror})") from err
        if raw.size % 4:
            raise LogError(f"{self.bins[i]}: truncated scan ({raw.size * 4} bytes, not a "
                           f"multiple of {POINT_BYTES})")
        xyz = raw.reshape(-1, 4)[:, :3]
        finite = np.isfinite(xyz).all(axis=1)
        if finite.all():
            return np.ascontiguousarray(xyz), None, len(xyz)
        index = np.flatnonzero(finite)
        return np.ascontiguousarray(xyz[index]), index, len(xyz)

    def scans(self, start_ns: int | None = None, end_ns: int | None = None
              ) -> Iterator[PosedScan]:
        """Posed scans with stamp in ``[start_ns, end_ns)``, one ``.bin`` read at a time."""
        self.stats = {}
        for i, stamp in enumerate(self.stamps_ns):
            if (start_ns is not None and stamp < start_ns) or (end_ns is not None
                                                                and stamp >= end_ns):
                continue
            points, index, count = self.read_points(i)
            self.posed_in = WORLD_FRAME
            yield PosedScan(int(stamp), points, False, self.poses[i].copy(), LIDAR_FRAME,
                            number=int(self.numbers[i]), source_count=count,
                            source_index=index)

    # --- other queries -------------------------------------------------------------------

    def positions_at(self, stamps_ns: np.ndarray, frame: str | None = None) -> np.ndarray:
        """(K, 3) lidar position at each stamp, linear between scans; NaN outside the scans'
        span. ``frame`` must be the lidar's (the only frame a KITTI folder places)."""
        stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
        out = np.full((stamps.size, 3), np.nan)
        inside = (stamps >= self.stamps_ns[0]) & (stamps <= self.stamps_ns[-1])
        if frame not in (None, LIDAR_FRAME) or not inside.any():
            return out
        t = self.stamps_ns.astype(np.float64)
        for axis in range(3):
            out[inside, axis] = np.interp(stamps[inside].astype(np.float64), t,
                                          self.poses[:, axis, 3])
        return out

    def gnss_spans(self) -> list[tuple[int | None, int | None]]:
        return [(None, None)]

    def gnss_fixes(self, start_ns: int | None = None, end_ns: int | None = None
                   ) -> np.ndarray:
        """Always empty (0, 4): a KITTI sequence folder has no GNSS (module docstring)."""
        return np.empty((0, 4))

    def gnss_antenna_frame(self) -> str:
        return LIDAR_FRAME

    def sensor_layers(self) -> tuple[int, str]:
        """KITTI's odometry scans are a Velodyne HDL-64E's: 64 layers (its .bin files hold no
        laser index; :meth:`LogReader.sensor_layers`)."""
        return KITTI_LAYERS, "a KITTI folder: a Velodyne HDL-64E"

    def info(self) -> dict[str, Any]:
        """Summary for ``evperc info``, with the keys of :meth:`LogReader.info`; the
        "topics" are the folder's files."""
        n = len(self.bins)
        sample = min(n, 20)
        counts = [self.bins[i].stat().st_size // POINT_BYTES for i in range(sample)]
        labels = (len(list(self.labels_dir.glob("*.label"))) if self.labels_dir is not None
                  else 0)
        topics = [{"topic": "velodyne/", "schema": "KITTI .bin (float32 x y z reflectance)",
                   "encoding": "kitti", "messages": n},
                  {"topic": "poses.txt", "schema": "KITTI cam0 poses (3x4) + calib.txt Tr",
                   "encoding": "kitti", "messages": n}]
        if labels:
            topics.append({"topic": "labels/", "schema": "SemanticKITTI .label (uint32)",
                           "encoding": "kitti", "messages": labels})
        start, end = int(self.stamps_ns[0]), int(self.stamps_ns[-1])
        layers = self.sensor_layers()
        return {"path": str(self.path), "kind": "kitti", "indexed": True, "complete": True,
                "stopped": None, "start_ns": start, "end_ns": end,
                "duration_s": (end - start) / 1e9, "topics": topics,
                "detected": {"lidar_topic": "velodyne/*.bin",
                             "pose_source": "poses.txt (cam0) · calib.txt Tr, world = first "
                                            "lidar pose (z up)",
                             "gnss_topic": None, "static_tf_topics": []},
                "lidar_frame": LIDAR_FRAME,
                "mean_points_per_scan": float(np.mean(counts)),
                "points_sample_scans": sample,
                "lidar_layers": {"count": layers[0], "from": layers[1]},
                "first_scan": int(self.numbers[0]), "last_scan": int(self.numbers[-1]),
                "labels": labels}
