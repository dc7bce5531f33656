"""Rendering speed: ms per frame of ``FrameRenderer.render`` for 200×200 and 400×400 windows.

Synthetic frames (random betP, decisions, ζ, conflict; the window scrolls one cell per frame
so the trace tiles are exercised). Run: ``.venv/bin/python benchmarks/bench_render.py``.
"""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np

from evperc.geo.window import Window
from evperc.render.frame import DEFAULT_LAYERS, FrameRenderer
from evperc.render.run_render import PNG_COMPRESS_LEVEL

CASES = (
    (200, DEFAULT_LAYERS),
    (400, DEFAULT_LAYERS),
    (200, ("betp", "decision", "decision6", "trace", "zeta", "conflict")),
)


def _frames(n_cells: int, count: int, seed: int = 0) -> list[SimpleNamespace]:
    rng = np.random.default_rng(seed)
    betp = rng.dirichlet(np.ones(5), (n_cells, n_cells)).astype(np.float32)
    decision = rng.integers(0, 7, (n_cells, n_cells)).astype(np.uint8)
    zeta = rng.uniform(0, 1, (n_cells, n_cells)).astype(np.float32)
    conflict = rng.uniform(0, 0.3, (n_cells, n_cells, 3)).astype(np.float32)
    out = []
    for k in range(count):
        window = Window(0.5, n_cells, n_cells, -n_cells // 2, k - n_cells // 2)
        out.append(SimpleNamespace(
            index=k, stamp_ns=k * 100_000_000, pose=np.array([k * 0.5, 0.0, 0.1]),
            window=window, decision=np.roll(decision, k, axis=1), betp=betp, zeta=zeta,
            conflict=conflict))
    return out


def run(frames: int = 30) -> list[dict]:
    """One row per case: window, layers, picture size, ms per frame (after one warm-up)."""
    rows = []
    for n_cells, layers in CASES:
        data = _frames(n_cells, frames + 1)
        renderer = FrameRenderer(layers)
        image = renderer.render(data[0])
        start = time.perf_counter()
        for frame in data[1:]:
            image = renderer.render(frame)
        ms = (time.perf_counter() - start) * 1000.0 / frames
        rows.append({"window": f"{n_cells}x{n_cells}", "layers": ",".join(layers),
                     "image": f"{image.shape[1]}x{image.shape[0]}", "ms_per_frame": ms})
    rows.append(_png_row(image))
    return rows


def _png_row(image: np.ndarray, repeats: int = 5) -> dict:
    """For scale: encoding the last picture as PNG (what ``evperc render --dest`` adds)."""
    import io

    import imageio.v3 as iio

    start = time.perf_counter()
    for _ in range(repeats):
        iio.imwrite(io.BytesIO(), image, extension=".png", compress_level=PNG_COMPRESS_LEVEL)
    ms = (time.perf_counter() - start) * 1000.0 / repeats
    return {"window": "PNG encode", "layers": "", "image": f"{image.shape[1]}x{image.shape[0]}",
            "ms_per_frame": ms}


if __name__ == "__main__":
    for row in run():
        print(f"{row['window']:>8}  {row['image']:>10}  {row['ms_per_frame']:7.2f} ms/frame  "
              f"[{row['layers']}]")
