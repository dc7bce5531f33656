"""Writing an `evperc run` output directory (docs/output-format.md, format_version 1).

Chunks are written atomically (temporary file, then rename); ``manifest.json`` is rewritten
after every chunk with ``complete: false`` and a last time with ``complete: true``. A reader
therefore never mistakes an interrupted run for a finished one.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from evperc import config as config_mod
from evperc.errors import OutputError

log = logging.getLogger(__name__)

FORMAT_VERSION = 1
MANIFEST = "manifest.json"
FRAMES_DIR = "frames"


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename."""
    tmp = path.with_name(f".{path.name}.tmp")
    with tmp.open("wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _json_default(value: Any) -> Any:
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def write_json(path: Path, obj: Any) -> None:
    text = json.dumps(obj, indent=1, sort_keys=True, default=_json_default, allow_nan=True)
    atomic_write_bytes(path, text.encode())


def prepare_output_dir(out_dir: Path, overwrite: bool) -> None:
    """Create ``out_dir``; refuse an existing non-empty one unless ``overwrite``."""
    if out_dir.exists():
        if not out_dir.is_dir():
            raise OutputError(f"{out_dir}: exists and is not a directory")
        if any(out_dir.iterdir()):
            if not overwrite:
                raise OutputError(f"{out_dir}: output directory exists; pass --overwrite to "
                                  "replace it or --out to choose another")
            if not (out_dir / MANIFEST).exists():
                raise OutputError(f"{out_dir}: exists and is not an evperc output; refusing "
                                  "to overwrite it, choose another --out")
            shutil.rmtree(out_dir)
    try:
        (out_dir / FRAMES_DIR).mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"{out_dir}: cannot create output directory ({err.strerror})") from err
    if not os.access(out_dir, os.W_OK):
        raise OutputError(f"{out_dir}: output directory is not writable")


@dataclass
class _Chunk:
    stamp_ns: list[int] = field(default_factory=list)
    pose: list[np.ndarray] = field(default_factory=list)
    origin: list[tuple[int, int]] = field(default_factory=list)
    masses: list[np.ndarray] = field(default_factory=list)
    betp: list[np.ndarray] = field(default_factory=list)
    decision: list[np.ndarray] = field(default_factory=list)
    zeta: list[np.ndarray] = field(default_factory=list)
    conflict: list[np.ndarray] = field(default_factory=list)


class RunWriter:
    """Streams frames into ``out_dir/frames/chunk_NNNNN.npz`` and keeps the manifest."""

    def __init__(self, out_dir: str | Path, config: dict[str, Any], meta: dict[str, Any],
                 overwrite: bool = False) -> None:
        self.out_dir = Path(out_dir)
        prepare_output_dir(self.out_dir, overwrite)
        self.chunk_frames = int(config["output"]["chunk_frames"])
        self.compress = bool(config["output"]["compress"])
        self.manifest: dict[str, Any] = {
            "format_version": FORMAT_VERSION, "complete": False, "frame_count": 0,
            "chunk_frames": self.chunk_frames, "chunks": [], "frames": [],
            "config": config, **meta}
        try:
            atomic_write_bytes(self.out_dir / "config.toml", config_mod.dumps(config).encode())
            write_json(self.out_dir / MANIFEST, self.manifest)
        except OSError as err:
            raise OutputError(f"{self.out_dir}: cannot write ({err.strerror})") from err
        self._chunk = _Chunk()
        #: called with the frame count after a chunk file is written, before the manifest
        self.on_chunk: Callable[[int], None] | None = None

    @classmethod
    def resume(cls, out_dir: str | Path) -> RunWriter:
        """Reopen an interrupted run: keep the chunks the manifest lists, drop the rest."""
        from evperc.io.run_reader import read_manifest

        out_dir = Path(out_dir)
        manifest = read_manifest(out_dir)
        writer = cls.__new__(cls)
        writer.out_dir = out_dir
        writer.manifest = manifest
        writer.chunk_frames = int(manifest["chunk_frames"])
        writer.compress = bool(manifest["config"]["output"]["compress"])
        manifest["frames"] = manifest["frames"][:manifest["frame_count"]]
        listed = {c["file"] for c in manifest["chunks"]}
        for path in (out_dir / FRAMES_DIR).iterdir():
            if f"{FRAMES_DIR}/{path.name}" not in listed:
                path.unlink()
        writer._chunk = _Chunk()
        writer.on_chunk = None
        return writer

    def add(self, stamp_ns: int, pose: np.ndarray, origin: tuple[int, int], masses: np.ndarray,
            betp: np.ndarray, decision: np.ndarray, zeta: np.ndarray, conflict: np.ndarray
            ) -> bool:
        """Queue one frame; a full chunk is written at once (then returns True)."""
        c = self._chunk
        c.stamp_ns.append(int(stamp_ns))
        c.pose.append(np.asarray(pose, dtype=np.float64))
        c.origin.append((int(origin[0]), int(origin[1])))
        c.masses.append(masses.astype(np.float16))
        c.betp.append(betp.astype(np.float16))
        c.decision.append(decision.astype(np.uint8))
        c.zeta.append(zeta.astype(np.float16))
        c.conflict.append(conflict.astype(np.float16))
        self.manifest["frames"].append({"stamp_ns": int(stamp_ns),
                                        "pose": [float(v) for v in pose],
                                        "origin": [int(origin[0]), int(origin[1])]})
        if len(c.stamp_ns) >= self.chunk_frames:
            self._flush()
            return True
        return False

    def _flush(self) -> None:
        c = self._chunk
        if not c.stamp_ns:
            return
        masses = np.stack(c.masses)
        used = np.flatnonzero(np.any(masses != 0, axis=tuple(range(masses.ndim - 1))))
        index = len(self.manifest["chunks"])
        name = f"chunk_{index:05d}.npz"
        arrays = {
            "stamp_ns": np.array(c.stamp_ns, dtype=np.int64),
            "pose": np.stack(c.pose), "origin": np.array(c.origin, dtype=np.int64),
            "focal_masks": used.astype(np.uint8), "masses": masses[..., used],
            "betp": np.stack(c.betp), "decision": np.stack(c.decision),
            "zeta": np.stack(c.zeta), "conflict": np.stack(c.conflict)}
        path = self.out_dir / FRAMES_DIR / name
        tmp = path.with_name(f".{name}.tmp")
        try:
            with tmp.open("wb") as f:
                (np.savez_compressed if self.compress else np.savez)(f, **arrays)
            os.replace(tmp, path)
        except OSError as err:
            raise OutputError(f"{path}: cannot write chunk ({err.strerror})") from err
        first = self.manifest["frame_count"]
        self.manifest["chunks"].append({"file": f"{FRAMES_DIR}/{name}", "first_frame": first,
                                        "frame_count": len(c.stamp_ns)})
        self.manifest["frame_count"] = first + len(c.stamp_ns)
        if self.on_chunk is not None:
            self.on_chunk(self.manifest["frame_count"])
        write_json(self.out_dir / MANIFEST, self.manifest)
        self._chunk = _Chunk()

    def close(self, summary: dict[str, Any]) -> None:
        """Write the last chunk, then the manifest with ``complete: true``."""
        self._flush()
        self.manifest["summary"] = summary
        self.manifest["complete"] = True
        write_json(self.out_dir / MANIFEST, self.manifest)
