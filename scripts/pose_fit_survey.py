#!/usr/bin/env python3
"""The pose check of every log given, as `evperc run` makes it before its frame loop
(evperc/sensor/pose_fit.py; docs/evaluation.md § "Since 2026-12-04, ninth session"):

    python scripts/pose_fit_survey.py W/drives/*/drive.mcap ../shared/data/kitti00 \\
        ../shared/data/semantickitti/*

One line per log: the scans compared, the motion between them, the returns compared, the
share matched at the poses and at the best offset, the offset (m), the best turn (degrees)
and its share, the verdict and the
check's time (the log opened and its first scan read before it, as `evperc run` does); "not
checked" when the vehicle moved less than 3 m in the first 200 scans or a scan had fewer
than 200 obstacle returns within 30 m. The default configuration, no map.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from evperc.config import load_config  # noqa: E402
from evperc.runner import Pipeline, RunRequest  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("logs", nargs="+", type=Path)
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)
    for path in args.logs:
        pipeline = Pipeline(RunRequest(log_path=path, out_dir=Path("unused"),
                                       config=load_config(None)))
        pipeline.warm_up_inputs()
        t0 = time.perf_counter()
        fit = pipeline.check_poses()
        ms = 1e3 * (time.perf_counter() - t0)
        if fit is None:
            print(f"{path}: not checked ({ms:.0f} ms)")
            continue
        print(f"{path}: scans {fit.first}, {fit.second}; moved {fit.moved_m:.2f} m; returns "
              f"{fit.returns[0]}, {fit.returns[1]}; share {fit.share_at_poses:.3f} -> "
              f"{fit.share_best:.3f}; offset ({fit.offset_m[0]:+.2f}, {fit.offset_m[1]:+.2f}) "
              f"m; turned {fit.yaw_deg:+.1f} deg: share {fit.share_turned:.3f}; "
              f"{'MISFIT' if fit.misfit else 'fits'} ({ms:.0f} ms)")


if __name__ == "__main__":
    main()
