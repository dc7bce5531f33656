"""Rendering a whole run (``evperc render``): PNG per frame, an animated GIF, or both.

Frames are streamed: one frame (two with ``compare``) in memory at a time, except the GIF,
whose frames Pillow holds until it writes the file; its size is checked before starting.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from evperc.errors import MapError, OutputError, UsageError
from evperc.progress import bar
from evperc.render.compose import Compositor
from evperc.render.frame import DEFAULT_LAYERS, FrameRenderer
from evperc.render.map_outlines import MapOutlines

log = logging.getLogger(__name__)

#: Largest GIF (raw RGB bytes of all frames) accepted before writing starts.
GIF_MAX_BYTES = 1 << 30
#: zlib level of the PNG frames: 1 encodes ~2.5× faster than Pillow's 6, files ~20% larger
PNG_COMPRESS_LEVEL = 1


def parse_frames(text: str | None) -> slice:
    """``"A:B:STEP"`` (each part optional, Python slice rules) → slice; None → all frames."""
    if text is None or text.strip() == "":
        return slice(None)
    parts = text.split(":")
    if len(parts) > 3:
        raise UsageError(f"--frames {text!r}: expected A:B:STEP, e.g. 0:100:5")
    try:
        values = [int(p) if p.strip() else None for p in parts]
    except ValueError as err:
        raise UsageError(f"--frames {text!r}: expected whole numbers A:B:STEP, e.g. 0:100:5"
                         ) from err
    if len(values) == 1:  # a single frame index
        index = values[0]
        if index is None:
            return slice(None)
        return slice(index, index + 1 if index != -1 else None)
    if len(values) == 3 and values[2] is not None and values[2] <= 0:
        raise UsageError(f"--frames {text!r}: STEP must be a positive whole number")
    return slice(*values)


def mark_frames(run: Any, frames: slice) -> Iterator[tuple[Any, bool]]:
    """``(frame, picked)`` for every frame up to the last one ``frames`` picks (streamed)."""
    indices = range(*frames.indices(len(run)))
    if len(indices) == 0:
        return
    wanted = set(indices)
    last = max(indices)
    for k, frame in enumerate(run.frames):
        yield frame, k in wanted
        if k >= last:
            return


def select_frames(run: Any, frames: slice) -> Iterator[Any]:
    """The frames of ``run`` picked by ``frames`` (streamed; stops after the last one)."""
    return (frame for frame, picked in mark_frames(run, frames) if picked)


def match_frames(marked_a: Iterator[tuple[Any, bool]], frames_b: Iterator[Any],
                 passed_b: Callable[[Any], None] = lambda frame: None
                 ) -> Iterator[tuple[Any, Any, bool]]:
    """``(frame_a, frame_b or None, picked)``: B's frame of the same ``stamp_ns`` (both
    streams in stamp order); B frames without a partner go to ``passed_b``."""
    frame_b = next(frames_b, None)
    missing = 0
    for frame_a, picked in marked_a:
        while frame_b is not None and frame_b.stamp_ns < frame_a.stamp_ns:
            passed_b(frame_b)
            frame_b = next(frames_b, None)
        if frame_b is not None and frame_b.stamp_ns == frame_a.stamp_ns:
            yield frame_a, frame_b, picked
            frame_b = next(frames_b, None)
        else:
            missing += picked
            yield frame_a, None, picked
    if missing:
        log.warning("%d frame(s) have no frame of the same stamp in the compared run; skipped",
                    missing)


def outlines_for(run: Any, map_path: Path, roads_path: Path | None = None) -> MapOutlines:
    """The map at ``map_path`` (read by ``evperc.geo.maps.load_map``) in the run's CRS."""
    from evperc.geo.maps import load_map

    crs = run.manifest.get("crs", "local")
    if crs in ("", "local", None):
        raise MapError(f"{run.out_dir}: the run has no geographic CRS (crs {crs!r}); map "
                       "outlines cannot be placed, drop --map")
    config_map = (run.manifest.get("config") or {}).get("map")
    if config_map is None:
        from evperc.config import load_config
        config_map = load_config()["map"]
    map_data = load_map(map_path, roads_path, config_map=config_map).to_crs(crs)
    return MapOutlines.from_map_data(map_data)


@dataclass
class RenderRequest:
    """What ``evperc render`` asks for."""

    run: Any
    dest: Path | None = None
    gif: Path | None = None
    frames: slice = field(default_factory=lambda: slice(None))
    layers: Sequence[str] = DEFAULT_LAYERS
    fps: float = 10.0
    compare: Any | None = None
    outlines: MapOutlines | None = None
    cell_px: int | None = None
    overwrite: bool = False


def _label(run: Any) -> str:
    out_dir = getattr(run, "out_dir", None)
    return Path(out_dir).name if out_dir is not None else ""


def _first_stamp(run: Any) -> int | None:
    stamp = (getattr(run, "manifest", None) or {}).get("first_stamp_ns")
    return int(stamp) if stamp is not None else None


def prepare_dest(dest: Path, overwrite: bool) -> None:
    if dest.exists() and not dest.is_dir():
        raise OutputError(f"{dest}: exists and is not a directory; choose another --out")
    old = sorted(dest.glob("frame_*.png")) if dest.is_dir() else []
    if old and not overwrite:
        raise OutputError(f"{dest}: already holds frame_*.png; pass --overwrite or choose "
                          "another --out")
    try:
        dest.mkdir(parents=True, exist_ok=True)
        for path in old:
            path.unlink()
    except OSError as err:
        raise OutputError(f"{dest}: cannot write ({err.strerror})") from err


def slice_text(frames: slice) -> str:
    """``--frames`` as the user writes it: ``A:B:STEP`` (empty parts left out)."""
    parts = ["" if v is None else str(v) for v in (frames.start, frames.stop, frames.step)]
    return ":".join(parts[:2]) + (f":{parts[2]}" if parts[2] else "")


def render_run(req: RenderRequest) -> dict[str, Any]:
    """Render the selected frames; returns ``{"frames", "dest", "gif", "size"}``."""
    import imageio.v3 as iio

    if req.dest is None and req.gif is None:
        raise UsageError("give --out DIR for PNG frames and/or --gif FILE")
    if req.fps <= 0:
        raise UsageError(f"--fps {req.fps}: must be positive")
    if req.gif is not None and req.gif.exists() and not req.overwrite:
        raise OutputError(f"{req.gif}: exists; pass --overwrite or choose another --gif")
    if req.dest is not None:
        prepare_dest(req.dest, req.overwrite)
    run_a, run_b = req.run, req.compare
    if run_b is not None and (tuple(run_a.shape) != tuple(run_b.shape)
                              or run_a.resolution_m != run_b.resolution_m):
        raise UsageError(f"--compare {_label(run_b)}: window {run_b.shape} at "
                         f"{run_b.resolution_m} m differs from {run_a.shape} at "
                         f"{run_a.resolution_m} m; compare runs made with the same grid")
    t0 = _first_stamp(run_a)
    compositor = Compositor(req.cell_px)
    label_a = _label(run_a) if run_b is not None else ""
    renderer_a = FrameRenderer(req.layers, run_a.decision_codes, t0_ns=t0,
                               outlines=req.outlines, label=label_a)
    renderer_b = None
    if run_b is not None:
        renderer_b = FrameRenderer(req.layers, run_b.decision_codes, t0_ns=t0,
                                   outlines=req.outlines, label=_label(run_b))
    n_selected = len(range(*req.frames.indices(len(run_a))))
    if n_selected == 0:
        raise UsageError(f"--frames {slice_text(req.frames)} selects none of the {len(run_a)} "
                         f"frames of {getattr(run_a, 'out_dir', 'the run')}")
    # every frame up to the last picked one feeds the trace; only picked ones are drawn
    marked = mark_frames(run_a, req.frames)
    stream: Iterator[tuple[Any, Any, bool]]
    if renderer_b is not None:
        stream = match_frames(marked, iter(run_b.frames), renderer_b.observe)
    else:
        stream = ((frame, None, picked) for frame, picked in marked)

    gif_writer = None
    count = 0
    size: tuple[int, int] | None = None
    progress = bar(total=n_selected, desc="render")
    try:
        for frame_a, frame_b, picked in stream:
            if not picked or (renderer_b is not None and frame_b is None):
                renderer_a.observe(frame_a)
                if frame_b is not None and renderer_b is not None:
                    renderer_b.observe(frame_b)
                continue
            panels_a = renderer_a.panels(frame_a)
            if renderer_b is not None:
                panels_b = renderer_b.panels(frame_b)
                grid = [[pa, pb] for pa, pb in zip(panels_a, panels_b, strict=True)]
            else:
                grid = [panels_a]
            image = compositor.compose(grid, renderer_a.time_text(frame_a))
            size = (image.shape[1], image.shape[0])
            if req.dest is not None:
                index = getattr(frame_a, "index", count)
                iio.imwrite(req.dest / f"frame_{index:05d}.png", image,
                            compress_level=PNG_COMPRESS_LEVEL)
            if req.gif is not None:
                if gif_writer is None:
                    need = n_selected * image.nbytes
                    if need > GIF_MAX_BYTES:
                        raise UsageError(
                            f"--gif {req.gif}: {n_selected} frames of {size[0]}x{size[1]} "
                            f"need about {need >> 20} MiB; pick fewer with --frames A:B:STEP")
                    gif_writer = iio.imopen(req.gif, "w", extension=".gif")
                gif_writer.write(image, duration=1000.0 / req.fps, loop=0)
            count += 1
            progress.update()
    except BaseException:
        if gif_writer is not None:
            gif_writer.close()
            req.gif.unlink(missing_ok=True)    # no half-written animation
        raise
    finally:
        progress.close()
    if gif_writer is not None:
        gif_writer.close()
    if count == 0:
        raise UsageError(f"--frames {slice_text(req.frames)}: no frame drawn (none of the "
                         f"selected frames has a frame of --compare at its stamp)"
                         if renderer_b is not None else
                         f"--frames {slice_text(req.frames)}: no frame drawn")
    return {"frames": count, "dest": req.dest, "gif": req.gif if count else None,
            "size": size}


def frame_images(run: Any, layers: Sequence[str] = DEFAULT_LAYERS, frames: slice = slice(None)
                 ) -> Iterator[np.ndarray]:
    """The pictures of a run's frames, one at a time (for notebooks and scripts)."""
    renderer = FrameRenderer(layers, run.decision_codes, t0_ns=_first_stamp(run))
    for frame, picked in mark_frames(run, frames):
        if picked:
            yield renderer.render(frame)
        else:
            renderer.observe(frame)
