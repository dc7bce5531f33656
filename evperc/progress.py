"""Progress bars of the long commands (run, render, export, simulate, batch): tqdm with a
total, so that it shows the fraction done and the time left; drawn only on a terminal, or
always with ``EVPERC_PROGRESS=1`` (``0``: never)."""

from __future__ import annotations

import os
from collections.abc import Iterable
from typing import Any

from tqdm import tqdm


def bar(iterable: Iterable[Any] | None = None, *, total: int | None, desc: str,
        unit: str = "frame", initial: int = 0, enabled: bool | None = None) -> tqdm:
    """A tqdm bar over ``iterable`` (or updated by hand) with ``total`` steps; ``enabled``
    ``None``: only when stderr is a terminal. Left off the screen when done: the command's
    one-line summary follows."""
    forced = os.environ.get("EVPERC_PROGRESS")
    if enabled is None and forced in ("0", "1"):
        enabled = forced == "1"
    return tqdm(iterable, total=total, desc=desc, unit=unit, initial=initial, leave=False,
                disable=None if enabled is None else not enabled, dynamic_ncols=True)
