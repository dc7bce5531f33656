"""Pictures of single frames: where cells land, north up, legend, scale bar, ego, trace."""

from __future__ import annotations

import math

import numpy as np
import shapely

from evperc.render.colours import CLASS_COLOURS, STATIC_COLOUR
from evperc.render.frame import FrameRenderer, render_frame
from evperc.render.map_outlines import MapOutlines
from tests.render.conftest import CODES, make_frame

FAR = (-1000.0, -1000.0, 0.0)   # ego pose outside the window: nothing drawn over the cells


def cell_pixel(layout, j: int, row: int, col: int, rows: int) -> tuple[int, int]:
    """(y, x) of the centre pixel of grid cell (row, col) in panel j: row 0 is the south,
    so it is drawn at the bottom of the panel."""
    left, top = layout.panel_origin(0, j)
    px = layout.cell_px
    return top + (rows - 1 - row) * px + px // 2, left + col * px + px // 2


def test_cells_land_north_up_with_their_colours() -> None:
    rows, cols = 8, 10
    frame = make_frame(rows, cols, pose=FAR)
    frame.decision[0, 0] = CODES["moving"]           # south-west corner
    frame.decision[7, 9] = CODES["infrastructure"]   # north-east corner
    frame.decision[7, 0] = CODES["unknown"]          # north-west corner
    frame.betp[7, 0] = [0, 0, 0, 0, 1]               # moving: red
    frame.betp[0, 9] = [0, 0, 1, 0, 0]               # unmapped: magenta
    renderer = FrameRenderer(("betp", "decision"), CODES, cell_px=10)
    image = renderer.render(frame)
    layout = renderer.layout
    assert image.shape == (layout.height, layout.width, 3) and image.dtype == np.uint8

    def at(j: int, row: int, col: int) -> tuple[int, ...]:
        y, x = cell_pixel(layout, j, row, col, rows)
        return tuple(int(v) for v in image[y, x])

    assert at(0, 7, 0) == (255, 0, 0)
    assert at(0, 0, 9) == (255, 0, 255)
    assert at(0, 3, 3) == (0, 255, 0)
    assert at(1, 0, 0) == (255, 0, 0)
    assert at(1, 7, 9) == (150, 150, 255)   # infrastructure is static in 4 colours
    assert at(1, 7, 0) == (0, 0, 0)
    assert at(1, 4, 4) == (0, 255, 0)
    # the south-west cell is the bottom-left block of the panel: its 10x10 pixels are red
    left, top = layout.panel_origin(0, 1)
    block = image[top + 70:top + 80, left:left + 10]
    assert np.all(block == (255, 0, 0))


def test_fine_decision_and_zeta_and_conflict_layers() -> None:
    rows, cols = 4, 4
    frame = make_frame(rows, cols, pose=FAR)
    frame.decision[1, 2] = CODES["unmapped"]
    frame.zeta[2, 1] = 1.0
    frame.conflict[3, 3] = [1.0, 0.0, 0.0]
    renderer = FrameRenderer(("decision6", "zeta", "conflict"), CODES, cell_px=8)
    image = renderer.render(frame)
    layout = renderer.layout

    def at(j: int, row: int, col: int) -> tuple[int, ...]:
        y, x = cell_pixel(layout, j, row, col, rows)
        return tuple(int(v) for v in image[y, x])

    assert at(0, 1, 2) == (255, 0, 255)
    assert at(0, 0, 0) == (0, 255, 0)
    assert at(1, 2, 1) == (252, 255, 164) and at(1, 0, 0) == (0, 0, 0)
    assert at(2, 3, 3) == (255, 0, 0) and at(2, 0, 0) == (0, 0, 0)


def count_colour(region: np.ndarray, rgb: tuple[int, int, int]) -> int:
    return int(np.all(region == rgb, axis=-1).sum())


def test_legend_swatches_are_in_the_legend_region() -> None:
    frame = make_frame(40, 40, pose=FAR)
    renderer = FrameRenderer(("betp", "decision"), CODES)
    image = renderer.render(frame)
    layout = renderer.layout
    for j, colours in enumerate([
            [(0, 255, 0), (0, 0, 255), (255, 0, 255), (255, 160, 0), (255, 0, 0),
             (128, 128, 0), (191, 104, 64), (0, 0, 0)],
            [(0, 255, 0), (255, 0, 0), (150, 150, 255), (0, 0, 0)]]):
        left, top, right, bottom = layout.legend_box(0, j)
        region = image[top:bottom, left:right]
        for rgb in colours:
            assert count_colour(region, rgb) >= 64, (j, rgb)   # an 8x8 swatch at least
    # the betP panel is all free (green): its legend colours other than green are legend-only
    left, top, right, bottom = layout.panel_box(0, 0)
    assert count_colour(image[top:bottom, left:right], (255, 0, 255)) == 0


def longest_dark_run(region: np.ndarray) -> int:
    dark = np.all(region < 80, axis=-1)
    best = 0
    for line in dark:           # test code: a plain loop is fine
        run = 0
        for v in line:
            run = run + 1 if v else 0
            best = max(best, run)
    return best


def test_scale_bar_has_the_length_it_claims() -> None:
    # 40 cells × 0.5 m = 20 m panel; a quarter is 5 m, a round length; auto scale 400 // 40 =
    # 10 px per cell → 5 m = 10 cells = 100 px
    frame = make_frame(40, 40, pose=FAR)
    renderer = FrameRenderer(("decision",), CODES)
    image = renderer.render(frame)
    layout = renderer.layout
    assert layout.cell_px == 10
    left, top, right, bottom = layout.footer_box()
    assert longest_dark_run(image[top:bottom, left:right]) == 100
    assert renderer.compositor.scale_bar.length_m == 5.0


def test_north_arrow_and_time_are_drawn_in_the_footer() -> None:
    frame = make_frame(40, 40, pose=FAR, stamp_ns=2_500_000_000, index=7)
    renderer = FrameRenderer(("decision",), CODES, t0_ns=1_000_000_000)
    assert renderer.time_text(frame) == "t = 1.50 s   frame 7"
    image = renderer.render(frame)
    left, top, right, bottom = renderer.layout.footer_box()
    arrow = image[top:bottom, right - 24:right]
    assert np.all(arrow < 80, axis=-1).sum() > 30
    text = image[top:top + 24, left:left + 150]
    assert np.all(text < 80, axis=-1).sum() > 30


def ego_pixels(yaw: float) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    rows = cols = 40
    pose = (10.0, 10.0, yaw)                     # the window centre (20 m × 20 m)
    frame = make_frame(rows, cols, pose=pose)
    renderer = FrameRenderer(("decision",), CODES)
    image = renderer.render(frame)
    left, top = renderer.layout.panel_origin(0, 0)
    px = renderer.layout.cell_px
    centre = (top + int(round((rows - 10.0 / 0.5) * px)), left + int(round(10.0 / 0.5 * px)))
    from evperc.render.compose import EGO_FILL

    assert EGO_FILL not in (*CLASS_COLOURS.values(), STATIC_COLOUR)
    ys, xs = np.nonzero(np.all(image == EGO_FILL, axis=-1))
    return ys, xs, centre


def test_ego_is_drawn_at_the_pose_pointing_along_the_heading() -> None:
    ys, xs, (cy, cx) = ego_pixels(math.pi / 2)       # heading north = up in the image
    assert len(ys) > 100
    assert abs(np.median(xs) - cx) <= 2
    assert ys.min() < cy < ys.max()
    top_width = np.ptp(xs[ys <= ys.min() + 5])
    bottom_width = np.ptp(xs[ys >= ys.max() - 5])
    assert top_width < bottom_width                  # the tip is at the north end
    ys, xs, (cy, cx) = ego_pixels(0.0)               # heading east = right in the image
    right_height = np.ptp(ys[xs >= xs.max() - 5])
    left_height = np.ptp(ys[xs <= xs.min() + 5])
    assert right_height < left_height


def test_trace_accumulates_moving_cells_across_a_scroll() -> None:
    rows, cols = 6, 6
    renderer = FrameRenderer(("trace",), CODES, cell_px=6)
    first = make_frame(rows, cols, pose=FAR, stamp_ns=0)
    first.decision[2, 3] = CODES["moving"]                  # global (2, 3)
    renderer.render(first)
    second = make_frame(rows, cols, row0=1, col0=2, pose=FAR, stamp_ns=100)
    image = renderer.render(second)                          # the cell is now free
    layout = renderer.layout
    y, x = cell_pixel(layout, 0, 2 - 1, 3 - 2, rows)
    assert tuple(image[y, x]) == (255, 0, 0)
    y, x = cell_pixel(layout, 0, 0, 0, rows)                 # never moving: dimmed green
    r, g, b = (int(v) for v in image[y, x])
    assert r == 0 and b == 0 and 70 <= g <= 80
    # render_frame has no memory: the second frame alone shows no trace
    alone = render_frame(second, ("trace",), CODES, cell_px=6)
    pl, pt, pr, pb = layout.panel_box(0, 0)
    assert count_colour(alone[pt:pb, pl:pr], (255, 0, 0)) == 0
    assert count_colour(image[pt:pb, pl:pr], (255, 0, 0)) == 36     # one 6x6 cell


def test_map_outlines_are_drawn_where_the_polygons_are() -> None:
    rows = cols = 20                                          # 1 m cells, 10 px each
    frame = make_frame(rows, cols, resolution_m=1.0, pose=FAR)
    outlines = MapOutlines(buildings=[shapely.box(5, 5, 15, 15)])
    renderer = FrameRenderer(("betp",), CODES, cell_px=10, outlines=outlines)
    image = renderer.render(frame)
    left, top = renderer.layout.panel_origin(0, 0)
    white = np.all(image == (255, 255, 255), axis=-1)
    # west edge x = 5 m → column left + 50, spanning y 15 m .. 5 m → rows top + 50 .. top + 150
    assert white[top + 52:top + 148, left + 50].all()
    # south edge y = 5 m → image row top + (20 - 5) · 10 = top + 150 (an edge belongs north)
    assert white[top + 149:top + 151, left + 52:left + 148].any(axis=0).all()
    assert not white[top + 100, left + 100]                   # inside: the cell colour
    assert not white[top + 20, left + 20]                     # outside
