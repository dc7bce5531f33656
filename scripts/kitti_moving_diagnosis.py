"""Where the moving points of a SemanticKITTI slice are lost (issues 20 and 21).

Runs ``evperc run SEQ --no-map --point-labels`` in this process with the runner's stages
wrapped (nothing of evperc is changed) and records, per scan: the motion gate layer, the
sensor grid, the decision before and after the object fill, ∅_FO, the clusters, the tracks
and the per-point kinds and labels. Then, for every point SemanticKITTI labels moving
(classes 252–259), the first reason in this order that it is not labelled moving:

    dropped-range     the sensor model drops it: horizontal range outside [min, max)
    dropped-height    ... higher than max_obstacle_height_m above the local ground
    outside           its cell lies outside the window
    ground            the ground split calls it ground (labelled static)
    moving            its cell is decided moving (a true positive)
    moving-reach      labelled moving by a moving object's reach (objects.point_reach_cells)
    reported-static   its cell is in a reported object that is not moving (stopped)
    track-unconfirmed in a cluster whose track has fewer than confirm_frames associations
    track-slow        ... confirmed, but the velocity test fails (speed or vᵀΣ⁻¹v)
    track-no-evidence ... the velocity passes but too few frames of grid evidence
    no-cluster-<dec>  in no kept cluster; <dec> the cell's decision before the fill

and, for each point, the gate state of its cell: ``ever`` (ever-free, the gate open),
the cell's free scans before this one (sensor m({F}) ≥ gate_min_free, no return) and the
fewest of its 3 × 3 block (the gate needs gate_free_s, 3 scans at 10 Hz, in all nine).

    PYTHONPATH=$PWD python scripts/kitti_moving_diagnosis.py ../shared/data/semantickitti/00 \
        [--set objects.confirm_frames=2 ...] [--config configs/semantickitti.toml] [--json F]

Prints a per-scan table of the reasons, the gate / cluster / track state of the moving
points, and the pooled MOS scores (scans from ``--warmup`` on) of the run's own labels.
"""

from __future__ import annotations

import argparse
import ast
import collections
import json
import logging
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import evperc.objects.stage as stage_mod  # noqa: E402
import evperc.runner as runner  # noqa: E402
from evperc.config import load_config  # noqa: E402
from evperc.eval.semantickitti import IGNORED_CLASSES, MOVING_CLASSES  # noqa: E402
from evperc.fusion.twin import DECISION_CODES  # noqa: E402
from evperc.objects.point_labels import MOVING, point_cells  # noqa: E402
from evperc.objects.tracking import is_moving  # noqa: E402
from evperc.sensor.ground import GROUND, IGNORED  # noqa: E402

log = logging.getLogger("kitti_moving_diagnosis")
NAMES = {v: k for k, v in DECISION_CODES.items()}


class Recorder:
    """Wraps the runner's stage functions for one run and keeps what they saw, per frame."""

    def __init__(self) -> None:
        self.frames: list[dict[str, Any]] = []
        self.numbers: list[int] = []  # each frame's scan file number (after the run)
        self._cur: dict[str, Any] = {}

    def install(self) -> list[tuple[Any, str, Any]]:
        saved = [(runner, "gate_step", runner.gate_step),
                 (runner, "fill_moving", runner.fill_moving),
                 (runner, "point_labels", runner.point_labels),
                 (stage_mod.ObjectStage, "step", stage_mod.ObjectStage.step)]
        rec = self
        gate_step, fill, labels_fn, obj_step = (s[2] for s in saved)

        def gate_wrap(state, free, occupied, dt_s, params, **kw):
            out = gate_step(state, free, occupied, dt_s, params, **kw)
            rec._cur = {"free": np.array(free), "occupied": np.array(occupied),
                        "gate": np.array(out)}
            return out

        def fill_wrap(decision, moving_cells):
            rec._cur["decision_before"] = decision.copy()
            rec._cur["moving_cells"] = np.array(moving_cells)
            return fill(decision, moving_cells)

        def step_wrap(self_, state, decision, betp_moving, conflict_fo, window, stamp_ns,
                      occupied_now=None, heights=None, near_building=None, return_sums=None,
                      sensor_xy=None):
            got: dict[str, Any] = {}
            inner = self_.clusterer.clusters

            def clusters_wrap(*a, **k):
                got["clusters"] = inner(*a, **k)
                return got["clusters"]
            self_.clusterer.clusters = clusters_wrap
            try:
                result = obj_step(self_, state, decision, betp_moving, conflict_fo, window,
                                  stamp_ns, occupied_now, heights, near_building,
                                  return_sums, sensor_xy)
            finally:
                del self_.clusterer.clusters
            rec._cur.update(clusters=got["clusters"], conflict_fo=np.array(conflict_fo),
                            decision_objects_in=decision.copy(),
                            objects=result[0].copy(), object_cells=np.array(result[1]),
                            tracks=[_track_view(t, window) for t in state.tracks],
                            params=self_.tracking_params)
            return result

        def labels_wrap(points, kinds, t_crs, window, decision, source_count=None,
                        source_index=None, **kw):
            out = labels_fn(points, kinds, t_crs, window, decision, source_count,
                            source_index, **kw)
            rec._cur.update(points=np.array(points), kinds=np.array(kinds[:len(points)]),
                            t_crs=np.array(t_crs), window=window,
                            decision=decision.copy(), labels=np.array(out),
                            source_index=None if source_index is None else np.array(
                                source_index), source_count=source_count)
            rec.frames.append(rec._cur)
            rec._cur = {}
            return out

        runner.gate_step = gate_wrap
        runner.fill_moving = fill_wrap
        runner.point_labels = labels_wrap
        stage_mod.ObjectStage.step = step_wrap
        return saved

    @staticmethod
    def uninstall(saved: list[tuple[Any, str, Any]]) -> None:
        for owner, name, value in saved:
            setattr(owner, name, value)


def _track_view(t: Any, window: Any) -> dict[str, Any]:
    r = t.footprint[:, 0] - window.row0 if len(t.footprint) else np.zeros(0, np.int64)
    c = t.footprint[:, 1] - window.col0 if len(t.footprint) else np.zeros(0, np.int64)
    return {"id": t.track_id, "hits": t.hits, "missed": t.missed, "moving": t.moving,
            "ever_moving": t.ever_moving, "velocity": t.velocity, "sigma": t.sigma,
            "conflict_evidence": t.conflict_evidence, "vacated_evidence": t.vacated_evidence,
            "cells": set((r * window.cols + c).tolist()) if t.missed == 0 else set()}


def run_recorded(seq: Path, config: dict[str, Any], out_dir: Path) -> Recorder:
    """The run of ``seq`` with its per-frame passes recorded, with
    ``objects.backfill_frames`` = 0: the hooks collect a frame's passes in the order the
    frame loop calls them, which the backfill changes (a frame's point labels come L frames
    later); the reasons are those of the causal frame (docs/method.md §8 step 8)."""
    config = {**config, "objects": {**config["objects"], "backfill_frames": 0}}
    rec = Recorder()
    saved = rec.install()
    try:
        runner.run(runner.RunRequest(log_path=seq, out_dir=out_dir, config=config,
                                     overwrite=True, point_labels=True), progress=False)
    finally:
        Recorder.uninstall(saved)
    # the scans' own file numbers, frame by frame (a folder may skip numbers)
    rec.numbers = [int(f.stem) for f in sorted((out_dir / "labels").glob("*.label"))]
    return rec


def truth_of(seq: Path, number: int) -> np.ndarray:
    return np.fromfile(seq / "labels" / f"{number:06d}.label", "<u4") & 0xFFFF


def free_runs(rec: Recorder, min_free: float) -> list[dict[tuple[int, int], int]]:
    """Per frame i, for every global cell, the consecutive free scans ending at scan i − 1
    (a return resets; a scan not observing the cell neither adds nor breaks: the gate's
    rule in scans, not seconds)."""
    runs: dict[tuple[int, int], int] = {}
    before = []
    for f in rec.frames:
        before.append(dict(runs))
        w = f["window"]
        free = (f["free"] >= min_free) & (f["occupied"] <= 0)
        occ = f["occupied"] > 0
        for r, c in zip(*np.nonzero(occ), strict=True):
            runs[(int(r) + w.row0, int(c) + w.col0)] = 0
        for r, c in zip(*np.nonzero(free), strict=True):
            k = (int(r) + w.row0, int(c) + w.col0)
            runs[k] = runs.get(k, 0) + 1
    return before


def diagnose(rec: Recorder, seq: Path, config: dict[str, Any], warmup: int) -> dict[str, Any]:
    sensor = config["sensor"]
    min_free = config["fusion"]["gate_min_free"]
    runs_before = free_runs(rec, min_free)
    moving_code = DECISION_CODES["moving"]
    scans = []
    pooled = collections.Counter()
    for i, f in enumerate(rec.frames):
        number = rec.numbers[i]
        truth = truth_of(seq, number)
        idx = f["source_index"] if f["source_index"] is not None else np.arange(len(f["points"]))
        gt = truth[idx]
        mov = np.isin(gt, MOVING_CLASSES)
        w = f["window"]
        pts = f["points"][mov]
        kinds = f["kinds"][mov]
        row, col, inside = point_cells(pts, f["t_crs"], w)
        hrange = np.hypot(pts[:, 0], pts[:, 1])
        all_labels = f["labels"][idx] if f["source_index"] is not None else f["labels"]
        point_said = all_labels[mov] == MOVING
        cells = np.where(inside, row * w.cols + col, -1)
        before = f.get("decision_before", f["decision"]).reshape(-1)
        after = f["decision"].reshape(-1)
        cl = f.get("clusters")
        cluster_of = {}
        if cl is not None:
            for k in range(len(cl)):
                for cell in cl.cells_of(k).tolist():
                    cluster_of[cell] = k
        tracks = f.get("tracks", [])
        track_of_cell = {cell: t for t in tracks for cell in t["cells"]}
        reported = {}
        if "objects" in f:
            o, oc, at = f["objects"], f["object_cells"], 0
            for rec_ in o:
                n = int(rec_["cell_count"])
                for cell in oc[at:at + n].tolist():
                    reported[cell] = int(rec_["state"])
                at += n
        params = f.get("params")
        reasons = collections.Counter()
        gate_open = free_cells = 0
        tracks_seen = {}
        occ_now = f["occupied"].reshape(-1) > 0
        not_now = 0
        for p in range(len(pts)):
            cell = int(cells[p])
            if kinds[p] == IGNORED:
                in_range = sensor["min_range_m"] <= hrange[p] < sensor["max_range_m"]
                reasons["dropped-height" if in_range else "dropped-range"] += 1
                continue
            if cell < 0:
                reasons["outside"] += 1
                continue
            if kinds[p] == GROUND:
                reasons["ground"] += 1
                continue
            gate_open += int(f["gate"].reshape(-1)[cell] > 0)
            free_cells += int(before[cell] == DECISION_CODES["free"])
            not_now += int(not occ_now[cell])
            t = track_of_cell.get(cell)
            if cell in cluster_of and t is not None:
                tracks_seen[t["id"]] = t
            if after[cell] == moving_code:
                reasons["moving"] += 1
                continue
            if point_said[p]:
                reasons["moving-reach"] += 1
                continue
            if cell in reported:
                reasons["reported-static"] += 1
                continue
            if cell in cluster_of and t is not None:
                if t["hits"] < params.confirm_frames:
                    reasons["track-unconfirmed"] += 1
                elif not is_moving(t["velocity"], t["sigma"], params):
                    reasons["track-slow"] += 1
                else:
                    reasons["track-no-evidence"] += 1
                continue
            reasons[f"no-cluster-{NAMES[int(before[cell])]}"] += 1
        # gate history of the moving points' obstacle cells
        hist = []
        rb = runs_before[i]
        for cell in sorted({int(c) for c, k in zip(cells, kinds, strict=True)
                            if c >= 0 and k != GROUND and k != IGNORED}):
            r, c = divmod(cell, w.cols)
            g = (r + w.row0, c + w.col0)
            own = rb.get(g, 0)
            block = min(rb.get((g[0] + dr, g[1] + dc), 0) for dr in (-1, 0, 1)
                        for dc in (-1, 0, 1))
            hist.append((own, block))
        labels = f["labels"][idx] if f["source_index"] is not None else f["labels"]
        labelled = ~np.isin(gt, IGNORED_CLASSES)
        said = labels == MOVING
        cnt = {"tp": int((said & mov).sum()), "fp": int((said & labelled & ~mov).sum()),
               "fn": int((~said & mov).sum()), "tn": int((~said & labelled & ~mov).sum())}
        if i >= warmup:
            pooled.update(cnt)
        scans.append({
            "scan": number, "moving_points": int(mov.sum()), "reasons": dict(reasons),
            "obstacle_cells": len(hist),
            "cells_with_free_before": sum(1 for own, _ in hist if own > 0),
            "cells_free_3_before": sum(1 for own, _ in hist if own >= 3),
            "cells_block_free_3_before": sum(1 for _, b in hist if b >= 3),
            "points_gate_open": gate_open, "points_cell_free": free_cells,
            "points_cell_no_return_now": not_now,
            "tracks": {tid: {k: t[k] for k in ("hits", "moving", "ever_moving",
                                               "conflict_evidence", "vacated_evidence")}
                       | {"speed": float(np.hypot(*t["velocity"])), "sigma": t["sigma"]}
                       for tid, t in tracks_seen.items()},
            "counts": cnt})
    return {"scans": scans, "pooled": dict(pooled), "scores": scores(pooled)}


def scores(c: collections.Counter | dict[str, int]) -> dict[str, float | None]:
    tp, fp, fn, tn = (c.get(k, 0) for k in ("tp", "fp", "fn", "tn"))
    return {"iou": tp / (tp + fp + fn) if tp + fp + fn else None,
            "precision": tp / (tp + fp) if tp + fp else None,
            "recall": tp / (tp + fn) if tp + fn else None,
            "static_to_moving": fp / (fp + tn) if fp + tn else None}


def _value(text: str) -> Any:
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("seq", type=Path)
    ap.add_argument("--config", type=Path)
    ap.add_argument("--preset")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--warmup", type=int, default=2)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    overrides = dict((k, _value(v)) for k, v in (s.split("=", 1) for s in args.set))
    config = load_config(args.config, overrides=overrides, preset=args.preset)
    with tempfile.TemporaryDirectory() as tmp:
        rec = run_recorded(args.seq, config, Path(tmp) / "run")
    result = diagnose(rec, args.seq, config, args.warmup)
    keys = sorted({k for s in result["scans"] for k in s["reasons"]})
    print("scan moving " + " ".join(f"{k:>18}" for k in keys))
    for s in result["scans"]:
        print(f"{s['scan']:4d} {s['moving_points']:6d} "
              + " ".join(f"{s['reasons'].get(k, 0):18d}" for k in keys))
    print("\nscan obst.cells free-before free>=3 block>=3 | pts: gate-open cell-free "
          "no-return-now | tracks")
    for s in result["scans"]:
        tr = "; ".join(f"#{tid} hits {t['hits']} v {t['speed']:.2f}±{t['sigma']:.2f} "
                       f"mov {int(t['moving'])} ev {t['conflict_evidence']}/"
                       f"{t['vacated_evidence']}" for tid, t in s["tracks"].items())
        print(f"{s['scan']:4d} {s['obstacle_cells']:10d} {s['cells_with_free_before']:11d} "
              f"{s['cells_free_3_before']:7d} {s['cells_block_free_3_before']:8d} | "
              f"{s['points_gate_open']:9d} {s['points_cell_free']:9d} "
              f"{s['points_cell_no_return_now']:13d} | {tr}")
    sc = result["scores"]
    print(f"\npooled scans {args.warmup}+: {result['pooled']} "
          + " ".join(f"{k} {v:.3f}" if v is not None else f"{k} -" for k, v in sc.items()))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1, default=str))


if __name__ == "__main__":
    main()
