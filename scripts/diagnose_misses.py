#!/usr/bin/env python3
"""Where a run's classification goes wrong on simulated drives, against the truth (the
diagnoses of docs/evaluation.md § "Since 2026-12-04, fourth session").

Reads the runs and drives of a `scripts/evaluation_study.py` work directory (the map runs):

    python scripts/diagnose_misses.py stopped  --work W --tag TAG --profile hdl64 --seeds 1,…,10
    python scripts/diagnose_misses.py objects  --work W --tag TAG --profile ibeo4 --seeds 1,…,10
    python scripts/diagnose_misses.py observed --work W --tag TAG --profile ibeo4 --seeds 1,…,5
    python scripts/diagnose_misses.py edges    --work W --tag TAG --profile hdl64 --seeds 1,…,10
    python scripts/diagnose_misses.py coast    --work W --tag TAG --profile ibeo4 --seeds 1,…,10
    python scripts/diagnose_misses.py episodes --work W --tag TAG --profile ibeo4 --seeds 1,…,10
    python scripts/diagnose_misses.py ego      --work W --profile hdl64 --seeds 1,…,26

- stopped: the visible cells decided ``stopped`` that the truth does not hold S, by distance
  to the nearest truth S cell, and those far from every S cell next to a building's cells;
  the scores of three decision rules on the same runs (façade strips static, the static
  cells of components holding ``stopped`` cells stopped, car-shaped static components
  stopped).
- objects: the agent-frames with a visible truth-M cell that no moving record holds, by
  agent role, by the agent's visible cells, and by where in the agent's episode they fall;
  and per role the agent-frames found, by the range of their nearest visible cell.
- observed: the observed truth-M cells not decided moving, by whether their agent has a
  visible cell in the frame and whether it is detected there; and the observed-cell recall
  (and F1) a method reaches at best when it reports only the agents visible in the frame.
- edges: the observed truth-M cells not decided moving of the agents detected in the frame,
  by agent role: their Chebyshev distance to the nearest cell decided moving, their
  decision, whether the scan sees them, whether a record holds them.
- coast: a forward prediction of lost moving tracks (their last cells carried at their
  velocity into cells the scan does not see, for N frames), scored on observed cells.
- episodes: the moving episodes (observed cells, as ``evperc evaluate``'s latency) and
  those missed, by the agent's role, by the range of its nearest visible cell from the
  sensor over the episode and by the most cells of it visible in one frame.
- ego: truth agents within 1 m of the lidar (inside the ego vehicle), per drive.
"""

from __future__ import annotations

import argparse
import collections
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import evaluation_study as study
import numpy as np
from scipy import ndimage

import evperc
from evperc.eval.metrics import TRUTH_CODES, _pairs, evaluate
from evperc.geo.window import Window, overlap
from evperc.output.objects import OBJECT_STATES, record_cells
from evperc.sim.truth import load_truth

#: each profile's drive length (s), as scripts/evaluation_study.py simulates it
SECONDS = {p: int(s) for p, s in study.DEFAULT_SECONDS.items()}
BLOCK = np.ones((3, 3), bool)


def frames(work: Path, tag: str, profile: str, seed: int) -> Iterator[tuple[Any, ...]]:
    """(run frame, truth frame, run slices, truth slices, decision codes, roles) of a drive."""
    name = f"{profile}-s{seed}-{SECONDS[profile]}s"
    run = evperc.load(work / "runs" / tag / f"{name}-map")
    truth = load_truth(work / "drives" / name / "truth")
    roles = {a["id"]: a["role"] for a in truth.agents}
    codes = dict(run.decision_codes)
    for f, t in _pairs(run.frames, truth.frames):
        dec = np.asarray(f.decision)
        ov = overlap(Window(truth.resolution_m, *dec.shape, int(f.origin[0]),
                            int(f.origin[1])), t.window)
        if ov is not None:
            yield f, t, ov[0], ov[1], codes, roles


def stopped(args: argparse.Namespace) -> None:
    n = collections.Counter()
    theta = np.arange(16) * np.pi / 16
    for seed in args.seeds:
        for f, t, (rr, rc), (tr, tc), codes, _ in frames(args.work, args.tag, args.profile, seed):
            d, cls = np.asarray(f.decision)[rr, rc], t.classes[tr, tc]
            vis = np.asarray(t.visible[tr, tc], bool)
            truth_s, decided_s = cls == TRUTH_CODES["stopped"], d == codes["stopped"]
            n["truth S"] += int((truth_s & vis).sum())
            n["decided S"] += int((decided_s & vis).sum())
            n["right S"] += int((truth_s & decided_s & vis).sum())
            wrong = decided_s & vis & ~truth_s
            to_s = ndimage.distance_transform_edt(~truth_s)
            n["wrong S"] += int(wrong.sum())
            n["wrong S next to a truth S cell"] += int((wrong & (to_s < 1.5)).sum())
            far = wrong & (to_s > 4.1)
            building = ndimage.binary_dilation(cls == TRUTH_CODES["infrastructure"], BLOCK)
            n["wrong S > 4 cells from S"] += int(far.sum())
            n["... of which next to a building"] += int((far & building).sum())
            occupied = np.isin(d, [codes["static"], codes["stopped"], codes["unmapped"]])
            comp, k = ndimage.label(occupied, BLOCK)
            width, length = np.zeros(k + 1), np.zeros(k + 1)
            for i, box in enumerate(ndimage.find_objects(comp), 1):
                r, c = np.nonzero(comp[box] == i)
                extent = np.ptp(np.outer(c, np.cos(theta)) + np.outer(r, np.sin(theta)), axis=0)
                along = (int(np.argmin(extent)) + 8) % 16
                length[i] = (extent[along] + 1.0) * t.window.resolution_m
                width[i] = len(r) / (extent[along] + 1.0) * t.window.resolution_m
            at_building = np.zeros(k + 1, bool)
            at_building[np.unique(comp[building & occupied])] = True
            holds_s = np.zeros(k + 1, bool)
            holds_s[np.unique(comp[decided_s])] = True
            at_building[0] = holds_s[0] = False
            rules = {"facade strips static": (decided_s, at_building[comp] & (width[comp] <= 0.55)),
                     "static of components with stopped cells stopped":
                         (d == codes["static"], holds_s[comp]),
                     "car-shaped static components stopped":
                         (d == codes["static"], ~at_building[comp] & (width[comp] >= 1.0)
                          & (length[comp] >= 2.5) & (length[comp] <= 7.0))}
            for name, (cells, rule) in rules.items():
                changed = cells & rule & vis
                n[f"{name}: S"] += int((changed & truth_s).sum())
                n[f"{name}: not S"] += int((changed & ~truth_s).sum())
    for key, value in n.items():
        print(f"{key}: {value}")

    def f1(right: int, decided: int) -> str:
        return f"P {right / decided:.3f} R {right / n['truth S']:.3f} F1 " \
               f"{2 * right / (decided + n['truth S']):.3f}"
    print("decisions:", f1(n["right S"], n["decided S"]))
    s, o = n["facade strips static: S"], n["facade strips static: not S"]
    print("facade strips static:", f1(n["right S"] - s, n["decided S"] - s - o))
    for name in ("static of components with stopped cells stopped",
                 "car-shaped static components stopped"):
        s, o = n[f"{name}: S"], n[f"{name}: not S"]
        print(f"{name}:", f1(n["right S"] + s, n["decided S"] + s + o))


RANGES_M = (20.0, 40.0)


def _ring(range_m: float) -> str:
    """The range bucket of :data:`RANGES_M` a distance (m) falls in."""
    return ("< 20 m" if range_m < RANGES_M[0] else "20-40 m" if range_m < RANGES_M[1]
            else ">= 40 m")


def _nearest_m(seen: np.ndarray, xs: np.ndarray, ys: np.ndarray, sensor: Any) -> float:
    """Range (m) from the sensor's x, y to the nearest cell of ``seen`` (bool rows × cols
    whose cell centres are ``ys`` × ``xs``); inf if it holds none."""
    rows, cols = np.nonzero(seen)
    if rows.size == 0:
        return float("inf")
    return float(np.hypot(xs[cols] - sensor[0], ys[rows] - sensor[1]).min())


def objects(args: argparse.Namespace) -> None:
    n = collections.Counter()
    for seed in args.seeds:
        rows = []  # (frame, agent, role, found, visible cells)
        for k, (f, t, (rr, rc), (tr, tc), _, roles) in enumerate(
                frames(args.work, args.tag, args.profile, seed)):
            agent = np.where(t.classes[tr, tc] == TRUTH_CODES["moving"], t.agent[tr, tc], 0)
            vis = np.asarray(t.visible[tr, tc], bool)
            recs = f.objects
            moving = np.isin(f.object_labels()[rr, rc],
                             recs["track_id"][recs["state"] == OBJECT_STATES["moving"]])
            x, y = t.window.cell_centres()
            for a in np.unique(agent[vis & (agent > 0)]):
                cells = agent == a
                role, found = roles.get(int(a), "?"), bool((cells & moving).any())
                rows.append((k, int(a), role, found, int((cells & vis).sum())))
                near_m = _nearest_m(cells & vis, x[tc], y[tr], t.sensor_pose)
                n[f"{role}: found by range {_ring(near_m)}"] += found
                n[f"{role}: agent-frames by range {_ring(near_m)}"] += 1
        found_at = collections.defaultdict(list)
        for k, a, _, found, _ in rows:
            if found:
                found_at[a].append(k)
        for k, a, role, found, visible in rows:
            n[f"{role}: agent-frames"] += 1
            if found:
                continue
            n[f"{role}: missed"] += 1
            n["missed with one visible cell" if visible == 1 else "missed, more cells"] += 1
            ks = found_at[a]
            n["never found" if not ks else "before its first detection" if k < min(ks)
              else "after its last" if k > max(ks) else "between detections"] += 1
    for key, value in sorted(n.items()):
        print(f"{key}: {value}")


def _observed_moving(f: Any, t: Any, run_cells: tuple[slice, slice],
                     truth_cells: tuple[slice, slice], codes: dict[str, int]
                     ) -> tuple[np.ndarray, ...]:
    """Of one frame, on the cells both windows cover: the run's decision, the observed
    truth-M cells, the truth's agent ids, the cells visible in the frame, the cells decided
    moving, and per agent id whether an observed M cell of it is visible (``seen``) and
    whether one is decided moving (``detected``)."""
    (rr, rc), (tr, tc) = run_cells, truth_cells
    d = np.asarray(f.decision)[rr, rc]
    moving = (t.classes[tr, tc] == TRUTH_CODES["moving"]) & t.observed[tr, tc]
    agent, vis = t.agent[tr, tc], np.asarray(t.visible[tr, tc], bool)
    decided = d == codes["moving"]
    size = int(agent.max(initial=0)) + 1
    seen = np.bincount(agent[moving & vis], minlength=size) > 0
    detected = np.bincount(agent[moving & decided], minlength=size) > 0
    return d, moving, agent, vis, decided, seen, detected


def observed(args: argparse.Namespace) -> None:
    n = collections.Counter()
    for seed in args.seeds:
        for f, t, run_cells, truth_cells, codes, _ in frames(args.work, args.tag,
                                                             args.profile, seed):
            _, moving, agent, _, decided, seen, detected = _observed_moving(
                f, t, run_cells, truth_cells, codes)
            missed = moving & ~decided
            n["observed truth M"] += int(moving.sum())
            n["... of agents invisible in the frame"] += int((moving & ~seen[agent]).sum())
            n["decided moving"] += int((moving & decided).sum())
            n["missed, agent invisible in the frame"] += int((missed & ~seen[agent]).sum())
            n["missed, agent visible and detected"] += int((missed & seen[agent]
                                                           & detected[agent]).sum())
            n["missed, agent visible, not detected"] += int((missed & seen[agent]
                                                            & ~detected[agent]).sum())
    for key, value in n.items():
        print(f"{key}: {value}")
    # what a method that reports only the agents it sees in the frame can reach at best
    bound = 1.0 - n["... of agents invisible in the frame"] / max(n["observed truth M"], 1)
    print(f"recall bound (agents visible in the frame): {bound:.3f}; F1 bound at precision 1: "
          f"{2 * bound / (1 + bound):.3f}")


def edges(args: argparse.Namespace) -> None:
    n: collections.Counter = collections.Counter()
    for seed in args.seeds:
        for f, t, run_cells, truth_cells, codes, roles in frames(args.work, args.tag,
                                                                 args.profile, seed):
            names = {v: k for k, v in codes.items()}
            d, moving, agent, vis, decided, seen, detected = _observed_moving(
                f, t, run_cells, truth_cells, codes)
            missed = moving & ~decided & seen[agent] & detected[agent]
            if not missed.any():
                continue
            reach = ndimage.distance_transform_cdt(~decided, metric="chessboard")
            held = f.object_labels()[run_cells] > 0
            for r, c in zip(*np.nonzero(missed), strict=True):
                role = roles.get(int(agent[r, c]), "?")
                dist = int(reach[r, c])
                n[f"{role}: cells"] += 1
                n[f"{role}: distance {dist if dist < 3 else '3+'}"] += 1
                n[f"{role}: decided {names[int(d[r, c])]}"] += 1
                n[f"{role}: {'visible' if vis[r, c] else 'not visible'} this scan"] += 1
                n[f"{role}: in a record" if held[r, c] else f"{role}: in no record"] += 1
    for key, value in sorted(n.items()):
        print(f"{key}: {value}")


def coast(args: argparse.Namespace) -> None:
    horizons = [0, 2, 5, 8]
    scores = {h: np.zeros(3, np.int64) for h in horizons}  # right, decided, truth
    for seed in args.seeds:
        last: dict[int, tuple] = {}  # track -> (frame, stamp, lattice rows, cols, vx, vy)
        for k, (f, t, (rr, rc), (tr, tc), codes, _) in enumerate(
                frames(args.work, args.tag, args.profile, seed)):
            dec = np.asarray(f.decision)
            rows, cols = dec.shape
            row0, col0 = int(f.origin[0]), int(f.origin[1])
            recs = f.objects
            present = set(recs["track_id"].tolist())
            for rec, own in zip(recs, record_cells(recs, f.object_cells), strict=True):
                if rec["state"] == OBJECT_STATES["moving"]:
                    last[int(rec["track_id"])] = (k, f.stamp_ns, own // cols + row0,
                                                  own % cols + col0, *rec["velocity_m_per_s"])
            obs = np.asarray(t.observed[tr, tc], bool)
            truth = t.classes[tr, tc] == TRUTH_CODES["moving"]
            unseen = ~np.asarray(t.visible[tr, tc], bool) & np.isin(
                dec[rr, rc], [codes["unknown"], codes["free"], codes["moving"]])
            res = t.window.resolution_m
            for h in horizons:
                pred = dec[rr, rc] == codes["moving"]
                for track, (k0, stamp, r0, c0, vx, vy) in last.items():
                    if track in present or not 0 < k - k0 <= h:
                        continue
                    dt = (f.stamp_ns - stamp) * 1e-9
                    r = r0 + int(round(vy * dt / res)) - row0 - rr.start
                    c = c0 + int(round(vx * dt / res)) - col0 - rc.start
                    ok = (r >= 0) & (r < pred.shape[0]) & (c >= 0) & (c < pred.shape[1])
                    r, c = r[ok], c[ok]
                    take = unseen[r, c]
                    pred[r[take], c[take]] = True
                scores[h] += [(pred & truth & obs).sum(), (pred & obs).sum(), (truth & obs).sum()]
    for h, (right, decided, truth) in scores.items():
        print(f"coast {h} frames: observed moving P {right / decided:.3f} R {right / truth:.3f} "
              f"F1 {2 * right / (decided + truth):.3f}")


def episodes(args: argparse.Namespace) -> None:
    n: collections.Counter = collections.Counter()
    for seed in args.seeds:
        name = f"{args.profile}-s{seed}-{SECONDS[args.profile]}s"
        run = evperc.load(args.work / "runs" / args.tag / f"{name}-map")
        truth = load_truth(args.work / "drives" / name / "truth")
        roles = {a["id"]: a["role"] for a in truth.agents}
        pairs = list(_pairs(run.frames, truth.frames))
        for e in evaluate(run, truth, cells="observed")["latency_frames"]["per_episode"]:
            near_m, cells = np.inf, 0  # nearest visible cell (m), most visible cells a frame
            for _, t in pairs[e["onset_frame"]:e["end_frame"]]:
                seen = (t.agent == e["agent"]) & (t.classes == TRUTH_CODES["moving"]) & t.visible
                if seen.any():
                    near_m = min(near_m, _nearest_m(seen, *t.window.cell_centres(),
                                                    t.sensor_pose))
                    cells = max(cells, int(seen.sum()))
            ring = _ring(near_m)
            size = "1 cell" if cells <= 1 else "2-3 cells" if cells <= 3 else ">= 4 cells"
            missed = e["latency_frames"] is None
            for key in (f"role {roles.get(e['agent'], '?')}", f"nearest {ring}",
                        f"most visible {size}"):
                n[key, missed] += 1
    for key in sorted({k for k, _ in n}):
        total = n[key, True] + n[key, False]
        print(f"{key}: {n[key, True]} missed of {total} episodes")


def ego(args: argparse.Namespace) -> None:
    for seed in args.seeds:
        name = f"{args.profile}-s{seed}-{SECONDS[args.profile]}s"
        truth = load_truth(args.work / "drives" / name / "truth")
        frames_near, visible = collections.Counter(), collections.Counter()
        for t in truth.frames:
            rows, cols = t.classes.shape
            reach = int(np.ceil(1.0 / truth.resolution_m))
            near = t.agent[rows // 2 - reach:rows // 2 + reach + 1,
                           cols // 2 - reach:cols // 2 + reach + 1]
            for a in np.unique(near[near > 0]):
                frames_near[int(a)] += 1
                visible[int(a)] += int(((t.agent == a) & t.visible
                                        & (t.classes == TRUTH_CODES["moving"])).sum())
        if frames_near:
            print(name, {a: (frames_near[a], visible[a]) for a in frames_near},
                  "(agent: frames within 1 m of the lidar, visible truth-M cells then)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("what", choices=["stopped", "objects", "observed", "edges", "coast",
                                         "episodes", "ego"])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--tag", default="", help="the runs' config tag (WORK/runs/TAG)")
    parser.add_argument("--profile", choices=sorted(SECONDS), required=True)
    parser.add_argument("--seeds", type=lambda s: [int(x) for x in s.split(",")], required=True)
    args = parser.parse_args()
    {"stopped": stopped, "objects": objects, "observed": observed, "edges": edges,
     "coast": coast, "episodes": episodes, "ego": ego}[args.what](args)


if __name__ == "__main__":
    main()
