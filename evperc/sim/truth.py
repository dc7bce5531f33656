"""Per-frame ground truth on evperc's global lattice (docs/truth-format.md).

Rules (cell = its centre, docs/conventions.md):
- class: the truth class of the solid whose footprint holds the cell centre, or which has
  its reference point (centre) in the cell — so every object covers at least one cell;
  buildings I, street furniture U, agents S or M at that instant; everything else F.
  Priority where footprints overlap: M > S > U > I > F.
- visible: what a lidar can tell about the cell in this scan, as the sensor model (method.md §3)
  sees it: along each azimuth (the one nearest to the cell centre), up to the nearest
  return off the ground if there is one — upper layers passing over a car say nothing about
  the cells behind it — else up to the farthest ground return; plus the cells holding those
  returns.
- observed: visible at this frame or any earlier one.
"""

from __future__ import annotations

import io
import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from evperc.errors import OutputError
from evperc.geo.window import Window
from evperc.output.writer import atomic_write_bytes, write_json
from evperc.sim.lidar import GROUND, Hits
from evperc.sim.scene import (
    BOX,
    FREE,
    INFRASTRUCTURE,
    MOVING,
    STOPPED,
    UNMAPPED,
    Solids,
)

FORMAT_VERSION = 1
CLASS_CODES = {"free": FREE, "moving": MOVING, "stopped": STOPPED,
               "infrastructure": INFRASTRUCTURE, "unmapped": UNMAPPED}
_RANK = np.zeros(256, dtype=np.int8)
_RANK[[FREE, INFRASTRUCTURE, UNMAPPED, STOPPED, MOVING]] = [0, 1, 2, 3, 4]


def paint_solids(classes: np.ndarray, ids: np.ndarray | None, window: Window, solids: Solids,
                 first_id: int = 1) -> None:
    """Write the solids' labels into ``classes`` (window-shaped) in place, and their ids
    (``first_id + index``) into ``ids``; solids are painted in priority order."""
    if len(solids) == 0:
        return
    r = window.resolution_m
    half = int(math.ceil(float(np.max(np.hypot(solids.length, solids.width))) / (2 * r))) + 1
    offs = np.arange(-half, half + 1)
    row_c, col_c = window.index_of(solids.x, solids.y)
    rows = row_c[:, None, None] + offs[None, :, None]
    cols = col_c[:, None, None] + offs[None, None, :]
    cx = (cols + window.col0 + 0.5) * r - solids.x[:, None, None]
    cy = (rows + window.row0 + 0.5) * r - solids.y[:, None, None]
    c = np.cos(solids.heading)[:, None, None]
    s = np.sin(solids.heading)[:, None, None]
    along, across = c * cx + s * cy, -s * cx + c * cy
    hl = (solids.length / 2)[:, None, None]
    hw = (solids.width / 2)[:, None, None]
    in_box = (np.abs(along) <= hl) & (np.abs(across) <= hw)
    in_cyl = cx * cx + cy * cy <= hl * hl
    inside = np.where((solids.kind == BOX)[:, None, None], in_box, in_cyl)
    inside |= (offs[None, :, None] == 0) & (offs[None, None, :] == 0)
    inside &= window.contains(rows, cols)
    rank = _RANK[solids.label]
    solid, pr, pc = np.nonzero(inside)
    rr, cc, rk = rows[solid, pr, 0], cols[solid, 0, pc], rank[solid]
    flat = rr * window.cols + cc
    if flat.size == 0:  # no solid in the window
        return
    order = np.lexsort((rk, flat))
    last = np.r_[flat[order][1:] != flat[order][:-1], True]
    pick = order[last]
    pick = pick[rk[pick] >= _RANK[classes[rr[pick], cc[pick]]]]
    classes[rr[pick], cc[pick]] = solids.label[solid[pick]]
    if ids is not None:
        ids[rr[pick], cc[pick]] = first_id + solid[pick]


def paint_buildings(classes: np.ndarray, window: Window, buildings: np.ndarray) -> None:
    """Cells whose centre lies in a building polygon become INFRASTRUCTURE (in place)."""
    if len(buildings) == 0:
        return
    x, y = window.cell_centres()
    xx, yy = np.meshgrid(x, y)
    xmin, ymin, xmax, ymax = window.bounds
    near = buildings[shapely.intersects(buildings, shapely.box(xmin, ymin, xmax, ymax))]
    if len(near) == 0:
        return
    pts = shapely.points(xx.ravel(), yy.ravel())
    idx = np.unique(shapely.STRtree(near).query(pts, predicate="within")[0])
    classes.reshape(-1)[idx] = INFRASTRUCTURE


def visible_cells(window: Window, hits: Hits, x: float, y: float, yaw: float) -> np.ndarray:
    """Cells a returning beam crossed or ended in (module docstring), bool (rows, cols)."""
    out = np.zeros(window.shape, dtype=bool)
    returned = np.isfinite(hits.horizontal_m)
    obstacle = returned & (hits.label != GROUND)
    nearest_obstacle = np.where(obstacle, hits.horizontal_m, np.inf).min(axis=0)
    farthest_ground = np.where(returned & ~obstacle, hits.horizontal_m, -np.inf).max(axis=0)
    reach = np.where(np.isfinite(nearest_obstacle), nearest_obstacle, farthest_ground)
    az = hits.azimuths
    if len(az) > 1:
        step = (az[-1] - az[0]) / (len(az) - 1)
        full_circle = abs(step * len(az) - 2 * np.pi) < 1e-6
        cx, cy = window.cell_centres()
        dx, dy = cx[None, :] - x, cy[:, None] - y
        rel = np.angle(np.exp(1j * (np.arctan2(dy, dx) - yaw)))
        idx = np.rint((rel - az[0]) / step).astype(np.int64)
        if full_circle:
            idx %= len(az)
        inside = (idx >= 0) & (idx < len(az))
        out |= inside & (np.hypot(dx, dy) <= reach[np.clip(idx, 0, len(az) - 1)])
    ok = returned & (hits.horizontal_m <= reach[None, :])
    h = hits.horizontal_m[ok]
    a = np.broadcast_to(az[None, :], ok.shape)[ok] + yaw
    row, col = window.index_of(x + h * np.cos(a), y + h * np.sin(a))
    inside = window.contains(row, col)
    out[row[inside], col[inside]] = True
    return out


@dataclass(frozen=True)
class TruthFrame:
    """Ground truth of one scan, in the window ``window`` (row 0 = south)."""

    index: int
    stamp_ns: int
    origin: tuple[int, int]
    window: Window
    sensor_pose: np.ndarray   # lidar x_m, y_m, yaw_rad in the working CRS
    classes: np.ndarray       # (rows, cols) uint8, CLASS_CODES
    observed: np.ndarray      # (rows, cols) bool
    visible: np.ndarray       # (rows, cols) bool
    agent: np.ndarray         # (rows, cols) int32: 1 + agent index, 0 none


class TruthWriter:
    """Streams truth frames into ``truth_dir/chunk_NNNNN.npz`` and ``manifest.json``."""

    def __init__(self, truth_dir: Path, window_rows: int, resolution_m: float, crs: str,
                 meta: dict[str, Any], chunk_frames: int = 50) -> None:
        self.dir = Path(truth_dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.chunk_frames = chunk_frames
        self.manifest: dict[str, Any] = {
            "format_version": FORMAT_VERSION, "complete": False, "frame_count": 0,
            "class_codes": CLASS_CODES, "crs": crs, "resolution_m": resolution_m,
            "rows": window_rows, "cols": window_rows, "chunk_frames": chunk_frames,
            "chunks": [], "frames": [], **meta}
        self._buf: list[TruthFrame] = []

    def add(self, frame: TruthFrame) -> None:
        self._buf.append(frame)
        self.manifest["frames"].append({"stamp_ns": frame.stamp_ns,
                                        "origin": list(frame.origin),
                                        "sensor_pose": [float(v) for v in frame.sensor_pose]})
        if len(self._buf) >= self.chunk_frames:
            self._flush()

    def _flush(self) -> None:
        if not self._buf:
            return
        b = self._buf
        name = f"chunk_{len(self.manifest['chunks']):05d}.npz"
        arrays = {"stamp_ns": np.array([f.stamp_ns for f in b], dtype=np.int64),
                  "origin": np.array([f.origin for f in b], dtype=np.int64),
                  "sensor_pose": np.stack([f.sensor_pose for f in b]).astype(np.float64),
                  "classes": np.stack([f.classes for f in b]).astype(np.uint8),
                  "observed": np.stack([f.observed for f in b]),
                  "visible": np.stack([f.visible for f in b]),
                  "agent": np.stack([f.agent for f in b]).astype(np.int32)}
        data = io.BytesIO()
        np.savez_compressed(data, **arrays)
        atomic_write_bytes(self.dir / name, data.getvalue())
        first = self.manifest["frame_count"]
        self.manifest["chunks"].append({"file": name, "first_frame": first,
                                        "frame_count": len(b)})
        self.manifest["frame_count"] = first + len(b)
        write_json(self.dir / "manifest.json", self.manifest)
        self._buf = []

    def close(self) -> None:
        self._flush()
        self.manifest["complete"] = True
        write_json(self.dir / "manifest.json", self.manifest)


class Truth:
    """A truth directory: ``.manifest``, ``.class_codes``, ``.agents``, ``.frames``."""

    def __init__(self, truth_dir: Path, manifest: dict[str, Any]) -> None:
        self.dir = truth_dir
        self.manifest = manifest
        self.class_codes: dict[str, int] = manifest["class_codes"]
        self.resolution_m: float = manifest["resolution_m"]
        self.shape = (manifest["rows"], manifest["cols"])
        self.agents: list[dict[str, Any]] = manifest.get("agents", [])

    def __len__(self) -> int:
        return int(self.manifest["frame_count"])

    def __iter__(self) -> Iterator[TruthFrame]:
        return self.frames

    @property
    def frames(self) -> Iterator[TruthFrame]:
        """All frames in order, one chunk in memory at a time."""
        rows, cols = self.shape
        for chunk in self.manifest["chunks"]:
            path = self.dir / chunk["file"]
            try:
                with np.load(path) as npz:
                    a = {k: npz[k] for k in npz.files}
            except (OSError, ValueError) as err:
                raise OutputError(f"{path}: unreadable truth chunk ({err})") from err
            for k in range(len(a["stamp_ns"])):
                row0, col0 = (int(v) for v in a["origin"][k])
                yield TruthFrame(chunk["first_frame"] + k, int(a["stamp_ns"][k]), (row0, col0),
                                 Window(self.resolution_m, rows, cols, row0, col0),
                                 a["sensor_pose"][k], a["classes"][k], a["observed"][k],
                                 a["visible"][k], a["agent"][k])


def load_truth(truth_dir: str | Path) -> Truth:
    """Open a truth directory written by ``evperc simulate`` (``DIR/truth``, or ``DIR``)."""
    truth_dir = Path(truth_dir)
    if not (truth_dir / "manifest.json").is_file() and (truth_dir / "truth").is_dir():
        truth_dir = truth_dir / "truth"
    path = truth_dir / "manifest.json"
    if not path.is_file():
        raise OutputError(f"{truth_dir}: not a truth directory (no manifest.json); give the "
                          "truth/ folder written by `evperc simulate`")
    try:
        manifest = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise OutputError(f"{path}: unreadable truth manifest ({err})") from err
    if manifest.get("format_version") != FORMAT_VERSION or "class_codes" not in manifest:
        raise OutputError(f"{path}: not a truth manifest of format_version {FORMAT_VERSION}")
    if not manifest.get("complete"):
        raise OutputError(f"{truth_dir}: truth is incomplete (simulation interrupted?); "
                          "rerun `evperc simulate`")
    return Truth(truth_dir, manifest)
