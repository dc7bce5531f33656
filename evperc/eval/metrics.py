"""Scores of an evperc run against simulated ground truth (docs/truth-format.md).

Matching: a run frame and a truth frame are paired when their ``stamp_ns`` are equal; cells
are compared where both windows cover the same global lattice cells, and only where the
truth is ``observed`` (some ray crossed or ended in the cell at this or an earlier scan).
A truth of another drive is refused (:class:`~evperc.errors.TruthError`): another CRS or
cell size (another lattice), no frame at a common stamp, or a paired frame whose run
sensor position is more than :data:`POSE_TOLERANCE_M` from the truth's.

Decisions map to classes free→F, infrastructure→I, unmapped→U, stopped→S, moving→M.
``static`` (undecided among I, U, S) and ``unknown`` predict no fine class: they are misses
for recall and do not count for precision; the confusion matrix shows them. Coarse scores
use free / static = {I, U, S} / moving, where every static decision (``static``,
``infrastructure``, ``unmapped``, ``stopped``) is static.

For class c over the evaluated cells: precision = TP / #(decided c), recall = TP / #(truth c),
F1 = 2PR / (P + R), support = #(truth c); undefined ratios are ``None``.

Moving cells within one cell (``moving_within_one_cell``): the truth's class raster puts a
cell in an object's footprint when its centre lies in it (strict, the scores above); a return
from a car's surface often falls in a cell whose centre is just outside the footprint, or the
footprint's edge crosses the cell. So the moving class is also scored with a tolerance of one
cell (8-neighbourhood, centres at most 0.71 m apart at 0.5 m cells): a cell decided ``moving``
is correct if it or one of its 8 neighbours is truth M (the neighbour need not be evaluated
itself); a truth M cell is found if it or one of its 8 neighbours is decided ``moving``.
Precision = correct / decided moving, recall = found / truth M, over the evaluated cells.
The stopped class is scored the same way (``stopped_within_one_cell``): a parked car's
returns fall as often just outside its footprint as a moving car's.

Detection latency, per moving episode of a simulated agent: an episode is a maximal run of
consecutive matched frames in which the agent has at least one evaluated cell of truth
class M. Its onset is the first frame of the episode in which a ray of that frame hits or
crosses one of the agent's cells (``visible``); it is detected at the first frame from the
onset on in which at least one of its M cells is decided ``moving``. Latency = detection −
onset in frames (0 = detected in the first scan that sees it). Episodes never visible are
not counted; visible ones never detected are ``missed``. Each episode's ``visible_frames``
counts its frames from the onset with a visible cell of the agent, and ``by_visible_frames``
splits the episodes and the missed ones by it (1–4, 5–9, 10 and more frames): a tracker that
confirms an object over three frames cannot report one glimpsed in fewer. Within one cell
(``latency_frames_within_one_cell``): detected at the first frame in which one of its M
cells is decided ``moving`` or has a neighbour (8-neighbourhood) that is — the one-cell
tolerance of the cell scores: a walking person is one cell, and its returns as often fall in
the cell beside its footprint.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np

from evperc.errors import TruthError, UsageError
from evperc.geo.window import Window, overlap
from evperc.output.objects import OBJECT_STATES

FINE = ("free", "infrastructure", "unmapped", "stopped", "moving")
COARSE = ("free", "static", "moving")
#: the classes also scored within one cell (8-neighbourhood)
TOLERANT_CLASSES = ("moving", "stopped")
TRUTH_CODES = {"free": 1, "moving": 2, "stopped": 4, "infrastructure": 5, "unmapped": 6}
_COARSE_OF_FINE = {"free": "free", "infrastructure": "static", "unmapped": "static",
                   "stopped": "static", "moving": "moving"}
_COARSE_OF_DECISION = {"free": "free", "moving": "moving", "static": "static",
                       "stopped": "static", "infrastructure": "static", "unmapped": "static"}


def _pairs(run_frames: Iterable[Any], truth_frames: Iterable[Any]) -> Iterator[tuple[Any, Any]]:
    """Frames with equal stamps (both sequences in increasing stamp order)."""
    truth_it = iter(truth_frames)
    t = next(truth_it, None)
    for f in run_frames:
        while t is not None and t.stamp_ns < f.stamp_ns:
            t = next(truth_it, None)
        if t is not None and t.stamp_ns == f.stamp_ns:
            yield f, t


def _scores(tp: np.ndarray, predicted: np.ndarray, support: np.ndarray, names: tuple[str, ...]
            ) -> dict[str, dict[str, float | int | None]]:
    out = {}
    for i, name in enumerate(names):
        p = float(tp[i] / predicted[i]) if predicted[i] else None
        r = float(tp[i] / support[i]) if support[i] else None
        f1 = 2 * p * r / (p + r) if p is not None and r is not None and p + r > 0 else None
        out[name] = {"precision": p, "recall": r, "f1": f1, "support": int(support[i])}
    return out


CELL_SETS = ("observed", "visible")

#: largest distance between a run frame's sensor position and the truth's at the same stamp
#: for the truth to count as of the run's drive: 4 cells of 0.5 m. The run places the log in
#: the CRS from its GNSS fixes (the sample drive: RMS residual 0.00 m, every frame within
#: 1 cm of the truth); another drive at the same stamps is metres to kilometres away.
POSE_TOLERANCE_M = 2.0


def evaluate(run: Any, truth: Any, cells: str = "observed") -> dict[str, Any]:
    """Metrics of ``run`` (``.frames`` with ``stamp_ns, origin, decision``, and
    ``.decision_codes``) against ``truth`` (:func:`evperc.sim.truth.load_truth`).

    ``cells``: ``"observed"`` scores every cell some ray reached at this or an earlier frame
    (what the grid is meant to remember); ``"visible"`` only the cells a ray reaches in the
    frame itself (what the sensor sees now: no penalty for forgetting)."""
    if cells not in CELL_SETS:
        raise UsageError(f"cells {cells!r}: choose one of {', '.join(CELL_SETS)}")
    codes: dict[str, int] = dict(run.decision_codes)
    decisions = sorted(codes, key=codes.get)
    d_lut = np.full(256, -1, dtype=np.int64)
    d_lut[[codes[n] for n in decisions]] = np.arange(len(decisions))
    t_lut = np.full(256, -1, dtype=np.int64)
    tcodes = dict(getattr(truth, "class_codes", TRUTH_CODES))
    t_lut[[tcodes[n] for n in FINE]] = np.arange(len(FINE))
    res = truth.resolution_m
    run_res = getattr(run, "resolution_m", res)
    if abs(run_res - res) > 1e-9:
        raise TruthError(f"run cell size {run_res} m differs from the truth's {res} m; "
                         "simulate with the run's --config")
    run_crs = getattr(run, "crs", None)
    truth_crs = getattr(truth, "manifest", {}).get("crs")
    if run_crs is not None and truth_crs is not None and run_crs != truth_crs:
        raise TruthError(f"{_where(truth)}: truth is in {truth_crs}, the run in {run_crs}: "
                         "not the same drive's lattice; give the truth of the run's drive")
    n_agents = len(getattr(truth, "agents", [])) or 0
    moving_code = codes.get("moving", -1)
    confusion = np.zeros((len(FINE), len(decisions)), dtype=np.int64)
    #: per class scored within one cell: correct, decided, found, truth
    tolerant = {name: np.zeros(4, dtype=np.int64) for name in TOLERANT_CLASSES}
    objects = ObjectScore()
    rows: list[tuple[np.ndarray, ...]] = []
    stamps, matched, run_frames = [], 0, 0

    def counted(frames: Iterable[Any]) -> Iterator[Any]:
        nonlocal run_frames
        for f in frames:
            run_frames += 1
            yield f

    for f, t in _pairs(counted(run.frames), truth.frames):
        matched += 1
        stamps.append(t.stamp_ns)
        _check_pose(run, truth, f, t)
        dec = np.asarray(f.decision)
        win = Window(res, dec.shape[0], dec.shape[1], int(f.origin[0]), int(f.origin[1]))
        ov = overlap(win, t.window)
        if ov is None:
            rows.append(tuple(np.zeros(n_agents + 1, dtype=bool) for _ in range(4)))
            continue
        (rr, rc), (tr, tc) = ov
        d = d_lut[dec[rr, rc]]
        tc_ = t_lut[t.classes[tr, tc]]
        scored = t.observed if cells == "observed" else t.visible
        ok = np.asarray(scored[tr, tc], dtype=bool) & (tc_ >= 0) & (d >= 0)
        confusion += np.bincount(tc_[ok] * len(decisions) + d[ok],
                                 minlength=confusion.size).reshape(confusion.shape)
        for name, counts in tolerant.items():
            counts += _tolerant_counts(dec == codes.get(name, -1), t.classes == tcodes[name],
                                       ok, (rr, rc), (tr, tc))
        agent = np.where(ok, t.agent[tr, tc], 0)
        n = max(n_agents, int(agent.max(initial=0))) + 1
        if n > n_agents + 1:
            n_agents = n - 1
            rows = [tuple(np.pad(a, (0, n - len(a))) for a in r) for r in rows]
        is_m = agent > 0
        is_m &= t.classes[tr, tc] == tcodes["moving"]
        moving_now = np.bincount(agent[is_m], minlength=n) > 0
        visible_now = np.bincount(agent[is_m & t.visible[tr, tc]], minlength=n) > 0
        decided_m = dec == moving_code
        detected = np.bincount(agent[is_m & decided_m[rr, rc]], minlength=n) > 0
        near = np.bincount(agent[is_m & dilate_one_cell(decided_m)[rr, rc]], minlength=n) > 0
        rows.append((moving_now, visible_now, detected, near))
        objects.add(f, t, (rr, rc), (tr, tc), tcodes["moving"])

    if run_frames and not matched:
        raise TruthError(f"{_where(truth)}: no truth frame at the stamp of any of the run's "
                         f"{run_frames} frames: not the run's drive; give the truth of the "
                         "drive the run was made from")
    metrics = _summarise(confusion, decisions)
    for name, counts in tolerant.items():
        metrics[f"{name}_within_one_cell"] = _tolerant_scores(counts)
    metrics["objects"] = objects.summary()
    metrics["cell_set"] = cells
    metrics["frames_span_ns"] = [stamps[0], stamps[-1]] if stamps else None
    metrics["frames_matched"] = matched
    metrics["frames_unmatched"] = run_frames - matched
    metrics["latency_frames"] = _latency(rows, np.array(stamps, dtype=np.int64))
    metrics["latency_frames_within_one_cell"] = _latency(
        [r[:2] + r[3:] for r in rows], np.array(stamps, dtype=np.int64))
    return metrics


def dilate_one_cell(mask: np.ndarray) -> np.ndarray:
    """``mask`` OR-ed with its 8 neighbours (cells beyond the edge are False)."""
    rows, cols = mask.shape
    padded = np.zeros((rows + 2, cols + 2), dtype=bool)
    padded[1:-1, 1:-1] = mask
    out = np.zeros_like(mask, dtype=bool)
    for dr in range(3):
        for dc in range(3):
            out |= padded[dr:dr + rows, dc:dc + cols]
    return out


def _tolerant_counts(decided: np.ndarray, truth: np.ndarray, ok: np.ndarray,
                     run_cells: tuple[Any, Any], truth_cells: tuple[Any, Any]) -> np.ndarray:
    """(correct, decided, found, truth) of one class within one cell, over the evaluated
    cells ``ok`` of the overlap (``run_cells`` / ``truth_cells`` index it in each grid)."""
    near_truth = dilate_one_cell(truth)[truth_cells]
    near_decided = dilate_one_cell(decided)[run_cells]
    d, t = decided[run_cells] & ok, truth[truth_cells] & ok
    return np.array([(d & near_truth).sum(), d.sum(), (t & near_decided).sum(), t.sum()],
                    dtype=np.int64)


def _tolerant_scores(counts: np.ndarray) -> dict[str, Any]:
    correct, decided, found, truth = (int(v) for v in counts)
    p = correct / decided if decided else None
    r = found / truth if truth else None
    f1 = 2 * p * r / (p + r) if p is not None and r is not None and p + r > 0 else None
    return {"precision": p, "recall": r, "f1": f1, "decided": decided, "correct": correct,
            "support": truth, "found": found, "tolerance_cells": 1}


def _where(truth: Any) -> str:
    return str(getattr(truth, "dir", "truth"))


def _check_pose(run: Any, truth: Any, f: Any, t: Any) -> None:
    """Refuse a truth frame whose sensor is elsewhere than the run's at the same stamp."""
    pose, truth_pose = getattr(f, "pose", None), getattr(t, "sensor_pose", None)
    if pose is None or truth_pose is None:
        return
    distance = float(np.hypot(pose[0] - truth_pose[0], pose[1] - truth_pose[1]))
    if not distance <= POSE_TOLERANCE_M:
        raise TruthError(
            f"{_where(truth)}: at stamp {t.stamp_ns} the truth's sensor is {distance:.1f} m "
            f"from the run's (more than {POSE_TOLERANCE_M} m): not the run's drive; give the "
            "truth of the drive the run was made from")
class ObjectScore:
    """Object-level scores of a run's object list (``frame.objects``) against the truth's
    agents, over the matched frames (docs/evaluation.md).

    Per frame, the true moving objects are the agents with a cell of class M that is
    ``visible`` in this frame (in the part both windows cover); a reported ``moving`` object
    matches the moving agent that holds most of its cells (class M cells of the truth), if
    any. Precision = matched moving objects / moving objects reported; recall = true moving
    objects matched by some reported one / true moving objects. A track switch: an agent
    matched in a frame by a track other than the one that matched it last (two tracks on one
    agent in a frame count a switch each, in record order). An identity switch (CLEAR MOT's
    IDSW: Bernardin and Stiefelhagen 2008): each agent keeps one track, the one it kept
    before if that track matches it in this frame, else the first that does; a change of the
    kept track is one switch. A duplicate: an agent-frame matched by more than one reported
    moving object (MOT's one-to-one matching would count the extra ones as false). Frames of
    a run without an object list (``frame.objects is None``) are not scored.

    Within one cell (``within_one_cell`` of the summary): the same with each reported
    object's cells widened by their 8 neighbours before the vote — it matches the moving
    agent holding most of the class M cells in or next to its cells (the cell scores' one-cell
    tolerance: a one-cell person's returns often lie in the cell beside its footprint)."""

    def __init__(self) -> None:
        self.frames = 0
        self.reported = 0
        self.matched = 0
        self.truth = 0
        self.found = 0
        self.switches = 0
        self.last_track: dict[int, int] = {}
        self.identity_switches = 0
        self.kept_track: dict[int, int] = {}
        self.duplicates = 0
        self.matched_near = 0  # within one cell
        self.found_near = 0

    def add(self, f: Any, t: Any, run_cells: tuple[slice, slice],
            truth_cells: tuple[slice, slice], moving_code: int) -> None:
        objects = getattr(f, "objects", None)
        if objects is None:
            return
        self.frames += 1
        (rr, rc), (tr, tc) = run_cells, truth_cells
        agent = np.where(t.classes[tr, tc] == moving_code, t.agent[tr, tc], 0)
        visible_agents = set(np.unique(agent[t.visible[tr, tc] & (agent > 0)]).tolist())
        self.truth += len(visible_agents)
        labels = f.object_labels()[rr, rc]
        moving = objects[objects["state"] == OBJECT_STATES["moving"]]
        self.reported += len(moving)
        found: set[int] = set()
        found_near: set[int] = set()
        tracks_on: dict[int, list[int]] = {}  # agent: the tracks matching it, in record order
        for o in moving:
            own = labels == o["track_id"]
            near = _near_agent(own, agent)
            if near is not None:
                self.matched_near += 1
                found_near.add(near)
            hits = agent[own & (agent > 0)]
            if hits.size == 0:
                continue
            best = int(np.bincount(hits).argmax())
            self.matched += 1
            found.add(best)
            previous = self.last_track.get(best)
            if previous is not None and previous != int(o["track_id"]):
                self.switches += 1
            self.last_track[best] = int(o["track_id"])
            tracks_on.setdefault(best, []).append(int(o["track_id"]))
        for best, tracks in tracks_on.items():
            self.duplicates += len(tracks) > 1
            kept = self.kept_track.get(best)
            if kept is None or kept not in tracks:
                self.identity_switches += kept is not None
                self.kept_track[best] = tracks[0]
        self.found += len(found & visible_agents)
        self.found_near += len(found_near & visible_agents)

    def summary(self) -> dict[str, Any] | None:
        if self.frames == 0:
            return None
        return {"frames": self.frames, "moving_reported": self.reported,
                "moving_matched": self.matched, "moving_truth": self.truth,
                "moving_found": self.found,
                "precision": self.matched / self.reported if self.reported else None,
                "recall": self.found / self.truth if self.truth else None,
                "track_switches": self.switches,
                "identity_switches": self.identity_switches,
                "duplicate_matches": self.duplicates,
                "within_one_cell": {
                    "moving_matched": self.matched_near, "moving_found": self.found_near,
                    "precision": self.matched_near / self.reported if self.reported else None,
                    "recall": self.found_near / self.truth if self.truth else None}}


def _near_agent(own: np.ndarray, agent: np.ndarray) -> int | None:
    """The agent holding most of the cells of ``agent`` (ids, 0 = none) in or next to the
    cells of ``own`` (bool, the same shape); None if there is none."""
    rows, cols = np.nonzero(own)
    if rows.size == 0:
        return None
    r0, c0 = max(int(rows.min()) - 1, 0), max(int(cols.min()) - 1, 0)
    r1, c1 = int(rows.max()) + 2, int(cols.max()) + 2
    block = agent[r0:r1, c0:c1]
    hits = block[dilate_one_cell(own[r0:r1, c0:c1]) & (block > 0)]
    return int(np.bincount(hits).argmax()) if hits.size else None


def _summarise(confusion: np.ndarray, decisions: list[str]) -> dict[str, Any]:
    col = {n: i for i, n in enumerate(decisions)}
    fine_pred = np.array([confusion[:, col[n]].sum() if n in col else 0 for n in FINE])
    fine_tp = np.array([confusion[i, col[n]] if n in col else 0 for i, n in enumerate(FINE)])
    support = confusion.sum(axis=1)
    coarse_conf = np.zeros((3, 3), dtype=np.int64)
    for i, tname in enumerate(FINE):
        for j, dname in enumerate(decisions):
            if dname in _COARSE_OF_DECISION:
                coarse_conf[COARSE.index(_COARSE_OF_FINE[tname]),
                            COARSE.index(_COARSE_OF_DECISION[dname])] += confusion[i, j]
    coarse_support = np.array([support[[_COARSE_OF_FINE[n] == c for n in FINE]].sum()
                               for c in COARSE])
    total = int(confusion.sum())
    sm = {t: {d: int(confusion[FINE.index(t), col[d]]) for d in decisions}
          for t in ("stopped", "moving")}
    return {
        "cells": total,
        "accuracy": float(fine_tp.sum() / total) if total else None,
        "per_class": _scores(fine_tp, fine_pred, support, FINE),
        "coarse": _scores(np.diag(coarse_conf), coarse_conf.sum(axis=0), coarse_support,
                          COARSE),
        "coarse_accuracy": float(np.trace(coarse_conf) / total) if total else None,
        "confusion": {"truth": list(FINE), "decision": decisions,
                      "counts": confusion.tolist()},
        "stopped_vs_moving": sm,
    }


def _latency(rows: list[tuple[np.ndarray, ...]], stamps: np.ndarray) -> dict[str, Any]:
    episodes: list[dict[str, Any]] = []
    if rows:
        moving, visible, detected = (np.stack([r[k] for r in rows]) for k in range(3))
        for agent in range(1, moving.shape[1]):  # one pass per simulated agent
            m = moving[:, agent].astype(np.int8)
            edges = np.diff(np.concatenate([[0], m, [0]]))
            for start, end in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1),
                                  strict=True):
                seen = np.flatnonzero(visible[start:end, agent])
                if len(seen) == 0:
                    continue
                onset = start + int(seen[0])
                hit = np.flatnonzero(detected[onset:end, agent])
                ep = {"agent": agent, "onset_frame": int(onset), "end_frame": int(end),
                      "visible_frames": len(seen),
                      "latency_frames": int(hit[0]) if len(hit) else None,
                      "latency_s": (float(stamps[onset + hit[0]] - stamps[onset]) / 1e9
                                    if len(hit) else None)}
                episodes.append(ep)
    lat = np.array([e["latency_frames"] for e in episodes if e["latency_frames"] is not None])
    return {"episodes": len(episodes), "detected": int(len(lat)),
            "missed": len(episodes) - int(len(lat)),
            "mean": float(lat.mean()) if len(lat) else None,
            "median": float(np.median(lat)) if len(lat) else None,
            "max": int(lat.max()) if len(lat) else None,
            "by_visible_frames": _by_visible_frames(episodes),
            "per_episode": episodes}


#: the ``by_visible_frames`` buckets of the episodes, by key: the least and most frames with
#: a visible cell of the agent (1-4: under half a second at 10 Hz, shorter than the
#: tracker's confirmation and evidence; 10 and more: a second and more)
VISIBLE_FRAME_BUCKETS = {"1-4": (1, 4), "5-9": (5, 9), "10+": (10, None)}


def _by_visible_frames(episodes: list[dict[str, Any]]) -> dict[str, dict[str, int]]:
    """Episodes and missed episodes per :data:`VISIBLE_FRAME_BUCKETS` bucket of their
    ``visible_frames``."""
    out = {}
    for key, (low, high) in VISIBLE_FRAME_BUCKETS.items():
        eps = [e for e in episodes
               if e["visible_frames"] >= low and (high is None or e["visible_frames"] <= high)]
        out[key] = {"episodes": len(eps),
                    "missed": sum(e["latency_frames"] is None for e in eps)}
    return out


def format_report(metrics: dict[str, Any], other: dict[str, Any] | None = None,
                  names: tuple[str, str] = ("run", "compare")) -> str:
    """A plain-text table of ``metrics`` (and ``other`` side by side)."""
    runs = [(names[0], metrics)] + ([(names[1], other)] if other is not None else [])

    def num(v: float | None) -> str:
        return "   -  " if v is None else f"{v:6.3f}"

    head = f"{'class':<15}{'support':>9}" + "".join(
        f"  | {name[:20]:<20} P      R      F1   " for name, _ in runs)
    lines = ["frames matched: " + ", ".join(f"{n} {m['frames_matched']}" for n, m in runs),
             "cells evaluated: " + ", ".join(
                 f"{n} {m['cells']} ({m.get('cell_set', 'observed')})" for n, m in runs),
             "", head]
    for table, keys in (("per_class", FINE), ("coarse", COARSE)):
        for k in keys:
            row = f"{k:<15}{metrics[table][k]['support']:>9}"
            for _, m in runs:
                s = m[table][k]
                row += f"  | {'':<20}{num(s['precision'])} {num(s['recall'])} {num(s['f1'])}"
            lines.append(row)
        lines.append("")
    for n, m in runs:
        conf = m["confusion"]
        lines.append(f"confusion ({n}): rows truth, columns decision")
        lines.append(f"{'':<15}" + "".join(f"{d[:9]:>10}" for d in conf["decision"]))
        for t, counts in zip(conf["truth"], conf["counts"], strict=True):
            lines.append(f"{t:<15}" + "".join(f"{c:>10}" for c in counts))
        lat = m["latency_frames"]
        for name in TOLERANT_CLASSES:
            tol = m.get(f"{name}_within_one_cell")
            if tol is not None:
                lines.append(f"{name} within one cell ({n}): P "
                             f"{num(tol['precision']).strip()} ({tol['correct']}/"
                             f"{tol['decided']}), R {num(tol['recall']).strip()} "
                             f"({tol['found']}/{tol['support']}), F1 {num(tol['f1']).strip()}")
        obj = m.get("objects")
        if obj is not None:  # strict, then within one cell
            for label, scores, tail in (
                    (f"objects ({n})", obj, f", track switches {obj['track_switches']} "
                     f"(identity switches {obj['identity_switches']}, agent-frames matched "
                     f"twice or more {obj['duplicate_matches']})"),
                    (f"objects within one cell ({n})", obj.get("within_one_cell"), "")):
                if scores is not None:
                    lines.append(f"{label}: moving P {num(scores['precision']).strip()} "
                                 f"({scores['moving_matched']}/{obj['moving_reported']}), R "
                                 f"{num(scores['recall']).strip()} ({scores['moving_found']}/"
                                 f"{obj['moving_truth']}){tail}")
        lines.append(f"moving-object latency ({n}): {lat['episodes']} episodes, "
                     f"{lat['detected']} detected, {lat['missed']} missed; frames mean "
                     f"{num(lat['mean']).strip()}, median {num(lat['median']).strip()}, "
                     f"max {lat['max'] if lat['max'] is not None else '-'}")
        lines.append(f"missed episodes by frames visible ({n}): " + ", ".join(
            f"{k} frames {b['missed']} of {b['episodes']}"
            for k, b in lat["by_visible_frames"].items()))
        near_lat = m.get("latency_frames_within_one_cell")
        if near_lat is not None:
            lines.append(f"moving-object latency within one cell ({n}): "
                         f"{near_lat['detected']} detected, {near_lat['missed']} missed; "
                         f"frames mean {num(near_lat['mean']).strip()}")
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"
