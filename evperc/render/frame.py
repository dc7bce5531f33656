"""Rendering one frame of a run into layer panels and a picture (method.md §6).

``FrameRenderer`` keeps the state that spans frames (the moving trace, the time origin, the
cached picture template), so ``evperc run --render`` and ``evperc render`` share it:

    renderer = FrameRenderer(("betp", "decision", "trace"), run.decision_codes)
    for frame in run.frames:
        image = renderer.render(frame)      # (H, W, 3) uint8, north up

A frame is anything with ``stamp_ns``, ``pose``, ``window``, ``decision``, ``betp``, ``zeta``
and ``conflict`` as documented in docs/output-format.md.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from evperc.errors import UsageError
from evperc.render import colours as c
from evperc.render.compose import Compositor, Panel
from evperc.render.map_outlines import BUILDING_OUTLINE, ROAD_OUTLINE, MapOutlines
from evperc.render.trace import MovingTrace

LAYER_TITLES: dict[str, str] = {
    "betp": "pignistic colour (betP), dark where unknown",
    "decision": "decision",
    "decision6": "decision (fine)",
    "trace": "moving trace",
    "zeta": "zeta (stopped accumulator)",
    "conflict": "conflict",
}
LAYERS = tuple(LAYER_TITLES)
#: the fine decision by default: with a map, infrastructure (and unmapped) cells show
DEFAULT_LAYERS = ("betp", "decision6", "trace")


def parse_layers(text: str) -> tuple[str, ...]:
    """``"betp,decision"`` → ``("betp", "decision")``; unknown names raise UsageError."""
    names = tuple(name.strip() for name in text.split(",") if name.strip())
    bad = [name for name in names if name not in LAYER_TITLES]
    if bad or not names:
        raise UsageError(f"--layers {text!r}: unknown layer {', '.join(bad) or '(none)'}; "
                         f"choose from {','.join(LAYERS)}")
    return names


def _legend(layer: str, codes: Mapping[str, int]) -> tuple[tuple[c.RGB, str], ...]:
    if layer == "betp":
        return (*((rgb, c.CLASS_NAMES[k]) for k, rgb in c.CLASS_COLOURS.items()),
                *((rgb, name) for name, rgb in c.FADING_COLOURS.items()),
                ((0, 0, 0), "unknown"))
    if layer == "decision":
        return tuple((rgb, name) for name, rgb in c.DECISION4_COLOURS.items())
    if layer == "decision6":
        ordered = sorted(codes, key=lambda name: codes[name])
        return tuple((c.DECISION6_COLOURS.get(name, c.UNNAMED_COLOUR), name) for name in ordered)
    if layer == "trace":
        return ((c.TRACE_COLOUR, "moving so far"),)
    if layer == "zeta":
        lut = c.ramp_lut()
        return tuple((tuple(int(v) for v in lut[int(round(z * 255))]), f"{z:g}")
                     for z in (0.0, 0.5, 1.0))
    if layer == "conflict":
        return tuple((rgb, label) for label, rgb in c.CONFLICT_COLOURS.items())
    raise ValueError(layer)


class FrameRenderer:
    """Renders frames of one run; keeps the moving trace and the picture template."""

    def __init__(self, layers: Sequence[str] = DEFAULT_LAYERS,
                 decision_codes: Mapping[str, int] | None = None, *,
                 cell_px: int | None = None, t0_ns: int | None = None,
                 outlines: MapOutlines | None = None, label: str = "",
                 trace: MovingTrace | None = None, objects: bool = True) -> None:
        bad = [name for name in layers if name not in LAYER_TITLES]
        if bad:
            raise ValueError(f"unknown layers {bad}; known: {LAYERS}")
        self.layers = tuple(layers)
        self.codes = dict(decision_codes or c.DEFAULT_DECISION_CODES)
        self.t0_ns = t0_ns
        self.outlines = outlines
        self.label = label
        self.trace = trace if trace is not None else MovingTrace()
        self.compositor = Compositor(cell_px)
        self._lut4 = c.decision_lut(self.codes, c.DECISION4_COLOURS, c.DECISION4_OF_CODE)
        self._lut6 = c.decision_lut(self.codes, c.DECISION6_COLOURS)
        self._zeta_lut = c.ramp_lut()
        extra = ((BUILDING_OUTLINE, "building"), (ROAD_OUTLINE, "road")) if outlines else ()
        #: draw the frames' object lists (outline, track id, velocity arrow over 1 s)
        self.objects = objects
        if objects:
            extra += tuple((rgb, f"{state} object") for state, rgb in c.OBJECT_COLOURS.items())
        self._legends = {name: _legend(name, self.codes) + extra for name in self.layers}

    def layer_rgb(self, layer: str, frame: Any, trace: np.ndarray | None = None) -> np.ndarray:
        """(rows, cols, 3) uint8 colours of one layer, grid row order (row 0 = south)."""
        if layer == "betp":
            masses = getattr(frame, "masses", None)
            if masses is None:
                return c.pignistic_colour(frame.betp)
            return c.pignistic_colour_known(frame.betp, np.asarray(masses)[..., -1])
        if layer == "decision":
            return c.apply_lut(frame.decision, self._lut4)
        if layer == "decision6":
            return c.apply_lut(frame.decision, self._lut6)
        if layer == "trace":
            if trace is None:
                trace = frame.decision == self.codes["moving"]
            return c.trace_colour(c.apply_lut(frame.decision, self._lut4), trace)
        if layer == "zeta":
            return c.ramp_colour(frame.zeta, self._zeta_lut)
        if layer == "conflict":
            return c.conflict_colour(frame.conflict)
        raise ValueError(layer)

    def observe(self, frame: Any) -> None:
        """Advance the state (moving trace, time origin) by a frame that is not drawn."""
        if self.t0_ns is None:
            self.t0_ns = int(frame.stamp_ns)
        if "trace" in self.layers:
            self.trace.add(np.asarray(frame.decision) == self.codes["moving"], frame.window)

    def panels(self, frame: Any) -> list[Panel]:
        """The panels of ``frame``; advances the moving trace."""
        self.observe(frame)
        trace = self.trace.sample(frame.window) if "trace" in self.layers else None
        prefix = f"{self.label}: " if self.label else ""
        pose = np.asarray(frame.pose, dtype=np.float64)
        objects = getattr(frame, "objects", None) if self.objects else None
        return [Panel(prefix + LAYER_TITLES[name], self.layer_rgb(name, frame, trace),
                      self._legends[name], frame.window, pose, self.outlines, objects)
                for name in self.layers]

    def time_text(self, frame: Any) -> str:
        """``t = 1.23 s`` from the first frame (``t0_ns``), and the frame index if known."""
        t0 = self.t0_ns if self.t0_ns is not None else int(frame.stamp_ns)
        text = f"t = {(int(frame.stamp_ns) - t0) * 1e-9:.2f} s"
        index = getattr(frame, "index", None)
        return text if index is None else f"{text}   frame {index}"

    def render(self, frame: Any) -> np.ndarray:
        """The picture of ``frame``: (H, W, 3) uint8, panels side by side, north up."""
        panels = self.panels(frame)
        return self.compositor.compose([panels], self.time_text(frame))

    @property
    def layout(self):  # noqa: ANN201 - Layout | None, set after the first render
        """Pixel layout of the last picture (see :class:`evperc.render.compose.Layout`)."""
        return self.compositor.layout


def render_frame(frame: Any, layers: Sequence[str] = DEFAULT_LAYERS,
                 decision_codes: Mapping[str, int] | None = None, *,
                 cell_px: int | None = None, outlines: MapOutlines | None = None
                 ) -> np.ndarray:
    """One frame alone (the trace holds only this frame's moving cells): (H, W, 3) uint8."""
    return FrameRenderer(layers, decision_codes, cell_px=cell_px,
                         outlines=outlines).render(frame)
