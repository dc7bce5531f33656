"""The reader contract every log source keeps (docs/architecture.md, "Log sources").

A *source* is one container format: an MCAP file (:class:`evperc.logs.mcap_source.McapSource`),
a ROS 1 bag (:class:`evperc.logs.rosbag1.Rosbag1Source`), a ROS 2 bag directory
(:class:`evperc.logs.rosbag2.Rosbag2Source`). It knows its topics (name, schema name, encodings,
message count) and time span, streams raw messages of chosen topics in log-time order, and
decodes one raw message into an attribute-style (or dict) message object. It knows nothing of
lidar, poses or TF: :class:`evperc.logs.message_log.LogReader` detects the topics by schema name and
chains the poses the same way for every source, through the adapters of
:mod:`evperc.logs.mcap_messages`.

The factory (:func:`evperc.logs.message_log.open_source`) asks each registered source class,
in order, whether it ``claims`` the path by its content (magic bytes, a ``metadata.yaml``),
and opens the path with the first that does; adding a source is one new module and one entry
in that list.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, Protocol

from evperc.logs.mcap_source import TopicInfo

#: bytes read from the start of a file to recognise its kind
HEAD_BYTES = 16


class RawLike(Protocol):
    """A message as a source yields it, not yet decoded."""

    topic: str

    @property
    def log_time(self) -> int: ...


class LogSource(Protocol):
    """What :class:`evperc.logs.message_log.LogReader` needs of a source.

    ``end_ns`` is the log time of the last message (inclusive); ``indexed`` is True when
    ``iter_raw`` yields log-time order; ``seeks`` is True when ``iter_raw(start_ns=…)`` goes
    to that time without reading the log before it (an index by time); ``stop_reason`` is
    None unless the data ended early (damaged or truncated), in which case ``iter_raw``
    stopped there after one warning.
    """

    kind: str
    path: Path
    indexed: bool
    seeks: bool
    topics: dict[str, TopicInfo]
    start_ns: int | None
    end_ns: int | None
    stop_reason: str | None

    @classmethod
    def claims(cls, path: Path, head: bytes) -> bool:
        """True if ``path`` (a file starting with ``head``, or a directory) is of this kind."""
        ...

    @classmethod
    def open(cls, path: str | Path) -> LogSource: ...

    def iter_raw(self, topics: Iterable[str] | None = None, start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[Any]:
        """Raw messages (:class:`RawLike`) of ``topics`` with log time in [start_ns, end_ns)."""
        ...

    def decode(self, raw: Any) -> Any:
        """The message object of one raw message (field access by attribute or key)."""
        ...
