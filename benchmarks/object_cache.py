"""Where the object part's time goes in a run: the compiled passes against the memory they
read (docs/performance.md § "The loop's first touch of memory, and the held frames' layers").

One `evperc run` of the 60 s hdl64 drive (bench_run's, 200 m window) in this process, with
the object stage (:meth:`ObjectStage.step`: clusters and tracker), the footprint completion
and the unmapped cue wrapped: their arguments at calls 300–319 are copied, and each call's
thread CPU time is taken (the run's). After the run the same 20 calls are made again on
copies of those arguments, back to back (the caches hold them: "warm"), and once more with
48 MB of memory streamed before each call (the caches hold none of them: "cold", as after
the fused step's ~20 MB of state and the other threads' streams). Prints ms a call, median
of the 20 calls.

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
from evperc.objects import stage, unmapped  # noqa: E402

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
    taken = {"object stage": Taken(stage.ObjectStage.step),
             "footprint completion": Taken(runner.complete_footprints),
             "unmapped cue": Taken(unmapped.UnmappedCue.step)}
    # functions, not the Taken objects: as class attributes they bind ``self`` as methods do
    stage.ObjectStage.step = lambda *a, **k: taken["object stage"](*a, **k)  # type: ignore
    runner.complete_footprints = lambda *a, **k: taken["footprint completion"](*a, **k)
    unmapped.UnmappedCue.step = lambda *a, **k: taken["unmapped cue"](*a, **k)  # type: ignore
    try:
        cli(["-q", "run", str(sim / "drive.mcap"), "--map", str(sim / "map.geojson"),
             "--config", str(config), "--out", str(bench_run.CACHE / "runs" / "object-cache"),
             "--overwrite"], standalone_mode=False)
    finally:
        stage.ObjectStage.step = taken["object stage"].function  # type: ignore[method-assign]
        runner.complete_footprints = taken["footprint completion"].function
        unmapped.UnmappedCue.step = taken["unmapped cue"].function  # type: ignore[method-assign]
    stream = np.ones(STREAM_BYTES // 8)
    print("ms a call, median of calls 300-319 of the 60 s drive: in the run / warm / cold")
    for name, t in taken.items():
        t.again(None)  # once to warm
        warm, cold = t.again(None), t.again(stream)
        print(f"{name:22s} {statistics.median(t.run_ms):.3f} / {statistics.median(warm):.3f} / "
              f"{statistics.median(cold):.3f}")


if __name__ == "__main__":
    main()
