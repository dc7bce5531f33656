"""Per-point moving / static labels of a scan, SemanticKITTI-MOS convention (``--point-labels``).

One ``uint32`` a point of the input cloud, in its point order (docs/output-format.md):
:data:`MOVING` 251, :data:`STATIC` 9, :data:`UNKNOWN` 0 — the labels the LiDAR-MOS benchmark's
scripts read. A point's label follows evperc's own reasoning about it:

- ground, by the sensor model's ground split (:mod:`evperc.sensor.ground`): static;
- dropped by the sensor model (non-finite, horizontal range outside
  ``[min_range_m, max_range_m)``, or higher than ``max_obstacle_height_m`` above the ground):
  unknown — evperc says nothing about them;
- obstacle: the decision of the window cell holding it after the scan is fused
  (docs/method.md §6): ``moving`` → moving; ``static``, ``stopped``, ``infrastructure``,
  ``unmapped`` → static; ``free`` → static (the cell's evidence is of free space, the return says
  occupied: nothing says it moves); ``unknown`` → unknown; outside the window → unknown.

**Object reach** (``objects.point_reach_cells`` > 0, ours, issue 21; off in the classic
rule above): a moving object (:mod:`evperc.objects.tracking`) is the cells of its cluster,
the cells *seen occupied now* — in each 0.5° azimuth bin the sensor model marks occupied only
the range bin of its first obstacle return (docs/method.md §3), so the returns off the far
part of the object (a motorcyclist's rider behind its front, a car's roof behind its rear)
fall into cells whose own evidence is free (rays carved them before the object got there)
or unknown. Those points carry no decision of their own. For each moving object ``o`` with
cells ``C_o``, its obstacle points' levelled heights ``[z_lo, z_hi]`` and
``N_o`` = the cells within Chebyshev distance ``point_reach_cells`` of ``C_o``: an obstacle
point in a cell of ``N_o`` decided ``free`` or ``unknown`` whose height lies in
``[z_lo − m, z_hi + m]`` (``m`` = ``objects.point_height_margin_m``) is moving. Points in
cells with an occupied decision of their own (``static``, ``stopped``, …: e.g. a parked car
beside the object) keep it; ground points stay static.

Cell of a point: its offset from the sensor levelled as the sensor model does it (float32
``R·p``, :func:`evperc.sensor.beams.level_points`), added to the sensor position (float64),
``(⌊y/r⌋ − row0, ⌊x/r⌋ − col0)`` as in :meth:`evperc.geo.window.Window.index_of`.
Vectorised numpy: about 2 ms for 120,000 points; the fused step is not involved.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from evperc.fusion.twin import DECISION_CODES
from evperc.geo.window import Window
from evperc.output.writer import atomic_write_bytes
from evperc.sensor.ground import GROUND, OBSTACLE

UNKNOWN = np.uint32(0)
STATIC = np.uint32(9)
MOVING = np.uint32(251)
#: the folder of the label files in a run's output
LABELS_DIR = "labels"

#: label of an obstacle point per decision code of its cell
DECISION_LABEL = np.zeros(max(DECISION_CODES.values()) + 1, np.uint32)
for _name, _code in DECISION_CODES.items():
    DECISION_LABEL[_code] = {"unknown": UNKNOWN, "moving": MOVING}.get(_name, STATIC)
#: decisions whose points a moving object may claim (no occupied decision of their own)
CLAIMABLE = np.zeros(len(DECISION_LABEL), bool)
CLAIMABLE[[DECISION_CODES["free"], DECISION_CODES["unknown"]]] = True


def point_cells(points: np.ndarray, T_crs_sensor: np.ndarray, window: Window,
                with_height: bool = False) -> tuple[np.ndarray, ...]:
    """Window cell ``(row, col)`` of each point (N, 3, sensor frame) and whether it lies in
    the window (module docstring: the sensor model's float32 levelling, the float64 sensor
    position, :meth:`evperc.geo.window.Window.index_of`); row and col are int64, valid
    where ``inside``. ``with_height``: also the levelled height ``z`` (float32, metres above
    the sensor), as a fourth array."""
    p = np.asarray(points, np.float32)
    R = np.asarray(T_crs_sensor, np.float64)[:3, :3].astype(np.float32)
    # the sensor model's float32 levelling, term by term (evperc.sensor.beams)
    x = R[0, 0] * p[:, 0] + R[0, 1] * p[:, 1] + R[0, 2] * p[:, 2]
    y = R[1, 0] * p[:, 0] + R[1, 1] * p[:, 1] + R[1, 2] * p[:, 2]
    res = float(window.resolution_m)
    row = np.floor((T_crs_sensor[1, 3] + y.astype(np.float64)) / res).astype(np.int64)
    col = np.floor((T_crs_sensor[0, 3] + x.astype(np.float64)) / res).astype(np.int64)
    row -= window.row0
    col -= window.col0
    inside = (row >= 0) & (row < window.rows) & (col >= 0) & (col < window.cols)
    if not with_height:
        return row, col, inside
    return row, col, inside, R[2, 0] * p[:, 0] + R[2, 1] * p[:, 1] + R[2, 2] * p[:, 2]


def object_reach(cells: np.ndarray, z: np.ndarray, decision: np.ndarray, cols: int,
                 moving_objects: Sequence[np.ndarray], reach_cells: int,
                 height_margin_m: float) -> np.ndarray:
    """Which obstacle points (flat window ``cells``, levelled heights ``z``) the moving
    objects reach (module docstring, "Object reach"): bool (N,).

    Per object: the cells within Chebyshev distance ``reach_cells`` of its cells (on the
    window: a cell near the edge reaches only the cells inside), of those the ones decided
    ``free`` or ``unknown``, and the points there within ``height_margin_m`` of the height
    range of the object's own points (an object holding no obstacle point reaches none)."""
    rows = decision.size // cols
    n_cells = decision.size
    # owner[cell]: the index of the object holding the cell, -1 (objects are disjoint
    # clusters; were they not, the later one would own a shared cell)
    owner = np.full(n_cells, -1, np.int64)
    for k, own in enumerate(moving_objects):
        owner[np.asarray(own, np.int64)] = k
    lo = np.full(len(moving_objects), np.inf)
    hi = np.full(len(moving_objects), -np.inf)
    of_point = owner[cells]
    held = of_point >= 0
    np.minimum.at(lo, of_point[held], z[held])
    np.maximum.at(hi, of_point[held], z[held])
    # the bounds in the heights' own float32 (a height at the bound exactly is inside)
    lo = (lo - height_margin_m).astype(z.dtype)
    hi = (hi + height_margin_m).astype(z.dtype)
    out = np.zeros(len(cells), bool)
    k = int(reach_cells)
    # the cells within reach of some object: the objects' cells dilated (few cells), so
    # that only the points there are looked at below
    near = np.zeros(n_cells, bool)
    held_cells = np.flatnonzero(owner >= 0)
    hr, hc = np.divmod(held_cells, cols)
    for dr in range(-k, k + 1):
        for dc in range(-k, k + 1):
            rr, cc = hr + dr, hc + dc
            ok = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
            near[rr[ok] * cols + cc[ok]] = True
    near &= CLAIMABLE[decision.reshape(-1)]
    cand = np.flatnonzero(near[cells])
    if cand.size == 0:
        return out
    r, c = np.divmod(cells[cand], cols)
    zc = z[cand]
    hit = np.zeros(cand.size, bool)
    for dr in range(-k, k + 1):  # each neighbour offset, vectorised over the candidates
        for dc in range(-k, k + 1):
            rr, cc = r + dr, c + dc
            ok = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
            o = np.where(ok, owner[np.where(ok, rr * cols + cc, 0)], -1)
            fits = o >= 0
            oi = np.where(fits, o, 0)
            hit |= fits & (zc >= lo[oi]) & (zc <= hi[oi])
    out[cand] = hit
    return out


def point_labels(points: np.ndarray, kinds: np.ndarray, T_crs_sensor: np.ndarray,
                 window: Window, decision: np.ndarray, source_count: int | None = None,
                 source_index: np.ndarray | None = None,
                 moving_objects: Sequence[np.ndarray] = (), reach_cells: int = 0,
                 height_margin_m: float = 0.0) -> np.ndarray:
    """uint32 label of every point of the source cloud (module docstring).

    ``points`` (N, 3) and ``kinds`` (N,) the scan's points and their kinds from the sensor
    model, ``T_crs_sensor`` its pose in the working CRS, ``decision`` the frame's decision
    grid (``window.shape``). ``source_count`` / ``source_index``: the cloud's point count and
    the index of each row of ``points`` in it (points the reader dropped get :data:`UNKNOWN`).
    ``moving_objects``: the flat window cells of each moving object of the frame;
    ``reach_cells``, ``height_margin_m``: the object reach (module docstring; 0 = off).
    """
    n = len(points)
    labels = np.zeros(n, np.uint32)
    labels[kinds[:n] == GROUND] = STATIC
    obstacle = np.flatnonzero(kinds[:n] == OBSTACLE)
    if obstacle.size:
        reaching = reach_cells > 0 and len(moving_objects) > 0
        row, col, inside, *height = point_cells(np.asarray(points)[obstacle], T_crs_sensor,
                                                window, with_height=reaching)
        obstacle, row, col = obstacle[inside], row[inside], col[inside]
        labels[obstacle] = DECISION_LABEL[decision[row, col]]
        if reaching:
            reach = object_reach(row * window.cols + col, height[0][inside], decision,
                                 window.cols,
                                 moving_objects, reach_cells, height_margin_m)
            labels[obstacle[reach]] = MOVING
    if source_index is None and (source_count is None or source_count == n):
        return labels
    full = np.zeros(n if source_count is None else source_count, np.uint32)
    full[np.arange(n) if source_index is None else source_index] = labels
    return full


def label_path(out_dir: Path, number: int) -> Path:
    """``OUT/labels/NNNNNN.label``."""
    return Path(out_dir) / LABELS_DIR / f"{number:06d}.label"


def write_labels(out_dir: Path, number: int, labels: np.ndarray) -> Path:
    """Write one scan's labels (little-endian uint32) through a temporary file and a rename."""
    path = label_path(out_dir, number)
    path.parent.mkdir(exist_ok=True)
    atomic_write_bytes(path, np.asarray(labels, "<u4").tobytes())
    return path
