"""Do the log's poses fit its scans? A check of the input before the run (docs/architecture.md,
`evperc.sensor`; docs/evaluation.md § "Since 2026-12-04, ninth session").

The grid decides a cell moving where a return lands in space seen free before: with poses
that misplace a scan by a fraction of a cell, every wall and parked car does that. Wrong
poses are the first thing to rule out on a new log — a pose topic in another frame, a
scaled odometry, stamps that do not match the scans' — and nothing downstream can tell them
from motion. So the run compares two scans of its first stretch of driving:

1. The first scan ``A`` of the requested span and the first scan ``B`` posed at least
   :data:`BASELINE_M` away from it (at most :data:`MAX_SCANS` scans read; a vehicle that
   stands still that long is not checked).
2. Each scan's obstacle returns (the sensor grid's own ground split,
   :func:`evperc.sensor.grid.sensor_grid` ``kinds_out``) within :data:`REACH_M` of the
   sensor, placed in the log's world frame by the scan's pose, horizontal (x, y) only: a wall
   seen by different beams of a multi-layer lidar is one line.
3. ``A``'s returns marked on a raster of :data:`RASTER_M` cells, each widened by its 8
   neighbours; the *share* of ``B``'s returns that fall on a marked cell (a return within
   ~0.1–0.3 m of one of ``A``'s) at the poses, and at the best horizontal offset of ``B``
   found by a search (steps of :data:`COARSE_M` within :data:`SEARCH_M`, then of
   :data:`FINE_M` around the best); then the same with ``B`` turned about its sensor, by
   :data:`TURNS_DEG` (whole degrees, then the half degrees beside the best), the offsets
   searched near the best one without a turn.
4. The poses *misfit* when the best offset is at least :data:`MISFIT_M` (half the default
   cell: a wall misplaced that much lands in the next cell), or the best turn at least
   :data:`MISFIT_YAW_DEG` (a return 15 m away misplaced by half a cell), and it raises the
   share by at least :data:`MISFIT_GAIN` (a real improvement, not the search finding
   noise). Moving objects lower all shares alike; the static scene decides.

What it catches: a pose scale or speed error (10 % over 3 m: a 0.3 m offset), poses of
another frame or time base, a heading or lidar-yaw error of 1–3° (measured to the half
degree). What it does not: a constant error shared by both scans (a time offset at constant
speed, a fixed extrinsic translation), errors later in the log, and errors beyond the search
(turns beyond 3°, offsets beyond 2 m: a lidar mounted backwards misplaces the second scan by
twice the baseline). Cost: the scans read until ``B``, two sensor grids and the searches:
22–161 ms on the simulated and SemanticKITTI logs (``scripts/pose_fit_survey.py``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from evperc.geo.window import Window
from evperc.sensor.grid import sensor_grid
from evperc.sensor.ground import OBSTACLE
from evperc.sensor.params import SensorParams

log = logging.getLogger(__name__)


class PosedScan(Protocol):
    """What the check reads of a scan (:class:`evperc.logs.scan.PosedScan`; the sensor
    stage does not import the log readers)."""

    stamp_ns: int
    points: np.ndarray
    planar: bool
    T_world_sensor: np.ndarray


#: m of horizontal motion between the two scans compared
BASELINE_M = 3.0
#: m: a second scan posed farther than this from the first is a jump in the poses (30 m/s
#: for 0.2 s after the baseline), not a pair to compare: the check stops there
MAX_BASELINE_M = 9.0
#: scans read at most to find the second one
MAX_SCANS = 200
#: m: the returns compared lie at most this far from their sensor (horizontally)
REACH_M = 30.0
#: m: the raster that marks the first scan's returns
RASTER_M = 0.1
#: m: the offsets searched, within ±SEARCH_M on each axis, first by COARSE_M, then by FINE_M
#: within ±COARSE_M of the best
SEARCH_M = 2.0
COARSE_M = 0.25
FINE_M = 0.05
#: offsets whose share is within this of the best are the flat top whose middle is reported
PLATEAU = 0.01
#: the second scan's returns used at most (every k-th: deterministic)
MAX_RETURNS = 20_000
#: degrees: the turns of the second scan compared (about its sensor): a heading or lidar-yaw
#: error
TURN_STEP_DEG = 0.5
TURNS_DEG = tuple(float(v) for v in np.arange(-3.0, 3.01, TURN_STEP_DEG))
#: the second scan's returns the turns are compared on at most
MAX_TURN_RETURNS = 5_000
#: m: with a turn, the offsets searched within this of the best offset without one
TURN_SEARCH_M = 0.75
#: degrees: a best turn at least this large (a return 15 m away misplaced by ~0.26 m, half a
#: cell) that raises the share by MISFIT_GAIN is a misfit too
MISFIT_YAW_DEG = 1.0
#: fewer obstacle returns than this in either scan: too little to judge
MIN_RETURNS = 200
#: the verdict: a best offset at least this far (m) ...
MISFIT_M = 0.25
#: ... that raises the share of matched returns by at least this much
MISFIT_GAIN = 0.10


@dataclass(frozen=True)
class PoseFit:
    """The comparison of two scans of the log (module docstring). ``first``, ``second``: the
    scans' positions in the requested span (0 = its first scan); ``seconds``: between their
    stamps; ``moved_m``: between their poses; ``share_at_poses``, ``share_best``: of the
    second scan's returns on the first's, at the poses and at ``offset_m`` (x, y: where the
    second scan fits best, relative to its pose)."""

    first: int
    second: int
    seconds: float
    moved_m: float
    returns: tuple[int, int]
    share_at_poses: float
    share_best: float
    offset_m: tuple[float, float]
    #: the turn (degrees, about the second scan's sensor) and the offset after it that fit
    #: best (:func:`fit_scans`), and their share; 0 / None when not searched
    yaw_deg: float = 0.0
    turned_offset_m: tuple[float, float] | None = None
    share_turned: float | None = None

    @property
    def offset_norm_m(self) -> float:
        return math.hypot(*self.offset_m)

    @property
    def misfit(self) -> bool:
        """The poses misplace the second scan (module docstring, step 4)."""
        return (self.offset_norm_m >= MISFIT_M
                and self.share_best - self.share_at_poses >= MISFIT_GAIN) or self.turns

    @property
    def turns(self) -> bool:
        """The second scan fits markedly better turned (module docstring, step 4)."""
        return (abs(self.yaw_deg) >= MISFIT_YAW_DEG and self.share_turned is not None
                and self.share_turned - self.share_at_poses >= MISFIT_GAIN)

    def summary(self) -> dict[str, object]:
        """For the run's manifest."""
        return {"scans": [self.first, self.second], "seconds": round(self.seconds, 3),
                "moved_m": round(self.moved_m, 3), "returns": list(self.returns),
                "share_at_poses": round(self.share_at_poses, 4),
                "share_best": round(self.share_best, 4),
                "offset_m": [round(v, 3) for v in self.offset_m], "misfit": self.misfit,
                "yaw_deg": self.yaw_deg, "turns": self.turns,
                "turned_offset_m": (None if self.turned_offset_m is None
                                    else [round(v, 3) for v in self.turned_offset_m]),
                "share_turned": (None if self.share_turned is None
                                 else round(self.share_turned, 4))}

    def message(self, log_name: str) -> str:
        """One line: what was found and what to check."""
        share = self.offset_norm_m / max(self.moved_m, 1e-9)
        return (f"{log_name}: the poses do not fit the scans: scan {self.second}'s returns "
                f"match scan {self.first}'s best {self.offset_norm_m:.2f} m from where their "
                f"poses put them ({share:.0%} of the {self.moved_m:.1f} m driven between them; "
                f"{self.share_at_poses:.0%} of its returns match at the poses, "
                f"{self.share_best:.0%} there{self._turn_text()}): expect walls and parked cars "
                "decided moving; check the pose topic, its frame and stamps, and the lidar's "
                "extrinsic")

    def fit_text(self) -> str:
        """How well the poses fit, in a few words (``evperc info``, for a fit)."""
        return (f"scan {self.second} lies {self.offset_norm_m:.2f} m from where its pose puts "
                f"it against scan {self.first}, {self.moved_m:.1f} m away")

    def _turn_text(self) -> str:
        if not self.turns or self.turned_offset_m is None or self.share_turned is None:
            return ""
        return (f"; turned {self.yaw_deg:+.1f}° about its sensor and moved "
                f"{math.hypot(*self.turned_offset_m):.2f} m, {self.share_turned:.0%}")


def obstacle_xy(scan: PosedScan, params: SensorParams, reach_m: float = REACH_M
                ) -> np.ndarray:
    """(N, 2) float64: the log-frame x, y of ``scan``'s obstacle returns (the sensor grid's
    ground split) within ``reach_m`` of the sensor."""
    kinds = np.empty(len(scan.points), np.uint8)
    T = np.asarray(scan.T_world_sensor, np.float64)
    res = 1.0  # the ground split comes before the grid: a one-cell grid is enough
    one_cell = Window(res, 1, 1, math.floor(T[1, 3] / res), math.floor(T[0, 3] / res))
    sensor_grid(scan.points, scan.planar, T, one_cell, params, kinds_out=kinds)
    points = np.asarray(scan.points, np.float64)[kinds == OBSTACLE]
    points = points[np.hypot(points[:, 0], points[:, 1]) <= reach_m]
    return (points @ T[:3, :3].T + T[:3, 3])[:, :2]


def _shares(marked: np.ndarray, origin: np.ndarray, b: np.ndarray,
            offsets: np.ndarray) -> np.ndarray:
    """For each (dx, dy) of ``offsets``: the share of ``b``'s points that, moved by it, fall
    on a marked cell of ``marked`` (cells of RASTER_M from ``origin``)."""
    out = np.empty(len(offsets))
    rows, cols = marked.shape
    for k, (dx, dy) in enumerate(offsets):
        ix = np.floor((b[:, 0] + (dx - origin[0])) / RASTER_M).astype(np.int64)
        iy = np.floor((b[:, 1] + (dy - origin[1])) / RASTER_M).astype(np.int64)
        inside = (ix >= 0) & (ix < cols) & (iy >= 0) & (iy < rows)
        out[k] = np.count_nonzero(marked[iy[inside], ix[inside]]) / len(b)
    return out


def _grid(step: float, half: float, centre: tuple[float, float]) -> np.ndarray:
    n = round(half / step)
    steps = np.arange(-n, n + 1) * step
    return np.array([(centre[0] + dx, centre[1] + dy) for dx in steps for dy in steps])


def _raster(a: np.ndarray, b: np.ndarray, half: float = SEARCH_M
            ) -> tuple[np.ndarray, np.ndarray]:
    """``(marked, origin)``: ``a``'s returns on a raster of :data:`RASTER_M` cells from
    ``origin``, each widened by its 8 neighbours, over ``a`` and ``b`` and the reach of a
    search within ``half``."""
    margin = half + COARSE_M + 2 * RASTER_M
    origin = np.minimum(a.min(axis=0), b.min(axis=0)) - margin
    top = np.maximum(a.max(axis=0), b.max(axis=0)) + margin
    cols, rows = (int(v) + 1 for v in np.floor((top - origin) / RASTER_M))
    hit = np.zeros((rows + 2, cols + 2), bool)
    hit[np.floor((a[:, 1] - origin[1]) / RASTER_M).astype(np.int64) + 1,
        np.floor((a[:, 0] - origin[0]) / RASTER_M).astype(np.int64) + 1] = True
    marked = np.zeros((rows, cols), bool)  # hit, widened by its 8 neighbours
    for dr in range(3):
        for dc in range(3):
            marked |= hit[dr:dr + rows, dc:dc + cols]
    return marked, origin


def _search(marked: np.ndarray, origin: np.ndarray, b: np.ndarray,
            centre: tuple[float, float] = (0.0, 0.0), half: float = SEARCH_M
            ) -> tuple[float, float, tuple[float, float]]:
    """:func:`fit_returns` on a raster made by :func:`_raster`; the coarse offsets within
    ``half`` of ``centre``."""
    at_poses = float(_shares(marked, origin, b, np.zeros((1, 2)))[0])
    coarse = _grid(COARSE_M, half, centre)
    shares = _shares(marked, origin, b, coarse)
    centre = coarse[int(np.argmax(shares))]
    fine = _grid(FINE_M, COARSE_M, (float(centre[0]), float(centre[1])))
    shares = _shares(marked, origin, b, fine)
    top = float(shares.max())
    if top <= at_poses:
        return at_poses, at_poses, (0.0, 0.0)
    # a return matches within a raster cell or two, so the share is flat near its maximum:
    # the middle of that top, not its first offset
    flat = fine[shares >= top - PLATEAU]
    return at_poses, top, (float(flat[:, 0].mean()), float(flat[:, 1].mean()))


def _thinned(b: np.ndarray, most: int) -> np.ndarray:
    return b[::math.ceil(len(b) / most)] if len(b) > most else b


def best_offset(a: np.ndarray, b: np.ndarray, half: float = SEARCH_M
                ) -> tuple[float, float, tuple[float, float]]:
    """Points ``b`` on points ``a`` (both (N, 2) x, y), without a turn: ``(share at no offset,
    best share, best offset (x, y))`` of ``b`` (at most :data:`MAX_RETURNS` of them, every
    k-th), searched as :func:`fit_scans` does (step 3 of the module docstring), the coarse
    offsets within ``half`` on each axis."""
    b = _thinned(b, MAX_RETURNS)
    marked, origin = _raster(a, b, half)
    return _search(marked, origin, b, half=half)


def fit_scans(a: np.ndarray, b: np.ndarray, sensor: tuple[float, float]
              ) -> tuple[tuple[float, float, tuple[float, float]],
                         tuple[float, float, tuple[float, float]]]:
    """Returns ``b`` on returns ``a`` (both (N, 2) log-frame x, y; module docstring, step 3):
    ``(share at the poses, best share, best offset (x, y))`` — the best offset the mean of
    the fine offsets whose share is within :data:`PLATEAU` of the best (the share's flat
    top), (0, 0) when no offset beats the poses — and ``(turn, share, offset)`` of ``b``
    turned about ``sensor`` (:func:`_best_turn`), on one raster."""
    b = _thinned(b, MAX_RETURNS)
    marked, origin = _raster(a, b)
    unturned = _search(marked, origin, b)
    return unturned, _best_turn(marked, origin, b, sensor, unturned)


def _best_turn(marked: np.ndarray, origin: np.ndarray, b: np.ndarray,
               sensor: tuple[float, float], unturned: tuple[float, float, tuple[float, float]]
               ) -> tuple[float, float, tuple[float, float]]:
    """``(yaw, share, offset)``: the turn of ``b`` about ``sensor`` (its sensor's x, y), of
    :data:`TURNS_DEG`, and the offset after it, that match the most of ``b`` on the raster
    — what a heading or extrinsic yaw error looks like. ``unturned``: :func:`_search`'s
    result without a turn; the offsets are searched within :data:`TURN_SEARCH_M` of its
    offset (a turn moves it little). The whole degrees of :data:`TURNS_DEG` are compared
    first, then the half degrees beside the best, each on at most :data:`MAX_TURN_RETURNS`
    returns; ties: the smaller turn."""
    near = unturned[2]
    few = _thinned(b, MAX_TURN_RETURNS)
    shares: dict[float, float] = {}

    def share_at(yaw: float) -> float:
        if yaw not in shares:
            shares[yaw] = _search(marked, origin, _turned(few, sensor, yaw), near,
                                  TURN_SEARCH_M)[1]
        return shares[yaw]

    best = max(sorted(TURNS_DEG[::2], key=abs), key=share_at)
    best = max(sorted((best - TURN_STEP_DEG, best, best + TURN_STEP_DEG), key=abs),
               key=lambda y: share_at(y) if y in TURNS_DEG else -1.0)
    if best == 0.0:
        return 0.0, unturned[1], near
    _, share, offset = _search(marked, origin, _turned(b, sensor, best), near, TURN_SEARCH_M)
    return best, share, offset


def _turned(b: np.ndarray, centre: tuple[float, float], yaw_deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    d = b - centre
    return np.column_stack([centre[0] + c * d[:, 0] - s * d[:, 1],
                            centre[1] + s * d[:, 0] + c * d[:, 1]])


def check_poses(scans: Iterable[PosedScan], params: SensorParams) -> PoseFit | None:
    """The :class:`PoseFit` of the first scan of ``scans`` and the first one posed
    :data:`BASELINE_M` away (at most :data:`MAX_SCANS` read), or None when the vehicle did
    not move that far, a scan has fewer than :data:`MIN_RETURNS` obstacle returns (a sparse
    sensor: nothing to judge by), or a pose is not finite or jumps more than
    :data:`MAX_BASELINE_M` (the raster would span the jump)."""
    first: PosedScan | None = None
    for index, scan in enumerate(scans):
        if index >= MAX_SCANS:
            return None
        if not np.isfinite(scan.T_world_sensor).all():
            return None  # a damaged pose: the run's own checks deal with it
        if first is None:
            first = scan
            continue
        moved = float(np.hypot(*(scan.T_world_sensor[:2, 3] - first.T_world_sensor[:2, 3])))
        if moved < BASELINE_M:
            continue
        if moved > MAX_BASELINE_M:  # a jump, not driving: no common scene to compare
            log.info("poses not checked against the scans: they jump %.0f m between two "
                     "scans", moved)
            return None
        a, b = obstacle_xy(first, params), obstacle_xy(scan, params)
        if min(len(a), len(b)) < MIN_RETURNS:
            log.info("poses not checked against the scans: %d and %d obstacle returns within "
                     "%.0f m, under %d (a sparse sensor)", len(a), len(b), REACH_M, MIN_RETURNS)
            return None
        (at_poses, best, offset), (yaw, turned_share, turned) = fit_scans(
            a, b, (float(scan.T_world_sensor[0, 3]), float(scan.T_world_sensor[1, 3])))
        return PoseFit(0, index, (scan.stamp_ns - first.stamp_ns) * 1e-9, moved,
                       (len(a), len(b)), at_poses, best, offset, yaw, turned, turned_share)
    return None
