"""`evperc batch` throughput: 4 synthetic logs of 30 scans (~1,500 points per scan) run
in-process one after the other, then on a LocalCluster of 1 and of 2 single-threaded
workers; with the default 100 m window (200 × 200 cells) and a 40 m one (80 × 80).

Cluster start-up is timed apart from the batch. Each cluster runs the batch twice: "cold"
(fresh workers import evperc and its libraries during their first task) and "warm" (the
same workers again, into another output root)."""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evperc.batch import BatchRequest, open_client, run_batch  # noqa: E402
from evperc.config import load_config  # noqa: E402
from evperc.runner import RunRequest  # noqa: E402
from evperc.runner import run as run_one  # noqa: E402
from tests.batch.logs import write_street_log  # noqa: E402

N_LOGS = 4
N_SCANS = 30
WINDOWS_M = (100.0, 40.0)


def _peak_rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _row(window_m: float, mode: str, workers: int, frames: int, wall_s: float,
         start_s: float | None) -> dict:
    return {"window_m": window_m, "mode": mode, "workers": workers, "logs": N_LOGS,
            "frames": frames,
            "cluster_start_s": round(start_s, 2) if start_s is not None else "-",
            "wall_s": round(wall_s, 2), "logs_per_s": round(N_LOGS / wall_s, 3),
            "frames_per_s": round(frames / wall_s, 2)}


def _bench_window(logs: list[Path], out: Path, window_m: float) -> list[dict]:
    config = load_config(overrides={"grid.window_size_m": window_m})
    load_1min = round(os.getloadavg()[0], 2)  # other processes share the cores
    t0 = time.perf_counter()
    frames = sum(run_one(RunRequest(log_path=p, out_dir=out / "seq" / p.stem,
                                    config=config))["frames"] for p in logs)
    rows = [_row(window_m, "sequential in-process", 1, frames, time.perf_counter() - t0, None)]
    rows[0]["load_1min_before"] = load_1min
    for workers in (1, 2):
        t0 = time.perf_counter()
        with open_client(workers=workers) as client:
            start_s = time.perf_counter() - t0
            for state in ("cold", "warm"):
                t1 = time.perf_counter()
                result = run_batch(BatchRequest(logs=tuple(logs),
                                                out_root=out / f"dask{workers}{state}",
                                                config=config), client=client, progress=False)
                wall_s = time.perf_counter() - t1
                bad = [r for r in result if r["status"] != "ok"]
                if bad:
                    raise RuntimeError(f"benchmark batch failed: {bad}")
                rows.append(_row(window_m, f"dask, {state}", workers,
                                 sum(r["frames"] for r in result), wall_s, start_s))
            peak_mb = round(max(client.run(_peak_rss_mb).values()))
        rows[-1]["worker_peak_rss_mb"] = rows[-2]["worker_peak_rss_mb"] = peak_mb
    by_mode = {(r["mode"], r["workers"]): r for r in rows}
    for state in ("cold", "warm"):
        one, two = by_mode[(f"dask, {state}", 1)], by_mode[(f"dask, {state}", 2)]
        two["ratio_2_vs_1_worker"] = round(one["wall_s"] / two["wall_s"], 2)
    return rows


def run() -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        tmp_dir = Path(tmp)
        logs = [write_street_log(tmp_dir / f"drive{k}.mcap", N_SCANS, seed=k)
                for k in range(N_LOGS)]
        for window_m in WINDOWS_M:
            rows += _bench_window(logs, tmp_dir / f"w{window_m:g}", window_m)
    return rows


if __name__ == "__main__":
    from run import print_table  # benchmarks/run.py

    print_table("evperc batch: 4 logs x 30 scans", run())
