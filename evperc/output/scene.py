"""A frame's object list as a ``foxglove.SceneUpdate`` (``evperc export``, ``/evperc/objects``).

One ``SceneEntity`` per object record (:data:`evperc.output.objects.OBJECT_DTYPE`), id
``track-N`` (N the track id, stable over the track), in the grids' frame (the CRS):

* a cube on the ground over the bbox: centre ``((xmin+xmax)/2, (ymin+ymax)/2, h/2)``, size
  ``(extent_x, extent_y, h)`` with ``h`` = :data:`BOX_HEIGHT_M`; red for moving, orange for
  stopped, semi-transparent so the grid shows through;
* for a moving object an arrow from the centroid along the velocity, as long as the way the
  object goes in :data:`ARROW_SECONDS` (shaft and head together);
* a text label ``id N  v.v m/s`` above the cube (the speed ``|v|``);
* metadata (shown in Foxglove's object inspector): state, velocity, speed, speed sigma,
  mean betP(M), cells, age.

Foxglove keeps an entity until an entity of the same id replaces it or a deletion removes it
(``lifetime`` zero, the schema's "remain visible until it is replaced or deleted"). So each
update also deletes (``MATCHING_ID``) every track of the previous exported frame that is not
in this one, with the frame's timestamp: the deletion removes only entities older than it.
A lifetime of one frame period instead would blink when frames are late and would not hold
for ``--frames A:B:STEP``. Entities are ``frame_locked``: fixed in the CRS frame, they stay
put whatever frame Foxglove displays in.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from evperc.output.objects import OBJECT_STATES

OBJECTS_TOPIC = "/evperc/objects"
#: height of the drawn boxes (m): the object list is 2-D; a car's height, for the eye only
BOX_HEIGHT_M = 1.5
#: an arrow is as long as the way the object goes in this time at its speed (s)
ARROW_SECONDS = 1.0
ARROW_HEAD_M = 0.4
#: RGBA, 0..1, per state code
STATE_COLOURS = {OBJECT_STATES["moving"]: (1.0, 0.1, 0.1, 0.5),
                 OBJECT_STATES["stopped"]: (1.0, 0.55, 0.0, 0.5)}
STATE_NAMES = {code: name for name, code in OBJECT_STATES.items()}


def entity_id(track_id: int) -> str:
    """The SceneEntity id of a track."""
    return f"track-{int(track_id)}"


def scene_message(objects: np.ndarray, stamp: Any, frame_id: str,
                  previous: set[str]) -> tuple[bytes, set[str]]:
    """The encoded ``foxglove.SceneUpdate`` of one frame's ``objects`` and the entity ids it
    shows. ``stamp``: the frame's ``foxglove.Timestamp``; ``previous``: the ids shown by the
    previous exported frame (deleted here if gone)."""
    from foxglove.messages import SceneEntityDeletion, SceneEntityDeletionType, SceneUpdate

    entities = [_entity(o, stamp, frame_id) for o in objects]
    shown = {entity_id(o["track_id"]) for o in objects}
    deletions = [SceneEntityDeletion(timestamp=stamp,
                                     type=SceneEntityDeletionType.MatchingId, id=gone)
                 for gone in sorted(previous - shown)]
    return SceneUpdate(deletions=deletions, entities=entities).encode(), shown


def _entity(o: np.void, stamp: Any, frame_id: str) -> Any:
    from foxglove.messages import (
        ArrowPrimitive,
        Color,
        CubePrimitive,
        Duration,
        KeyValuePair,
        SceneEntity,
        TextPrimitive,
        Vector3,
    )

    xmin, ymin, xmax, ymax = (float(v) for v in o["bbox_m"])
    vx, vy = (float(v) for v in o["velocity_m_per_s"])
    speed = math.hypot(vx, vy)
    state = int(o["state"])
    r, g, b, a = STATE_COLOURS.get(state, (0.5, 0.5, 0.5, 0.5))
    colour, white = Color(r=r, g=g, b=b, a=a), Color(r=1.0, g=1.0, b=1.0, a=1.0)
    cube = CubePrimitive(
        pose=_pose((xmin + xmax) / 2, (ymin + ymax) / 2, BOX_HEIGHT_M / 2),
        size=Vector3(x=float(o["extent_m"][0]), y=float(o["extent_m"][1]), z=BOX_HEIGHT_M),
        color=colour)
    arrows = []
    length = speed * ARROW_SECONDS
    if state == OBJECT_STATES["moving"] and length > 0:
        head = min(ARROW_HEAD_M, length / 2)
        arrows.append(ArrowPrimitive(
            pose=_pose(float(o["centroid_m"][0]), float(o["centroid_m"][1]), BOX_HEIGHT_M / 2,
                       math.atan2(vy, vx)),
            shaft_length=length - head, shaft_diameter=0.1, head_length=head,
            head_diameter=0.3, color=white))
    label = TextPrimitive(
        pose=_pose(float(o["centroid_m"][0]), float(o["centroid_m"][1]), BOX_HEIGHT_M + 0.5),
        billboard=True, font_size=14.0, scale_invariant=True, color=white,
        text=f"id {int(o['track_id'])}  {speed:.1f} m/s")
    metadata = {
        "state": STATE_NAMES.get(state, str(state)),
        "velocity_m_per_s": f"{vx:.2f}, {vy:.2f}",
        "speed_m_per_s": f"{speed:.2f}",
        "speed_sigma_m_per_s": f"{float(o['speed_sigma_m_per_s']):.2f}",
        "mean_betp_moving": f"{float(o['mean_betp_moving']):.3f}",
        "cell_count": str(int(o["cell_count"])),
        "age_frames": str(int(o["age_frames"])),
    }
    return SceneEntity(
        timestamp=stamp, frame_id=frame_id, id=entity_id(o["track_id"]),
        lifetime=Duration(0, 0), frame_locked=True,
        metadata=[KeyValuePair(key=k, value=v) for k, v in metadata.items()],
        arrows=arrows, cubes=[cube], texts=[label])


def _pose(x: float, y: float, z: float, yaw: float = 0.0) -> Any:
    from foxglove.messages import Pose, Quaternion, Vector3

    return Pose(position=Vector3(x=x, y=y, z=z),
                orientation=Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)))
