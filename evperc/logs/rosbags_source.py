"""Bags read through rosbags' readers (``rosbags.rosbag1.Reader``, ``rosbags.rosbag2.Reader``):
the part ROS 1 ``.bag`` files (:mod:`evperc.logs.rosbag1`) and ROS 2 bag directories
(:mod:`evperc.logs.rosbag2`) share. The readers are used directly rather than through
``AnyReader``, which picks the bag version by the file's suffix: evperc goes by content.

Opening reads the bag's index (ROS 1: the connection and chunk records and one small entry per
message; ROS 2: ``metadata.yaml`` and the storage's topic table) and builds the message types
from the definitions the bag carries (types the bag does not define come from rosbags' bundled
store, ``DEFAULT_STORE``). ``iter_raw`` then streams messages in log-time order (ROS 1: a merge
of the per-connection indexes, one decompressed chunk in memory at a time; ROS 2 sqlite3: one
``ORDER BY timestamp`` query per storage file, read row by row), so memory does not grow
with the bag's length beyond the ROS 1 index (~200 bytes per message). ``decode`` deserialises with
the bag's type store into rosbags' message dataclasses (attribute access; ``uint8[]`` as a
numpy array), which the adapters of :mod:`evperc.logs.mcap_messages` read as they read ROS 2
MCAP messages: rosbags spells every type name the ROS 2 way (``sensor_msgs/msg/PointCloud2``,
ROS 1's ``tf/tfMessage`` as ``tf/msg/tfMessage``).

Where the data stops being readable (a damaged chunk, a short file) the stream ends there with
ONE warning per bag, as for an MCAP file.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from evperc.errors import LogError
from evperc.logs.mcap_source import TopicInfo

log = logging.getLogger(__name__)

#: the largest rosbags timestamp means "no messages" (rosbags' convention)
_NO_TIME = 2**63 - 1
#: the line between concatenated IDL definitions (ROS 2 bags)
_IDL_SEPARATOR = "=" * 80 + "\n"


@dataclass
class BagMessage:
    """One message as rosbags reads it: its connection, log time and serialised bytes."""

    topic: str
    log_time: int
    data: bytes
    connection: Any


class RosbagsSource:
    """A bag opened with rosbags (see the module docstring); subclasses name the kind."""

    kind: ClassVar[str] = "rosbags"
    #: the message encoding of this kind, as ``evperc info`` shows it
    message_encoding: ClassVar[str] = ""
    #: rosbags' bundled type store for types the bag does not define
    DEFAULT_STORE: ClassVar[str] = "latest"

    def __init__(self, path: Path, reader: Any, store: Any) -> None:
        self.path = path
        self._deserialize = (store.deserialize_ros1 if self.message_encoding == "ros1"
                             else store.deserialize_cdr)
        self.indexed = True  # both bag kinds stream in log-time order
        self.seeks = self._seeks(path)
        self.stop_reason: str | None = None
        self._bag = reader
        self._lock = threading.Lock()  # one file handle / sqlite connection for all streams
        self._warned = False
        self.topics: dict[str, TopicInfo] = {}
        self._connections: dict[str, list[Any]] = {}
        for name, info in sorted(reader.topics.items()):
            fmt = getattr(info.msgdef.format, "name", "NONE")
            self.topics[name] = TopicInfo(
                topic=name, schema=info.msgtype or "",
                schema_encoding=self._schema_encoding(fmt),
                message_encoding=self.message_encoding, messages=int(info.msgcount))
            self._connections[name] = list(info.connections)
        start, end = reader.start_time, reader.end_time
        empty = start >= _NO_TIME or end <= 0 or reader.message_count == 0
        self.start_ns = None if empty else int(start)
        self.end_ns = None if empty else int(end) - 1  # rosbags' end is exclusive

    @classmethod
    def _schema_encoding(cls, fmt: str) -> str:
        return {"MSG": "ros2msg", "IDL": "ros2idl"}.get(fmt, "")

    @classmethod
    def _seeks(cls, path: Path) -> bool:
        """Whether a time-range read skips what comes before (a ROS 1 bag: its index by
        connection and time, in memory)."""
        return True

    @classmethod
    def _reader(cls, path: Path) -> Any:
        """The rosbags reader of ``path`` (not opened)."""
        raise NotImplementedError

    @classmethod
    def _open_error(cls, path: Path, why: str) -> LogError:
        return LogError(f"{path}: cannot read this {cls.kind} ({why})")

    @classmethod
    def open(cls, path: str | Path) -> RosbagsSource:
        """Open the bag at ``path``, read its index and build its message types; LogError if
        it cannot be read."""
        from rosbags.typesys import Stores, get_typestore

        path = Path(path)
        reader = cls._reader(path)
        try:
            reader.open()
        except Exception as err:  # rosbags raises its own and plain errors for a bad bag
            raise cls._open_error(path, _text(err)) from err
        try:
            store = _typestore(reader.connections, get_typestore(Stores(cls.DEFAULT_STORE)))
        except Exception as err:
            raise LogError(f"{path}: cannot parse the message definitions in this {cls.kind} "
                           f"({_text(err)})") from err
        return cls(path, reader, store)

    # --- reading ---------------------------------------------------------------------------

    def iter_raw(self, topics: Iterable[str] | None = None, start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[BagMessage]:
        """Messages of ``topics`` with log time in [start_ns, end_ns), undecoded, in log-time
        order; stops quietly (after one warning per bag) where the data is unreadable."""
        if topics is None:
            connections = [c for conns in self._connections.values() for c in conns]
        else:
            connections = [c for t in set(topics) for c in self._connections.get(t, [])]
        if not connections:
            return
        stream = self._bag.messages(connections=connections, start=start_ns, stop=end_ns)
        count = 0
        try:
            while True:
                with self._lock:
                    try:
                        connection, log_time, data = next(stream)
                    except StopIteration:
                        return
                    except Exception as err:  # a damaged bag ends the stream
                        self._stopped(count, err)
                        return
                count += 1
                yield BagMessage(connection.topic, int(log_time), data, connection)
        finally:
            with self._lock:
                stream.close()

    def _stopped(self, count: int, err: Exception) -> None:
        reason = f"unreadable data after {count} messages ({_text(err)})"
        if self.stop_reason is None:
            self.stop_reason = reason
        if not self._warned:
            self._warned = True
            log.warning("%s: bag is truncated or damaged; %s; using the messages before it",
                        self.path, reason)

    def decode(self, raw: BagMessage) -> Any:
        """The rosbags message object of ``raw`` (deserialised with the bag's type store)."""
        return self._deserialize(raw.data, raw.connection.msgtype)


def _typestore(connections: list[Any], bundled: Any) -> Any:
    """A rosbags type store with the types the bag defines (``.msg`` text, ROS 1 and ROS 2, or
    ROS 2 IDL, one or several concatenated definitions) and, from the ``bundled`` store, those
    it uses without defining them (ROS 2 bags before Iron carry no definitions)."""
    from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

    types: dict[str, Any] = {}
    for connection in connections:
        fmt, text = connection.msgdef.format.name, connection.msgdef.data
        if fmt == "MSG":
            types.update(get_types_from_msg(text, connection.msgtype))
        elif fmt == "IDL":
            for part in text.split(_IDL_SEPARATOR):
                if part.startswith("IDL: "):
                    part = part.split("\n", 1)[1]
                if part.strip():
                    types.update(get_types_from_idl(part))
    store = get_typestore(Stores.EMPTY)
    store.register(types)
    todo = [c.msgtype for c in connections]
    wanted: dict[str, Any] = {}
    while todo:  # the undefined types and everything they use
        name = todo.pop()
        if name in wanted or name in store.fielddefs or name not in bundled.fielddefs:
            continue
        wanted[name] = bundled.fielddefs[name]
        for _, (_, desc) in bundled.fielddefs[name][1]:
            todo.extend(_type_names(desc))
    if wanted:
        store.register(wanted)
    return store


def _type_names(desc: Any) -> Iterator[str]:
    """Message type names inside a rosbags field description (nested tuples)."""
    if isinstance(desc, str) and "/" in desc:
        yield desc
    elif isinstance(desc, tuple):
        for item in desc:
            yield from _type_names(item)


def _text(err: Exception) -> str:
    """``err`` as one line: its type and message (rosbags' messages can span lines)."""
    text = " ".join(str(err).split())
    return f"{type(err).__name__}: {text}" if text else type(err).__name__
