"""Per-cell Python reference of :mod:`evperc.objects.split`, written from its docstring and
not from the kernel: the parts are a geodesic Voronoi partition of the cluster (each cell to
the claiming track whose painted cells are fewest 8-connected steps away through the
cluster, ties to the lower track row), where the kernel grows all fronts at once in one
queue."""

from __future__ import annotations

import math
from collections import Counter, deque
from itertools import combinations

import numpy as np

from evperc.fusion.twin import DECISION_CODES

MOVING = DECISION_CODES["moving"]


def painted(state, window, dt_s: float) -> dict[int, int | None]:
    """Flat window cell -> the track row whose carried footprint covers it (None: two)."""
    out: dict[int, int | None] = {}
    end = np.cumsum(state.fp_n)
    for i in range(len(state.id)):
        if state.missed[i] != 0:
            continue
        dr = int(np.round(state.velocity[i, 1] * dt_s / window.resolution_m))
        dc = int(np.round(state.velocity[i, 0] * dt_s / window.resolution_m))
        for iy, ix in state.fp[end[i] - state.fp_n[i]:end[i]].tolist():
            r, c = iy + dr - window.row0, ix + dc - window.col0
            if 0 <= r < window.rows and 0 <= c < window.cols:
                j = r * window.cols + c
                if j not in out:
                    out[j] = i
                elif out[j] != i:
                    out[j] = None
    return out


def geodesic(cells: list[int], sources: set[int], cols: int) -> dict[int, int]:
    """Steps from ``sources`` to each cell of ``cells`` reachable 8-connected through them."""
    inside = set(cells)
    dist = {s: 0 for s in sources}
    queue = deque(sources)
    while queue:
        i = queue.popleft()
        r, c = divmod(i, cols)
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                rr, cc = r + dr, c + dc
                if (dr or dc) and 0 <= cc < cols and rr >= 0:
                    j = rr * cols + cc
                    if j in inside and j not in dist:
                        dist[j] = dist[i] + 1
                        queue.append(j)
    return dist


def split_parts(clusters, state, window, stamp_ns: int, min_overlap: int,
                speed_difference: float) -> list[list[int]]:
    """The cells of each output cluster, in order (parts in place of a shared cluster)."""
    dt_s = (stamp_ns - state.prev_ns) * 1e-9
    label = painted(state, window, dt_s)
    out: list[list[int]] = []
    for k in range(len(clusters)):
        cells = clusters.cells_of(k).tolist()
        counts = Counter(label[c] for c in cells if label.get(c) is not None)
        takers = sorted(t for t, n in counts.items() if n >= max(min_overlap, 1))
        v = state.velocity
        moving = state.flags[:, 1]
        fitted = [math.isfinite(x) for x in state.sigma]
        apart = any(math.hypot(v[a, 0] - v[b, 0], v[a, 1] - v[b, 1]) >= speed_difference
                    and (moving[a] or moving[b]) and fitted[a] and fitted[b]
                    for a, b in combinations(takers, 2))
        if not apart:
            out.append(cells)
            continue
        dists = [geodesic(cells, {c for c in cells if label.get(c) == t}, window.cols)
                 for t in takers]
        owner = {}
        for c in cells:
            best = min(((d[c], p) for p, d in enumerate(dists) if c in d), default=None)
            if best is not None:
                owner[c] = best[1]
        sizes = Counter(owner.values())
        largest = max(range(len(takers)), key=lambda p: (sizes[p], -p))
        out.extend([c for c in cells if owner.get(c, largest) == p] for p in range(len(takers)))
    return out


def part_stats(cells: list[int], window, decision: np.ndarray, betp: np.ndarray
               ) -> tuple[tuple[float, float], tuple[float, ...], int, float]:
    """(centroid, bbox, seeds, mean betP(M)) of one part, as the clustering defines them:
    the mean cell centre, the outer cell edges, the cells decided moving, mean betP(M)."""
    rows = np.array(cells) // window.cols
    cols = np.array(cells) % window.cols
    res = window.resolution_m
    centroid = ((window.col0 + cols.mean() + 0.5) * res, (window.row0 + rows.mean() + 0.5) * res)
    bbox = ((window.col0 + cols.min()) * res, (window.row0 + rows.min()) * res,
            (window.col0 + cols.max() + 1) * res, (window.row0 + rows.max() + 1) * res)
    flat_dec = decision.reshape(-1)[cells]
    flat_betp = betp.reshape(-1)[cells].astype(np.int64)
    return (centroid, bbox, int((flat_dec == MOVING).sum()),
            float(flat_betp.sum() / len(cells) / 255.0))
