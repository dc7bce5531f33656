"""Composing layer panels into one picture: titles, legends, scale bar, north arrow, ego, time.

Layout (pixels, x right, y down)::

    MARGIN
    +-- title --+  +-- title --+        one grid row of panels per run row (compare: per layer)
    |  panel    |  |  panel    |        panel = grid flipped north-up, each cell cell_px²
    +-----------+  +-----------+
    legend lines   legend lines
    ...
    footer: time text | scale bar (label above) | north arrow

Everything that does not change between frames (background, titles, legends, scale bar,
north arrow) is drawn once into a template; a frame copies it and pastes the panels.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from evperc.geo.window import Window
from evperc.output.objects import OBJECT_STATES
from evperc.render.colours import OBJECT_COLOURS
from evperc.render.draw import draw_segments, upscale
from evperc.render.map_outlines import MapOutlines

RGB = tuple[int, int, int]

MARGIN = 8
GAP = 10
TITLE_H = 16
LEGEND_LINE_H = 14
LEGEND_PAD = 4
SWATCH = 10
FOOTER_H = 44
MIN_WIDTH = 380
TIME_W = 170
BACKGROUND: RGB = (255, 255, 255)
INK: RGB = (0, 0, 0)
EGO_FILL: RGB = (0, 255, 255)  # cyan: no class or decision colour
EGO_EDGE: RGB = (255, 255, 255)
EGO_LENGTH_M = 4.5
EGO_WIDTH_M = 2.0
SCALE_BAR_THICKNESS = 3

_font: ImageFont.ImageFont | ImageFont.FreeTypeFont | None = None


def font() -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    """Pillow's built-in default font (loaded once)."""
    global _font
    if _font is None:
        try:
            _font = ImageFont.load_default(size=12)
        except (TypeError, ImportError, OSError):  # Pillow without FreeType: bitmap font
            _font = ImageFont.load_default()
    return _font


def text_width(text: str) -> int:
    return int(math.ceil(font().getlength(text)))


@dataclass(frozen=True, eq=False)
class Panel:
    """One layer of one frame, ready to be composed."""

    title: str
    rgb: np.ndarray                          # (rows, cols, 3) uint8, row 0 = south
    legend: tuple[tuple[RGB, str], ...]
    window: Window
    pose: np.ndarray | None = None           # x_m, y_m, yaw_rad (working CRS)
    outlines: MapOutlines | None = None
    #: the frame's object list (evperc.output.objects.OBJECT_DTYPE records), drawn over
    objects: np.ndarray | None = None


#: seconds of travel the velocity arrow of an object shows
ARROW_S = 1.0


@dataclass(frozen=True)
class Layout:
    """Pixel geometry of a picture with ``grid_rows × grid_cols`` equal panels."""

    grid_rows: int
    grid_cols: int
    panel_h: int
    panel_w: int
    cell_px: int
    legend_lines: int
    width: int
    height: int

    @property
    def row_h(self) -> int:
        return TITLE_H + self.panel_h + LEGEND_PAD + self.legend_lines * LEGEND_LINE_H + GAP

    def panel_origin(self, i: int, j: int) -> tuple[int, int]:
        """(left, top) pixel of panel (grid row i, grid column j)."""
        return MARGIN + j * (self.panel_w + GAP), MARGIN + i * self.row_h + TITLE_H

    def panel_box(self, i: int, j: int) -> tuple[int, int, int, int]:
        left, top = self.panel_origin(i, j)
        return left, top, left + self.panel_w, top + self.panel_h

    def legend_box(self, i: int, j: int) -> tuple[int, int, int, int]:
        left, top, right, bottom = self.panel_box(i, j)
        return left, bottom + LEGEND_PAD, right, bottom + LEGEND_PAD + \
            self.legend_lines * LEGEND_LINE_H

    def footer_box(self) -> tuple[int, int, int, int]:
        top = MARGIN + self.grid_rows * self.row_h
        return MARGIN, top, self.width - MARGIN, top + FOOTER_H


def make_layout(grid_rows: int, grid_cols: int, rows: int, cols: int, cell_px: int,
                legend_lines: int) -> Layout:
    panel_h, panel_w = rows * cell_px, cols * cell_px
    width = max(MIN_WIDTH, 2 * MARGIN + grid_cols * panel_w + (grid_cols - 1) * GAP)
    body = grid_rows * (TITLE_H + panel_h + LEGEND_PAD + legend_lines * LEGEND_LINE_H + GAP)
    height = MARGIN + body + FOOTER_H + MARGIN
    return Layout(grid_rows, grid_cols, panel_h, panel_w, cell_px, legend_lines, width, height)


def legend_positions(items: Sequence[tuple[RGB, str]], width: int
                     ) -> list[tuple[int, int, RGB, str]]:
    """(dx, line, colour, label) of each legend item, wrapped to ``width`` pixels."""
    out = []
    x, line = 0, 0
    for colour, label in items:
        w = SWATCH + 4 + text_width(label) + 10
        if x > 0 and x + w > width:
            x, line = 0, line + 1
        out.append((x, line, colour, label))
        x += w
    return out


def nice_length(max_m: float) -> float:
    """The largest 1, 2 or 5 × 10^k metres not above ``max_m``."""
    k = math.floor(math.log10(max_m))
    best = 10.0 ** k
    for step in (1.0, 2.0, 5.0, 10.0):
        if step * 10.0 ** k <= max_m:
            best = step * 10.0 ** k
    return best


def format_metres(length_m: float) -> str:
    if length_m >= 1000:
        return f"{length_m / 1000:g} km"
    return f"{length_m:g} m"


@dataclass(frozen=True)
class ScaleBar:
    left: int
    top: int
    length_px: int
    length_m: float


def scale_bar_for(layout: Layout, resolution_m: float) -> ScaleBar:
    """A bar of a round length no longer than a quarter of a panel."""
    panel_m = layout.panel_w / layout.cell_px * resolution_m
    length_m = nice_length(max(panel_m / 4.0, resolution_m))
    length_px = int(round(length_m / resolution_m * layout.cell_px))
    _, top, _, _ = layout.footer_box()
    return ScaleBar(MARGIN + TIME_W, top + 26, length_px, length_m)


class Compositor:
    """Turns a grid of :class:`Panel` into an RGB picture; caches the static template."""

    def __init__(self, cell_px: int | None = None) -> None:
        self.cell_px = cell_px
        self._key: tuple | None = None
        self._template: np.ndarray | None = None
        self.layout: Layout | None = None
        self.scale_bar: ScaleBar | None = None

    @staticmethod
    def auto_cell_px(rows: int, cols: int) -> int:
        """Pixels per cell so that a panel is about 400 pixels across (at least 1)."""
        return max(1, 400 // max(rows, cols))

    def compose(self, grid: Sequence[Sequence[Panel]], time_text: str) -> np.ndarray:
        """The picture (H, W, 3) uint8 of panels ``grid[i][j]`` and the footer text."""
        first = grid[0][0]
        rows, cols = first.window.shape
        for row in grid:
            for p in row:
                if p.window.shape != (rows, cols) or \
                        p.window.resolution_m != first.window.resolution_m:
                    raise ValueError("all panels must share the window shape and resolution")
        px = self.cell_px or self.auto_cell_px(rows, cols)
        key = (px, rows, cols, first.window.resolution_m,
               tuple(tuple((p.title, p.legend) for p in row) for row in grid))
        if key != self._key:
            self._build_template(grid, px, rows, cols, first.window.resolution_m)
            self._key = key
        layout = self.layout
        assert layout is not None and self._template is not None
        canvas = self._template.copy()
        egos = []
        drawn_objects = []
        for i, row in enumerate(grid):
            for j, panel in enumerate(row):
                box = layout.panel_box(i, j)
                left, top, right, bottom = box
                canvas[top:bottom, left:right] = upscale(panel.rgb[::-1], px)
                if panel.outlines is not None:
                    self._draw_outlines(canvas, panel, box, px)
                if panel.pose is not None:
                    egos.append(self._ego_polygon(panel, box, px))
                if panel.objects is not None and len(panel.objects):
                    drawn_objects.append((panel, box))
        image = Image.fromarray(canvas)
        draw = ImageDraw.Draw(image)
        for polygon in egos:
            if polygon is not None:
                draw.polygon(polygon, fill=EGO_FILL, outline=EGO_EDGE)
        for panel, box in drawn_objects:
            self._draw_objects(draw, panel, box, px)
        _, ftop, _, _ = layout.footer_box()
        draw.text((MARGIN, ftop + 8), time_text, fill=INK, font=font())
        return np.array(image)

    def _build_template(self, grid: Sequence[Sequence[Panel]], px: int, rows: int, cols: int,
                        resolution_m: float) -> None:
        panel_w = cols * px
        positions = [[legend_positions(p.legend, panel_w) for p in row] for row in grid]
        lines = 1 + max((pos[-1][1] for row in positions for pos in row if pos), default=0)
        layout = make_layout(len(grid), max(len(row) for row in grid), rows, cols, px, lines)
        image = Image.new("RGB", (layout.width, layout.height), BACKGROUND)
        draw = ImageDraw.Draw(image)
        for i, row in enumerate(grid):
            for j, panel in enumerate(row):
                left, top = layout.panel_origin(i, j)
                draw.text((left, top - TITLE_H + 2), panel.title, fill=INK, font=font())
                _, ltop, _, _ = layout.legend_box(i, j)
                for dx, line, colour, label in positions[i][j]:
                    x, y = left + dx, ltop + line * LEGEND_LINE_H
                    draw.rectangle((x, y + 1, x + SWATCH - 1, y + SWATCH), fill=colour,
                                   outline=(128, 128, 128))
                    draw.text((x + SWATCH + 4, y), label, fill=INK, font=font())
        bar = scale_bar_for(layout, resolution_m)
        draw.rectangle((bar.left, bar.top, bar.left + bar.length_px - 1,
                        bar.top + SCALE_BAR_THICKNESS - 1), fill=INK)
        draw.text((bar.left, bar.top - 14), format_metres(bar.length_m), fill=INK, font=font())
        self._draw_north_arrow(draw, layout)
        self.layout, self.scale_bar = layout, bar
        self._template = np.array(image)

    @staticmethod
    def _draw_north_arrow(draw: ImageDraw.ImageDraw, layout: Layout) -> None:
        _, top, right, bottom = layout.footer_box()
        cx = right - 12
        tip, base = top + 14, bottom - 4
        draw.polygon([(cx, tip), (cx - 6, tip + 12), (cx + 6, tip + 12)], fill=INK)
        draw.line([(cx, tip + 10), (cx, base)], fill=INK, width=2)
        draw.text((cx - 3, top), "N", fill=INK, font=font())

    @staticmethod
    def _to_pixels(panel: Panel, box: tuple[int, int, int, int], px: int, x: np.ndarray,
                   y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Working-CRS metres → pixel coordinates of the panel (north up)."""
        w = panel.window
        left, top, _, _ = box
        u = left + (np.asarray(x) / w.resolution_m - w.col0) * px
        v = top + (w.rows - (np.asarray(y) / w.resolution_m - w.row0)) * px
        return u, v

    def _draw_outlines(self, canvas: np.ndarray, panel: Panel, box: tuple[int, int, int, int],
                       px: int) -> None:
        assert panel.outlines is not None
        for seg, colour in panel.outlines.segments_in(panel.window.bounds):
            if len(seg) == 0:
                continue
            u0, v0 = self._to_pixels(panel, box, px, seg[:, 0], seg[:, 1])
            u1, v1 = self._to_pixels(panel, box, px, seg[:, 2], seg[:, 3])
            draw_segments(canvas, np.stack([u0, v0, u1, v1], axis=1), colour, box)

    def _draw_objects(self, draw: ImageDraw.ImageDraw, panel: Panel,
                      box: tuple[int, int, int, int], px: int) -> None:
        """Each object's bounding box, track id and velocity arrow (``ARROW_S`` of travel
        from the centroid), in the colour of its state."""
        left, top, right, bottom = box
        for o in panel.objects:
            colour = OBJECT_COLOURS["moving" if int(o["state"]) == OBJECT_STATES["moving"]
                                    else "stopped"]
            x0, y0, x1, y1 = (float(v) for v in o["bbox_m"])
            u0, v1 = self._to_pixels(panel, box, px, np.array(x0), np.array(y0))
            u1, v0 = self._to_pixels(panel, box, px, np.array(x1), np.array(y1))
            draw.rectangle((float(u0), float(v0), float(u1) - 1, float(v1) - 1),
                           outline=colour, width=2 if px >= 3 else 1)
            cx, cy = (float(v) for v in o["centroid_m"])
            vx, vy = (float(v) for v in o["velocity_m_per_s"])
            uc, vc = (float(a) for a in self._to_pixels(panel, box, px, np.array(cx),
                                                        np.array(cy)))
            ue, ve = (float(a) for a in self._to_pixels(
                panel, box, px, np.array(cx + vx * ARROW_S), np.array(cy + vy * ARROW_S)))
            ue, ve = min(max(ue, left), right - 1), min(max(ve, top), bottom - 1)
            if math.hypot(ue - uc, ve - vc) >= 3:
                draw.line([(uc, vc), (ue, ve)], fill=colour, width=2)
                ang = math.atan2(ve - vc, ue - uc)
                head = [(ue, ve)] + [(ue - 7 * math.cos(ang + s), ve - 7 * math.sin(ang + s))
                                     for s in (0.45, -0.45)]
                draw.polygon(head, fill=colour)
            tx = min(max(float(u1) + 2, left), right - text_width(str(o["track_id"])) - 1)
            draw.text((tx, max(float(v0) - 12, top)), str(int(o["track_id"])), fill=colour,
                      font=font())

    def _ego_polygon(self, panel: Panel, box: tuple[int, int, int, int], px: int
                     ) -> list[tuple[float, float]] | None:
        x, y, yaw = (float(v) for v in panel.pose[:3])
        u, v = self._to_pixels(panel, box, px, np.array(x), np.array(y))
        u, v = float(u), float(v)
        left, top, right, bottom = box
        if not (left <= u < right and top <= v < bottom):
            return None
        m_to_px = px / panel.window.resolution_m
        half_len = max(6.0, EGO_LENGTH_M * m_to_px) / 2
        half_wid = max(3.0, EGO_WIDTH_M * m_to_px) / 2
        dx, dy = math.cos(yaw), -math.sin(yaw)     # image y grows southwards
        nx, ny = -dy, dx
        return [(u + half_len * dx, v + half_len * dy),
                (u - half_len * dx + half_wid * nx, v - half_len * dy + half_wid * ny),
                (u - half_len * dx - half_wid * nx, v - half_len * dy - half_wid * ny)]
