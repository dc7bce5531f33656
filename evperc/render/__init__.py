"""Pictures of evperc outputs: pignistic colour, decision maps, traces."""

from evperc.render.frame import DEFAULT_LAYERS, LAYERS, FrameRenderer, render_frame

__all__ = ["DEFAULT_LAYERS", "LAYERS", "FrameRenderer", "render_frame"]
