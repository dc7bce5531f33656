"""Reading + decoding lidar scans from MCAP: milliseconds per scan of ``LogReader.scans()``.

Workloads of ``bench_run.py`` (simulated into ``bench-out/`` once, reused when present):
(a) hdl64, ~117,000 points per scan (ROS 2 PointCloud2, 16-byte points, zstd chunks);
(b) ibeo4, ~800 points per scan. The first ``SCANS`` posed scans of each log are read,
best of ``REPEATS`` passes (the variants alternate), after one warm-up pass.

Columns:
- ``before_ms``: the same reader with the previous PointCloud2 → xyz conversion (a
  structured numpy view of the payload, three ``astype`` copies, a stacked array, a finite
  mask over it, a boolean-index copy), swapped in for the measurement;
- ``after_ms``: the reader as it is (strided views of the payload, one compiled pass);
- ``prefetched_ms``: the same scans through ``evperc.plumbing.prefetched`` (the consumer
  does nothing: the producer thread's throughput);
- ``serial_work_ms`` / ``overlap_work_ms``: wall time per scan when the consumer spends
  ``WORK_MS`` per scan in a GIL-free compiled loop (a stand-in for the fusion kernels),
  without and with prefetching; ``work_ms`` is that loop's measured time in the overlapped
  pass and ``main_wait_ms`` = overlap − work, what reading and decoding still cost the main
  thread (waiting for a scan, or for the GIL while the producer runs Python code).

Run: ``.venv/bin/python benchmarks/bench_decode.py`` (or ``python benchmarks/run.py decode``).
"""

from __future__ import annotations

import contextlib
import itertools
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import evperc.logs.mcap_messages as mcap_messages  # noqa: E402
from evperc.logs.factory import open_log  # noqa: E402
from evperc.logs.pointcloud import XYZ, MissingFieldsError  # noqa: E402
from evperc.plumbing import prefetched  # noqa: E402

WORKLOADS = [("a: hdl64 10 s", "sim-hdl64-10s", "hdl64", 10),
             ("b: ibeo4 20 s", "sim-ibeo4-20s", "ibeo4", 20)]
SCANS = 50
REPEATS = 5
WORK_MS = 5.0


def _xyz_structured(data, fields: Mapping[str, tuple[int, str]], point_step: int, width: int,
                    height: int = 1, row_step: int | None = None,
                    big_endian: bool = False) -> np.ndarray:
    """The previous ``xyz_from_packed`` (before this benchmark was written), kept verbatim as
    the "before" of the table."""
    if not all(name in fields for name in XYZ):
        raise MissingFieldsError(sorted(fields))
    order = ">" if big_endian else "<"
    dtype = np.dtype({
        "names": list(XYZ),
        "formats": [order + fields[name][1] for name in XYZ],
        "offsets": [fields[name][0] for name in XYZ],
        "itemsize": point_step,
    })
    if height <= 0 or width <= 0 or point_step <= 0:
        return np.empty((0, 3), np.float32)
    raw = np.frombuffer(data, dtype=np.uint8)
    packed_row = width * point_step
    row_step = max(row_step or packed_row, packed_row)
    n_rows = min(height, (raw.size + row_step - packed_row) // row_step)
    if row_step != packed_row:
        raw = np.concatenate([raw, np.zeros(n_rows * row_step - min(raw.size, n_rows * row_step),
                                            np.uint8)])
        raw = raw[: n_rows * row_step].reshape(n_rows, row_step)[:, :packed_row].reshape(-1)
    else:
        raw = raw[: n_rows * packed_row]
    points = raw.view(dtype)
    xyz = np.stack([points[name].astype(np.float32) for name in XYZ], axis=-1)
    return xyz[np.isfinite(xyz).all(axis=1)]


def _xyz_structured_indexed(*args, **kwargs) -> tuple[np.ndarray, None, int]:
    """:func:`_xyz_structured` in the shape of the decoder's ``xyz_indexed_from_packed``:
    ``(points, None, len(points))`` — the benchmark's logs drop no point (only returns) and
    it labels no points, so the index the decoder would compute is not needed."""
    points = _xyz_structured(*args, **kwargs)
    return points, None, len(points)


@contextlib.contextmanager
def _previous_conversion() -> Iterator[None]:
    current = mcap_messages.xyz_indexed_from_packed
    mcap_messages.xyz_indexed_from_packed = _xyz_structured_indexed
    try:
        yield
    finally:
        mcap_messages.xyz_indexed_from_packed = current


@numba.njit(cache=True, nogil=True)
def _busy(n: int) -> float:
    """GIL-free arithmetic for the consumer stand-in."""
    acc = 0.0
    for i in range(n):
        acc += np.sqrt(i + acc * 1e-9)
    return acc


def _calibrate(ms: float) -> int:
    n = 1_000_000
    _busy(10)
    while True:
        t0 = time.perf_counter()
        _busy(n)
        dt = time.perf_counter() - t0
        if dt > 0.02:
            return max(1, int(n * ms * 1e-3 / dt))
        n *= 4


def _log_path(folder: str, profile: str, seconds: float) -> Path:
    path = ROOT / "bench-out" / folder / "drive.mcap"
    if not path.exists():
        from bench_run import simulate  # noqa: PLC0415 - only when the log is missing

        simulate(folder, profile, seconds)
    return path


def _one_pass(reader, wrap: Callable[[Iterator], Iterator] | None,
              work_n: int) -> tuple[float, float, float]:
    """(wall s per scan, s per scan in the consumer's work, mean points) of one pass over
    the first SCANS scans."""
    count = total = 0
    work = 0.0
    t0 = time.perf_counter()
    scans = reader.scans()
    with contextlib.closing(wrap(scans) if wrap else scans) as items:
        for scan in itertools.islice(items, SCANS):
            count += 1
            total += len(scan.points)
            if work_n:
                t_work = time.perf_counter()
                _busy(work_n)
                work += time.perf_counter() - t_work
    count = max(count, 1)
    return (time.perf_counter() - t0) / count, work / count, total / count


def _prefetch(it: Iterator) -> Iterator:
    return prefetched(it, depth=2)


def _measure(path: Path, work_n: int) -> dict:
    """Best pass of each variant; the variants alternate within each of REPEATS rounds so
    that a change of machine load hits them alike."""
    reader = open_log(path)
    _one_pass(reader, None, 0)  # warm-up: numba cache, page cache
    variants = {"before": (None, 0), "after": (None, 0), "prefetched": (_prefetch, 0),
                "serial_work": (None, work_n), "overlap_work": (_prefetch, work_n)}
    best: dict[str, tuple[float, float, float]] = {}
    for _ in range(REPEATS):
        for name, (wrap, n) in variants.items():
            with _previous_conversion() if name == "before" else contextlib.nullcontext():
                result = _one_pass(reader, wrap, n)
            if name not in best or result[0] < best[name][0]:
                best[name] = result
    ms = {name: 1e3 * value[0] for name, value in best.items()}
    work = 1e3 * best["overlap_work"][1]
    return {"scans": SCANS, "points": round(best["after"][2]), "before_ms": ms["before"],
            "after_ms": ms["after"], "speedup": ms["before"] / ms["after"],
            "prefetched_ms": ms["prefetched"], "serial_work_ms": ms["serial_work"],
            "overlap_work_ms": ms["overlap_work"], "work_ms": work,
            "main_wait_ms": ms["overlap_work"] - work}


def run() -> list[dict]:
    """One row per workload; see the module docstring for the columns."""
    work_n = _calibrate(WORK_MS)
    return [{"workload": label, **_measure(_log_path(folder, profile, seconds), work_n)}
            for label, folder, profile, seconds in WORKLOADS]


def main() -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from run import print_table  # noqa: PLC0415

    print_table(f"decode: ms per scan, first {SCANS} scans, best of {REPEATS}", run())


if __name__ == "__main__":
    main()
