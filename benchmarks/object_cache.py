"""Where the object part's time goes in a run: the compiled passes against the memory they
read (docs/performance.md § "The loop's first touch of memory, and the held frames' layers").

Two `evperc run`s of the 60 s hdl64 drive (bench_run's, 200 m window) in this process: one
with the object stage (:meth:`ObjectStage.step`), the footprint completion and the unmapped
cue wrapped, one with the object stage's parts (clusters, tracker, small moving groups): their
arguments at calls 300–319 are copied, and each call's thread CPU time is taken (the
run's). After the runs the same 20 calls are made again on copies of those arguments, back
to back (the caches hold them: "warm"), and once more with 48 MB of memory streamed before
each call (the caches hold none of them: "cold", as after the fused step's ~20 MB of state
and the other threads' streams). Prints ms a call, median of the 20 calls.

    python benchmarks/object_cache.py
"""

from __future__ import annotations

import copy
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import bench_run  # noqa: E402  (benchmarks/ is on sys.path)

from evperc import runner  # noqa: E402
from evperc.cli import cli  # noqa: E402
from evperc.objects import clusters, stage, unmapped  # noqa: E402

CALLS = range(300, 320)
STREAM_BYTES = 48 << 20


class Taken:
    """A wrapped callable: the arguments of the calls in :data:`CALLS` and their CPU times."""

    def __init__(self, function: Callable[..., Any]) -> None:
        self.function = function
        self.calls = 0
        self.args: list[tuple[tuple, dict]] = []
        self.run_ms: list[float] = []

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        self.calls += 1
        if self.calls not in CALLS:
            return self.function(*args, **kwargs)
        self.args.append(copy.deepcopy((args, kwargs)))
        t = time.thread_time()
        try:
            return self.function(*args, **kwargs)
        finally:
            self.run_ms.append((time.thread_time() - t) * 1e3)

    def again(self, stream: np.ndarray | None) -> list[float]:
        """The calls made again on copies of their arguments (``stream``: touched first)."""
        out = []
        for args, kwargs in self.args:
            a, k = copy.deepcopy((args, kwargs))
            if stream is not None:
                stream += 1.0
            t = time.thread_time()
            self.function(*a, **k)
            out.append((time.thread_time() - t) * 1e3)
        return out


def main() -> None:
    sim = bench_run.simulate("sim-hdl64-60s", "hdl64", 60)
    config = bench_run.config_file("window200", bench_run.WINDOW_200)
    # (name, owner, attribute), a run each: the passes, then the object stage's parts (a
    # wrapped call inside a wrapped one would charge it the copies' cache misses)
    runs = [[("object stage", stage.ObjectStage, "step"),
             ("footprint completion", runner, "complete_footprints"),
             ("unmapped cue", unmapped.UnmappedCue, "step")],
            [("  clusters", clusters.Clusterer, "clusters"),
             ("  tracker", stage, "track_step"),
             ("  small moving groups", stage.ObjectStage, "list_small_moving")]]
    taken: dict[str, Taken] = {}
    for wrapped in runs:
        for name, owner, attr in wrapped:
            taken[name] = Taken(getattr(owner, attr))
            # a function, not the Taken object: as a class attribute it binds ``self``
            setattr(owner, attr, lambda *a, _t=taken[name], **k: _t(*a, **k))
        try:
            cli(["-q", "run", str(sim / "drive.mcap"), "--map", str(sim / "map.geojson"),
                 "--config", str(config), "--out",
                 str(bench_run.CACHE / "runs" / "object-cache"), "--overwrite"],
                standalone_mode=False)
        finally:
            for name, owner, attr in wrapped:
                setattr(owner, attr, taken[name].function)
    stream = np.ones(STREAM_BYTES // 8)
    print("ms a call, median of calls 300-319 of the 60 s drive: in the run / warm / cold")
    for name, t in taken.items():
        t.again(None)  # once to warm
        warm, cold = t.again(None), t.again(stream)
        print(f"{name:22s} {statistics.median(t.run_ms):.3f} / {statistics.median(warm):.3f} / "
              f"{statistics.median(cold):.3f}")


if __name__ == "__main__":
    main()
