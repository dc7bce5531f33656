"""Vectorised raster primitives on numpy images: upscaling and many line segments at once."""

from __future__ import annotations

import numpy as np


def upscale(rgb: np.ndarray, cell_px: int) -> np.ndarray:
    """Nearest-neighbour enlargement: every cell becomes ``cell_px × cell_px`` pixels."""
    if cell_px == 1:
        return rgb
    return np.repeat(np.repeat(rgb, cell_px, axis=0), cell_px, axis=1)


def clip_segments(seg: np.ndarray, xmin: float, ymin: float, xmax: float, ymax: float
                  ) -> np.ndarray:
    """Liang–Barsky clipping of segments ``(N, 4)`` = x0, y0, x1, y1 to a rectangle.

    Returns the visible parts ``(K, 4)``, K ≤ N; segments wholly outside are dropped."""
    seg = np.asarray(seg, dtype=np.float64).reshape(-1, 4)
    x0, y0, x1, y1 = seg.T
    dx, dy = x1 - x0, y1 - y0
    p = np.stack([-dx, dx, -dy, dy])
    q = np.stack([x0 - xmin, xmax - x0, y0 - ymin, ymax - y0])
    t0 = np.zeros(len(seg))
    t1 = np.ones(len(seg))
    keep = np.ones(len(seg), dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = q / p
    parallel = p == 0
    keep &= ~np.any(parallel & (q < 0), axis=0)
    entering = (p < 0) & ~parallel
    leaving = (p > 0) & ~parallel
    t0 = np.maximum(t0, np.max(np.where(entering, r, -np.inf), axis=0))
    t1 = np.minimum(t1, np.min(np.where(leaving, r, np.inf), axis=0))
    keep &= t0 <= t1
    t0, t1 = t0[keep], t1[keep]
    x0, y0, dx, dy = x0[keep], y0[keep], dx[keep], dy[keep]
    return np.stack([x0 + t0 * dx, y0 + t0 * dy, x0 + t1 * dx, y0 + t1 * dy], axis=1)


def draw_segments(image: np.ndarray, seg: np.ndarray, colour: tuple[int, int, int],
                  box: tuple[int, int, int, int] | None = None) -> None:
    """Draw 1-px segments ``(N, 4)`` (x0, y0, x1, y1 in pixel coordinates, x right, y down)
    into ``image`` (H, W, 3) in place, by sampling each segment at ≤ 0.5 px steps.

    ``box`` = (left, top, right, bottom) pixel rectangle (exclusive right/bottom) to clip to;
    the whole image by default."""
    h, w = image.shape[:2]
    left, top, right, bottom = box if box is not None else (0, 0, w, h)
    seg = clip_segments(seg, left, top, right - 1e-6, bottom - 1e-6)
    if len(seg) == 0:
        return
    length = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    n = np.ceil(length * 2).astype(np.int64) + 1
    owner = np.repeat(np.arange(len(seg)), n)
    start = np.cumsum(n) - n
    t = (np.arange(n.sum()) - start[owner]) / np.maximum(n[owner] - 1, 1)
    x = seg[owner, 0] + t * (seg[owner, 2] - seg[owner, 0])
    y = seg[owner, 1] + t * (seg[owner, 3] - seg[owner, 1])
    xi = np.clip(np.floor(x).astype(np.int64), left, right - 1)
    yi = np.clip(np.floor(y).astype(np.int64), top, bottom - 1)
    image[yi, xi] = colour
