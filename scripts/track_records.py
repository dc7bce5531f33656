#!/usr/bin/env python3
"""One track's records, frame by frame, beside the simulator's truth under its cells: a
replay of the object stage (the defaults, or ``--set``) on the fusion outputs recorded by
scripts/object_replay.py, printed for the track ids asked for.

Per frame and track: its state (1 moving, 2 stopped: ``OBJECT_STATES``), cell count,
velocity and centroid (m), the truth agents under its cells (agent id: cells; 0 is no
agent) and the truth classes there (``class_codes`` of the truth manifest: 1 free,
2 moving, 4 stopped, 5 infrastructure, 6 unmapped), and the speed of its main agent from
the agent's cells' centroid one frame before (m/s; blank on the agent's first frame).
Records the backfill added to a held frame carry the velocity of the later report, so a
run of frames with one velocity is a backfill's.

    PYTHONPATH=$PWD .venv/bin/python scripts/track_records.py --work /tmp/sp \\
        --drive hdl64-s7 --tracks 113,123
"""

from __future__ import annotations

import argparse
import collections
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

import object_replay  # noqa: E402

from evperc.config import load_config  # noqa: E402
from evperc.output.objects import record_cells  # noqa: E402
from evperc.sim.truth import load_truth  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True,
                        help="scripts/object_replay.py's work folder")
    parser.add_argument("--drive", required=True, help="PROFILE-sSEED, e.g. hdl64-s7")
    parser.add_argument("--tracks", required=True, help="track ids, comma-separated")
    parser.add_argument("--set", default="", help="[objects] overrides, 'key=value;...'")
    args = parser.parse_args()
    tracks = [int(t) for t in args.tracks.split(",")]
    config = object_replay.with_objects(load_config(), object_replay.parse_set(args.set))
    run = object_replay.replay(args.work / "replay_runs" / args.drive, config)
    truth = load_truth(args.work / "drives" / args.drive / "truth")
    res = float(truth.manifest["resolution_m"])
    by_stamp = {t.stamp_ns: t for t in truth.frames}
    last: dict[tuple[int, int], tuple[np.ndarray, int]] = {}
    for frame in run.frames:
        t = by_stamp.get(frame.stamp_ns)
        if t is None:
            continue
        objects = frame.objects
        own_cells = record_cells(objects, frame.object_cells)
        for track in tracks:
            at = np.flatnonzero(objects["track_id"] == track)
            if at.size == 0:
                continue
            k = int(at[0])
            cells = own_cells[k]
            rows, cols = np.divmod(cells, frame.decision.shape[1])
            tr = rows + frame.origin[0] - t.origin[0]
            tc = cols + frame.origin[1] - t.origin[1]
            ok = (tr >= 0) & (tr < t.classes.shape[0]) & (tc >= 0) & (tc < t.classes.shape[1])
            agents = collections.Counter(t.agent[tr[ok], tc[ok]].tolist()).most_common(3)
            classes = collections.Counter(t.classes[tr[ok], tc[ok]].tolist())
            speed = ""
            main_agent = next((a for a, _ in agents if a > 0), None)
            if main_agent is not None:
                ar, ac = np.nonzero(t.agent == main_agent)
                centre = np.array([ac.mean() + t.origin[1], ar.mean() + t.origin[0]]) * res
                before = last.get((track, main_agent))
                if before is not None:
                    dt_s = (frame.stamp_ns - before[1]) * 1e-9
                    speed = f"{np.hypot(*(centre - before[0])) / dt_s:.2f}"
                last[(track, main_agent)] = (centre, frame.stamp_ns)
            print(f"frame {frame.index} track {track} state {objects['state'][k]} "
                  f"cells {cells.size} v {np.round(objects['velocity_m_per_s'][k], 2)} "
                  f"centroid {np.round(objects['centroid_m'][k], 1)} agents {agents} "
                  f"classes {dict(classes)} agent speed {speed}")


if __name__ == "__main__":
    main()
