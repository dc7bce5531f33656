"""ROS 1 bags (``.bag``, format 2.0) read through rosbags; see :mod:`evperc.logs.rosbags_source`.

Recognised by the file's first line, ``#ROSBAG V2.0``. A bag must be indexed (a recorder that
was killed leaves it unindexed: ``rosbag reindex`` repairs it). ROS 1 bags carry the full
message definitions, so the types come from the bag itself.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

from evperc.errors import LogError
from evperc.logs.rosbags_source import RosbagsSource

MAGIC = b"#ROSBAG V"
VERSION = b"#ROSBAG V2.0\n"


class Rosbag1Source(RosbagsSource):
    """A ROS 1 bag file."""

    kind: ClassVar[str] = "rosbag1"
    message_encoding: ClassVar[str] = "ros1"
    DEFAULT_STORE: ClassVar[str] = "ros1_noetic"

    @classmethod
    def claims(cls, path: Path, head: bytes) -> bool:
        return head.startswith(MAGIC)

    @classmethod
    def _reader(cls, path: Path) -> Any:
        from rosbags.rosbag1 import Reader

        return Reader(path)

    @classmethod
    def _schema_encoding(cls, fmt: str) -> str:
        return "ros1msg" if fmt == "MSG" else ""

    @classmethod
    def _open_error(cls, path: Path, why: str) -> LogError:
        with path.open("rb") as f:
            first = f.readline(len(VERSION))
        if first != VERSION:
            version = first.decode("ascii", "replace").strip().removeprefix("#ROSBAG ")
            return LogError(f"{path}: ROS 1 bag of format {version}; evperc reads format V2.0 "
                            "(ROS 1 since C Turtle); migrate it with `rosbag fix`")
        return LogError(f"{path}: cannot read this ROS 1 bag ({why}); if the recording was cut "
                        "off, repair it with `rosbag reindex`")
