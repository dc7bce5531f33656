"""The manifest of an `evperc run` output directory (docs/output-format.md): its name, the
format version this evperc writes and the ones it reads, and reading it with its checks.
Shared by the writer and the reader, so neither imports the other."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from evperc.errors import OutputError

#: the output format this evperc writes
FORMAT_VERSION = 4
#: output formats this evperc reads (2: dense mass planes, before the block-sparse runs; 3:
#: betP stored beside the masses, before it was derived from them on reading)
READABLE_VERSIONS = (2, 3, FORMAT_VERSION)
MANIFEST = "manifest.json"


def read_manifest(out_dir: str | Path) -> dict[str, Any]:
    """The manifest of ``out_dir`` as a dict; :class:`OutputError` if there is none, it is
    not JSON, or its format is one this evperc does not read."""
    out_dir = Path(out_dir)
    path = out_dir / MANIFEST
    if not path.is_file():
        raise OutputError(f"{out_dir}: not an evperc output (no {MANIFEST})")
    try:
        manifest = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise OutputError(f"{path}: unreadable manifest ({err})") from err
    if manifest.get("format_version") not in READABLE_VERSIONS:
        raise OutputError(f"{path}: format_version {manifest.get('format_version')!r}, this "
                          f"evperc reads {', '.join(map(str, READABLE_VERSIONS))}")
    return manifest
