#!/usr/bin/env python3
"""Where the false moving cells come from (issue "ibeofp"): replays the object stage on the
fusion outputs recorded by scripts/object_replay.py and attributes every false moving cell
of the ±1-cell score to a path of the pipeline and to what it is in the simulator's truth.

A *false moving cell* is one that counts against ``moving_within_one_cell`` precision
(:mod:`evperc.eval.metrics`): decided ``moving`` in the run's final decision, evaluated
(``--cells visible``: a ray of this scan reaches it; or ``observed``), and neither it nor
one of its 8 neighbours is truth class M.

Path (first that applies, in the order of the pipeline):

- ``fusion_no_object``: the fusion decided it moving (the conflict through the motion gate,
  the decision before the object stage's fill) and no reported moving object holds it;
- ``fusion_in_object``: the fusion decided it moving and a reported moving object holds it
  (the fill would have decided it moving anyway);
- ``fill``: the fusion did not decide it moving, the cluster cells of a reported moving
  object did (:func:`evperc.objects.stage.fill_moving`);
- ``backfill_candidate``, ``backfill_gap``, ``backfill_lead``, ``backfill_box``: a cell the
  backfill decided moving after the frame's own step (docs/method.md §8 step 8: a track's
  candidate filled when it was reported later, a gap bridged, the lead before its first
  association, the vehicle box of a record it added);
- ``completion``: a completed cell of the frame's own step (:mod:`evperc.objects.footprint`:
  carried forward from the object's earlier cluster cells where the scan is silent; the
  vehicle boxes of its own records).

Truth: its class (free / infrastructure / stopped / unmapped) and what is near it, the first
that applies within ``--near`` cells (Chebyshev): a moving agent (a spill of 2+ cells), a
stopped agent (parked car, stopped car, standing pedestrian: by the agent's role), unmapped
infrastructure (pole, trunk, bollard, fence), a building face; else ``open``.

Objects: a reported moving object of the final object list that holds no truth M cell
(:class:`evperc.eval.metrics.ObjectScore` matches none) is *false*. Per track: frames
reported falsely, its false cells, what its cells are in the truth (the majority class and
the agent role), its speed, age, and the evidence it was reported moving on (the tracker's
conflict / vacated counts when it was first reported moving; ``arrival``: the conflict
count jumped to the need in one frame, objects.arrival_share).

    PYTHONPATH=$PWD .venv/bin/python scripts/trace_false_moving.py --work /tmp/ibeofp \\
        --profiles ibeo4 --seeds 3,4,5,6 [--set "key=value"] [--json out.json]
    (drives WORK/drives/PROFILE-sSEED, simulated if absent; runs recorded in
    WORK/replay_runs/PROFILE-sSEED as scripts/object_replay.py does)
"""

from __future__ import annotations

import argparse
import collections
import json
import logging
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

import object_replay  # noqa: E402

from evperc.eval.metrics import dilate_one_cell  # noqa: E402
from evperc.fusion.twin import DECISION_CODES  # noqa: E402
from evperc.geo.window import Window, overlap  # noqa: E402
from evperc.output.objects import OBJECT_STATES, moving_object_cells  # noqa: E402
from evperc.sim.truth import load_truth  # noqa: E402

log = logging.getLogger("trace_false_moving")

#: the status of the track whose cluster (this frame's association) holds a cell
TRACK_STATUS = ("young", "confirmed_still", "confirmed_moving")
PATHS = ("fusion_no_object", "fusion_in_object", "fill", "backfill_candidate", "backfill_gap",
         "backfill_lead", "backfill_box", "completion")
NEAR = ("moving_agent", "stopped_car", "parked_car", "pedestrian", "unmapped", "building",
        "open")
UNMAPPED_SHAPES = ("none", "pole_or_bollard", "trunk", "fence")
RANGE_BINS = (10, 20, 33, 50, 1e9)
#: frames back in which a truth M cell within one cell makes a false cell a "trail"
TRAIL_FRAMES = 10
_MOVING = DECISION_CODES["moving"]
_MOVING_STATE = OBJECT_STATES["moving"]


@dataclass
class StageFrame:
    """What the object stage saw and returned in one frame, before the completion."""

    stamp_ns: int
    fusion_decision: np.ndarray   # (rows, cols) decision before the fill
    tracker_moving: np.ndarray    # flat window cells of the tracker's moving objects
    tracks: dict[int, dict[str, Any]]  # track id -> state after the step
    track_status: np.ndarray      # (rows, cols) int8: TRACK_STATUS of the track associated
    #                               with the cell's cluster this frame, -1 none


STAGE: list[StageFrame] = []


def traced_step(self: Any, state: Any, decision: np.ndarray, betp_moving: np.ndarray,
                conflict_fo: np.ndarray, window: Window, stamp_ns: int,
                occupied_now: np.ndarray | None = None, heights: np.ndarray | None = None,
                near_building: np.ndarray | None = None, return_sums: np.ndarray | None = None,
                sensor_xy: tuple[float, float] | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`ObjectStage.step` (the same call and result) that appends a
    :class:`StageFrame` to :data:`STAGE`."""
    fusion = decision.copy()
    objects, cells = self.__class__.step(self, state, decision, betp_moving, conflict_fo,
                                         window, stamp_ns, occupied_now, heights,
                                         near_building, return_sums, sensor_xy)
    moving = moving_object_cells(objects, cells)
    tracks = {}
    for i in range(len(state.id)):
        tracks[int(state.id[i])] = {
            "hits": int(state.hits[i]), "evidence": (int(state.evidence[i, 0]),
                                                     int(state.evidence[i, 1])),
            "moving": bool(state.flags[i, 1]), "ever_moving": bool(state.flags[i, 0])}
    status = np.full(decision.shape, -1, np.int8)
    confirm = self.tracking_params.confirm_frames
    ends = np.cumsum(state.fp_n)
    for i in range(len(state.id)):
        if state.missed[i] or not state.fp_n[i]:
            continue
        fp = state.fp[ends[i] - state.fp_n[i]:ends[i]]
        r, c = fp[:, 0] - window.row0, fp[:, 1] - window.col0
        inside = (r >= 0) & (r < window.rows) & (c >= 0) & (c < window.cols)
        k = (0 if state.hits[i] < confirm else 2 if state.flags[i, 1] else 1)
        status[r[inside], c[inside]] = k
    STAGE.append(StageFrame(int(stamp_ns), fusion,
                            np.zeros(0, np.int64) if moving is None else moving, tracks,
                            status))
    return objects, cells


def _near_labels(t: Any, roles: dict[int, str], codes: dict[str, int], reach: int
                 ) -> np.ndarray:
    """(rows, cols) index into :data:`NEAR` of each truth cell: the first thing within
    ``reach`` cells (Chebyshev)."""
    size = 2 * reach + 1
    out = np.full(t.classes.shape, NEAR.index("open"), np.int8)
    stopped = t.classes == codes["stopped"]
    agent_role = np.zeros(t.classes.shape, object)
    masks = {"moving_agent": t.classes == codes["moving"],
             "unmapped": t.classes == codes["unmapped"],
             "building": t.classes == codes["infrastructure"]}
    for role_name, near in (("stopped_car", "car"), ("parked_car", "parked"),
                            ("pedestrian", "pedestrian")):
        ids = [a for a, r in roles.items() if r == near]
        masks[role_name] = stopped & np.isin(t.agent, ids)
    del agent_role
    for name in reversed(NEAR[:-1]):  # the first in NEAR wins: written last
        m = ndimage.maximum_filter(masks[name].astype(np.uint8), size=size) > 0
        out[m] = NEAR.index(name)
    return out


def _unmapped_shapes(t: Any, codes: dict[str, int], reach: int) -> np.ndarray:
    """(rows, cols) index into :data:`UNMAPPED_SHAPES`: the largest side (cells) of the
    8-connected unmapped component within ``reach`` cells: 1-2 a pole or bollard, 3 a
    trunk, longer a fence."""
    u = t.classes == codes["unmapped"]
    labels, n = ndimage.label(u, structure=np.ones((3, 3)))
    side = np.zeros(n + 1, np.int64)
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        side[k] = max(sl[0].stop - sl[0].start, sl[1].stop - sl[1].start)
    big = ndimage.maximum_filter(side[labels], size=2 * reach + 1)
    out = np.zeros(u.shape, np.int8)
    out[(big >= 1) & (big <= 2)] = 1
    out[big == 3] = 2
    out[big > 3] = 3
    return out


def attribute(stage: list[StageFrame], run: Any, truth: Any, cells: str, reach: int,
              need: int) -> dict[str, Any]:
    """Counts of the false moving cells by path × truth class × near, the false objects."""
    codes = dict(truth.class_codes)
    class_names = {v: k for k, v in codes.items()}
    roles = {int(a["id"]): str(a.get("role", "?")) for a in truth.agents}
    by_stamp = {s.stamp_ns: s for s in stage}
    run_by_stamp = {f.stamp_ns: f for f in run.frames}
    counts: collections.Counter[tuple[str, str, str]] = collections.Counter()
    decided = correct = 0
    tracks: dict[int, dict[str, Any]] = {}
    first_moving: dict[int, dict[str, Any]] = {}
    prev_tracks: dict[int, dict[str, Any]] = {}
    reported = false_reported = 0
    aspects: collections.Counter[tuple[str, str, str]] = collections.Counter()
    recent_m: collections.deque[set[tuple[int, int]]] = collections.deque(maxlen=TRAIL_FRAMES)
    for t in truth.frames:
        mr, mc = np.nonzero(t.classes == codes["moving"])
        recent_m.append(set(zip((mr + t.window.row0).tolist(), (mc + t.window.col0).tolist(),
                                strict=True)))
        s, f = by_stamp.get(t.stamp_ns), run_by_stamp.get(t.stamp_ns)
        if s is None or f is None:
            continue
        for tid, tr in s.tracks.items():  # how each track first became moving
            if tr["moving"] and tid not in first_moving:
                before = prev_tracks.get(tid, {"evidence": (0, 0)})["evidence"]
                c, v = tr["evidence"]
                how = ("arrival" if c >= need and before[0] < need - 1 else
                       "conflict" if c >= need else "vacated" if v >= need else "?")
                first_moving[tid] = {"how": how, "evidence": (c, v), "hits": tr["hits"]}
        prev_tracks = s.tracks
        dec = np.asarray(f.decision)
        win = Window(truth.resolution_m, dec.shape[0], dec.shape[1], int(f.origin[0]),
                     int(f.origin[1]))
        ov = overlap(win, t.window)
        if ov is None:
            continue
        (rr, rc), (tr_, tc) = ov
        scored = (t.visible if cells == "visible" else t.observed)[tr_, tc]
        known = np.isin(t.classes[tr_, tc], list(codes.values()))
        ok = scored & known & (dec[rr, rc] > 0)
        is_m = t.classes == codes["moving"]
        near_m = dilate_one_cell(is_m)[tr_, tc]
        moving = (dec[rr, rc] == _MOVING) & ok
        decided += int(moving.sum())
        correct += int((moving & near_m).sum())
        false = moving & ~near_m
        # the run window's flat cells of the overlap
        flat = (np.arange(dec.size).reshape(dec.shape))[rr, rc]
        tracker = np.zeros(dec.size, bool)
        tracker[s.tracker_moving] = True
        final_objects = np.zeros(dec.size, bool)
        final_cells = moving_object_cells(f.objects, f.object_cells)
        if final_cells is not None:
            final_objects[final_cells] = True
        fusion_m = (s.fusion_decision == _MOVING).reshape(-1)
        near = _near_labels(t, roles, codes, reach)[tr_, tc]
        cls = t.classes[tr_, tc]
        shape_u = _unmapped_shapes(t, codes, reach)[tr_, tc].reshape(-1)
        status = s.track_status.reshape(-1)
        trail = set().union(*list(recent_m)[:-1]) if len(recent_m) > 1 else set()
        sx, sy = float(t.sensor_pose[0]), float(t.sensor_pose[1])
        res = truth.resolution_m
        good = (moving & near_m).reshape(-1)
        near_agent = ndimage.maximum_filter(np.where(is_m, t.agent, 0), size=3)[tr_, tc]
        for i in np.flatnonzero(good).tolist():  # the correct ones, for what a rule costs
            w = int(flat.reshape(-1)[i])
            path = ("fusion_in_object" if final_objects[w] else "fusion_no_object") \
                if fusion_m[w] else "fill" if tracker[w] else _completed(f, w)
            st = int(s.track_status.reshape(-1)[w])
            aspects[("correct " + path, "track", "none" if st < 0 else TRACK_STATUS[st])] += 1
            if st < 0:  # which agent a rule on untracked moving cells would cost
                aspects[("correct " + path, "untracked_agent_role",
                         roles.get(int(near_agent.reshape(-1)[i]), "?"))] += 1
        for i in np.flatnonzero(false.reshape(-1)).tolist():
            w = int(flat.reshape(-1)[i])
            gr, gc = divmod(w, dec.shape[1])
            gr, gc = gr + win.row0, gc + win.col0
            rng = float(np.hypot((gc + 0.5) * res - sx, (gr + 0.5) * res - sy))
            if fusion_m[w]:
                path = "fusion_in_object" if final_objects[w] else "fusion_no_object"
            elif tracker[w]:
                path = "fill"
            elif final_objects[w]:
                path = _completed(f, w)
            else:
                path = "?"
            counts[(path, class_names.get(int(cls.reshape(-1)[i]), "?"),
                    NEAR[int(near.reshape(-1)[i])])] += 1
            st = int(status[w])
            aspects[(path, "track", "none" if st < 0 else TRACK_STATUS[st])] += 1
            was_m = any((gr + dr, gc + dc) in trail for dr in (-1, 0, 1) for dc in (-1, 0, 1))
            aspects[(path, "trail", "was_M_recently" if was_m else "never_M_recently")] += 1
            aspects[(path, "range_m", next(f"<{b}" for b in RANGE_BINS if rng < b))] += 1
            aspects[(path, "unmapped_shape", UNMAPPED_SHAPES[int(shape_u[i])])] += 1
            aspects[(path, "near×range_m", NEAR[int(near.reshape(-1)[i])] + " "
                     + next(f"<{b:g}" for b in RANGE_BINS if rng < b))] += 1
        # objects: a reported moving object with no truth M cell is false
        labels = f.object_labels()
        agent_m = np.where(is_m, t.agent, 0)
        agent_run = np.zeros(dec.shape, np.int64)
        agent_run[rr, rc] = agent_m[tr_, tc]
        stopped_agent = np.zeros(dec.shape, np.int64)
        stopped_agent[rr, rc] = np.where(t.classes[tr_, tc] == codes["stopped"],
                                         t.agent[tr_, tc], 0)
        cls_run = np.zeros(dec.shape, np.int64)
        cls_run[rr, rc] = t.classes[tr_, tc]
        false_run = np.zeros(dec.shape, bool)
        false_run[rr, rc] = false
        for o in f.objects[f.objects["state"] == _MOVING_STATE]:
            reported += 1
            mine = labels == o["track_id"]
            if (agent_run[mine] > 0).any():
                continue
            false_reported += 1
            tid = int(o["track_id"])
            rec = tracks.setdefault(tid, {"frames": 0, "false_cells": 0,
                                          "classes": collections.Counter(),
                                          "stopped_roles": collections.Counter(),
                                          "speeds": [], "cells": [], "stamps": []})
            rec["frames"] += 1
            rec["false_cells"] += int((mine & false_run).sum())
            rec["stamps"].append(t.stamp_ns)
            rec["cells"].append(int(o["cell_count"]))
            rec["speeds"].append(float(np.hypot(*o["velocity_m_per_s"])))
            for c in cls_run[mine].tolist():
                rec["classes"][class_names.get(int(c), "unseen")] += 1
            for a in stopped_agent[mine & (stopped_agent > 0)].tolist():
                rec["stopped_roles"][roles.get(int(a), "?")] += 1
            rec["centroid"] = [float(v) for v in o["centroid_m"]]
    for tid, rec in tracks.items():
        rec["how"] = first_moving.get(tid, {}).get("how", "?")
        rec["first_evidence"] = first_moving.get(tid, {}).get("evidence")
        rec["classes"] = dict(rec["classes"])
        rec["stopped_roles"] = dict(rec["stopped_roles"])
        rec["what"] = _what(rec)
    return {"decided": decided, "correct": correct,
            "false_cells": {"|".join(k): v for k, v in counts.items()},
            "aspects": {"|".join(k): v for k, v in aspects.items()},
            "objects_reported": reported, "objects_false": false_reported,
            "false_tracks": tracks}


def _completed(frame: Any, cell: int) -> str:
    """The path of a moving cell of ``frame`` neither the fusion nor the frame's own fill
    decided: the backfill's step that did (``backfill_…``), else ``completion``."""
    step = (frame.added_by or {}).get(cell)
    return "completion" if step is None else "backfill_" + step


def _what(rec: dict[str, Any]) -> str:
    """One word for what a false track's cells are in the truth."""
    if rec["stopped_roles"]:
        return "stopped " + max(rec["stopped_roles"], key=rec["stopped_roles"].get)
    cl = {k: v for k, v in rec["classes"].items() if k not in ("free", "unseen")}
    if cl:
        return max(cl, key=cl.get)
    return "free"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--seeds", default="3,4,5,6")
    parser.add_argument("--profiles", default="ibeo4")
    parser.add_argument("--config", type=Path, help="a --config file for the runs")
    parser.add_argument("--set", default="", help="[objects] overrides of the replay, "
                        "'key=value;key=value' (scripts/object_replay.py)")
    parser.add_argument("--cells", default="visible", choices=("visible", "observed"))
    parser.add_argument("--near", type=int, default=2, help="cells (Chebyshev) of 'near'")
    parser.add_argument("--json", type=Path, help="write every result here")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    overrides = object_replay.parse_set(args.set)
    results = {}
    for profile in args.profiles.split(","):
        for seed in args.seeds.split(","):
            drive, out = object_replay.recorded(args.work, profile, seed, args.config)
            config = object_replay.replay_config(out, args.config, overrides)
            STAGE.clear()
            run = object_replay.replay(out, config, step=traced_step, trace_backfill=True)
            results[f"{profile}-s{seed}"] = attribute(list(STAGE), run,
                                                      load_truth(drive / "truth"), args.cells,
                                                      args.near,
                                                      int(config["objects"]["motion_evidence_frames"]))
    print_report(results)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1, default=str))


def print_report(results: dict[str, Any]) -> None:
    print("\n| run | decided moving | correct ±1 | P ±1 | false | " + " | ".join(PATHS)
          + " | false objects / reported |")
    print("|---|---|---|---|---|" + "---|" * len(PATHS) + "---|")
    pooled: collections.Counter[str] = collections.Counter()
    for name, r in results.items():
        fc = r["false_cells"]
        by_path = collections.Counter()
        for k, v in fc.items():
            by_path[k.split("|")[0]] += v
            pooled[k] += v
        p = r["correct"] / r["decided"] if r["decided"] else float("nan")
        print(f"| {name} | {r['decided']} | {r['correct']} | {p:.3f} | "
              f"{r['decided'] - r['correct']} | " + " | ".join(str(by_path[x]) for x in PATHS)
              + f" | {r['objects_false']} / {r['objects_reported']} |")
    total = sum(pooled.values())
    print(f"\nPooled false moving cells ({total}) by path × truth class × near:")
    print("| path | truth | near | cells | % |\n|---|---|---|---|---|")
    for k, v in sorted(pooled.items(), key=lambda kv: -kv[1]):
        if v < max(2, total // 200):
            continue
        path, cls, near = k.split("|")
        print(f"| {path} | {cls} | {near} | {v} | {100 * v / total:.1f} |")
    for axis, i in (("path", 0), ("truth", 1), ("near", 2)):
        c = collections.Counter()
        for k, v in pooled.items():
            c[k.split("|")[i]] += v
        print(f"\nby {axis}: " + ", ".join(f"{a} {v} ({100 * v / total:.0f} %)"
                                          for a, v in c.most_common()))
    print("\nFalse moving tracks (reported moving with no truth M cell), most false cells first:")
    print("| run | track | frames | false cells | what | how | first evidence (c, v) | "
          "speed m/s (median) | cells (median) | truth classes |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, r in results.items():
        rows = sorted(r["false_tracks"].items(), key=lambda kv: -kv[1]["false_cells"])
        for tid, t in rows:
            if t["false_cells"] < 3 and t["frames"] < 3:
                continue
            print(f"| {name} | {tid} | {t['frames']} | {t['false_cells']} | {t['what']} | "
                  f"{t['how']} | {t['first_evidence']} | {np.median(t['speeds']):.1f} | "
                  f"{np.median(t['cells']):.0f} | {t['classes']} |")
    pa: collections.Counter[str] = collections.Counter()
    for r in results.values():
        for k, v in r["aspects"].items():
            pa[k] += v
    print("\nFalse moving cells by aspect (path | aspect | value: cells):")
    for k, v in sorted(pa.items()):
        print(f"  {k}: {v}")
    what = collections.Counter()
    how = collections.Counter()
    for r in results.values():
        for t in r["false_tracks"].values():
            what[t["what"]] += t["false_cells"]
            how[t["how"]] += t["false_cells"]
    print("\nfalse tracks' false cells by what: " + ", ".join(f"{a} {v}" for a, v in
                                                              what.most_common()))
    print("... by how they became moving: " + ", ".join(f"{a} {v}" for a, v in
                                                          how.most_common()))


if __name__ == "__main__":
    main()
