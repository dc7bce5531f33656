"""Fixtures for render/export tests: frames as plain objects, and real output folders."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from evperc.config import load_config
from evperc.geo.window import Window
from evperc.output.writer import RunWriter

CODES = {"unknown": 0, "free": 1, "moving": 2, "static": 3, "stopped": 4, "infrastructure": 5,
         "unmapped": 6}


def make_frame(rows: int = 8, cols: int = 10, *, row0: int = 0, col0: int = 0,
               resolution_m: float = 0.5, stamp_ns: int = 0, index: int = 0,
               pose: tuple[float, float, float] | None = None) -> SimpleNamespace:
    """A frame as documented in docs/output-format.md: all cells free (betP(F) = 1)."""
    window = Window(resolution_m, rows, cols, row0, col0)
    betp = np.zeros((rows, cols, 5), np.float32)
    betp[..., 0] = 1.0
    if pose is None:
        pose = ((col0 + cols / 2) * resolution_m, (row0 + rows / 2) * resolution_m, 0.0)
    return SimpleNamespace(
        index=index, stamp_ns=stamp_ns, pose=np.array(pose, dtype=np.float64),
        origin=(row0, col0), window=window,
        decision=np.full((rows, cols), CODES["free"], np.uint8), betp=betp,
        zeta=np.zeros((rows, cols), np.float32), conflict=np.zeros((rows, cols, 3), np.float32),
        masses=np.zeros((rows, cols, 32), np.float32))


def write_run(out: Path, frames: list[SimpleNamespace], crs: str = "EPSG:32631",
              objects: list[tuple[np.ndarray, np.ndarray]] | None = None) -> Path:
    """Write ``frames`` as a real `evperc run` output folder (RunWriter); ``objects``: each
    frame's object records and cells (docs/output-format.md, "Objects"), or none."""
    first = frames[0]
    config = load_config()
    config["output"]["chunk_frames"] = 2
    meta = {"decision_codes": CODES, "classes": list("FIUSM"), "crs": crs,
            "resolution_m": first.window.resolution_m, "rows": first.window.rows,
            "cols": first.window.cols}
    writer = RunWriter(out, config, meta)
    for i, f in enumerate(frames):
        records, cells = objects[i] if objects is not None else (None, None)
        # masses that agree with the betP given: each class's betP on its singleton (a
        # Bayesian mass function, whose betP is itself); cells with no betP are vacuous
        masses = np.zeros(f.window.shape + (32,), np.float32)
        for k in range(5):
            masses[..., 1 << k] = f.betp[..., k]
        masses[..., 31] = 1.0 - f.betp.sum(axis=-1)
        writer.add(f.stamp_ns, f.pose, f.origin, masses, f.betp, f.decision, f.zeta, f.conflict,
                   objects=records, object_cells=cells)
    writer.close({"frames": len(frames)})
    return out


@pytest.fixture
def frame_factory():
    return make_frame
