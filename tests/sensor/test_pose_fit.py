"""evperc.sensor.pose_fit: do the poses fit the scans? Synthetic streets with known pose errors
(the injected error is the oracle), and the check's refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from evperc.config import default_config
from evperc.logs.scan import PosedScan
from evperc.sensor.params import SensorParams
from evperc.sensor.pose_fit import (
    BASELINE_M,
    MAX_BASELINE_M,
    MAX_SCANS,
    MISFIT_M,
    check_poses,
    fit_scans,
)

SENSOR_HEIGHT = 1.73
PARAMS = SensorParams.from_config(default_config()["sensor"], 0.5)


def street(rng: np.random.Generator) -> np.ndarray:
    """World points of a street: façades at y = ±9 m with doorways, parked cars (4.5 × 1.8
    m outlines) at random x on both kerbs, poles, a cross wall at x = 32 m, and the road.
    Heights from the road (z = 0) up."""
    parts = []
    xs = np.arange(-40.0, 45.0, 0.08)
    for y in (-9.0, 9.0):
        wall = xs[(np.floor(xs / 6.0) % 3) != 0]  # doorways every 18 m
        for h in np.arange(0.3, 3.0, 0.35):
            parts.append(np.column_stack([wall, np.full(len(wall), y), np.full(len(wall), h)]))
    for x0 in rng.uniform(-35.0, 38.0, 14):
        y0 = rng.choice([-6.5, 5.0])
        t = np.linspace(0.0, 1.0, 60)
        outline = np.concatenate([
            np.column_stack([x0 + 4.5 * t, np.full(60, y0)]),
            np.column_stack([x0 + 4.5 * t, np.full(60, y0 + 1.8)]),
            np.column_stack([np.full(60, x0), y0 + 1.8 * t]),
            np.column_stack([np.full(60, x0 + 4.5), y0 + 1.8 * t])])
        for h in (0.5, 0.9, 1.3):
            parts.append(np.column_stack([outline, np.full(len(outline), h)]))
    for x0 in np.arange(-36.0, 40.0, 7.0):  # poles
        for h in np.arange(0.3, 4.0, 0.2):
            parts.append(np.array([[x0, 7.5, h], [x0 + 0.1, 7.5, h]]))
    ys = np.arange(-9.0, 9.0, 0.08)
    for h in np.arange(0.3, 3.0, 0.35):
        parts.append(np.column_stack([np.full(len(ys), 32.0), ys, np.full(len(ys), h)]))
    gx, gy = np.meshgrid(np.arange(-40.0, 45.0, 0.5), np.arange(-8.5, 8.5, 0.5))
    parts.append(np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)]))
    return np.concatenate(parts)


def pose(x: float, y: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = (x, y, SENSOR_HEIGHT)
    return T


def scan_at(world: np.ndarray, true_pose: np.ndarray, logged_pose: np.ndarray,
            stamp_ns: int, rng: np.random.Generator) -> PosedScan:
    """The street seen from ``true_pose`` (returns within 40 m, 2 cm range noise, a random
    90 % of them: no occlusion), logged with ``logged_pose``."""
    local = (world - true_pose[:3, 3]) @ true_pose[:3, :3]
    local = local[np.hypot(local[:, 0], local[:, 1]) < 40.0]
    local = local[rng.random(len(local)) < 0.9]
    local = local + rng.normal(0.0, 0.02, local.shape)
    return PosedScan(stamp_ns, local.astype(np.float32), False, logged_pose, "lidar")


def drive(error: np.ndarray | None = None, speed_m_per_scan: float = 0.8, n: int = 8,
          seed: int = 0) -> list[PosedScan]:
    """Scans every ``speed_m_per_scan`` metres along the street; ``error`` (4 × 4, applied to
    the logged poses of every scan after the first, on the right: a misplaced sensor) or
    none."""
    rng = np.random.default_rng(seed)
    world = street(rng)
    scans = []
    for k in range(n):
        true = pose(k * speed_m_per_scan)
        logged = true if (error is None or k == 0) else true @ error
        scans.append(scan_at(world, true, logged, k * 100_000_000, rng))
    return scans


def test_poses_that_fit_are_not_a_misfit() -> None:
    found = check_poses(drive(), PARAMS)
    assert found is not None
    assert found.second == 4  # the first scan posed 3 m or more away: 4 × 0.8 m
    assert found.moved_m == pytest.approx(3.2)
    assert not found.misfit and not found.turns and found.yaw_deg == 0.0
    # the middle of the share's flat top, on fine steps of 0.05 m: within two steps of none
    assert found.offset_norm_m <= 0.1
    assert found.share_at_poses > 0.8


@pytest.mark.parametrize("offset", [(0.6, 0.0), (-0.4, 0.3), (0.0, -0.5)])
def test_a_misplaced_scan_is_found_and_its_offset_measured(offset: tuple[float, float]) -> None:
    error = pose(*offset)
    error[2, 3] = 0.0
    found = check_poses(drive(error=error), PARAMS)
    assert found is not None and found.misfit and not found.turns
    # the logged pose puts the scan ``offset`` too far: it fits best moved back by it; to
    # within two fine steps (test_poses_that_fit_are_not_a_misfit)
    assert found.offset_m[0] == pytest.approx(-offset[0], abs=0.1)
    assert found.offset_m[1] == pytest.approx(-offset[1], abs=0.1)
    assert "the poses do not fit the scans" in found.message("drive.mcap")
    assert found.message("drive.mcap").startswith("drive.mcap: ")


@pytest.mark.parametrize("yaw", [2.0, -1.5, 1.0])
def test_a_heading_error_is_found_and_its_turn_measured(yaw: float) -> None:
    # a heading (or lidar yaw) error turns the second scan about its sensor: at 15 m, 1° is
    # 0.26 m; no offset undoes it, a turn does (the injected turn is the oracle, on the
    # search's 0.5° steps)
    found = check_poses(drive(error=_yaw_only(yaw)), PARAMS)
    assert found is not None and found.misfit and found.turns
    assert found.yaw_deg == pytest.approx(-yaw, abs=0.25)
    assert found.turned_offset_m is not None and math.hypot(*found.turned_offset_m) <= 0.1
    assert found.share_turned - found.share_best >= 0.3  # the turn, not the offset, fits
    assert f"turned {-yaw:+.1f}°" in found.message("drive.mcap")


def test_half_a_degree_is_not_called_a_misfit() -> None:
    found = check_poses(drive(error=_yaw_only(0.5)), PARAMS)
    assert found is not None and not found.misfit and abs(found.yaw_deg) <= 0.5


def _yaw_only(deg: float) -> np.ndarray:
    T = pose(0.0, 0.0, deg)
    T[2, 3] = 0.0
    return T


def test_a_geo_referenced_frame_far_from_its_origin() -> None:
    # poses in UTM-like coordinates (500 km east, 6,700 km north): the same verdict and offset
    far = pose(500_000.0, 6_700_000.0)
    far[2, 3] = 0.0
    error = pose(0.4, -0.3)
    error[2, 3] = 0.0
    scans = [PosedScan(s.stamp_ns, s.points, s.planar, far @ s.T_world_sensor, s.frame_id)
             for s in drive(error=error)]
    found = check_poses(scans, PARAMS)
    assert found is not None and found.misfit
    assert found.offset_m == pytest.approx((-0.4, 0.3), abs=0.1)


def test_an_error_below_half_a_cell_is_not_called_a_misfit() -> None:
    error = pose(0.1, 0.0)
    error[2, 3] = 0.0
    found = check_poses(drive(error=error), PARAMS)
    assert found is not None and not found.misfit
    assert found.offset_norm_m < MISFIT_M


def test_no_check_without_motion_or_without_returns() -> None:
    slow = drive(speed_m_per_scan=0.01, n=20)
    assert check_poses(slow, PARAMS) is None  # 0.19 m in 20 scans: never 3 m
    assert check_poses(iter([]), PARAMS) is None
    sparse = [PosedScan(s.stamp_ns, s.points[::200], False, s.T_world_sensor, "lidar")
              for s in drive()]
    assert check_poses(sparse, PARAMS) is None  # ~250 obstacle returns a scan


def test_a_jump_or_a_broken_pose_is_no_pair_to_compare() -> None:
    # a GNSS jump of 1,000 km right after the first scan: no raster across it (it would need
    # 10^14 cells), no verdict
    jumped = drive()
    far = pose(1_000_000.0)
    far[2, 3] = 0.0
    jumped[2:] = [PosedScan(s.stamp_ns, s.points, False, far @ s.T_world_sensor, "lidar")
                  for s in jumped[2:]]
    assert check_poses(jumped, PARAMS) is None
    broken = drive()
    T = broken[1].T_world_sensor.copy()
    T[0, 3] = np.nan
    broken[1] = PosedScan(broken[1].stamp_ns, broken[1].points, False, T, "lidar")
    assert check_poses(broken, PARAMS) is None
    assert MAX_BASELINE_M > BASELINE_M + 0.8  # a fast car's next scan after the baseline


def test_at_most_max_scans_are_read() -> None:
    read = []

    def scans():
        first = drive(n=1)[0]
        for k in range(MAX_SCANS + 50):
            read.append(k)
            yield first
    assert check_poses(scans(), PARAMS) is None
    assert len(read) == MAX_SCANS + 1
    assert BASELINE_M == 3.0


def test_fit_scans_finds_a_pure_shift_and_a_pure_turn_of_the_same_points() -> None:
    rng = np.random.default_rng(3)
    a = np.concatenate([np.column_stack([rng.uniform(-20, 20, 3000), rng.normal(5, 0.02, 3000)]),
                        np.column_stack([rng.normal(-4, 0.02, 3000), rng.uniform(-10, 10, 3000)]),
                        rng.uniform(-20, 20, (400, 2))])
    (at_poses, best, offset), (yaw, _, _) = fit_scans(a, a + (0.7, -0.35), (0.0, 0.0))
    assert at_poses < 0.2 and best > 0.95 and yaw == 0.0
    assert offset == pytest.approx((-0.7, 0.35), abs=0.05)
    (at_poses, best, offset), (yaw, _, _) = fit_scans(a, a.copy(), (0.0, 0.0))
    assert at_poses == best == 1.0 and offset == (0.0, 0.0) and yaw == 0.0
    c, s = math.cos(math.radians(1.5)), math.sin(math.radians(1.5))
    turned = a @ np.array([[c, s], [-s, c]])  # each row turned +1.5° about the origin
    _, (yaw, share, offset) = fit_scans(a, turned, (0.0, 0.0))
    assert yaw == -1.5 and share > 0.95 and math.hypot(*offset) <= 0.05
