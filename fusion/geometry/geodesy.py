"""GNSS fixes to a local planar frame: WGS84 geodetic coordinates to east-north-up (ENU).

A GPS receiver reports latitude and longitude (deg) and the height above the WGS84 ellipsoid
(m; sensor_msgs/NavSatFix ``altitude``). To compare them with odometry they go to a local
tangent plane at a chosen origin: geodetic -> Earth-centred Earth-fixed (ECEF) -> ENU, the exact
rotation (no flat-earth approximation), so the result holds over any distance a ground robot
drives. Constants from NIMA TR8350.2 (WGS84): ``a = 6378137 m``, ``1/f = 298.257223563``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["WGS84_A", "WGS84_F", "geodetic_to_ecef", "geodetic_to_enu"]

#: WGS84 semi-major axis, m.
WGS84_A = 6378137.0
#: WGS84 flattening.
WGS84_F = 1.0 / 298.257223563
_E2 = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared


def geodetic_to_ecef(lat_deg: ArrayLike, lon_deg: ArrayLike,
                     height_m: ArrayLike) -> NDArray[np.float64]:
    """ECEF coordinates (..., 3), m, of WGS84 latitude, longitude (deg) and ellipsoidal
    height (m)."""
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    lon = np.radians(np.asarray(lon_deg, dtype=float))
    h = np.asarray(height_m, dtype=float)
    sin_lat = np.sin(lat)
    n = WGS84_A / np.sqrt(1.0 - _E2 * sin_lat * sin_lat)  # prime vertical radius of curvature
    r = (n + h) * np.cos(lat)
    return np.stack([r * np.cos(lon), r * np.sin(lon), (n * (1.0 - _E2) + h) * sin_lat],
                    axis=-1)


def geodetic_to_enu(lat_deg: ArrayLike, lon_deg: ArrayLike, height_m: ArrayLike,
                    origin: tuple[float, float, float]) -> NDArray[np.float64]:
    """East, north, up (..., 3), m, of WGS84 fixes relative to ``origin`` = (latitude deg,
    longitude deg, height m): the tangent plane at the origin, up along its ellipsoid normal.

    Raises:
        ValueError: an origin that is not finite or a latitude beyond +-90 deg.
    """
    lat0, lon0, h0 = (float(v) for v in origin)
    if not all(np.isfinite((lat0, lon0, h0))) or abs(lat0) > 90.0:
        raise ValueError(f"origin must be a finite (latitude deg in [-90, 90], longitude deg, "
                         f"height m), got {origin!r}")
    d = geodetic_to_ecef(lat_deg, lon_deg, height_m) - geodetic_to_ecef(lat0, lon0, h0)
    phi, lam = np.radians(lat0), np.radians(lon0)
    sp, cp, sl, cl = np.sin(phi), np.cos(phi), np.sin(lam), np.cos(lam)
    east = -sl * d[..., 0] + cl * d[..., 1]
    north = -sp * cl * d[..., 0] - sp * sl * d[..., 1] + cp * d[..., 2]
    up = cp * cl * d[..., 0] + cp * sl * d[..., 1] + sp * d[..., 2]
    return np.stack([east, north, up], axis=-1)
