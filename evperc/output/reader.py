"""Reading an `evperc run` output directory: ``evperc.load(DIR)`` (docs/output-format.md)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from evperc.errors import OutputError
from evperc.geo.window import Window
from evperc.output import mass_tiles
from evperc.output.manifest import read_manifest
from evperc.output.objects import object_labels
from evperc.output.quantise import dequantise, dequantise_planar, pignistic_of_planes


@dataclass(frozen=True)
class Frame:
    """One frame of a run; arrays in the window's geometry (row 0 = south)."""

    index: int
    stamp_ns: int
    pose: np.ndarray          # x_m, y_m, yaw_rad of the sensor in the working CRS
    origin: tuple[int, int]   # global lattice (row0, col0) of the window
    window: Window
    decision: np.ndarray      # (rows, cols) uint8
    #: (rows, cols, 5) float32: F, I, U, S, M; the pignistic probability of ``masses``
    #: (format_version 4; stored beside them, ×255, before)
    betp: np.ndarray
    zeta: np.ndarray          # (rows, cols) float32
    conflict: np.ndarray      # (rows, cols, 3) float32: ∅_FO, ∅_OF, ∅_other
    masses: np.ndarray        # (rows, cols, 32) float32
    decision_counts: np.ndarray  # (n_codes,) int64: cells per decision code
    #: the frame's moving and stopped objects, records of
    #: :data:`evperc.output.objects.OBJECT_DTYPE` by track id; None if the run computed no
    #: objects (``objects.enabled = false``, or written before them)
    objects: np.ndarray | None = None
    #: (Σ cell_count,) uint32: flat window indices (row · cols + col) of the objects' cells,
    #: object after object in record order
    object_cells: np.ndarray | None = None

    def object_labels(self) -> np.ndarray | None:
        """(rows, cols) uint32: each object's cells hold its track id, 0 elsewhere."""
        if self.objects is None:
            return None
        return object_labels(self.objects, self.object_cells, self.decision.shape)


class Run:
    """An output directory: ``.manifest``, ``.frames`` (streamed), ``len(run)``."""

    def __init__(self, out_dir: Path, manifest: dict[str, Any]) -> None:
        self.out_dir = out_dir
        self.manifest = manifest
        self.decision_codes: dict[str, int] = manifest["decision_codes"]
        self.resolution_m: float = manifest["resolution_m"]
        self.shape: tuple[int, int] = (manifest["rows"], manifest["cols"])
        self.crs: str = manifest["crs"]

    def __len__(self) -> int:
        return int(self.manifest["frame_count"])

    @property
    def frames(self) -> Iterator[Frame]:
        """All frames in order, one chunk in memory at a time."""
        for chunk in self.manifest["chunks"]:
            yield from self._read_chunk(chunk)

    def frame(self, index: int) -> Frame:
        """Frame ``index`` (reads its chunk)."""
        for chunk in self.manifest["chunks"]:
            first = chunk["first_frame"]
            if first <= index < first + chunk["frame_count"]:
                for frame in self._read_chunk(chunk):
                    if frame.index == index:
                        return frame
        raise IndexError(f"{self.out_dir}: no frame {index} (run has {len(self)})")

    def _read_chunk(self, chunk: dict[str, Any]) -> Iterator[Frame]:
        path = self.out_dir / chunk["file"]
        try:
            with np.load(path) as npz:
                arrays = {k: npz[k] for k in npz.files}
        except (OSError, ValueError, KeyError) as err:
            raise OutputError(f"{path}: unreadable chunk ({err})") from err
        rows, cols = self.shape
        planes = self._mass_planes(path, arrays)
        objects = self._objects(path, arrays)
        stored_betp = self.manifest["format_version"] < 4
        for k in range(len(arrays["stamp_ns"])):
            stored = next(planes)
            masses = dequantise_planar(stored)
            betp = (dequantise_planar(arrays["betp"][k]) if stored_betp
                    else pignistic_of_planes(stored))
            row0, col0 = (int(v) for v in arrays["origin"][k])
            yield Frame(
                index=chunk["first_frame"] + k, stamp_ns=int(arrays["stamp_ns"][k]),
                pose=arrays["pose"][k], origin=(row0, col0),
                window=Window(self.resolution_m, rows, cols, row0, col0),
                decision=arrays["decision"][k], betp=betp,
                zeta=dequantise(arrays["zeta"][k]),
                conflict=dequantise_planar(arrays["conflict"][k]), masses=masses,
                decision_counts=arrays["decision_counts"][k], **next(objects))

    @staticmethod
    def _objects(path: Path, arrays: dict[str, np.ndarray]) -> Iterator[dict[str, Any]]:
        """Each frame's ``objects`` and ``object_cells`` (None without the members)."""
        if "object_counts" not in arrays:
            while True:
                yield {}
        records, cells = arrays["objects"], arrays["object_cells"]
        ends = np.cumsum(arrays["object_counts"])
        cell_ends = np.concatenate([[0], np.cumsum(records["cell_count"].astype(np.int64))])
        if (ends.size and ends[-1] != records.size) or cell_ends[-1] != cells.size:
            raise OutputError(f"{path}: object records and cells do not match their counts")
        first = 0
        for end in ends:
            yield {"objects": records[first:end],
                   "object_cells": cells[cell_ends[first]:cell_ends[end]]}
            first = int(end)

    def _mass_planes(self, path: Path, arrays: dict[str, np.ndarray]) -> Iterator[np.ndarray]:
        """Each frame's dense uint8 mass planes ``(32, rows, cols)``."""
        if self.manifest["format_version"] == 2:  # the chunk's used planes, dense
            masks = arrays["focal_masks"].astype(np.int64)
            for stored in arrays["masses"]:
                planes = np.zeros((32, *self.shape), np.uint8)
                planes[masks] = stored
                yield planes
            return
        tile = int(self.manifest["mass_tile_cells"])
        ends = np.cumsum(arrays["mass_bytes"])
        if ends.size and ends[-1] != arrays["mass_runs"].size:
            raise OutputError(f"{path}: {arrays['mass_runs'].size} bytes of mass runs, the "
                              f"frames list {int(ends[-1])}")
        for k, end in enumerate(ends):
            runs = arrays["mass_runs"][end - arrays["mass_bytes"][k]:end]
            try:
                yield mass_tiles.decode(runs, arrays["tile_masks"][k], self.shape, tile)
            except ValueError as err:
                raise OutputError(f"{path}: frame {k}: {err}") from err


def load(out_dir: str | Path, allow_incomplete: bool = False) -> Run:
    """Open an output directory written by ``evperc run``.

    Raises :class:`OutputError` if it is not one, or if the run did not finish (unless
    ``allow_incomplete``: then only the chunks already written are visible).
    """
    out_dir = Path(out_dir)
    manifest = read_manifest(out_dir)
    if not manifest.get("complete") and not allow_incomplete:
        raise OutputError(f"{out_dir}: run is incomplete (interrupted?); rerun it, or resume "
                          "with `evperc run --resume`")
    return Run(out_dir, manifest)
