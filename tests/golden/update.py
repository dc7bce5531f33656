"""Rewrite the golden files (``make golden``). Review the diff before committing it."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from tests.golden.golden import CASES, compute, dumps, paths


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        for case in CASES:
            summary, arrays = compute(case, Path(tmp) / case)
            json_path, npz_path = paths(case)
            json_path.write_text(dumps(summary))
            np.savez_compressed(npz_path, **arrays)
            print(f"wrote {json_path.name} and {npz_path.name}")


if __name__ == "__main__":
    main()
