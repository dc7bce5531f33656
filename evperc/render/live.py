"""``evperc run --render DIR``: draw each frame as the run produces it."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import imageio.v3 as iio

from evperc.fusion.twin import DECISION_CODES
from evperc.geo.window import Window
from evperc.render.frame import DEFAULT_LAYERS, FrameRenderer
from evperc.render.run_render import PNG_COMPRESS_LEVEL, prepare_dest


class LiveRenderer:
    """Callable given each frame's arrays by :func:`evperc.runner.run`; writes
    ``DIR/frame_NNNNN.png`` with the default layers (pignistic colour, decision, trace)."""

    def __init__(self, dest: Path, request: Any) -> None:
        self.dest = Path(dest)
        prepare_dest(self.dest, overwrite=bool(getattr(request, "overwrite", False)))
        self.resolution_m = request.config["grid"]["cell_size_m"]
        self.renderer = FrameRenderer(DEFAULT_LAYERS, DECISION_CODES)
        self.count = 0

    def __call__(self, frame: dict[str, Any]) -> None:
        rows, cols = frame["decision"].shape
        row0, col0 = frame["origin"]
        view = SimpleNamespace(index=self.count, window=Window(self.resolution_m, rows, cols,
                                                               row0, col0), **frame)
        image = self.renderer.render(view)
        iio.imwrite(self.dest / f"frame_{self.count:05d}.png", image,
                    compress_level=PNG_COMPRESS_LEVEL)
        self.count += 1
