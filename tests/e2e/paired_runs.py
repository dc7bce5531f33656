"""One simulated drive run under several configs and scored against its truth (the e2e tests
that compare a default with the config before it: test_sparse_scanner, test_rehit_window)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from tests.e2e.test_sim_eval import OSM, invoke_ok


def paired_scores(root: Path, profile: str, seed: int,
                  configs: dict[str, Path | None]) -> dict[str, dict[str, Any]]:
    """``evperc simulate`` (``profile``, ``seed``, 10 s, the Helsinki test map) into ``root``,
    then per name of ``configs`` ``evperc run`` with the map (and ``--config`` the file, or the
    defaults for None) and ``evperc evaluate --cells visible``: the metrics JSON per name."""
    drive = root / "drive"
    invoke_ok("simulate", "--map", str(OSM / "helsinki_buildings.geojson"), "--roads",
              str(OSM / "helsinki_roads.geojson"), "--profile", profile, "--seconds", "10",
              "--seed", str(seed), "--out", str(drive))
    out = {}
    for name, config in configs.items():
        extra = () if config is None else ("--config", str(config))
        invoke_ok("run", str(drive / "drive.mcap"), "--map", str(drive / "map.geojson"),
                  "--out", str(root / name), *extra)
        path = root / f"{name}.json"
        invoke_ok("evaluate", str(root / name), "--truth", str(drive / "truth"), "--cells",
                  "visible", "--json", str(path))
        out[name] = json.loads(path.read_text())
    return out


def moving_within_one_cell(root: Path, profile: str, seed: int, before: Path
                           ) -> dict[str, dict[str, Any]]:
    """:func:`paired_scores` of the defaults ("now") and the config file ``before``: each
    run's ``moving_within_one_cell`` scores."""
    scores = paired_scores(root, profile, seed, {"now": None, "before": before})
    return {name: s["moving_within_one_cell"] for name, s in scores.items()}
