"""scripts/kitti_sparse_copy.py: a 16-layer copy of a SemanticKITTI slice keeps each kept
point with its own label and nothing else (checked against the source files point by point,
by coordinates, not through the script's mask)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
SMALL = REPO / "tests" / "data" / "semantickitti05"
sys.path.insert(0, str(REPO / "scripts"))
import kitti_sparse_copy as sparse  # noqa: E402


def test_the_copy_keeps_points_near_the_layers_with_their_labels(tmp_path: Path) -> None:
    layers = sparse.layer_elevations()
    assert len(layers) == 16 and layers[0] == -24.0 and np.isclose(layers[-1], 0.0)
    dst = tmp_path / "copy"
    kept, total = sparse.sparse_copy(SMALL, dst, layers)
    assert 0.15 < kept / total < 0.35   # ~16 of the HDL-64E's 64 lines
    for name in ("calib.txt", "poses.txt", "times.txt"):
        assert (dst / name).read_bytes() == (SMALL / name).read_bytes()
    for scan in sorted((SMALL / "velodyne").glob("*.bin")):
        src = np.fromfile(scan, "<f4").reshape(-1, 4)
        src_labels = np.fromfile(SMALL / "labels" / f"{scan.stem}.label", "<u4")
        out = np.fromfile(dst / "velodyne" / scan.name, "<f4").reshape(-1, 4)
        out_labels = np.fromfile(dst / "labels" / f"{scan.stem}.label", "<u4")
        assert len(out) == len(out_labels) > 0
        # every kept point is a source point with the same label, in the source's order
        index = {row.tobytes(): i for i, row in enumerate(src)}
        at = np.array([index[row.tobytes()] for row in out])
        assert (np.diff(at) > 0).all()
        np.testing.assert_array_equal(out_labels, src_labels[at])
        # elevations, in float64 from the written coordinates (the script's are float32:
        # 1e-4 degrees of slack)
        xyz = out[:, :3].astype(np.float64)
        elevation = np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))
        assert (np.abs(elevation[:, None] - layers[None, :]).min(axis=1) <= 0.2 + 1e-4).all()
        dropped = np.setdiff1d(np.arange(len(src)), at)
        d = src[dropped, :3].astype(np.float64)
        d_el = np.degrees(np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])))
        assert (np.abs(d_el[:, None] - layers[None, :]).min(axis=1) > 0.2 - 1e-4).all()


def test_a_folder_that_is_no_slice_is_refused_in_one_line(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="no velodyne: give a SemanticKITTI sequence folder"):
        sparse.sparse_copy(tmp_path, tmp_path / "copy", sparse.layer_elevations())
    with pytest.raises(SystemExit, match="would replace its source"):
        sparse.sparse_copy(SMALL, SMALL, sparse.layer_elevations())
