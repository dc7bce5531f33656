"""Shared fixtures of the sensor-grid tests."""

from __future__ import annotations

import pytest

from evperc.sensor import SensorParams


@pytest.fixture
def params() -> SensorParams:
    """The config defaults (μ_F 0.7, μ_O 0.8, 1–80 m, 0.5°, 0.3 m, 2.5 m, 1.73 m), 0.5 m bins."""
    return SensorParams(range_bin_m=0.5)
