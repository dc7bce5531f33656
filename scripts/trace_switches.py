#!/usr/bin/env python3
"""Trace every track switch of ``evperc evaluate``'s object score (issue: switches doubled
with the footprint completion).

Replays the object stage (scripts/object_replay.py) under each ``--set`` and scores it with
:class:`evperc.eval.metrics.ObjectScore`'s matching rule (a reported moving object matches the
truth agent holding most of its cells of class M), and gives each switch — agent ``a``
matched at frame k by track ``n`` after track ``p`` matched it last — the first cause that
applies:

- ``same_frame``: ``p`` also matches ``a`` in frame k (two tracks on one agent: each such
  frame counts a switch per extra track, in record order);
- ``prev_elsewhere``: ``p`` is reported moving in frame k and matches another agent (a
  footprint that slid onto a neighbour, or the neighbour's track that took this agent);
- ``prev_unmatched``: ``p`` is reported moving in frame k but matches no agent;
- ``prev_not_moving``: ``p`` is in the object list, not moving;
- ``prev_merged``: ``p`` was reported but merged into another object as its fragment
  (``objects.fragment_gap_cells``);
- ``prev_gone``: ``p`` is not in the object list (its track ended); ``new_track`` if ``n`` was
  first reported in the last 3 frames (a restart), else ``old_track``.

Also counted: switches by an identity-kept rule (an agent switches only when none of the
tracks matching it in frame k is the one it kept; with several, it keeps the first), and the
agent-frames matched by more than one track (``duplicates``) — `evperc evaluate`'s
``identity_switches`` and ``duplicate_matches``, counted here apart from the scorer and
checked against it on every drive.

Each switch also says whether the frame-k match of ``n`` needs the completed cells (without
them ``n`` would match no agent, or another) — ``by_completion``.

    PYTHONPATH=$PWD .venv/bin/python scripts/trace_switches.py --work /tmp/recall/base \\
        --seeds 1,2 --set "footprint_frames=0;arrival_share=0" --set ""
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

import object_replay as rp  # noqa: E402

from evperc.eval.metrics import evaluate, overlap  # noqa: E402
from evperc.geo.window import Window  # noqa: E402
from evperc.output.objects import OBJECT_STATES, object_labels  # noqa: E402

log = logging.getLogger("trace_switches")
_MOVING = OBJECT_STATES["moving"]


def matches(objects: np.ndarray, labels: np.ndarray, agent: np.ndarray) -> list[tuple[int, int]]:
    """(track id, agent) of each reported moving object matching an agent, in record order
    (ObjectScore's rule: the agent holding most of its cells of class M)."""
    out = []
    for o in objects[objects["state"] == _MOVING]:
        hits = agent[(labels == o["track_id"]) & (agent > 0)]
        if hits.size:
            out.append((int(o["track_id"]), int(np.bincount(hits).argmax())))
    return out


def trace(run: Any, truth: Any, raw: dict[int, tuple[np.ndarray, np.ndarray]]
          ) -> dict[str, Any]:
    """Switch causes of a replayed run (``raw``: per stamp, the object list before the
    completion)."""
    tcode = truth.class_codes["moving"] if hasattr(truth, "class_codes") else None
    from evperc.eval.metrics import TRUTH_CODES
    tcode = tcode if tcode is not None else TRUTH_CODES["moving"]
    truth_at = {t.stamp_ns: t for t in truth.frames}
    last: dict[int, int] = {}
    first_seen: dict[int, int] = {}
    causes: Counter[str] = Counter()
    events = []
    matched = 0
    kept: dict[int, int] = {}
    kept_switches = duplicates = 0
    res = run.resolution_m
    for k, f in enumerate(run.frames):
        t = truth_at.get(f.stamp_ns)
        if t is None:
            continue
        dec = np.asarray(f.decision)
        win = Window(res, dec.shape[0], dec.shape[1], int(f.origin[0]), int(f.origin[1]))
        ov = overlap(win, t.window)
        if ov is None:
            continue
        (rr, rc), (tr, tc) = ov
        agent = np.where(t.classes[tr, tc] == tcode, t.agent[tr, tc], 0)
        labels = f.object_labels()[rr, rc]
        now = matches(f.objects, labels, agent)
        robj, rcells = raw[f.stamp_ns]
        raw_match = dict(matches(robj, object_labels(robj, rcells, dec.shape)[rr, rc], agent))
        states = {int(o["track_id"]): int(o["state"]) for o in f.objects}
        for o in f.objects:
            if o["state"] == _MOVING:
                first_seen.setdefault(int(o["track_id"]), k)
        of_track: dict[int, list[int]] = {}
        for tid, a in now:
            of_track.setdefault(tid, []).append(a)
        matched += len(now)
        agents_of_frame = Counter(a for _, a in now)
        for tid, a in now:
            p = last.get(a)
            if p is not None and p != tid:
                if a in of_track.get(p, []):
                    cause = "same_frame"
                elif p in of_track:
                    cause = "prev_elsewhere"
                elif states.get(p) == _MOVING:
                    cause = "prev_unmatched"
                elif p in states:
                    cause = "prev_not_moving"
                elif p in {int(o["track_id"]) for o in robj}:
                    cause = "prev_merged"
                else:
                    cause = "prev_gone:" + ("new_track" if k - first_seen[tid] < 3
                                            else "old_track")
                by_completion = raw_match.get(tid) != a
                causes[cause] += 1
                causes["by_completion" if by_completion else "by_cluster"] += 1
                events.append({"frame": k, "agent": a, "prev": p, "new": tid, "cause": cause,
                               "by_completion": by_completion,
                               "tracks_on_agent": agents_of_frame[a]})
            last[a] = tid
        for a in {a for _, a in now}:  # the identity-kept rule (see the module docstring)
            tids = [tid for tid, b in now if b == a]
            if kept.get(a) is not None and kept[a] not in tids:
                kept_switches += 1
            if kept.get(a) not in tids:
                kept[a] = tids[0]
            duplicates += len(tids) > 1
    return {"switches": len(events), "matched": matched, "causes": dict(causes),
            "events": events, "kept_switches": kept_switches, "duplicates": duplicates}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--seeds", default="1,2")
    parser.add_argument("--profiles", default="ibeo4,hdl64")
    parser.add_argument("--set", action="append", default=None)
    parser.add_argument("--events", action="store_true", help="list every switch")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    from evperc.config import load_config
    from evperc.sim.truth import load_truth
    base = load_config(None)
    original = rp.complete_footprints
    for s in args.set or [""]:
        for profile in args.profiles.split(","):
            for seed in args.seeds.split(","):
                drive = rp.simulated_drive(args.work, profile, seed)
                out = args.work / "replay_runs" / f"{profile}-s{seed}"
                truth = load_truth(drive / "truth")
                raw: dict[int, tuple[np.ndarray, np.ndarray]] = {}

                def hooked(state: Any, objects: np.ndarray, cells: np.ndarray, window: Any,
                           stamp_ns: int, *a: Any, _raw: Any = raw) -> Any:
                    _raw[int(stamp_ns)] = (objects.copy(), np.asarray(cells).copy())
                    return original(state, objects, cells, window, stamp_ns, *a)
                rp.complete_footprints = hooked
                try:
                    run = rp.replay(out, rp.with_objects(base, rp.parse_set(s)))
                finally:
                    rp.complete_footprints = original
                for f in run.frames:  # footprint off: the hook is not called
                    raw.setdefault(f.stamp_ns, (f.objects, f.object_cells))
                r = trace(run, truth, raw)
                obj = evaluate(run, truth, cells="visible")["objects"]
                assert obj["track_switches"] == r["switches"], (obj, r["switches"])
                # the scorer's identity rule and this module's, written apart, agree
                assert (obj["identity_switches"], obj["duplicate_matches"]) == (
                    r["kept_switches"], r["duplicates"]), (obj, r)
                p_r = " / ".join("–" if v is None else f"{v:.3f}"  # a drive without a mover
                                 for v in (obj["precision"], obj["recall"]))
                print(f"| {s or 'defaults'} | {profile}-s{seed} | {r['switches']} | "
                      f"{r['matched']} | {r['switches'] / max(r['matched'], 1):.3f} | "
                      f"{p_r} | "
                      f"{r['kept_switches']} | {r['duplicates']} | "
                      f"{dict(sorted(r['causes'].items()))} |")
                if args.events:
                    for e in r["events"]:
                        print("   ", e)


if __name__ == "__main__":
    main()
