"""The object list through `evperc run` and `evperc.load`: stored per frame, consistent with
the frame's layers, off with ``objects.enabled = false`` (then the chunks are as before)."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

import evperc
from evperc.config import load_config
from evperc.fusion.twin import DECISION_CODES as D
from evperc.output.objects import OBJECT_DTYPE, OBJECT_STATES
from evperc.output.writer import RunWriter
from evperc.runner import RunRequest, run
from tests.e2e.scenes import write_street_drive

#: stamp -> the fused step's betP ((rows, cols, 5), as quantised by the step) of the "on"
#: run's frames, seen by ``on_frame``: what ``mean_betp_moving`` is taken over (the stored
#: files hold no betP since format_version 4; a reader derives it from the masses)
STEP_BETP: dict[int, np.ndarray] = {}


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """Objects on (the defaults), off, and on without ``fill_moving``; without the vehicle
    boxes: the scene's 2 m square "car" is no car a 4.4 m box fits, and a record's
    ``mean_betp_moving`` is over its cluster's cells, which the checks below take to be all
    its cells (the boxes' run: tests/objects/test_boxes.py); with the cell centres' mean for
    a centroid, which they check (the returns' mean, the default since 2026-12-07:
    tests/objects/test_return_centroids.py)."""
    tmp = tmp_path_factory.mktemp("objects")
    drive = write_street_drive(tmp / "street.mcap", n_scans=30)
    out = []
    for name, enabled, fill in (("on", True, True), ("off", False, True),
                                ("nofill", True, False)):
        config = load_config(overrides={"grid.window_size_m": 40.0, "output.chunk_frames": 10,
                                        "objects.enabled": enabled,
                                        "objects.fill_moving": fill,
                                        "objects.box_length_m": 0.0,
                                        "objects.centroid": "cells"})

        def keep_betp(frame: dict) -> None:
            STEP_BETP[int(frame["stamp_ns"])] = frame["betp"]

        run(RunRequest(log_path=drive, out_dir=tmp / name, config=config),
            on_frame=keep_betp if name == "on" else None)
        out.append(tmp / name)
    return out[0], out[1], out[2]


def test_objects_are_stored_and_agree_with_the_frame(runs: tuple[Path, Path, Path]) -> None:
    on, _, _ = runs
    frames = list(evperc.load(on).frames)
    with_objects = [f for f in frames if len(f.objects)]
    assert with_objects, "the crossing car (2 m/s north) is reported"
    for f in frames:
        assert f.objects.dtype == OBJECT_DTYPE
        labels = f.object_labels()
        assert (labels > 0).sum() == f.objects["cell_count"].sum()  # cells not shared
        for o in f.objects:
            cells = labels == o["track_id"]
            # its cells are occupied now, never mapped infrastructure or free
            assert np.isin(f.decision[cells], [D["moving"], D["static"], D["stopped"],
                                               D["unmapped"]]).all()
            rows, cols = np.nonzero(cells)
            x, y = f.window.cell_centres()
            np.testing.assert_allclose(o["centroid_m"], [x[cols].mean(), y[rows].mean()])
            np.testing.assert_allclose(o["mean_betp_moving"],
                                       STEP_BETP[f.stamp_ns][cells, 4].mean(), atol=1e-5)
            # the stored masses' betP(M), which evperc.load gives, is the same but for the
            # rounding: each of a cell's n focal masses is within 1/510, which moves the
            # numerator Σ_{A∋M} m(A)/|A| by at most Σ_{A∋M} 1/|A| / 510 ≤ 6.2 / 510 and the
            # normaliser by n / 510; the step's own betP is rounded to 1/510 too
            n = (f.masses[cells] > 0).sum(axis=-1)
            bound = (6.2 + n) / 510 / (1 - n / 510) + 1 / 510
            assert (np.abs(f.betp[cells, 4] - STEP_BETP[f.stamp_ns][cells, 4])
                    <= bound + 1e-6).all()
    car = [o for f in with_objects for o in f.objects]
    assert {int(o["track_id"]) for o in car} == {1}
    assert all(o["state"] == OBJECT_STATES["moving"] for o in car)
    # the car crosses north at 2 m/s: the fitted vy, median over its frames
    assert 1.0 < float(np.median([o["velocity_m_per_s"][1] for o in car])) < 3.0


def test_objects_change_only_their_moving_cells_and_no_mass(runs: tuple[Path, Path, Path]
                                                             ) -> None:
    on, off, nofill = runs
    filled = 0
    for a, b, c in zip(evperc.load(on).frames, evperc.load(off).frames,
                       evperc.load(nofill).frames, strict=True):
        np.testing.assert_array_equal(a.masses, b.masses)  # never evidence (method.md §8)
        np.testing.assert_array_equal(c.decision, b.decision)  # without the fill: as off
        labels = a.object_labels()
        moving_ids = a.objects["track_id"][a.objects["state"] == OBJECT_STATES["moving"]]
        in_moving = np.isin(labels, moving_ids) & (labels > 0)
        assert (a.decision[in_moving] == D["moving"]).all()  # the fill
        differ = a.decision != b.decision
        assert not (differ & ~in_moving).any()  # and nothing else
        filled += int(differ.sum())
        assert b.objects is None and b.object_labels() is None
    assert filled > 0, "the crossing car's far cells, decided occupied, become moving"


def test_objects_off_leaves_the_chunks_as_before(runs: tuple[Path, Path, Path]) -> None:
    on, off, _ = runs
    names = zipfile.ZipFile(off / "frames" / "chunk_00000.npz").namelist()
    assert not any(n.startswith("object") for n in names)
    assert {"objects.npy", "object_counts.npy", "object_cells.npy"} <= set(
        zipfile.ZipFile(on / "frames" / "chunk_00000.npz").namelist())


def test_writer_refuses_objects_for_some_frames_only(tmp_path: Path) -> None:
    config = load_config(overrides={"output.compress": False})
    meta = {"rows": 4, "cols": 4, "decision_codes": D}
    writer = RunWriter(tmp_path / "w", config, meta)
    try:
        writer.frame_slot()
        writer.commit_frame(1, np.zeros(3), (0, 0), np.zeros(7, np.int64),
                            objects=np.zeros(0, OBJECT_DTYPE),
                            object_cells=np.zeros(0, np.uint32))
        writer.frame_slot()
        with pytest.raises(RuntimeError, match="some frames"):
            writer.commit_frame(2, np.zeros(3), (0, 0), np.zeros(7, np.int64))
    finally:
        writer.abort()
