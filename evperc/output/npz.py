"""Writing NPZ files (docs/output-format.md: ZIP archives of ``.npy`` members, deflated).

The members are deflated by ISA-L (``isal.isal_zlib``) instead of zlib. The stream is
standard raw deflate (RFC 1951), so ``np.load``/``zipfile`` read the files with plain
zlib; only the writer needs ``isal``.

Measured on the uint8 planes of workload (a) (issue 7: 42 planes of 400×400 a frame,
6.56 MB; chunks 3–8 of ``sim-hdl64-10s`` with ``window200.toml``, 54 frames), one core,
raw deflate of the members, best of 3 (``benchmarks/bench_npz.py`` re-measures the whole
``write_npz``):

=================  ==========  =========  ==========
compressor         ms / frame  MB/s       kB / frame
=================  ==========  =========  ==========
zlib 1.2.13, 1     8.56        766        238.5
isal 1.9.1, 0      1.35        4,864      268.2
isal 1.9.1, 1      1.42        4,626      216.1
isal 1.9.1, 2      1.45        4,531      215.8
isal 1.9.1, 3      8.10        810        229.1
zlib-ng 1.1.0, 1   2.63        2,498      284.4
zlib-ng 1.1.0, 2   3.96        1,658      200.9
libdeflate 0.9, 1  15.77       416        186.8
libdeflate 0.9, 2  9.06        724        184.5
=================  ==========  =========  ==========

The whole ``write_npz`` (zipfile, CRC-32, file, fsync) on all 99 frames of that run,
``benchmarks/bench_npz.py``, best of 3: 2.59 ms and 203 kB per frame, against 10.13 ms and
225 kB for the former zipfile + zlib level 1 writer measured in the same run (the run's
writer thread, which also selects the used mass planes and writes the checkpoint and
the manifest, took 17–25 ms per frame with zlib and 9–15 ms with this: shared 2 cores).

ISA-L level 1 is 6× faster than zlib level 1 and 10 % smaller; level 2 is no better here,
level 0 is barely faster and 24 % larger. zlib-ng is 1.9–2.8× slower; libdeflate has no
streaming API (whole members in memory) and is slower on these planes. ``isal`` ships
wheels for CPython 3.11 on Linux x86_64/aarch64 and macOS x86_64/arm64, and releases the
GIL while compressing (the run's writer thread overlaps the main thread).

How ISA-L gets into ``zipfile``: ``ZipFile.open(name, "w")`` returns a member writer that
holds its compressor in ``_compressor`` and its running CRC-32 and sizes in ``_crc``,
``_file_size``, ``_compress_size`` (CPython since 3.6); its compressor is replaced by an
ISA-L one and its ``write`` (eight lines: count, CRC, compress, write) by the same steps
with ISA-L's CRC-32 (identical values, 0.22 instead of 0.94 ms per frame of (a); on two
shared cores it raised the whole run of (a) by 9–27 % in paired runs). Only that one
member object changes (no global monkey-patching, other threads' ``zipfile`` use is
untouched), and ``zipfile`` keeps doing everything else: headers, data descriptors, zip64,
the central directory, closing. The alternative, a hand-written ZIP writer, would be ~100
lines of format code to maintain. Should a future Python change these attributes, members
are written by plain ``zipfile`` + zlib (a warning is logged, the file is still valid) and
``tests/output/test_npz.py`` fails.

The array bytes are handed to the member as views in pieces of ``_PIECE`` bytes
without the copy ``np.lib.format.write_array`` makes (``tobytes`` of 16 MiB buffers). Alone
the piece size is not critical (64 KiB to whole arrays within 2 %); in a run, each piece
is one release and re-acquisition of the GIL by the writer thread while the two other
threads want it, so pieces are 16 MiB (a frame's members whole): 4 alternating pairs of
runs of (a) on the 300-scan log, median 193.7 against 188.7 frames/s with 1 MiB pieces
(+2.6 %, within the host's noise, but in 3 pairs of 4). Member contents are
byte-identical to ``np.savez``'s (``.npy`` format 1.0 headers).
"""

from __future__ import annotations

import io
import logging
import os
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from isal import isal_zlib

log = logging.getLogger(__name__)

#: ISA-L deflate level (0–3): 1 is as fast as 0 and ~20 % smaller on the output planes
DEFLATE_LEVEL = 1
#: bytes of an array handed to the member writer at a time
_PIECE = 1 << 24

_warned = False


@dataclass(frozen=True)
class Concatenated:
    """A 1-D member made of ``parts`` (1-D arrays of one dtype) end to end, written part by
    part without joining them in memory (a chunk's mass runs, one part per frame)."""

    parts: tuple[np.ndarray, ...]

    @property
    def dtype(self) -> np.dtype:
        return self.parts[0].dtype if self.parts else np.dtype(np.uint8)


@dataclass(frozen=True)
class DeflatedMember:
    """A member already deflated (:class:`DeflateStream`): its raw deflate stream in parts,
    the CRC-32 and the size of its uncompressed bytes (``.npy`` header and data)."""

    parts: tuple[bytes, ...]
    crc: int
    size: int


@dataclass(frozen=True)
class DeflatedPiece:
    """An array's bytes deflated on their own (:func:`deflate_piece`), ended by a sync flush,
    for :meth:`DeflateStream.add_deflated`: the raw deflate blocks, the CRC-32 and the size
    of the bytes, their dtype."""

    parts: tuple[bytes, ...]
    crc: int
    size: int
    dtype: np.dtype


def deflate_piece(array: np.ndarray) -> DeflatedPiece:
    """``array``'s bytes (C order) as a :class:`DeflatedPiece`: deflated now, appended to a
    member's stream later (a held frame's layers, while they are in the cache)."""
    compressor = isal_zlib.compressobj(DEFLATE_LEVEL, isal_zlib.DEFLATED, -15)
    parts: list[bytes] = []
    crc, size = _deflate_into(compressor, array, parts, 0)
    parts.append(compressor.flush(isal_zlib.Z_SYNC_FLUSH))
    return DeflatedPiece(tuple(parts), crc, size, array.dtype)


def _deflate_into(compressor: Any, array: np.ndarray, parts: list[bytes], crc: int
                  ) -> tuple[int, int]:
    """Feed ``array``'s bytes to ``compressor`` piece by piece, its output onto ``parts``;
    the CRC-32 continued from ``crc`` and the bytes fed."""
    size = 0
    for part in _contiguous_parts(array):
        data = part.reshape(-1).view(np.uint8)
        for start in range(0, data.size, _PIECE):
            piece = data[start:start + _PIECE]
            crc = isal_zlib.crc32(piece, crc)
            packed = compressor.compress(piece)
            if packed:
                parts.append(packed)
        size += data.size
    return crc, size


class _Flushed:
    """Stands for a member writer's compressor once the member's stream is complete."""

    @staticmethod
    def flush() -> bytes:
        return b""


class DeflateStream:
    """A ``.npy`` member deflated piece by piece as its data arrives — a chunk's layers frame
    by frame, while the frame is still in the cache, instead of all at once when the chunk
    is full. The header, which states the final shape, is deflated last and put in front:
    a deflate stream ended by a sync flush followed by another deflate stream is one valid
    stream (RFC 1951 blocks in sequence), and ISA-L combines the CRC-32s. The same holds
    for pieces deflated apart (:meth:`add_deflated`)."""

    def __init__(self, dtype: np.dtype | type) -> None:
        self.dtype = np.dtype(dtype)
        self._compressor = isal_zlib.compressobj(DEFLATE_LEVEL, isal_zlib.DEFLATED, -15)
        self._parts: list[bytes] = []
        self._crc = 0
        self._size = 0
        self._fed = False  # the compressor holds data not yet flushed out
        self._end: bytes | None = None  # the stream's final flush, once member() ran

    def add(self, array: np.ndarray) -> None:
        """Append the bytes of ``array`` (C order, of this stream's dtype)."""
        if self._end is not None:
            raise ValueError("the member is complete")
        if array.dtype != self.dtype:
            raise ValueError(f"{array.dtype} data for a {self.dtype} member")
        self._crc, size = _deflate_into(self._compressor, array, self._parts, self._crc)
        self._size += size
        self._fed = self._fed or size > 0

    def add_deflated(self, piece: DeflatedPiece) -> None:
        """Append bytes deflated apart (:func:`deflate_piece`): their blocks follow this
        stream's, flushed to a byte boundary first if it holds data of its own; data added
        after them starts a new compressor (the old one's back-references would reach
        across the piece)."""
        if self._end is not None:
            raise ValueError("the member is complete")
        if piece.dtype != self.dtype:
            raise ValueError(f"{piece.dtype} data for a {self.dtype} member")
        if self._fed:
            self._parts.append(self._compressor.flush(isal_zlib.Z_SYNC_FLUSH))
            self._compressor = isal_zlib.compressobj(DEFLATE_LEVEL, isal_zlib.DEFLATED, -15)
            self._fed = False
        self._parts.extend(piece.parts)
        self._crc = isal_zlib.crc32_combine(self._crc, piece.crc, piece.size)
        self._size += piece.size

    def member(self, shape: tuple[int, ...]) -> DeflatedMember:
        """The complete member: an array of ``shape`` (its data all added); the stream
        takes no more data after it."""
        if int(np.prod(shape, dtype=np.int64)) * self.dtype.itemsize != self._size:
            raise ValueError(f"{self._size} bytes added for a {self.dtype} array of shape "
                             f"{shape}")
        header_io = io.BytesIO()
        np.lib.format.write_array_header_1_0(header_io, {
            "descr": np.lib.format.dtype_to_descr(self.dtype), "fortran_order": False,
            "shape": tuple(shape)})
        header = header_io.getvalue()
        head = isal_zlib.compressobj(DEFLATE_LEVEL, isal_zlib.DEFLATED, -15)
        front = head.compress(header) + head.flush(isal_zlib.Z_SYNC_FLUSH)
        crc = isal_zlib.crc32_combine(isal_zlib.crc32(header), self._crc, self._size)
        if self._end is None:
            self._end = self._compressor.flush()
        return DeflatedMember((front, *self._parts, self._end), crc, len(header) + self._size)


def member_writer_supported() -> bool:
    """Whether ``zipfile``'s member writer has the state that :func:`_use_isal` and
    :class:`DeflatedMember` rely on (CPython 3.6 to 3.13)."""
    with zipfile.ZipFile(io.BytesIO(), "w", compression=zipfile.ZIP_DEFLATED) as archive:
        with archive.open("probe", "w") as member:
            return all(hasattr(member, name) for name in _MEMBER_STATE)


def write_npz(path: Path, arrays: dict[str, np.ndarray | Concatenated | DeflatedMember],
              compress: bool) -> None:
    """Write ``arrays`` as the NPZ ``path`` (members ``NAME.npy``), deflated at
    :data:`DEFLATE_LEVEL` if ``compress`` else stored.

    Atomic: written to ``.NAME.tmp`` beside ``path``, fsynced, then renamed; the temporary
    file is removed if anything fails. Members are always zip64 (no 4 GiB limit).
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    mode = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    try:
        with tmp.open("wb") as f:
            with zipfile.ZipFile(f, "w", compression=mode) as archive:
                for name, array in arrays.items():
                    with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                        if isinstance(array, DeflatedMember):
                            if not compress:
                                raise ValueError(f"{name}: a deflated member in a stored "
                                                 "archive")
                            _write_deflated(member, array)
                        else:
                            if compress:
                                _use_isal(member)
                            _write_npy(member, array)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


#: the member writer's state that :func:`_use_isal` relies on (CPython 3.6 to 3.13)
_MEMBER_STATE = ("_compressor", "_file_size", "_crc", "_compress_size", "_fileobj")


def _use_isal(member: object) -> None:
    """Make a ``zipfile`` member writer deflate and checksum with ISA-L (see the module
    docstring)."""
    global _warned
    if not all(hasattr(member, name) for name in _MEMBER_STATE):
        if not _warned:
            log.warning("zipfile's member writer has changed: NPZ members are deflated with "
                        "zlib (slower)")
            _warned = True
        return
    member._compressor = isal_zlib.compressobj(DEFLATE_LEVEL, isal_zlib.DEFLATED, -15)

    def write(data: object) -> int:
        """``zipfile._ZipWriteFile.write`` with ISA-L's CRC-32 (the same value, ~4× faster
        than zlib's: 0.22 against 0.94 ms per frame of workload (a))."""
        view = memoryview(data).cast("B")
        member._file_size += view.nbytes
        member._crc = isal_zlib.crc32(view, member._crc)
        packed = member._compressor.compress(view)
        member._compress_size += len(packed)
        member._fileobj.write(packed)
        return view.nbytes

    member.write = write


def _write_deflated(member: object, deflated: DeflatedMember) -> None:
    """Put an already deflated stream into a ``zipfile`` member writer, with its CRC-32
    and sizes (which ``zipfile`` writes into the headers when the member is closed)."""
    member._compressor = _Flushed()
    for part in deflated.parts:
        member._fileobj.write(part)
        member._compress_size += len(part)
    member._file_size = deflated.size
    member._crc = deflated.crc


def _write_npy(fp: object, array: np.ndarray | Concatenated) -> None:
    """``array`` in ``.npy`` format 1.0 to the binary stream ``fp`` (what ``np.save``
    writes), its data as views without copying when contiguous."""
    if isinstance(array, Concatenated):
        if any(p.ndim != 1 or p.dtype != array.dtype for p in array.parts):
            raise ValueError("Concatenated parts must be 1-D arrays of one dtype")
        size = sum(p.size for p in array.parts)
        np.lib.format.write_array_header_1_0(fp, {"descr": np.lib.format.dtype_to_descr(
            array.dtype), "fortran_order": False, "shape": (size,)})
        for part in array.parts:
            _write_data(fp, part)
        return
    array = np.asarray(array)
    if array.dtype.hasobject:
        raise ValueError("object arrays cannot be written without pickling")
    header = np.lib.format.header_data_from_array_1_0(array)
    np.lib.format.write_array_header_1_0(fp, header)
    if header["fortran_order"]:
        array = array.T
    _write_data(fp, array)


def _write_data(fp: object, array: np.ndarray) -> None:
    """The bytes of ``array`` in C order, as views in pieces of :data:`_PIECE` bytes."""
    for part in _contiguous_parts(array):
        data = part.reshape(-1).view(np.uint8)
        for start in range(0, data.size, _PIECE):
            fp.write(data[start:start + _PIECE])


def _contiguous_parts(array: np.ndarray) -> Iterator[np.ndarray]:
    """C-contiguous sub-arrays whose bytes, in order, are ``array``'s in C order: the array
    itself, else its slices along the first axis (recursively; e.g. a chunk's used mass
    planes, ``masses[:, lo:hi]``, without a copy of the whole), else copied pieces."""
    if array.flags.c_contiguous:
        yield array
    elif array.ndim > 1 and array[0].nbytes >= _PIECE // 16:
        for sub in array:
            yield from _contiguous_parts(sub)
    else:
        yield np.ascontiguousarray(array)
