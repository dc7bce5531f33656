"""Pose buffers: where the sensor was at a given stamp, from a pose topic or a TF tree.

A :class:`PoseTrack` holds the recent samples of one moving frame (sorted by stamp) and
interpolates between the two samples that bracket a stamp (evperc.logs.transforms). A query
answers one of:

- ``OK`` with the 4×4 pose;
- ``WAIT``: no sample at or after the stamp yet (the caller waits for more messages);
- ``BEFORE``: the stamp precedes the first sample;
- ``GAP``: the bracketing samples are further apart than the allowed gap.

:class:`TransformTree` keeps static edges (``/tf_static``) and dynamic edges (one track per
parent→child pair) and composes the chain from a frame up to the world frame, each dynamic edge
interpolated at the query stamp. :class:`PoseTopicSource` and :class:`TfSource` turn these into
``T_world_sensor`` for a sensor frame.
"""

from __future__ import annotations

import bisect
import logging
from dataclasses import dataclass, field

import numpy as np

from evperc.errors import PoseError
from evperc.logs.mcap_messages import PoseRecord
from evperc.logs.transforms import interpolate_pose, pose_matrix

log = logging.getLogger(__name__)

OK, WAIT = "ok", "wait"
BEFORE, AFTER, GAP, NO_CHAIN = ("before_pose_span", "after_pose_span", "pose_gap",
                                "no_transform_chain")
_MAX_CHAIN = 64


@dataclass
class PoseTrack:
    """Samples (stamp_ns, translation, quaternion) of one moving frame, kept sorted by stamp."""

    stamps: list[int] = field(default_factory=list)
    translations: list[tuple[float, float, float]] = field(default_factory=list)
    rotations: list[tuple[float, float, float, float]] = field(default_factory=list)

    def add(self, stamp_ns: int, translation: tuple, rotation: tuple) -> bool:
        """Insert a sample in stamp order; False (and nothing stored) for a duplicate stamp."""
        i = bisect.bisect_left(self.stamps, stamp_ns)
        if i < len(self.stamps) and self.stamps[i] == stamp_ns:
            return False
        self.stamps.insert(i, stamp_ns)
        self.translations.insert(i, translation)
        self.rotations.insert(i, rotation)
        return True

    def sample(self, stamp_ns: int, max_gap_ns: int) -> tuple[str, np.ndarray | None]:
        """(status, 4×4 pose) at ``stamp_ns``; see the module docstring for the statuses."""
        if not self.stamps:
            return WAIT, None
        if stamp_ns < self.stamps[0]:
            return BEFORE, None
        if stamp_ns > self.stamps[-1]:
            return WAIT, None
        i = bisect.bisect_left(self.stamps, stamp_ns)
        if self.stamps[i] == stamp_ns:
            return OK, pose_matrix(self.translations[i], self.rotations[i])
        t0, t1 = self.stamps[i - 1], self.stamps[i]
        if t1 - t0 > max_gap_ns:
            return GAP, None
        alpha = (stamp_ns - t0) / (t1 - t0)
        return OK, interpolate_pose(self.translations[i - 1], self.rotations[i - 1],
                                    self.translations[i], self.rotations[i], alpha)

    def prune(self, keep_from_ns: int) -> None:
        """Forget samples before ``keep_from_ns``, except the last one before it."""
        i = bisect.bisect_right(self.stamps, keep_from_ns) - 1
        if i > 0:
            del self.stamps[:i], self.translations[:i], self.rotations[:i]

    def __len__(self) -> int:
        return len(self.stamps)


@dataclass
class TransformTree:
    """Frames linked child -> parent by static transforms and by dynamic (tracked) ones."""

    static: dict[str, tuple[str, np.ndarray]] = field(default_factory=dict)
    dynamic: dict[str, tuple[str, PoseTrack]] = field(default_factory=dict)

    def add_static(self, record: PoseRecord) -> None:
        self.static[record.child_frame_id] = (
            record.frame_id, pose_matrix(record.translation, record.rotation))

    def add_dynamic(self, record: PoseRecord) -> bool:
        """Add a sample of the parent→child edge; False for a duplicate stamp."""
        parent, track = self.dynamic.get(record.child_frame_id, (None, None))
        if parent != record.frame_id or track is None:
            if parent is not None:
                log.debug("frame %s re-parented from %s to %s", record.child_frame_id, parent,
                          record.frame_id)
            track = PoseTrack()
            self.dynamic[record.child_frame_id] = (record.frame_id, track)
        return track.add(record.stamp_ns, record.translation, record.rotation)

    def parent_of(self, frame: str) -> str | None:
        if frame in self.dynamic:
            return self.dynamic[frame][0]
        if frame in self.static:
            return self.static[frame][0]
        return None

    def root_of(self, frame: str) -> str:
        for _ in range(_MAX_CHAIN):
            parent = self.parent_of(frame)
            if parent is None:
                return frame
            frame = parent
        return frame

    def static_transform(self, ancestor: str, frame: str) -> np.ndarray | None:
        """T_ancestor_frame from static edges only, or None if they do not link the two."""
        T = np.eye(4)
        for _ in range(_MAX_CHAIN):
            if frame == ancestor:
                return T
            if frame not in self.static:
                return None
            parent, T_parent_frame = self.static[frame]
            T = T_parent_frame @ T
            frame = parent
        return None

    def lookup(self, world: str, frame: str, stamp_ns: int,
               max_gap_ns: int) -> tuple[str, np.ndarray | None]:
        """(status, T_world_frame) with every dynamic edge of the chain taken at ``stamp_ns``.

        ``WAIT`` also when the chain does not reach ``world`` yet (an edge may still come).
        """
        T = np.eye(4)
        for _ in range(_MAX_CHAIN):
            if frame == world:
                return OK, T
            if frame in self.dynamic:
                parent, track = self.dynamic[frame]
                status, T_parent_frame = track.sample(stamp_ns, max_gap_ns)
                if status != OK:
                    return status, None
            elif frame in self.static:
                parent, T_parent_frame = self.static[frame]
            else:
                return WAIT, None
            T = T_parent_frame @ T
            frame = parent
        return WAIT, None

    def prune(self, keep_from_ns: int) -> None:
        for _, track in self.dynamic.values():
            track.prune(keep_from_ns)


class PoseSource:
    """Base: poses of a sensor frame in the world, fed message by message."""

    static: TransformTree

    def add_static(self, records: list[PoseRecord]) -> None:
        for record in records:
            self.static.add_static(record)

    def add(self, records: list[PoseRecord]) -> int:
        """Feed pose records; returns how many were dropped as duplicate stamps."""
        raise NotImplementedError

    def lookup(self, sensor_frame: str, stamp_ns: int) -> tuple[str, np.ndarray | None]:
        raise NotImplementedError

    def prune(self, keep_from_ns: int) -> None:
        raise NotImplementedError

    def abandon_reason(self, sensor_frame: str) -> str:
        """Why a scan still waiting when its deadline passes is skipped."""
        return AFTER

    @property
    def world_frame_name(self) -> str | None:
        """The frame the poses are given in, once known (``T_world_sensor``'s world)."""
        raise NotImplementedError


class PoseTopicSource(PoseSource):
    """Poses of the vehicle (the message's child frame, or an unnamed body) from one topic.

    T_world_sensor = T_world_poseframe · T_poseframe_body(t) · T_body_sensor, where
    T_world_poseframe is the identity unless ``world_frame`` names another frame (then from
    static TF), and T_body_sensor comes from static TF if it links body and sensor, else from
    ``extrinsic``, else is the identity (with one warning).
    """

    def __init__(self, path: str, topic: str, max_gap_ns: int, world_frame: str | None,
                 extrinsic: np.ndarray | None, said: set | None = None):
        self.path, self.topic, self.max_gap_ns = path, topic, max_gap_ns
        self.said = set() if said is None else said  # messages already logged (once per log)
        self.world_frame = world_frame or None
        self.extrinsic = None if extrinsic is None else np.asarray(extrinsic, np.float64)
        self.static = TransformTree()
        self.track = PoseTrack()
        self.pose_frame: str | None = None
        self.body_frame: str = ""
        self._fixed: dict[str, np.ndarray] = {}

    def add(self, records: list[PoseRecord]) -> int:
        dropped = 0
        for record in records:
            if self.pose_frame is None:
                self.pose_frame, self.body_frame = record.frame_id, record.child_frame_id
            dropped += not self.track.add(record.stamp_ns, record.translation, record.rotation)
        return dropped

    def lookup(self, sensor_frame: str, stamp_ns: int) -> tuple[str, np.ndarray | None]:
        status, T_frame_body = self.track.sample(stamp_ns, self.max_gap_ns)
        if status != OK:
            return status, None
        return OK, self._world_from_poseframe() @ T_frame_body @ self._body_to_sensor(
            sensor_frame)

    @property
    def world_frame_name(self) -> str | None:
        return self.world_frame or self.pose_frame

    def _world_from_poseframe(self) -> np.ndarray:
        key = "__world__"
        if key not in self._fixed:
            T = np.eye(4)
            if self.world_frame and self.world_frame != self.pose_frame:
                T = self.static.static_transform(self.world_frame, self.pose_frame or "")
                if T is None:
                    raise PoseError(
                        f"{self.path}: poses on {self.topic} are in frame '{self.pose_frame}', "
                        f"and no static transform links it to world frame '{self.world_frame}';"
                        " leave input.world_frame empty to use the pose frame")
            self._fixed[key] = T
        return self._fixed[key]

    def _body_to_sensor(self, sensor_frame: str) -> np.ndarray:
        if sensor_frame in self._fixed:
            return self._fixed[sensor_frame]
        body = self.body_frame
        if not body and sensor_frame in self.static.static:
            body = self.static.root_of(sensor_frame)  # unnamed body: root of the static tree
        first_time = ("extrinsic", sensor_frame) not in self.said
        self.said.add(("extrinsic", sensor_frame))
        T = None
        if body == sensor_frame or not sensor_frame:
            T, how = np.eye(4), "the pose frame is the sensor frame"
        elif body and (T := self.static.static_transform(body, sensor_frame)) is not None:
            how = f"static TF {body} -> {sensor_frame}"
        elif self.extrinsic is not None:
            T, how = self.extrinsic, "the configured input.extrinsic"
        else:
            T, how = np.eye(4), "identity"
            if first_time:
                log.warning("%s: no static transform from the pose body '%s' (topic %s) to "
                            "lidar frame '%s' and no input.extrinsic; assuming the lidar sits "
                            "at the pose", self.path, body or "?", self.topic, sensor_frame)
        if first_time:
            log.info("%s: lidar extrinsic for frame '%s': %s", self.path, sensor_frame, how)
        self._fixed[sensor_frame] = T
        return T

    def prune(self, keep_from_ns: int) -> None:
        self.track.prune(keep_from_ns)


class TfSource(PoseSource):
    """Poses from the TF tree: the chain from the world frame down to the sensor frame.

    The world frame is ``world_frame`` if given, else the root of the tree above the sensor
    frame when the first scan is resolved (logged).
    """

    def __init__(self, path: str, max_gap_ns: int, world_frame: str | None,
                 said: set | None = None):
        self.path, self.max_gap_ns = path, max_gap_ns
        self.said = set() if said is None else said
        self.world_frame = world_frame or None
        self.static = TransformTree()
        self.tree = self.static  # static and dynamic edges live in one tree

    def add(self, records: list[PoseRecord]) -> int:
        return sum(not self.tree.add_dynamic(r) for r in records)

    @property
    def world_frame_name(self) -> str | None:
        return self.world_frame

    def lookup(self, sensor_frame: str, stamp_ns: int) -> tuple[str, np.ndarray | None]:
        world = self.world_frame
        if world is None:
            world = self.tree.root_of(sensor_frame)
            if not any(f in self.tree.dynamic for f in self._chain(sensor_frame)):
                return WAIT, None  # no moving edge above the sensor yet
        status, T = self.tree.lookup(world, sensor_frame, stamp_ns, self.max_gap_ns)
        if status == OK and self.world_frame is None:
            self.world_frame = world
            if ("world", world) not in self.said:
                self.said.add(("world", world))
                log.info("%s: world frame '%s' (root of the TF tree above '%s')", self.path,
                         world, sensor_frame)
        return status, T

    def abandon_reason(self, sensor_frame: str) -> str:
        chain = self._chain(sensor_frame)
        reaches = self.world_frame is None or self.world_frame in chain
        return AFTER if reaches and any(f in self.tree.dynamic for f in chain) else NO_CHAIN

    def _chain(self, frame: str) -> list[str]:
        chain = []
        for _ in range(_MAX_CHAIN):
            chain.append(frame)
            parent = self.tree.parent_of(frame)
            if parent is None:
                break
            frame = parent
        return chain

    def prune(self, keep_from_ns: int) -> None:
        self.tree.prune(keep_from_ns)
