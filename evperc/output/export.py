"""Export a run as an MCAP file for Foxglove (``evperc export RUN_DIR --out FILE``).

Per frame, on ``/evperc/grid``, one ``foxglove.Grid`` (protobuf) in frame ``evperc`` (the
run's working CRS, x east, y north, metres; ``--frame-id``): its ``pose`` is the window's
south-west corner
``(col0·r, row0·r)`` with identity orientation, so data row 0 is the southern row, exactly
the row order of the run (docs/conventions.md). Each cell holds, little-endian::

    offset  0..19  betp_F, betp_I, betp_U, betp_S, betp_M   float32
    offset 20      zeta                                     float32
    offset 24      decision                                 uint8 (run.decision_codes)
    offset 28..31  red, green, blue, alpha                  uint8: pignistic colour (method.md §6)

``cell_stride`` = 32 bytes, ``row_stride`` = 32 · cols. On ``/evperc/ego`` a
``foxglove.FrameTransform`` ``evperc`` → ``ego`` carries the vehicle pose (x, y, yaw). On
``/evperc/world`` a ``foxglove.FrameTransform`` ``evperc`` → the log's world frame (the
frame its poses are in, e.g. ``map`` or ``odom``: the manifest's ``world_frame``) places that
frame in the CRS (the run's geo-reference ``T_crs_world``, planar; the identity when the run
worked in the log's own frame). Open this file together with the log in Foxglove and the
grids lie under the log's point clouds. On ``/evperc/objects``, for a run with an object list
(``frame.objects``), one ``foxglove.SceneUpdate`` per frame: a box, a velocity arrow and a
label per object, entity id ``track-N``, and deletions of the tracks gone since the previous
exported frame (:mod:`evperc.output.scene`); a run without objects has no such channel. A
metadata record ``evperc`` names the CRS, resolution, frames and decision codes. Messages
are encoded with the foxglove-sdk's schemas and written with the ``mcap`` writer, at log
time = the frame's ``stamp_ns``.
"""

from __future__ import annotations

import json
import logging
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from evperc.errors import OutputError
from evperc.output.scene import OBJECTS_TOPIC, scene_message
from evperc.progress import bar
from evperc.render.colours import pignistic_colour

log = logging.getLogger(__name__)

GRID_TOPIC = "/evperc/grid"
EGO_TOPIC = "/evperc/ego"
WORLD_TOPIC = "/evperc/world"
#: the grids' frame: not ``map``, which many logs use for their own local world frame
DEFAULT_FRAME_ID = "evperc"
CLASSES = ("F", "I", "U", "S", "M")
CELL_STRIDE = 32
#: (name, numpy type, byte offset, foxglove NumericType name) of each cell field
CELL_FIELDS: tuple[tuple[str, str, int, str], ...] = (
    *((f"betp_{k}", "<f4", 4 * i, "Float32") for i, k in enumerate(CLASSES)),
    ("zeta", "<f4", 20, "Float32"),
    ("decision", "u1", 24, "Uint8"),
    ("red", "u1", 28, "Uint8"), ("green", "u1", 29, "Uint8"), ("blue", "u1", 30, "Uint8"),
    ("alpha", "u1", 31, "Uint8"),
)
CELL_DTYPE = np.dtype({"names": [f[0] for f in CELL_FIELDS],
                       "formats": [f[1] for f in CELL_FIELDS],
                       "offsets": [f[2] for f in CELL_FIELDS], "itemsize": CELL_STRIDE})


def pack_cells(frame: Any) -> bytes:
    """The Grid ``data`` of a frame: rows south → north, columns west → east."""
    rows, cols = frame.window.shape
    cells = np.zeros((rows, cols), dtype=CELL_DTYPE)
    betp = np.asarray(frame.betp, dtype=np.float32)
    for i, k in enumerate(CLASSES):
        cells[f"betp_{k}"] = betp[..., i]
    cells["zeta"] = frame.zeta
    cells["decision"] = frame.decision
    rgb = pignistic_colour(betp)
    cells["red"], cells["green"], cells["blue"] = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    cells["alpha"] = 255
    return cells.tobytes()


def _timestamp(stamp_ns: int) -> Any:
    from foxglove.messages import Timestamp

    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return Timestamp(sec, nsec)


def grid_message(frame: Any, frame_id: str = DEFAULT_FRAME_ID) -> bytes:
    """The encoded ``foxglove.Grid`` of one frame."""
    from foxglove.messages import (
        Grid,
        PackedElementField,
        PackedElementFieldNumericType,
        Pose,
        Quaternion,
        Vector2,
        Vector3,
    )

    w = frame.window
    fields = [PackedElementField(name=name, offset=offset,
                                 type=getattr(PackedElementFieldNumericType, kind))
              for name, _, offset, kind in CELL_FIELDS]
    corner = Pose(position=Vector3(x=w.col0 * w.resolution_m, y=w.row0 * w.resolution_m, z=0.0),
                  orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))
    grid = Grid(timestamp=_timestamp(frame.stamp_ns), frame_id=frame_id, pose=corner,
                column_count=w.cols, cell_size=Vector2(x=w.resolution_m, y=w.resolution_m),
                row_stride=CELL_STRIDE * w.cols, cell_stride=CELL_STRIDE, fields=fields,
                data=pack_cells(frame))
    return grid.encode()


def ego_message(frame: Any, frame_id: str = DEFAULT_FRAME_ID, ego_frame_id: str = "ego"
                ) -> bytes:
    """The encoded ``foxglove.FrameTransform`` ``frame_id`` → ``ego_frame_id`` (pose x, y, yaw)."""
    x, y, yaw = (float(v) for v in np.asarray(frame.pose)[:3])
    return _planar_transform(frame.stamp_ns, frame_id, ego_frame_id, x, y, 0.0, yaw)


def world_message(stamp_ns: int, T_crs_world: np.ndarray, frame_id: str, world_frame: str
                  ) -> bytes:
    """The encoded ``foxglove.FrameTransform`` ``frame_id`` (the CRS) → ``world_frame`` (the
    log's): ``T_crs_world``, a rotation about the vertical and a translation (evperc's
    geo-references are planar, :mod:`evperc.geo.georef`)."""
    T = np.asarray(T_crs_world, dtype=np.float64)
    yaw = math.atan2(T[1, 0], T[0, 0])
    return _planar_transform(stamp_ns, frame_id, world_frame, *(float(v) for v in T[:3, 3]),
                             yaw)


def _planar_transform(stamp_ns: int, parent: str, child: str, x: float, y: float, z: float,
                      yaw: float) -> bytes:
    from foxglove.messages import FrameTransform, Quaternion, Vector3

    return FrameTransform(
        timestamp=_timestamp(stamp_ns), parent_frame_id=parent, child_frame_id=child,
        translation=Vector3(x=x, y=y, z=z),
        rotation=Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))).encode()


def export_mcap(run: Any, mcap_path: str | Path, *, frames: slice = slice(None),
                frame_id: str = DEFAULT_FRAME_ID, ego_frame_id: str = "ego",
                overwrite: bool = False) -> dict[str, Any]:
    """Write the selected frames of ``run`` to ``mcap_path`` (see the module docstring).

    The file appears only when complete (written under a temporary name, then renamed).
    Returns ``{"frames", "path", "topics"}``."""
    from foxglove.messages import FrameTransform, Grid, SceneUpdate
    from mcap.writer import Writer

    from evperc.render.run_render import select_frames

    path = Path(mcap_path)
    if path.exists() and not overwrite:
        raise OutputError(f"{path}: exists; pass --overwrite or choose another --out")
    if not path.parent.is_dir():
        raise OutputError(f"{path}: folder {path.parent} does not exist")
    world_frame = run.manifest.get("world_frame")
    T_crs_world = run.manifest.get("T_crs_world")
    T_crs_world = np.eye(4) if T_crs_world is None else np.asarray(T_crs_world, np.float64)
    if world_frame == frame_id:
        log.warning("%s: the log's world frame is also '%s'; choose another --frame-id to "
                    "link the grids to the log", path, frame_id)
        world_frame = None
    elif not world_frame:
        log.info("%s: the run does not name the log's world frame (run made before "
                 "2026-11-26, or unfinished): grids not linked to the log", path)
    tmp = path.with_name(f".{path.name}.tmp")
    count = 0
    try:
        with tmp.open("wb") as stream:
            writer = Writer(stream)
            writer.start(profile="", library="evperc")
            channels = {}
            schemas: dict[str, int] = {}

            def register(topic: str, message: Any) -> None:
                schema = message.get_schema()
                if schema.name not in schemas:
                    schemas[schema.name] = writer.register_schema(schema.name, schema.encoding,
                                                                  schema.data)
                channels[topic] = writer.register_channel(topic, "protobuf",
                                                          schemas[schema.name])

            for topic, message in ((GRID_TOPIC, Grid), (EGO_TOPIC, FrameTransform),
                                   (WORLD_TOPIC, FrameTransform)):
                register(topic, message)
            writer.add_metadata("evperc", {
                "crs": str(run.manifest.get("crs", "local")),
                "resolution_m": repr(float(run.manifest.get("resolution_m", 0.0))),
                "frame_id": frame_id, "ego_frame_id": ego_frame_id,
                "world_frame": world_frame or "",
                "decision_codes": json.dumps(dict(run.decision_codes), sort_keys=True),
                "source": str(getattr(run, "out_dir", ""))})
            total = len(range(*frames.indices(len(run))))
            shown: set[str] = set()  # the object entities of the previous exported frame
            for frame in bar(select_frames(run, frames), total=total, desc="export"):
                stamp = int(frame.stamp_ns)
                if frame.objects is not None:
                    if OBJECTS_TOPIC not in channels:  # a run lists objects in every frame
                        register(OBJECTS_TOPIC, SceneUpdate)
                    scene, shown = scene_message(frame.objects, _timestamp(stamp), frame_id,
                                                 shown)
                    writer.add_message(channels[OBJECTS_TOPIC], stamp, scene, stamp,
                                       sequence=count)
                writer.add_message(channels[GRID_TOPIC], stamp, grid_message(frame, frame_id),
                                   stamp, sequence=count)
                writer.add_message(channels[EGO_TOPIC], stamp,
                                   ego_message(frame, frame_id, ego_frame_id), stamp,
                                   sequence=count)
                if world_frame:
                    writer.add_message(channels[WORLD_TOPIC], stamp,
                                       world_message(stamp, T_crs_world, frame_id, world_frame),
                                       stamp, sequence=count)
                count += 1
            writer.finish()
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"{path}: cannot write ({err.strerror})") from err
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if OBJECTS_TOPIC not in channels:
        log.info("%s: the run has no object list (objects.enabled = false, or made before "
                 "it): no %s", path, OBJECTS_TOPIC)
    topics = [t for t in channels if t != WORLD_TOPIC or world_frame]
    log.info("%d frames -> %s (%s)", count, path, ", ".join(topics))
    return {"frames": count, "path": path, "topics": topics}
