"""Reading + decoding lidar scans from each kind of log evperc reads: scans/s of
``LogReader.scans()`` on the hdl64 drive (~117,000 points per scan, 1.9 MB PointCloud2).

The (a) log of ``bench_decode.py`` / ``bench_run.py`` (``bench-out/sim-hdl64-10s``, ROS 2
MCAP with zstd chunks as ``evperc simulate`` writes it) rewritten once, with the test suite's
third-party writers (tests/bag_writers.py), into ``bench-out/sim-hdl64-10s-kinds/``:

- ``ros2-uncompressed.mcap``: the same records copied into chunks without compression
  (mcap's writer), to tell the cost of zstd from that of the container;
- ``ros1.mcap``: ROS 1 messages in MCAP (mcap-ros1-support's writer: zstd chunks of 1 MiB,
  as ``mcap convert`` writes), decoded by mcap-ros1-support (genpy);
- ``drive.bag``: ROS 1 bag (rosbags' writer, uncompressed chunks, as ``rosbag record`` by
  default), decoded by rosbags;
- ``drive_db3/``: ROS 2 bag, sqlite3 storage (rosbags' writer, uncompressed), decoded by
  rosbags.

For each kind, the first ``SCANS`` posed scans (poses chained from /odom and /tf_static as in
a run), best of ``REPEATS`` passes after one warm-up pass, the kinds alternating within each
round so that a change of load hits them alike. ``open_s`` is the time ``open_log`` takes
(topic detection; a ROS 1 bag reads its index).

Run: ``.venv/bin/python benchmarks/bench_decode_kinds.py`` (or ``python benchmarks/run.py
decode_kinds``).
"""

from __future__ import annotations

import itertools
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from evperc.logs.factory import open_log  # noqa: E402

SCANS = 50
REPEATS = 5
SOURCE = ("sim-hdl64-10s", "hdl64", 10)


def logs() -> dict[str, Path]:
    """The four kinds of the hdl64 log, written once into bench-out/."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_decode import _log_path  # noqa: PLC0415

    src = _log_path(*SOURCE)
    out = ROOT / "bench-out" / f"{SOURCE[0]}-kinds"
    paths = {"ros2 mcap": src, "ros2 mcap, no zstd": out / "ros2-uncompressed.mcap",
             "ros1 mcap": out / "ros1.mcap", "rosbag1 .bag": out / "drive.bag",
             "rosbag2 .db3": out / "drive_db3"}
    if not (out / ".done").exists():
        from tests.bag_writers import (  # noqa: PLC0415
            write_ros1_mcap,
            write_rosbag1,
            write_rosbag2_sqlite,
        )

        shutil.rmtree(out, ignore_errors=True)
        out.mkdir(parents=True)
        _uncompressed_copy(src, paths["ros2 mcap, no zstd"])
        write_ros1_mcap(src, paths["ros1 mcap"])
        write_rosbag1(src, paths["rosbag1 .bag"])
        write_rosbag2_sqlite(src, paths["rosbag2 .db3"])
        (out / ".done").touch()
    return paths


def _uncompressed_copy(src: Path, out: Path) -> None:
    """``src``'s schemas, channels and messages, as they are, in uncompressed chunks."""
    from mcap.reader import make_reader  # noqa: PLC0415
    from mcap.writer import CompressionType, Writer  # noqa: PLC0415

    with src.open("rb") as f, out.open("wb") as g:
        writer = Writer(g, compression=CompressionType.NONE)
        writer.start(profile="ros2")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding,
                                                            schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id])
            writer.add_message(channels[channel.id], message.log_time, message.data,
                               message.publish_time)
        writer.finish()


def _one_pass(reader) -> tuple[float, float]:
    """(s per scan, mean points) over the first SCANS posed scans."""
    count = total = 0
    t0 = time.perf_counter()
    for scan in itertools.islice(reader.scans(), SCANS):
        count += 1
        total += len(scan.points)
    count = max(count, 1)
    return (time.perf_counter() - t0) / count, total / count


def run() -> list[dict]:
    """One row per kind; see the module docstring."""
    paths = logs()
    readers, open_s = {}, {}
    for kind, path in paths.items():
        t0 = time.perf_counter()
        readers[kind] = open_log(path)
        open_s[kind] = time.perf_counter() - t0
        _one_pass(readers[kind])  # warm-up: page cache, numba cache, type generation
    best: dict[str, tuple[float, float]] = {}
    for _ in range(REPEATS):
        for kind, reader in readers.items():
            result = _one_pass(reader)
            if kind not in best or result[0] < best[kind][0]:
                best[kind] = result
    ref = best["ros2 mcap"][0]
    return [{"kind": kind, "scans": SCANS, "points": round(points),
             "ms_per_scan": 1e3 * s, "scans_per_s": 1.0 / s, "vs_ros2_mcap": s / ref,
             "open_s": open_s[kind], "size_mb": _size(paths[kind]) / 1e6}
            for kind, (s, points) in best.items()]


def _size(path: Path) -> int:
    if path.is_dir():
        return sum(p.stat().st_size for p in path.iterdir())
    return path.stat().st_size


def main() -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from run import print_table  # noqa: PLC0415

    print_table(f"decode by kind: hdl64, first {SCANS} scans, best of {REPEATS}", run())


if __name__ == "__main__":
    main()
