"""Geo-reference: the log's world frame → the working CRS (method.md §7).

``T_crs_world`` is a rigid 4×4 transform (rotation about z, translation in x, y; z kept).

Heading convention (:func:`from_origin`): ``heading_deg`` is the angle of the local frame's
x axis counter-clockwise from **true (geographic) east** at the origin, which is what a GNSS /
INS yaw or a compass bearing gives (bearing clockwise from true north = 90° − heading). Grid
east of a UTM zone differs from true east by the grid convergence γ (up to ~3° at the zone
edges, at high latitudes more); the rotation stored here is the grid angle of that true
direction, found by projecting a point 1 m along it on the ellipsoid (``pyproj.Geod.fwd``),
so the convergence is taken into account whatever the CRS.

Scale: local-frame metres are used as grid metres; the point scale factor of the projection
(UTM: 0.9996 on the central meridian, up to about 1.001 at the zone edge) is not applied, so
positions drift by at most about 1 m per km from the origin in UTM. :func:`from_gnss` fits
the drive's own positions and absorbs most of it near the fixes.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import pyproj

from evperc.errors import GeoreferenceError
from evperc.geo.crs import LONLAT, transformer

log = logging.getLogger(__name__)

#: positions closer together than this do not fix a heading (:func:`from_gnss`)
MIN_SPAN_M = 5.0

_GEOD = pyproj.Geod(ellps="WGS84")


@dataclass(frozen=True, eq=False)
class Georeference:
    """The log's world frame placed in ``crs``: ``p_crs = T_crs_world · p_world``.

    ``rms_residual_m`` is the fit residual when built from GNSS fixes (0 otherwise)."""

    crs: pyproj.CRS
    T_crs_world: np.ndarray
    rms_residual_m: float = 0.0

    @property
    def heading_rad(self) -> float:
        """Grid angle of the world frame's x axis, counter-clockwise from grid east."""
        return math.atan2(self.T_crs_world[1, 0], self.T_crs_world[0, 0])

    def apply(self, T_world_sensor: np.ndarray) -> np.ndarray:
        """``T_crs_sensor = T_crs_world · T_world_sensor`` (4×4, or stacked ``(..., 4, 4)``)."""
        return self.T_crs_world @ np.asarray(T_world_sensor, dtype=np.float64)

    def apply_xy(self, xy_world: np.ndarray) -> np.ndarray:
        """World-frame positions ``(N, 2)`` → working-CRS ``(N, 2)`` (x east, y north)."""
        xy = np.asarray(xy_world, dtype=np.float64)
        return xy @ self.T_crs_world[:2, :2].T + self.T_crs_world[:2, 3]


def _planar(theta: float, tx: float, ty: float) -> np.ndarray:
    t = np.eye(4)
    c, s = math.cos(theta), math.sin(theta)
    t[:2, :2] = [[c, -s], [s, c]]
    t[:2, 3] = [tx, ty]
    return t


def identity(crs: pyproj.CRS) -> Georeference:
    """Poses already in ``crs`` (``input.poses_crs``)."""
    return Georeference(crs, np.eye(4))


def from_origin(lat_deg: float, lon_deg: float, heading_deg: float, crs: pyproj.CRS
                ) -> Georeference:
    """The local frame's origin at ``(lat, lon)``, its x axis ``heading_deg`` counter-
    clockwise from true east (module docstring: grid convergence is applied).

    ``T_crs_world`` = rotation by the grid angle of that direction, translation = the
    origin projected into ``crs``."""
    values = (lat_deg, lon_deg, heading_deg)
    if not all(math.isfinite(v) for v in values) or abs(lat_deg) > 90.0:
        raise GeoreferenceError(
            f"origin lat={lat_deg!r}, lon={lon_deg!r}, heading={heading_deg!r} deg is not a "
            "valid position; set input.origin_lat_deg / origin_lon_deg / origin_heading_deg")
    tr = transformer(LONLAT, crs)
    x0, y0 = tr.transform(lon_deg, lat_deg)
    azimuth = 90.0 - heading_deg  # clockwise from true north
    lon1, lat1, _ = _GEOD.fwd(lon_deg, lat_deg, azimuth, 1.0)
    x1, y1 = tr.transform(lon1, lat1)
    if not all(math.isfinite(v) for v in (x0, y0, x1, y1)):
        raise GeoreferenceError(
            f"origin lon={lon_deg}, lat={lat_deg} lies outside {crs.to_string()}; set map.crs "
            "to a CRS covering the drive, or \"\" for its UTM zone")
    theta = math.atan2(y1 - y0, x1 - x0)
    log.info("geo-reference from origin: (%.3f, %.3f) in %s, grid heading %.4f deg "
             "(true %.4f deg)", x0, y0, crs.to_string(), math.degrees(theta), heading_deg)
    return Georeference(crs, _planar(theta, x0, y0))


def from_gnss(world_xy: np.ndarray, fixes_lonlat: np.ndarray, crs: pyproj.CRS
              ) -> Georeference:
    """2-D rigid fit (Kabsch / Umeyama without scale) of the world positions ``(K, 2)`` to
    the GNSS fixes ``(K, 2)`` (lon, lat degrees) projected into ``crs``:
    minimise Σ ‖R·p_k + t − q_k‖², R = V·diag(1, det(V Uᵀ))·Uᵀ from the SVD of the
    covariance H = Σ (p_k − p̄)(q_k − q̄)ᵀ = U S Vᵀ, t = q̄ − R p̄.

    Non-finite pairs are dropped. Raises :class:`GeoreferenceError` when the positions span
    less than :data:`MIN_SPAN_M` (the heading is then undeterminable)."""
    p = np.asarray(world_xy, dtype=np.float64).reshape(-1, 2)
    ll = np.asarray(fixes_lonlat, dtype=np.float64).reshape(-1, 2)
    if len(p) != len(ll):
        raise ValueError(f"{len(p)} world positions but {len(ll)} GNSS fixes")
    qx, qy = transformer(LONLAT, crs).transform(ll[:, 0], ll[:, 1])
    q = np.column_stack([qx, qy])
    ok = np.isfinite(p).all(axis=1) & np.isfinite(q).all(axis=1)
    p, q = p[ok], q[ok]
    span = _span(p)
    if len(p) < 2 or span < MIN_SPAN_M:
        raise GeoreferenceError(
            f"the GNSS fixes ({len(p)} usable) cover only {span:.1f} m of the drive, too little "
            f"(< {MIN_SPAN_M:.0f} m) to fix the heading; set input.origin_heading_deg with "
            "input.origin_lat_deg / origin_lon_deg")
    p_mean, q_mean = p.mean(axis=0), q.mean(axis=0)
    h = (p - p_mean).T @ (q - q_mean)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rot = vt.T @ np.diag([1.0, d]) @ u.T
    t = q_mean - rot @ p_mean
    theta = math.atan2(rot[1, 0], rot[0, 0])
    residual = q - (p @ rot.T + t)
    rms = float(np.sqrt(np.mean(np.sum(residual**2, axis=1))))
    log.info("geo-reference from %d GNSS fixes over %.0f m: grid heading %.3f deg, RMS "
             "residual %.2f m", len(p), span, math.degrees(theta), rms)
    return Georeference(crs, _planar(theta, float(t[0]), float(t[1])), rms)


def _span(p: np.ndarray) -> float:
    """A lower bound (≥ half) of the largest distance between two of the points ``(K, 2)``:
    the largest distance from the point farthest from the centroid."""
    if len(p) < 2:
        return 0.0
    far = p[np.argmax(np.sum((p - p.mean(axis=0)) ** 2, axis=1))]
    return float(np.sqrt(np.max(np.sum((p - far) ** 2, axis=1))))
