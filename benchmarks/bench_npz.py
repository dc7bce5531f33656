"""Writing output chunks: ``evperc.output.npz.write_npz`` (ISA-L deflate) against the former
zipfile + zlib level 1 writer, measured in the same run on the real planes of workload (a).

Planes: the full 9-frame chunks of an ``evperc run`` of (a) (hdl64 10 s, 200 m window:
42 uint8 planes of 400×400 a frame), run once into ``bench-out/npz-a/`` (git-ignored; reused
when present; the log is simulated by bench_run.py's ``simulate`` if missing). Each writer
writes every chunk to a temporary folder (atomic rename and fsync included), best of
``repeats``, alternating the writers. Raw rows: deflate of the same member bytes in memory,
no file (zlib-ng only if installed, for comparison).

``python benchmarks/bench_npz.py`` or ``python benchmarks/run.py npz``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np
from isal import isal_zlib

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evperc.output import npz  # noqa: E402
from evperc.output.manifest import FORMAT_VERSION  # noqa: E402

CACHE = ROOT / "bench-out"
SIM = "sim-hdl64-10s"
OUT = CACHE / "npz-a"


def zlib_write_npz(path: Path, arrays: dict[str, np.ndarray], compress: bool) -> None:
    """The writer before evperc.output.npz (evperc/output/writer.py at 26025a8): zipfile, zlib 1."""
    tmp = path.with_name(f".{path.name}.tmp")
    mode = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    try:
        with zipfile.ZipFile(tmp, "w", compression=mode, compresslevel=1) as archive:
            for name, array in arrays.items():
                with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                    np.lib.format.write_array(member, np.ascontiguousarray(array),
                                              allow_pickle=False)
        with tmp.open("rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def real_chunks() -> list[dict[str, np.ndarray]]:
    """The full chunks of an (a) run (frames of the last, partial chunk left out)."""
    manifest = OUT / "manifest.json"
    done = manifest.exists() and json.loads(manifest.read_text())
    if not (done and done["complete"] and done["format_version"] == FORMAT_VERSION):
        sim = CACHE / SIM
        if not (sim / ".done").exists():
            sys.path.insert(0, str(Path(__file__).resolve().parent))
            from bench_run import simulate
            simulate(SIM, "hdl64", 10.0)
        config = CACHE / "configs" / "window200.toml"
        config.parent.mkdir(parents=True, exist_ok=True)
        config.write_text("[grid]\nwindow_size_m = 200.0\n")
        subprocess.run([sys.executable, "-m", "evperc", "-q", "run", str(sim / "drive.mcap"),
                        "--map", str(sim / "map.geojson"), "--config", str(config),
                        "--out", str(OUT), "--overwrite"], check=True, cwd=ROOT)
    chunks = []
    for path in sorted((OUT / "frames").glob("chunk_*.npz")):
        with np.load(path) as z:
            chunks.append({k: z[k] for k in z.files})
    full = max(len(c["stamp_ns"]) for c in chunks)
    return [c for c in chunks if len(c["stamp_ns"]) == full]


def time_writers(chunks: list[dict[str, np.ndarray]], writers: dict[str, Callable],
                 repeats: int) -> dict[str, tuple[float, int]]:
    """Best seconds over all chunks and bytes written, per writer (alternating runs)."""
    best = {name: float("inf") for name in writers}
    size = {}
    with tempfile.TemporaryDirectory(dir=CACHE) as tmp:
        for _ in range(repeats):
            for name, write in writers.items():
                paths = [Path(tmp) / f"{name}_{i:05d}.npz" for i in range(len(chunks))]
                t0 = time.perf_counter()
                for path, arrays in zip(paths, chunks, strict=True):
                    write(path, arrays, True)
                best[name] = min(best[name], time.perf_counter() - t0)
                size[name] = sum(p.stat().st_size for p in paths)
        for i, arrays in enumerate(chunks):  # lossless, readable by np.load
            with np.load(Path(tmp) / f"isal_{i:05d}.npz") as z:
                assert all(np.array_equal(z[k], v) for k, v in arrays.items())
    return {name: (best[name], size[name]) for name in writers}


def raw_codecs() -> dict[str, Callable[[], object]]:
    codecs = {"zlib 1": lambda: zlib.compressobj(1, zlib.DEFLATED, -15)}
    for level in (0, 1, 2):
        codecs[f"isal {level}"] = (
            lambda level=level: isal_zlib.compressobj(level, isal_zlib.DEFLATED, -15))
    try:
        from zlib_ng import zlib_ng
    except ImportError:
        return codecs
    for level in (1, 2):
        codecs[f"zlib-ng {level}"] = (
            lambda level=level: zlib_ng.compressobj(level, zlib_ng.DEFLATED, -15))
    return codecs


def time_raw(buffers: list[memoryview], make: Callable[[], object],
             repeats: int) -> tuple[float, int]:
    best, size = float("inf"), 0
    for _ in range(repeats):
        t0 = time.perf_counter()
        size = 0
        for data in buffers:
            deflater = make()
            size += len(deflater.compress(data)) + len(deflater.flush())
        best = min(best, time.perf_counter() - t0)
    return best, size


def run(repeats: int = 3) -> list[dict]:
    """One row per writer / codec: ms and MB/s per (a) frame, output kB per frame."""
    chunks = real_chunks()
    frames = sum(len(c["stamp_ns"]) for c in chunks)
    arrays = [np.ascontiguousarray(a) for c in chunks for a in c.values()]
    nbytes = sum(a.nbytes for a in arrays)

    def row(what: str, seconds: float, size: int) -> dict:
        return {"writer": what, "ms_per_frame": seconds * 1e3 / frames,
                "MB_per_s": nbytes / seconds / 1e6, "kB_per_frame": size / frames / 1e3,
                "frames": frames, "MB_in_per_frame": nbytes / frames / 1e6}

    writers = {"zlib": zlib_write_npz, "isal": npz.write_npz}
    timed = time_writers(chunks, writers, repeats)
    rows = [row("write_npz: zipfile + zlib 1 (before)", *timed["zlib"]),
            row(f"write_npz: evperc.output.npz (isal {npz.DEFLATE_LEVEL})", *timed["isal"])]
    buffers = [memoryview(a.reshape(-1).view(np.uint8)) for a in arrays]
    for name, make in raw_codecs().items():
        rows.append(row(f"raw deflate, {name}", *time_raw(buffers, make, repeats)))
    return rows


if __name__ == "__main__":
    for r in run():
        print(f"{r['writer']:<40} {r['ms_per_frame']:6.2f} ms/frame {r['MB_per_s']:7.0f} MB/s "
              f"{r['kB_per_frame']:7.1f} kB/frame")
