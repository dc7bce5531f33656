"""``open_log(path)``: the reader for whatever kind of log ``path`` is, as KISS-ICP keeps its
dataloaders — one module per source kind, each listed once in :data:`SOURCES` with the test
that recognises it (by content, not by name) and the function that opens it.

Every reader offers what :class:`evperc.logs.message_log.LogReader` offers (docs/architecture.md:
``scans()``, ``start_ns`` / ``end_ns``, ``stats``, ``gnss_spans()``, ``gnss_fixes()``,
``positions_at()``, ``info()``, …). Adding a source is a new module and one row here;
nothing else changes.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

from evperc.logs import kitti, message_log


class Source(NamedTuple):
    """One kind of log: its name (``evperc info`` prints it), a test on the path and the
    opener, called with ``open_log``'s keyword options."""

    kind: str
    recognises: Callable[[Path], bool]
    open: Callable[..., Any]


#: every log kind evperc reads, tried in order; the last one (MCAP) takes any other file and
#: gives the one-line error of a file that is no log evperc knows
SOURCES: list[Source] = [
    Source("kitti", kitti.claims, lambda path, **_: kitti.KittiLog(path)),
    Source("mcap", lambda path: True, message_log.open_message_log),
]


def source_of(path: str | Path) -> Source:
    """The first of :data:`SOURCES` that recognises ``path`` (the last one takes any)."""
    path = Path(path)
    return next(source for source in SOURCES if source.recognises(path))


def log_kind(path: str | Path) -> str:
    """The :attr:`Source.kind` of the log at ``path``, without opening it."""
    return source_of(path).kind


def open_log(path: str | Path, **options: Any) -> Any:
    """Open the log at ``path`` with the reader of its kind (:data:`SOURCES`); ``options``
    are the reader's (topics, world frame, extrinsic, ``max_pose_gap_s``, ``strict``: see
    :func:`evperc.logs.message_log.open_message_log`). Raises :class:`~evperc.errors.LogError` for a
    missing or unreadable file."""
    return source_of(path).open(Path(path), **options)
