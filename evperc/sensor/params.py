"""Parameters of the lidar sensor model (method §3), read from the config's ``[sensor]`` table."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class SensorParams:
    """Moras 2011 sensor-model parameters; units in the field names.

    ``range_bin_m`` is the depth of a polar range bin (method.md §3: the cell size); ``None``
    means the resolution of the window the grid is computed on. ``free_margin_m`` (d_s) and
    ``free_erosion_m`` (d_p) are the conservative-free-space margins of
    :mod:`evperc.sensor.conservative`; 0 is the paper's model.
    """

    mu_free: float = 0.7
    mu_occupied: float = 0.8
    min_range_m: float = 1.0
    max_range_m: float = 80.0
    azimuth_resolution_deg: float = 0.5
    ground_threshold_m: float = 0.3
    max_obstacle_height_m: float = 2.5
    sensor_height_m: float = 1.73
    range_bin_m: float | None = None
    free_margin_m: float = 0.0
    free_erosion_m: float = 0.0
    ground_fallback: str = "prior"
    ground_local_raise_m: float = 0.0
    ground_chain: bool = False
    foot_lift_m: float = 0.0
    ground_chain_gap_m: float = 0.0
    ground_chain_gap_road_only: bool = False

    @staticmethod
    def from_config(sensor: Mapping[str, Any], cell_size_m: float) -> SensorParams:
        """From a validated ``config["sensor"]`` table; range bins of ``cell_size_m``."""
        return SensorParams(
            mu_free=float(sensor["mu_free"]),
            mu_occupied=float(sensor["mu_occupied"]),
            min_range_m=float(sensor["min_range_m"]),
            max_range_m=float(sensor["max_range_m"]),
            azimuth_resolution_deg=float(sensor["azimuth_resolution_deg"]),
            ground_threshold_m=float(sensor["ground_threshold_m"]),
            max_obstacle_height_m=float(sensor["max_obstacle_height_m"]),
            sensor_height_m=float(sensor["sensor_height_m"]),
            range_bin_m=float(cell_size_m),
            free_margin_m=float(sensor["free_margin_m"]),
            free_erosion_m=float(sensor["free_erosion_m"]),
            ground_fallback=str(sensor["ground_fallback"]),
            ground_local_raise_m=float(sensor["ground_local_raise_m"]),
            ground_chain=bool(sensor["ground_chain"]),
            foot_lift_m=float(sensor["foot_lift_m"]),
            ground_chain_gap_m=float(sensor["ground_chain_gap_m"]),
            ground_chain_gap_road_only=bool(sensor["ground_chain_gap_road_only"]),
        )
