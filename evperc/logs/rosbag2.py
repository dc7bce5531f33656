"""ROS 2 bags: a directory with ``metadata.yaml`` and its storage files (``.db3`` sqlite3, or
``.mcap``), read through rosbags; see :mod:`evperc.logs.rosbags_source`.

Recognised by the ``metadata.yaml`` in a directory, or by a file starting with the SQLite
header (``SQLite format 3``): a ``.db3`` file is read as the bag of the directory it sits in,
which must hold its ``metadata.yaml`` (the file list, message counts and time span come from
there, as ``ros2 bag`` uses them; ``ros2 bag reindex`` rewrites a lost one). Split bags (several
storage files) are read file after file, as recorded. Bags recorded before Iron carry no
message definitions; their types come from rosbags' bundled Humble store (the messages evperc
reads are the same in Foxy, Galactic and Humble).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

from evperc.errors import LogError
from evperc.logs.rosbags_source import RosbagsSource

SQLITE_MAGIC = b"SQLite format 3\x00"
METADATA = "metadata.yaml"


class Rosbag2Source(RosbagsSource):
    """A ROS 2 bag directory (sqlite3 or MCAP storage)."""

    kind: ClassVar[str] = "rosbag2"
    message_encoding: ClassVar[str] = "cdr"
    DEFAULT_STORE: ClassVar[str] = "ros2_humble"

    @classmethod
    def claims(cls, path: Path, head: bytes) -> bool:
        if path.is_dir():
            return (path / METADATA).is_file()
        return head.startswith(SQLITE_MAGIC)

    @classmethod
    def _reader(cls, path: Path) -> Any:
        """The reader of the bag directory (of ``path`` itself, or the one a .db3 is in)."""
        from rosbags.rosbag2 import Reader

        if not path.is_dir() and not (path.parent / METADATA).is_file():
            raise LogError(f"{path}: a ROS 2 sqlite3 bag file without the {METADATA} of its "
                           f"bag directory ({path.parent}); restore it with `ros2 bag reindex "
                           f"{path.parent}`, then give the directory")
        return Reader(path if path.is_dir() else path.parent)

    @classmethod
    def _open_error(cls, path: Path, why: str) -> LogError:
        return LogError(f"{path}: cannot read this ROS 2 bag ({why})")

    @classmethod
    def _seeks(cls, path: Path) -> bool:
        """sqlite3 storage selects a time range by query; an MCAP storage file is scanned
        from its start when it has no chunk index (a recording cut short), which rosbags does
        not tell apart here: taken as not seeking."""
        bag = path if path.is_dir() else path.parent
        return not any(bag.glob("*.mcap"))
