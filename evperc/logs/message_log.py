"""Reading logged drives: lidar scans joined with the poses at their stamps.

``open_message_log(path)`` (what :func:`evperc.logs.factory.open_log` calls for every log
that is a container of messages) opens the log with the source its content names
(:func:`open_source`: an MCAP file, a ROS 1 ``.bag``, a ROS 2 bag directory with ``.db3`` or
``.mcap`` files; see :mod:`evperc.logs.source`) and finds the topics (by schema name, see
:mod:`evperc.logs.mcap_messages`; the ROS 1 names, ``sensor_msgs/PointCloud2``, too):

- lidar: ``sensor_msgs/msg/PointCloud2``, ``sensor_msgs/msg/LaserScan``,
  ``foxglove.PointCloud``, ``foxglove.LaserScan``;
- poses, in order of preference when none is chosen: a pose topic (``nav_msgs/msg/Odometry``,
  ``geometry_msgs/msg/PoseStamped``, ``geometry_msgs/msg/PoseWithCovarianceStamped``,
  ``foxglove.PoseInFrame``, ``foxglove.Odometry``), else the TF tree (``tf2_msgs/msg/TFMessage``,
  ``foxglove.FrameTransform(s)``; topics ending in ``tf_static`` hold static transforms);
- GNSS: ``sensor_msgs/msg/NavSatFix``, ``foxglove.LocationFix``.

Several candidates for one role raise :class:`TopicError` listing a ready-to-paste option per
candidate; none raises naming the schemas the file has.

``LogReader.scans()`` streams the log in log-time order (file order if it has no index). Scans
wait in a short queue until a pose at or after their stamp arrives; the pose at the scan stamp
is interpolated (linear position, slerp orientation). A scan is skipped, and counted in
``LogReader.stats`` under its reason, when:

- ``before_pose_span`` / ``after_pose_span``: its stamp lies outside the poses (a scan still
  waiting ``max_pose_gap_s + 1 s`` of log time after its stamp counts as after);
- ``pose_gap``: the two poses around it are more than ``max_pose_gap_s`` apart;
- ``no_transform_chain``: TF never links its frame to the world frame;
- ``duplicate_stamp`` / ``backwards_stamp``: its stamp equals / precedes the previous scan's
  (time going backwards on the lidar topic: later scans are kept, the older one dropped);
- ``undecodable``: the message could not be decoded.

``pose_duplicate_stamp`` counts pose samples dropped because their edge already had a sample
with that stamp (pose samples arriving out of order are re-sorted, not dropped). Memory is
bounded by the queue (scans within ``max_pose_gap_s + 1 s``) and the pose samples since the
oldest waiting scan; it does not grow with the log's length.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from evperc.errors import LogError, TopicError
from evperc.logs.mcap_messages import (
    GNSS_ADAPTERS,
    LAYER_ADAPTERS,
    LIDAR_ADAPTERS,
    POSE_ADAPTERS,
    TF_ADAPTERS,
    ScanRecord,
    is_static_tf_topic,
    schema_list,
)
from evperc.logs.mcap_poses import OK, WAIT, PoseSource, PoseTopicSource, TfSource
from evperc.logs.mcap_source import McapSource
from evperc.logs.pointcloud import MissingFieldsError
from evperc.logs.rosbag1 import Rosbag1Source
from evperc.logs.rosbag2 import Rosbag2Source
from evperc.logs.scan import PosedScan
from evperc.logs.source import HEAD_BYTES, LogSource, RawLike

log = logging.getLogger(__name__)

#: extra log time a scan may wait for its pose beyond max_pose_gap_s (message latency)
WAIT_SLACK_NS = 1_000_000_000
#: scans decoded by ``info()`` to estimate the mean points per scan
INFO_SAMPLE_SCANS = 20
#: lidar messages :meth:`LogReader.sensor_layers` looks at (past undecodable ones)
LAYERS_SAMPLE_SCANS = 3
#: a long log's GNSS fixes are read in this many spans of log time (:meth:`LogReader.gnss_spans`)
GNSS_SPANS = 16
#: ... of this many seconds each, spread evenly from the log's first message to its last
GNSS_SPAN_S = 2.0


@dataclass
class GnssSpan:
    """A span's fixes and the pose messages read with them (:meth:`LogReader.gnss_span`):
    ``poses`` are those logged in ``[read_from_ns, read_to_ns)``."""

    reader: LogReader
    fixes: np.ndarray
    read_from_ns: int
    read_to_ns: int
    poses: list[RawLike]

    def positions(self, frame: str | None = None) -> np.ndarray:
        """:meth:`LogReader.positions_at` the fixes' stamps, from the poses held (and those
        logged after the span, as far as the last fix needs)."""
        return self.reader.positions_at(self.fixes[:, 0].astype(np.int64), frame, self._raws)

    def _raws(self, lo: int, hi: int) -> Iterator[RawLike]:
        """The pose messages logged in ``[lo, hi)``, as the source's ``iter_raw`` yields them."""
        topics = self.reader.pose_topics[1]
        if lo < self.read_from_ns:  # a fix stamped before its span's poses: read them all
            yield from self.reader.source.iter_raw(topics, lo, hi)
            return
        for raw in self.poses:
            if lo <= raw.log_time < hi:
                yield raw
        if hi > self.read_to_ns:
            yield from self.reader.source.iter_raw(topics, self.read_to_ns, hi)


def open_message_log(path: str | Path, *, lidar_topic: str | None = None,
             pose_topic: str | None = None, gnss_topic: str | None = None,
             world_frame: str | None = None, extrinsic: np.ndarray | None = None,
             max_pose_gap_s: float = 1.0, strict: bool = True) -> LogReader:
    """Open a log (any kind :func:`open_source` recognises) and choose its lidar and pose topics.

    ``extrinsic`` (4×4, T_vehicle_lidar) is used when poses describe the vehicle and the log
    has no static transform to the lidar frame. Empty strings count as "not given".
    ``strict=False`` defers topic errors to the first read (``info()`` reports them instead).
    Raises :class:`LogError` for a missing file or one of no kind evperc reads,
    :class:`TopicError` when no topic or several topics fit a role.
    """
    source = open_source(path)
    reader = LogReader(source, lidar_topic=lidar_topic or None, pose_topic=pose_topic or None,
                       gnss_topic=gnss_topic or None, world_frame=world_frame or None,
                       extrinsic=extrinsic, max_pose_gap_s=max_pose_gap_s)
    if strict:
        reader.lidar_topic  # noqa: B018 - detect now, fail fast
        reader.pose_topics  # noqa: B018
    return reader


#: the message sources, asked in this order whether they claim a path (evperc.logs.source)
MESSAGE_SOURCES: tuple[type, ...] = (McapSource, Rosbag1Source, Rosbag2Source)


def open_source(path: str | Path) -> LogSource:
    """The source of the first kind in :data:`MESSAGE_SOURCES` that claims ``path`` by its content;
    LogError naming what was found when none does."""
    path = Path(path)
    head = b""
    try:
        if not path.is_dir():
            with path.open("rb") as f:
                head = f.read(HEAD_BYTES)
    except FileNotFoundError as err:
        raise LogError(f"{path}: log file not found") from err
    except OSError as err:
        raise LogError(f"{path}: cannot read log ({err.strerror})") from err
    for kind in MESSAGE_SOURCES:
        if kind.claims(path, head):
            return kind.open(path)
    raise LogError(f"{path}: {_found(path, head)}; evperc reads MCAP files, ROS 1 bags (.bag) "
                   "ROS 2 bag directories (metadata.yaml with .db3 or .mcap files) and KITTI "
                   "sequence folders (velodyne/, poses.txt, calib.txt, times.txt)")


def _found(path: Path, head: bytes) -> str:
    """What ``path`` is, for the error when no source claims it."""
    if path.is_dir():
        return ("is a directory without a metadata.yaml (not a ROS 2 bag) nor velodyne/ and "
                "poses.txt (not a KITTI sequence); give the log file inside it")
    if not head:
        return "not an MCAP file or bag: the file is empty"
    text = head.decode("ascii", "replace")
    shown = repr(text) if text.isprintable() else head.hex(" ")
    return f"not an MCAP file or bag: it starts with {shown}"


class LogReader:
    """Scans with poses, GNSS fixes and a summary of one log; see the module docstring."""

    def __init__(self, source: LogSource, *, lidar_topic: str | None, pose_topic: str | None,
                 gnss_topic: str | None, world_frame: str | None, extrinsic: np.ndarray | None,
                 max_pose_gap_s: float):
        self.source = source
        self.path = source.path
        self.world_frame = world_frame
        self.extrinsic = extrinsic
        self.max_gap_ns = int(round(max_pose_gap_s * 1e9))
        self._requested = {"lidar": lidar_topic, "pose": pose_topic, "gnss": gnss_topic}
        self._chosen: dict[str, Any] = {}
        self._lidar_frame: str | None = None
        self._gnss_frame: str | None = None
        self._said: set = set()  # one-time log messages already given
        self._static: list | None = None  # the static transforms' pose samples, once read
        self.stats: dict[str, int] = {}
        #: the frame of the posed scans' ``T_world_sensor`` (named in the log), once a scan
        #: has been posed by :meth:`scans`
        self.posed_in: str | None = None

    # --- the log's extent ----------------------------------------------------------------

    @property
    def start_ns(self) -> int:
        """Log time of the first message (ns)."""
        return int(self.source.start_ns or 0)

    @property
    def end_ns(self) -> int:
        """Log time just after the last message (ns; ranges are half-open)."""
        return int(self.source.end_ns or 0) + 1

    # --- topic detection -----------------------------------------------------------------

    @property
    def scan_count(self) -> int:
        """Lidar messages in the log (its summary's count; the scans before skipping)."""
        return self.source.topics[self.lidar_topic].messages

    @property
    def lidar_topic(self) -> str:
        if "lidar" not in self._chosen:
            topic = self._choose("lidar", LIDAR_ADAPTERS, "--lidar-topic")
            if topic is None:
                raise TopicError(
                    f"{self.path}: no lidar topic; it has {self._schemas_text()}; evperc reads "
                    f"{schema_list(LIDAR_ADAPTERS)}")
            self._chosen["lidar"] = topic
        return self._chosen["lidar"]

    @property
    def pose_topics(self) -> tuple[str, list[str]]:
        """("topic", [pose topic]) or ("tf", [dynamic TF topics]); static TF is read apart."""
        if "pose" not in self._chosen:
            self._chosen["pose"] = self._choose_pose()
        return self._chosen["pose"]

    @property
    def gnss_topic(self) -> str | None:
        if "gnss" not in self._chosen:
            self._chosen["gnss"] = self._choose("gnss", GNSS_ADAPTERS, "input.gnss_topic =")
        return self._chosen["gnss"]

    @property
    def static_tf_topics(self) -> list[str]:
        return [t.topic for t in self.source.topics.values()
                if t.schema in TF_ADAPTERS and is_static_tf_topic(t.topic) and t.messages]

    def _candidates(self, adapters: dict) -> list[str]:
        return sorted(t.topic for t in self.source.topics.values()
                      if t.schema in adapters and t.messages > 0)

    def _choose(self, role: str, adapters: dict, option: str) -> str | None:
        requested = self._requested[role]
        if requested is not None:
            return self._check_requested(role, requested, adapters)
        candidates = self._candidates(adapters)
        if len(candidates) > 1:
            quote = '"' if option.endswith("=") else ""
            options = " | ".join(f"{option} {quote}{t}{quote}" for t in candidates)
            raise TopicError(f"{self.path}: {len(candidates)} {role} topics fit; choose one: "
                             f"{options}")
        return candidates[0] if candidates else None

    def _check_requested(self, role: str, topic: str, adapters: dict) -> str:
        info = self.source.topics.get(topic)
        if info is None:
            fits = ", ".join(self._candidates(adapters)) or "none"
            raise TopicError(f"{self.path}: no topic {topic}; {role} topics in the log: {fits}")
        if info.schema not in adapters:
            raise TopicError(f"{self.path}: topic {topic} has schema {info.schema or '(none)'},"
                             f" not a {role} schema ({', '.join(adapters)})")
        return topic

    def _choose_pose(self) -> tuple[str, list[str]]:
        requested = self._requested["pose"]
        if requested is not None:
            both = {**POSE_ADAPTERS, **TF_ADAPTERS}
            topic = self._check_requested("pose", requested, both)
            kind = "topic" if self.source.topics[topic].schema in POSE_ADAPTERS else "tf"
            return kind, [topic]
        poses = self._candidates(POSE_ADAPTERS)
        if len(poses) > 1:
            options = " | ".join(f"--pose-topic {t}" for t in poses)
            raise TopicError(f"{self.path}: {len(poses)} pose topics fit; choose one: {options}")
        if poses:
            return "topic", poses
        tf = [t for t in self._candidates(TF_ADAPTERS) if not is_static_tf_topic(t)]
        if tf:
            return "tf", tf
        raise TopicError(
            f"{self.path}: no pose topic; it has {self._schemas_text()}; evperc reads "
            f"{schema_list(POSE_ADAPTERS)} or a TF tree ({schema_list(TF_ADAPTERS)} on /tf)")

    def _schemas_text(self) -> str:
        schemas = sorted({f"{t.schema or '(no schema)'}" for t in self.source.topics.values()})
        return f"schemas {', '.join(schemas)}" if schemas else "no topics"

    # --- decoding ------------------------------------------------------------------------

    def _scan(self, raw: RawLike) -> ScanRecord:
        adapter = LIDAR_ADAPTERS[self.source.topics[raw.topic].schema]
        try:
            return adapter(self.source.decode(raw), raw.log_time)
        except MissingFieldsError as err:
            raise LogError(f"{self.path}: topic {raw.topic}: point cloud has no x/y/z fields "
                           f"(fields: {', '.join(err.present) or 'none'}); evperc needs x, y, z"
                           ) from err

    def _pose_records(self, raw: RawLike) -> list:
        """The pose samples of one pose or TF message; none if it cannot be decoded (counted
        as ``pose_undecodable``, like undecodable scans: one bad message must not end the
        run; a log without any usable pose still fails with a clear error)."""
        schema = self.source.topics[raw.topic].schema
        try:
            decoded = self.source.decode(raw)
            if schema in POSE_ADAPTERS:
                return [POSE_ADAPTERS[schema](decoded, raw.log_time)]
            return TF_ADAPTERS[schema](decoded, raw.log_time)
        except LogError:
            raise
        except Exception as err:
            if "pose_undecodable" not in self.stats:
                log.warning("%s: topic %s: cannot decode a pose message at log time %d ns "
                            "(%s); skipping such messages", self.path, raw.topic,
                            raw.log_time, err)
            self._count("pose_undecodable")
            return []

    def _pose_source(self) -> PoseSource:
        kind, topics = self.pose_topics
        source: PoseSource
        if kind == "topic":
            source = PoseTopicSource(str(self.path), topics[0], self.max_gap_ns,
                                     self.world_frame, self.extrinsic, self._said)
        else:
            source = TfSource(str(self.path), self.max_gap_ns, self.world_frame, self._said)
        if self._static is None:  # read once: each scans() would read them again
            self._static = [self._pose_records(raw)
                            for raw in self.source.iter_raw(self.static_tf_topics)]
        for records in self._static:
            source.add_static(records)
        return source

    # --- streaming -----------------------------------------------------------------------

    def scans(self, start_ns: int | None = None, end_ns: int | None = None
              ) -> Iterator[PosedScan]:
        """Posed scans with stamp in [start_ns, end_ns), in stamp order; see the module doc.

        ``stats`` is reset at each call and complete when the iterator is exhausted.
        """
        lidar = self.lidar_topic
        poses = self._pose_source()
        pose_topics = set(self.pose_topics[1])
        self.stats = {}
        margin = self.max_gap_ns + WAIT_SLACK_NS
        pending: deque[ScanRecord] = deque()
        last_stamp: int | None = None
        read_from = None if start_ns is None else start_ns - margin
        read_to = None if end_ns is None else end_ns + margin
        for raw in self.source.iter_raw([lidar, *pose_topics], read_from, read_to):
            now = raw.log_time
            if raw.topic == lidar:
                scan = self._decode_scan(raw)
                if scan is None or not _in_range(scan.stamp_ns, start_ns, end_ns):
                    pass
                elif last_stamp is not None and scan.stamp_ns <= last_stamp:
                    self._count("duplicate_stamp" if scan.stamp_ns == last_stamp
                                else "backwards_stamp")
                else:
                    last_stamp = scan.stamp_ns
                    pending.append(scan)
            if raw.topic in pose_topics:
                self._count("pose_duplicate_stamp", poses.add(self._pose_records(raw)))
            yield from self._release(pending, poses, deadline=now - margin)
            horizon = pending[0].stamp_ns if pending else (
                last_stamp if last_stamp is not None else now - margin)
            poses.prune(horizon)
        yield from self._release(pending, poses, deadline=None)

    def _release(self, pending: deque[ScanRecord], poses: PoseSource,
                 deadline: int | None) -> Iterator[PosedScan]:
        """Pose the waiting scans that can be; drop those past ``deadline`` (None: all)."""
        while pending:
            scan = pending[0]
            status, T = poses.lookup(scan.frame_id, scan.stamp_ns)
            if status == WAIT:
                if deadline is not None and scan.stamp_ns >= deadline:
                    return
                status = poses.abandon_reason(scan.frame_id)
            pending.popleft()
            if status != OK:
                self._count(status)
                continue
            if scan.T_frame_sensor is not None:
                T = T @ scan.T_frame_sensor
            self.posed_in = poses.world_frame_name
            yield PosedScan(scan.stamp_ns, scan.points, scan.planar, T, scan.frame_id,
                            source_count=scan.source_count, source_index=scan.source_index)

    def _decode_scan(self, raw: RawLike) -> ScanRecord | None:
        try:
            return self._scan(raw)
        except LogError:
            raise
        except Exception as err:  # one bad message must not end the run
            if "undecodable" not in self.stats:
                log.warning("%s: topic %s: cannot decode a message at log time %d ns (%s); "
                            "skipping such messages", self.path, raw.topic,
                            raw.log_time, err)
            self._count("undecodable")
            return None

    def sensor_layers(self) -> tuple[int, str] | None:
        """The lidar's number of layers and how it was read, from the first lidar message
        that shows it (of the first :data:`LAYERS_SAMPLE_SCANS`): its laser index field
        (``ring``), an organised cloud's rows, or a 2-D scan's one; None if none shows it or
        none decodes (the run says why, not this)."""
        try:
            lidar = self.lidar_topic
        except TopicError:
            return None
        adapter = LAYER_ADAPTERS.get(self.source.topics[lidar].schema)
        if adapter is None:
            return None
        for n, raw in enumerate(self.source.iter_raw([lidar])):
            if n >= LAYERS_SAMPLE_SCANS:
                break
            try:
                layers = adapter(self.source.decode(raw))
            except Exception:  # an undecodable message: the run counts and reports it
                continue
            if layers is not None:
                return layers
        return None

    def _count(self, reason: str, n: int = 1) -> None:
        if n:
            self.stats[reason] = self.stats.get(reason, 0) + n

    # --- other queries -------------------------------------------------------------------

    def positions_at(self, stamps_ns: np.ndarray, frame: str | None = None,
                     raws: Callable[[int, int], Iterable[RawLike]] | None = None
                     ) -> np.ndarray:
        """(K, 3) world-frame position of ``frame`` (default: the lidar) at each stamp; NaN
        rows where no pose fits.

        Uses the same pose source and interpolation as :meth:`scans`. ``raws(lo, hi)``: the
        pose messages logged in ``[lo, hi)``, as the source's ``iter_raw`` of the pose topics
        would yield them (default: that read; :meth:`gnss_span` hands over the ones it read).
        """
        stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
        out = np.full((stamps.size, 3), np.nan)
        if stamps.size == 0:
            return out
        frame = self.lidar_frame if frame is None else frame
        poses = self._pose_source()
        # the "lidar extrinsic for frame ..." line is about the lidar: not said for another
        # frame (the GNSS antenna's, placed by the geo-reference before the run)
        quiet = frame != self.lidar_frame and ("extrinsic", frame) not in self._said
        if quiet:
            self._said.add(("extrinsic", frame))
        try:
            self._positions(poses, frame, stamps, out, raws)
        finally:
            if quiet:
                self._said.discard(("extrinsic", frame))
        return out

    def _positions(self, poses: PoseSource, frame: str, stamps: np.ndarray,
                   out: np.ndarray,
                   raws: Callable[[int, int], Iterable[RawLike]] | None = None) -> None:
        order = np.argsort(stamps, kind="stable")
        queue = deque(int(i) for i in order)
        margin = self.max_gap_ns + WAIT_SLACK_NS

        def release(deadline: int | None) -> None:
            while queue:
                status, T = poses.lookup(frame, int(stamps[queue[0]]))
                if status == WAIT and deadline is not None and stamps[queue[0]] >= deadline:
                    return
                i = queue.popleft()
                if status == OK:
                    out[i] = T[:3, 3]

        lo, hi = int(stamps.min()) - margin, int(stamps.max()) + margin
        messages = (self.source.iter_raw(self.pose_topics[1], lo, hi) if raws is None
                    else raws(lo, hi))
        for raw in messages:
            poses.add(self._pose_records(raw))
            release(raw.log_time - margin)
            if not queue:  # every stamp placed: the rest of the span is not read
                return
            poses.prune(int(stamps[queue[0]]))
        release(None)

    @property
    def lidar_frame(self) -> str:
        """frame_id of the first lidar message."""
        if self._lidar_frame is None:
            self._lidar_frame = ""
            for raw in self.source.iter_raw([self.lidar_topic]):
                self._lidar_frame = self._scan(raw).frame_id
                break
        return self._lidar_frame

    def gnss_antenna_frame(self) -> str:
        """The frame the GNSS fixes locate: their ``frame_id`` when the pose source can place
        it (the vehicle body of the pose topic, or a frame TF links to it); otherwise the
        vehicle body of a pose topic, otherwise the lidar frame (each fallback logged once)."""
        frame = self._gnss_frame
        if frame is None:
            self.gnss_fixes()
            frame = self._gnss_frame or ""
        poses = self._pose_source()
        kind, _ = self.pose_topics
        if kind == "topic":
            for raw in self.source.iter_raw(self.pose_topics[1]):
                poses.add(self._pose_records(raw))
                break
            body = poses.body_frame
            if frame and (frame == body or poses.static.static_transform(body, frame)
                          is not None):
                return frame
            log.info("%s: GNSS frame '%s' is not linked to the vehicle body '%s' by TF; "
                     "taking the fixes at the body", self.path, frame, body)
            return body
        # TF: the frame may only appear in dynamic TF; positions_at gives NaN if it never does
        return frame or self.lidar_frame

    def gnss_spans(self) -> list[tuple[int | None, int | None]]:
        """The spans of log time ``[start_ns, end_ns)`` whose GNSS fixes geo-reference the log
        (:func:`evperc.runner.geo_reference`): the whole log, ``[(None, None)]``, unless it is
        longer than :data:`GNSS_SPANS` spans of :data:`GNSS_SPAN_S` and its source reads a span
        without reading what comes before (``seeks``); then those spans, spread evenly from
        its first message to its last. The fixes share chunks with the scans, so reading all
        of an hour's fixes decompressed the whole log twice before the first frame (14 s for a
        5-minute hdl64 drive; docs/performance.md)."""
        width = int(GNSS_SPAN_S * 1e9)
        start, end = self.source.start_ns, self.source.end_ns
        if (start is None or end is None or not self.source.seeks
                or end - start <= GNSS_SPANS * width):
            return [(None, None)]
        step = (end - start - width) / (GNSS_SPANS - 1)
        firsts = [start + round(k * step) for k in range(GNSS_SPANS)]
        return [(a, a + width) for a in firsts]

    def gnss_fixes(self, start_ns: int | None = None, end_ns: int | None = None
                   ) -> np.ndarray:
        """(K, 4) float64 rows (stamp_ns, lat_deg, lon_deg, alt_m), sorted by stamp, unique
        stamps, of the fixes logged in ``[start_ns, end_ns)`` (default: the whole log);
        fixes without a position (NavSatFix status −1, NaN) are left out. Empty (0, 4) when
        the log has no GNSS topic."""
        topic = self.gnss_topic
        if topic is None:
            return np.empty((0, 4))
        return self._fixes(topic, self.source.iter_raw([topic], start_ns, end_ns))

    def gnss_span(self, start_ns: int, end_ns: int) -> GnssSpan:
        """The fixes logged in ``[start_ns, end_ns)`` (:meth:`gnss_fixes`) and what places
        them (:meth:`positions_at` at their stamps), from one read of the log: the GNSS and
        pose topics together from ``max_pose_gap_s`` + 1 s before the span to its end — the
        messages a separate read of the fixes and then of the poses around them would each
        take from the same chunks, which hold the scans too (each chunk decompressed once
        instead of twice: docs/performance.md § "One read a span"). The poses read
        are kept for :meth:`GnssSpan.positions` (a span's: a few seconds of one topic); the
        poses after the span are read then, as far as the last fix needs. The same values as
        the two reads (tested), for fixes whose stamps lie in the span; otherwise
        :meth:`GnssSpan.positions` reads as :meth:`positions_at` does."""
        topic = self.gnss_topic
        if topic is None:
            return GnssSpan(self, np.empty((0, 4)), start_ns, end_ns, [])
        margin = self.max_gap_ns + WAIT_SLACK_NS
        fix_raws: list[RawLike] = []
        pose_raws: list[RawLike] = []
        for raw in self.source.iter_raw([topic, *self.pose_topics[1]], start_ns - margin,
                                        end_ns):
            if raw.topic != topic:
                pose_raws.append(raw)
            elif raw.log_time >= start_ns:
                fix_raws.append(raw)
        return GnssSpan(self, self._fixes(topic, fix_raws), start_ns - margin, end_ns,
                        pose_raws)

    def _fixes(self, topic: str, raws: Iterable[RawLike]) -> np.ndarray:
        """:meth:`gnss_fixes` of the messages ``raws`` of ``topic``."""
        adapter = GNSS_ADAPTERS[self.source.topics[topic].schema]
        rows = []
        for raw in raws:
            fix = adapter(self.source.decode(raw), raw.log_time)
            if fix is not None:
                if self._gnss_frame is None:
                    self._gnss_frame = fix.frame_id
                rows.append((fix.stamp_ns, fix.lat_deg, fix.lon_deg, fix.alt_m))
        if not rows:
            return np.empty((0, 4))
        fixes = np.asarray(rows, dtype=np.float64)
        _, first = np.unique(fixes[:, 0], return_index=True)
        return fixes[first]

    def info(self) -> dict[str, Any]:
        """Summary for ``evperc info``: file, index, topics, time span, detected topics, and the
        mean finite points per scan over the first ``INFO_SAMPLE_SCANS`` lidar messages."""
        topics = [{"topic": t.topic, "schema": t.schema, "encoding": t.message_encoding,
                   "messages": t.messages} for t in sorted(self.source.topics.values(),
                                                           key=lambda t: t.topic)]
        start, end = self.source.start_ns, self.source.end_ns
        out: dict[str, Any] = {
            "path": str(self.path),
            "kind": self.source.kind,
            "indexed": self.source.indexed,
            "complete": self.source.stop_reason is None,
            "stopped": self.source.stop_reason,
            "start_ns": start,
            "end_ns": end,
            "duration_s": None if start is None else (end - start) / 1e9,
            "topics": topics,
        }
        detected: dict[str, Any] = {}
        for role, getter in (("lidar_topic", lambda: self.lidar_topic),
                             ("pose_source", lambda: _pose_text(self.pose_topics)),
                             ("gnss_topic", lambda: self.gnss_topic)):
            try:
                detected[role] = getter()
            except TopicError as err:
                detected[role] = None
                detected[f"{role}_problem"] = str(err)
        detected["static_tf_topics"] = self.static_tf_topics
        out["detected"] = detected
        if detected.get("lidar_topic"):
            counts, frame = [], None
            for raw in self.source.iter_raw([detected["lidar_topic"]]):
                scan = self._decode_scan(raw)
                if scan is not None:
                    counts.append(len(scan.points))
                    frame = frame or scan.frame_id
                if len(counts) >= INFO_SAMPLE_SCANS:
                    break
            out["lidar_frame"] = frame
            out["mean_points_per_scan"] = float(np.mean(counts)) if counts else None
            out["points_sample_scans"] = len(counts)
        layers = self.sensor_layers()
        out["lidar_layers"] = None if layers is None else {"count": layers[0],
                                                            "from": layers[1]}
        return out


def _pose_text(pose: tuple[str, list[str]]) -> str:
    kind, topics = pose
    return topics[0] if kind == "topic" else f"TF tree ({', '.join(topics)})"


def _in_range(stamp: int, start: int | None, end: int | None) -> bool:
    return (start is None or stamp >= start) and (end is None or stamp < end)
