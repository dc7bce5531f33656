#!/usr/bin/env python3
"""Why moving agents are missed (issue 21): runs ``evperc run`` in process with a hook on the
object stage, then attributes every missed moving agent-frame of the simulator's truth to a
cause, and summarises the moving episodes never detected.

An agent-frame is an agent with a cell of truth class M that is ``visible`` in the frame (the
true moving objects of :class:`evperc.eval.metrics.ObjectScore`). It is *found* if a reported
``moving`` object holds a majority of agent cells of that agent (the same rule). A missed one
gets the first cause that applies, in the order of the pipeline:

- ``no_return``: no cell of the agent (dilated by one cell: returns spill) holds a return of
  this scan and none is decided moving: nothing to cluster;
- ``small_cluster``: the agent's returns form groups (the clustering with no size limit)
  all smaller than ``min_cluster_cells``;
- ``too_large``: the group is longer than ``max_cluster_extent_m`` (merged with a wall);
- ``young_track``: its cluster's track has fewer than ``confirm_frames`` associations;
- ``velocity_test``: the track is confirmed but its fitted velocity fails the speed or
  Mahalanobis test;
- ``no_evidence``: the velocity passes but the grid's motion evidence is still short of
  ``motion_evidence_frames``;
- ``merged``: a moving object is reported there, but most of its cells are another agent's;
- ``adjacent``: a moving object is reported on the agent's returns, but they lie in the
  cells next to its truth-M cells (the match counts M cells only);
- ``other``: none of the above (the agent's returns are in no kept cluster or no track).

A ``small_cluster`` agent-frame is detailed (the table "Small clusters"): its group was kept
all the same (by the isolated or the small-conflict rule: ``kept:`` and why its track was
not reported, the causes above — ``young_track`` / ``velocity_test`` / ``no_evidence`` /
``adjacent`` — or ``no_track``), or it was dropped with a cell decided moving
(``moving_cell``), or with none: ``no_moving_cell`` and the largest ∅_FO under the agent
(×255: 0, < 25, < 64, < 128, ≥ 128) — the conflict a gate-closed cell keeps, which no rule
reads as motion. ``tall``: a return at least ``isolated_min_height_m`` (0.4 m) up within one
cell. For a dropped tall group (``no_moving_cell tall``) the table "What breaks the
isolation" names the truth of the cells decided static, stopped, unmapped or infrastructure
within ``isolated_clearance_m`` of it (:func:`isolation_breakers`): ``free`` there is a cell
still decided as it was held while nothing is in it — the cells a walker has just left;
``none (N cells)``: isolated, but smaller than ``isolated_min_cells``.

``--after-backfill``: an agent-frame is found when the run's final object list (the backfill's
fills and gaps included) holds it, not the object stage's own records of the frame; the
causes are those of the frame's own step all the same.

A ``velocity_test`` agent-frame is detailed too (the table "Velocity test"): its track's
fitted speed under ``moving_speed_m_per_s`` (``slow``, with the agent's own speed at the
frame: < 0.3, < 0.6 or ≥ 0.6 m/s — the truth calls an agent moving above 0.1 m/s), or
the Mahalanobis test failing with the fit's centroid noise at the floor
``centroid_sigma_m`` (``floor``) or above it (``residual``: the centroids scatter more than
the floor), each with ``evidence`` when the track already has
some motion evidence (conflict or vacated frames) and ``no evidence`` when it has none.

Found by role and range (the table "Found by role and range"): every agent-frame by the
agent's role and the range from the sensor to the centre of its visible truth-M cells
(< 20, 20–40, 40–60, ≥ 60 m); and by role and the agent's own speed at the frame against
``moving_speed_m_per_s`` (the table "Found by role and planned speed": an agent setting off
or slowing down is M from 0.1 m/s, and the simulator smooths its speed over 2 s).

An agent's speed is the simulator's, exact: the drive planned again from the truth
manifest's map, roads, profile, length and seed (:func:`planned_speeds`); where that plan is
not the truth's drive (another simulator configuration), the speed over the second around
the frame from its truth cells' centroid (whole cells: a person's start reads as 0.5–1 m/s).

Cell level: the visible truth-M cells not decided ``moving`` are split by what they are
decided and by whether their agent was found (a found agent's undecided cells are what a
footprint completion could fill).

    PYTHONPATH=$PWD .venv/bin/python scripts/trace_missed.py --work /tmp/objstudy --seeds 1,2
    (the drives of scripts/object_study.py: WORK/drives/PROFILE-sSEED, simulated if absent;
    the object stage replayed on the fusion outputs recorded by scripts/object_replay.py)
"""

from __future__ import annotations

import argparse
import collections
import json
import logging
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

import object_replay  # noqa: E402

from evperc.eval.metrics import dilate_one_cell  # noqa: E402
from evperc.fusion.twin import DECISION_CODES  # noqa: E402
from evperc.objects.clusters import (  # noqa: E402
    STILL,
    Clusterer,
    ClusterParams,
    isolated_reach,
    with_return_centroids,
)
from evperc.objects.tracking import footprint_seeds, is_moving, track_step  # noqa: E402
from evperc.output.objects import OBJECT_STATES, record_cells  # noqa: E402
from evperc.sim.truth import load_truth  # noqa: E402

log = logging.getLogger("trace_missed")

CAUSES = ("no_return", "small_cluster", "too_large", "young_track", "velocity_test",
          "no_evidence", "merged", "adjacent", "other")
_NAMES = {v: k for k, v in DECISION_CODES.items()}


@dataclass
class FrameRecord:
    """What the object stage saw and did in one frame (global lattice = window + origin)."""

    stamp_ns: int
    row0: int
    col0: int
    shape: tuple[int, int]
    occupied: np.ndarray          # flat window indices holding a return
    relaxed_cells: np.ndarray     # clusters without size limits, flat, cluster by cluster
    relaxed_offsets: np.ndarray
    relaxed_extent: np.ndarray    # (n,) largest bbox side, m
    kept_label: dict[int, int]    # flat window cell -> kept cluster index
    cluster_track: list[dict[str, Any] | None]  # per kept cluster: its track after the step
    moving_objects: list[np.ndarray]  # flat cells of each reported moving object
    decision: np.ndarray          # flat, the fusion's decision the step read
    conflict_fo: np.ndarray       # flat, ∅_FO ×255
    heights: np.ndarray | None    # flat, highest return above the ground (float16)


RECORDS: list[FrameRecord] = []


def traced_step(self: Any, state: Any, decision: np.ndarray, betp_moving: np.ndarray,
                conflict_fo: np.ndarray, window: Any, stamp_ns: int,
                occupied_now: np.ndarray | None = None, heights: np.ndarray | None = None,
                near_building: np.ndarray | None = None, return_sums: np.ndarray | None = None,
                sensor_xy: tuple[float, float] | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`ObjectStage.step` (the same calls, the same results) that appends a
    :class:`FrameRecord` to :data:`RECORDS`."""
    seeds = footprint_seeds(state, window)
    clusters = self.clusterer.clusters(decision, betp_moving, conflict_fo, window, seeds,
                                       occupied_now, heights, near_building)
    self.list_small_moving(decision, heights)
    relaxed = getattr(self, "_trace_relaxed", None)
    if relaxed is None:
        p = self.cluster_params
        rp = ClusterParams(min_cells=1, max_extent_m=1e9, seed_conflict_fo=p.seed_conflict_fo,
                           seeds=p.seeds)
        relaxed = self._trace_relaxed = Clusterer(rp, decision.shape)
    rc = relaxed.clusters(decision, betp_moving, conflict_fo, window, seeds, occupied_now)
    clusters = self.splitter.split(clusters, state, window, stamp_ns, decision, betp_moving,
                                   conflict_fo)
    if return_sums is not None and self.needs_return_sums:
        p = self.cluster_params
        clusters = with_return_centroids(clusters, return_sums, window, p.centroid_max_cells,
                                         p.centroid_min_returns, heights, sensor_xy,
                                         p.centroid_depth_m)
    records, cells = track_step(state, clusters, window, stamp_ns, self.tracking_params,
                                decision, near_building)
    extent = np.maximum(rc.bbox_m[:, 2] - rc.bbox_m[:, 0], rc.bbox_m[:, 3] - rc.bbox_m[:, 1]) \
        if len(rc) else np.zeros(0)
    kept_label: dict[int, int] = {}
    first_of: dict[tuple[int, int], int] = {}
    for k in range(len(clusters)):
        ck = clusters.cells_of(k)
        for c in ck.tolist():
            kept_label[c] = k
        r, c = divmod(int(ck[0]), window.cols)
        first_of[(r + window.row0, c + window.col0)] = k
    cluster_track: list[dict[str, Any] | None] = [None] * len(clusters)
    tp = self.tracking_params
    for t in state.tracks:
        if t.missed or not len(t.footprint):
            continue
        k = first_of.get((int(t.footprint[0, 0]), int(t.footprint[0, 1])))
        if k is None:
            continue
        cluster_track[k] = {"id": t.track_id, "hits": t.hits,
                            "fast": is_moving(t.velocity, t.sigma, tp), "moving": t.moving,
                            "ever_moving": t.ever_moving, "speed": math.hypot(*t.velocity),
                            "sigma": t.sigma, "floor": _at_floor(t, tp.centroid_sigma_m),
                            "evidence": (t.conflict_evidence, t.vacated_evidence)}
    moving_objects = []
    at = 0
    for rec in records:
        n = int(rec["cell_count"])
        if rec["state"] == OBJECT_STATES["moving"]:
            moving_objects.append(np.asarray(cells[at:at + n], np.int64))
        at += n
    occ = (np.flatnonzero(occupied_now.reshape(-1)) if occupied_now is not None
           else np.zeros(0, np.int64))
    RECORDS.append(FrameRecord(int(stamp_ns), window.row0, window.col0, decision.shape, occ,
                               rc.cells.copy(), rc.offsets.copy(), extent, kept_label,
                               cluster_track, moving_objects, decision.reshape(-1).copy(),
                               conflict_fo.reshape(-1).copy(),
                               None if heights is None
                               else heights.reshape(-1).astype(np.float16)))
    return records, cells


def _at_floor(track: Any, sigma0: float) -> bool:
    """Whether a track's velocity fit took the centroid noise floor ``sigma0`` (its residual
    scatter smaller), from its standard deviation s = σ / √S (evperc.objects.tracking). The
    floor is ``centroid_sigma_m`` alone with ``centroid_sigma_per_m`` 0, the default; with a
    range term the floor is higher and this reads some floor fits as residual ones."""
    t = np.asarray(track.t_ns, np.float64) * 1e-9
    spread = float(((t - t.mean()) ** 2).sum()) if t.size else 0.0
    return (not math.isfinite(track.sigma) or spread <= 0.0
            or track.sigma * math.sqrt(spread) <= sigma0 * (1 + 1e-6))


def _velocity_detail(track: dict[str, Any], v0: float, truth_speed: float | None) -> str:
    """A ``velocity_test`` agent-frame's detail (module docstring)."""
    evidence = "evidence" if any(track["evidence"]) else "no evidence"
    if track["speed"] < v0:
        speed = ("truth ?" if truth_speed is None else "truth < 0.3" if truth_speed < 0.3
                 else "truth < 0.6" if truth_speed < 0.6 else "truth >= 0.6")
        return f"slow ({speed} m/s), {evidence}"
    return f"{'floor' if track['floor'] else 'residual'}, {evidence}"


def _speed_around(path: list[tuple[int, float, float]], stamp: int) -> float | None:
    """An agent's speed over the second around ``stamp`` (m/s) from its truth cells'
    centroids (``path``: (stamp, x, y) in time order); None near the ends of its path."""
    stamps = np.array([p[0] for p in path], np.int64)
    i0 = int(np.searchsorted(stamps, stamp - 500_000_000))
    i1 = int(np.searchsorted(stamps, stamp + 500_000_000, "right")) - 1
    if i0 >= i1 or stamps[i1] - stamps[i0] < 800_000_000:
        return None
    (t0, x0, y0), (t1, x1, y1) = path[i0], path[i1]
    return math.hypot(x1 - x0, y1 - y0) / ((t1 - t0) * 1e-9)


def planned_speeds(truth: Any) -> dict[int, np.ndarray] | None:
    """Every agent's speed (m/s) at each scan of the drive, exact: the simulator's plan of
    the drive (:func:`evperc.sim.drive.plan`, no scan cast) from the truth manifest's map,
    roads, profile, length and seed, with the default configuration's simulator keys; by
    truth agent id (1 + the plan's agent index), an array over the truth's frames. None when
    the plan is not the truth's drive (other agents' roles than the manifest's, or the
    agents at the first scan a median of more than 0.5 m from their truth cells' centroids:
    a drive simulated with other keys, or a moved map) — the cells' estimate
    (:func:`_speed_around`) stands then."""
    from evperc.config import load_config
    from evperc.sim.drive import SimRequest, plan
    from evperc.sim.scene import read_map_layers

    m = truth.manifest

    def where(name: str) -> Path:  # a relative path in the manifest: from the project root
        path = Path(name)
        return path if path.is_absolute() or path.exists() else REPO / path

    try:
        roads = where(m["roads"]) if m.get("roads") else None
        layers = read_map_layers(where(m["map"]), roads)
        req = SimRequest(map_path=where(m["map"]), out_dir=Path("."), config=load_config(),
                         roads_path=roads, profile=m["profile"], seconds=float(m["seconds"]),
                         seed=int(m["seed"]))
        agents = plan(req, layers).agents
    except (OSError, KeyError, ValueError) as err:
        log.warning("no planned speeds (%s): the truth cells' estimate", err)
        return None
    first = next(iter(truth.frames))
    res = first.window.resolution_m
    off = []  # an agent cut by the window's edge has its centroid off: the median decides
    for a in np.unique(first.agent[first.agent > 0]).tolist():
        rr, cc = np.nonzero(first.agent == a)
        if a - 1 < len(agents):
            off.append(math.hypot((cc.mean() + first.window.col0 + 0.5) * res
                                  - agents.x[0, a - 1],
                                  (rr.mean() + first.window.row0 + 0.5) * res
                                  - agents.y[0, a - 1]))
    if ([str(r) for r in agents.role] != [a.get("role") for a in truth.agents]
            or not off or float(np.median(off)) > 0.5):
        log.warning("the simulator's plan is not the truth's drive: the truth cells' speed "
                    "estimate")
        return None
    return {a + 1: np.abs(agents.speed[:, a]) for a in range(len(agents))}


def _speed_bucket(v: float | None, v0: float) -> str:
    """An agent-frame's planned speed against the motion test's ``v0``."""
    if v is None:
        return "speed ?"
    return (f"< {v0:g} m/s" if v < v0 else f"{v0:g}-1 m/s" if v < 1.0 else ">= 1 m/s")


RANGES_M = (20.0, 40.0, 60.0)


def _range_band(r: float) -> str:
    for lo, hi in zip((0.0, *RANGES_M[:-1]), RANGES_M, strict=True):
        if r < hi:
            return f"{lo:.0f}-{hi:.0f} m"
    return f">= {RANGES_M[-1]:.0f} m"


def _final_moving(frame: Any) -> list[np.ndarray]:
    """The flat cells of each moving record of a run frame's final object list."""
    objects = frame.objects
    return [c for c, state in zip(record_cells(objects, frame.object_cells), objects["state"],
                                  strict=True) if state == OBJECT_STATES["moving"]]


def _kept_track(rec: FrameRecord, near: np.ndarray) -> tuple[bool, dict[str, Any] | None]:
    """Whether a kept cluster holds any of the cells ``near``, and the track (after the
    step) of the one holding most of them (None: no track)."""
    kept = [k for k in (rec.kept_label.get(int(c)) for c in near.tolist()) if k is not None]
    if not kept:
        return False, None
    return True, rec.cluster_track[collections.Counter(kept).most_common(1)[0][0]]


def _track_cause(track: dict[str, Any], confirm: int) -> str:
    """Why a track was not reported moving on an agent (module docstring's causes, in their
    order): ``young_track``, ``velocity_test``, ``no_evidence``, else ``adjacent`` (it was,
    on the cells next to the agent's)."""
    if track["hits"] < confirm:
        return "young_track"
    if not track["fast"]:
        return "velocity_test"
    if not track["moving"]:
        return "no_evidence"
    return "adjacent"


def _small_detail(rec: FrameRecord, near: np.ndarray, occ: np.ndarray, confirm: int,
                  min_height_m: float) -> str:
    """What became of a ``small_cluster`` agent-frame's group (module docstring)."""
    kept, track = _kept_track(rec, near)
    if kept:
        return "kept:" + ("no_track" if track is None else _track_cause(track, confirm))
    tall = (rec.heights is not None and near.size > 0
            and float(rec.heights[near].max()) >= min_height_m)
    height = "tall" if tall else "low"
    if (rec.decision[near] == DECISION_CODES["moving"]).any():
        return f"moving_cell {height}"
    fo = int(rec.conflict_fo[near].max()) if near.size else 0
    level = next(f"<{b}" for b in (1, 25, 64, 128, 256) if fo < b)
    decided = "/".join(sorted({_NAMES.get(int(x), "?") for x in rec.decision[near[occ[near]]]}))
    return f"no_moving_cell {height} {decided} fo{level}"


_STILL_CODES = np.array([DECISION_CODES[n] for n in STILL], np.uint8)


def isolation_breakers(group: np.ndarray, decision: np.ndarray, reach: int, agent: int,
                       agent_run: np.ndarray, class_run: np.ndarray,
                       class_names: dict[int, str]) -> list[str]:
    """What keeps a small group from being isolated (:func:`evperc.objects.clusters._isolated`),
    by the truth: the cells decided static, stopped, unmapped or infrastructure within
    ``reach`` cells (Chebyshev) of the group's cells ``group`` (flat, on the run window of
    ``decision``, (rows, cols)), not in it, each named ``same agent`` (``agent_run``, the
    truth agent of each run cell, is ``agent``), ``another agent``, ``outside`` (no truth:
    ``class_run`` < 0) or its truth class (``class_names``; ``free``: a cell decided as it
    was held, which no return holds now — the cells a walker left). Sorted, each once."""
    rows, cols = decision.shape
    flat, agents, classes = decision.reshape(-1), agent_run.reshape(-1), class_run.reshape(-1)
    inside = set(np.asarray(group, np.int64).tolist())
    kinds: set[str] = set()
    for g in inside:
        r, c = divmod(g, cols)
        for rr in range(max(r - reach, 0), min(r + reach + 1, rows)):
            for cc in range(max(c - reach, 0), min(c + reach + 1, cols)):
                j = rr * cols + cc
                if j in inside or flat[j] not in _STILL_CODES:
                    continue
                who, cls = int(agents[j]), int(classes[j])
                if who == agent:
                    kinds.add("same agent")
                elif who > 0:
                    kinds.add("another agent")
                elif cls < 0:
                    kinds.add("outside")
                else:
                    kinds.add(class_names.get(cls, "?"))
    return sorted(kinds)


def _on_run(layer: np.ndarray, tw: Any, rec: FrameRecord, fill: int) -> np.ndarray:
    """A truth window's ``layer`` (``tw``'s shape) on the run window of ``rec``: (rows, cols)
    int64, ``fill`` where the truth window does not reach."""
    out = np.full(rec.shape, fill, np.int64)
    r0, c0 = max(tw.row0, rec.row0), max(tw.col0, rec.col0)
    r1 = min(tw.row0 + layer.shape[0], rec.row0 + rec.shape[0])
    c1 = min(tw.col0 + layer.shape[1], rec.col0 + rec.shape[1])
    if r0 < r1 and c0 < c1:
        out[r0 - rec.row0:r1 - rec.row0, c0 - rec.col0:c1 - rec.col0] = \
            layer[r0 - tw.row0:r1 - tw.row0, c0 - tw.col0:c1 - tw.col0]
    return out


def _to_window(lattice_rc: np.ndarray, rec: FrameRecord) -> np.ndarray:
    r = lattice_rc[:, 0] - rec.row0
    c = lattice_rc[:, 1] - rec.col0
    ok = (r >= 0) & (r < rec.shape[0]) & (c >= 0) & (c < rec.shape[1])
    return r[ok] * rec.shape[1] + c[ok]


def attribute(records: list[FrameRecord], truth: Any, run: Any, params: dict[str, Any],
              after_backfill: bool = False) -> dict[str, Any]:
    """Causes per missed agent-frame, the missed episodes, the small clusters' detail and
    the cell-level split; with ``after_backfill`` found by the run's final object list."""
    by_stamp = {r.stamp_ns: r for r in records}
    run_by_stamp = {f.stamp_ns: f for f in run.frames}
    min_cells = int(params["min_cluster_cells"])
    max_extent = float(params["max_cluster_extent_m"])
    confirm = int(params["confirm_frames"])
    min_height = float(params["isolated_min_height_m"])
    reach_cells = isolated_reach(float(params["isolated_clearance_m"]), truth.resolution_m)
    class_names = {code: name for name, code in truth.class_codes.items()}
    breakers: collections.Counter[str] = collections.Counter()
    roles = {a["id"]: a for a in truth.agents}
    causes: collections.Counter[str] = collections.Counter()
    by_role: dict[str, collections.Counter[str]] = collections.defaultdict(collections.Counter)
    found_n = total_n = 0
    cells_split: collections.Counter[str] = collections.Counter()
    small: collections.Counter[str] = collections.Counter()
    per_agent: dict[int, list[dict[str, Any]]] = collections.defaultdict(list)
    centroids: dict[int, list[tuple[int, float, float]]] = collections.defaultdict(list)
    by_range: dict[tuple[str, str], list[int]] = collections.defaultdict(lambda: [0, 0])
    # (agent, stamp, truth frame, role, track)
    slow_pending: list[tuple[int, int, int, str, dict[str, Any]]] = []
    v0 = float(params["moving_speed_m_per_s"])
    planned = planned_speeds(truth)
    by_speed: dict[str, list[int]] = collections.defaultdict(lambda: [0, 0])
    speed_causes: dict[str, collections.Counter[str]] = collections.defaultdict(
        collections.Counter)
    for t in truth.frames:
        rec = by_stamp.get(t.stamp_ns)
        f = run_by_stamp.get(t.stamp_ns)
        if rec is None or f is None:
            continue
        tw = t.window
        res = tw.resolution_m
        agent_ids = np.unique(t.agent[t.agent > 0])
        for a in agent_ids.tolist():  # centroids of every agent, for its speed
            rr, cc = np.nonzero(t.agent == a)
            centroids[a].append((t.stamp_ns, (cc.mean() + tw.col0 + 0.5) * res,
                                 (rr.mean() + tw.row0 + 0.5) * res))
        is_m = (t.classes == truth.class_codes["moving"]) & (t.agent > 0)
        vis_m = is_m & t.visible
        visible_agents = np.unique(t.agent[vis_m]).tolist()
        # run window rasters of this frame
        shape = rec.shape
        occ = np.zeros(shape[0] * shape[1], bool)
        occ[rec.occupied] = True
        relaxed_label = np.full(shape[0] * shape[1], -1, np.int64)
        for k in range(len(rec.relaxed_offsets) - 1):
            relaxed_label[rec.relaxed_cells[rec.relaxed_offsets[k]:rec.relaxed_offsets[k + 1]]] = k
        sizes = np.diff(rec.relaxed_offsets)
        # truth agent ids on the run window (for the object match)
        agent_run = _on_run(np.where(is_m, t.agent, 0), tw, rec, 0).reshape(-1)
        # every truth cell's class and agent on the run window (the isolation's breakers)
        class_run = _on_run(t.classes, tw, rec, -1)
        any_agent_run = _on_run(t.agent, tw, rec, 0)
        found: set[int] = set()
        merged_over: set[int] = set()
        for cells in (_final_moving(f) if after_backfill else rec.moving_objects):
            hits = agent_run[cells]
            hits = hits[hits > 0]
            if hits.size:
                best = int(np.bincount(hits).argmax())
                found.add(best)
                merged_over.update(set(np.unique(hits).tolist()) - {best})
        final = np.asarray(f.decision).reshape(-1)
        for a in visible_agents:
            total_n += 1
            role = str(roles.get(a, {}).get("role", "?"))
            ar, ac = np.nonzero(t.agent == a)
            mask = np.zeros(t.agent.shape, bool)
            mask[ar, ac] = True
            dil = dilate_one_cell(mask)
            dr, dc = np.nonzero(dil)
            near = _to_window(np.stack([dr + tw.row0, dc + tw.col0], 1), rec)
            vr, vc = np.nonzero(vis_m & (t.agent == a))
            vis_cells = _to_window(np.stack([vr + tw.row0, vc + tw.col0], 1), rec)
            is_found = a in found
            reach = math.hypot((vc.mean() + tw.col0 + 0.5) * res - float(t.sensor_pose[0]),
                               (vr.mean() + tw.row0 + 0.5) * res - float(t.sensor_pose[1]))
            band = by_range[(role, _range_band(reach))]
            band[0] += 1
            band[1] += int(is_found)
            true_speed = None if planned is None else float(planned[a][t.index])
            speed_key = f"{role} {_speed_bucket(true_speed, v0)}"
            speed_row = by_speed[speed_key]
            speed_row[0] += 1
            speed_row[1] += int(is_found)
            for code in final[vis_cells].tolist():
                name = _NAMES.get(int(code), "?")
                cells_split[("found " if is_found else "missed ") + name] += 1
            info = {"stamp": t.stamp_ns, "found": is_found, "cells": int(mask.sum()),
                    "visible": int(len(vis_cells)), "detected_cells": int(np.count_nonzero(
                        final[vis_cells] == DECISION_CODES["moving"]))}
            if is_found:
                found_n += 1
                info["cause"] = None
                per_agent[a].append(info)
                continue
            labels = relaxed_label[near]
            has_ret = occ[near]
            if not has_ret.any() and not (final[near] == DECISION_CODES["moving"]).any():
                cause = "no_return"
            else:
                lab = labels[labels >= 0]
                if lab.size == 0:
                    cause = "other"
                else:
                    best = int(np.bincount(lab).argmax())
                    info["group_cells"] = int(sizes[best])
                    if sizes[lab].max() < min_cells:
                        cause = "small_cluster"
                        detail = _small_detail(rec, near, occ, confirm, min_height)
                        small[f"{role} {detail}"] += 1
                        if detail.startswith("no_moving_cell tall"):  # why not isolated
                            group = rec.relaxed_cells[rec.relaxed_offsets[best]:
                                                      rec.relaxed_offsets[best + 1]]
                            kinds = isolation_breakers(
                                group, rec.decision.reshape(shape), reach_cells, a,
                                any_agent_run, class_run, class_names)
                            breakers[f"{role}: {', '.join(kinds)}" if kinds else
                                     f"{role}: none ({len(group)} cells)"] += 1
                    elif rec.relaxed_extent[best] > max_extent + 1e-9:
                        cause = "too_large"
                    else:
                        kept, tr_ = _kept_track(rec, near)
                        if not kept:
                            cause = "other"  # returns in no kept cluster
                        elif tr_ is None:
                            cause = "other"
                            info["other"] = "no_track"
                        else:
                            info["track"] = tr_
                            cause = _track_cause(tr_, confirm)
                            if cause == "velocity_test":
                                slow_pending.append((a, t.stamp_ns, t.index, role, tr_))
                            if cause == "adjacent" and a in merged_over:
                                cause = "merged"
            info["cause"] = cause
            speed_causes[speed_key][cause] += 1
            causes[cause] += 1
            by_role[role][cause] += 1
            per_agent[a].append(info)
    speeds = {}
    for a, cs in centroids.items():
        arr = np.array(cs)
        if len(arr) >= 2:
            d = np.hypot(np.diff(arr[:, 1]), np.diff(arr[:, 2]))
            dt = np.diff(arr[:, 0]) * 1e-9
            # path over duration: a one-cell pedestrian's centroid moves by whole cells
            speeds[a] = float(d.sum() / max(dt.sum(), 1e-9))
    episodes = []
    for a, infos in per_agent.items():  # episodes: consecutive visible frames of an agent
        infos.sort(key=lambda i: i["stamp"])
        groups: list[list[dict[str, Any]]] = []
        for i in infos:
            if groups and i["stamp"] - groups[-1][-1]["stamp"] <= 150_000_000:
                groups[-1].append(i)
            else:
                groups.append([i])
        for g in groups:
            detected = any(i["detected_cells"] for i in g)
            ag = roles.get(a, {})
            episodes.append({
                "agent": a, "role": ag.get("role"), "length_m": ag.get("length_m"),
                "width_m": ag.get("width_m"), "speed_m_per_s": speeds.get(a),
                "frames": len(g), "found_frames": sum(i["found"] for i in g),
                "cell_detected": detected, "max_visible_cells": max(i["visible"] for i in g),
                "causes": dict(collections.Counter(i["cause"] for i in g if i["cause"])),
                "group_cells": sorted({i.get("group_cells") for i in g
                                       if i.get("group_cells") is not None})})
    velocity: collections.Counter[str] = collections.Counter()
    for a, stamp, frame, role, tr_ in slow_pending:
        speed = (_speed_around(centroids[a], stamp) if planned is None
                 else float(planned[a][frame]))
        velocity[f"{role} {_velocity_detail(tr_, v0, speed)}"] += 1
    return {"agent_frames": total_n, "found": found_n, "causes": dict(causes),
            "small_clusters": dict(small), "isolation_breakers": dict(breakers),
            "velocity_test": dict(velocity),
            "by_range": {f"{role} {band}": v for (role, band), v in sorted(by_range.items())},
            "by_speed": {k: v for k, v in sorted(by_speed.items())},
            "speed_causes": {k: dict(v) for k, v in sorted(speed_causes.items())},
            "speeds_planned": planned is not None,
            "by_role": {k: dict(v) for k, v in by_role.items()},
            "cells": dict(cells_split), "episodes": episodes}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--seeds", default="1,2")
    parser.add_argument("--profiles", default="ibeo4,hdl64")
    parser.add_argument("--config", type=Path, help="a --config file for the runs")
    parser.add_argument("--set", default="", help="[objects] overrides of the replay, "
                        "'key=value;key=value' (scripts/object_replay.py)")
    parser.add_argument("--json", type=Path, help="write every result here")
    parser.add_argument("--after-backfill", action="store_true",
                        help="found: in the run's final object list (the backfill's fills)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    overrides = object_replay.parse_set(args.set)
    results = {}
    for profile in args.profiles.split(","):
        for seed in args.seeds.split(","):
            drive, out = object_replay.recorded(args.work, profile, seed, args.config)
            config = object_replay.replay_config(out, args.config, overrides)
            RECORDS.clear()
            run = object_replay.replay(out, config, step=traced_step)
            results[f"{profile}-s{seed}"] = attribute(list(RECORDS), load_truth(
                drive / "truth"), run, config["objects"], args.after_backfill)
    print_report(results)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1, default=str))


def _print_found(results: dict[str, Any], table: str) -> None:
    """The rows of ``table`` (key -> [agent-frames, found]) pooled over the runs."""
    pooled: dict[str, list[int]] = collections.defaultdict(lambda: [0, 0])
    for r in results.values():
        for key, (n, found) in r[table].items():
            pooled[key][0] += n
            pooled[key][1] += found
    for key, (n, found) in sorted(pooled.items()):
        print(f"  {key}: {found} / {n} ({found / n:.3f})")


def print_report(results: dict[str, Any]) -> None:
    print("\n| run | agent-frames | found | " + " | ".join(CAUSES) + " |")
    print("|---|---|---|" + "---|" * len(CAUSES))
    for name, r in results.items():
        print(f"| {name} | {r['agent_frames']} | {r['found']} | "
              + " | ".join(str(r["causes"].get(c, 0)) for c in CAUSES) + " |")
    print("\nSmall clusters (missed agent-frames, all runs; module docstring):")
    pooled: collections.Counter[str] = collections.Counter()
    for r in results.values():
        pooled.update(r["small_clusters"])
    for what, n in pooled.most_common():
        print(f"  {what}: {n}")
    print("\nWhat breaks the isolation of the dropped tall groups (the truth of the cells "
          "decided static, stopped, unmapped or infrastructure within "
          "isolated_clearance_m; all runs):")
    pooled = collections.Counter()
    for r in results.values():
        pooled.update(r["isolation_breakers"])
    for what, n in pooled.most_common():
        print(f"  {what}: {n}")
    print("\nVelocity test (missed agent-frames, all runs; module docstring):")
    pooled = collections.Counter()
    for r in results.values():
        pooled.update(r["velocity_test"])
    for what, n in pooled.most_common():
        print(f"  {what}: {n}")
    print("\nFound by role and range (agent-frames found / all, all runs):")
    _print_found(results, "by_range")
    planned = sum(r["speeds_planned"] for r in results.values())
    print(f"\nFound by role and planned speed (the simulator's, {planned} of {len(results)} "
          "runs; agent-frames found / all):")
    _print_found(results, "by_speed")
    print("\nMissed by role and planned speed, by cause (agent-frames, all runs):")
    by_cause: dict[str, collections.Counter[str]] = collections.defaultdict(collections.Counter)
    for r in results.values():
        for key, c in r["speed_causes"].items():
            by_cause[key].update(c)
    for key, c in sorted(by_cause.items()):
        print(f"  {key}: {dict(c.most_common())}")
    print("\nBy role (missed agent-frames):")
    for name, r in results.items():
        for role, c in sorted(r["by_role"].items()):
            print(f"  {name} {role}: {dict(sorted(c.items(), key=lambda kv: -kv[1]))}")
    print("\nVisible truth-M cells by final decision (found / missed agent):")
    for name, r in results.items():
        print(f"  {name}: {dict(sorted(r['cells'].items(), key=lambda kv: -kv[1]))}")
    print("\nEpisodes never decided moving (cell level):")
    for name, r in results.items():
        eps = r["episodes"]
        missed = [e for e in eps if not e["cell_detected"]]
        print(f"  {name}: {len(missed)} of {len(eps)}")
        for e in missed:
            sp = e["speed_m_per_s"]
            print(f"    agent {e['agent']} {e['role']} {e['length_m']:.1f}x{e['width_m']:.1f} m "
                  f"{'?' if sp is None else f'{sp:.1f}'} m/s, {e['frames']} frames, "
                  f"<= {e['max_visible_cells']} visible cells, groups {e['group_cells']}, "
                  f"causes {e['causes']}")


if __name__ == "__main__":
    main()
