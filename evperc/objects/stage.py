"""The object stages of one frame in a row (docs/method.md, "Objects"): clusters
(:mod:`evperc.objects.clusters`) seeded by the frame's moving cells and the footprints of
the tracks that moved, then the tracker (:mod:`evperc.objects.tracking`).

Inputs are a frame's stored outputs only (decision, betP(M) and ∅_FO as uint8 ×255, the
window, the stamp): the stage does not depend on how the fusion decided them."""

from __future__ import annotations

from typing import Any

import numpy as np

from evperc.geo.window import Window
from evperc.objects.clusters import Clusterer, ClusterParams
from evperc.objects.tracking import TrackerState, TrackingParams, footprint_seeds, track_step


def objects_enabled(config: dict[str, Any]) -> bool:
    """Whether a run with ``config`` computes objects (a config written before the
    ``[objects]`` table existed, e.g. an old run's manifest on resume: no)."""
    return bool(config.get("objects", {}).get("enabled", False))


class ObjectStage:
    """Clusters and tracks over windows of one shape."""

    def __init__(self, config: dict[str, Any], shape: tuple[int, int]) -> None:
        self.cluster_params = ClusterParams.from_config(config)
        self.tracking_params = TrackingParams.from_config(config)
        self.clusterer = Clusterer(self.cluster_params, shape)

    def step(self, state: TrackerState, decision: np.ndarray, betp_moving: np.ndarray,
             conflict_fo: np.ndarray, window: Window, stamp_ns: int
             ) -> tuple[np.ndarray, np.ndarray]:
        """The frame's reported objects and their cells (:func:`track_step`); ``state``
        is updated in place."""
        seeds = footprint_seeds(state, window)
        clusters = self.clusterer.clusters(decision, betp_moving, conflict_fo, window, seeds)
        return track_step(state, clusters, window, stamp_ns, self.tracking_params)

    def history(self) -> int:
        return self.tracking_params.history_frames
