"""NPZ writing (evperc.output.npz; docs/output-format.md): readable by np.load, member contents
byte-identical to numpy's own ``np.savez`` / ``np.savez_compressed``, deflated by ISA-L,
zip64 members, atomic.

References are numpy's writers and the ZIP format read with ``zipfile``/``struct``/``zlib``
directly, never evperc's own reader."""

from __future__ import annotations

import io
import os
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest
from isal import isal_zlib

from evperc.output import npz
from evperc.output.npz import DEFLATE_LEVEL, write_npz


def planes(frames: int, channels: int, n: int, seed: int = 0) -> np.ndarray:
    """uint8 planes like the run's: smooth fields with flat regions, quantised."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n, 0:n] / n
    out = np.empty((frames, channels, n, n), np.uint8)
    for k in range(frames):
        for c in range(channels):
            field = np.sin(6 * x + c + 0.1 * k) * np.cos(4 * y - c)
            field[rng.random((n, n)) < 0.7] = 0.0
            out[k, c] = np.round(255 * np.clip(field, 0, 1))
    return out


def chunk_arrays(n: int = 64) -> dict[str, np.ndarray]:
    """Every dtype and shape a chunk or checkpoint holds, plus edge cases."""
    return {
        "stamp_ns": np.array([1_700_000_000_000_000_000, 1_700_000_000_100_000_000], np.int64),
        "pose": np.array([[1.5, -2.25, 0.1], [np.nan, np.inf, -0.0]], np.float64),
        "origin": np.array([[-3, 7], [2**40, -(2**40)]], np.int64),
        "focal_masks": np.arange(1, 32, dtype=np.uint8),
        "masses": planes(2, 31, n),
        "decision": planes(2, 1, n, seed=1)[:, 0],
        "frames": np.int64(12),                     # 0-d, as in checkpoints
        "resolution_m": np.float64(0.5),
        "pg": np.random.default_rng(2).random((n, n, 32), dtype=np.float32),
        "empty": np.zeros((0, 3), np.float64),
        "strided": planes(1, 4, n, seed=3)[0, :, ::2, 1::3],   # not contiguous
        "fortran": np.asfortranarray(np.arange(12, dtype=np.int64).reshape(3, 4)),
        "big_endian": np.arange(5, dtype=">i8"),
        "flags": np.array([True, False, True]),
    }


def numpy_npz(arrays: dict[str, np.ndarray], compress: bool) -> bytes:
    buffer = io.BytesIO()
    (np.savez_compressed if compress else np.savez)(buffer, **arrays)
    return buffer.getvalue()


def members(data: bytes | Path) -> dict[str, bytes]:
    """Uncompressed member bytes, by name (zipfile checks each member's CRC-32)."""
    source = io.BytesIO(data) if isinstance(data, bytes) else data
    with zipfile.ZipFile(source) as archive:
        return {info.filename: archive.read(info) for info in archive.infolist()}


@pytest.mark.parametrize("compress", [True, False])
def test_round_trip_through_np_load(tmp_path: Path, compress: bool) -> None:
    arrays = chunk_arrays()
    path = tmp_path / "chunk_00000.npz"
    write_npz(path, arrays, compress)
    with np.load(path) as loaded:
        assert sorted(loaded.files) == sorted(arrays)
        for name, array in arrays.items():
            got = loaded[name]
            assert got.dtype == array.dtype, name
            assert got.shape == array.shape, name
            np.testing.assert_array_equal(got, array, err_msg=name)
    assert sorted(os.listdir(tmp_path)) == ["chunk_00000.npz"]  # no temporary left


@pytest.mark.parametrize("compress", [True, False])
def test_members_identical_to_numpy_savez(tmp_path: Path, compress: bool) -> None:
    arrays = chunk_arrays()
    path = tmp_path / "c.npz"
    write_npz(path, arrays, compress)
    ours, reference = members(path), members(numpy_npz(arrays, compress))
    assert ours.keys() == reference.keys()
    for name in reference:
        assert ours[name] == reference[name], name


def test_compressed_members_are_isal_deflate(tmp_path: Path) -> None:
    arrays = {"masses": planes(1, 5, 128), "stamp_ns": np.arange(3, dtype=np.int64)}
    path = tmp_path / "c.npz"
    write_npz(path, arrays, compress=True)
    npy = members(numpy_npz(arrays, compress=False))
    with zipfile.ZipFile(path) as archive:
        for info in archive.infolist():
            assert info.compress_type == zipfile.ZIP_DEFLATED
            raw = _raw_member(path, info)
            # standard raw deflate, readable with plain zlib
            assert zlib.decompressobj(-15).decompress(raw) == npy[info.filename]
            # and written by ISA-L at DEFLATE_LEVEL (header, then the data, as fed)
            header = _npy_header_length(npy[info.filename])
            deflater = isal_zlib.compressobj(DEFLATE_LEVEL, isal_zlib.DEFLATED, -15)
            expected = (deflater.compress(npy[info.filename][:header])
                        + deflater.compress(npy[info.filename][header:]) + deflater.flush())
            assert raw == expected, info.filename


def test_stored_members(tmp_path: Path) -> None:
    arrays = {"a": planes(1, 2, 32)}
    path = tmp_path / "s.npz"
    write_npz(path, arrays, compress=False)
    with zipfile.ZipFile(path) as archive:
        (info,) = archive.infolist()
    assert info.compress_type == zipfile.ZIP_STORED
    assert info.compress_size == info.file_size == len(members(numpy_npz(arrays, False))["a.npy"])


def test_large_member_spans_many_pieces_and_is_zip64(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """A member of 2.5 pieces plus a header; every local header carries the zip64 extra
    field (sizes 0xFFFFFFFF in the fixed part, real sizes in the extra) so that members past
    4 GiB need nothing else."""
    monkeypatch.setattr(npz, "_PIECE", 1 << 20)
    n = int(2.5 * npz._PIECE) + 7
    big = (np.arange(n, dtype=np.uint64) * 2654435761 % 251).astype(np.uint8)
    arrays = {"big": big, "small": np.arange(4, dtype=np.float64)}
    path = tmp_path / "z.npz"
    write_npz(path, arrays, compress=True)
    with np.load(path) as loaded:
        np.testing.assert_array_equal(loaded["big"], big)
    with zipfile.ZipFile(path) as archive:
        infos = archive.infolist()
    blob = path.read_bytes()
    for info in infos:
        fixed = struct.unpack("<4s2B4HL2L2H", blob[info.header_offset:info.header_offset + 30])
        signature, version = fixed[0], fixed[1]
        compress_size, file_size, name_len, extra_len = fixed[8:12]
        assert signature == b"PK\x03\x04"
        assert version >= 45                      # ZIP64 "version needed to extract"
        assert compress_size == file_size == 0xFFFFFFFF
        extra = blob[info.header_offset + 30 + name_len:][:extra_len]
        tag, size, real_file_size, real_compress_size = struct.unpack("<HHQQ", extra[:20])
        assert (tag, size) == (1, 16)
        assert (real_file_size, real_compress_size) == (info.file_size, info.compress_size)
    assert infos[0].file_size == len(members(numpy_npz({"big": big}, False))["big.npy"])


def test_failed_array_leaves_no_temporary_and_keeps_old_file(tmp_path: Path) -> None:
    path = tmp_path / "chunk.npz"
    path.write_bytes(b"old")
    arrays = {"ok": planes(1, 2, 32), "bad": np.array([object()], dtype=object)}
    with pytest.raises(ValueError):
        write_npz(path, arrays, compress=True)
    assert sorted(os.listdir(tmp_path)) == ["chunk.npz"]
    assert path.read_bytes() == b"old"


def test_failed_fsync_leaves_no_temporary(tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    def fail(fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(npz.os, "fsync", fail)
    with pytest.raises(OSError):
        write_npz(tmp_path / "chunk.npz", {"a": np.zeros(3)}, compress=True)
    assert os.listdir(tmp_path) == []


def test_member_writer_without_compressor_attribute_keeps_zlib(
        caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    """Should zipfile's member writer lose ``_compressor``, the member stays as zipfile
    makes it (zlib) and a warning says so."""
    monkeypatch.setattr(npz, "_warned", False)
    member = object()
    with caplog.at_level("WARNING", logger="evperc.output.npz"):
        npz._use_isal(member)
        npz._use_isal(member)
    assert [r.levelname for r in caplog.records] == ["WARNING"]
    assert not hasattr(member, "_compressor")


def _raw_member(path: Path, info: zipfile.ZipInfo) -> bytes:
    """The compressed bytes of a member, located from its local header."""
    blob = path.read_bytes()
    name_len, extra_len = struct.unpack("<2H", blob[info.header_offset + 26:][:4])
    start = info.header_offset + 30 + name_len + extra_len
    return blob[start:start + info.compress_size]


def _npy_header_length(npy: bytes) -> int:
    """Bytes of a version-1.0 ``.npy`` header (magic, version, length, dict)."""
    assert npy[:8] == b"\x93NUMPY\x01\x00"
    return 10 + struct.unpack("<H", npy[8:10])[0]


@pytest.mark.parametrize("compress", [True, False])
def test_views_are_written_without_a_whole_copy_and_read_back_equal(
        tmp_path: Path, compress: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """A chunk's used mass planes ``masses[:, lo:hi]`` (not contiguous) are written slice by
    slice: the bytes are np.save's, and no copy of the whole view is made."""
    masses = planes(3, 32, 600, seed=4)  # (3, 32, 600, 600) uint8, ~35 MB
    view = masses[:, 1:31]
    copied: list[int] = []
    real = np.ascontiguousarray

    def spy(a, *args, **kwargs):
        copied.append(np.asarray(a).nbytes)
        return real(a, *args, **kwargs)

    monkeypatch.setattr(npz.np, "ascontiguousarray", spy)
    write_npz(tmp_path / "v.npz", {"masses": view}, compress)
    assert max(copied, default=0) < view.nbytes // 30
    with np.load(tmp_path / "v.npz") as got:
        np.testing.assert_array_equal(got["masses"], view)
    buffer = io.BytesIO()
    np.save(buffer, view)
    with zipfile.ZipFile(tmp_path / "v.npz") as archive:
        assert archive.read("masses.npy") == buffer.getvalue()


def test_crcs_written_with_isal_are_zlibs(tmp_path: Path) -> None:
    """The member CRC-32s come from ISA-L: zipfile's own check (testzip re-reads every
    member with zlib's CRC-32) finds them right, and they equal zlib.crc32 of the .npy
    bytes that np.save writes."""
    arrays = {**chunk_arrays(), "big": planes(2, 3, 700, seed=9)}  # several pieces
    path = tmp_path / "c.npz"
    write_npz(path, arrays, compress=True)
    with zipfile.ZipFile(path) as archive:
        assert archive.testzip() is None
        for name, array in arrays.items():
            buffer = io.BytesIO()
            np.save(buffer, array)
            assert archive.getinfo(f"{name}.npy").CRC == zlib.crc32(buffer.getvalue())


def test_a_concatenated_member_is_its_parts_end_to_end(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """``Concatenated`` parts (a chunk's mass runs, one part per frame) are written as one
    1-D member, byte-identical to np.savez of the joined array, a part larger than a piece
    in several pieces."""
    monkeypatch.setattr(npz, "_PIECE", 1 << 16)
    rng = np.random.default_rng(3)
    parts = tuple(rng.integers(0, 256, n).astype(np.uint8) for n in (5, 0, 3 * npz._PIECE + 7))
    joined = np.concatenate(parts)
    write_npz(tmp_path / "c.npz", {"runs": npz.Concatenated(parts),
                                   "none": npz.Concatenated(())}, compress=True)
    np.savez(tmp_path / "ref.npz", runs=joined, none=np.zeros(0, np.uint8))
    with zipfile.ZipFile(tmp_path / "c.npz") as got, zipfile.ZipFile(tmp_path / "ref.npz") as ref:
        assert got.read("runs.npy") == ref.read("runs.npy")
        assert got.read("none.npy") == ref.read("none.npy")
    with pytest.raises(ValueError, match="1-D arrays of one dtype"):
        write_npz(tmp_path / "bad.npz", {"runs": npz.Concatenated(
            (np.zeros(2, np.uint8), np.zeros(2, np.int16)))}, compress=True)
    assert not (tmp_path / "bad.npz").exists()


def test_a_member_deflated_frame_by_frame_is_the_whole_array(tmp_path: Path) -> None:
    """DeflateStream: parts added one by one, the header (with the final shape) deflated last
    and put in front — one valid deflate stream whose member is byte-identical to
    np.savez's, with the right CRC-32 (zipfile checks it on reading)."""
    rng = np.random.default_rng(5)
    frames = [planes(1, 5, 60, seed=k)[0] for k in range(3)]
    stream = npz.DeflateStream(np.uint8)
    for frame in frames:
        stream.add(frame)
    write_npz(tmp_path / "s.npz", {"betp": stream.member((3, 5, 60, 60)),
                                   "other": rng.random(4)}, compress=True)
    np.savez(tmp_path / "ref.npz", betp=np.stack(frames))
    with zipfile.ZipFile(tmp_path / "s.npz") as got, zipfile.ZipFile(tmp_path / "ref.npz") as ref:
        assert got.testzip() is None
        assert got.read("betp.npy") == ref.read("betp.npy")
        assert got.getinfo("betp.npy").compress_size < got.getinfo("betp.npy").file_size
    with pytest.raises(ValueError, match="bytes added for a uint8 array of shape"):
        stream.member((4, 5, 60, 60))
    with pytest.raises(ValueError, match="float64 data for a uint8 member"):
        npz.DeflateStream(np.uint8).add(np.zeros(3))
    with pytest.raises(ValueError, match="deflated member in a stored archive"):
        write_npz(tmp_path / "x.npz", {"betp": stream.member((3, 5, 60, 60))}, compress=False)


@pytest.mark.parametrize("order", ["pieces only", "mixed", "own data after a piece"])
def test_pieces_deflated_apart_join_a_member_stream(tmp_path: Path, order: str) -> None:
    """DeflateStream.add_deflated: frames deflated on their own (deflate_piece, a held
    frame's layers) and frames the stream deflates itself, in any order, make the member
    np.savez writes (byte for byte once inflated; zipfile checks the CRC-32). Data the stream
    deflates after a piece must not refer back across it: its compressor starts anew."""
    frames = [planes(1, 5, 60, seed=k)[0] for k in range(5)]
    apart = {"pieces only": [True] * 5, "mixed": [True, False, True, True, False],
             "own data after a piece": [False, True, False, False, True]}[order]
    stream = npz.DeflateStream(np.uint8)
    for frame, piece in zip(frames, apart, strict=True):
        if piece:
            stream.add_deflated(npz.deflate_piece(frame))
        else:
            stream.add(frame)
    write_npz(tmp_path / "s.npz", {"betp": stream.member((5, 5, 60, 60))}, compress=True)
    np.savez(tmp_path / "ref.npz", betp=np.stack(frames))
    with zipfile.ZipFile(tmp_path / "s.npz") as got, zipfile.ZipFile(tmp_path / "ref.npz") as ref:
        assert got.testzip() is None
        assert got.read("betp.npy") == ref.read("betp.npy")
    piece = npz.deflate_piece(frames[0])
    # a piece ends on a byte boundary, not with a final block: inflated as far as it goes
    assert zlib.decompressobj(-15).decompress(b"".join(piece.parts)) == frames[0].tobytes()
    assert piece.crc == zlib.crc32(frames[0].tobytes()) and piece.size == frames[0].size
    with pytest.raises(ValueError, match="float64 data for a uint8 member"):
        npz.DeflateStream(np.uint8).add_deflated(npz.deflate_piece(np.zeros(3)))
