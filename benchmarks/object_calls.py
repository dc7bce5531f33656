"""Where the object stages' time goes in a whole run (issue 21's "the object stages cost ≤ 10 %
of a frame"): one ``evperc run`` of workload (a) (bench_run's 10 s hdl64 drive, 200 m
window) in this process, with the CPU time (``time.thread_time``) of every call of the
object-side passes on the fusion thread recorded — the object stage and its parts, the
footprint completion, the vehicle boxes, the decision fills, the small groups' support, the
backfill and the unmapped cue, with the motion gate and the fused step beside them for scale.

Only calls made once the frame loop has started count (the first ``Pipeline.step``): the
start-up's warm-up calls, which load the compiled kernels, are left out. Prints per pass
its calls, the mean CPU ms a frame and the median and 90th percentile of one call. Nested
passes are timed inside their callers (``ObjectStage.step`` holds the clusters, the split and
the tracker; ``Backfill.push`` the fills and the bridges).

    python benchmarks/object_calls.py [RUNS]     # RUNS runs (default 1), each printed

An in-process probe: each wrapper adds a Python call and two clock reads to the pass it
times, so the run's own stage clock (``stage_cpu_ms_per_frame`` of the manifest summary)
stays the figure of record.
"""

from __future__ import annotations

import collections
import functools
import statistics
import sys
import threading
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import bench_run  # noqa: E402

import evperc.objects.backfill as backfill  # noqa: E402
import evperc.objects.boxes as boxes  # noqa: E402
import evperc.objects.clusters as clusters  # noqa: E402
import evperc.objects.split as split  # noqa: E402
import evperc.objects.stage as stage  # noqa: E402
import evperc.objects.support as support  # noqa: E402
import evperc.objects.unmapped as unmapped  # noqa: E402
import evperc.runner as runner  # noqa: E402
from evperc.cli import cli  # noqa: E402

#: (owner, attribute, label): the passes timed
PASSES = [
    (runner, "gate_step", "motion gate (gate_step)"),
    (runner, "fused_step", "fused step"),
    (stage.ObjectStage, "step", "ObjectStage.step"),
    (clusters.Clusterer, "clusters", "  clusters"),
    (stage.ObjectStage, "list_small_moving", "  small moving groups listed"),
    (split.Splitter, "split", "  split of shared clusters"),
    (stage, "with_return_centroids", "  returns' centroids"),
    (stage, "footprint_seeds", "  footprint seeds"),
    (stage, "track_step", "  tracker"),
    (runner, "complete_footprints", "footprint completion"),
    (boxes.VehicleBoxes, "complete", "vehicle boxes (frame's and backfill's)"),
    (runner, "moving_object_cells", "moving objects' cells"),
    (runner, "fill_moving", "fill moving"),
    (runner, "unfill_small", "unfill small groups"),
    (runner, "small_moving_cells", "small moving cells"),
    (support.SmallGroupSupport, "push", "support: push"),
    (support.SmallGroupSupport, "judge", "support: judge"),
    (runner, "candidates", "backfill candidates"),
    (backfill.Backfill, "push", "Backfill.push"),
    (backfill.Backfill, "_bridge", "  gaps and lead"),
    (backfill, "fill", "  fills"),
    (backfill.Backfill, "_box_added", "  boxes of added records"),
    (runner, "unfill_unconfirmed", "unfill unconfirmed"),
    (runner, "count_codes", "decision counts"),
    (unmapped.UnmappedCue, "step", "unmapped cue"),
]


class Recorder:
    """CPU ns of each call of the wrapped passes on the main thread, once the loop runs."""

    def __init__(self) -> None:
        self.calls: dict[str, list[int]] = collections.defaultdict(list)
        self.frames = 0

    def wrap(self, owner: Any, name: str, label: str) -> None:
        f = getattr(owner, name)

        @functools.wraps(f)
        def timed(*args: Any, **kwargs: Any) -> Any:
            if not self.frames or threading.current_thread() is not threading.main_thread():
                return f(*args, **kwargs)
            t0 = time.thread_time_ns()
            try:
                return f(*args, **kwargs)
            finally:
                self.calls[label].append(time.thread_time_ns() - t0)

        setattr(owner, name, timed)

    def count_frames(self) -> None:
        step = runner.Pipeline.step

        @functools.wraps(step)
        def counted(pipeline: Any, *args: Any, **kwargs: Any) -> Any:
            self.frames += 1
            return step(pipeline, *args, **kwargs)

        runner.Pipeline.step = counted  # type: ignore[method-assign]

    def table(self) -> str:
        lines = ["| pass | calls | CPU ms a frame (mean) | one call, median ms | p90 ms |",
                 "|---|---|---|---|---|"]
        for _, _, label in PASSES:
            xs = sorted(self.calls.get(label, []))
            if not xs:
                continue
            lines.append(f"| {label} | {len(xs)} | {sum(xs) / 1e6 / self.frames:.3f} | "
                         f"{statistics.median(xs) / 1e6:.3f} | "
                         f"{xs[int(0.9 * (len(xs) - 1))] / 1e6:.3f} |")
        return "\n".join(lines)


def main(runs: int) -> None:
    sim = bench_run.simulate("sim-hdl64-10s", "hdl64", 10)
    config = bench_run.config_file("window200", bench_run.WINDOW_200)
    out = bench_run.CACHE / "runs" / "object-calls"
    for k in range(runs):
        recorder = Recorder()
        originals = [(owner, name, getattr(owner, name)) for owner, name, _ in PASSES]
        step = runner.Pipeline.step
        recorder.count_frames()
        for owner, name, label in PASSES:
            recorder.wrap(owner, name, label)
        try:
            cli.main(["-q", "run", str(sim / "drive.mcap"), "--map", str(sim / "map.geojson"),
                      "--config", str(config), "--out", str(out), "--overwrite"],
                     standalone_mode=False)
        finally:  # unwrapped before the next run
            for owner, name, original in originals:
                setattr(owner, name, original)
            runner.Pipeline.step = step  # type: ignore[method-assign]
        print(f"\n## run {k + 1}: {recorder.frames} frames of workload (a)\n")
        print(recorder.table())


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 1)
