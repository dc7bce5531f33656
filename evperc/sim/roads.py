"""Road centre-line graph and paths along it, for the simulator's ego vehicle and traffic.

Nodes are the distinct vertices of the drivable highway lines (rounded to 1 cm), edges join
consecutive vertices of a line; OSM ways that share a node are therefore connected.
A path is a polyline ``(V, 2)`` in the working CRS; a pose along it is given by the arc
length ``s`` and a lateral offset ``d`` (positive to the right of the direction of travel).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

DRIVABLE = frozenset({
    "motorway", "trunk", "primary", "secondary", "tertiary", "unclassified", "residential",
    "service", "living_street", "motorway_link", "trunk_link", "primary_link",
    "secondary_link", "tertiary_link"})


@dataclass(frozen=True)
class RoadGraph:
    """Undirected graph of drivable centre lines in CSR form."""

    xy: np.ndarray          # (N, 2) node positions, metres
    indptr: np.ndarray      # (N + 1,) CSR row pointers into ``neighbours``
    neighbours: np.ndarray  # (2E,) neighbour node of each half-edge
    width_m: np.ndarray     # (2E,) road width of each half-edge

    @property
    def degree(self) -> np.ndarray:
        return np.diff(self.indptr)

    @staticmethod
    def from_lines(lines: np.ndarray, widths_m: np.ndarray) -> RoadGraph:
        """Graph of shapely LineStrings ``lines`` with one road width per line."""
        coords, line_index = shapely.get_coordinates(lines, return_index=True)
        key = np.round(coords[:, :2] * 100.0).astype(np.int64)
        uniq, node_of = np.unique(key, axis=0, return_inverse=True)
        node_of = node_of.reshape(-1)
        same_line = line_index[1:] == line_index[:-1]
        a, b = node_of[:-1][same_line], node_of[1:][same_line]
        w = np.asarray(widths_m, dtype=np.float64)[line_index[:-1][same_line]]
        keep = a != b
        a, b, w = a[keep], b[keep], w[keep]
        src = np.concatenate([a, b])
        dst = np.concatenate([b, a])
        ww = np.concatenate([w, w])
        order = np.lexsort((dst, src))
        src, dst, ww = src[order], dst[order], ww[order]
        indptr = np.searchsorted(src, np.arange(len(uniq) + 1))
        return RoadGraph(uniq / 100.0, indptr, dst, ww)

    def edges_of(self, node: int) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.indptr[node], self.indptr[node + 1]
        return self.neighbours[lo:hi], self.width_m[lo:hi]

    def random_walk(self, start: int, length_m: float, rng: np.random.Generator,
                    first: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """A path of at least ``length_m`` (or until a dead end) from node ``start``.

        At each node the walk prefers the straightest continuation (weights ∝ cos² of the
        turn, U-turns only at dead ends). Returns ``(polyline (V, 2), width per segment)``.
        """
        path, widths = [start], []
        prev, node, travelled = -1, start, 0.0
        while travelled < length_m and len(path) < 10_000:
            nbrs, w = self.edges_of(node)
            if len(nbrs) == 0:
                break
            if first is not None and len(path) == 1 and first in nbrs:
                choice = int(np.flatnonzero(nbrs == first)[0])
            else:
                choice = self._choose(node, prev, nbrs, rng)
            nxt = int(nbrs[choice])
            travelled += float(np.hypot(*(self.xy[nxt] - self.xy[node])))
            widths.append(float(w[choice]))
            path.append(nxt)
            prev, node = node, nxt
        return self.xy[np.array(path)], np.array(widths)

    def _choose(self, node: int, prev: int, nbrs: np.ndarray, rng: np.random.Generator) -> int:
        if prev < 0:
            return int(rng.integers(len(nbrs)))
        forward = nbrs != prev
        if not forward.any():
            return 0
        heading_in = self.xy[node] - self.xy[prev]
        out = self.xy[nbrs] - self.xy[node]
        cos = (out @ heading_in) / (np.linalg.norm(out, axis=1) * np.linalg.norm(heading_in)
                                    + 1e-12)
        weight = np.where(forward, np.clip(cos, 0.0, 1.0) ** 8 + 1e-3, 0.0)
        return int(rng.choice(len(nbrs), p=weight / weight.sum()))


def arc_length(polyline: np.ndarray) -> np.ndarray:
    """Cumulative arc length ``(V,)`` of a polyline, starting at 0."""
    seg = np.hypot(*np.diff(polyline, axis=0).T)
    return np.concatenate([[0.0], np.cumsum(seg)])


def pose_along(polyline: np.ndarray, s: np.ndarray, d: np.ndarray | float = 0.0,
               smooth_m: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position ``(x, y)`` and heading at arc lengths ``s`` (clipped to the path), offset
    laterally by ``d`` metres to the right of the direction of travel.

    The heading is that of the chord from ``s − smooth_m`` to ``s + smooth_m``, so poses
    turn smoothly through the polyline's vertices."""
    cum = arc_length(polyline)
    s = np.clip(np.asarray(s, dtype=np.float64), 0.0, cum[-1])
    base = _point_at(polyline, cum, s)
    ahead = _point_at(polyline, cum, np.clip(s + smooth_m, 0.0, cum[-1]))
    behind = _point_at(polyline, cum, np.clip(s - smooth_m, 0.0, cum[-1]))
    chord = ahead - behind
    heading = np.arctan2(chord[..., 1], chord[..., 0])
    d = np.asarray(d, dtype=np.float64)
    x = base[..., 0] + d * np.sin(heading)
    y = base[..., 1] - d * np.cos(heading)
    return x, y, heading


def _point_at(polyline: np.ndarray, cum: np.ndarray, s: np.ndarray) -> np.ndarray:
    seg = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(polyline) - 2)
    length = np.maximum(cum[seg + 1] - cum[seg], 1e-9)
    frac = np.clip((s - cum[seg]) / length, 0.0, 1.0)
    return polyline[seg] + frac[..., None] * (polyline[seg + 1] - polyline[seg])
