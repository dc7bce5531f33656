"""Objects drawn over the panels: outline, id and velocity arrow at the right pixels."""

from __future__ import annotations

import numpy as np

from evperc.output.objects import OBJECT_DTYPE, OBJECT_STATES
from evperc.render.colours import OBJECT_COLOURS
from evperc.render.frame import FrameRenderer

from .conftest import make_frame

PX = 10


def _object(state: str, vx: float) -> np.ndarray:
    o = np.zeros(1, OBJECT_DTYPE)
    o["track_id"] = 7
    o["state"] = OBJECT_STATES[state]
    o["bbox_m"] = [5.0, 10.0, 6.5, 11.0]       # cols 10..12, rows 20..21 of a 0.5 m grid
    o["centroid_m"] = [5.75, 10.5]
    o["velocity_m_per_s"] = [vx, 0.0]
    return o


def _mask(image: np.ndarray, rgb: tuple[int, int, int]) -> np.ndarray:
    return (image == np.array(rgb, np.uint8)).all(axis=-1)


def test_moving_object_outline_and_arrow_where_the_bbox_and_velocity_say():
    frame = make_frame(40, 40, pose=(1.0, 1.0, 0.0))
    renderer = FrameRenderer(("decision",), cell_px=PX)
    frame.objects = _object("moving", 2.0)
    image = renderer.render(frame)
    left, top, _, _ = renderer.layout.panel_box(0, 0)
    moving_px = _mask(image, OBJECT_COLOURS["moving"])
    # bbox x 5.0..6.5 m -> cols 10..13 (edges) -> u = left + 100 .. left + 130;
    # y 10.0..11.0 m -> rows 20..22 from the south of 40 -> v = top + 180 .. top + 200
    assert moving_px[top + 180:top + 200, left + 100].all()      # west edge
    assert moving_px[top + 180, left + 100:left + 130].all()     # north edge
    # arrow: 2 m/s over 1 s from x 5.75 to 7.75 m -> u = left + 115 .. left + 155, v = top + 190
    assert moving_px[top + 190, left + 132:left + 150].all()
    frame.objects = _object("stopped", 0.0)
    image = FrameRenderer(("decision",), cell_px=PX).render(frame)
    assert not _mask(image, OBJECT_COLOURS["moving"])[top:top + 400, left:left + 400].any()
    stopped_px = _mask(image, OBJECT_COLOURS["stopped"])
    assert stopped_px[top + 180:top + 200, left + 100].all()
    assert not stopped_px[top + 190, left + 135:left + 150].any()   # no arrow when still


def test_frames_without_objects_draw_none():
    frame = make_frame(40, 40)
    renderer = FrameRenderer(("decision",), cell_px=PX)
    image = renderer.render(frame)
    left, top, right, bottom = renderer.layout.panel_box(0, 0)
    assert not _mask(image, OBJECT_COLOURS["moving"])[top:bottom, left:right].any()
    frame.objects = _object("moving", 2.0)
    off = FrameRenderer(("decision",), cell_px=PX, objects=False).render(frame)
    assert not _mask(off, OBJECT_COLOURS["moving"]).any()
