"""Odometry tracks against GPS fixes: the position RMSE after one rigid planar alignment.

Odometry starts at its own origin and heading; GPS is in east, north. Each track is compared
at the fix times (linear interpolation, fixes outside the track's span left out) with the fixes
in a local east-north plane (:func:`fusion.geometry.geodesy.geodetic_to_enu`, origin the first
fix), after the one rotation and translation that fit it best
(:func:`fusion.evaluation.trajectory.se2_alignment`; no scale, so a distance error counts). This
is how issue 11 scored a real outdoor robot's bag. A GPS fix has its own error (metres for a
plain receiver): the RMSE includes it, so compare tracks with each other rather than with 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.evaluation.trajectory import path_length, se2_alignment
from fusion.geometry.geodesy import geodetic_to_enu

__all__ = ["GpsComparison", "compare_with_fixes", "fixes_to_enu"]


def fixes_to_enu(latitude: ArrayLike, longitude: ArrayLike,
                 altitude: ArrayLike) -> NDArray[np.float64]:
    """East, north (N, 2), m, of WGS84 fixes (deg, deg, m) relative to the first fix."""
    lat, lon, alt = (np.asarray(a, dtype=float) for a in (latitude, longitude, altitude))
    if lat.size == 0:
        raise ValueError("no fixes")
    return geodetic_to_enu(lat, lon, alt, (lat[0], lon[0], alt[0]))[:, :2]


@dataclass
class GpsComparison:
    """Tracks against GPS.

    Attributes:
        rmse: per track name, the position RMSE after its own alignment, m.
        fixes: per track name, how many fixes fell inside its span (those compared).
        gps_distance: length of the GPS path over the fixes compared with the first track, m.
        gps_in_track_frame: per track name, (K, 2) m, the fixes it was compared with, moved into
            that track's frame by the inverse of its alignment (to draw beside it).
    """

    rmse: dict[str, float] = field(default_factory=dict)
    fixes: dict[str, int] = field(default_factory=dict)
    gps_distance: float = 0.0
    gps_in_track_frame: dict[str, NDArray[np.float64]] = field(default_factory=dict)


def compare_with_fixes(fix_t: ArrayLike, fix_en: ArrayLike,
                       tracks: dict[str, tuple[ArrayLike, ArrayLike]]) -> GpsComparison:
    """Compare each of ``tracks`` (name -> (t (M,) s, xy (M, 2) m), t increasing) with the fixes
    ``fix_en`` ((N, 2) east, north m at ``fix_t`` s).

    Raises:
        ValueError: a track with fewer than 2 fixes inside its span, or whose points at those
            fixes do not move (see :func:`fusion.evaluation.trajectory.se2_alignment`); the
            message names the track.
    """
    ft = np.asarray(fix_t, dtype=float)
    fen = np.asarray(fix_en, dtype=float)
    if fen.shape != (ft.size, 2):
        raise ValueError(f"fix_en must have shape ({ft.size}, 2), got {fen.shape}")
    out = GpsComparison()
    for k, (name, (t, xy)) in enumerate(tracks.items()):
        t = np.asarray(t, dtype=float)
        xy = np.asarray(xy, dtype=float)
        inside = (ft >= t[0]) & (ft <= t[-1])
        if np.count_nonzero(inside) < 2:
            raise ValueError(f"{name}: {np.count_nonzero(inside)} GPS fixes inside its span "
                             f"{t[0]:.3f}-{t[-1]:.3f} s; need at least 2")
        at = np.column_stack([np.interp(ft[inside], t, xy[:, 0]),
                              np.interp(ft[inside], t, xy[:, 1])])
        ref = fen[inside]
        try:
            theta, shift, moved = se2_alignment(at, ref)
        except ValueError as exc:
            raise ValueError(f"{name}: {exc}") from exc
        out.rmse[name] = float(np.sqrt(np.mean(np.sum((moved - ref) ** 2, axis=1))))
        out.fixes[name] = int(ref.shape[0])
        c, s = np.cos(theta), np.sin(theta)
        out.gps_in_track_frame[name] = (ref - shift) @ np.array([[c, -s], [s, c]])
        if k == 0:
            out.gps_distance = path_length(ref)
    return out
