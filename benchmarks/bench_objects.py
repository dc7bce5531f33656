"""The object stages alone (issue 21) over a finished run's stored frames:
``ObjectStage.step`` on each frame's decision, betP(M) and ∅_FO (uint8 as stored), clusters
and tracker timed apart (the split of shared clusters timed with the clusters), best of 3
per frame; prints median and 90th percentile per frame, and the mean number of clusters and
tracks. The scan's occupied cells are not stored: every cell decided occupied stands in for
them (more cells than the run's stage sees, so an upper bound).

``python benchmarks/bench_objects.py RUN_DIR`` (e.g. a run of workload (a) of bench_run.py);
in `make bench` (``run()``) workload (a)'s run of bench_run.py, made first if missing.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from evperc import load  # noqa: E402
from evperc.config import load_config  # noqa: E402
from evperc.fusion.twin import DECISION_CODES  # noqa: E402
from evperc.objects.stage import ObjectStage  # noqa: E402
from evperc.objects.tracking import TrackerState, footprint_seeds, track_step  # noqa: E402

OCCUPIED = [DECISION_CODES[n] for n in ("moving", "static", "stopped", "unmapped")]


def run() -> list[dict]:
    """`make bench`: the stages on workload (a) (bench_run.py's run, made if missing)."""
    import bench_run

    out = bench_run.CACHE / "runs" / "a"
    if not (out / "manifest.json").exists():
        sim = bench_run.simulate("sim-hdl64-10s", "hdl64", 10)
        bench_run.run_evperc(sim, out, bench_run.config_file("window200", bench_run.WINDOW_200))
    return measure(str(out))


def measure(run_dir: str) -> list[dict]:
    """Per-frame times of the clusters and the tracker (ms, median and 90th percentile of
    the best of 3), and the clusters and tracks a frame."""
    run = load(run_dir)
    stage = ObjectStage(load_config(), run.shape)
    frames = [(f.decision.copy(), np.round(f.betp[..., 4] * 255).astype(np.uint8),
               np.round(f.conflict[..., 0] * 255).astype(np.uint8), f.window, f.stamp_ns,
               np.isin(f.decision, OCCUPIED))
              for f in run.frames]
    dec0, betp0, fo0, window0, stamp0, now0 = frames[0]
    stage.step(TrackerState(), dec0, betp0, fo0, window0, stamp0, now0)  # numba: load the code
    times = np.zeros((3, len(frames), 2))
    clusters_n, tracks_n = [], []
    for rep in range(3):
        state = TrackerState()
        for k, (dec, betp_m, fo, window, stamp, now) in enumerate(frames):
            t0 = time.perf_counter()
            clusters = stage.clusterer.clusters(dec, betp_m, fo, window,
                                                footprint_seeds(state, window), now)
            clusters = stage.splitter.split(clusters, state, window, stamp, dec, betp_m, fo)
            t1 = time.perf_counter()
            track_step(state, clusters, window, stamp, stage.tracking_params, dec)
            times[rep, k] = (t1 - t0, time.perf_counter() - t1)
            if rep == 0:
                clusters_n.append(len(clusters))
                tracks_n.append(len(state.tracks))
    best = times.min(axis=0) * 1e3
    rows = [{"stage": name, "median ms": float(np.median(v)),
             "p90 ms": float(np.percentile(v, 90))}
            for name, v in (("clusters", best[:, 0]), ("tracker", best[:, 1]),
                            ("both", best.sum(axis=1)))]
    rows[-1]["frames"] = len(frames)
    rows[-1]["clusters a frame"] = float(np.mean(clusters_n))
    rows[-1]["tracks a frame"] = float(np.mean(tracks_n))
    return rows


if __name__ == "__main__":
    from run import print_table

    print_table(f"objects ({sys.argv[1]})", measure(sys.argv[1]))
