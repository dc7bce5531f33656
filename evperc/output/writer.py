"""Writing an `evperc run` output directory (docs/output-format.md, format_version 4).

Frames are quantised to uint8 as they arrive and grouped in chunks. One background thread
deflates each frame's layers as soon as the frame is committed (ISA-L releases the GIL, so
this runs on the second core while the main thread fuses the next frames), and writes the
chunk file when the chunk is full — so the end of a run waits for one frame and the file,
not for a whole chunk (12–17 ms on workload (a) before, 4–9 after). At most one chunk is
being written while the next one fills, which bounds memory. A frame the caller holds
before committing it (:meth:`RunWriter.hold`, the object list's backfill) has its layers
but the decision deflated at once too, and keeps only its decision and betP(M).

Order on disk for every chunk: the chunk file (temporary name, then rename), then the
caller's ``on_chunk`` commit (the run's checkpoint), then ``manifest.json`` with
``complete: false``. ``close()`` writes the manifest a last time with ``complete: true``. A
reader therefore never mistakes an interrupted run for a finished one, and a resumed run
finds a checkpoint that matches the manifest.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from evperc import config as config_mod
from evperc.errors import OutputError, WriteError
from evperc.gil_kept import copy_layer
from evperc.output import mass_tiles
from evperc.output.layers import MASS_TILE, StoredOutputs
from evperc.output.manifest import FORMAT_VERSION, MANIFEST, read_manifest
from evperc.output.npz import (
    Concatenated,
    DeflatedPiece,
    DeflateStream,
    deflate_piece,
    member_writer_supported,
    write_npz,
)
from evperc.output.objects import OBJECT_DTYPE
from evperc.output.quantise import quantise, quantise_planar

log = logging.getLogger(__name__)

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


def chunk_frames_for(config: dict[str, Any], shape: tuple[int, int]) -> int:
    """Frames per chunk: ``output.chunk_frames``, fewer if a chunk would pass
    ``output.chunk_max_mb`` of uint8 layers before deflate (held in memory, two chunks at
    once, only when the chunks are stored, ``output.compress = false``; deflated chunks
    keep a ring of :data:`RING_SLOTS` frames)."""
    frame_bytes = shape[0] * shape[1] * BYTES_PER_CELL
    cap = int(config["output"]["chunk_max_mb"] * 1e6 // max(frame_bytes, 1))
    return max(1, min(int(config["output"]["chunk_frames"]), cap))


def check_output_dir(out_dir: Path, overwrite: bool) -> bool:
    """Refuse an existing non-empty ``out_dir`` unless ``overwrite`` (and then refuse one that
    is not an evperc output); True if there is an old output to replace. Cheap: `evperc run`
    calls it before any slow work, :func:`prepare_output_dir` again when it creates it."""
    if not out_dir.exists():
        return False
    if not out_dir.is_dir():
        raise OutputError(f"{out_dir}: exists and is not a directory")
    if not any(out_dir.iterdir()):
        return False
    if not overwrite:
        raise OutputError(f"{out_dir}: output directory exists; pass --overwrite to "
                          "replace it or --out to choose another")
    if not (out_dir / MANIFEST).exists():
        raise OutputError(f"{out_dir}: exists and is not an evperc output; refusing "
                          "to overwrite it, choose another --out")
    return True


def prepare_output_dir(out_dir: Path, overwrite: bool) -> None:
    """Create ``out_dir``; refuse an existing non-empty one unless ``overwrite``."""
    if check_output_dir(out_dir, overwrite):
        shutil.rmtree(out_dir)
    try:
        (out_dir / FRAMES_DIR).mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"{out_dir}: cannot create output directory ({err.strerror})") from err
    if not os.access(out_dir, os.W_OK):
        raise OutputError(f"{out_dir}: output directory is not writable")


#: bytes of uint8 layers per cell and frame at most: 32 masses (all planes of every tile),
#: 5 betP, decision, ζ, 3 conflicts
BYTES_PER_CELL = 32 + 5 + 1 + 1 + 3


class _Layers:
    """Preallocated uint8 layers of ``slots`` frames; frames are quantised straight into
    them (no per-frame arrays, no stacking copy). Each slot has room for the mass runs of
    all 32 planes; only the bytes written are touched (and stored)."""

    def __init__(self, slots: int, shape: tuple[int, int]) -> None:
        rows, cols = shape
        self.mass_runs = np.empty((slots, 32 * rows * cols), np.uint8)
        self.mass_bytes = np.zeros(slots, np.int64)
        self.tile_masks = np.empty(
            (slots, rows, mass_tiles.tiles_per_row(cols, MASS_TILE)), np.uint32)
        self.betp = np.empty((slots, 5, rows, cols), np.uint8)
        self.decision = np.empty((slots, rows, cols), np.uint8)
        self.zeta = np.empty((slots, rows, cols), np.uint8)
        self.conflict = np.empty((slots, 3, rows, cols), np.uint8)

    def view(self, i: int) -> StoredOutputs:
        return StoredOutputs(self.mass_runs[i], self.tile_masks[i], self.mass_bytes[i:i + 1],
                             self.betp[i], self.conflict[i], self.zeta[i], self.decision[i])

    def layer(self, name: str, i: int) -> np.ndarray:
        """Slot ``i``'s part of the member ``name``."""
        if name == "mass_runs":
            return self.mass_runs[i, :self.mass_bytes[i]]
        return getattr(self, name)[i]


@dataclass
class HeldLayers:
    """A fused frame the caller holds before committing it (the object list's backfill,
    :meth:`RunWriter.hold`): its decision and betP(M) in arrays of its own, which the caller
    may still change (the decision) or read; its other layers deflated by the writer thread
    while they were in the cache, their ring slot free again."""

    decision: np.ndarray  # uint8 (rows, cols)
    betp_moving: np.ndarray  # uint8 (rows, cols), betP(M) ×255 as the fused step quantised it
    mass_bytes: int
    #: member name -> its deflated bytes of the frame (every streamed member but the decision)
    pieces: dict[str, DeflatedPiece] = field(default_factory=dict)
    error: Exception | None = None  # of deflating them, raised with the chunk


class _Chunk:
    """The frames of one chunk: their metadata, and their layers — in ``layers`` slot
    ``slots[k]`` for frame ``k``: a ring shared by the chunks when the layers are deflated
    frame by frame (``streams``), the chunk's own slots (slot k for frame k) otherwise."""

    def __init__(self, capacity: int, n_codes: int, layers: _Layers) -> None:
        self.capacity = capacity
        self.layers = layers
        self.count = 0
        self.slots = np.arange(capacity)
        self.stamp_ns = np.zeros(capacity, np.int64)
        self.pose = np.zeros((capacity, 3), np.float64)
        self.origin = np.zeros((capacity, 2), np.int64)
        self.mass_bytes = np.zeros(capacity, np.int64)
        self.decision_counts = np.zeros((capacity, n_codes), np.int64)
        #: each frame's object records and cells (evperc.output.objects), None: not computed
        self.objects: list[tuple[np.ndarray, np.ndarray]] | None = None
        #: the layers deflated frame by frame (:meth:`stream`), None: deflated when written
        self.streams: dict[str, DeflateStream] | None = None
        self.streamed = 0  # frames in the streams
        self.error: Exception | None = None  # of deflating a frame, raised with the chunk
        #: frame -> its held layers (committed with ``held=``: no slot of the ring)
        self.held: dict[int, HeldLayers] = {}

    def reset(self, streaming: bool) -> None:
        """Empty, for the next chunk."""
        self.count = self.streamed = 0
        self.error = None
        self.objects = None
        self.held = {}
        self.streams = ({name: DeflateStream(getattr(self.layers, name).dtype)
                         for name in STREAMED} if streaming else None)

    def layer(self, name: str, k: int) -> np.ndarray:
        """Frame ``k``'s part of the member ``name``."""
        return self.layers.layer(name, int(self.slots[k]))

    def stream(self, k: int) -> None:
        """Deflate frame ``k``'s layers into the chunk's streams (in frame order)."""
        if k != self.streamed:
            raise RuntimeError(f"frame {k} deflated out of order (expected {self.streamed})")
        held = self.held.pop(k, None)
        if held is not None and held.error is not None:
            raise held.error
        for name, stream in self.streams.items():
            if held is None:
                stream.add(self.layer(name, k))
            elif name == "decision":
                stream.add(held.decision)
            else:
                stream.add_deflated(held.pieces[name])
        self.streamed += 1

    def arrays(self) -> dict[str, Any]:
        """The NPZ members of the frames held: the deflated streams, or views of the chunk's
        own layers; the mass runs of the frames as one member, written piece by piece."""
        k = self.count
        if self.streams is not None:
            if self.streamed != k:
                raise RuntimeError(f"{self.streamed} of {k} frames deflated")
            shapes = {name: (k, *getattr(self.layers, name).shape[1:]) for name in STREAMED}
            shapes["mass_runs"] = (int(self.mass_bytes[:k].sum()),)
            layers = {name: stream.member(shapes[name])
                      for name, stream in self.streams.items()}
        else:
            own = self.layers
            layers = {"tile_masks": own.tile_masks[:k], "decision": own.decision[:k],
                      "zeta": own.zeta[:k], "conflict": own.conflict[:k],
                      "mass_runs": Concatenated(tuple(self.layer("mass_runs", i)
                                                      for i in range(k)))}
        arrays = {"stamp_ns": self.stamp_ns[:k], "pose": self.pose[:k],
                  "origin": self.origin[:k], "tile_masks": layers["tile_masks"],
                  "mass_bytes": self.mass_bytes[:k], "mass_runs": layers["mass_runs"],
                  "decision": layers["decision"],
                  "zeta": layers["zeta"], "conflict": layers["conflict"],
                  "decision_counts": self.decision_counts[:k]}
        if self.objects is not None:
            arrays["object_counts"] = np.array([len(o) for o, _ in self.objects], np.int64)
            arrays["objects"] = (np.concatenate([o for o, _ in self.objects])
                                 if self.objects else np.zeros(0, OBJECT_DTYPE))
            arrays["object_cells"] = (np.concatenate([c for _, c in self.objects])
                                      .astype(np.uint32) if self.objects
                                      else np.zeros(0, np.uint32))
        return arrays


#: frames whose layers are held at once when they are deflated frame by frame: the one
#: being filled, and up to three waiting for (or in) the writer thread
RING_SLOTS = 4
#: the chunk members deflated frame by frame as the frames arrive
STREAMED = ("tile_masks", "mass_runs", "decision", "zeta", "conflict")


class RunWriter:
    """Streams frames into ``out_dir/frames/chunk_NNNNN.npz`` and keeps the manifest."""

    def __init__(self, out_dir: str | Path, config: dict[str, Any], meta: dict[str, Any],
                 overwrite: bool = False) -> None:
        self.out_dir = Path(out_dir)
        prepare_output_dir(self.out_dir, overwrite)
        self.chunk_frames = chunk_frames_for(config, (int(meta["rows"]), int(meta["cols"])))
        self.compress = bool(config["output"]["compress"])
        self.manifest: dict[str, Any] = {
            "format_version": FORMAT_VERSION, "complete": False, "frame_count": 0,
            "chunk_frames": self.chunk_frames, "mass_tile_cells": MASS_TILE, "chunks": [],
            "first_stamp_ns": None,
            "config": config, **meta}
        try:
            atomic_write_bytes(self.out_dir / "config.toml", config_mod.dumps(config).encode())
            write_json(self.out_dir / MANIFEST, self.manifest)
        except OSError as err:
            raise OutputError(f"{self.out_dir}: cannot write ({err.strerror})") from err
        self._start()

    def _start(self) -> None:
        shape = (int(self.manifest["rows"]), int(self.manifest["cols"]))
        # two buffers: one filling while the writer thread writes the other
        n_codes = len(self.manifest["decision_codes"])
        self._shape = shape
        # deflate each frame's layers as it arrives (evperc.output.npz.DeflateStream), from a
        # ring of a few frames' layers; whole chunks deflated when written (each chunk
        # holding its frames' layers) if the chunks are stored or zipfile's internals have
        # changed
        self._streaming = self.compress and member_writer_supported()
        if self._streaming:
            ring = _Layers(RING_SLOTS, shape)
            layers = [ring, ring]
        else:
            layers = [_Layers(self.chunk_frames, shape) for _ in range(2)]
        self._ring_free = threading.Semaphore(RING_SLOTS)  # slots the writer deflated
        self._next_slot = 0
        self._reserved: int | None = None  # the slot handed out by frame_slot()
        self._buffers = [_Chunk(self.chunk_frames, n_codes, layer) for layer in layers]
        for chunk in self._buffers:
            chunk.reset(self._streaming)
        self._chunk = self._buffers[0]
        self._queued = self.manifest["frame_count"]   # frames handed to the writer thread
        self._chunks_queued = len(self.manifest["chunks"])
        self._lock = threading.Lock()
        self._written: list[dict[str, Any]] = list(self.manifest["chunks"])  # on disk
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="evperc-writer")
        self._pending: Future | None = None
        #: seconds the writer thread spent stacking, compressing and writing chunks
        self.thread_seconds = 0.0
        #: CPU seconds of the writer thread so far (updated after each chunk)
        self.thread_cpu_s = 0.0
        #: called with the frame count when a chunk is queued; returns the commit to run
        #: (in the writer thread) after the chunk file is written and before the manifest,
        #: or None: then the chunk is written but the manifest lists it only at the next
        #: commit (a resume redoes it) or at close()
        self.on_chunk: Callable[[int], Callable[[], None] | None] | None = None

    @property
    def can_hold(self) -> bool:
        """Whether :meth:`hold` can hold frames (the layers deflated frame by frame from a
        ring; not with whole chunks deflated at once)."""
        return self._streaming

    @classmethod
    def resume(cls, out_dir: str | Path) -> RunWriter:
        """Reopen an interrupted run: keep the chunks the manifest lists, drop the rest."""

        out_dir = Path(out_dir)
        manifest = read_manifest(out_dir)
        if manifest["format_version"] != FORMAT_VERSION:
            raise OutputError(f"{out_dir}: written in output format_version "
                              f"{manifest['format_version']} by an earlier evperc; it cannot "
                              "be resumed, run it again with --overwrite")
        writer = cls.__new__(cls)
        writer.out_dir = out_dir
        writer.manifest = manifest
        writer.chunk_frames = int(manifest["chunk_frames"])
        writer.compress = bool(manifest["config"]["output"]["compress"])
        listed = {c["file"] for c in manifest["chunks"]}
        for path in (out_dir / FRAMES_DIR).iterdir():
            if f"{FRAMES_DIR}/{path.name}" not in listed:
                path.unlink()
        writer._start()
        return writer

    @property
    def frame_count(self) -> int:
        """Frames received so far (written or queued)."""
        return self._queued + self._chunk.count

    def frame_slot(self) -> StoredOutputs:
        """Views of the next frame's layers. Fill them (the fused step quantises straight
        into them), then call :meth:`commit_frame` (or :meth:`hold`). Waits while the writer
        thread has not yet deflated the frames that used the ring's slots before."""
        if self._reserved is None:
            if self._streaming:
                self._ring_free.acquire()
                self._reserved = self._next_slot
                self._next_slot = (self._next_slot + 1) % RING_SLOTS
            else:
                self._reserved = self._chunk.count
        return self._chunk.layers.view(self._reserved)

    def hold(self) -> HeldLayers:
        """The frame in :meth:`frame_slot` is fused and will be committed later, after the
        frames held before it (``commit_frame(..., held=)``), its decision perhaps changed:
        its decision and betP(M) are copied out, its other layers deflated by the writer
        thread now, while they are in the cache, and its slot freed then. Needs
        :attr:`can_hold`. The held frames take ~0.3 MB each on a 200 m window, not a slot of
        the ring (~2.8 MB written) each (docs/performance.md § The main thread against
        e996c3d)."""
        if not self._streaming:
            raise RuntimeError("frames are held only when deflated frame by frame")
        if self._reserved is None:
            raise RuntimeError("hold() without frame_slot()")
        slot, self._reserved = self._reserved, None
        layers = self._chunk.layers  # the ring: the same layers for both chunks
        # copied by a compiled pass: numpy's copy of a layer releases the GIL (gil_kept)
        held = HeldLayers(copy_layer(layers.decision[slot]), copy_layer(layers.betp[slot, 4]),
                          int(layers.mass_bytes[slot]))
        self._pool.submit(self._deflate_held, layers, slot, held)
        return held

    def _deflate_held(self, layers: _Layers, slot: int, held: HeldLayers) -> None:
        """Writer thread: deflate a held frame's layers but its decision, free its slot."""
        t0 = time.perf_counter()
        try:
            for name in STREAMED:
                if name != "decision":
                    held.pieces[name] = deflate_piece(layers.layer(name, slot))
        except Exception as err:  # noqa: BLE001 - raised by _write_chunk, in order
            held.error = err
        finally:
            self._ring_free.release()
            self.thread_seconds += time.perf_counter() - t0
            self.thread_cpu_s = time.thread_time()

    def commit_frame(self, stamp_ns: int, pose: np.ndarray, origin: tuple[int, int],
                     decision_counts: np.ndarray | None = None,
                     objects: np.ndarray | None = None,
                     object_cells: np.ndarray | None = None,
                     held: HeldLayers | None = None) -> bool:
        """The frame whose layers fill :meth:`frame_slot` (or, with ``held``, the oldest
        frame :meth:`hold` returned, not yet committed) is complete; a full chunk is handed
        to the writer thread (then returns True). ``objects``, ``object_cells``: the frame's
        object list (:mod:`evperc.output.objects`; kept, not copied), given for every frame
        of a run or for none."""
        if held is None and self._reserved is None:
            raise RuntimeError("commit_frame() without frame_slot()")
        c = self._chunk
        k = c.count
        if k > 0 and (objects is None) != (c.objects is None):
            raise RuntimeError("object lists given for some frames of a chunk only")
        if objects is not None:
            if objects.dtype != OBJECT_DTYPE or object_cells is None:
                raise ValueError("objects must be OBJECT_DTYPE records with their cells")
            if k == 0:
                c.objects = []
            c.objects.append((objects, object_cells))
        if held is None:
            slot, self._reserved = self._reserved, None
            c.slots[k] = slot
            c.mass_bytes[k] = c.layers.mass_bytes[slot]
            decision = c.layers.decision[slot]
        else:
            c.held[k] = held
            c.mass_bytes[k] = held.mass_bytes
            decision = held.decision
        c.stamp_ns[k] = int(stamp_ns)
        c.pose[k] = pose
        c.origin[k] = origin
        if decision_counts is None:
            decision_counts = np.bincount(decision.ravel(), minlength=c.decision_counts.shape[1])
        c.decision_counts[k] = decision_counts
        c.count = k + 1
        if self._streaming:
            self._pool.submit(self._stream_frame, c, k, held is None)
        if self.manifest["first_stamp_ns"] is None:
            self.manifest["first_stamp_ns"] = int(stamp_ns)
        if c.count >= self.chunk_frames:
            self._flush()
            return True
        return False

    def add(self, stamp_ns: int, pose: np.ndarray, origin: tuple[int, int], masses: np.ndarray,
            betp: np.ndarray, decision: np.ndarray, zeta: np.ndarray, conflict: np.ndarray,
            decision_counts: np.ndarray | None = None, objects: np.ndarray | None = None,
            object_cells: np.ndarray | None = None) -> bool:
        """Queue one frame of float layers, interleaved ``(rows, cols, k)`` (quantised at once:
        the caller may reuse its arrays), and its object list if any; see
        :meth:`commit_frame`. ``betp`` goes into the frame's slot like the fused step's (a
        held frame's betP(M)); it is not stored: a reader derives it from the masses."""
        if tuple(decision.shape) != self._shape:
            raise ValueError(f"frame of shape {decision.shape}, the run's window is "
                             f"{self._shape}")
        slot = self.frame_slot()
        planes = quantise_planar(masses)
        slot.tile_masks[...] = mass_tiles.masks_of(np.moveaxis(masses, -1, 0), MASS_TILE)
        runs = mass_tiles.encode(planes, slot.tile_masks, MASS_TILE)
        slot.mass_runs[:runs.size] = runs
        slot.mass_length[0] = runs.size
        quantise_planar(betp, out=slot.betp)
        slot.decision[...] = decision
        slot.zeta[...] = quantise(zeta)
        quantise_planar(conflict, out=slot.conflict)
        return self.commit_frame(stamp_ns, pose, origin, decision_counts, objects,
                                 object_cells)

    def _wait(self) -> None:
        if self._pending is not None:
            pending, self._pending = self._pending, None
            pending.result()  # re-raises the writer thread's error here

    def _flush(self) -> None:
        c = self._chunk
        if not c.count:
            return
        self._wait()  # the other buffer is free again once its chunk is on disk
        self._chunk = self._buffers[1] if c is self._buffers[0] else self._buffers[0]
        self._chunk.reset(self._streaming)
        index = self._chunks_queued
        first = self._queued
        self._chunks_queued += 1
        self._queued += c.count
        commit = self.on_chunk(self._queued) if self.on_chunk is not None else None
        self._pending = self._pool.submit(self._write_chunk, c, index, first, commit)

    def _stream_frame(self, c: _Chunk, k: int, in_ring: bool = True) -> None:
        """Writer thread: deflate frame ``k`` of chunk ``c`` (queued before the chunk); free
        its ring slot if it has one (``in_ring``: not a held frame's)."""
        t0 = time.perf_counter()
        try:
            if c.error is None:
                c.stream(k)
        except Exception as err:  # noqa: BLE001 - raised by _write_chunk, in order
            c.error = err
        finally:
            if in_ring:
                self._ring_free.release()  # the frame's slot may be filled again
            self.thread_seconds += time.perf_counter() - t0
            self.thread_cpu_s = time.thread_time()

    def _write_chunk(self, c: _Chunk, index: int, first: int,
                     commit: Callable[[], None] | None) -> None:
        t0 = time.perf_counter()
        if c.error is not None:
            self.thread_seconds += time.perf_counter() - t0
            raise c.error
        name = f"chunk_{index:05d}.npz"
        arrays = c.arrays()
        path = self.out_dir / FRAMES_DIR / name
        try:
            write_npz(path, arrays, self.compress)
            with self._lock:
                self._written.append({"file": f"{FRAMES_DIR}/{name}", "first_frame": first,
                                      "frame_count": c.count})
            if commit is None and self.on_chunk is not None:
                return
            if commit is not None:
                commit()
            with self._lock:
                self.manifest["chunks"] = list(self._written)
                self.manifest["frame_count"] = first + c.count
                write_json(self.out_dir / MANIFEST, self.manifest)
        except OSError as err:
            raise WriteError(f"{path}: cannot write chunk ({err.strerror or err})") from err
        finally:
            self.thread_seconds += time.perf_counter() - t0
            self.thread_cpu_s = time.thread_time()

    def finish(self) -> None:
        """Write the last chunk and wait for the writer thread (the manifest stays
        incomplete until :meth:`close`)."""
        self._flush()
        self._wait()

    def close(self, summary: dict[str, Any]) -> None:
        """Write the last chunk, then the manifest with ``complete: true``."""
        try:
            self.finish()
            self.manifest["chunks"] = list(self._written)
            self.manifest["frame_count"] = self._queued
            self.manifest["summary"] = summary
            self.manifest["complete"] = True
            write_json(self.out_dir / MANIFEST, self.manifest)
        except OSError as err:
            raise WriteError(f"{self.out_dir}: cannot write manifest ({err.strerror})") from err
        finally:
            self._pool.shutdown(wait=True)

    def abort(self) -> None:
        """Stop after an error or Ctrl-C: finish the chunk being written (so nothing is half
        written), leave the manifest incomplete, and release the thread."""
        try:
            self._wait()
        except Exception as err:  # the run already failed; say why the chunk is missing
            log.warning("%s: last chunk not written: %s", self.out_dir, err)
        finally:
            self._pool.shutdown(wait=True)
