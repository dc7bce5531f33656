"""Lidar sensor models producing {F, O} mass grids (method.md §3)."""

from evperc.sensor.grid import sensor_grid
from evperc.sensor.params import SensorParams

__all__ = ["SensorParams", "sensor_grid"]
