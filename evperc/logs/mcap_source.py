"""Opening an MCAP file and streaming its messages, indexed or not, intact or truncated.

An indexed file (summary with chunk indexes) is read through mcap's seeking reader, which
yields messages in log-time order chunk by chunk (memory bounded by the chunks overlapping in
time). A file without an index, or one whose footer is missing (truncated: a recorder killed
mid-drive), is read once at open with a sequential reader to learn its channels, counts and
time span, and the offset, time span and channels of every complete chunk: an index of its
own, so that its messages too come in log-time order, chunk by chunk, as from an indexed file
(a writer may put all poses in one early chunk and the scans in later ones; read in file
order, the scans would find the poses around them already passed). Only a file with
messages outside chunks is read in file order. Wherever the data stops being valid (short
read, bad CRC, broken record) the stream ends there, and ONE warning per file says where and
why. Messages are decoded per channel, by its message encoding: ROS 2 CDR
(mcap-ros2-support), ROS 1 (``ros1`` with ``ros1msg`` schemas, as ``mcap convert drive.bag
drive.mcap`` writes them; mcap-ros1-support), protobuf (mcap-protobuf-support) and JSON. One
file may mix encodings, so the encoding is a property of the channel, not of the source
(docs/architecture.md, "Log sources").
"""

from __future__ import annotations

import base64
import heapq
import io
import json
import logging
import struct
import sys
import threading
import types
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mcap.stream_reader
import zstandard
from isal import isal_zlib
from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile, UnsupportedCompressionError
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.summary import Summary

from evperc.errors import LogError

log = logging.getLogger(__name__)

MAGIC = b"\x89MCAP0\r\n"


def _use_isal_crc() -> bool:
    """mcap checks each chunk's CRC-32 with ``zlib.crc32``, found as a module global of
    ``mcap.stream_reader`` (0.27 ms per 1.9 MB chunk of an hdl64 scan, in the decode thread
    that bounds a run's speed); ISA-L computes the same CRC-32 ~9× faster. Hand mcap a zlib
    whose ``crc32`` is ISA-L's; False (mcap's own kept) if mcap no longer reads it there."""
    if getattr(getattr(mcap.stream_reader, "zlib", None), "crc32", None) is not zlib.crc32:
        log.debug("mcap.stream_reader no longer uses zlib.crc32: chunk CRCs stay zlib's")
        return False
    mcap.stream_reader.zlib = types.SimpleNamespace(**{**vars(zlib), "crc32": isal_zlib.crc32})
    return True


_use_isal_crc()

#: a read of a decompressed chunk this long or longer is a view of the chunk, not a copy
VIEW_MIN_BYTES = 1 << 16


class _ChunkBytes(io.BytesIO):
    """The ``BytesIO`` mcap wraps a decompressed chunk in, whose reads of
    :data:`VIEW_MIN_BYTES` or more return a ``memoryview`` of the chunk instead of a copy:
    a message's payload (an hdl64 scan's 1.9 MB point cloud) is then read where it lies.
    Shorter reads (record headers, schema and channel fields) stay ``bytes``, as mcap's
    parsers expect. Written to (mcap does not), it is a plain ``BytesIO``."""

    def __init__(self, initial_bytes: bytes = b"") -> None:
        super().__init__(initial_bytes)
        self._view: memoryview | None = (memoryview(initial_bytes)
                                         if isinstance(initial_bytes, bytes) else None)

    def read(self, size: int | None = -1) -> bytes | memoryview:  # type: ignore[override]
        if self._view is None or size is None or size < VIEW_MIN_BYTES:
            return super().read(size)
        start = self.tell()
        data = self._view[start:start + size]
        self.seek(start + len(data))
        return data

    def write(self, data: Any) -> int:  # type: ignore[override]
        self._view = None
        return super().write(data)


#: set in a thread while :meth:`McapSource.iter_raw` reads: mcap's chunk streams are then
#: :class:`_ChunkBytes` (anyone else's use of mcap in the process gets its ``BytesIO``)
_views = threading.local()


def _chunk_stream(initial_bytes: bytes = b"") -> io.BytesIO:
    """What ``mcap.stream_reader`` calls for ``BytesIO``: :class:`_ChunkBytes` within
    :meth:`McapSource.iter_raw`, a plain ``BytesIO`` anywhere else."""
    if getattr(_views, "on", False):
        if isinstance(initial_bytes, memoryview):  # a chunk in a thread's buffer
            return _ChunkView(initial_bytes)  # type: ignore[return-value]
        return _ChunkBytes(initial_bytes)
    return io.BytesIO(initial_bytes)


def _read_chunks_without_copies() -> bool:
    """mcap reads a message out of its decompressed chunk with ``BytesIO.read``, a copy of
    the payload (0.35 ms of the decode thread a scan of workload (a), 8 % of its reading:
    docs/performance.md § "Scans read where they lie"); hand ``get_chunk_data_stream`` a
    ``BytesIO`` whose long reads are views (:func:`_chunk_stream`), for evperc's own reads
    only. False (mcap's own kept) if mcap no longer makes its chunk streams there."""
    code = mcap.stream_reader.get_chunk_data_stream.__code__
    if mcap.stream_reader.BytesIO is not io.BytesIO or "BytesIO" not in code.co_names:
        log.debug("mcap.stream_reader no longer wraps chunks in BytesIO: payloads are copied")
        return False
    mcap.stream_reader.BytesIO = _chunk_stream
    return True


_read_chunks_without_copies()


#: chunks decompressed by each reading thread into buffers it keeps (a fresh 1.9 MB
#: ``bytes`` per hdl64 scan costs the decode thread the first touch of its pages)
CHUNK_BUFFERS = 4
#: a chunk larger than this is decompressed into a ``bytes`` of its own, as mcap does
CHUNK_BUFFER_MAX_BYTES = 32 << 20


class _ChunkView:
    """The stream mcap parses a decompressed chunk from when the chunk lies in one of
    :class:`_ChunkBuffers`' buffers: reads as ``io.BytesIO``'s, those of
    :data:`VIEW_MIN_BYTES` or more a ``memoryview`` of the buffer, shorter ones ``bytes``."""

    __slots__ = ("_view", "_pos")

    def __init__(self, view: memoryview) -> None:
        self._view = view
        self._pos = 0

    def read(self, size: int | None = -1) -> bytes | memoryview:
        start = self._pos
        long_read = size is not None and size >= VIEW_MIN_BYTES
        end = len(self._view) if size is None or size < 0 else start + size
        self._pos = max(start, min(end, len(self._view)))
        data = self._view[start:self._pos]
        return data if long_read else data.tobytes()

    def tell(self) -> int:
        return self._pos

    def seek(self, pos: int, whence: int = 0) -> int:
        base = (0, self._pos, len(self._view))[whence]
        self._pos = max(base + pos, 0)
        return self._pos


def _viewed_by_none(buffers: list[bytearray], i: int) -> bool:
    """No view of ``buffers[i]`` is alive: its only references are the list's and the
    argument's (a memoryview of a bytearray, and every slice of it, hold one more)."""
    return sys.getrefcount(buffers[i]) <= 2


def _read_into(view: memoryview, readinto: Callable[[memoryview], int | None]) -> int:
    """The bytes ``readinto`` put into ``view``, called until it is full or gives none."""
    done = 0
    while done < len(view):
        n = readinto(view[done:])
        if not n:
            break
        done += n
    return done


def _refcounts_tell_views() -> bool:
    """:func:`_viewed_by_none` tells a free buffer from a viewed one in this Python (a
    probe at import; where it cannot, no buffer is kept and mcap reads as it does)."""
    probe = [bytearray(1)]
    free = _viewed_by_none(probe, 0)
    view = memoryview(probe[0])[:1]
    viewed = not _viewed_by_none(probe, 0)
    del view
    return free and viewed and _viewed_by_none(probe, 0)


_KEEP_BUFFERS = _refcounts_tell_views()


class _ChunkBuffers(threading.local):
    """The buffers a reading thread keeps — the chunks it decompresses (with its zstd
    decompressor), or the chunk records it reads from the file — each reused once no view
    of what it holds is left (a message's payload, a point cloud read where it lies); while
    every buffer is viewed, a new one is made, up to :data:`CHUNK_BUFFERS`, and past that
    the caller makes a ``bytes`` of its own."""

    def __init__(self) -> None:
        self.dctx: zstandard.ZstdDecompressor | None = None  # made by the first decompress
        self.buffers: list[bytearray] = []

    def take(self, size: int) -> bytearray | None:
        for i in range(len(self.buffers)):
            if _viewed_by_none(self.buffers, i):
                if len(self.buffers[i]) < size:
                    self.buffers[i] = bytearray(size)
                return self.buffers[i]
        if len(self.buffers) < CHUNK_BUFFERS:
            self.buffers.append(bytearray(size))
            return self.buffers[-1]
        return None

    def decompress(self, data: bytes, size: int) -> memoryview | None:
        """``data`` (a zstd chunk of ``size`` bytes decompressed) in a buffer of this
        thread's; None where no buffer is free."""
        buffer = self.take(size)
        if buffer is None:
            return None
        if self.dctx is None:
            self.dctx = zstandard.ZstdDecompressor()
        view = memoryview(buffer)[:size]
        reader = self.dctx.stream_reader(data, read_across_frames=True)
        done = _read_into(view, reader.readinto)
        if done != size or reader.read(1):
            raise zstandard.ZstdError(f"a chunk decompressed to {done} or more bytes, "
                                      f"its record says {size}")
        return view


_chunk_buffers = _ChunkBuffers()
#: the compressed chunks' records, read from the file (:class:`_RecordFile`)
_record_buffers = _ChunkBuffers()


class _RecordFile:
    """The log file as :meth:`McapSource.iter_raw` hands it to mcap's readers: a read of
    :data:`VIEW_MIN_BYTES` or more (a chunk's compressed data) goes into a buffer the
    reading thread keeps (:class:`_ChunkBuffers`, as the decompressed chunks do; a fresh
    1.2 MB ``bytes`` a scan otherwise) and comes back as a ``memoryview`` of it, as long as
    the file gave (short at its end, as ``read`` is); any other call is the file's."""

    def __init__(self, file: Any) -> None:
        self._file = file

    def read(self, size: int | None = -1) -> bytes | memoryview:
        if (not _KEEP_BUFFERS or size is None or size < VIEW_MIN_BYTES
                or size > CHUNK_BUFFER_MAX_BYTES):
            return self._file.read(size)
        buffer = _record_buffers.take(size)
        if buffer is None:
            return self._file.read(size)
        view = memoryview(buffer)[:size]
        done = _read_into(view, self._file.readinto)
        return view[:done] if done else b""

    def __getattr__(self, name: str) -> Any:
        return getattr(self._file, name)


def _decompress(data: bytes, max_output_size: int = 0) -> bytes | memoryview:
    """``zstandard.decompress`` as mcap calls it, but within :meth:`McapSource.iter_raw`
    (whose chunk streams are :class:`_ChunkView` for a buffer) into a buffer of the reading
    thread's."""
    if getattr(_views, "on", False) and 0 < max_output_size <= CHUNK_BUFFER_MAX_BYTES:
        view = _chunk_buffers.decompress(data, max_output_size)
        if view is not None:
            return view
    return zstandard.decompress(data, max_output_size)


def _decompress_into_buffers() -> bool:
    """Hand mcap a ``zstandard`` whose ``decompress`` fills a buffer kept by the reading
    thread (:func:`_decompress`); False (mcap's own kept) if mcap no longer calls
    ``zstandard.decompress`` in ``get_chunk_data_stream``, or this Python's reference
    counts do not tell a viewed buffer (:func:`_refcounts_tell_views`)."""
    code = mcap.stream_reader.get_chunk_data_stream.__code__
    if (getattr(mcap.stream_reader, "zstandard", None) is not zstandard
            or "zstandard" not in code.co_names or "decompress" not in code.co_names
            or mcap.stream_reader.BytesIO is not _chunk_stream):
        log.debug("mcap.stream_reader no longer calls zstandard.decompress: chunks are "
                  "decompressed by mcap")
        return False
    if not _KEEP_BUFFERS:
        return False
    mcap.stream_reader.zstandard = types.SimpleNamespace(
        **{**{k: getattr(zstandard, k) for k in dir(zstandard) if not k.startswith("__")},
           "decompress": _decompress})
    return True


_decompress_into_buffers()


@dataclass
class TopicInfo:
    """One topic of the log: its schema name, encodings and message count."""

    topic: str
    schema: str
    schema_encoding: str
    message_encoding: str
    messages: int = 0


@dataclass(frozen=True)
class ChunkSpan:
    """A complete, valid chunk of an unindexed file, found by the sequential read at open."""

    offset: int           # file offset of the chunk record (its opcode byte)
    start_ns: int         # log time of its first and last message (inclusive)
    end_ns: int
    channels: frozenset[int]  # ids of the channels it has messages of


@dataclass
class RawMessage:
    """A message as read from the file, not yet decoded."""

    topic: str
    schema: Schema | None
    channel: Channel
    message: Message

    @property
    def log_time(self) -> int:
        """Log time of the message (ns)."""
        return self.message.log_time


class _SummaryReader(SeekingReader):
    """mcap's seeking reader given the file's summary, read once at open: each reader reads
    and parses it again otherwise (its chunk and message indexes: ~30 ms on a 3,000-chunk
    file, at each of the time-range reads of a long log's geo-reference)."""

    def __init__(self, stream: Any, summary: Summary) -> None:
        super().__init__(stream, validate_crcs=True)
        self._known = summary

    def get_summary(self) -> Summary:
        return self._known


@dataclass
class McapSource:
    """An MCAP file opened for reading; see the module docstring.

    Attributes: ``path``, ``indexed`` (summary with chunk index present), ``topics``
    (topic name -> :class:`TopicInfo`), ``start_ns`` / ``end_ns`` (log time of the first and
    last message, ``end_ns`` inclusive), ``stop_reason`` (``None`` when the whole file is valid).
    """

    path: Path
    kind: str = "mcap"
    indexed: bool = False
    #: a time-range read goes through the chunk index (an indexed file)
    seeks: bool = False
    topics: dict[str, TopicInfo] = field(default_factory=dict)
    start_ns: int | None = None
    end_ns: int | None = None
    stop_reason: str | None = None
    #: an unindexed file's complete chunks (None: an indexed file, or messages outside chunks)
    chunks: list[ChunkSpan] | None = None
    _schemas: dict[int, Schema] = field(default_factory=dict)
    _channels: dict[int, Channel] = field(default_factory=dict)
    _warned: bool = False
    _decoders: dict[int, Callable[[bytes], Any]] = field(default_factory=dict)
    #: an indexed file's summary, read at open
    _summary: Summary | None = None

    @classmethod
    def claims(cls, path: Path, head: bytes) -> bool:
        """An MCAP file starts with the MCAP magic bytes."""
        return head.startswith(MAGIC)

    @classmethod
    def open(cls, path: str | Path) -> McapSource:
        """Check that ``path`` is a readable MCAP file and learn its topics; LogError if not."""
        path = Path(path)
        try:
            with path.open("rb") as f:
                magic = f.read(len(MAGIC))
        except FileNotFoundError as err:
            raise LogError(f"{path}: log file not found") from err
        except IsADirectoryError as err:
            raise LogError(f"{path}: is a directory; give the .mcap file inside it") from err
        except OSError as err:
            raise LogError(f"{path}: cannot read log ({err.strerror})") from err
        if magic != MAGIC:
            raise LogError(f"{path}: not an MCAP file (it does not start with the MCAP magic "
                           "bytes)")
        source = cls(path=path)
        if not source._read_summary():
            source._scan_sequentially()
        return source

    # --- opening -----------------------------------------------------------------------

    def _read_summary(self) -> bool:
        """Fill topics and time span from the summary; False if there is no usable index."""
        try:
            with self.path.open("rb") as f:
                summary = SeekingReader(f).get_summary()
        except Exception as err:  # any failure means "no usable footer"
            log.debug("%s: no readable summary (%s)", self.path, err)
            return False
        if summary is None or not summary.chunk_indexes:
            return False
        self.indexed = self.seeks = True
        self._summary = summary
        for channel in summary.channels.values():
            self._add_channel(channel, summary.schemas.get(channel.schema_id))
        stats = summary.statistics
        if stats is not None and stats.message_count > 0:
            for channel_id, count in stats.channel_message_counts.items():
                channel = summary.channels.get(channel_id)
                if channel is not None:
                    self.topics[channel.topic].messages += count
            self.start_ns, self.end_ns = stats.message_start_time, stats.message_end_time
        else:
            self.start_ns = min(c.message_start_time for c in summary.chunk_indexes)
            self.end_ns = max(c.message_end_time for c in summary.chunk_indexes)
            for raw in self.iter_raw():
                self.topics[raw.topic].messages += 1
        return True

    def _scan_sequentially(self) -> None:
        """One pass over an unindexed or truncated file: channels, counts, time span, and
        the complete chunks (:class:`ChunkSpan`) that :meth:`iter_raw` then reads in
        log-time order."""
        start, end = None, None
        chunks: list[ChunkSpan] | None = []
        count = 0
        with self.path.open("rb") as f:
            records = StreamReader(f, validate_crcs=True, emit_chunks=True).records
            while True:
                offset = f.tell()  # end of the last record read completely
                try:
                    record = next(records)
                    inner = (breakup_chunk(record, validate_crc=True)
                             if isinstance(record, Chunk) else [record])
                except StopIteration:
                    break
                except Exception as err:  # a broken file ends the data there
                    self._stopped(offset, count, err)
                    break
                channels = set()
                for item in inner:
                    if isinstance(item, Schema):
                        self._schemas[item.id] = item
                    elif isinstance(item, Channel):
                        self._channels[item.id] = item
                        self._add_channel(item, self._schemas.get(item.schema_id))
                    elif isinstance(item, Message):
                        channel = self._channels.get(item.channel_id)
                        if channel is None:
                            continue
                        count += 1
                        channels.add(item.channel_id)
                        self.topics[channel.topic].messages += 1
                        t = item.log_time
                        start = t if start is None else min(start, t)
                        end = t if end is None else max(end, t)
                        if not isinstance(record, Chunk):
                            chunks = None  # a message outside chunks: file order
                if isinstance(record, Chunk) and channels and chunks is not None:
                    chunks.append(ChunkSpan(offset, record.message_start_time,
                                            record.message_end_time, frozenset(channels)))
        self.start_ns, self.end_ns = start, end
        self.chunks = chunks
        if self.stop_reason is None:
            log.info("%s: no index; reading it sequentially (once, to index its chunks)", self.path)

    def _add_channel(self, channel: Channel, schema: Schema | None) -> None:
        if channel.topic not in self.topics:
            self.topics[channel.topic] = TopicInfo(
                topic=channel.topic, schema=schema.name if schema else "",
                schema_encoding=schema.encoding if schema else "",
                message_encoding=channel.message_encoding)

    # --- reading -----------------------------------------------------------------------

    def iter_raw(self, topics: Iterable[str] | None = None, start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[RawMessage]:
        """Messages of ``topics`` with log time in [start_ns, end_ns), undecoded.

        Log-time order for an indexed file, file order otherwise. Stops quietly at the end of
        the valid data after warning once (per file) where and why it stopped.
        """
        wanted = None if topics is None else set(topics)
        with self.path.open("rb") as f:
            if self.indexed:
                reader = _SummaryReader(_RecordFile(f), self._summary)
                iterator = reader.iter_messages(topics=wanted, starting_at=start_ns,
                                                ending_before=end_ns, log_time_order=True)
            elif self.chunks is not None:
                iterator = self._iter_chunks(f, wanted, start_ns, end_ns)
            else:
                iterator = self._iter_stream(f, wanted, start_ns, end_ns)
            count = 0
            while True:
                offset = f.tell()  # end of the last record read completely
                _views.on = True
                try:
                    schema, channel, message = next(iterator)
                except StopIteration:
                    return
                except UnsupportedCompressionError as err:
                    name = str(err).rsplit(" ", 1)[-1]
                    raise LogError(f"{self.path}: its chunks are {name}-compressed; install the "
                                   f"Python package '{name}' to read it") from err
                except Exception as err:  # a broken file ends the stream
                    self._stopped(offset, count, err)
                    return
                finally:
                    _views.on = False
                count += 1
                yield RawMessage(channel.topic, schema, channel, message)

    def _iter_chunks(self, f: Any, wanted: set[str] | None, start_ns: int | None,
                     end_ns: int | None) -> Iterator[tuple[Schema | None, Channel, Message]]:
        """The messages of the chunks found at open, in log-time order (ties: file order):
        a heap of chunks by first log time and of their decoded messages, as mcap's seeking
        reader does with a summary's chunk indexes."""
        ids = None if wanted is None else {i for i, c in self._channels.items()
                                           if c.topic in wanted}
        heap: list[tuple[int, int, int, Any]] = [
            (c.start_ns, c.offset, -1, c) for c in self.chunks or []
            if (ids is None or c.channels & ids)
            and (start_ns is None or c.end_ns >= start_ns)
            and (end_ns is None or c.start_ns < end_ns)]
        heapq.heapify(heap)
        while heap:
            _, offset, index, item = heapq.heappop(heap)
            if index >= 0:
                yield item
                continue
            f.seek(offset + 1 + 8)  # opcode and record length
            chunk = Chunk.read(ReadDataStream(_RecordFile(f)))
            for i, record in enumerate(breakup_chunk(chunk, validate_crc=True)):
                if not isinstance(record, Message) or (
                        ids is not None and record.channel_id not in ids):
                    continue
                if (start_ns is not None and record.log_time < start_ns) or (
                        end_ns is not None and record.log_time >= end_ns):
                    continue
                channel = self._channels[record.channel_id]
                heapq.heappush(heap, (record.log_time, offset, i, (
                    self._schemas.get(channel.schema_id), channel, record)))

    def _iter_stream(self, f: Any, wanted: set[str] | None, start_ns: int | None,
                     end_ns: int | None) -> Iterator[tuple[Schema | None, Channel, Message]]:
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        for record in StreamReader(f, validate_crcs=True).records:
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
                self._add_channel(record, schemas.get(record.schema_id))
            elif isinstance(record, Message):
                channel = channels[record.channel_id]
                if wanted is not None and channel.topic not in wanted:
                    continue
                if (start_ns is not None and record.log_time < start_ns) or (
                        end_ns is not None and record.log_time >= end_ns):
                    continue
                yield schemas.get(channel.schema_id), channel, record

    def _stopped(self, offset: int, count: int, err: Exception) -> None:
        size = self.path.stat().st_size
        if isinstance(err, EndOfFile) or isinstance(err, struct.error):
            why = "the file ends inside a record"
        else:
            why = f"{type(err).__name__}: {err}" if str(err) else type(err).__name__
        reason = f"the record after byte {offset} of {size} is unreadable ({why})"
        if self.stop_reason is None:
            self.stop_reason = reason
        if not self._warned:
            self._warned = True
            log.warning("%s: log is truncated or damaged; %s; using the %d messages before it",
                        self.path, reason, count)
        else:
            log.debug("%s: %s after %d messages", self.path, reason, count)

    def decode(self, raw: RawMessage) -> Any:
        """The decoded message: a ROS 2 / ROS 1 (genpy) / protobuf object or, for JSON, a
        dict."""
        decoder = self._decoders.get(raw.channel.id)
        if decoder is None:
            decoder = self._decoders[raw.channel.id] = _decoder_for(self.path, raw)
        return decoder(raw.message.data)


def _as_bytes(decoder: Callable[[bytes], Any]) -> Callable[[bytes | memoryview], Any]:
    """``decoder`` given ``bytes`` whatever it is handed (a long payload is a view of its
    chunk, :class:`_ChunkBytes`; mcap-ros1's, mcap-ros2's and json's decoders take bytes)."""
    def decode(data: bytes | memoryview) -> Any:
        return decoder(data.tobytes() if isinstance(data, memoryview) else data)
    return decode


def _decoder_for(path: Path, raw: RawMessage) -> Callable[[bytes], Any]:
    encoding = raw.channel.message_encoding
    schema = raw.schema
    if encoding == "json":
        return _as_bytes(json.loads)
    try:
        if encoding == "cdr":
            from mcap_ros2.decoder import DecoderFactory as Ros2Factory

            decoder = Ros2Factory().decoder_for(encoding, schema)
            if decoder is not None:
                decoder = _rosbags_cdr(schema, _as_bytes(decoder))
        elif encoding == "ros1":
            from mcap_ros1.decoder import DecoderFactory as Ros1Factory

            decoder = Ros1Factory().decoder_for(encoding, schema)
        elif encoding == "protobuf":
            from mcap_protobuf.decoder import DecoderFactory as ProtobufFactory

            decoder = ProtobufFactory().decoder_for(encoding, schema)
        else:
            decoder = None
    except Exception as err:  # a bad embedded schema is a log problem
        raise LogError(f"{path}: topic {raw.topic}: cannot parse schema "
                       f"{schema.name if schema else '?'} ({err})") from err
    if decoder is None:
        schema_text = f"{schema.name} ({schema.encoding})" if schema else "no schema"
        raise LogError(f"{path}: topic {raw.topic}: cannot decode message encoding "
                       f"'{encoding}' with {schema_text}; supported: ROS 2 cdr with ros2msg "
                       "schemas, ROS 1 ros1 with ros1msg schemas, protobuf, json")
    return decoder if encoding == "cdr" else _as_bytes(decoder)


def _rosbags_cdr(schema: Schema | None, fallback: Callable[[bytes], Any]
                 ) -> Callable[[bytes], Any]:
    """A ROS 2 CDR decoder for a ``ros2msg`` schema through rosbags' deserialiser (the one
    that reads ROS 2 bags, :mod:`evperc.logs.rosbags_source`), ``fallback`` (mcap-ros2's)
    for the messages it refuses and for schemas it cannot parse.

    Why: mcap-ros2 reads a message field by field in Python, each float64 of an Odometry's
    two 36-value covariances included (~31 µs a message, 5 a scan at 50 Hz, in the decode
    thread that bounds a run); rosbags reads fixed-size arrays with one ``numpy.frombuffer``
    (~10 µs). The values are the same bytes read as the same IEEE types; a ``uint8[]`` comes
    as a numpy view of the message instead of a ``bytes`` copy (the point payload: one copy
    of ~1.9 MB a scan fewer), which the adapters read alike
    (:mod:`evperc.logs.mcap_messages`)."""
    if schema is None or schema.encoding != "ros2msg":
        return fallback
    try:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        store = get_typestore(Stores.EMPTY)
        store.register(get_types_from_msg(schema.data.decode(), schema.name))
        name = schema.name
        store.get_msgdef(name)
    except Exception as err:  # a definition rosbags does not read: mcap-ros2 reads it
        log.debug("%s: rosbags cannot parse the schema (%s); mcap-ros2 decodes it",
                  schema.name, err)
        return fallback
    deserialize = store.deserialize_cdr

    def decode(data: bytes) -> Any:
        try:
            return deserialize(memoryview(data), name)
        except Exception:  # a message rosbags refuses: mcap-ros2's result or error
            return fallback(data)
    return decode


def json_bytes(value: Any) -> bytes:
    """A ``bytes`` field of a JSON-encoded message: base64 text (foxglove's JSON convention)."""
    if isinstance(value, str):
        return base64.b64decode(value)
    return bytes(value)


