"""The output directory: writer → evperc.load round trip, atomicity, refusal to overwrite."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import evperc
from evperc.config import load_config
from evperc.errors import OutputError
from evperc.fusion.twin import DECISION_CODES
from evperc.output.writer import RunWriter

ROWS, COLS = 4, 5


def frame_arrays(rng: np.random.Generator):
    masses = np.zeros((ROWS, COLS, 32), np.float32)
    masses[..., 31] = rng.uniform(0, 1, (ROWS, COLS))
    masses[..., 1] = 1 - masses[..., 31]
    # the pignistic probability of these masses, by hand: {F} keeps its mass, Ω shares its
    # mass among the five classes
    betp = np.repeat(masses[..., 31:] / 5, 5, axis=-1)
    betp[..., 0] += masses[..., 1]
    decision = rng.integers(0, 7, (ROWS, COLS)).astype(np.uint8)
    zeta = rng.uniform(0, 1, (ROWS, COLS)).astype(np.float32)
    conflict = rng.uniform(0, 0.3, (ROWS, COLS, 3)).astype(np.float32)
    return masses, betp, decision, zeta, conflict


def make_writer(out: Path, chunk_frames: int = 2, overwrite: bool = False) -> RunWriter:
    config = load_config()
    config["output"]["chunk_frames"] = chunk_frames
    meta = {"decision_codes": DECISION_CODES, "classes": list("FIUSM"), "crs": "EPSG:32635",
            "resolution_m": 0.5, "rows": ROWS, "cols": COLS}
    return RunWriter(out, config, meta, overwrite=overwrite)


def test_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    writer = make_writer(tmp_path / "out")
    written = []
    for k in range(5):
        arrays = frame_arrays(rng)
        writer.add(1000 + k, np.array([k, 2.0 * k, 0.1]), (10 + k, -3), *arrays)
        written.append(arrays)
    writer.close({"frames": 5})
    run = evperc.load(tmp_path / "out")
    assert len(run) == 5
    assert run.decision_codes == DECISION_CODES
    frames = list(run.frames)
    assert [f.stamp_ns for f in frames] == [1000, 1001, 1002, 1003, 1004]
    assert len(list((tmp_path / "out" / "frames").glob("chunk_*.npz"))) == 3
    for k, (frame, (masses, betp, decision, zeta, conflict)) in enumerate(
            zip(frames, written, strict=True)):
        assert frame.origin == (10 + k, -3)
        assert frame.window.row0 == 10 + k
        np.testing.assert_array_equal(frame.decision, decision)
        # the format stores values in [0, 1] within 1/255 (docs/output-format.md)
        np.testing.assert_allclose(frame.masses, masses, atol=1 / 510 + 1e-6)
        # betP is not stored (format_version 4): it is the pignistic probability of the
        # stored masses, so it carries their rounding: two focal sets each within 1/510
        # move the numerator Σ_{A∋θ} m(A)/|A| by at most (1 + 1/5)/510 and the normaliser
        # Σ m(A) by at most 2/510, so betP by at most (1.2 + 2)/510 / (1 − 2/510)
        np.testing.assert_allclose(frame.betp, betp, atol=3.2 / 510 / (1 - 2 / 510) + 1e-6)
        np.testing.assert_allclose(frame.betp.sum(axis=-1), 1.0, atol=1e-6)
        np.testing.assert_allclose(frame.zeta, zeta, atol=1 / 510 + 1e-6)
        np.testing.assert_allclose(frame.conflict, conflict, atol=1 / 510 + 1e-6)
    assert run.frame(3).stamp_ns == 1003
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["complete"] is True
    assert manifest["frame_count"] == 5
    assert (tmp_path / "out" / "config.toml").is_file()


def test_unfinished_run_is_not_complete(tmp_path: Path) -> None:
    writer = make_writer(tmp_path / "out")
    rng = np.random.default_rng(2)
    for k in range(3):
        writer.add(k, np.zeros(3), (0, 0), *frame_arrays(rng))
    writer.abort()  # no close(): as after Ctrl-C (the chunk being written is finished)
    with pytest.raises(OutputError, match="incomplete"):
        evperc.load(tmp_path / "out")
    partial = evperc.output.reader.load(tmp_path / "out", allow_incomplete=True)
    assert len(partial) == 2  # only the chunk already on disk
    assert not list((tmp_path / "out" / "frames").glob(".*tmp"))


def test_existing_output_is_refused_without_overwrite(tmp_path: Path) -> None:
    make_writer(tmp_path / "out").close({})
    with pytest.raises(OutputError, match="--overwrite"):
        make_writer(tmp_path / "out")
    make_writer(tmp_path / "out", overwrite=True).close({})
    other = tmp_path / "precious"
    other.mkdir()
    (other / "thesis.tex").write_text("x")
    with pytest.raises(OutputError, match="not an evperc output"):
        make_writer(other, overwrite=True)
    assert (other / "thesis.tex").exists()


def test_load_rejects_non_outputs(tmp_path: Path) -> None:
    with pytest.raises(OutputError, match="no manifest.json"):
        evperc.load(tmp_path)


def test_chunks_are_capped_by_bytes() -> None:
    from evperc.output.writer import BYTES_PER_CELL, chunk_frames_for

    config = load_config()
    assert chunk_frames_for(config, (50, 50)) == 50     # 0.1 MB a frame: the frame count rules
    assert chunk_frames_for(config, (200, 200)) == 38   # 1.68 MB a frame: 64 MB / 1.68 MB
    big = chunk_frames_for(config, (400, 400))           # 6.7 MB a frame
    assert big == int(64e6 // (400 * 400 * BYTES_PER_CELL)) == 9
    config["output"]["chunk_max_mb"] = 1.0
    assert chunk_frames_for(config, (400, 400)) == 1     # never zero


def test_a_frame_of_the_wrong_shape_is_refused(tmp_path: Path) -> None:
    writer = make_writer(tmp_path / "out")
    rng = np.random.default_rng(3)
    masses, betp, decision, zeta, conflict = frame_arrays(rng)
    with pytest.raises(ValueError, match="window"):
        writer.add(0, np.zeros(3), (0, 0), masses, betp, decision[:2], zeta, conflict)
    writer.abort()


def test_manifest_size_does_not_grow_with_frames(tmp_path: Path) -> None:
    """Per-frame metadata lives in the chunks: the manifest of 3 frames and of 90 frames (one
    chunk each) are the same size, and decision counts come back per frame from the chunk."""
    rng = np.random.default_rng(2)
    sizes = []
    for n in (3, 90):
        out = tmp_path / f"out{n}"
        writer = make_writer(out, chunk_frames=100)
        for k in range(n):
            writer.add(10**18 + k, np.array([k, 0.0, 0.0]), (0, 0), *frame_arrays(rng))
        writer.close({"frames": n})
        manifest = json.loads((out / "manifest.json").read_text())
        assert manifest["frame_count"] == n and manifest["first_stamp_ns"] == 10**18
        manifest.pop("frame_count")
        manifest["chunks"][0].pop("frame_count")
        manifest.pop("summary")
        sizes.append(len(json.dumps(manifest)))
        for frame in evperc.load(out).frames:
            want = np.bincount(frame.decision.ravel(), minlength=len(DECISION_CODES))
            np.testing.assert_array_equal(frame.decision_counts, want)
    assert sizes[0] == sizes[1]


def test_masses_of_wide_windows_round_trip_through_the_tiles(tmp_path: Path) -> None:
    """Format 3 stores masses in tiles of 64 cells (evperc.output.mass_tiles): rows of several
    tiles, the last one shorter, tiles with different planes, vacuous tiles; chunk members
    hold one run per frame, their lengths listed in ``mass_bytes``."""
    rng = np.random.default_rng(12)
    rows, cols = 3, 150
    config = load_config()
    config["output"]["chunk_frames"] = 2
    meta = {"decision_codes": DECISION_CODES, "classes": list("FIUSM"), "crs": "local",
            "resolution_m": 0.5, "rows": rows, "cols": cols}
    writer = RunWriter(tmp_path / "out", config, meta)
    written = []
    for k in range(3):
        masses = np.zeros((rows, cols, 32), np.float32)
        masses[..., 31] = 1.0
        for r in range(rows):  # a band of cells with a few random focal sets each
            lo, hi = sorted(rng.integers(0, cols, 2))
            sets = rng.choice(31, size=3, replace=False)
            masses[r, lo:hi, sets] = rng.dirichlet(np.ones(4), hi - lo)[:, :3].T
            masses[r, lo:hi, 31] = 1 - masses[r, lo:hi, sets].sum(axis=0)
        betp = np.full((rows, cols, 5), 0.2, np.float32)
        writer.add(k, np.zeros(3), (0, 0), masses, betp, np.zeros((rows, cols), np.uint8),
                   np.zeros((rows, cols), np.float32), np.zeros((rows, cols, 3), np.float32))
        written.append(masses)
    writer.close({})
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["format_version"] == 4 and manifest["mass_tile_cells"] == 64
    with np.load(tmp_path / "out" / "frames" / "chunk_00000.npz") as chunk:
        assert "betp" not in chunk.files  # derived from the masses on reading
        assert chunk["tile_masks"].shape == (2, rows, 3)
        assert chunk["mass_runs"].size == chunk["mass_bytes"].sum()
        assert chunk["mass_runs"].size < 2 * 32 * rows * cols // 4  # sparse
    for frame, masses in zip(evperc.load(tmp_path / "out").frames, written, strict=True):
        np.testing.assert_allclose(frame.masses, masses, atol=1 / 510 + 1e-6)
        assert (frame.masses[masses == 0] == 0).all()


def two_frames(out: Path, rng: np.random.Generator) -> tuple[Path, dict[str, np.ndarray]]:
    """A run of two random frames in one chunk: the chunk's path and its members."""
    writer = make_writer(out, chunk_frames=3)
    for k in range(2):
        writer.add(k, np.zeros(3), (0, 0), *frame_arrays(rng))
    writer.close({})
    path = out / "frames" / "chunk_00000.npz"
    with np.load(path) as chunk:
        return path, {k: chunk[k] for k in chunk.files}


def test_a_chunk_whose_runs_do_not_match_its_masks_is_refused(tmp_path: Path) -> None:
    path, members = two_frames(tmp_path / "out", np.random.default_rng(4))
    members["mass_bytes"] = members["mass_bytes"] + np.array([1, -1])
    np.savez(path, **members)
    with pytest.raises(OutputError, match=r"chunk_00000.npz: frame 0: .* bytes of mass runs"):
        list(evperc.load(tmp_path / "out").frames)


def write_format_2(out: Path, masses: np.ndarray) -> None:
    """An output as evperc wrote it in format 2 (dense planes of the chunk's used subsets
    in ``masses``, their subsets in ``focal_masks``), written with numpy alone."""
    (out / "frames").mkdir(parents=True)
    used = np.flatnonzero(masses.any(axis=(0, 1, 2)))
    k = masses.shape[0]
    planes = np.round(np.moveaxis(masses, -1, 1)[:, used] * 255).astype(np.uint8)
    np.savez(out / "frames" / "chunk_00000.npz", stamp_ns=np.arange(k), pose=np.zeros((k, 3)),
             origin=np.zeros((k, 2), np.int64), focal_masks=used.astype(np.uint8),
             masses=planes, betp=np.full((k, 5, ROWS, COLS), 51, np.uint8),
             decision=np.zeros((k, ROWS, COLS), np.uint8),
             zeta=np.zeros((k, ROWS, COLS), np.uint8),
             conflict=np.zeros((k, 3, ROWS, COLS), np.uint8),
             decision_counts=np.zeros((k, len(DECISION_CODES)), np.int64))
    manifest = {"format_version": 2, "complete": True, "frame_count": k, "chunk_frames": k,
                "chunks": [{"file": "frames/chunk_00000.npz", "first_frame": 0,
                            "frame_count": k}],
                "decision_codes": DECISION_CODES, "classes": list("FIUSM"), "crs": "local",
                "resolution_m": 0.5, "rows": ROWS, "cols": COLS, "config": load_config(),
                "request": {}}
    (out / "manifest.json").write_text(json.dumps(manifest))


def test_outputs_of_format_2_are_still_read_but_not_resumed(tmp_path: Path) -> None:
    rng = np.random.default_rng(8)
    masses = np.stack([frame_arrays(rng)[0] for _ in range(2)])
    write_format_2(tmp_path / "old", masses)
    frames = list(evperc.load(tmp_path / "old").frames)
    assert len(frames) == 2
    for frame, want in zip(frames, masses, strict=True):
        np.testing.assert_allclose(frame.masses, want, atol=1 / 510 + 1e-6)
    manifest = json.loads((tmp_path / "old" / "manifest.json").read_text())
    manifest["complete"] = False
    (tmp_path / "old" / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(OutputError, match="format_version 2 by an earlier evperc"):
        RunWriter.resume(tmp_path / "old")


def test_outputs_of_format_3_keep_their_stored_betp(tmp_path: Path) -> None:
    """Format 3 stored betP beside the masses; a reader takes it as stored, not derived."""
    rng = np.random.default_rng(9)
    path, members = two_frames(tmp_path / "old", rng)
    stored = rng.integers(0, 256, (2, 5, ROWS, COLS)).astype(np.uint8)
    np.savez(path, **members, betp=stored)
    manifest = json.loads((tmp_path / "old" / "manifest.json").read_text())
    manifest["format_version"] = 3
    (tmp_path / "old" / "manifest.json").write_text(json.dumps(manifest))
    for frame, want in zip(evperc.load(tmp_path / "old").frames, stored, strict=True):
        np.testing.assert_allclose(frame.betp, np.moveaxis(want, 0, -1) / 255, atol=1e-7)
    manifest["complete"] = False
    (tmp_path / "old" / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(OutputError, match="format_version 3 by an earlier evperc"):
        RunWriter.resume(tmp_path / "old")


def write_frames(out: Path, n: int, seed: int) -> list:
    rng = np.random.default_rng(seed)
    writer = make_writer(out, chunk_frames=3)
    for k in range(n):
        writer.add(k, np.zeros(3), (0, k), *frame_arrays(rng))
    writer.close({})
    return list(evperc.load(out).frames)


def test_layers_deflated_frame_by_frame_equal_whole_chunks(tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch
                                                           ) -> None:
    """The writer deflates each frame's layers as it arrives (evperc.output.npz.DeflateStream);
    with zipfile's member writer changed it deflates whole chunks instead. Both give the same
    frames, and every chunk member passes zipfile's CRC check."""
    import zipfile

    import evperc.output.writer as writer_mod

    streamed = write_frames(tmp_path / "streamed", 7, seed=3)
    for path in (tmp_path / "streamed" / "frames").glob("chunk_*.npz"):
        with zipfile.ZipFile(path) as archive:
            assert archive.testzip() is None
    monkeypatch.setattr(writer_mod, "member_writer_supported", lambda: False)
    whole = write_frames(tmp_path / "whole", 7, seed=3)
    assert len(streamed) == len(whole) == 7
    for a, b in zip(streamed, whole, strict=True):
        for name in ("decision", "betp", "zeta", "conflict", "masses", "decision_counts"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_a_failure_to_deflate_a_frame_fails_the_run_at_its_chunk(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import evperc.output.writer as writer_mod

    def broken(self, array):
        raise MemoryError("no room to deflate")

    monkeypatch.setattr(writer_mod.DeflateStream, "add", broken)
    writer = make_writer(tmp_path / "out", chunk_frames=2)
    rng = np.random.default_rng(1)
    with pytest.raises(MemoryError, match="no room to deflate"):
        for k in range(5):
            writer.add(k, np.zeros(3), (0, 0), *frame_arrays(rng))
        writer.close({})
    writer.abort()
    assert not list((tmp_path / "out" / "frames").glob("chunk_*.npz"))


def test_the_ring_of_frame_layers_waits_for_the_writer_thread(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Frames' layers are filled into a ring of RING_SLOTS slots that the writer thread
    deflates: a frame cannot take a slot whose earlier frame is not deflated yet (memory
    stays at a few frames whatever the chunk size)."""
    import threading

    import evperc.output.writer as writer_mod

    gate = threading.Event()
    add = writer_mod.DeflateStream.add

    def slow_add(self, array):
        assert gate.wait(10)
        add(self, array)

    monkeypatch.setattr(writer_mod.DeflateStream, "add", slow_add)
    writer = make_writer(tmp_path / "out", chunk_frames=100)
    rng = np.random.default_rng(6)
    for k in range(writer_mod.RING_SLOTS):  # every slot filled, none deflated
        writer.add(k, np.zeros(3), (0, 0), *frame_arrays(rng))
    got_slot = threading.Event()
    thread = threading.Thread(target=lambda: (writer.frame_slot(), got_slot.set()))
    thread.start()
    assert not got_slot.wait(0.3)  # all slots wait for the writer thread
    gate.set()
    assert got_slot.wait(10)
    thread.join()
    writer.commit_frame(99, np.zeros(3), (0, 0))
    writer.close({})
    assert len(evperc.load(tmp_path / "out")) == writer_mod.RING_SLOTS + 1


def test_stored_chunks_hold_the_same_frames(tmp_path: Path) -> None:
    """``output.compress = false``: chunks are stored, not deflated (whole-chunk buffers, no
    ring), and read back the same as deflated ones."""
    import zipfile

    deflated = write_frames(tmp_path / "deflated", 5, seed=8)
    rng = np.random.default_rng(8)
    config = load_config()
    config["output"]["chunk_frames"] = 3
    config["output"]["compress"] = False
    meta = {"decision_codes": DECISION_CODES, "classes": list("FIUSM"), "crs": "EPSG:32635",
            "resolution_m": 0.5, "rows": ROWS, "cols": COLS}
    writer = RunWriter(tmp_path / "stored", config, meta)
    for k in range(5):
        writer.add(k, np.zeros(3), (0, k), *frame_arrays(rng))
    writer.close({})
    with zipfile.ZipFile(tmp_path / "stored" / "frames" / "chunk_00000.npz") as archive:
        assert {i.compress_type for i in archive.infolist()} == {zipfile.ZIP_STORED}
    stored = list(evperc.load(tmp_path / "stored").frames)
    for a, b in zip(deflated, stored, strict=True):
        for name in ("decision", "betp", "zeta", "conflict", "masses"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
