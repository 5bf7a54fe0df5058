"""Odometry tracks against GPS fixes: the position RMSE after one rigid planar alignment.

Odometry starts at its own origin and heading; GPS is in east, north. Every track is compared
at the same fix times (those inside all the tracks' spans; linear interpolation) with the fixes
in a local east-north plane (:func:`fusion.geometry.geodesy.geodetic_to_enu`, origin the first
fix), after the one rotation and translation that fit it best
(:func:`fusion.evaluation.trajectory.se2_alignment`; no scale, so a distance error counts). This
is how issue 11 scored a real outdoor robot's bag. A GPS fix has its own error (metres for a
plain receiver), and the antenna's offset from the base swings with the heading: the RMSE
includes both, so compare tracks with each other rather than with 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.evaluation.trajectory import position_rmse, se2_alignment
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
    """Tracks against GPS, over the same fixes: those inside every track's span.

    Attributes:
        rmse: per track name, the position RMSE after its own alignment, m.
        compared: how many fixes were compared (the same for every track).
        span: (first, last) s, the times of the fixes compared.
        gps_in_track_frame: per track name, (K, 2) m, the fixes compared, moved into that
            track's frame by the inverse of its alignment (to draw beside it).
    """

    rmse: dict[str, float] = field(default_factory=dict)
    compared: int = 0
    span: tuple[float, float] = (0.0, 0.0)
    gps_in_track_frame: dict[str, NDArray[np.float64]] = field(default_factory=dict)


def compare_with_fixes(fix_t: ArrayLike, fix_en: ArrayLike,
                       tracks: dict[str, tuple[ArrayLike, ArrayLike]]) -> GpsComparison:
    """Compare each of ``tracks`` (name -> (t (M,) s, xy (M, 2) m), t increasing) with the fixes
    ``fix_en`` ((N, 2) east, north m at ``fix_t`` s, increasing) inside every track's span.

    Raises:
        ValueError: fewer than 2 fixes inside the tracks' common span (the message gives both
            spans), or a track that is not finite there.
    """
    ft = np.asarray(fix_t, dtype=float)
    fen = np.asarray(fix_en, dtype=float)
    if fen.shape != (ft.size, 2):
        raise ValueError(f"fix_en must have shape ({ft.size}, 2), got {fen.shape}")
    series = {name: (np.asarray(t, dtype=float), np.asarray(xy, dtype=float))
              for name, (t, xy) in tracks.items()}
    start = max(t[0] for t, _ in series.values())
    end = min(t[-1] for t, _ in series.values())
    inside = (ft >= start) & (ft <= end)
    n = int(np.count_nonzero(inside))
    if n < 2:
        fixes = f"{ft[0]:.3f}-{ft[-1]:.3f} s" if ft.size else "none"
        raise ValueError(f"{n} of the {ft.size} GPS fixes (stamped {fixes}) lie inside the "
                         f"odometry's span {start:.3f}-{end:.3f} s; need at least 2 (are "
                         f"the stamps on another clock?)")
    ref = fen[inside]
    out = GpsComparison(compared=n, span=(float(ft[inside][0]), float(ft[inside][-1])))
    for name, (t, xy) in series.items():
        at = np.column_stack([np.interp(ft[inside], t, xy[:, 0]),
                              np.interp(ft[inside], t, xy[:, 1])])
        try:
            theta, shift, moved = se2_alignment(at, ref)
        except ValueError as exc:
            raise ValueError(f"{name}: {exc}") from exc
        out.rmse[name] = position_rmse(moved, ref)
        c, s = np.cos(theta), np.sin(theta)
        out.gps_in_track_frame[name] = (ref - shift) @ np.array([[c, -s], [s, c]])
    return out
