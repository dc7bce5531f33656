"""`evperc run --no-map` on real HDL-64 scans (KITTI odometry 00, first 16 scans).

The street is lined with parked cars and holds few or no moving objects: the share of
observed cells decided moving at the last frame must stay small.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import evperc
from evperc.cli import cli
from evperc.fusion.twin import DECISION_CODES
from tests.mcap_writers import write_kitti_odometry_mcap

KITTI = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "kitti00"
needs_kitti = pytest.mark.skipif(
    not (KITTI / "velodyne").is_dir(),
    reason=f"real KITTI scans not found at {KITTI} (the shared data folder is absent)")

#: measured 0.0155 with the tuned defaults (0.0097 with the SPEC values); a broken ground split or
#: pose chain lights whole streets up (>10 %)
MAX_MOVING_SHARE = 0.02


@needs_kitti
def test_kitti_no_map_run_keeps_parked_cars_static(tmp_path: Path) -> None:
    log = write_kitti_odometry_mcap(KITTI, tmp_path / "kitti00.mcap", 16)
    config = tmp_path / "kitti.toml"
    config.write_text("[sensor]\nmin_range_m = 2.7  # KITTI car body returns\n")
    out = tmp_path / "out"
    result = CliRunner().invoke(cli, ["run", str(log), "--no-map", "--config", str(config),
                                      "--out", str(out)])
    assert result.exit_code == 0, result.output
    run = evperc.load(out)
    assert len(run) == 16
    frames = list(run.frames)
    last = frames[-1]
    observed = last.decision != DECISION_CODES["unknown"]
    assert observed.mean() > 0.05
    moving_share = float((last.decision[observed] == DECISION_CODES["moving"]).mean())
    static_share = float(np.isin(last.decision[observed], [DECISION_CODES["static"]]).mean())
    free_share = float((last.decision[observed] == DECISION_CODES["free"]).mean())
    (tmp_path / "shares.json").write_text(json.dumps(
        {"moving": moving_share, "static": static_share, "free": free_share}))
    print(f"kitti00 last frame: moving {moving_share:.4f} static {static_share:.4f} "
          f"free {free_share:.4f} of {int(observed.sum())} observed cells")
    assert moving_share < MAX_MOVING_SHARE
    assert static_share > 0.01  # the parked cars and walls are there
    assert free_share > 0.5     # most of what a lidar sees is free road
    # the car drove about 13 m: the window followed it
    assert frames[0].origin != last.origin
    assert np.hypot(*(last.pose[:2] - frames[0].pose[:2])) > 10
